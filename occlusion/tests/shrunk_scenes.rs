//! The shrunk variant on the built-in `castle` and `nature` and on `scenes/cloister.toml`,
//! whole default tracks at a small resolution, layers as the pipeline makes them: no false
//! culls against the oracle (offset positions, twice the base sampling), and, where solids
//! do the hiding, closer to what the oracle sees than the conservative variant. (In
//! `nature` the terrain, a mesh without volume, does most of it: the shrunk variant cannot
//! use it and keeps a little more there.)

mod common;

use common::{builtin, prepare, run};
use occlusion::Variant;

fn check(name: &str, scene: &prerender::scene::Scene, positions: &[glam::DVec3], solid: bool) {
    let p = prepare(scene, positions, 48, 8, None, 8);
    let (shrunk, _, stats) = run(&p, scene, Variant::Shrunk);
    let (cons, _, _) = run(&p, scene, Variant::Conservative);
    eprintln!(
        "{name}: shrunk {:.2}×, conservative {:.2}× kept ÷ seen; {stats:?}",
        shrunk.later_ratio(),
        cons.later_ratio()
    );
    assert_eq!(shrunk.false_culls(), 0, "{name}: {:?}", shrunk.0);
    assert!(stats.culled > 0, "{name}: nothing culled");
    assert!(
        !solid || shrunk.later_ratio() <= cons.later_ratio(),
        "{name}: shrunk keeps more than conservative: {:?} vs {:?}",
        shrunk.0,
        cons.0
    );
}

#[test]
fn castle_nature_and_cloister() {
    for (name, solid) in [("castle", true), ("nature", false)] {
        let (scene, positions) = builtin(name);
        check(name, &scene, &positions, solid);
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cloister.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let scene = prerender::scene::Scene::parse_toml(&text, path).unwrap();
    let tracks = prerender::parse::tracks_from_scene_toml(&text, path)
        .unwrap()
        .unwrap();
    let positions: Vec<_> = tracks
        .get("main")
        .unwrap()
        .viewpoints()
        .iter()
        .map(|v| v.position)
        .collect();
    check("cloister", &scene, &positions, true);
}
