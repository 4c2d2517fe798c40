//! The demo report in a real browser: builds a small fixture demo directory (tiny generated
//! images and stage reports with the documented field names), runs
//! `railview demo --report-only` on it, and loads `report/index.html` in headless Chromium with
//! a check script that records, after the page's load event, every image's `naturalWidth` and
//! every table id into the DOM that `--dump-dom` prints.
//!
//! Needs `/usr/bin/chromium` (the test script installs it). Built with
//! `RAILVIEW_SKIP_BROWSER=1`, these tests show as ignored; without Chromium and without that
//! variable, they fail rather than passing silently.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::scratch_dir;
use image::{Rgb, RgbImage, Rgba, RgbaImage};
use serde_json::{json, Value};

const FACE: u32 = 8;
const SAMPLES: usize = 3;

fn tmp_dir(name: &str) -> PathBuf {
    scratch_dir("report", name)
}

fn write_json(path: &Path, v: &Value) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, serde_json::to_vec_pretty(v).unwrap()).unwrap();
}

fn plot(path: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    RgbImage::from_fn(w, h, |x, y| Rgb([(x * 7) as u8, (y * 5) as u8, 128]))
        .save(path)
        .unwrap();
}

/// A plot as the stages write it: PNG and, beside it, SVG (which the HTML page shows).
fn plot_both(png: &Path, w: u32, h: u32) {
    plot(png, w, h);
    std::fs::write(
        png.with_extension("svg"),
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\">\
             <rect width=\"{w}\" height=\"{h}\" fill=\"#8ab\"/></svg>"
        ),
    )
    .unwrap();
}

/// A demo directory as the stages would leave it, at 8² faces and 3 samples.
fn fixture(root: &Path) {
    let work = root.join("work/prerender");
    let slabs = [(0.0, Some(10.0)), (10.0, Some(60.0)), (60.0, None)];
    write_json(
        &work.join("prerender.json"),
        &json!({"scene": "castle", "renderer": "builtin", "track": "main", "samples": SAMPLES,
                "face_size": FACE, "lowres_face_size": 4, "seconds": 1.5,
                "rays_per_second": 123456.0, "viewpoints": [], "slabs": [], "extra": null}),
    );
    for i in 0..SAMPLES {
        let dir = work.join(format!("samples/{i:04}"));
        std::fs::create_dir_all(&dir).unwrap();
        RgbImage::from_fn(FACE, 6 * FACE, |x, y| {
            Rgb([(y / FACE * 40) as u8, (x * 20) as u8, i as u8 * 60])
        })
        .save(dir.join("color.png"))
        .unwrap();
        write_json(
            &dir.join("sample.json"),
            &json!({"index": i, "s": i as f64 * 2.5, "position": [i as f64 * 2.5, 1.7, 0.0],
                    "face_size": FACE, "lowres_face_size": 4, "seconds": 0.5, "primary_rays": 384}),
        );
        for (k, _) in slabs.iter().enumerate() {
            let sd = dir.join(format!("slab_{k}"));
            std::fs::create_dir_all(&sd).unwrap();
            RgbaImage::from_fn(FACE, 6 * FACE, |x, _| {
                Rgba([
                    200,
                    100,
                    k as u8 * 80,
                    if (x + k as u32).is_multiple_of(3) {
                        0
                    } else {
                        255
                    },
                ])
            })
            .save(sd.join("color.png"))
            .unwrap();
        }
        let ranges: Vec<Value> = slabs
            .iter()
            .map(|(n, f)| json!({"near": n, "far": f}))
            .collect();
        write_json(
            &dir.join("layers.json"),
            &json!({"slabs": ranges, "seconds": 0.2}),
        );
    }
    let slab_rows: Vec<Value> = slabs
        .iter()
        .enumerate()
        .map(|(k, (n, f))| {
            json!({"near": n, "far": f, "tiles_before": 18, "tiles_after": 18 - 4 * k,
                   "opaque_pixels": 1000 - 200 * k, "pixels": 1152,
                   "texture_bytes": 4000 - 800 * k, "mesh_bytes": 900})
        })
        .collect();
    write_json(
        &work.join("slabs.json"),
        &json!({"slabs": slab_rows, "tile_size": 4,
                "criterion": {"max_spacing_m": 2.5, "parallax_px": [3.1, 0.8],
                              "summary": "3 slab(s) from 2 candidate valley(s)"}}),
    );
    plot_both(&work.join("histogram.png"), 60, 30);
    let run = |alpha: f64, variant: &str, oracle: bool| {
        let rows: Vec<Value> = (0..3)
            .map(|k| {
                let mut r = json!({"slab": k, "tiles_before": 54, "tiles_after": 54 - 10 * k,
                                   "bytes_before": 54 * 64, "bytes_after": (54 - 10 * k) * 64});
                if oracle {
                    r["false_culls"] = json!(0);
                    r["false_cull_pixels"] = json!(0);
                    r["kept_never_visible"] = json!(k);
                    r["visible_tiles"] = json!(40);
                }
                r
            })
            .collect();
        json!({"alpha": alpha, "variant": variant, "slabs": rows, "seconds": 0.01})
    };
    write_json(
        &work.join("cull.json"),
        &json!({"viewpoints": SAMPLES, "face_size": FACE, "tile_size": 4,
                "slab_ranges": [], "load_seconds": 0.1,
                "oracle": {"per_segment": 4, "face_size": 8, "source": "geometry", "seconds": 0.3},
                "runs": [run(1.0, "conservative", true), run(0.9, "conservative", true),
                         run(1.0, "paper", true)]}),
    );
    plot(&work.join("cull/conservative-a1.png"), 48, 8);
    write_json(
        &root.join("work/build.json"),
        &json!({"scene": "castle", "track": "main", "face_size": FACE, "tile_size": 4,
                "samples": SAMPLES, "culling": "conservative, α = 1",
                "sizes": {"panoramas_rgba": 4608, "slab_layers_rgba": 13824,
                          "nonempty_tiles_rgba": 9000, "kept_tiles_rgba": 7000,
                          "kept_tiles_ptm": 3000, "meshes": 2000, "backgrounds_ptm": 500,
                          "database_objects": 5600},
                "seconds": [["prerender", 1.5], ["encode", 0.5], ["total", 2.0]]}),
    );
    write_json(&root.join("db/manifest.json"), &json!({"scene": "castle"}));
    std::fs::create_dir_all(root.join("db/objects")).unwrap();
    std::fs::write(root.join("db/objects/ab12"), vec![7u8; 3000]).unwrap();
    write_json(
        &root.join("walk/walk.json"),
        &json!({"scene": "castle", "track": "main", "length_m": 5.0, "speed_mps": 3.0,
                "latency_s": 0.05, "runs": [
                    {"strategy": "naive", "bandwidth_bps": 2000000, "time_to_first_frame_s": 0.8,
                     "mean_needed_fraction": 0.5, "mean_quality": 0.4, "bytes": 90000, "bytes_per_m": 18000.0},
                    {"strategy": "ach+prefetch", "bandwidth_bps": null, "time_to_first_frame_s": null,
                     "mean_needed_fraction": 0.95, "mean_quality": 0.9, "bytes": 9000, "bytes_per_m": 1800.0}]}),
    );
    plot_both(&root.join("walk/walk.png"), 80, 40);
    let stats = |mean: f64| {
        json!({"views": 2, "psnr_mean_db": mean, "psnr_worst5_db": mean - 1.0,
               "psnr_min_db": mean - 1.0, "ssim_mean": 0.9, "ssim_worst5": 0.85,
               "holes_mean": 0.001, "holes_worst5": 0.002, "holes_max": 0.002})
    };
    write_json(
        &root.join("eval/eval.json"),
        &json!({"db": "db", "scene": "castle", "truth": "the built-in ray tracer, 3×3 rays per pixel",
                "width": 8, "height": 6, "fov_deg": 90.0, "face_size": 8, "resolution_ratio": 1.0,
                "views": {"per_segment": 1, "directions": 2, "pitches_deg": [0.0], "max_segments": null},
                "adapter": "llvmpipe",
                "summary": [{"config": "full", "at_samples": stats(40.0), "between": stats(31.0),
                             "frame_ms": 4.0, "db_bytes": 3000}],
                "worst": [{"config": "full", "s": 1.25, "segment": 0, "yaw_deg": 90.0,
                           "yaw_from_track_deg": 90.0, "pitch_deg": 0.0, "at_reference": false,
                           "position": [1.25, 1.7, 0.0], "psnr_db": 30.0, "ssim": 0.85,
                           "hole_fraction": 0.002, "frame_ms": 4.0, "db_bytes": 3000}],
                "rows": []}),
    );
    plot(&root.join("eval/worst-1.png"), 30, 6);
    plot(&root.join("eval/worst-at-sample.png"), 30, 6);
    for stem in ["psnr_along_track", "psnr_vs_frame_ms", "psnr_vs_bytes"] {
        plot_both(&root.join(format!("eval/{stem}.png")), 50, 40);
    }
    let knobs = json!({"every": 1, "face_size": 64, "supersample": 1, "slabs": "auto",
                       "tile_size": 32, "mesh_error_px": 0.5, "cull_variant": "conservative",
                       "alpha": 1.0, "drop_levels": 0});
    let record = |label: &str, knobs: Value, bytes: u64| {
        json!({"label": label, "knobs": knobs, "samples": 3, "spacing_m": 2.5, "slab_count": 3,
               "resolution_ratio": 1.0,
               "error": {"views": 4, "psnr_mean_db": 30.0, "psnr_worst5_db": 27.5,
                         "psnr_min_db": 27.0, "ssim_mean": 0.9, "ssim_worst5": 0.85,
                         "holes_mean": 0.001, "holes_worst5": 0.002, "psnr_at_samples_db": 40.0},
               "costs": {"prerender_cpu_s": 1.0, "build_cpu_s": 2.0, "db_bytes": bytes,
                         "walk_bytes": bytes / 2, "frame_ms": 3.0},
               "dir": "nodes/db-x"})
    };
    let mut dropped = knobs.clone();
    dropped["drop_levels"] = json!(1);
    write_json(
        &root.join("tune/sweep.json"),
        &json!({"scene": "castle", "track": "main", "base": knobs,
                "views": "4 views between the samples.",
                "records": [record("base", knobs.clone(), 4000),
                            record("finest texture level left out", dropped, 3000)],
                "fronts": [["db-bytes", ["finest texture level left out"]]],
                "selections": [{"target_psnr_db": 27.0, "cost": "db-bytes", "chosen": 1,
                                "meets": [true, true], "front": [false, true]}]}),
    );
    for stem in [
        "pareto_prerender_cpu",
        "pareto_build_cpu",
        "pareto_db_bytes",
        "pareto_walk_bytes",
        "pareto_frame_ms",
    ] {
        plot_both(&root.join(format!("tune/{stem}.png")), 50, 40);
    }
    for i in 0..5 {
        plot(&root.join(format!("frames/frame_{i:04}.png")), 16, 9);
    }
    write_json(
        &root.join("demo.json"),
        &json!({"scene": "castle", "track": "main", "face_size": FACE, "stages": [
            {"name": "prerender", "command": "railview prerender --scene castle --track main --face-size 8 --out work",
             "status": "done", "seconds": 1.5},
            {"name": "view", "command": "railview view http://127.0.0.1:1", "status": "unavailable",
             "seconds": 0.0, "message": "this build of railview has no `view` command"}]}),
    );
}

fn report_only(root: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_railview"))
        .args(["demo", "--report-only", "--face-size", "8", "--out"])
        .arg(root)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "railview demo --report-only failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// The check results the injected script wrote into the page: (image srcs with their
/// naturalWidth, table ids, ids of "not available" notes' sections).
struct Checked {
    images: Vec<(String, u64)>,
    tables: Vec<String>,
    unavailable: usize,
}

const CHECK_SCRIPT: &str = r#"<script>
window.addEventListener('load', () => {
  const r = {
    images: [...document.images].map(i => [i.getAttribute('src'), i.complete ? i.naturalWidth : 0]),
    tables: [...document.querySelectorAll('table[id]')].map(t => t.id),
    unavailable: document.querySelectorAll('p.unavailable').length,
  };
  const out = document.createElement('pre');
  out.id = 'railview-check';
  out.textContent = JSON.stringify(r);
  document.body.appendChild(out);
});
</script>"#;

/// Load the page in headless Chromium.
fn browse(report_dir: &Path) -> Checked {
    let chromium = ["/usr/bin/chromium", "/usr/bin/chromium-browser"]
        .into_iter()
        .map(Path::new)
        .find(|p| p.exists())
        .expect(
            "Chromium is not installed (apt-get install chromium, or set RAILVIEW_SKIP_BROWSER=1 to ignore these tests)",
        );
    let html = std::fs::read_to_string(report_dir.join("index.html")).unwrap();
    assert!(html.contains("</body>"));
    // A test-only copy of the page, beside it so relative image links resolve the same way.
    let check = report_dir.join("check.html");
    std::fs::write(
        &check,
        html.replace("</body>", &format!("{CHECK_SCRIPT}\n</body>")),
    )
    .unwrap();
    let profile = report_dir.join(".chromium-profile");
    let out = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--allow-file-access-from-files",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(format!(
            "file://{}",
            check.canonicalize().unwrap().display()
        ))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&out.stdout);
    let start = dom.find("<pre id=\"railview-check\">").unwrap_or_else(|| {
        panic!(
            "the check script did not run; chromium said:\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let body = &dom[start + "<pre id=\"railview-check\">".len()..];
    let text = &body[..body.find("</pre>").unwrap()];
    let text = text
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&amp;", "&");
    let v: Value = serde_json::from_str(&text).unwrap();
    std::fs::remove_file(&check).ok();
    std::fs::remove_dir_all(&profile).ok();
    Checked {
        images: v["images"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| (p[0].as_str().unwrap().to_string(), p[1].as_u64().unwrap()))
            .collect(),
        tables: v["tables"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_str().unwrap().to_string())
            .collect(),
        unavailable: v["unavailable"].as_u64().unwrap() as usize,
    }
}

#[test]
#[cfg_attr(
    railview_skip_browser,
    ignore = "browser tests switched off by RAILVIEW_SKIP_BROWSER=1"
)]
fn full_report_loads_every_image_and_table_in_chromium() {
    let root = tmp_dir("full");
    fixture(&root);
    let stdout = report_only(&root);
    assert!(stdout.contains("report:"), "{stdout}");
    let report = root.join("report");
    let md = std::fs::read_to_string(report.join("index.md")).unwrap();
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    for attr in ["src=\"http", "href=\"http", "src=\"//", "href=\"//", "url("] {
        assert!(
            !html.contains(attr),
            "the page loads nothing from outside ({attr})"
        );
    }
    for (needle, why) in [
        (
            "| 1.00 | Tiles | 54 | 54 | 0.0% | 54 | 44 | 18.5% |",
            "paper-style tiles row",
        ),
        (
            "Reproduce: `railview cull",
            "culling numbers carry their command",
        ),
        (
            "Reproduce: `railview walk",
            "walk numbers carry their command",
        ),
        (
            "| PTM compressed (kept tiles) | 0.003 | 65.1% |",
            "database size row",
        ),
        (
            "(conservative, α = 1), then as stored",
            "sizes explained in one sentence",
        ),
        ("![viewpoint 1 at s = 2.50 m", "a viewpoint image"),
        ("(histogram.png)", "the depth histogram"),
        (
            "| full | 2 | 31.00 | 30.00 | 30.00 | 0.9000 | 0.100 | 40.00 | 4.00 | 3000 |",
            "eval: mean, worst 5 %, worst, floor",
        ),
        ("(eval-worst-1.png)", "the worst view beside its truth"),
        (
            "| finest texture level left out | 3 (2.50 m) | 3 | 30.00 | 27.50 |",
            "the sweep's table",
        ),
        (
            "cheapest by db-bytes: **finest texture level left out**",
            "the choice for the target",
        ),
    ] {
        assert!(
            md.contains(needle),
            "index.md lacks {why} ({needle}):\n{md}"
        );
    }
    let checked = browse(&report);
    let bad: Vec<&(String, u64)> = checked.images.iter().filter(|(_, w)| *w == 0).collect();
    assert!(bad.is_empty(), "images that did not load: {bad:?}");
    // 3 viewpoints, histogram, full view + 3 slab strips + 3 slab faces, a culling atlas,
    // walk plot, 2 worst views and 3 eval plots, 5 Pareto plots, 3 flythrough frames.
    assert_eq!(checked.images.len(), 26, "{:?}", checked.images);
    // Plots are SVG in the page.
    let svgs = checked
        .images
        .iter()
        .filter(|(s, _)| s.ends_with(".svg"))
        .count();
    assert_eq!(svgs, 10, "{:?}", checked.images);
    for id in [
        "stages",
        "prerender",
        "slab-table",
        "slab-criterion",
        "culling-conservative",
        "culling-paper",
        "false-culls",
        "db-sizes",
        "build-seconds",
        "walk",
        "eval",
        "eval-worst",
        "tune",
    ] {
        assert!(
            checked.tables.contains(&id.to_string()),
            "table #{id} missing: {:?}",
            checked.tables
        );
    }
    // The fixture has no network database: that one section says so (the real one is
    // checked by `demo_end_to_end_at_a_tiny_size_reuses_and_recovers`).
    assert_eq!(
        checked.unavailable, 1,
        "every section of the full fixture but the network is available"
    );
    assert!(md.contains("## The streets: a network of tracks"), "{md}");
    std::fs::remove_dir_all(&root).ok();
}

#[test]
#[cfg_attr(
    railview_skip_browser,
    ignore = "browser tests switched off by RAILVIEW_SKIP_BROWSER=1"
)]
fn empty_demo_directory_gives_a_report_that_says_what_is_missing() {
    let root = tmp_dir("empty");
    report_only(&root);
    let report = root.join("report");
    let md = std::fs::read_to_string(report.join("index.md")).unwrap();
    assert!(
        md.contains("> **Not available:** no `prerender.json` was found"),
        "{md}"
    );
    assert!(
        md.contains("> **Not available:** no `walk/walk.json` was found"),
        "{md}"
    );
    let checked = browse(&report);
    assert!(checked.images.is_empty());
    assert_eq!(checked.tables, vec!["stages".to_string()]);
    assert!(checked.unavailable >= 7, "{}", checked.unavailable);
    std::fs::remove_dir_all(&root).ok();
}

#[test]
#[cfg_attr(
    railview_skip_browser,
    ignore = "browser tests switched off by RAILVIEW_SKIP_BROWSER=1"
)]
fn a_broken_stage_image_is_left_out_not_linked() {
    let root = tmp_dir("broken");
    fixture(&root);
    std::fs::write(root.join("walk/walk.png"), b"\x89PNG\r\n\x1a\ntruncated").unwrap();
    // Without the build report, sizes are estimated from the stage reports.
    std::fs::remove_file(root.join("work/build.json")).unwrap();
    report_only(&root);
    let report = root.join("report");
    let md = std::fs::read_to_string(report.join("index.md")).unwrap();
    assert!(
        md.contains("| raw panoramas | 0.005 | 100.0% | 3 samples × 6 × 8² px |"),
        "{md}"
    );
    assert!(md.contains("| PTM compressed (database on disk) |"), "{md}");
    assert!(
        !md.contains("(walk.png)"),
        "a broken plot must not be linked"
    );
    assert!(
        md.contains("walk.png"),
        "the note names the broken file:\n{md}"
    );
    let checked = browse(&report);
    assert!(
        checked.images.iter().all(|(_, w)| *w > 0),
        "{:?}",
        checked.images
    );
    std::fs::remove_dir_all(&root).ok();
}

/// `railview demo` end to end at a tiny size: every stage this build has completes, a second
/// run reuses all of them, a run killed midway is recovered by the next, and the real report
/// loads in the browser.
#[test]
#[cfg_attr(
    railview_skip_browser,
    ignore = "browser tests switched off by RAILVIEW_SKIP_BROWSER=1"
)]
fn demo_end_to_end_at_a_tiny_size_reuses_and_recovers() {
    let root = tmp_dir("e2e");
    let out = root.join("demo");
    let demo = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_railview"));
        c.args([
            "demo",
            "--face-size",
            "16",
            "--walk-speed",
            "36",
            "--no-window",
            "--out",
        ])
        .arg(&out);
        c
    };
    // Killed midway (whatever it was doing), then run to the end.
    let mut child = demo()
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    child.kill().unwrap();
    child.wait().unwrap();
    let first = demo().output().unwrap();
    let stderr = String::from_utf8_lossy(&first.stderr).to_string();
    let stdout = String::from_utf8_lossy(&first.stdout).to_string();
    assert!(first.status.success(), "demo failed:\n{stdout}\n{stderr}");
    assert!(
        stdout.contains("report:") && stdout.contains("railview view"),
        "{stdout}"
    );

    let log: Value =
        serde_json::from_slice(&std::fs::read(out.join("demo.json")).unwrap()).unwrap();
    let stages = log["stages"].as_array().unwrap();
    for s in stages {
        let (name, status) = (s["name"].as_str().unwrap(), s["status"].as_str().unwrap());
        match status {
            "done" => {}
            // Only a command this build lacks, or a stage after one, may be missing.
            "unavailable" => {
                let why = s["message"].as_str().unwrap_or("");
                assert!(
                    why.contains("has no") || why.contains("needs"),
                    "{name}: {why}"
                );
            }
            other => panic!("stage {name} {other}: {s}"),
        }
    }
    for must in ["build", "cull", "eval", "tune", "network", "network-cull"] {
        let s = stages.iter().find(|s| s["name"] == must).unwrap();
        assert_eq!(s["status"], "done", "{must}: {s}");
    }

    // The second run reuses every completed stage.
    let second = demo().output().unwrap();
    assert!(second.status.success());
    let stderr = String::from_utf8_lossy(&second.stderr);
    for s in stages.iter().filter(|s| s["status"] == "done") {
        let name = s["name"].as_str().unwrap();
        assert!(
            stderr.contains(&format!("] {name}: reused")),
            "{name} was not reused:\n{stderr}"
        );
    }

    let checked = browse(&out.join("report"));
    assert!(
        checked.images.iter().all(|(_, w)| *w > 0),
        "{:?}",
        checked.images
    );
    for id in [
        "stages",
        "prerender",
        "slab-table",
        "culling-conservative",
        "network-junctions",
        "network-culling",
        "network-turns",
    ] {
        assert!(
            checked.tables.contains(&id.to_string()),
            "#{id}: {:?}",
            checked.tables
        );
    }
    std::fs::remove_dir_all(&root).ok();
}
