//! The rendered variant (depth renders from balls along each segment) on the built-in
//! `castle` and `nature` and on `scenes/cloister.toml` and `scenes/hall.toml` (round
//! columns, many slabs), whole default tracks at a small resolution, layers as the pipeline
//! makes them: no false culls against the oracle (offset positions), something culled, and
//! how close it keeps to what the oracle sees beside the conservative variant.

mod common;

use common::{builtin, prepare, run};
use occlusion::Variant;

fn check(name: &str, scene: &prerender::scene::Scene, positions: &[glam::DVec3]) {
    let p = prepare(scene, positions, 48, 8, None, 32);
    let (rendered, culls, _) = run(&p, scene, Variant::Rendered);
    let (cons, _, _) = run(&p, scene, Variant::Conservative);
    let culled: usize = culls
        .iter()
        .flat_map(|c| &c.slabs)
        .map(|s| s.culled.len())
        .sum();
    eprintln!(
        "{name}: rendered {:.2}×, conservative {:.2}× kept ÷ seen; {culled} culled",
        rendered.later_ratio(),
        cons.later_ratio()
    );
    assert_eq!(rendered.false_culls(), 0, "{name}: {:?}", rendered.0);
    assert!(culled > 0, "{name}: nothing culled");
}

fn toml_scene(file: &str) -> (prerender::scene::Scene, Vec<glam::DVec3>) {
    let path = format!("{}/../scenes/{file}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap();
    let scene = prerender::scene::Scene::parse_toml(&text, &path).unwrap();
    let tracks = prerender::parse::tracks_from_scene_toml(&text, &path)
        .unwrap()
        .unwrap();
    let track = tracks
        .get("main")
        .or_else(|| tracks.tracks.first())
        .unwrap();
    let positions = track.viewpoints().iter().map(|v| v.position).collect();
    (scene, positions)
}

#[test]
fn castle_and_nature() {
    for name in ["castle", "nature"] {
        let (scene, positions) = builtin(name);
        check(name, &scene, &positions);
    }
}

#[test]
fn cloister_and_hall() {
    for file in ["cloister.toml", "hall.toml"] {
        let (scene, positions) = toml_scene(file);
        check(file, &scene, &positions);
    }
}
