//! Starting a stage's directory from another's files without copying them.

use std::io;
use std::path::Path;

/// Recreate the tree under `src` at `dst` with hard links to its files (copies where the
/// file system has no hard links, e.g. across devices). `dst` must not exist. Every railview
/// stage writes whole files under new names and renames them into place, so a linked file is
/// replaced, never changed, and `src` stays as it was.
pub fn link_tree(src: &Path, dst: &Path) -> io::Result<u64> {
    if dst.exists() {
        return Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            format!("{} already exists", dst.display()),
        ));
    }
    std::fs::create_dir_all(dst)?;
    let mut files = 0;
    for entry in std::fs::read_dir(src)? {
        let entry = entry?;
        let from = entry.path();
        let to = dst.join(entry.file_name());
        let kind = entry.file_type()?;
        if kind.is_dir() {
            files += link_tree(&from, &to)?;
        } else if kind.is_file() {
            if std::fs::hard_link(&from, &to).is_err() {
                std::fs::copy(&from, &to)?;
            }
            files += 1;
        }
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linked_files_are_replaced_not_changed() {
        let root = std::env::temp_dir().join(format!("railview-link-{}", std::process::id()));
        std::fs::remove_dir_all(&root).ok();
        let (a, b) = (root.join("a"), root.join("b"));
        std::fs::create_dir_all(a.join("sub")).unwrap();
        std::fs::write(a.join("x"), b"one").unwrap();
        std::fs::write(a.join("sub/y"), b"two").unwrap();
        assert_eq!(link_tree(&a, &b).unwrap(), 2);
        assert_eq!(std::fs::read(b.join("sub/y")).unwrap(), b"two");
        // A stage replaces a file by renaming a new one over it: the source keeps its own.
        std::fs::write(b.join(".x.tmp"), b"three").unwrap();
        std::fs::rename(b.join(".x.tmp"), b.join("x")).unwrap();
        assert_eq!(std::fs::read(a.join("x")).unwrap(), b"one");
        assert!(link_tree(&a, &b).is_err());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
