//! Files written whole, with any number of writers at once.
//!
//! Every file railview writes goes to a temporary file in the directory it belongs in, is
//! flushed to disk and renamed over its final name: a reader sees the old file or the new one,
//! never a part, and a killed writer leaves at most a temporary file behind.
//!
//! The temporary name is `.{name}.tmp.{random}`, created with `O_EXCL` (the `tempfile`
//! crate), so it is unique across threads, processes, PID namespaces and hosts that share a
//! file system. A name made from the process id is not: every pod of a Kubernetes Job runs
//! its command as PID 1, and two such writers of one file would share the temporary and
//! rename it from under each other. [`is_temporary`] recognises the leftovers of a killed
//! writer (a leading dot and `.tmp.`), which `railview verify` reports.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// What every temporary name holds after the final file name.
pub const TEMP_MARK: &str = ".tmp.";

/// Random characters in a temporary or unique name (62 symbols each: 47 bits).
const RANDOM_CHARS: usize = 8;

fn builder<'a>(prefix: &'a str, suffix: &'a str) -> tempfile::Builder<'a, 'a> {
    let mut b = tempfile::Builder::new();
    b.prefix(prefix).suffix(suffix).rand_bytes(RANDOM_CHARS);
    // `tempfile` creates files readable by the owner only; outputs are shared (a web server,
    // the merge job of another user), so ask for what `File::create` gives: 0666 less umask.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(fs::Permissions::from_mode(0o666));
    }
    b
}

fn parent_and_name(path: &Path) -> io::Result<(&Path, String)> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{}: not a file name", path.display()),
        )
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    Ok((dir, name.to_string_lossy().into_owned()))
}

/// Write `path` whole: `fill` writes the content into a fresh temporary file beside it, which
/// is synced and renamed over `path`. Creates the parent directory. On any error the
/// temporary file is removed and `path` is as it was.
pub fn write_with(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> io::Result<()> {
    let (dir, name) = parent_and_name(path)?;
    fs::create_dir_all(dir)?;
    let prefix = format!(".{name}{TEMP_MARK}");
    let mut tmp = builder(&prefix, "").tempfile_in(dir)?;
    fill(tmp.as_file_mut())?;
    tmp.as_file_mut().flush()?;
    tmp.as_file().sync_all()?;
    // On failure the returned temporary file is dropped, which removes it.
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// Write `bytes` to `path` whole, as [`write()`] does but without flushing it to the disk: for
/// the many small files of a step that ends with [`sync_file_system`] before anything that
/// names them is written (a database's objects before its manifest). After a crash before
/// that flush such a file may hold other bytes than written, so a reader that reuses one
/// checks its content.
pub fn write_unsynced(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let (dir, name) = parent_and_name(path)?;
    fs::create_dir_all(dir)?;
    let prefix = format!(".{name}{TEMP_MARK}");
    let mut tmp = builder(&prefix, "").tempfile_in(dir)?;
    tmp.as_file_mut().write_all(bytes)?;
    tmp.as_file_mut().flush()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// Flushes everything written to the file system that holds `dir` to the disk (Linux's
/// `syncfs`; elsewhere every file under `dir`, one by one).
pub fn sync_file_system(dir: &Path) -> io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        let handle = File::open(dir)?;
        rustix::fs::syncfs(&handle)?;
        Ok(())
    }
    #[cfg(not(target_os = "linux"))]
    {
        fn walk(dir: &Path) -> io::Result<()> {
            for e in fs::read_dir(dir)? {
                let e = e?;
                if e.file_type()?.is_dir() {
                    walk(&e.path())?;
                } else {
                    File::open(e.path())?.sync_all()?;
                }
            }
            Ok(())
        }
        walk(dir)
    }
}

/// Write `bytes` to `path` whole (see [`write_with`]).
pub fn write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_with(path, |f| f.write_all(bytes))
}

/// Write `bytes` to `path` whole unless it already holds exactly these bytes; returns whether
/// it wrote. For a file that several writers produce with the same content (the track copy
/// every shard of a prerender writes): whichever writes last, the bytes are the same, and
/// once the file is there nobody rewrites it.
pub fn write_if_changed(path: &Path, bytes: &[u8]) -> io::Result<bool> {
    match fs::read(path) {
        Ok(old) if old == bytes => Ok(false),
        Ok(_) => write(path, bytes).map(|()| true),
        Err(e) if e.kind() == io::ErrorKind::NotFound => write(path, bytes).map(|()| true),
        Err(e) => Err(e),
    }
}

/// Whether `file_name` is a temporary file of [`write_with`] (one a killed writer left).
pub fn is_temporary(file_name: &str) -> bool {
    file_name.starts_with('.') && file_name.contains(TEMP_MARK)
}

/// Remove the temporary files killed writers left directly in `dir` (not below it); returns
/// how many. For a writer about to rewrite what it owns alone (a sample of one shard): a
/// writer still running in `dir` would lose its temporary file and fail.
pub fn remove_temporaries(dir: &Path) -> io::Result<usize> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut removed = 0;
    for e in entries {
        let e = e?;
        if is_temporary(&e.file_name().to_string_lossy()) && e.file_type()?.is_file() {
            match fs::remove_file(e.path()) {
                Ok(()) => removed += 1,
                Err(err) if err.kind() == io::ErrorKind::NotFound => {}
                Err(err) => return Err(err),
            }
        }
    }
    Ok(removed)
}

/// Create a new file `{prefix}{random}{suffix}` in `dir` (created if needed) that no other
/// writer anywhere has: for files one run owns alone, such as its run log. The file is kept.
pub fn create_unique(dir: &Path, prefix: &str, suffix: &str) -> io::Result<(File, PathBuf)> {
    fs::create_dir_all(dir)?;
    let (file, path) = builder(prefix, suffix)
        .tempfile_in(dir)?
        .keep()
        .map_err(|e| e.error)?;
    Ok((file, path))
}

/// Create `dir` if needed and check that a file can be created in it (a uniquely named probe,
/// removed again).
pub fn check_writable(dir: &Path) -> io::Result<()> {
    fs::create_dir_all(dir)?;
    let probe = builder(&format!(".write-test{TEMP_MARK}"), "").tempfile_in(dir)?;
    probe.close()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Barrier};

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("railview-files-{name}-{}", std::process::id()));
        fs::remove_dir_all(&d).ok();
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn write_replaces_whole_and_leaves_no_temporary() {
        let d = scratch("write");
        let p = d.join("sub").join("x.json");
        write(&p, b"first").unwrap();
        write(&p, b"second, longer").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"second, longer");
        assert_eq!(names(&d.join("sub")), ["x.json"]);
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn failed_fill_keeps_the_old_file_and_removes_the_temporary() {
        let d = scratch("fail");
        let p = d.join("keep.bin");
        write(&p, b"old").unwrap();
        let e = write_with(&p, |f| {
            f.write_all(b"half")?;
            Err(io::Error::other("disk full"))
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "disk full");
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert_eq!(names(&d), ["keep.bin"]);
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn many_writers_of_one_file_never_fail() {
        // Writers that would all have had the same process id: threads of one process.
        let d = scratch("many");
        let p = d.join("track.toml");
        let n = 16;
        let barrier = Arc::new(Barrier::new(n));
        let handles: Vec<_> = (0..n)
            .map(|i| {
                let (p, barrier) = (p.clone(), barrier.clone());
                std::thread::spawn(move || {
                    barrier.wait();
                    for round in 0..20 {
                        write(&p, format!("writer {i} round {round}\n").as_bytes()).unwrap();
                        write_if_changed(&p, b"same\n").unwrap();
                    }
                })
            })
            .collect();
        for h in handles {
            h.join().unwrap();
        }
        assert_eq!(names(&d), ["track.toml"]);
        let text = fs::read_to_string(&p).unwrap();
        assert!(text == "same\n" || text.starts_with("writer "), "{text}");
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn write_if_changed_skips_identical_bytes() {
        let d = scratch("changed");
        let p = d.join("t.toml");
        assert!(write_if_changed(&p, b"a").unwrap());
        let before = fs::metadata(&p).unwrap().modified().unwrap();
        assert!(!write_if_changed(&p, b"a").unwrap());
        assert_eq!(fs::metadata(&p).unwrap().modified().unwrap(), before);
        assert!(write_if_changed(&p, b"b").unwrap());
        assert_eq!(fs::read(&p).unwrap(), b"b");
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn temporary_names_are_recognised() {
        let d = scratch("names");
        let p = d.join("manifest.json");
        let mut seen = None;
        write_with(&p, |_| {
            seen = Some(names(&d));
            Ok(())
        })
        .unwrap();
        let during = seen.unwrap();
        assert_eq!(during.len(), 1);
        assert!(is_temporary(&during[0]), "{during:?}");
        assert!(during[0].starts_with(".manifest.json.tmp."), "{during:?}");
        assert!(!is_temporary("manifest.json"));
        assert!(!is_temporary("tmp.json"));
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn leftovers_of_killed_writers_are_removed() {
        let d = scratch("leftovers");
        fs::write(d.join(".color.png.tmp.AbCdEf12"), b"half").unwrap();
        fs::write(d.join("color.png"), b"whole").unwrap();
        fs::create_dir(d.join(".x.tmp.dir")).unwrap();
        assert_eq!(remove_temporaries(&d).unwrap(), 1);
        assert_eq!(names(&d), [".x.tmp.dir", "color.png"]);
        assert_eq!(remove_temporaries(&d.join("absent")).unwrap(), 0);
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn unique_files_differ_and_are_kept() {
        let d = scratch("unique");
        let (_, a) = create_unique(&d.join("runs"), "prerender-", ".jsonl").unwrap();
        let (_, b) = create_unique(&d.join("runs"), "prerender-", ".jsonl").unwrap();
        assert_ne!(a, b);
        assert!(a.is_file() && b.is_file());
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with("prerender-") && name.ends_with(".jsonl"));
        assert!(!is_temporary(&name));
        fs::remove_dir_all(&d).ok();
    }

    #[cfg(unix)]
    #[test]
    fn written_files_are_readable_by_others_as_the_umask_allows() {
        use std::os::unix::fs::PermissionsExt;
        let d = scratch("mode");
        let p = d.join("object");
        write(&p, b"x").unwrap();
        let plain = d.join("plain");
        File::create(&plain).unwrap();
        let mode = |p: &Path| fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&p), mode(&plain));
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn writability_check_leaves_nothing() {
        let d = scratch("probe");
        check_writable(&d.join("new")).unwrap();
        assert!(names(&d.join("new")).is_empty());
        assert!(check_writable(Path::new("/proc/railview-cannot-exist")).is_err());
        fs::remove_dir_all(&d).ok();
    }
}
