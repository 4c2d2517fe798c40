//! `town-K`: a procedural town of about K kilometres of street, for builds that scale.
//!
//! A square grid of `n × n` straight streets, `pitch` metres apart, chosen so that the streets
//! add up to K km (`2 n (n − 1) pitch = 1000 K`, the pitch between 60 and 100 m). Each block
//! between four streets, and each of a ring of blocks around the grid (so that the outer
//! streets are lined on both sides too), is a raised pavement with a ring of buildings of
//! varied frontages, depths, heights and facades around an open courtyard; lamp posts (thin
//! occluders) line the pavements and a few trees stand on them. One track per street: `ew-J`
//! runs east along `z = J · pitch`, `ns-I` north along `x = I · pitch`; every crossing is a
//! control point of both, so the `n²` crossings are the network's junctions
//! ([`tracks::network`]). Viewpoints are about a metre apart (never more than
//! [`tracks::limits::MAX_VIEWPOINTS`] in all).

use glam::DVec3;
use tracks::limits::MAX_VIEWPOINTS;
use tracks::{Sampling, Smoothing, Track, TrackSet};

use super::{Builder, Rng};
use crate::scene::{SceneDesc, Shape, Sky, Sun, Texture};

/// Seed of every `town-K` (K changes the layout, not the seed).
pub const SEED: u64 = 0x0007_0A11;
/// The sizes a town may have, kilometres of street.
pub const KM: std::ops::RangeInclusive<u32> = 1..=100;
/// Name prefix of the family: `town-K`.
pub const PREFIX: &str = "town-";

const EYE: f64 = 1.7;
/// Half width of the carriageway; the pavements start here.
const ROAD_HALF: f64 = 4.0;
/// Buildings stand this far from a street's centre line (a 3 m pavement).
const FRONT: f64 = 7.0;
const KERB: f64 = 0.15;
/// Lamp posts stand this far from the centre line, about this far apart.
const LAMP_OFFSET: f64 = 5.0;
const LAMP_STEP: f64 = 24.0;
/// Viewpoints are at most this far apart before the cap on their number.
const SPACING: f64 = 0.98;

/// `K` of a name `town-K` with `K` in [`KM`]; `None` for any other name.
pub fn km_of(name: &str) -> Option<u32> {
    let digits = name.strip_prefix(PREFIX)?;
    if digits.is_empty() || digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok().filter(|k| KM.contains(k))
}

/// Why `name` looks like a town but is none (`town-0`, `town-x`, `town-101`), or `None`.
pub fn name_error(name: &str) -> Option<String> {
    (name.starts_with(PREFIX) && km_of(name).is_none()).then(|| {
        format!(
            "scene `{name}`: a town is `{PREFIX}K` with K a whole number of kilometres of \
             street from {} to {}",
            KM.start(),
            KM.end()
        )
    })
}

/// The street grid of a town of `km` kilometres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Streets each way.
    pub streets: usize,
    /// Distance between neighbouring parallel streets, metres.
    pub pitch: f64,
    /// Segments (viewpoint gaps) between two neighbouring crossings.
    pub per_block: usize,
}

impl Grid {
    /// The grid with `2 n (n − 1) pitch = 1000 km` whose pitch is nearest 80 m (within
    /// 60..=100 m); a metre or less between viewpoints, fewer where that would pass
    /// [`MAX_VIEWPOINTS`].
    pub fn for_km(km: u32) -> Grid {
        let total = 1000.0 * f64::from(km);
        let pitch_of = |n: usize| total / (2 * n * (n - 1)) as f64;
        let streets = (2..200)
            .filter(|&n| (60.0..=100.0).contains(&pitch_of(n)))
            .min_by(|&a, &b| {
                (pitch_of(a) - 80.0)
                    .abs()
                    .total_cmp(&(pitch_of(b) - 80.0).abs())
            })
            .unwrap_or(3);
        let pitch = pitch_of(streets);
        let mut g = Grid {
            streets,
            pitch,
            per_block: (pitch / SPACING).ceil() as usize,
        };
        while g.viewpoints() > MAX_VIEWPOINTS && g.per_block > 1 {
            g.per_block -= 1;
        }
        g
    }

    /// Street length in all, metres.
    pub fn length(&self) -> f64 {
        (2 * self.streets * (self.streets - 1)) as f64 * self.pitch
    }

    /// Viewpoints of the network: every segment's, less one per independent cycle.
    pub fn viewpoints(&self) -> usize {
        let n = self.streets;
        2 * n * (n - 1) * self.per_block + 1 - (n - 1) * (n - 1)
    }

    /// Distance between viewpoints along a street, metres.
    pub fn spacing(&self) -> f64 {
        self.pitch / self.per_block as f64
    }

    /// Where street `i` runs (its x for `ns-i`, its z for `ew-i`; −1 and `n` are the far
    /// sides of the ring of blocks around the town).
    fn at(&self, i: i64) -> f64 {
        i as f64 * self.pitch
    }
}

/// The scene description and tracks of the town of `km` kilometres.
pub fn generate(km: u32, seed: u64) -> (SceneDesc, TrackSet) {
    let g = Grid::for_km(km);
    let mut rng = Rng::new(seed ^ u64::from(km).wrapping_mul(0x9E37_79B9));
    let mut b = Builder::default();
    b.desc.sky = Sky::default();
    b.desc.sun = Some(Sun {
        direction: DVec3::new(0.40, 0.78, 0.30),
        color: DVec3::new(1.0, 0.95, 0.86),
    });
    let m = Palette::new(&mut b);
    b.add(
        Shape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        },
        m.asphalt,
    );
    // The blocks between the streets and a ring of blocks around them, so that the outer
    // streets are lined on both sides like every other (and the cost of a view does not
    // depend on how much of the town lies at its edge).
    let n = g.streets as i64;
    for bi in -1..n {
        for bj in -1..n {
            let (x0, z0) = (g.at(bi), g.at(bj));
            block(&mut b, &mut rng, &m, [x0, x0 + g.pitch], [z0, z0 + g.pitch]);
        }
    }
    (
        b.desc,
        TrackSet {
            tracks: tracks(&g, km),
        },
    )
}

/// The town's materials (indices into the builder's list).
struct Palette {
    asphalt: usize,
    paving: usize,
    metal: usize,
    bark: usize,
    leaves: usize,
    roof: usize,
    facades: Vec<usize>,
}

impl Palette {
    fn new(b: &mut Builder) -> Palette {
        let asphalt = b.material(
            "asphalt",
            [0.22, 0.22, 0.23],
            Texture::Noise {
                color2: DVec3::new(0.28, 0.28, 0.29),
                size: 1.5,
            },
        );
        let paving = b.material(
            "paving",
            [0.55, 0.53, 0.50],
            Texture::Checker {
                color2: DVec3::new(0.48, 0.46, 0.44),
                size: 0.6,
            },
        );
        let metal = b.material("lamp_metal", [0.12, 0.13, 0.14], Texture::Solid);
        let bark = b.material("bark", [0.30, 0.20, 0.12], Texture::Solid);
        let leaves = b.material(
            "leaves",
            [0.14, 0.32, 0.10],
            Texture::Noise {
                color2: DVec3::new(0.24, 0.44, 0.14),
                size: 0.8,
            },
        );
        let roof = b.material("roof", [0.30, 0.28, 0.27], Texture::Solid);
        let mut facades = Vec::new();
        for (name, c) in [
            ("facade_cream", [0.80, 0.74, 0.60]),
            ("facade_ochre", [0.76, 0.56, 0.32]),
            ("facade_white", [0.85, 0.85, 0.82]),
            ("facade_rose", [0.76, 0.54, 0.50]),
            ("facade_grey", [0.52, 0.54, 0.56]),
        ] {
            facades.push(b.material(
                name,
                c,
                Texture::Windows {
                    glass: DVec3::new(0.10, 0.14, 0.20),
                    spacing: [3.0, 3.2],
                    size: [1.2, 1.6],
                },
            ));
        }
        facades.push(b.material(
            "brick",
            [0.50, 0.25, 0.18],
            Texture::Bricks {
                mortar: DVec3::new(0.65, 0.62, 0.58),
                width: 0.25,
                height: 0.08,
                joint: 0.012,
            },
        ));
        Palette {
            asphalt,
            paving,
            metal,
            bark,
            leaves,
            roof,
            facades,
        }
    }
}

/// The block between streets at `x` and `z` (centre lines): its pavement, a ring of buildings
/// around a courtyard, lamp posts along its four kerbs and a tree or two.
fn block(b: &mut Builder, rng: &mut Rng, m: &Palette, x: [f64; 2], z: [f64; 2]) {
    b.boxed(
        DVec3::new(x[0] + ROAD_HALF, 0.0, z[0] + ROAD_HALF),
        DVec3::new(x[1] - ROAD_HALF, KERB, z[1] - ROAD_HALF),
        m.paving,
    );
    let (lo, hi) = ([x[0] + FRONT, z[0] + FRONT], [x[1] - FRONT, z[1] - FRONT]);
    let depth = rng.range(10.0, 16.0).min(0.4 * (hi[0] - lo[0]));
    // North and south rows run the block's whole width; east and west rows fill between them.
    for (along_x, fixed, inward, span) in [
        (true, lo[1], 1.0, [lo[0], hi[0]]),
        (true, hi[1], -1.0, [lo[0], hi[0]]),
        (false, lo[0], 1.0, [lo[1] + depth, hi[1] - depth]),
        (false, hi[0], -1.0, [lo[1] + depth, hi[1] - depth]),
    ] {
        row(b, rng, m, along_x, fixed, fixed + inward * depth, span);
    }
    // Lamp posts along each kerb, spread evenly, clear of the corners.
    for (along_x, fixed, span) in [
        (true, z[0] + LAMP_OFFSET, x),
        (true, z[1] - LAMP_OFFSET, x),
        (false, x[0] + LAMP_OFFSET, z),
        (false, x[1] - LAMP_OFFSET, z),
    ] {
        let inner = [span[0] + FRONT, span[1] - FRONT];
        let count = ((inner[1] - inner[0]) / LAMP_STEP).round().max(1.0) as usize;
        for k in 0..count {
            let t = inner[0] + (inner[1] - inner[0]) * (k as f64 + 0.5) / count as f64;
            let base = if along_x {
                DVec3::new(t, KERB, fixed)
            } else {
                DVec3::new(fixed, KERB, t)
            };
            b.cylinder(base, base + DVec3::new(0.0, 4.5, 0.0), 0.09, m.metal);
            if rng.f() < 0.12 {
                // A tree beside the lamp, a few metres along the kerb.
                let step = if along_x { DVec3::X } else { DVec3::Z } * 5.0;
                tree(b, rng, m, base + step);
            }
        }
    }
}

/// Buildings side by side along one side of a block: footprints from `span[0]` to `span[1]`
/// along the row, from `front` to `back` across it; frontages 8–20 m, heights 6–28 m.
fn row(
    b: &mut Builder,
    rng: &mut Rng,
    m: &Palette,
    along_x: bool,
    front: f64,
    back: f64,
    span: [f64; 2],
) {
    let (c0, c1) = (front.min(back), front.max(back));
    let mut a = span[0];
    while span[1] - a > 0.5 {
        let mut w = rng.range(8.0, 20.0);
        if span[1] - (a + w) < 8.0 {
            w = span[1] - a;
        }
        let h = 6.0 + 22.0 * rng.f() * rng.f();
        let facade = m.facades[rng.below(m.facades.len())];
        let (min, max) = if along_x {
            (DVec3::new(a, 0.0, c0), DVec3::new(a + w, h, c1))
        } else {
            (DVec3::new(c0, 0.0, a), DVec3::new(c1, h, a + w))
        };
        b.boxed(min, max, facade);
        if rng.f() < 0.3 {
            // A plant room on the roof, set back from every edge.
            let inset = DVec3::new(2.0, 0.0, 2.0);
            let top = DVec3::new(0.0, h, 0.0);
            let lo = min.with_y(0.0) + inset + top;
            let hi = max.with_y(h + rng.range(1.5, 3.0)) - inset;
            if hi.x > lo.x && hi.z > lo.z {
                b.boxed(lo, hi, m.roof);
            }
        }
        a += w;
    }
}

/// A broadleaf: a trunk and a round crown above head height.
fn tree(b: &mut Builder, rng: &mut Rng, m: &Palette, base: DVec3) {
    let h = rng.range(3.0, 4.0);
    b.cylinder(base, base + DVec3::new(0.0, h, 0.0), 0.2, m.bark);
    b.add(
        Shape::Sphere {
            center: base + DVec3::new(0.0, h + 1.0, 0.0),
            radius: rng.range(1.4, 2.0),
        },
        m.leaves,
    );
}

/// One straight track per street, a control point at every crossing.
fn tracks(g: &Grid, km: u32) -> Vec<Track> {
    let source = format!("builtin:{PREFIX}{km}");
    let street = |name: String, at: &dyn Fn(f64) -> DVec3| {
        let points = (0..g.streets as i64).map(|k| at(g.at(k))).collect();
        Track::new(
            &name,
            points,
            Smoothing::None,
            Sampling::Spacing(g.spacing()),
            &source,
        )
        .expect("town street is valid")
    };
    let mut out = Vec::with_capacity(2 * g.streets);
    for j in 0..g.streets {
        let z = g.at(j as i64);
        out.push(street(format!("ew-{j}"), &|x| DVec3::new(x, EYE, z)));
    }
    for i in 0..g.streets {
        let x = g.at(i as i64);
        out.push(street(format!("ns-{i}"), &|z| DVec3::new(x, EYE, z)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::network::Network;

    #[test]
    fn town_names_parse_only_in_range() {
        assert_eq!(km_of("town-1"), Some(1));
        assert_eq!(km_of("town-100"), Some(100));
        for bad in [
            "town-0", "town-101", "town-", "town-x", "town-01", "town-+3", "town1",
        ] {
            assert_eq!(km_of(bad), None, "{bad}");
        }
        assert!(name_error("town-0").is_some_and(|e| e.contains("1 to 100")));
        assert!(name_error("castle").is_none());
        assert!(name_error("town-5").is_none());
    }

    #[test]
    fn grid_adds_up_to_the_length_and_viewpoints_asked() {
        for km in KM {
            let g = Grid::for_km(km);
            let want = 1000.0 * f64::from(km);
            assert!((g.length() - want).abs() <= 0.15 * want, "{km}: {g:?}");
            assert!((60.0..=100.0).contains(&g.pitch), "{km}: {g:?}");
            assert!(g.viewpoints() <= MAX_VIEWPOINTS, "{km}: {g:?}");
            let least = (1000 * km as usize).min(MAX_VIEWPOINTS * 99 / 100);
            assert!(g.viewpoints() >= least, "{km}: {g:?}");
            assert!(g.spacing() <= 1.0 + 1e-9, "{km}: {g:?}");
        }
    }

    #[test]
    fn towns_form_a_network_of_streets() {
        for km in [1, 2, 5, 10] {
            let g = Grid::for_km(km);
            let (desc, set) = generate(km, SEED);
            let again = generate(km, SEED);
            assert_eq!(desc, again.0, "{km}");
            assert_eq!(set, again.1, "{km}");
            let length: f64 = set.tracks.iter().map(|t| t.length()).sum();
            let want = 1000.0 * f64::from(km);
            assert!((length - want).abs() <= 0.15 * want, "{km}: {length}");
            let net = Network::new(set.tracks).unwrap();
            let n = g.streets;
            assert_eq!(net.junctions.len(), n * n, "{km}");
            // Corners join two branches, edges three, inner crossings four.
            let fours = net.junctions.iter().filter(|j| j.branches.len() == 4);
            assert_eq!(fours.count(), (n - 2) * (n - 2), "{km}");
            assert_eq!(net.viewpoints.len(), g.viewpoints(), "{km}");
            let at_junctions = (0..net.viewpoints.len())
                .filter(|&v| net.junction_at(v).is_some_and(|j| j.viewpoint == v))
                .count();
            assert_eq!(at_junctions, n * n, "{km}");
            assert!(net.viewpoints.len() >= 1000 * km as usize, "{km}");
        }
    }

    #[test]
    fn town_streets_are_open_at_eye_height() {
        let b = super::super::builtin("town-2").unwrap();
        let net = Network::new(b.tracks.tracks.clone()).unwrap();
        for e in 0..net.segments.len() {
            let p = net.segment_path(e);
            for w in p.windows(2) {
                let d = w[1] - w[0];
                let hit = b.scene.first_hit(w[0], d.normalize(), d.length());
                assert!(hit.is_none(), "segment {e} {:?}: {hit:?}", net.segments[e]);
            }
        }
        for v in net.viewpoints.iter().step_by(7) {
            let down = b.scene.first_hit(*v, DVec3::NEG_Y, f64::INFINITY);
            assert!(down.is_some_and(|d| (d - EYE).abs() < 1e-6), "{v} {down:?}");
            let up = b.scene.first_hit(*v, DVec3::Y, f64::INFINITY);
            assert!(up.is_none(), "{v} {up:?}");
        }
    }
}
