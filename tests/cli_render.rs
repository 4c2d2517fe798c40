//! `railview render` from the command line: negative angles parse, and bad input (a position
//! off the track, a pitch past the vertical, an output that is not PNG) fails with a message
//! naming the flag before anything is written. The built-in synthetic street keeps it fast.

mod common;

use std::path::PathBuf;
use std::process::Output;

use common::{railview, scratch_dir, small_castle, stderr};

fn tmp(name: &str) -> PathBuf {
    scratch_dir("cli-render", name)
}

fn render(at: &str, yaw: &str, pitch: &str, out: &std::path::Path) -> Output {
    railview(&[
        "render",
        "synth:street",
        "--at",
        at,
        "--yaw",
        yaw,
        "--pitch",
        pitch,
        "--size",
        "48x32",
        "-o",
        out.to_str().unwrap(),
    ])
}

#[test]
fn negative_yaw_and_pitch_render() {
    let d = tmp("negative");
    let out = d.join("view.png");
    let o = render("1", "-30", "-90", &out);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = std::fs::read(&out).expect("image written");
    assert_eq!(&img[1..4], b"PNG");
}

#[test]
fn bad_render_input_names_the_flag_and_writes_nothing() {
    let d = tmp("bad");
    let out = d.join("view.png");
    for (at, pitch, expect) in [
        (
            "-3",
            "0",
            "--at -3: outside track `main`, which runs from 0 to",
        ),
        ("1e9", "0", "--at 1000000000: outside track `main`"),
        ("1", "95", "camera pitch_deg is invalid: 95"),
        ("1", "-90.5", "camera pitch_deg is invalid: -90.5"),
    ] {
        let o = render(at, "0", pitch, &out);
        assert!(!o.status.success(), "--at {at} --pitch {pitch} succeeded");
        assert!(stderr(&o).contains(expect), "{}", stderr(&o));
        assert!(!out.exists(), "--at {at} --pitch {pitch} wrote an image");
    }
    let jpg = d.join("view.jpg");
    let o = render("1", "0", "0", &jpg);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("only PNG images are written"),
        "{}",
        stderr(&o)
    );
    assert!(!jpg.exists());
}

/// The PSNR `railview render … --truth` reports, from its standard error.
fn psnr_of(o: &Output) -> f64 {
    let err = stderr(o);
    assert!(o.status.success(), "{err}");
    err.lines()
        .find_map(|l| l.strip_prefix("PSNR against the ground truth: "))
        .and_then(|v| v.trim_end_matches(" dB").parse().ok())
        .unwrap_or_else(|| panic!("no PSNR in {err}"))
}

/// Rewrite a database's top manifest with another format number.
fn relabel_format(db: &std::path::Path, version: u32) {
    use db::{hash_hex, Database, MANIFEST_FILE, MANIFEST_HASH_FILE};
    let mut top = Database::open(db).unwrap().top().clone();
    top.version = version;
    let json = serde_json::to_vec(&top).unwrap();
    std::fs::write(db.join(MANIFEST_FILE), &json).unwrap();
    std::fs::write(
        db.join(MANIFEST_HASH_FILE),
        format!("{}\n", hash_hex(&json)),
    )
    .unwrap();
    std::fs::remove_file(db.join(format!("{MANIFEST_FILE}.gz"))).ok();
}

/// `--level-groups 1` draws what a streaming client shows before the finer levels arrive:
/// coarse levels are colour × coverage, their outlines drawn in the colour of what they
/// cover, a little further from the ground truth than every level. A database of an older
/// format is refused with the command that rebuilds it.
#[test]
fn coarse_levels_draw_outlines_in_their_own_colour() {
    let d = tmp("coarse");
    let db = small_castle(&d, 64);
    let view = |groups: Option<&str>| {
        let mut args = vec![
            "render",
            db.to_str().unwrap(),
            "--at",
            "3",
            "--size",
            "320x180",
            "-o",
        ];
        let out = d.join("view.png");
        let truth = d.join("truth.png");
        args.push(out.to_str().unwrap());
        args.extend(["--truth", truth.to_str().unwrap()]);
        if let Some(g) = groups {
            args.extend(["--level-groups", g]);
        }
        psnr_of(&railview(&args))
    };
    let full = view(None);
    let coarse = view(Some("1"));
    eprintln!("PSNR: all levels {full:.2} dB, coarsest group {coarse:.2} dB");
    assert!(full > coarse, "{full} against {coarse}");
    assert!(coarse > 20.0, "coarsest group {coarse} dB");
    relabel_format(&db, 4);
    let out = d.join("old.png");
    let o = railview(&["render", db.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(!o.status.success() && !out.exists());
    assert!(
        stderr(&o).contains("manifest format 4") && stderr(&o).contains("railview build"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn level_groups_need_a_database_and_at_least_one_group() {
    let d = tmp("groups");
    let out = d.join("view.png");
    let o = railview(&[
        "render",
        "synth:street",
        "--level-groups",
        "1",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--level-groups: synth:street is not a database"),
        "{}",
        stderr(&o)
    );
    let o = railview(&[
        "render",
        "synth:street",
        "--level-groups",
        "0",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--level-groups 0: at least 1"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists(), "nothing written");
}
