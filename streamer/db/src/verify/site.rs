//! The browser viewer's files beside a database ([`super::VerifyOptions::site`]).

use std::ffi::OsString;
use std::fs;
use std::path::Path;

use super::{problem, Report};

/// A note for each site file the directory lacks (a database need not carry a viewer).
pub(super) fn note_absent(
    dir: &Path,
    site: &[(&str, &[u8])],
    names: &[OsString],
    report: &mut Report,
) {
    for &(name, _) in site {
        if !names.iter().any(|n| n == name) {
            report.notes.push(problem(
                dir.join(name),
                "absent: no browser viewer beside the database for a static host (`railview \
                 build` writes it)"
                    .into(),
            ));
        }
    }
}

/// A file of the browser viewer: exactly the bytes this program writes. Read whole only when
/// its size matches, so a huge file costs nothing.
pub(super) fn check_file(path: &Path, want: &[u8], report: &mut Report) {
    let same = match fs::metadata(path) {
        Ok(m) if m.is_file() && m.len() == want.len() as u64 => match fs::read(path) {
            Ok(bytes) => bytes == want,
            Err(e) => {
                report.problems.push(problem(path.into(), e.to_string()));
                return;
            }
        },
        Ok(_) => false,
        Err(e) => {
            report.problems.push(problem(path.into(), e.to_string()));
            return;
        }
    };
    if same {
        report.site_files_checked += 1;
    } else {
        report.problems.push(problem(
            path.into(),
            "differs from the browser viewer this railview writes: changed, damaged, or \
             written by another version (a static host would serve it as it is; `railview \
             build` again, or `railview verify --rewrite-site`, writes this one)"
                .into(),
        ));
    }
}
