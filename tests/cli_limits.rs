//! Absurd numbers from outside (a manifest, a track file, the command line) are one-line
//! errors that name the value and its limit, with exit status 1 or 2 — never an abort or a
//! run without end — and error messages point at the right thing.

mod common;

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::Path;

use common::{railview, scratch_dir, stderr, text};
use streamer::walk::synth;

/// Runs `args` and checks that it fails with status 1 or 2 (not a signal), a first line
/// `error: …` holding every one of `needles`, and, for status 1, nothing more.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let o = railview(args);
    let code = o.status.code();
    assert!(
        matches!(code, Some(1) | Some(2)),
        "{args:?}: status {:?}\n{}",
        o.status,
        text(&o)
    );
    let err = stderr(&o);
    // Log lines (warnings on the way) are not the error.
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.contains("WARN") && !l.contains("INFO"))
        .collect();
    assert!(
        lines.first().is_some_and(|l| l.starts_with("error:")),
        "{args:?}: {err}"
    );
    if code == Some(1) {
        assert_eq!(lines.len(), 1, "{args:?}: more than one line:\n{err}");
    }
    for n in needles {
        assert!(
            lines[0].contains(n),
            "{args:?}: `{n}` not in `{}`",
            lines[0]
        );
    }
    lines[0].to_string()
}

/// A synthetic database whose manifest says `face_size = face`, without its checksum and
/// gzip copy (as a tester who edits it by hand leaves it).
fn db_with_face_size(dir: &Path, face: u64) -> std::path::PathBuf {
    let db = dir.join(format!("face{face}"));
    synth::write_synthetic(&db, &synth::SynthParams::default()).unwrap();
    std::fs::remove_file(db.join("manifest.json.blake3")).unwrap();
    std::fs::remove_file(db.join("manifest.json.gz")).unwrap();
    let path = db.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    m["face_size"] = face.into();
    std::fs::write(&path, serde_json::to_vec(&m).unwrap()).unwrap();
    db
}

/// A static file host for one directory (GET only, no ranges): enough for a client to read
/// a manifest a server of ours would refuse to serve.
fn static_host(root: &Path) -> String {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let root = root.to_path_buf();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(mut conn) = conn else { continue };
            let mut head = Vec::new();
            let mut byte = [0u8; 1];
            while !head.ends_with(b"\r\n\r\n") && conn.read(&mut byte).unwrap_or(0) == 1 {
                head.push(byte[0]);
            }
            let head = String::from_utf8_lossy(&head);
            let path = head.split_whitespace().nth(1).unwrap_or("/");
            let file = (!path.contains(".."))
                .then(|| std::fs::read(root.join(path.trim_start_matches('/'))).ok())
                .flatten();
            let _ = match file {
                Some(body) => conn
                    .write_all(
                        format!(
                            "HTTP/1.1 200 OK\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                            body.len()
                        )
                        .as_bytes(),
                    )
                    .and_then(|_| conn.write_all(&body)),
                None => conn.write_all(
                    b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
                ),
            };
        }
    });
    format!("http://{addr}")
}

/// Row 5: a hostile `face_size` in the manifest is refused by the server, the client and
/// `verify`, naming the field and the limit (it used to abort the client allocating 1.5e18
/// bytes).
#[test]
fn hostile_manifest_numbers_are_refused_by_server_client_and_verify() {
    let dir = scratch_dir("limits", "manifest");
    for face in [4_000_000_000u64, 65_536] {
        let db = db_with_face_size(&dir, face);
        let dbs = db.to_str().unwrap();
        let out = dir.join(format!("walk{face}"));
        let outs = out.to_str().unwrap();
        let face_s = face.to_string();
        let needles = ["face_size", face_s.as_str(), "8192"];
        refused(&["walk", dbs, "--out", outs], &needles);
        refused(&["serve", dbs, "--addr", "127.0.0.1:0"], &needles);
        // Through a plain static host, the client itself refuses it, and still writes
        // walk.json with why.
        let url = static_host(&db);
        refused(
            &["walk", &url, "--out", outs, "--give-up-after", "5s"],
            &needles,
        );
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
        assert!(json["error"].as_str().unwrap().contains("face_size"));
        let o = railview(&["verify", dbs]);
        assert_eq!(o.status.code(), Some(1), "{}", text(&o));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            stdout.contains("DAMAGED") && stdout.contains("face_size") && stdout.contains("8192"),
            "{stdout}"
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Rows 6 and 9: absurd command-line and track values are refused up front.
#[test]
fn absurd_command_line_and_track_values_are_one_line_errors() {
    let dir = scratch_dir("limits", "args");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let track = dir.join("tiny-spacing.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"t\"\npoints = [[0, 1.7, 0], [72, 1.7, 0]]\nspacing = 1e-9\n",
    )
    .unwrap();
    let t = track.to_str().unwrap();
    let line = refused(
        &[
            "prerender",
            "--scene",
            "castle",
            "--track",
            t,
            "--face-size",
            "16",
            "--out",
            o,
        ],
        &["spacing", "100000"],
    );
    // The track file's line of the offending [[track]] (not line 0).
    assert!(line.contains("tiny-spacing.toml:1:"), "{line}");
    for face in ["4294967295", "100000"] {
        refused(
            &[
                "prerender",
                "--scene",
                "castle",
                "--face-size",
                face,
                "--out",
                o,
            ],
            &["--face-size", face, "8192"],
        );
        refused(
            &[
                "build",
                "--scene",
                "castle",
                "--face-size",
                face,
                "--out",
                o,
            ],
            &["--face-size", face],
        );
    }
    for alpha in ["NaN", "2"] {
        refused(
            &["build", "--scene", "castle", "--alpha", alpha, "--out", o],
            &["--alpha", alpha, "(0, 1]"],
        );
    }
    let walk = |extra: &[&str], needles: &[&str]| {
        let mut args = vec!["walk", "no-such-db", "--out", o];
        args.extend_from_slice(extra);
        refused(&args, needles)
    };
    walk(&["--speed", "1e-9"], &["--speed", "0.01"]);
    // Not "must be positive": infinity is positive; it is not finite.
    walk(&["--speed", "inf"], &["--speed", "finite"]);
    walk(&["--in-flight", "0"], &["--in-flight", "1 to 64"]);
    walk(&["--pause", "NaN"], &["--pause", "finite"]);
    walk(&["--cache-mb", "1e12"], &["--cache-mb"]);
    // Nothing was written for refused commands.
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(dir);
}

/// Row 10: messages that point at the right thing.
#[test]
fn messages_name_the_right_thing() {
    let dir = scratch_dir("limits", "messages");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    // https:// is a URL this client does not speak, not a directory that is missing.
    refused(
        &["walk", "https://example.org/castle", "--out", o],
        &["only http://", "https://example.org/castle"],
    );
    // An OS error is printed once.
    let missing = dir.join("missing-db");
    let line = refused(&["verify", missing.to_str().unwrap()], &["missing-db"]);
    assert_eq!(
        line.matches("No such file or directory").count(),
        1,
        "{line}"
    );
    let line = refused(&["serve", missing.to_str().unwrap()], &["missing-db"]);
    assert_eq!(
        line.matches("No such file or directory").count(),
        1,
        "{line}"
    );
    // A damaged table names its object, not the manifest.
    let db = dir.join("db");
    let m = synth::write_synthetic(&db, &synth::SynthParams::default()).unwrap();
    let top = db::read_top(&db).unwrap();
    let rel = top.viewpoints[1].table.rel_path().unwrap();
    let mut bytes = std::fs::read(db.join(&rel)).unwrap();
    bytes[3] ^= 1;
    std::fs::write(db.join(&rel), &bytes).unwrap();
    let line = refused(
        &["serve", db.to_str().unwrap(), "--addr", "127.0.0.1:0"],
        &[&rel, "content hash", "railview verify"],
    );
    assert!(!line.contains("not a database manifest"), "{line}");
    assert!(!m.tracks.is_empty());
    let _ = std::fs::remove_dir_all(dir);
}

/// Row 4: a walk against a server that accepts connections and never answers (or one frozen
/// with SIGSTOP) ends with a clear error within its timeouts, and writes walk.json saying
/// why, instead of hanging.
#[test]
fn a_walk_against_a_silent_server_ends_within_its_timeout() {
    let dir = scratch_dir("limits", "silent");
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        // Accept and hold every connection; never answer.
        let mut held = Vec::new();
        for c in listener.incoming() {
            held.push(c);
        }
    });
    let out = dir.join("walk");
    let t0 = std::time::Instant::now();
    let line = refused(
        &[
            "walk",
            &url,
            "--out",
            out.to_str().unwrap(),
            "--response-timeout",
            "1s",
            "--give-up-after",
            "3s",
        ],
        &[&url, "no response within 1.0 s", "gave up"],
    );
    let took = t0.elapsed();
    assert!(
        took < std::time::Duration::from_secs(10),
        "{took:?}: {line}"
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
    assert!(json["error"].as_str().unwrap().contains("no response"));
    assert_eq!(json["runs"].as_array().unwrap().len(), 0);
    let _ = std::fs::remove_dir_all(dir);
}
