//! `railview build` killed with SIGKILL at several moments, then run again: the database
//! is byte for byte the one an uninterrupted build writes, with no stray temporary file
//! (property-style: the kill points are drawn from a seeded generator over the whole build,
//! one per fifth of its progress, counted in the files it has written, so every stage is hit
//! across the cases however loaded the machine is).

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{railview, scratch_dir, stderr};

const FACE: &str = "32";

/// The kill test times a whole build and kills later ones at fractions of that time, so the
/// tests here run one at a time (another build beside it would skew the timing).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn build_args(track: &Path, out: &Path, work: &Path) -> Vec<String> {
    [
        "build",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        FACE,
        "--zstd-level",
        "3",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--out",
        out.to_str().unwrap(),
        "--work",
        work.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// Every file under `dir` (relative path → bytes).
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap())
            .collect();
        entries.sort_by_key(|e| e.file_name());
        for e in entries {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.insert(
                    p.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// How many files and directories are under `dir` (0 when it does not exist yet; entries
/// that vanish while it is read, such as renamed temporary files, are skipped).
fn entries(dir: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.filter_map(Result::ok)
        .map(|e| {
            1 + if e.file_type().is_ok_and(|t| t.is_dir()) {
                entries(&e.path())
            } else {
                0
            }
        })
        .sum()
}

/// A small deterministic generator (the kill points must repeat from run to run).
struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn a_build_killed_at_random_moments_resumes_to_identical_bytes_and_no_stray_files() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = scratch_dir("resume", "kill");
    let track = dir.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 36]]\ncount = 3\n",
    )
    .unwrap();
    // The uninterrupted build, and how many entries it writes (its progress measure).
    let reference = dir.join("ref");
    let args = build_args(&track, &reference, &dir.join("ref.work"));
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = railview(&argv);
    assert!(o.status.success(), "{}", stderr(&o));
    let whole = entries(&reference) + entries(&dir.join("ref.work"));
    assert!(
        whole >= 20,
        "the reference build wrote only {whole} entries"
    );
    let want = files(&reference);
    let mut rng = Lcg(0x5eed_1234);
    let mut killed_midway = 0;
    for case in 0..5 {
        let out = dir.join(format!("db{case}"));
        let work = dir.join(format!("db{case}.work"));
        let args = build_args(&track, &out, &work);
        // One kill point in each fifth of the build's progress.
        let at = ((whole as f64 * (case as f64 + rng.unit()) / 5.0) as usize).max(1);
        let mut child = Command::new(env!("CARGO_BIN_EXE_railview"))
            .args(&args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let finished = loop {
            if child.try_wait().unwrap().is_some() {
                break true;
            }
            if entries(&out) + entries(&work) >= at {
                break false;
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        child.kill().unwrap(); // SIGKILL: no chance to clean up
        child.wait().unwrap();
        killed_midway += usize::from(!finished);
        if case == 0 {
            // What a kill during an object's write leaves (one of this writer's temporary
            // names, of a process that is gone): the resumed build removes it.
            let objects = out.join("objects").join("41");
            std::fs::create_dir_all(&objects).unwrap();
            std::fs::write(
                objects.join(format!(".41{}.tmp.999999999", "0".repeat(62))),
                b"half an object",
            )
            .unwrap();
        }
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = railview(&argv);
        assert!(
            o.status.success(),
            "case {case} (killed at {at} entries): {}",
            stderr(&o)
        );
        let got = files(&out);
        let stray: Vec<&PathBuf> = got
            .keys()
            .filter(|p| {
                p.file_name()
                    .is_some_and(|n| db::is_temp_name(&n.to_string_lossy()))
            })
            .collect();
        assert!(stray.is_empty(), "case {case}: stray files {stray:?}");
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            want.keys().collect::<Vec<_>>(),
            "case {case} (killed at {at} entries): different files"
        );
        for (path, bytes) in &want {
            assert!(
                got[path] == *bytes,
                "case {case} (killed at {at} entries): {} differs",
                path.display()
            );
        }
        // Empty directories a killed build left are not files: verify says intact.
        let v = db::verify(&out).unwrap();
        assert!(v.is_intact() && v.stray.is_empty(), "{:?}", v.problems);
    }
    assert!(
        killed_midway >= 3,
        "only {killed_midway} of 5 kills landed mid-build"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_work_directory_built_at_another_face_size_is_tiled_and_encoded_again() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = scratch_dir("resume", "face");
    let track = dir.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 38]]\ncount = 2\n",
    )
    .unwrap();
    let work = dir.join("shared.work");
    for (face, out) in [("32", "db32"), ("48", "db48")] {
        let out = dir.join(out);
        let mut args = build_args(&track, &out, &work);
        let at = args.iter().position(|a| a == "--face-size").unwrap();
        args[at + 1] = face.into();
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = railview(&argv);
        assert!(o.status.success(), "face {face}: {}", stderr(&o));
        let db = db::Database::open(&out).unwrap();
        assert_eq!(db.top().face_size.to_string(), face);
        // The tiles were cut again from the new panoramas, not reused from the old ones.
        let slabs: serde_json::Value = serde_json::from_slice(
            &std::fs::read(work.join("prerender").join("slabs.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(slabs["face_size"].to_string(), face, "stale tiling reused");
        let v = db::verify_with(
            &out,
            db::VerifyOptions {
                decode: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(v.is_intact(), "face {face}: {:?}", v.problems);
    }
    let _ = std::fs::remove_dir_all(dir);
}
