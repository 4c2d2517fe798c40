//! The whole pipeline as a function.

use codec::ptm;
use db::ach::AchParams;
use stages::build::{BuildParams, BuildScene};
use stages::encode::EncodeParams;
use stages::{CullChoice, Knobs};

/// The whole pipeline at a tiny size; the result verifies, and a rebuild writes nothing.
#[test]
fn builds_verifies_and_resumes() {
    let out = std::env::temp_dir().join(format!("railview-build-{}", std::process::id()));
    let work = out.with_extension("work");
    std::fs::remove_dir_all(&out).ok();
    std::fs::remove_dir_all(&work).ok();
    let params = BuildParams {
        work: Some(work.clone()),
        knobs: Knobs {
            face_size: 32,
            cull: CullChoice::Auto,
            zstd_level: 3,
            ..Knobs::default()
        },
        encode: EncodeParams {
            ach: AchParams {
                samples: 2,
                camera_size: 16,
            },
            ..EncodeParams::default()
        },
        ..BuildParams::new(BuildScene::Tracer("castle".into()), "main", &out)
    };
    let run = || stages::build::run(&params, &stages::progress::silent());
    run().unwrap();
    let v = db::verify(&out).unwrap();
    assert!(v.is_intact());
    // The tiles' own objects stay in the work directory: nothing unreferenced.
    assert!(v.notes.is_empty(), "{:?}", v.notes);
    let db = db::Database::open(&out).unwrap();
    let m = db.manifest();
    // A built-in scene: the shrunk variant by default.
    assert_eq!(m.cull_variant.as_deref(), Some("shrunk"));
    let track = &m.tracks[0];
    assert!(track.viewpoints.len() > 1);
    assert_eq!(track.segments.len(), track.viewpoints.len() - 1);
    for seg in &track.segments {
        let sum: f64 = seg.ach.iter().map(|a| a.ach).sum();
        // Tables store ACH values as f32.
        assert!(seg.ach.is_empty() || (sum - 1.0).abs() < 1e-5, "{sum}");
    }
    let kept = track.viewpoints[0].tiles.iter().find(|t| t.kept).unwrap();
    let ptm_ref = kept.ptm.as_ref().unwrap();
    // The PTM's ranges in its viewpoint's pack, each checked, make up the PTM file.
    let bytes: Vec<u8> = (0..ptm_ref.levels.len())
        .flat_map(|g| db.read_level(ptm_ref, g).unwrap())
        .collect();
    let img = ptm::decode(&bytes, ptm::Limits::default()).unwrap();
    assert_eq!((img.width(), img.height()), (ptm_ref.width, ptm_ref.height));
    let first = std::fs::read(out.join("manifest.json")).unwrap();
    run().unwrap();
    let again = std::fs::read(out.join("manifest.json")).unwrap();
    assert!(again == first, "a resumed build changed manifest.json");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(work.join("build.json")).unwrap()).unwrap();
    assert_eq!(report["objects_written"], 0);
    // The baseline and the ratio, from the same prerender directory.
    let sizes = &report["sizes"];
    let base = sizes["baseline"].as_u64().unwrap();
    assert!(base > 0);
    assert_eq!(
        base,
        sizes["baseline_colour_png"].as_u64().unwrap()
            + sizes["baseline_depth_png16"].as_u64().unwrap()
    );
    let ratio = sizes["db_over_baseline"].as_f64().unwrap();
    let db = sizes["database_objects"].as_u64().unwrap();
    assert!((ratio - db as f64 / base as f64).abs() < 1e-9);
    assert!(std::fs::read_to_string(work.join("build.md"))
        .unwrap()
        .contains("× the baseline"));
    // The report reads back typed, with the knobs as the command line writes them.
    let typed: stages::encode::BuildReport =
        serde_json::from_slice(&std::fs::read(work.join("build.json")).unwrap()).unwrap();
    assert_eq!(typed.config.cull_variant, CullChoice::Auto);
    assert_eq!(report["config"]["cull_variant"], "auto");
    assert_eq!(report["config"]["slabs"], "auto");

    // Layers rendered again (here: slab 1 of sample 0 emptied) make that sample's tiles
    // stale: it is tiled and encoded again, and the objects the new manifest no longer
    // references are removed, with an unrelated one an earlier build left.
    let dir = prerender::store::PrerenderDir::new(work.join("prerender"));
    let tiles_before = std::fs::read(slabs::io::tiles_json(&dir, 0)).unwrap();
    let layer = prerender::store::read_rgba_png(&dir.slab_color_png(0, 1)).unwrap();
    let emptied = tracks::CubeMap::from_fn(layer.face_size(), |f, x, y| {
        let p = *layer.get(f, x, y);
        [p[0], p[1], p[2], 0]
    });
    prerender::store::write_atomic(
        &dir.slab_color_png(0, 1),
        &prerender::store::encode_rgba_png(&emptied),
    )
    .unwrap();
    let old = b"an object of an earlier build";
    let stray = out.join(tracks::manifest::object_rel_path(&blake3::hash(old).to_hex()).unwrap());
    std::fs::create_dir_all(stray.parent().unwrap()).unwrap();
    std::fs::write(&stray, old).unwrap();
    run().unwrap();
    let tiles_after = std::fs::read(slabs::io::tiles_json(&dir, 0)).unwrap();
    assert_ne!(tiles_after, tiles_before, "stale tiles were kept");
    let report: stages::encode::BuildReport =
        serde_json::from_slice(&std::fs::read(work.join("build.json")).unwrap()).unwrap();
    assert!(report.objects_written > 0);
    assert!(report.objects_pruned >= 1);
    assert!(!stray.exists());
    let v = db::verify(&out).unwrap();
    assert!(v.is_intact() && v.notes.is_empty(), "{v:?}");
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&work).unwrap();
}
