//! `railview cull --oracle` on a POV-Ray import: the oracle renders depth with POV-Ray at the
//! positions between the reference viewpoints (faces of 16 px keep it fast), and the
//! conservative variant at α = 1 and the rendered variant (POV-Ray's depth renders from balls
//! along the segment) have no false culls while α = 0.8 is judged by the same marks.

mod common;

use std::path::{Path, PathBuf};

use common::{railview, text};

fn repo(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

#[test]
fn oracle_renders_depth_with_povray() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("railview-cli-cull-pov-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    let d = dir.to_str().unwrap();
    let (scene, track) = (
        repo("scenes/pov/analytic.pov"),
        repo("scenes/pov/analytic.toml"),
    );
    let o = railview(&[
        "import-pov",
        &scene,
        "--track",
        &track,
        "--up",
        "y",
        "--face-size",
        "16",
        "--lowres-face-size",
        "8",
        "--out",
        d,
        "--slabs",
        "0-2.5,2.5-6,6-inf",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = railview(&["slabs", d, "--tile-size", "4"]);
    assert!(o.status.success(), "{}", text(&o));
    let o = railview(&[
        "cull",
        d,
        "--oracle",
        "--oracle-face-size",
        "16",
        "--oracle-per-segment",
        "2",
        "--variant",
        "conservative,rendered",
        "--alpha",
        "1.0,0.8",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let t = std::fs::read_to_string(dir.join("cull.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&t).unwrap();
    assert_eq!(r["oracle"]["source"], "depth-renders (POV-Ray)", "{t}");
    let runs = r["runs"].as_array().unwrap();
    for variant in ["conservative", "rendered"] {
        let one = runs
            .iter()
            .find(|x| x["alpha"] == 1.0 && x["variant"] == variant)
            .unwrap();
        let slabs = one["slabs"].as_array().unwrap();
        assert_eq!(slabs.len(), 3, "{t}");
        for s in slabs {
            assert_eq!(s["false_culls"], 0, "{variant}: {t}");
            // The oracle saw something of every slab from somewhere.
            assert!(s["visible_tiles"].as_u64().unwrap() > 0, "{t}");
            assert!(s["never_visible"].as_u64().is_some(), "{t}");
        }
    }
    // The rendered variant ran at α = 1 only, on POV-Ray's depth renders.
    let rendered: Vec<_> = runs.iter().filter(|x| x["variant"] == "rendered").collect();
    assert_eq!(rendered.len(), 1, "{t}");
    assert!(
        rendered[0]["rendered"]["renders"].as_u64().unwrap() > 0,
        "{t}"
    );
    // The scratch renders are gone.
    assert!(!dir.join("cull-oracle").exists());
    // An import has no solids for the shrunk variant: asked for by name, it is refused.
    let o = railview(&["cull", d, "--variant", "shrunk"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("needs the exact geometry"),
        "{}",
        text(&o)
    );
    std::fs::remove_dir_all(&dir).ok();
}
