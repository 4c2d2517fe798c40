//! `railview eval` from the command line: bad input fails with a message naming the flag
//! before anything is rendered or written; a database is also evaluated as a client shows it
//! before its finer texture levels arrive, at what those levels cost; scene files and POV-Ray
//! imports get their ground truth from the renderer that made them.

mod common;

use std::path::Path;

use common::{railview, scratch_dir, scratch_path, small_castle, stderr, text};

fn repo(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

fn eval_json(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("eval.json")).unwrap()).unwrap()
}

/// Every view of `config` has a finite PSNR above `floor_db`; returns (between, at samples).
fn views_of(json: &serde_json::Value, config: &str, floor_db: f64) -> (usize, usize) {
    let rows: Vec<&serde_json::Value> = json["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["config"] == config)
        .collect();
    for r in &rows {
        let p = r["psnr_db"].as_f64().unwrap();
        assert!(p.is_finite() && p > floor_db, "{r}");
    }
    let at = rows.iter().filter(|r| r["at_reference"] == true).count();
    (rows.len() - at, at)
}

#[test]
fn eval_refuses_zero_segments_and_writes_nothing() {
    let out = scratch_path("cli-eval", "zero");
    let o = railview(&[
        "eval",
        "synth:street",
        "--out",
        out.to_str().unwrap(),
        "--segments",
        "0",
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("--segments = 0") && err.contains("1 to 100000"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn eval_of_a_database_adds_its_coarse_level_groups_at_their_bytes() {
    let d = scratch_dir("cli-eval", "groups");
    let db = small_castle(&d, 64);
    let out = d.join("eval");
    let o = railview(&[
        "eval",
        db.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--segments",
        "1",
        "--size",
        "96x64",
        "--per-segment",
        "1",
        "--directions",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("eval.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    let of = |config: &str| -> Vec<&serde_json::Value> {
        rows.iter().filter(|r| r["config"] == config).collect()
    };
    let (full, coarse) = (of("full"), of("db level groups=1"));
    assert!(!coarse.is_empty(), "no coarse rows in {rows:?}");
    assert_eq!(full.len(), coarse.len());
    let bytes = |r: &[&serde_json::Value]| r[0]["db_bytes"].as_u64().unwrap();
    assert!(
        bytes(&coarse) < bytes(&full),
        "coarse {} bytes, full {}",
        bytes(&coarse),
        bytes(&full)
    );
    // At the reference samples the coarse textures lose most: the full database is exact
    // there up to the resampling floor.
    let psnr = |r: &[&serde_json::Value]| -> f64 {
        r.iter()
            .filter(|r| r["at_reference"] == true)
            .map(|r| r["psnr_db"].as_f64().unwrap())
            .sum::<f64>()
    };
    assert!(
        psnr(&coarse) < psnr(&full),
        "{} against {}",
        psnr(&coarse),
        psnr(&full)
    );
    let md = std::fs::read_to_string(out.join("eval.md")).unwrap();
    assert!(md.contains("| db level groups=1 |"), "{md}");
}

#[test]
fn eval_on_a_scene_file_renders_its_truth_with_the_tracer() {
    let d = scratch_dir("cli-eval", "toml");
    let track = d.join("gate.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"gate\"\npoints = [[0, 1.7, 20], [0, 1.7, 12]]\ncount = 3\n",
    )
    .unwrap();
    let db = d.join("db");
    let scene = repo("scenes/cloister.toml");
    let o = railview(&[
        "build",
        "--scene",
        &scene,
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "32",
        "--zstd-level",
        "1",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--out",
        db.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out = d.join("eval");
    let args = [
        "eval",
        db.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--configs",
        "full",
        "--per-segment",
        "2",
        "--directions",
        "2",
        "--truth-supersample",
        "2",
    ];
    let o = railview(&args);
    assert!(o.status.success(), "{}", text(&o));
    let json = eval_json(&out);
    assert!(
        json["truth"].as_str().unwrap().contains("ray tracer"),
        "{}",
        json["truth"]
    );
    // Matched resolution: 32 px faces, 90° views 32 px wide.
    assert_eq!(json["width"].as_u64(), Some(32));
    assert!((json["resolution_ratio"].as_f64().unwrap() - 1.0).abs() < 1e-9);
    // Two segments × two positions × two directions between, three samples × two at them.
    assert_eq!(views_of(&json, "full", 10.0), (8, 6));
    for f in [
        "eval.csv",
        "eval.md",
        "worst-1.png",
        "psnr_along_track.svg",
        "psnr_vs_bytes.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // The truth pictures are kept: a second run renders none.
    let truths = std::fs::read_dir(out.join("truth")).unwrap().count();
    assert_eq!(truths, 14);
    let again = railview(&args);
    assert!(again.status.success(), "{}", text(&again));
    assert_eq!(
        std::fs::read_dir(out.join("truth")).unwrap().count(),
        truths
    );
}

#[test]
fn eval_on_a_pov_import_renders_its_truth_with_povray() {
    let d = scratch_dir("cli-eval", "pov");
    let db = d.join("db");
    let o = railview(&[
        "build",
        "--pov",
        &repo("scenes/pov/analytic.pov"),
        "--track",
        &repo("scenes/pov/analytic.toml"),
        "--up",
        "y",
        "--face-size",
        "16",
        "--lowres-face-size",
        "8",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--zstd-level",
        "1",
        "--out",
        db.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out = d.join("eval");
    let o = railview(&[
        "eval",
        db.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--configs",
        "full",
        "--per-segment",
        "1",
        "--directions",
        "2",
        "--truth-supersample",
        "2",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let json = eval_json(&out);
    assert!(
        json["truth"].as_str().unwrap().contains("POV-Ray"),
        "{}",
        json["truth"]
    );
    assert_eq!(views_of(&json, "full", 10.0), (2, 4));
    // Moved away from the build's work directory, the database needs it named.
    let moved = d.join("moved");
    std::fs::rename(&db, &moved).unwrap();
    let o = railview(&[
        "eval",
        moved.to_str().unwrap(),
        "--out",
        d.join("eval2").to_str().unwrap(),
        "--configs",
        "full",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--prerender"), "{}", stderr(&o));
}

/// At a reference sample, a view at matched resolution looking along a cube face shows the
/// panorama's own pixels: with panoramas anti-aliased like the truth, the reconstruction is
/// the truth to within rounding (the floor of the method, ≥ 60 dB).
#[test]
fn reconstruction_at_a_sample_is_the_antialiased_truth() {
    let d = scratch_dir("cli-eval", "floor");
    let track = d.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 2\n",
    )
    .unwrap();
    let db = d.join("db");
    let o = railview(&[
        "build",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "48",
        "--supersample",
        "2",
        "--zstd-level",
        "1",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--out",
        db.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out = d.join("eval");
    let o = railview(&[
        "eval",
        db.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--configs",
        "full",
        "--per-segment",
        "1",
        "--directions",
        "4",
        "--truth-supersample",
        "2",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let json = eval_json(&out);
    assert_eq!(json["width"].as_u64(), Some(48));
    let at: Vec<f64> = json["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["at_reference"] == true && r["config"] == "full")
        .map(|r| r["psnr_db"].as_f64().unwrap())
        .collect();
    // Two samples, each looking along the four horizontal faces.
    assert_eq!(at.len(), 8);
    for p in at {
        assert!(p >= 60.0, "{p} dB at a reference sample");
    }
}
