//! `railview verify` and the browser viewer's files beside a database: a static host serves
//! them as they are, so a changed page is damage, named; `--rewrite-site` puts this railview's
//! back; an absent one is only a note (a database need not carry a viewer).

mod common;

use common::{railview, scratch_dir, small_castle, text};

#[test]
fn verify_names_a_changed_viewer_file_and_rewrite_site_restores_it() {
    let dir = scratch_dir("cli-verify", "site");
    let db = small_castle(&dir, 16);
    let dbs = db.to_str().unwrap();
    let o = railview(&["verify", dbs]);
    assert!(o.status.success(), "{}", text(&o));
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    let line = out
        .lines()
        .find(|l| l.contains("of the browser viewer's"))
        .unwrap_or_else(|| panic!("{out}"));
    let counts: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(counts[0], counts[5], "every viewer file checked: {line}");
    assert!(!out.contains("not part of a database"), "{out}");

    // A page changed on the host: damage, naming the file; exit status 1.
    let main_js = db.join("main.js");
    let mut body = std::fs::read(&main_js).unwrap();
    body.extend_from_slice(b"\nfetch('https://elsewhere.example/');\n");
    std::fs::write(&main_js, &body).unwrap();
    let o = railview(&["verify", dbs]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        out.lines()
            .any(|l| l.starts_with("DAMAGED") && l.contains("main.js") && l.contains("differs")),
        "{out}"
    );

    // --rewrite-site writes this railview's viewer back.
    let o = railview(&["verify", dbs, "--rewrite-site"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!std::fs::read(&main_js).unwrap().ends_with(b"example/');\n"));

    // A database without its viewer is intact; the absence is a note.
    std::fs::remove_file(db.join("index.html")).unwrap();
    let o = railview(&["verify", dbs]);
    assert!(o.status.success(), "{}", text(&o));
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        out.lines()
            .any(|l| l.starts_with("note:") && l.contains("index.html") && l.contains("absent")),
        "{out}"
    );
    let _ = std::fs::remove_dir_all(dir);
}
