//! Helpers the command-line tests share: run the built `railview`, scratch directories per
//! test and process, and a run's output for assertion messages.

// Each test file uses some of them.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Run the `railview` binary of this build with `args` and wait for it.
pub fn railview(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_railview"))
        .args(args)
        .output()
        .expect("run railview")
}

/// `railview-{tag}-{name}-{pid}` under the temporary directory, removed if it was there
/// (not created: commands that must create it get the chance).
pub fn scratch_path(tag: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("railview-{tag}-{name}-{}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    d
}

/// [`scratch_path`], created empty.
pub fn scratch_dir(tag: &str, name: &str) -> PathBuf {
    let d = scratch_path(tag, name);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Standard error of a run.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Both streams of a run.
pub fn text(o: &Output) -> String {
    format!(
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Build the built-in castle along a 6 m track of three viewpoints at face `face` into
/// `dir/db` (prerender, slabs, culling and encoding take a second or two at face 64) and
/// return the database's path.
pub fn small_castle(dir: &std::path::Path, face: u32) -> PathBuf {
    let track = dir.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 3\n",
    )
    .unwrap();
    let db = dir.join("db");
    let face = face.to_string();
    let o = railview(&[
        "build",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        &face,
        "--zstd-level",
        "3",
        "--out",
        db.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    db
}
