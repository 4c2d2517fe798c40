//! `railview eval` from the command line: bad input fails with a message naming the flag
//! before anything is rendered or written.

mod common;

use common::{railview, scratch_path, stderr};

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
