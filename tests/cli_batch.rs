//! Prerendering split over processes that share one directory, as a batch system runs it:
//! the same inputs give the same bytes (a database built from shards is the one a single run
//! builds), and shards started at the same instant, each as PID 1 of its own PID namespace
//! (as every pod of a Kubernetes Job is), never fail or disturb each other. A town network
//! with every track, built from shards as the Slurm job files build it, is the database one
//! machine builds.
//!
//! The namespace test runs `unshare --pid --fork --mount-proc` (util-linux; as root, or with a
//! user namespace otherwise). Where namespaces cannot be made it fails, saying so; set
//! `RAILVIEW_SKIP_NAMESPACE_TESTS=1` to mark it ignored instead.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{
    assert_same_files, files_under, is_content, railview, scratch_dir, stderr, without_times,
    REPORTS,
};

/// A straight stretch of the castle's approach with `count` viewpoints.
fn track(dir: &Path, count: usize) -> PathBuf {
    let p = dir.join("track.toml");
    std::fs::write(
        &p,
        format!(
            "[[track]]\nname = \"gate\"\npoints = [[0, 1.7, 42], [0, 1.7, 34]]\ncount = {count}\n"
        ),
    )
    .unwrap();
    p
}

fn run_ok(args: &[&str]) {
    let o = railview(args);
    assert!(
        o.status.success(),
        "railview {}:\n{}",
        args.join(" "),
        stderr(&o)
    );
}

fn build(track: &Path, work: &Path, db: &Path) {
    run_ok(&[
        "build",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "64",
        "--zstd-level",
        "3",
        "--work",
        work.to_str().unwrap(),
        "--out",
        db.to_str().unwrap(),
    ]);
}

#[test]
fn two_builds_of_the_same_inputs_are_the_same_bytes() {
    let dir = scratch_dir("cli-batch", "twice");
    let track = track(&dir, 4);
    let (wa, wb) = (dir.join("a.work"), dir.join("b.work"));
    let (da, db) = (dir.join("a-db"), dir.join("b-db"));
    build(&track, &wa, &da);
    build(&track, &wb, &db);
    // The database, every file; the work directories (prerender, slabs, culling, encoded
    // tiles) apart from run logs and reports.
    assert_same_files(
        "database",
        &files_under(&da, &|_| true),
        &files_under(&db, &|_| true),
    );
    let content = |w: &Path| files_under(w, &|rel| is_content(rel));
    let ca = content(&wa);
    assert!(
        ca.keys().any(|k| k.ends_with("depth.exr"))
            && ca.keys().any(|k| k.ends_with("sample.json")),
        "{:?}",
        ca.keys().take(20).collect::<Vec<_>>()
    );
    assert_same_files("work directory", &ca, &content(&wb));
    // The reports differ only in their times.
    let reports = |w: &Path| -> Vec<(String, serde_json::Value)> {
        let names = files_under(w, &|rel| {
            REPORTS.contains(&rel.rsplit('/').next().unwrap()) && !rel.contains("runs/")
        });
        names
            .into_iter()
            .map(|(k, bytes)| {
                let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
                (k, without_times(&v))
            })
            .collect()
    };
    let (ra, rb) = (reports(&wa), reports(&wb));
    assert_eq!(
        ra.len(),
        REPORTS.len(),
        "{:?}",
        ra.iter().map(|r| &r.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in ra.iter().zip(&rb) {
        assert_eq!(a, b, "{name} differs beyond its times");
    }
    // Each run logged itself.
    for w in [&wa, &wb] {
        let logs: Vec<String> = std::fs::read_dir(w.join("prerender/runs"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        for stage in ["prerender-", "slabs-", "cull-"] {
            assert!(logs.iter().any(|l| l.starts_with(stage)), "{logs:?}");
        }
        assert!(w.join("runs").read_dir().unwrap().count() == 1);
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A town network, every track (`town-1 --track all`, about 1 000 viewpoints at faces of 16),
/// prerendered as three shards running together in one directory, one thread each as a Slurm
/// array's tasks get by default, then merged and built as `deploy/slurm-merge.sbatch` builds
/// it: the database is, byte for byte, the one a single `railview build` writes, and so is
/// the work directory apart from reports and run logs.
#[test]
fn a_town_network_built_in_shards_is_the_one_machine_database() {
    const SHARDS: usize = 3;
    let dir = scratch_dir("cli-batch", "town");
    let scene = ["--scene", "town-1", "--track", "all", "--face-size", "16"];
    let path = |p: &Path| p.to_str().unwrap().to_owned();
    // `railview build` as one machine runs it, and as the merge job resumes it.
    let build = |work: &Path, db: &Path| {
        let (work, db) = (path(work), path(db));
        let mut a = vec!["build"];
        a.extend(scene);
        a.extend(["--work", &work, "--out", &db]);
        run_ok(&a);
    };
    let (one_work, one_db) = (dir.join("one.work"), dir.join("one-db"));
    build(&one_work, &one_db);

    let work = dir.join("shards.work");
    let prerender = path(&work.join("prerender"));
    let children: Vec<_> = (0..SHARDS)
        .map(|k| {
            Command::new(env!("CARGO_BIN_EXE_railview"))
                .arg("prerender")
                .args(scene)
                .args(["--shard", &format!("{k}/{SHARDS}"), "--out", &prerender])
                .env("RAYON_NUM_THREADS", "1")
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("start a shard")
        })
        .collect();
    for (k, c) in children.into_iter().enumerate() {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "shard {k}/{SHARDS}:\n{}", stderr(&o));
    }
    let mut merge = vec!["prerender", "--merge"];
    merge.extend(scene);
    merge.extend(["--out", &prerender]);
    run_ok(&merge);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(work.join("prerender/prerender.json")).unwrap())
            .unwrap();
    assert_eq!(report["shards"].as_array().map(Vec::len), Some(SHARDS));
    let samples = report["extra"]["complete_samples"].as_u64().unwrap();
    assert!(samples > 500, "town-1 has {samples} samples");
    let db = dir.join("shards-db");
    build(&work, &db);

    assert_same_files(
        "database from shards against one machine",
        &files_under(&one_db, &|_| true),
        &files_under(&db, &|_| true),
    );
    assert_same_files(
        "work directory from shards against one machine",
        &files_under(&one_work, &|rel| is_content(rel)),
        &files_under(&work, &|rel| is_content(rel)),
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `unshare` arguments that give a command its own PID namespace here (root, or a user
/// namespace mapping us to root), after checking that the command sees itself as PID 1.
fn unshare_prefix() -> Vec<&'static str> {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.trim_ascii() == b"0");
    let mut args = vec!["unshare"];
    if !root {
        args.extend(["--user", "--map-root-user"]);
    }
    args.extend(["--pid", "--fork", "--mount-proc"]);
    let probe = Command::new(args[0])
        .args(&args[1..])
        .args(["sh", "-c", "echo $$"])
        .output();
    match probe {
        Ok(o) if o.status.success() && o.stdout.trim_ascii() == b"1" => args,
        Ok(o) => panic!(
            "cannot make a PID namespace with `{}` ({}): run the tests as root (scripts/test.sh), \
             or set RAILVIEW_SKIP_NAMESPACE_TESTS=1 to mark this test ignored",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ),
        Err(e) => panic!(
            "cannot run `unshare` ({e}): install util-linux, or set \
             RAILVIEW_SKIP_NAMESPACE_TESTS=1 to mark this test ignored"
        ),
    }
}

#[test]
#[cfg_attr(
    railview_skip_namespaces,
    ignore = "RAILVIEW_SKIP_NAMESPACE_TESTS=1: PID namespaces switched off"
)]
fn shards_started_together_as_pid_1_never_collide() {
    let dir = scratch_dir("cli-batch", "pid1");
    let track = track(&dir, 8);
    let bin = env!("CARGO_BIN_EXE_railview");
    let prefix = unshare_prefix();
    let common_args = |out: &Path| -> Vec<String> {
        [
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
        ]
        .map(String::from)
        .to_vec()
    };
    // One process, no shards: what every round must produce.
    let single = dir.join("single");
    let args = common_args(&single);
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let want = files_under(&single, &|rel| is_content(rel));
    const SHARDS: usize = 4;
    for round in 0..5 {
        let out = dir.join(format!("round{round}"));
        let go = dir.join(format!("go{round}"));
        // Each shard waits, as PID 1 of its own namespace, for the same file, then starts.
        let children: Vec<_> = (0..SHARDS)
            .map(|k| {
                let mut a = common_args(&out);
                a.extend(["--shard".into(), format!("{k}/{SHARDS}")]);
                let script = format!(
                    "while [ ! -e '{}' ]; do :; done; echo pid $$; exec \"$0\" \"$@\"",
                    go.display()
                );
                Command::new(prefix[0])
                    .args(&prefix[1..])
                    .args(["sh", "-c", &script, bin])
                    .args(&a)
                    .stdout(Stdio::piped())
                    .stderr(Stdio::piped())
                    .spawn()
                    .expect("start a shard")
            })
            .collect();
        std::thread::sleep(Duration::from_millis(300));
        std::fs::write(&go, b"").unwrap();
        let deadline = Instant::now() + Duration::from_secs(120);
        for (k, c) in children.into_iter().enumerate() {
            let o = c.wait_with_output().unwrap();
            assert!(
                Instant::now() < deadline,
                "round {round}: shards took too long"
            );
            let (out_text, err_text) = (
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr),
            );
            assert!(
                o.status.success(),
                "round {round}, shard {k}/{SHARDS} failed:\n{err_text}"
            );
            assert!(out_text.contains("pid 1"), "round {round}: {out_text}");
        }
        let mut merge = common_args(&out);
        merge.push("--merge".into());
        run_ok(&merge.iter().map(String::as_str).collect::<Vec<_>>());
        let got = files_under(&out, &|rel| is_content(rel));
        assert_same_files(&format!("round {round} against one process"), &want, &got);
        // Nothing left over: no temporary file anywhere, one log per shard.
        let all = files_under(&out, &|_| true);
        assert!(
            !all.keys().any(|k| k.contains(".tmp.")),
            "{:?}",
            all.keys()
                .filter(|k| k.contains(".tmp."))
                .collect::<Vec<_>>()
        );
        assert_eq!(
            all.keys().filter(|k| k.starts_with("runs/")).count(),
            SHARDS
        );
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("prerender.json")).unwrap()).unwrap();
        assert_eq!(report["shards"].as_array().map(Vec::len), Some(SHARDS));
        assert_eq!(report["extra"]["complete_samples"], 8);
        assert_eq!(report["extra"]["samples_with_layers"], 8);
    }
    std::fs::remove_dir_all(&dir).ok();
}
