//! `railview tune` and `railview build --target-psnr` end to end at a tiny size: a sweep of
//! castle databases along a 6 m track at faces of 32 px. A rerun reuses every stage and
//! writes the same report; a sweep made afresh elsewhere measures the same errors and bytes
//! (only CPU and frame times differ).

mod common;

use std::path::Path;

use common::{railview, scratch_dir, text};
use serde_json::Value;

fn json(path: &Path) -> Value {
    serde_json::from_slice(
        &std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .unwrap()
}

/// Arguments of the tiny sweep into `out`: the base, every 2nd viewpoint, no culling, the
/// finest texture level left out, combined for one target.
fn sweep_args(track: &Path, out: &Path) -> Vec<String> {
    [
        "tune",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--face-size",
        "32",
        "--every",
        "2",
        "--face-sizes",
        "",
        "--supersamples",
        "",
        "--slab-counts",
        "",
        "--tile-sizes",
        "",
        "--mesh-errors",
        "",
        "--culls",
        "none",
        "--drop-levels",
        "1",
        "--per-segment",
        "1",
        "--directions",
        "2",
        "--truth-supersample",
        "1",
        "--zstd-level",
        "1",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--walk-speed",
        "6",
        "--target-psnr",
        "15",
        "--combine",
    ]
    .map(String::from)
    .to_vec()
}

fn run(args: &[String]) {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = railview(&a);
    assert!(o.status.success(), "{}", text(&o));
}

/// The report without what is measured by a clock.
fn untimed(mut v: Value) -> Value {
    for r in v["records"].as_array_mut().unwrap() {
        let c = r["costs"].as_object_mut().unwrap();
        for k in ["prerender_cpu_s", "build_cpu_s", "frame_ms"] {
            c.remove(k);
        }
    }
    v["fronts"]
        .as_array_mut()
        .unwrap()
        .retain(|f| f[0] == "db-bytes" || f[0] == "walk-bytes");
    v
}

#[test]
fn sweep_reuses_its_stages_and_is_deterministic_apart_from_timings() {
    let d = scratch_dir("cli-tune", "sweep");
    let track = d.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 3\n",
    )
    .unwrap();
    let (a, b) = (d.join("a"), d.join("b"));
    run(&sweep_args(&track, &a));
    let report = json(&a.join("sweep.json"));
    let records = report["records"].as_array().unwrap();
    let labels: Vec<&str> = records
        .iter()
        .map(|r| r["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        &labels[..4],
        [
            "base",
            "every 2nd reference viewpoint",
            "no culling",
            "finest texture level left out"
        ]
    );
    for r in records {
        assert!(r["error"]["psnr_worst5_db"].as_f64().unwrap() > 10.0, "{r}");
        assert!(r["costs"]["db_bytes"].as_u64().unwrap() > 0);
        assert!(r["costs"]["walk_bytes"].as_u64().unwrap() > 0);
        assert!(Path::new(&a)
            .join(r["dir"].as_str().unwrap())
            .join("db/manifest.json")
            .is_file());
    }
    // Every second viewpoint: two instead of three; the finest level left out: fewer bytes.
    assert_eq!(
        (
            records[0]["samples"].as_u64(),
            records[1]["samples"].as_u64()
        ),
        (Some(3), Some(2))
    );
    let bytes = |i: usize| records[i]["costs"]["db_bytes"].as_u64().unwrap();
    assert!(bytes(3) < bytes(0), "{} vs {}", bytes(3), bytes(0));
    // A choice for the target, on the front of database bytes, and its reasons in the report.
    let chosen = report["selections"][0]["chosen"]
        .as_u64()
        .expect("a choice") as usize;
    assert_eq!(report["selections"][0]["front"][chosen], true);
    let md = std::fs::read_to_string(a.join("sweep.md")).unwrap();
    assert!(
        md.contains("Target 15.0 dB on the worst 5 % of views"),
        "{md}"
    );
    assert!(md.contains("| on the front of |"), "{md}");
    for f in [
        "sweep.csv",
        "pareto_db_bytes.svg",
        "pareto_db_bytes.png",
        "pareto_walk_bytes.svg",
    ] {
        assert!(a.join(f).is_file(), "{f} missing");
    }

    // Again: nothing is built or measured again, and the report is the same file.
    let first = std::fs::read(a.join("sweep.json")).unwrap();
    run(&sweep_args(&track, &a));
    assert_eq!(json(&a.join("sweep-run.json"))["stages_run"], 0);
    assert!(std::fs::read(a.join("sweep.json")).unwrap() == first);

    // Afresh elsewhere: the same errors, bytes and choices.
    run(&sweep_args(&track, &b));
    assert_eq!(
        untimed(json(&a.join("sweep.json"))),
        untimed(json(&b.join("sweep.json")))
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn build_for_a_target_takes_the_cheapest_configuration_that_reaches_it() {
    let d = scratch_dir("cli-tune", "target");
    let track = d.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 3\n",
    )
    .unwrap();
    let db = d.join("db");
    let build = |target: &str| {
        railview(&[
            "build",
            "--scene",
            "castle",
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
            "--per-segment",
            "1",
            "--directions",
            "2",
            "--target-psnr",
            target,
            "--out",
            db.to_str().unwrap(),
        ])
    };
    let o = build("20");
    assert!(o.status.success(), "{}", text(&o));
    let v = railview(&["verify", db.to_str().unwrap()]);
    assert!(v.status.success(), "{}", text(&v));
    let work = d.join("db.work");
    let report = json(&work.join("build.json"));
    let target = &report["target"];
    assert_eq!(target["target_psnr_db"], 20.0);
    let chosen = &target["chosen"];
    let worst5 = chosen["error"]["psnr_worst5_db"].as_f64().unwrap();
    assert!(worst5 >= 20.0, "{worst5}");
    // The cheapest of those that reach the target in the sweep it ran.
    let sweep = json(&work.join("tune/sweep.json"));
    let bytes = chosen["costs"]["db_bytes"].as_u64().unwrap();
    for r in sweep["records"].as_array().unwrap() {
        if r["error"]["psnr_worst5_db"].as_f64().unwrap() >= 20.0 {
            assert!(r["costs"]["db_bytes"].as_u64().unwrap() >= bytes, "{r}");
        }
    }
    // Its database is the one built: same manifest as the sweep's copy.
    let node = work.join("tune").join(chosen["dir"].as_str().unwrap());
    assert_eq!(
        std::fs::read(node.join("db/manifest.json")).unwrap(),
        std::fs::read(db.join("manifest.json")).unwrap()
    );
    let md = std::fs::read_to_string(work.join("build.md")).unwrap();
    assert!(md.contains("## Chosen for a PSNR target"), "{md}");
    assert!(md.contains("Against the base: db-bytes"), "{md}");
    // A target nothing reaches fails and says what the best was.
    let o = build("99");
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("No configuration reaches 99.0 dB"),
        "{}",
        text(&o)
    );
    std::fs::remove_dir_all(&d).ok();
}
