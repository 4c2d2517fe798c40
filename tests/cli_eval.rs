//! `railview eval` from the command line: bad input fails with a message naming the flag
//! before anything is rendered or written; a database is also evaluated as a client shows it
//! before its finer texture levels arrive, at what those levels cost.

mod common;

use common::{railview, scratch_dir, scratch_path, small_castle, stderr};

#[test]
fn eval_refuses_zero_segments_and_writes_nothing() {
    let out = scratch_path("cli-eval", "zero");
    let o = railview(&[
        "eval",
        "synth:street",
        "--out",
        out.to_str().unwrap(),
        "--segments",
        "0",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--segments must be at least 1"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
}

#[test]
fn eval_of_a_database_adds_its_coarse_level_groups_at_their_bytes() {
    let d = scratch_dir("cli-eval", "groups");
    let db = small_castle(&d, 64);
    let out = d.join("eval");
    let o = railview(&[
        "eval",
        db.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--segments",
        "1",
        "--size",
        "96x64",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("eval.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    let of = |config: &str| -> Vec<&serde_json::Value> {
        rows.iter().filter(|r| r["config"] == config).collect()
    };
    let (full, coarse) = (of("full"), of("db level groups=1"));
    assert!(!coarse.is_empty(), "no coarse rows in {rows:?}");
    assert_eq!(full.len(), coarse.len());
    let bytes = |r: &[&serde_json::Value]| r[0]["db_bytes"].as_u64().unwrap();
    assert!(
        bytes(&coarse) < bytes(&full),
        "coarse {} bytes, full {}",
        bytes(&coarse),
        bytes(&full)
    );
    // At the reference samples the coarse textures lose most: the full database is exact
    // there up to the resampling floor.
    let psnr = |r: &[&serde_json::Value]| -> f64 {
        r.iter()
            .filter(|r| r["at_reference"] == true)
            .map(|r| r["psnr_db"].as_f64().unwrap())
            .sum::<f64>()
    };
    assert!(
        psnr(&coarse) < psnr(&full),
        "{} against {}",
        psnr(&coarse),
        psnr(&full)
    );
    let md = std::fs::read_to_string(out.join("eval.md")).unwrap();
    assert!(md.contains("| db level groups=1 |"), "{md}");
}
