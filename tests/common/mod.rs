//! Helpers the command-line tests share: run the built `railview`, scratch directories per
//! test and process, and a run's output for assertion messages.

// Each test file uses some of them.
#![allow(dead_code)]

pub mod cdp;
pub mod nginx;

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

/// The reports of a work directory: what they hold besides content (times, which shard
/// rendered what).
pub const REPORTS: &[&str] = &["prerender.json", "slabs.json", "cull.json", "build.json"];

/// Whether a path (relative, `/`-separated) under a prerender or build work directory is
/// content, i.e. must be the same bytes for the same inputs: everything but the run logs, the
/// reports and the temporary files of killed writers.
pub fn is_content(rel: &str) -> bool {
    let name = rel.rsplit('/').next().unwrap_or(rel);
    !(rel.starts_with("runs/")
        || rel.contains("/runs/")
        || name.ends_with(".md")
        || REPORTS.contains(&name)
        || (name.starts_with('.') && name.contains(".tmp.")))
}

/// Every file under `root` for which `keep(relative path)` holds, with its bytes.
pub fn files_under(
    root: &std::path::Path,
    keep: &dyn Fn(&str) -> bool,
) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(
        root: &std::path::Path,
        dir: &std::path::Path,
        keep: &dyn Fn(&str) -> bool,
        out: &mut std::collections::BTreeMap<String, Vec<u8>>,
    ) {
        for e in std::fs::read_dir(dir).unwrap() {
            let path = e.unwrap().path();
            if path.is_dir() {
                walk(root, &path, keep, out);
                continue;
            }
            let rel = path
                .strip_prefix(root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            if keep(&rel) {
                out.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    walk(root, root, keep, &mut out);
    out
}

/// Assert that two trees hold the same files with the same bytes; the message names every
/// file that differs or exists on one side only.
pub fn assert_same_files(
    what: &str,
    a: &std::collections::BTreeMap<String, Vec<u8>>,
    b: &std::collections::BTreeMap<String, Vec<u8>>,
) {
    let mut diff: Vec<String> = Vec::new();
    for (k, v) in a {
        match b.get(k) {
            None => diff.push(format!("only in the first: {k}")),
            Some(w) if w != v => diff.push(format!("differs: {k}")),
            Some(_) => {}
        }
    }
    diff.extend(
        b.keys()
            .filter(|k| !a.contains_key(*k))
            .map(|k| format!("only in the second: {k}")),
    );
    assert!(
        diff.is_empty(),
        "{what}: {} of {} files differ:\n{}",
        diff.len(),
        a.len().max(b.len()),
        diff.join("\n")
    );
    assert!(!a.is_empty(), "{what}: no files compared");
}

/// A report with its times (keys holding `seconds`, and `rays_per_second`) and hosts taken
/// out, at any depth.
pub fn without_times(v: &serde_json::Value) -> serde_json::Value {
    match v {
        serde_json::Value::Object(m) => serde_json::Value::Object(
            m.iter()
                .filter(|(k, _)| {
                    !(k.contains("seconds") || *k == "rays_per_second" || *k == "hosts")
                })
                .map(|(k, v)| (k.clone(), without_times(v)))
                .collect(),
        ),
        serde_json::Value::Array(a) => a.iter().map(without_times).collect(),
        other => other.clone(),
    }
}
