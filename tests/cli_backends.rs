//! The GPU commands on both of wgpu's backends on Mesa's CPU drivers (`WGPU_BACKEND=vulkan`:
//! lavapipe; `WGPU_BACKEND=gl`: llvmpipe through EGL), and on a machine without any: `render`,
//! `eval` and `flythrough` give the same results on both (images within the tolerance of
//! `viewer/tests/backends.rs`: no channel more than 4 of 255 apart, mean at most 0.05), and
//! without an adapter every GPU command exits with one paragraph saying what to install, no
//! panic and no backtrace, and writes nothing.
//!
//! CI installs both drivers; a missing one fails these tests with the message of what to
//! install. `RAILVIEW_SKIP_GPU_TESTS=1` marks the GPU parts as ignored.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::{scratch_dir, small_castle, stderr};

/// `railview args…` with `env` set, `RUST_BACKTRACE=1` (a panic would print a backtrace).
fn railview_with(env: &[(&str, &str)], args: &[&str]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_railview"));
    c.args(args).env("RUST_BACKTRACE", "1");
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("run railview")
}

fn on(backend: &str, args: &[&str]) -> Output {
    let o = railview_with(&[("WGPU_BACKEND", backend)], args);
    assert!(o.status.success(), "{backend}: {args:?}: {}", stderr(&o));
    o
}

fn rgba(path: &Path) -> image::RgbaImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgba8()
}

/// Both images the same size, no channel more than 4 apart, mean at most 0.05.
fn assert_close(what: &str, a: &Path, b: &Path) {
    let (a, b) = (rgba(a), rgba(b));
    assert_eq!(a.dimensions(), b.dimensions(), "{what}");
    let (mut max, mut sum) = (0u8, 0u64);
    for (x, y) in a.as_raw().iter().zip(b.as_raw()) {
        max = max.max(x.abs_diff(*y));
        sum += u64::from(x.abs_diff(*y));
    }
    let mean = sum as f64 / a.as_raw().len() as f64;
    eprintln!("{what}: max |diff| {max}, mean {mean:.4}");
    assert!(max <= 4 && mean <= 0.05, "{what}: max {max}, mean {mean}");
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn render_eval_and_flythrough_agree_on_vulkan_and_gl() {
    let d = scratch_dir("cli-backends", "agree");
    let db = small_castle(&d, 32);
    let db = db.to_str().unwrap();
    for (backend, name) in [("vulkan", "Vulkan backend"), ("gl", "GL backend")] {
        let out = d.join(backend);
        let p = |f: &str| out.join(f).to_str().unwrap().to_string();
        let o = on(
            backend,
            &[
                "render",
                db,
                "--at",
                "3",
                "--size",
                "160x120",
                "-o",
                &p("view.png"),
            ],
        );
        assert!(stderr(&o).contains(name), "{}", stderr(&o));
        on(
            backend,
            &[
                "eval",
                db,
                "--out",
                &p("eval"),
                "--segments",
                "1",
                "--size",
                "64x48",
            ],
        );
        let o = on(
            backend,
            &[
                "flythrough",
                db,
                "-o",
                &p("frames"),
                "--frames",
                "3",
                "--size",
                "96x64",
            ],
        );
        assert!(stderr(&o).contains(name), "{}", stderr(&o));
    }
    let (vk, gl) = (d.join("vulkan"), d.join("gl"));
    assert_close("render", &vk.join("view.png"), &gl.join("view.png"));
    for i in 0..3 {
        let f = format!("frames/frame_{i:04}.png");
        assert_close(&f, &vk.join(&f), &gl.join(&f));
    }
    // The same evaluation: rows in the same order, errors within a hair.
    let rows = |dir: &Path| -> Vec<serde_json::Value> {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("eval/eval.json")).unwrap()).unwrap();
        v["rows"].as_array().unwrap().clone()
    };
    let (a, b) = (rows(&vk), rows(&gl));
    assert_eq!(a.len(), b.len());
    assert!(!a.is_empty());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x["config"], y["config"]);
        assert_eq!(x["position"], y["position"]);
        let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
        assert!(
            (f(x, "psnr_db") - f(y, "psnr_db")).abs() < 0.1,
            "{x}\nagainst\n{y}"
        );
        assert!((f(x, "hole_fraction") - f(y, "hole_fraction")).abs() < 1e-3);
    }
    std::fs::remove_dir_all(&d).ok();
}

/// No Vulkan driver (the loader finds none) and the search limited to Vulkan: what a machine
/// without any GPU driver sees.
const NO_ADAPTER: [(&str, &str); 3] = [
    ("VK_ICD_FILENAMES", "/nonexistent"),
    ("VK_DRIVER_FILES", "/nonexistent"),
    ("WGPU_BACKEND", "vulkan"),
];

#[test]
fn without_an_adapter_every_gpu_command_says_what_to_install() {
    let d = scratch_dir("cli-backends", "no-adapter");
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    let commands: Vec<Vec<String>> = [
        vec![
            "render",
            "synth:street",
            "--size",
            "32x32",
            "-o",
            &p("view.png"),
        ],
        vec![
            "eval",
            "synth:street",
            "--out",
            &p("eval"),
            "--segments",
            "1",
        ],
        vec![
            "flythrough",
            "synth:street",
            "-o",
            &p("frames"),
            "--frames",
            "2",
        ],
        vec![
            "bench-viewer",
            "--face",
            "16",
            "--frames",
            "1",
            "--size",
            "32x32",
        ],
    ]
    .into_iter()
    .map(|v| v.into_iter().map(String::from).collect())
    .collect();
    for args in &commands {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = railview_with(&NO_ADAPTER, &args);
        let err = stderr(&o);
        assert!(!o.status.success(), "{args:?} succeeded");
        // 101 is a panic's exit code.
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            !err.contains("panicked") && !err.contains("backtrace"),
            "{err}"
        );
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "one paragraph: {err}");
        assert!(
            lines[0].starts_with("error: no GPU adapter found (Vulkan; WGPU_BACKEND=vulkan"),
            "{err}"
        );
        assert!(
            err.contains("apt-get install mesa-vulkan-drivers libvulkan1"),
            "{err}"
        );
    }
    assert!(!d.join("view.png").exists());
    assert!(!d.join("eval/eval.json").exists());
    assert!(!d.join("frames/flythrough.json").exists());
    std::fs::remove_dir_all(&d).ok();
}

/// The demo on a machine without any GPU driver: the CPU stages (build, cull, walk) complete,
/// the GPU stages (eval, tune, flythrough) are recorded as failed with the message of what to
/// install, the report says so, and the demo exits non-zero saying which stages could not
/// run and why. With a driver back, the next run reuses the CPU stages and completes.
#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn the_demo_without_an_adapter_runs_its_cpu_stages_and_says_what_is_missing() {
    let d = scratch_dir("cli-backends", "demo");
    let out = d.join("demo");
    let args = [
        "demo",
        "--face-size",
        "16",
        "--walk-speed",
        "36",
        "--no-window",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = railview_with(&NO_ADAPTER, &args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("stages `eval`, `tune`, `flythrough` could not run: no GPU adapter found"),
        "{err}"
    );
    let log: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("demo.json")).unwrap()).unwrap();
    let status = |name: &str| -> (String, String) {
        let s = log["stages"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == name)
            .unwrap_or_else(|| panic!("no stage {name} in {log}"));
        (
            s["status"].as_str().unwrap().to_string(),
            s["message"].as_str().unwrap_or("").to_string(),
        )
    };
    for cpu in ["build", "cull", "walk"] {
        assert_eq!(status(cpu).0, "done", "{cpu}: {log}");
    }
    for gpu in ["eval", "tune", "flythrough"] {
        let (st, message) = status(gpu);
        assert_eq!(st, "failed", "{gpu}");
        assert!(
            message.contains("apt-get install mesa-vulkan-drivers"),
            "{message}"
        );
    }
    let report = std::fs::read_to_string(out.join("report/index.md")).unwrap();
    assert!(
        report.contains("failed: no GPU adapter found"),
        "the report says why the GPU sections are missing"
    );
    assert!(out.join("db/manifest.json").exists());
    assert!(out.join("walk/walk.json").exists());
    // The sweep stopped before building anything it could not evaluate.
    assert!(!out.join("tune/nodes").exists());

    // A driver there: the CPU stages are reused, the GPU ones run.
    let o = railview_with(&[], &args);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    for cpu in ["build", "cull", "walk"] {
        assert!(err.contains(&format!("] {cpu}: reused")), "{cpu}: {err}");
    }
    for gpu in ["eval", "tune", "flythrough"] {
        assert!(err.contains(&format!("] {gpu}: done")), "{gpu}: {err}");
    }
    std::fs::remove_dir_all(&d).ok();
}
