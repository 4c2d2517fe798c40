//! Removing the objects of an earlier build that a database's manifest no longer references.

use std::fs;
use std::path::Path;

use super::{verify, DbError};

/// What [`prune`] removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pruned {
    pub objects: usize,
    pub bytes: u64,
}

/// Removes the objects the manifest does not reference (those of an earlier build into the
/// same directory, whose manifest the last build replaced), so the directory holds the
/// database and nothing else. Only an intact database is pruned: with any problem (a missing
/// or damaged object, a manifest that cannot be read) nothing is removed and the first
/// problem is the error. The caller must not be writing `dir`: the directory's lock is held
/// while removing.
pub fn prune(dir: &Path) -> Result<Pruned, DbError> {
    let report = verify(dir)?;
    if let Some(p) = report.problems.first() {
        return Err(DbError::format(
            &p.path,
            format!("{} (nothing pruned: the database is not intact)", p.what),
        ));
    }
    let _lock = super::lock_dir(dir)?;
    let mut pruned = Pruned::default();
    for (path, size) in &report.unreferenced {
        fs::remove_file(path).map_err(|e| DbError::io(path, e))?;
        pruned.objects += 1;
        pruned.bytes += size;
    }
    Ok(pruned)
}
