//! `railview prerender` end to end: files, report, resume, shards, bad input (exit codes and
//! messages). Small faces keep it fast.

mod common;

use std::path::{Path, PathBuf};

use common::{railview, scratch_path, stderr};

fn tmp(name: &str) -> PathBuf {
    scratch_path("cli-prerender", name)
}

fn report(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("prerender.json")).expect("prerender.json");
    serde_json::from_str(&text).expect("report is JSON")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const TRACK: &str =
    "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 3\n";

#[test]
fn castle_short_track_with_slabs_resume_and_report() {
    let work = tmp("castle");
    let track = write(&work, "short.toml", TRACK);
    let out = work.join("out");
    let args = [
        "prerender",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "16",
        "--lowres-face-size",
        "8",
        "--slabs",
        "0-10,10-inf",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = railview(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&out);
    assert_eq!(r["samples"], 3);
    assert_eq!(r["face_size"], 16);
    assert!(r["seconds"].as_f64().unwrap() > 0.0);
    assert!(r["rays_per_second"].as_f64().unwrap() > 0.0);
    assert_eq!(r["extra"]["complete_samples"], 3);
    assert_eq!(r["extra"]["samples_with_layers"], 3);
    for i in 0..3 {
        let s = out.join("samples").join(format!("{i:04}"));
        for f in [
            "color.png",
            "depth.exr",
            "lowres_depth.exr",
            "sample.json",
            "layers.json",
            "slab_0/color.png",
            "slab_1/depth.exr",
        ] {
            assert!(s.join(f).is_file(), "missing {}", s.join(f).display());
        }
    }
    assert!(out.join("prerender.md").is_file());
    assert!(std::fs::read_to_string(out.join("track.toml"))
        .unwrap()
        .contains("short"));
    // The run log holds the times the markers do not.
    let sample = std::fs::read_to_string(out.join("samples/0000/sample.json")).unwrap();
    assert!(!sample.contains("seconds"), "{sample}");
    assert_eq!(r["shards"].as_array().map(Vec::len), Some(1), "{r}");
    assert_eq!(r["shards"][0]["shard"], serde_json::Value::Null);
    assert_eq!(r["shards"][0]["samples"], serde_json::json!([0, 1, 2]));
    // Resume: everything is skipped, and the report still has the first run's times.
    let o = railview(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("0 rendered, 3 skipped"),
        "{}",
        stderr(&o)
    );
    assert_eq!(report(&out)["seconds"], r["seconds"]);
    assert_eq!(report(&out)["shards"], r["shards"]);
    let logs = std::fs::read_dir(out.join("runs")).unwrap().count();
    assert_eq!(logs, 2, "one run log per run");
    // A rerun without --slabs keeps the slab layers in the report.
    let without: Vec<&str> = args
        .iter()
        .copied()
        .filter(|a| *a != "--slabs" && *a != "0-10,10-inf")
        .collect();
    let o = railview(&without);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&out);
    assert_eq!(r["slabs"].as_array().map(Vec::len), Some(2), "{r}");
    assert_eq!(r["extra"]["samples_with_layers"], 3);
    std::fs::remove_dir_all(&work).ok();
}

#[test]
fn shards_fill_one_directory() {
    let work = tmp("shards");
    let track = write(&work, "short.toml", TRACK);
    let out = work.join("out");
    for shard in ["1/2", "0/2"] {
        let o = railview(&[
            "prerender",
            "--scene",
            "nature",
            "--track",
            track.to_str().unwrap(),
            "--face-size",
            "8",
            "--lowres-face-size",
            "4",
            "--no-shadows",
            "--shard",
            shard,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    // Shards leave the report to the merge.
    assert!(!out.join("prerender.json").exists());
    let merge = |extra: &[&str]| {
        let mut a = vec![
            "prerender",
            "--scene",
            "nature",
            "--track",
            track.to_str().unwrap(),
            "--face-size",
            "8",
            "--lowres-face-size",
            "4",
            "--out",
            out.to_str().unwrap(),
            "--merge",
        ];
        a.extend_from_slice(extra);
        railview(&a)
    };
    // A missing sample is named, with the shard that renders it.
    std::fs::remove_file(out.join("samples/0001/sample.json")).unwrap();
    let o = merge(&[]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("1 of 3 samples") && e.contains(": 1.") && e.contains("shard 1/2"),
        "{e}"
    );
    assert!(!out.join("prerender.json").exists());
    let o = merge(&["--shard", "1/2"]);
    assert!(!o.status.success(), "--merge and --shard conflict");
    // The shard again, then the merge lists both shards' samples.
    let o = railview(&[
        "prerender",
        "--scene",
        "nature",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "8",
        "--lowres-face-size",
        "4",
        "--no-shadows",
        "--shard",
        "1/2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = merge(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&out);
    assert_eq!(r["extra"]["complete_samples"], 3);
    assert_eq!(r["shard"], serde_json::Value::Null);
    let shards: Vec<_> = r["shards"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["shard"].clone(), s["samples"].clone()))
        .collect();
    assert_eq!(
        shards,
        vec![
            (serde_json::json!([0, 2]), serde_json::json!([0, 2])),
            (serde_json::json!([1, 2]), serde_json::json!([1])),
        ]
    );
    let summed: f64 = r["shards"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["render_seconds"].as_f64().unwrap())
        .sum();
    assert!(summed > 0.0);
    assert!(
        (r["seconds"].as_f64().unwrap() - summed).abs() < 1e-9,
        "{r}"
    );
    std::fs::remove_dir_all(&work).ok();
}

#[test]
fn hand_written_example_scene_renders() {
    let out = tmp("cloister");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cloister.toml");
    let o = railview(&[
        "prerender",
        "--scene",
        scene,
        "--face-size",
        "8",
        "--lowres-face-size",
        "4",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(report(&out)["samples"].as_u64().unwrap() > 5);
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    let work = tmp("bad");
    let out = work.join("out");
    let run = |scene: &str, track: &str, out: &str| {
        railview(&[
            "prerender",
            "--scene",
            scene,
            "--track",
            track,
            "--face-size",
            "8",
            "--out",
            out,
        ])
    };
    let outs = out.to_str().unwrap();
    // Unwritable output directory.
    let o = run("castle", "main", "/proc/railview-no-such-dir/out");
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/proc/railview-no-such-dir"),
        "{}",
        stderr(&o)
    );
    // Malformed scene TOML: file and line.
    let bad = write(
        &work,
        "bad.toml",
        "[[object]]\ntype = 'sphere'\ncenter = [0, 0\nradius = 1\n",
    );
    let o = run(bad.to_str().unwrap(), "main", outs);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("bad.toml:3") || e.contains("bad.toml:4"), "{e}");
    // Unknown primitive and a negative size.
    let bad = write(&work, "prim.toml", "[[object]]\ntype = 'torus'\n");
    let e = stderr(&run(bad.to_str().unwrap(), "main", outs));
    assert!(e.contains("prim.toml:1") && e.contains("torus"), "{e}");
    let bad = write(
        &work,
        "neg.toml",
        "[[object]]\ntype = 'sphere'\ncenter = [0, 0, 0]\nradius = -1\n",
    );
    let e = stderr(&run(bad.to_str().unwrap(), "main", outs));
    assert!(e.contains("radius"), "{e}");
    // Tracks: duplicate points, zero length, unknown name.
    let dup = write(
        &work,
        "dup.toml",
        "[[track]]\nname='t'\npoints=[[0,1,0],[0,1,0],[1,1,0]]\ncount=2\n",
    );
    let o = run("castle", dup.to_str().unwrap(), outs);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("points"), "{}", stderr(&o));
    let o = run("castle", "nope", outs);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("main"), "{}", stderr(&o));
    let o = run("no-such-scene", "main", outs);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("castle"), "{}", stderr(&o));
    // Bad options.
    let o = railview(&[
        "prerender",
        "--scene",
        "castle",
        "--shard",
        "2/2",
        "--out",
        outs,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("2/2"), "{}", stderr(&o));
    let o = railview(&[
        "prerender",
        "--scene",
        "castle",
        "--slabs",
        "5-1",
        "--out",
        outs,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("slab"), "{}", stderr(&o));
    // Nothing half-written looks complete.
    assert!(!out.join("samples").exists());
    std::fs::remove_dir_all(&work).ok();
}
