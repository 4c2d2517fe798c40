//! The size limits ARCHITECTURE.md states for code outside tests: no function over
//! [`MAX_FUNCTION_LINES`] lines, no file over [`MAX_FILE_LINES`] lines, and the binary's
//! `src/` at most [`MAX_BINARY_LINES`] lines in all.
//!
//! The sources are formatted by `cargo fmt` (checked by the test command), so a function
//! starts at a line holding `fn NAME` and ends at the first later line that is its own
//! indentation followed by `}`. A file's length stops at its `#[cfg(test)] mod tests`.
//! Test files (`tests/`, `benches/`, `examples/`, `tests.rs`) are not counted.

use std::path::{Path, PathBuf};

const MAX_FUNCTION_LINES: usize = 150;
const MAX_FILE_LINES: usize = 800;
const MAX_BINARY_LINES: usize = 3500;

/// The workspace root (these tests belong to the root package).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `.rs` file under `dir` that is not a test, bench or example, skipping build outputs.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            let skipped = [
                "target",
                "tests",
                "benches",
                "examples",
                "fuzz",
                "node_modules",
            ];
            if !name.starts_with('.') && !skipped.contains(&name.as_str()) {
                sources(&path, out);
            }
        } else if name.ends_with(".rs") && name != "tests.rs" && !is_build_script(&path) {
            out.push(path);
        }
    }
}

/// A package's build script (`build.rs` beside its `Cargo.toml`), not a module named `build`.
fn is_build_script(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n == "build.rs")
        && path
            .parent()
            .is_some_and(|dir| dir.join("Cargo.toml").is_file())
}

/// The lines of a file up to its unit-test module.
fn code_lines(text: &str) -> Vec<&str> {
    let lines: Vec<&str> = text.lines().collect();
    let end = lines
        .windows(2)
        .position(|w| w[0].trim() == "#[cfg(test)]" && w[1].starts_with("mod "))
        .unwrap_or(lines.len());
    lines[..end].to_vec()
}

/// `(name, first line (1-based), length)` of every function with a body.
fn functions(lines: &[&str]) -> Vec<(String, usize, usize)> {
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let indent = &line[..line.len() - line.trim_start().len()];
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some(at) = words.iter().position(|w| *w == "fn") else {
            continue;
        };
        let before_ok = words[..at].iter().all(|w| {
            w.starts_with("pub") || ["const", "async", "unsafe", "extern", "\"C\""].contains(w)
        });
        if !before_ok || line.trim_end().ends_with(';') || line.trim_start().starts_with("//") {
            continue;
        }
        let name: String = words
            .get(at + 1)
            .map(|w| {
                w.chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect()
            })
            .unwrap_or_default();
        let opens = line.matches('{').count();
        if opens > 0 && opens == line.matches('}').count() {
            out.push((name, i + 1, 1));
            continue;
        }
        let close = format!("{indent}}}");
        if let Some(len) = lines[i + 1..].iter().position(|l| *l == close) {
            out.push((name, i + 1, len + 2));
        }
    }
    out
}

#[test]
fn functions_and_files_stay_within_the_stated_limits() {
    let root = root();
    let mut files = Vec::new();
    sources(&root, &mut files);
    files.sort();
    assert!(files.len() > 50, "found only {} source files", files.len());
    let mut faults = Vec::new();
    let mut binary_lines = 0;
    for path in &files {
        let text = std::fs::read_to_string(path).expect("source file readable");
        let lines = code_lines(&text);
        let rel = path
            .strip_prefix(&root)
            .unwrap_or(path)
            .display()
            .to_string();
        if rel.starts_with("src/") {
            binary_lines += text.lines().count();
        }
        if lines.len() > MAX_FILE_LINES {
            faults.push(format!(
                "{rel}: {} lines (at most {MAX_FILE_LINES})",
                lines.len()
            ));
        }
        for (name, at, len) in functions(&lines) {
            if len > MAX_FUNCTION_LINES {
                faults.push(format!(
                    "{rel}:{at}: fn {name} is {len} lines (at most {MAX_FUNCTION_LINES})"
                ));
            }
        }
    }
    if binary_lines > MAX_BINARY_LINES {
        faults.push(format!(
            "src/: {binary_lines} lines in all (at most {MAX_BINARY_LINES}: the binary is glue)"
        ));
    }
    assert!(
        faults.is_empty(),
        "over the size limits:\n{}",
        faults.join("\n")
    );
}

#[test]
fn the_scanner_measures_a_function_and_stops_at_the_test_module() {
    let text = "fn z() {}\nfn a() {\n    let x = 1;\n}\n\npub(crate) fn b(\n    y: u8,\n) -> u8 {\n    y\n}\n#[cfg(test)]\nmod tests {\n    fn c() {}\n}\n";
    let lines = code_lines(text);
    assert_eq!(lines.len(), 10);
    let f = functions(&lines);
    let expected = [("z", 1, 1), ("a", 2, 3), ("b", 6, 5)];
    let expected: Vec<_> = expected
        .iter()
        .map(|(n, a, l)| (n.to_string(), *a, *l))
        .collect();
    assert_eq!(f, expected);
}
