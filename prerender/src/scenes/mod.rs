//! Built-in scenes: deterministic procedural generators that emit the TOML scene format.
//!
//! - `castle` ([`castle`]): dense and occluded. A walled town on a perturbed street grid (after
//!   the city generator of Marvie, Perret and Bouatouch §3.1: a regular street graph, some
//!   streets removed, building footprints cut from the blocks with random sizes and styles),
//!   curtain walls with merlons, corner and gate towers, a keep. Track `main` enters through
//!   the gate and turns through the streets, so most of the town is hidden behind walls.
//! - `nature` ([`nature`]): open. Rolling terrain mesh, trees, rocks, far hills; track `main`
//!   winds across a meadow.
//! - `town-K` ([`town`]): a street grid of about K km (K from 1 to 100) with one track per
//!   street and a junction at every crossing, for builds whose size is a parameter.
//!
//! Each generator builds a [`SceneDesc`], writes it as TOML (plus its `[[track]]` tables) and
//! parses that text back, so the built-in scenes exercise exactly the format users write.

use glam::DVec3;
use tracks::TrackSet;

use crate::parse::to_toml;
use crate::scene::{Material, Object, Scene, SceneDesc, Shape, Texture};

pub mod castle;
pub mod nature;
pub mod town;

/// Names of the built-in scenes of fixed size (the towns, `town-K`, are a family; see
/// [`names_help`]).
pub const NAMES: [&str; 2] = ["castle", "nature"];

/// The built-in scenes as a message lists them: `castle, nature, town-K (K = 1 to 100 km of
/// street)`.
pub fn names_help() -> String {
    format!(
        "{}, {}K (K = {} to {} km of street)",
        NAMES.join(", "),
        town::PREFIX,
        town::KM.start(),
        town::KM.end()
    )
}

/// Why `name` is no built-in scene when it looks like one (a town of a size there is none
/// of), or `None`: the message for a name such as `town-0` that a caller would otherwise take
/// for a file name.
pub fn name_error(name: &str) -> Option<String> {
    town::name_error(name)
}

/// A generated scene with its tracks and the TOML text it was parsed from.
#[derive(Debug)]
pub struct BuiltinScene {
    pub scene: Scene,
    pub tracks: TrackSet,
    /// Scene and `[[track]]` tables; `Scene::parse_toml(&toml, …)` gives `scene` back.
    pub toml: String,
}

/// The built-in scene `name` (see [`NAMES`] and [`names_help`]), or `None`.
pub fn builtin(name: &str) -> Option<BuiltinScene> {
    let (desc, tracks) = match name {
        "castle" => castle::generate(castle::SEED),
        "nature" => nature::generate(nature::SEED),
        _ => town::generate(town::km_of(name)?, town::SEED),
    };
    let mut toml = format!("# Built-in scene `{name}` (generated; deterministic).\n\n");
    toml.push_str(&to_toml(&desc).expect("generators use no image textures"));
    toml.push_str(&tracks.to_toml());
    let scene = Scene::parse_toml(&toml, &format!("builtin:{name}"))
        .expect("generated scenes are valid by construction");
    Some(BuiltinScene {
        scene,
        tracks,
        toml,
    })
}

/// SplitMix64: small, fast, and the same on every platform.
#[derive(Clone, Debug)]
pub(crate) struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.f()
    }
    /// Uniform integer in [0, n).
    pub fn below(&mut self, n: usize) -> usize {
        (self.f() * n as f64) as usize % n.max(1)
    }
}

/// Helper to assemble a [`SceneDesc`].
#[derive(Default)]
pub(crate) struct Builder {
    pub desc: SceneDesc,
}

impl Builder {
    pub fn material(&mut self, name: &str, color: [f64; 3], texture: Texture) -> usize {
        self.desc.materials.push(Material {
            name: name.into(),
            color: DVec3::from_array(color),
            texture,
        });
        self.desc.materials.len() - 1
    }
    pub fn add(&mut self, shape: Shape, material: usize) {
        self.desc.objects.push(Object { shape, material });
    }
    pub fn boxed(&mut self, min: DVec3, max: DVec3, material: usize) {
        self.add(Shape::Box { min, max }, material);
    }
    pub fn cylinder(&mut self, base: DVec3, top: DVec3, r: f64, material: usize) {
        self.add(
            Shape::Cone {
                base,
                top,
                radius_base: r,
                radius_top: r,
            },
            material,
        );
    }
    pub fn cone(&mut self, base: DVec3, top: DVec3, r: f64, material: usize) {
        self.add(
            Shape::Cone {
                base,
                top,
                radius_base: r,
                radius_top: 0.0,
            },
            material,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_are_deterministic_and_round_trip() {
        for name in NAMES {
            let a = builtin(name).unwrap();
            let b = builtin(name).unwrap();
            assert_eq!(a.toml, b.toml, "{name}");
            let again = Scene::parse_toml(&a.toml, "again").unwrap();
            assert_eq!(again.desc(), a.scene.desc(), "{name}");
            let t = a.tracks.get("main").unwrap();
            assert!(
                (40.0..=90.0).contains(&t.length()),
                "{name}: {}",
                t.length()
            );
            let from_file = crate::parse::tracks_from_scene_toml(&a.toml, "x")
                .unwrap()
                .unwrap();
            assert_eq!(from_file, a.tracks);
        }
        assert!(builtin("moon").is_none());
        assert!(builtin("town-0").is_none());
        assert!(builtin("town-101").is_none());
        let town = builtin("town-1").unwrap();
        let again = Scene::parse_toml(&town.toml, "again").unwrap();
        assert_eq!(again.desc(), town.scene.desc());
        let from_file = crate::parse::tracks_from_scene_toml(&town.toml, "x")
            .unwrap()
            .unwrap();
        assert_eq!(from_file, town.tracks);
    }

    #[test]
    fn track_viewpoints_are_not_inside_geometry() {
        for name in NAMES {
            let b = builtin(name).unwrap();
            for vp in b.tracks.get("main").unwrap().viewpoints() {
                // Looking straight up or down, a viewpoint inside a solid would hit its inside
                // within a few metres both ways; in the open one direction is free or far.
                let up = b.scene.first_hit(vp.position, DVec3::Y, f64::INFINITY);
                let down = b.scene.first_hit(vp.position, DVec3::NEG_Y, f64::INFINITY);
                assert!(
                    down.is_some_and(|d| d > 0.5 && d < 10.0),
                    "{name} {vp:?} {down:?}"
                );
                assert!(up.is_none_or(|u| u > 2.0), "{name} {vp:?} {up:?}");
            }
        }
    }

    #[test]
    fn the_castle_streets_form_a_network_along_open_streets() {
        let b = builtin("castle").unwrap();
        let main = b.tracks.get("main").unwrap().clone();
        let net = tracks::network::Network::new(b.tracks.tracks.clone()).unwrap();
        assert_eq!(net.tracks.len(), 5);
        assert!(net.junctions.len() >= 3, "{}", net.junctions.len());
        // A crossing of two straight tracks: four branches on two tracks.
        assert!(net.junctions.iter().any(|j| {
            let mut t: Vec<usize> = j.branches.iter().map(|b| b.track).collect();
            t.dedup();
            j.branches.len() == 4
                && t.len() == 2
                && t.iter().all(|&k| net.tracks[k].points.len() <= 3)
        }));
        // `main` is sampled as alone (up to rounding: a junction is the other track's point).
        let alone = main.viewpoints();
        let m = net.track_index("main").unwrap();
        assert_eq!(net.stops[m].len(), alone.len());
        for (stop, vp) in net.stops[m].iter().zip(&alone) {
            assert!(net.viewpoints[stop.viewpoint].distance(vp.position) < 1e-9);
            assert!((stop.s - vp.s).abs() < 1e-9);
        }
        // Every segment runs along an open street at eye height, and every viewpoint is
        // outside the buildings.
        for e in 0..net.segments.len() {
            let p = net.segment_path(e);
            for w in p.windows(2) {
                let d = w[1] - w[0];
                let hit = b.scene.first_hit(w[0], d.normalize(), d.length());
                assert!(hit.is_none(), "segment {e} {:?}: {hit:?}", net.segments[e]);
            }
        }
        for v in &net.viewpoints {
            let down = b.scene.first_hit(*v, DVec3::NEG_Y, f64::INFINITY);
            assert!(down.is_some_and(|d| d > 0.5 && d < 10.0), "{v} {down:?}");
        }
    }
}
