//! `railview build --pov` end to end on the analytic POV-Ray scene: base pass, automatic
//! slabs rendered by POV-Ray, cull, encode, ACH, then `railview verify` on the database.
//! Faces of 16 px and a low-resolution pass of 8 px keep it fast.

mod common;

use std::path::{Path, PathBuf};

use common::{railview, scratch_path, text};

fn tmp(name: &str) -> PathBuf {
    scratch_path("cli-build-pov", name)
}

fn json(path: &Path) -> serde_json::Value {
    let t = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&t).expect("JSON")
}

fn repo(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

#[test]
fn build_pov_analytic_end_to_end_and_verify() {
    let work = tmp("analytic");
    let db = work.join("db");
    let stages = work.join("stages");
    let (scene, track) = (
        repo("scenes/pov/analytic.pov"),
        repo("scenes/pov/analytic.toml"),
    );
    let args = [
        "build",
        "--pov",
        &scene,
        "--track",
        &track,
        "--up",
        "y",
        "--face-size",
        "16",
        "--lowres-face-size",
        "8",
        "--ach-samples",
        "2",
        "--ach-camera-size",
        "16",
        "--zstd-level",
        "3",
        "--out",
        db.to_str().unwrap(),
        "--work",
        stages.to_str().unwrap(),
    ];
    let o = railview(&args);
    assert!(o.status.success(), "{}", text(&o));

    // The slab layers were chosen automatically and rendered by POV-Ray.
    let pre_dir = stages.join("prerender");
    let pre = json(&pre_dir.join("prerender.json"));
    assert_eq!(pre["renderer"], "povray");
    let slabs = pre["slabs"].as_array().expect("slabs in prerender.json");
    assert!(!slabs.is_empty(), "no slabs recorded: {pre}");
    assert!(pre["extra"]["slab_renders"].as_u64().unwrap() >= 2 * slabs.len() as u64);
    let samples = pre["samples"].as_u64().unwrap() as usize;
    assert_eq!(samples, 2);
    for i in 0..samples {
        let layers = json(&pre_dir.join(format!("samples/{i:04}/layers.json")));
        assert_eq!(layers["slabs"].as_array().unwrap().len(), slabs.len());
        for k in 0..slabs.len() {
            for f in ["color.png", "depth.exr"] {
                let p = pre_dir.join(format!("samples/{i:04}/slab_{k}/{f}"));
                assert!(p.is_file(), "{} missing", p.display());
            }
        }
    }
    // The last slab reaches infinity (written as null), so the sky belongs to a layer.
    assert!(slabs.last().unwrap()["far"].is_null(), "{pre}");

    // The sky behind every occluder was rendered alone by POV-Ray (rays starting past every
    // object) and matched the panoramas' own sky where they see it.
    assert!(pre_dir.join("sky.png").is_file());
    let build = json(&stages.join("build.json"));
    assert_eq!(build["sky"], "rendered", "{build}");
    // Culling ran from POV-Ray's depth renders along the track (`auto` for an import);
    // the database has a track with segments.
    let build = json(&stages.join("build.json"));
    assert!(
        build["culling"].as_str().unwrap().starts_with("rendered"),
        "{build}"
    );
    let manifest = serde_json::to_value(db::read_top(&db).unwrap()).unwrap();
    // The graph (format 9's pieces, assembled): the viewpoints once, the track as its stops
    // (two: one segment).
    assert_eq!(manifest["viewpoints"].as_array().unwrap().len(), 2);
    let track = &manifest["tracks"][0];
    assert_eq!(track["stops"].as_array().unwrap().len(), 2, "{track}");
    // Tiles are in each viewpoint's table (manifest format 2), read through the database.
    let full = db::Database::open(&db).unwrap();
    assert!(full.manifest().tracks[0].viewpoints[0]
        .tiles
        .iter()
        .any(|t| t.kept));

    // Decoded too: POV-Ray leaves its background under every slab's mask, and the builder
    // clears it (format 5).
    let v = railview(&["verify", db.to_str().unwrap(), "--decode"]);
    assert!(v.status.success(), "{}", text(&v));
    let out = String::from_utf8_lossy(&v.stdout);
    assert!(out.contains("intact"), "{out}");
    let (ptms, meshes) = out
        .lines()
        .find_map(|l| l.strip_suffix(" meshes decoded")?.split_once(" PTMs and "))
        .unwrap_or_else(|| panic!("no count in {out}"));
    let (ptms, meshes): (usize, usize) = (ptms.parse().unwrap(), meshes.parse().unwrap());
    assert!(ptms > 0 && meshes > 0, "{out}");

    // A second build resumes every stage: nothing rendered or written again, same manifest.
    let first = std::fs::read(db.join("manifest.json")).unwrap();
    let again = railview(&args);
    assert!(again.status.success(), "{}", text(&again));
    assert!(
        !String::from_utf8_lossy(&again.stderr).contains("slab0-depth"),
        "{}",
        text(&again)
    );
    assert_eq!(json(&stages.join("build.json"))["objects_written"], 0);
    assert!(std::fs::read(db.join("manifest.json")).unwrap() == first);
    std::fs::remove_dir_all(&work).ok();
}

#[test]
fn build_scene_and_pov_conflict() {
    let o = railview(&[
        "build",
        "--scene",
        "castle",
        "--pov",
        &repo("scenes/pov/analytic.pov"),
        "--out",
        "/nonexistent/db",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cannot be used with"), "{err}");
}

/// Every file under `root` (relative path, bytes), sorted.
fn tree(root: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut todo = vec![root.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_path_buf();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// A scene lit by radiosity (`scenes/pov/room.pov`): the import samples radiosity once for
/// the track and every colour render loads those samples, so that the same build twice
/// gives byte-identical objects (each render sampling anew, two renders of one view
/// differed by a mean of 2.4 levels on the balcony), and the report says how neighbouring
/// references agree on the surfaces both see.
#[test]
fn radiosity_is_sampled_once_and_two_builds_are_byte_identical() {
    let work = tmp("radiosity");
    std::fs::remove_dir_all(&work).ok();
    let (scene, track) = (repo("scenes/pov/room.pov"), repo("scenes/pov/room.toml"));
    for run in ["a", "b"] {
        let (db, stages) = (work.join(run), work.join(format!("{run}.work")));
        let o = railview(&[
            "build",
            "--pov",
            &scene,
            "--track",
            &track,
            "--face-size",
            "16",
            "--out",
            db.to_str().unwrap(),
            "--work",
            stages.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", text(&o));
        let pre = stages.join("prerender");
        assert!(pre.join("radiosity.rad").is_file());
        // A closed room: no panorama sees sky, so there is no sky to render alone.
        assert!(!pre.join("sky.png").exists());
        let report = json(&pre.join("prerender.json"));
        assert_eq!(report["extra"]["radiosity_shared"], true, "{report}");
        let a = &report["extra"]["agreement"];
        assert!(a["pixels"].as_u64().unwrap() > 0, "{a}");
        assert!(a["mean"].as_f64().unwrap() < 20.0, "{a}");
        let md = std::fs::read_to_string(pre.join("prerender.md")).unwrap();
        assert!(md.contains("radiosity sampled once for the track"), "{md}");
    }
    let (a, b) = (tree(&work.join("a/objects")), tree(&work.join("b/objects")));
    assert!(!a.is_empty());
    let names = |t: &[(PathBuf, Vec<u8>)]| t.iter().map(|(p, _)| p.clone()).collect::<Vec<_>>();
    assert_eq!(
        names(&a),
        names(&b),
        "the two builds wrote different objects"
    );
    assert!(a == b, "same object names with different bytes");
    std::fs::remove_dir_all(&work).ok();
}
