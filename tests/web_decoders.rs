//! The browser viewer's decoders under Node's test runner (`viewer/web/test/`): the PTM,
//! mesh, table and BLAKE3 code of the page against the vectors the Rust codec writes
//! (`streamer/db/tests/web_vectors.rs`), whole, cut short and damaged. Needs `node` (18 or
//! later; `scripts/test.sh` installs Debian's `nodejs`); `RAILVIEW_SKIP_NODE_TESTS=1` marks
//! it ignored. Node runs tests only: the viewer itself needs none.

use std::process::Command;

#[test]
#[cfg_attr(
    railview_skip_node,
    ignore = "RAILVIEW_SKIP_NODE_TESTS=1: Node.js is not available"
)]
fn the_browser_decoders_pass_their_tests_under_node() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/viewer/web/test");
    let tests: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".test.mjs"))
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    assert!(!tests.is_empty(), "no tests in {dir}");
    let out = Command::new("node")
        .arg("--test")
        .args(&tests)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "node: {e} (apt-get install nodejs, or set RAILVIEW_SKIP_NODE_TESTS=1 to mark this test ignored)"
            )
        });
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "node --test failed:\n{report}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The runner found and passed the tests (it exits 0 with none).
    let passed = report
        .lines()
        .find_map(|l| l.strip_prefix("# pass "))
        .and_then(|n| n.trim().parse::<u32>().ok())
        .unwrap_or(0);
    assert!(passed >= 20, "only {passed} tests passed:\n{report}");
}
