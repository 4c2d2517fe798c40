//! `railview cull --oracle` on a TOML scene: the three variants side by side in the paper's
//! table form with run time and kept ÷ seen, the shrunk one at α = 1 only and without false
//! culls; `--variant` named one by one, and a clear error for a name it does not know; a scene
//! edited since `prerender` refused by the shrunk variant.

mod common;

use common::{railview, scratch_dir, scratch_path, stderr, text};

#[test]
fn three_variants_side_by_side() {
    let dir = scratch_path("cli-cull", "cloister");
    let d = dir.to_str().unwrap();
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cloister.toml");
    let o = railview(&[
        "prerender",
        "--scene",
        scene,
        "--face-size",
        "32",
        "--lowres-face-size",
        "16",
        "--no-shadows",
        "--out",
        d,
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = railview(&["slabs", d, "--tile-size", "8"]);
    assert!(o.status.success(), "{}", text(&o));
    let o = railview(&[
        "cull",
        d,
        "--alpha",
        "1.0,0.8",
        "--oracle",
        "--oracle-per-segment",
        "8",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let t = std::fs::read_to_string(dir.join("cull.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&t).unwrap();
    let runs = r["runs"].as_array().unwrap();
    let of = |v: &str| -> Vec<&serde_json::Value> {
        runs.iter().filter(|x| x["variant"] == v).collect()
    };
    // shrunk at α = 1 only; the others at both α.
    assert_eq!(of("shrunk").len(), 1, "{t}");
    assert_eq!(of("shrunk")[0]["alpha"], 1.0, "{t}");
    assert_eq!((of("conservative").len(), of("paper").len()), (2, 2), "{t}");
    let shrunk = of("shrunk")[0];
    assert!(shrunk["seconds"].as_f64().unwrap() > 0.0, "{t}");
    assert!(shrunk["shrunk"]["culled"].as_u64().unwrap() > 0, "{t}");
    for s in shrunk["slabs"].as_array().unwrap() {
        assert_eq!(s["false_culls"], 0, "{t}");
    }
    let md = std::fs::read_to_string(dir.join("cull.md")).unwrap();
    for needle in [
        "## Variant `shrunk`",
        "## Variant `conservative`",
        "kept ÷ seen",
    ] {
        assert!(md.contains(needle), "{needle} not in\n{md}");
    }
    assert!(dir.join("cull/shrunk-a1.png").is_file());
    // One variant by name; an unknown one is refused, naming the flag.
    let o = railview(&["cull", d, "--variant", "shrunk", "--alpha", "0.9"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = std::fs::read_to_string(dir.join("cull.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&t).unwrap();
    assert_eq!(r["runs"].as_array().unwrap().len(), 1, "{t}");
    let o = railview(&["cull", d, "--variant", "shrunken"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--variant `shrunken`"),
        "{}",
        stderr(&o)
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The shrunk variant's proof is about the scene's solids: a scene file edited after
/// `prerender` is refused with a message that says so, and the image-based variants still run.
#[test]
fn shrunk_refuses_a_scene_edited_since_prerender() {
    let dir = scratch_dir("cli-cull", "edited");
    let scene = dir.join("cloister.toml");
    let original =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cloister.toml"))
            .unwrap();
    std::fs::write(&scene, &original).unwrap();
    let d = dir.join("pre");
    let d = d.to_str().unwrap();
    let o = railview(&[
        "prerender",
        "--scene",
        scene.to_str().unwrap(),
        "--face-size",
        "16",
        "--lowres-face-size",
        "8",
        "--no-shadows",
        "--out",
        d,
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = railview(&["slabs", d, "--tile-size", "8"]);
    assert!(o.status.success(), "{}", text(&o));
    // Unchanged: accepted.
    let o = railview(&["cull", d, "--variant", "shrunk"]);
    assert!(o.status.success(), "{}", text(&o));
    // The lawn raised by 30 cm: every ground pixel of the first viewpoint moves.
    let edited = original.replacen("point = [0, 0, 0]", "point = [0, 0.3, 0]", 1);
    assert_ne!(edited, original);
    std::fs::write(&scene, edited).unwrap();
    let o = railview(&["cull", d, "--variant", "shrunk"]);
    assert!(!o.status.success(), "{}", text(&o));
    let e = stderr(&o);
    assert!(
        e.contains("the scene changed since `railview prerender`") && e.contains("cloister.toml"),
        "{e}"
    );
    let o = railview(&["cull", d, "--variant", "conservative"]);
    assert!(o.status.success(), "{}", text(&o));
    std::fs::remove_dir_all(&dir).ok();
}
