//! `railview render` from the command line: negative angles parse, and bad input (a position
//! off the track, a pitch past the vertical, an output that is not PNG) fails with a message
//! naming the flag before anything is written. The built-in synthetic street keeps it fast.

mod common;

use std::path::PathBuf;
use std::process::Output;

use common::{railview, scratch_dir, stderr};

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
