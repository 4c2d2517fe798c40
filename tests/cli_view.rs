//! `railview view URL --frames N` under Xvfb: a small castle database built and served by the
//! binary, the window streams from the server until every visible tile is shown, then closes.
//! The window shows the headless render of the same camera on wgpu's default backend and on
//! GL (`WGPU_BACKEND=gl`, llvmpipe), and without any adapter it exits saying what to
//! install. Needs `xvfb-run` and Mesa's Vulkan and GL drivers; `RAILVIEW_SKIP_GPU_TESTS=1`
//! marks the GPU tests as ignored.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

use common::{railview, scratch_dir, small_castle, stderr};

fn tmp(name: &str) -> PathBuf {
    scratch_dir("cli-view", name)
}

/// Kills the server when the test ends, however it ends.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_negative_cache_budget_is_refused_before_any_window_opens() {
    let o = railview(&["view", "synth:street", "--memory-mib", "-1"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--memory-mib -1: must be between 1 and 1048576"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_target_rate_out_of_range_is_refused_before_any_window_opens() {
    for bad in ["0", "-5", "NaN"] {
        let o = railview(&["view", "synth:street", "--target-fps", bad]);
        assert!(!o.status.success());
        assert!(
            stderr(&o).contains(&format!("--target-fps {bad}: must be between 1 and 1000")),
            "{}",
            stderr(&o)
        );
    }
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn view_streams_from_a_served_database_and_closes_after_its_frames() {
    let bin = env!("CARGO_BIN_EXE_railview");
    let work = tmp("castle");
    let db = small_castle(&work, 16);

    let mut child = Command::new(bin)
        .arg("serve")
        .arg(&db)
        .args(["--addr", "127.0.0.1:0"])
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let server = Server(child);
    let mut line = String::new();
    BufReader::new(stderr).read_line(&mut line).unwrap();
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("http://"))
        .unwrap_or_else(|| panic!("no URL in `{line}`"))
        .to_string();

    let runtime = work.join("xdg");
    std::fs::create_dir_all(&runtime).unwrap();
    let o = Command::new("xvfb-run")
        .args([
            "-a",
            bin,
            "view",
            &url,
            "--frames",
            "80",
            "--memory-mib",
            "1",
        ])
        .env("XDG_RUNTIME_DIR", &runtime)
        .output()
        .expect("xvfb-run (apt-get install xvfb)");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("every visible tile shown after"), "{out}");
    // How smooth the walk was (the frame-to-frame intervals), and what the frame-time budget
    // drew at the end.
    assert!(out.contains("frame interval median"), "{out}");
    assert!(
        out.contains("drawing at the end:") && out.contains("(target 10 fps)"),
        "{out}"
    );
    let summary = out
        .lines()
        .find(|l| l.contains("frames in"))
        .unwrap_or_else(|| panic!("no summary in {out}"));
    // `… cache peak P of B bytes …`: the budget held.
    let words: Vec<&str> = summary.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "peak").unwrap();
    let peak: u64 = words[at + 1].parse().unwrap();
    let budget: u64 = words[at + 3].parse().unwrap();
    assert!(peak > 0 && peak <= budget, "{summary}");
    drop(server);
    let _ = std::fs::remove_dir_all(work);
}

/// What [`window_shot`] saw.
struct Shot {
    /// The command's standard output.
    out: String,
    window: image::RgbImage,
    /// The view's size in pixels, `WxH` (`…; view WxH px`: the view fills the window's right
    /// and bottom edges).
    size: String,
    /// The scratch directory (removed by the caller) and the database in it.
    work: PathBuf,
    db: PathBuf,
}

/// A window on a small castle database closed after `frames` frames at `--target-fps fps`,
/// with a screenshot, on `backend` (`WGPU_BACKEND`; `None`: wgpu's choice).
fn window_shot(name: &str, frames: u32, fps: u32, backend: Option<&str>) -> Shot {
    let bin = env!("CARGO_BIN_EXE_railview");
    let work = tmp(name);
    let db = small_castle(&work, 16);
    let shot = work.join("window.png");
    let runtime = work.join("xdg");
    std::fs::create_dir_all(&runtime).unwrap();
    let mut cmd = Command::new("xvfb-run");
    cmd.args(["-a", bin, "view"])
        .arg(&db)
        .args([
            "--frames",
            &frames.to_string(),
            "--target-fps",
            &fps.to_string(),
        ])
        .arg("--screenshot")
        .arg(&shot)
        .env("XDG_RUNTIME_DIR", &runtime);
    if let Some(b) = backend {
        cmd.env("WGPU_BACKEND", b);
    }
    let o = cmd.output().expect("xvfb-run (apt-get install xvfb)");
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let size = out
        .split("; view ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .unwrap_or_else(|| panic!("no view size in {out}"))
        .to_string();
    let window = image::open(&shot).unwrap().to_rgb8();
    Shot {
        out,
        window,
        size,
        work,
        db,
    }
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn the_window_shows_the_headless_render_of_the_same_camera() {
    same_picture("same-picture", None);
}

/// The machine of a fresh install with Mesa's GL but not its Vulkan driver: the window opens
/// on wgpu's GL backend (its surface, no view formats: the copy encodes sRGB itself) and
/// shows the same bytes.
#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn the_window_opens_on_the_gl_backend_and_shows_the_headless_render() {
    same_picture("same-picture-gl", Some("gl"));
}

fn same_picture(name: &str, backend: Option<&str>) {
    // Standing at the track's start, the default view; a target rate no frame misses, so
    // the frame-time budget draws everything, as `railview render` does.
    let Shot {
        out,
        window,
        size,
        work,
        db,
    } = window_shot(name, 12, 1, backend);
    if backend == Some("gl") {
        assert!(out.contains("GL backend"), "{out}");
    }
    let (w, h) = size.split_once('x').unwrap();
    let (w, h): (u32, u32) = (w.parse().unwrap(), h.parse().unwrap());
    let rendered = work.join("render.png");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_railview"));
    cmd.args(["render"])
        .arg(&db)
        .args(["--at", "0", "--fov", "90", "--size", &size, "-o"])
        .arg(&rendered);
    if let Some(b) = backend {
        cmd.env("WGPU_BACKEND", b);
    }
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let headless = image::open(&rendered).unwrap().to_rgb8();
    assert!(
        window.width() >= w && window.height() == h,
        "{size} in {window:?}"
    );
    let x0 = window.width() - w;
    let mut worst = 0u8;
    for (x, y, p) in headless.enumerate_pixels() {
        let q = window.get_pixel(x0 + x, y);
        for c in 0..3 {
            worst = worst.max(p[c].abs_diff(q[c]));
        }
    }
    // The view is copied into the window texel for pixel: the same bytes.
    assert!(worst <= 1, "largest difference {worst} of 255");
    let _ = std::fs::remove_dir_all(work);
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn a_rate_out_of_reach_draws_the_view_smaller_and_scales_it_up() {
    // 1000 fps: every step of the budget is too slow, so it walks down the whole ladder
    // (one step per eight frames), the view's size included.
    let Shot {
        out,
        window,
        size,
        work,
        ..
    } = window_shot("scaled", 120, 1000, None);
    assert!(out.contains("drawn at 50 % of the view's size"), "{out}");
    // The smaller picture fills the view's whole rectangle: its corners are scene, not the
    // panels' colour.
    let w: u32 = size.split_once('x').unwrap().0.parse().unwrap();
    let panel = *window.get_pixel(2, window.height() - 2);
    let (x0, x1) = (window.width() - w + 2, window.width() - 3);
    for (x, y) in [
        (x0, 2),
        (x1, 2),
        (x0, window.height() - 3),
        (x1, window.height() - 3),
    ] {
        assert_ne!(*window.get_pixel(x, y), panel, "({x}, {y})");
    }
    let _ = std::fs::remove_dir_all(work);
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn without_an_adapter_the_window_says_what_to_install() {
    let work = tmp("no-adapter");
    let runtime = work.join("xdg");
    std::fs::create_dir_all(&runtime).unwrap();
    let o = Command::new("xvfb-run")
        .args(["-a", env!("CARGO_BIN_EXE_railview"), "view", "synth:street"])
        .args(["--frames", "3"])
        .env("XDG_RUNTIME_DIR", &runtime)
        .env("VK_ICD_FILENAMES", "/nonexistent")
        .env("VK_DRIVER_FILES", "/nonexistent")
        .env("WGPU_BACKEND", "vulkan")
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("xvfb-run (apt-get install xvfb)");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        !err.contains("panicked") && !err.contains("backtrace"),
        "{err}"
    );
    assert!(
        err.contains("error: no GPU adapter found")
            && err.contains("apt-get install mesa-vulkan-drivers"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(work);
}
