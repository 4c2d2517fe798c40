//! `castle`: a walled town, dense and occluded.
//!
//! Generation follows the steps of the city generator in Marvie, Perret & Bouatouch (§3.1):
//! a regular street graph (three streets each way inside the walls), disturbed by removing
//! street segments (a building is put across them) except those the track uses; the blocks
//! between streets are cut into building footprints of random sizes; each building gets a
//! random height and a style from a small library (plaster or brick facades with windows,
//! flat or pitched roofs). Around the town: curtain walls with merlons, corner towers, a gate
//! flanked by towers, and a keep on one block.

use std::sync::Arc;

use glam::DVec3;
use tracks::{Sampling, Smoothing, Track, TrackSet};

use super::{Builder, Rng};
use crate::scene::{Mesh, PointLight, Shape, Sky, Sun, Texture};

/// Seed of the built-in `castle`.
pub const SEED: u64 = 0x00CA_571E;

/// Inner face of the curtain walls (± metres in x and z).
const INNER: f64 = 28.0;
const WALL_THICK: f64 = 2.0;
const WALL_H: f64 = 9.0;
/// Street centre lines (both directions) and half width.
const STREETS: [f64; 3] = [-14.0, 0.0, 14.0];
const STREET_HALF: f64 = 2.5;
/// Blocks end this far inside the walls (a walkway along them).
const WALK: f64 = 2.0;
const EYE: f64 = 1.7;

/// Intervals between streets along one axis: the blocks' extents.
fn block_spans() -> Vec<(f64, f64)> {
    let mut edges = vec![-INNER + WALK];
    for s in STREETS {
        edges.push(s - STREET_HALF);
        edges.push(s + STREET_HALF);
    }
    edges.push(INNER - WALK);
    edges.chunks(2).map(|c| (c[0], c[1])).collect()
}

/// A pitched roof over `[x0,x1]×[z0,z1]` at eave height `h`, ridge `rise` higher, ridge along
/// the longer side.
fn roof(x0: f64, x1: f64, z0: f64, z1: f64, h: f64, rise: f64) -> Mesh {
    let along_x = x1 - x0 >= z1 - z0;
    let (zc, xc) = (0.5 * (z0 + z1), 0.5 * (x0 + x1));
    let positions = if along_x {
        vec![
            DVec3::new(x0, h, z0),
            DVec3::new(x1, h, z0),
            DVec3::new(x1, h, z1),
            DVec3::new(x0, h, z1),
            DVec3::new(x0, h + rise, zc),
            DVec3::new(x1, h + rise, zc),
        ]
    } else {
        vec![
            DVec3::new(x0, h, z0),
            DVec3::new(x0, h, z1),
            DVec3::new(x1, h, z1),
            DVec3::new(x1, h, z0),
            DVec3::new(xc, h + rise, z0),
            DVec3::new(xc, h + rise, z1),
        ]
    };
    Mesh {
        positions,
        triangles: vec![
            [0, 1, 5],
            [0, 5, 4],
            [3, 4, 5],
            [3, 5, 2],
            [0, 4, 3],
            [1, 2, 5],
        ],
    }
}

/// The scene description and its tracks.
pub fn generate(seed: u64) -> (crate::scene::SceneDesc, TrackSet) {
    let mut rng = Rng::new(seed);
    let mut b = Builder::default();
    lighting(&mut b);
    let m = Palette::new(&mut b);
    ground(&mut b, &m);
    curtain_walls(&mut b, &m);
    merlons(&mut b, &m);
    towers(&mut b, &m);
    let spans = block_spans();
    blocked_streets(&mut b, &mut rng, &spans, &m);
    blocks(&mut b, &mut rng, &spans, &m);
    trees(&mut b, &mut rng);
    (
        b.desc,
        TrackSet {
            tracks: [vec![main_track()], street_tracks()].concat(),
        },
    )
}

/// Sky, sun and the one point light.
fn lighting(b: &mut Builder) {
    b.desc.sky = Sky::default();
    b.desc.sun = Some(Sun {
        direction: DVec3::new(0.45, 0.75, 0.35),
        color: DVec3::new(1.0, 0.95, 0.85),
    });
    b.desc.lights.push(PointLight {
        position: DVec3::new(1.5, 4.0, -1.5),
        color: DVec3::new(6.0, 4.5, 2.5),
    });
}

/// The town's materials (indices into the builder's list), created in this order.
struct Palette {
    grass: usize,
    cobbles: usize,
    stone: usize,
    slate: usize,
    tiles: usize,
    wood: usize,
    /// House facades: four plasters and a brick.
    styles: Vec<usize>,
}

impl Palette {
    fn new(b: &mut Builder) -> Palette {
        let grass = b.material(
            "grass",
            [0.18, 0.32, 0.10],
            Texture::Noise {
                color2: DVec3::new(0.30, 0.42, 0.14),
                size: 2.5,
            },
        );
        let cobbles = b.material(
            "cobbles",
            [0.42, 0.40, 0.37],
            Texture::Bricks {
                mortar: DVec3::new(0.25, 0.24, 0.22),
                width: 0.35,
                height: 0.35,
                joint: 0.03,
            },
        );
        let stone = b.material(
            "stone",
            [0.55, 0.52, 0.47],
            Texture::Bricks {
                mortar: DVec3::new(0.70, 0.68, 0.63),
                width: 0.9,
                height: 0.45,
                joint: 0.04,
            },
        );
        let slate = b.material(
            "slate",
            [0.20, 0.22, 0.28],
            Texture::Noise {
                color2: DVec3::new(0.28, 0.30, 0.36),
                size: 0.7,
            },
        );
        let tiles = b.material(
            "roof_tiles",
            [0.55, 0.22, 0.14],
            Texture::Checker {
                color2: DVec3::new(0.45, 0.18, 0.12),
                size: 0.4,
            },
        );
        let wood = b.material("gate_wood", [0.35, 0.22, 0.12], Texture::Solid);
        let mut styles: Vec<usize> = Vec::new();
        for (name, c) in [
            ("plaster_cream", [0.80, 0.74, 0.60]),
            ("plaster_ochre", [0.78, 0.58, 0.32]),
            ("plaster_white", [0.85, 0.85, 0.82]),
            ("plaster_rose", [0.78, 0.55, 0.50]),
        ] {
            styles.push(b.material(
                name,
                c,
                Texture::Windows {
                    glass: DVec3::new(0.10, 0.14, 0.20),
                    spacing: [2.8, 3.2],
                    size: [1.0, 1.5],
                },
            ));
        }
        styles.push(b.material(
            "brick_house",
            [0.50, 0.25, 0.18],
            Texture::Bricks {
                mortar: DVec3::new(0.65, 0.62, 0.58),
                width: 0.25,
                height: 0.08,
                joint: 0.012,
            },
        ));
        Palette {
            grass,
            cobbles,
            stone,
            slate,
            tiles,
            wood,
            styles,
        }
    }
}

/// Ground and paving: the grass plane, the cobbled town and the road to the gate.
fn ground(b: &mut Builder, m: &Palette) {
    b.add(
        Shape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        },
        m.grass,
    );
    b.boxed(
        DVec3::new(-INNER, -0.2, -INNER),
        DVec3::new(INNER, 0.02, INNER),
        m.cobbles,
    );
    // The road to the gate.
    b.boxed(
        DVec3::new(-STREET_HALF, -0.2, INNER),
        DVec3::new(STREET_HALF, 0.02, INNER + 20.0),
        m.cobbles,
    );
}

/// Curtain walls; the front wall (+z) has the gate opening at |x| < STREET_HALF, with an open
/// gate leaf against the inside of the wall.
fn curtain_walls(b: &mut Builder, m: &Palette) {
    let stone = m.stone;
    let (i, o) = (INNER, INNER + WALL_THICK);
    let gate_h = 5.0;
    b.boxed(DVec3::new(-o, 0.0, -o), DVec3::new(o, WALL_H, -i), stone); // back
    b.boxed(DVec3::new(-o, 0.0, -i), DVec3::new(-i, WALL_H, i), stone); // west
    b.boxed(DVec3::new(i, 0.0, -i), DVec3::new(o, WALL_H, i), stone); // east
    b.boxed(
        DVec3::new(-o, 0.0, i),
        DVec3::new(-STREET_HALF, WALL_H, o),
        stone,
    );
    b.boxed(
        DVec3::new(STREET_HALF, 0.0, i),
        DVec3::new(o, WALL_H, o),
        stone,
    );
    b.boxed(
        DVec3::new(-STREET_HALF, gate_h, i),
        DVec3::new(STREET_HALF, WALL_H, o),
        stone,
    );
    // An open gate leaf against the inside of the wall.
    b.boxed(
        DVec3::new(STREET_HALF + 0.1, 0.0, i - 2.6),
        DVec3::new(STREET_HALF + 0.25, gate_h - 0.2, i - 0.1),
        m.wood,
    );
}

/// Merlons along the wall tops.
fn merlons(b: &mut Builder, m: &Palette) {
    let stone = m.stone;
    let (i, o) = (INNER, INNER + WALL_THICK);
    let mut x = -o + 0.5;
    while x < o - 1.0 {
        for (z0, z1) in [(-o, -i), (i, o)] {
            b.boxed(
                DVec3::new(x, WALL_H, z0),
                DVec3::new(x + 1.0, WALL_H + 1.2, z0 + 0.5 * (z1 - z0)),
                stone,
            );
        }
        for (x0, x1) in [(-o, -i), (i, o)] {
            b.boxed(
                DVec3::new(x0, WALL_H, x),
                DVec3::new(x0 + 0.5 * (x1 - x0), WALL_H + 1.2, x + 1.0),
                stone,
            );
        }
        x += 2.0;
    }
}

/// Corner towers and gate towers, each with a slate cone.
fn towers(b: &mut Builder, m: &Palette) {
    let mid = INNER + 0.5 * WALL_THICK;
    for (cx, cz, r, h) in [
        (-mid, -mid, 4.0, 14.0),
        (mid, -mid, 4.0, 14.0),
        (-mid, mid, 4.0, 14.0),
        (mid, mid, 4.0, 14.0),
        (-(STREET_HALF + 2.6), mid + 1.0, 2.5, 12.0),
        (STREET_HALF + 2.6, mid + 1.0, 2.5, 12.0),
    ] {
        b.cylinder(DVec3::new(cx, 0.0, cz), DVec3::new(cx, h, cz), r, m.stone);
        b.cone(
            DVec3::new(cx, h, cz),
            DVec3::new(cx, h + 1.4 * r, cz),
            r + 0.5,
            m.slate,
        );
    }
}

/// Whether the track runs along the street segment `span` of street `street`.
fn track_uses(vertical: bool, street: f64, span: (f64, f64)) -> bool {
    let c = 0.5 * (span.0 + span.1);
    if vertical {
        (street == 0.0 && c > 0.0) || (street == 14.0 && c < 0.0 && c > -14.0)
    } else {
        street == 0.0 && c > 0.0 && c < 14.0
    }
}

/// The street graph: segments between crossings; some that the track does not use are removed
/// by putting a building across them.
fn blocked_streets(b: &mut Builder, rng: &mut Rng, spans: &[(f64, f64)], m: &Palette) {
    for vertical in [true, false] {
        for &s in &STREETS {
            for &span in spans {
                if track_uses(vertical, s, span) || rng.f() > 0.3 {
                    continue;
                }
                let (a0, a1) = (s - STREET_HALF, s + STREET_HALF);
                let h = rng.range(5.0, 9.0);
                let style = m.styles[rng.below(m.styles.len())];
                let (min, max) = if vertical {
                    (DVec3::new(a0, 0.0, span.0), DVec3::new(a1, h, span.1))
                } else {
                    (DVec3::new(span.0, 0.0, a0), DVec3::new(span.1, h, a1))
                };
                b.boxed(min, max, style);
            }
        }
    }
}

/// Blocks → building footprints (the keep takes one block).
fn blocks(b: &mut Builder, rng: &mut Rng, spans: &[(f64, f64)], m: &Palette) {
    for (bi, &(x0, x1)) in spans.iter().enumerate() {
        for (bj, &(z0, z1)) in spans.iter().enumerate() {
            if bi == 1 && bj == 1 {
                keep(b, 0.5 * (x0 + x1), 0.5 * (z0 + z1), m);
            } else {
                houses(b, rng, (x0, x1), (z0, z1), m);
            }
        }
    }
}

/// The keep: a tall round tower with a slate cone, centred at (`cx`, `cz`).
fn keep(b: &mut Builder, cx: f64, cz: f64, m: &Palette) {
    b.cylinder(
        DVec3::new(cx, 0.0, cz),
        DVec3::new(cx, 24.0, cz),
        4.2,
        m.stone,
    );
    b.cone(
        DVec3::new(cx, 24.0, cz),
        DVec3::new(cx, 31.0, cz),
        4.8,
        m.slate,
    );
}

/// One block `[x0,x1]×[z0,z1]` cut across its longer side into two or three houses of random
/// widths, heights and styles, some with pitched roofs.
fn houses(b: &mut Builder, rng: &mut Rng, (x0, x1): (f64, f64), (z0, z1): (f64, f64), m: &Palette) {
    let split_x = x1 - x0 >= z1 - z0;
    let (lo, hi) = if split_x { (x0, x1) } else { (z0, z1) };
    let parts = 2 + rng.below(2);
    let mut cuts = vec![lo];
    for k in 1..parts {
        let base = lo + (hi - lo) * k as f64 / parts as f64;
        cuts.push(base + rng.range(-0.12, 0.12) * (hi - lo) / parts as f64);
    }
    cuts.push(hi);
    for w in cuts.windows(2) {
        let (a, c) = (w[0], w[1]);
        let (bx0, bx1, bz0, bz1) = if split_x {
            (a, c, z0, z1)
        } else {
            (x0, x1, a, c)
        };
        let h = rng.range(6.0, 13.0);
        let style = m.styles[rng.below(m.styles.len())];
        b.boxed(DVec3::new(bx0, 0.0, bz0), DVec3::new(bx1, h, bz1), style);
        if rng.f() < 0.6 {
            let rise = rng.range(1.8, 3.2);
            b.add(
                Shape::Mesh(Arc::new(roof(bx0, bx1, bz0, bz1, h, rise))),
                m.tiles,
            );
        }
    }
}

/// A few trees outside the walls (their materials come last in the list).
fn trees(b: &mut Builder, rng: &mut Rng) {
    let bark = b.material("bark", [0.30, 0.20, 0.12], Texture::Solid);
    let leaves = b.material(
        "leaves",
        [0.12, 0.30, 0.08],
        Texture::Noise {
            color2: DVec3::new(0.22, 0.42, 0.12),
            size: 0.8,
        },
    );
    for _ in 0..14 {
        let side = if rng.f() < 0.5 { -1.0 } else { 1.0 };
        let x = side * rng.range(6.0, 40.0);
        let z = rng.range(INNER + 6.0, INNER + 30.0);
        let h = rng.range(2.5, 4.0);
        b.cylinder(DVec3::new(x, 0.0, z), DVec3::new(x, h, z), 0.25, bark);
        b.add(
            Shape::Sphere {
                center: DVec3::new(x, h + 1.2, z),
                radius: rng.range(1.6, 2.4),
            },
            leaves,
        );
    }
}

/// Track `main`: in through the gate, along the middle street, then right and back.
/// The town's street network beside `main`, along streets the generator leaves open with this
/// seed (checked by a test): `west` (x = −14) and `cross` (z = 0) cross at (−14, 0); `cross`
/// ends on `main`'s corner at (0, 0); `south` (z = −14) starts at `west`'s end and crosses
/// `main`'s last leg at (14, −14); `north` (z = 14) leaves `main` at (0, 14). Every junction on
/// `main` is one of its viewpoints (2 m apart), so `main` is sampled as alone.
fn street_tracks() -> Vec<Track> {
    let street = |name: &str, points: &[[f64; 2]]| {
        Track::new(
            name,
            points.iter().map(|p| DVec3::new(p[0], EYE, p[1])).collect(),
            Smoothing::None,
            Sampling::Spacing(2.0),
            "builtin:castle",
        )
        .expect("castle street is valid")
    };
    vec![
        street("west", &[[-14.0, -14.0], [-14.0, 0.0], [-14.0, 14.0]]),
        street("cross", &[[-24.0, 0.0], [0.0, 0.0]]),
        street("south", &[[-14.0, -14.0], [14.0, -14.0], [24.0, -14.0]]),
        street("north", &[[0.0, 14.0], [24.0, 14.0]]),
    ]
}

fn main_track() -> Track {
    let points = vec![
        DVec3::new(0.0, EYE, INNER + 14.0),
        DVec3::new(0.0, EYE, 0.0),
        DVec3::new(14.0, EYE, 0.0),
        DVec3::new(14.0, EYE, -16.0),
    ];
    Track::new(
        "main",
        points,
        Smoothing::None,
        Sampling::Spacing(2.0),
        "builtin:castle",
    )
    .expect("castle track is valid")
}
