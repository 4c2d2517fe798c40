//! `verify`: checks every file of a database and names each damaged or missing one.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use tracks::manifest::{object_rel_path, Manifest, ObjectRef, PackRange, PtmRef, SegmentEntry};

use super::split::{assemble, decode_ach, decode_table, TopManifest, ViewTable};
use super::{
    gunzip_limited, gzip, hash_hex, hash_matches, parse_root, DbError, MANIFEST_FILE,
    MANIFEST_GZ_FILE, MANIFEST_HASH_FILE,
};
use codec::ptm;

mod site;

/// One thing wrong with a database.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Problem {
    /// The file at fault.
    pub path: PathBuf,
    pub what: String,
}

/// The result of [`verify`].
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Report {
    /// Distinct objects the manifest references.
    pub objects_referenced: usize,
    /// Files under `objects/` whose content was hashed.
    pub files_checked: usize,
    pub bytes_checked: u64,
    /// PTM level groups whose range hash was checked.
    pub level_ranges_checked: usize,
    /// Viewpoint tables read, hash-checked and decoded.
    pub tables_checked: usize,
    /// PTMs decoded to their finest level ([`VerifyOptions::decode`]; 0 otherwise).
    pub ptms_decoded: usize,
    /// Meshes decoded ([`VerifyOptions::decode`]; 0 otherwise).
    pub meshes_decoded: usize,
    /// Damage: the database is intact only when this is empty.
    pub problems: Vec<Problem>,
    /// Harmless findings (unreferenced objects, files that are not part of a database, site
    /// files absent).
    pub notes: Vec<Problem>,
    /// Site files ([`VerifyOptions::site`]) found with exactly their bytes.
    pub site_files_checked: usize,
    /// Temporary files of interrupted writes (a leading `.` and a `.tmp` marker), in the
    /// database's directory, `objects/` or `objects/HH/`: harmless to readers, but not part
    /// of the database ([`VerifyOptions::remove_temp`] removes them).
    pub stray: Vec<Problem>,
    /// Stray temporary files removed ([`VerifyOptions::remove_temp`]).
    pub removed: Vec<PathBuf>,
    /// Object files the manifest does not reference, with their sizes.
    pub unreferenced: Vec<(PathBuf, u64)>,
}

impl Report {
    pub fn is_intact(&self) -> bool {
        self.problems.is_empty()
    }
}

/// What [`verify_with`] checks beyond the files.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VerifyOptions<'a> {
    /// Decode every PTM to its finest level and every mesh (the hashes say the bytes are the
    /// ones written, not that they decode), and check the rule of formats 5 on: colour 0
    /// under every texel with alpha 0 ([`super::clear_masked`]; readers divide coarse levels
    /// by their alpha).
    pub decode: bool,
    /// Remove the stray temporary files found ([`Report::stray`]).
    pub remove_temp: bool,
    /// The files a static host serves beside the database (the browser viewer: name and
    /// bytes, as this program writes them). Each one present must hold exactly these bytes
    /// (a changed page is damage: a host would serve it); one absent is a note.
    pub site: &'a [(&'a str, &'a [u8])],
}

/// Checks the manifest (its values against the limits of [`tracks::limits`] too), its
/// checksum, its gzip copy (when present: it must decompress to exactly manifest.json's
/// bytes), every object's size and hash (referenced or not), and every PTM level range's
/// hash; lists stray temporary files. `Err` only when `dir` itself cannot be read.
pub fn verify(dir: &Path) -> Result<Report, DbError> {
    verify_with(dir, VerifyOptions::default())
}

/// [`verify`], with the checks of `opts`.
pub fn verify_with(dir: &Path, opts: VerifyOptions) -> Result<Report, DbError> {
    let mut report = Report::default();
    check_top_dir(dir, opts.site, &mut report)?;
    let (top, pieces) = match read_top_checked(dir, &mut report) {
        Some((top, pieces)) => (Some(top), pieces),
        None => (None, Vec::new()),
    };
    let decode = opts.decode.then(|| {
        top.as_ref()
            .is_some_and(|t| t.coarse_levels_premultiplied())
    });
    let (table_refs, tables) = match &top {
        Some(top) => check_tables(dir, top, &mut report),
        None => (Vec::new(), Vec::new()),
    };
    let manifest: Option<Manifest> = top.as_ref().map(|top| {
        let refs: Vec<Option<&ViewTable>> = tables.iter().map(|t| t.as_ref()).collect();
        assemble(top, &refs)
    });
    let table_refs: Vec<ObjectRef> = pieces.into_iter().chain(table_refs).collect();
    let wanted = wanted_objects(dir, &table_refs, manifest.as_ref(), &mut report);
    check_objects(dir, &wanted, decode, &mut report);
    remove_stray(dir, opts, &mut report);
    Ok(report)
}

/// The database's own directory: the manifest's files, objects/ and the site's files with
/// their bytes, nothing else.
fn check_top_dir(dir: &Path, site: &[(&str, &[u8])], report: &mut Report) -> Result<(), DbError> {
    let top_level = fs::read_dir(dir).map_err(|e| DbError::io(dir, e))?;
    let mut entries: Vec<_> = top_level.filter_map(Result::ok).collect();
    entries.sort_by_key(|e| e.file_name());
    let names: Vec<std::ffi::OsString> = entries.iter().map(|e| e.file_name()).collect();
    site::note_absent(dir, site, &names, report);
    for e in entries {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(&(_, want)) = site.iter().find(|(n, _)| *n == name) {
            site::check_file(&e.path(), want, report);
        } else if super::is_temp_name(&name) {
            report.stray.push(problem(e.path(), TEMP_NOTE.into()));
        } else if ![
            MANIFEST_FILE,
            MANIFEST_HASH_FILE,
            MANIFEST_GZ_FILE,
            "objects",
        ]
        .contains(&name.as_str())
        {
            report
                .notes
                .push(problem(e.path(), "not part of a database".into()));
        }
    }
    Ok(())
}

/// The root, its gzip copy and its checksum file, and every piece of the index: the top
/// manifest when all of it reads, with the pieces' references.
fn read_top_checked(dir: &Path, report: &mut Report) -> Option<(TopManifest, Vec<ObjectRef>)> {
    let manifest_path = dir.join(MANIFEST_FILE);
    let hash_path = dir.join(MANIFEST_HASH_FILE);
    let manifest_bytes = fs::read(&manifest_path);
    check_manifest_gz(dir, manifest_bytes.as_deref().ok(), report);
    let bytes = match manifest_bytes {
        Err(e) => {
            report
                .problems
                .push(problem(manifest_path.clone(), e.to_string()));
            return None;
        }
        Ok(bytes) => bytes,
    };
    match fs::read_to_string(&hash_path) {
        Err(e) => report.problems.push(problem(
            hash_path.clone(),
            format!("{e} (the manifest cannot be checked)"),
        )),
        Ok(text)
            if object_rel_path(text.trim_end_matches('\n')).is_none() || !text.ends_with('\n') =>
        {
            report.problems.push(problem(
                hash_path.clone(),
                "not a BLAKE3 hex line: the file is damaged".into(),
            ))
        }
        Ok(text) => {
            let got = hash_hex(&bytes);
            if text.trim_end() != got {
                let what = format!("manifest.json hashes to {got}, manifest.json.blake3 says {}: one of the two is damaged", text.trim_end());
                report
                    .problems
                    .push(problem(manifest_path.clone(), what.clone()));
                report.problems.push(problem(hash_path.clone(), what));
            }
        }
    }
    let root = parse_root(&manifest_path, &bytes)
        .map_err(|e| (report.problems).push(problem(manifest_path.clone(), strip_path(&e))))
        .ok()?;
    // The pieces of the index: each one read is referenced; a bad one is named by its file.
    let mut pieces: Vec<ObjectRef> = Vec::new();
    let mut failed: Option<PathBuf> = None;
    let got = super::index::read_all(root, |r: &ObjectRef| {
        pieces.push(r.clone());
        let at = r.rel_path().map(|rel| dir.join(rel));
        super::read_piece(dir, r).inspect_err(|_| failed = at)
    });
    got.map(|top| (top, pieces))
        .map_err(|e| {
            report
                .problems
                .push(problem(failed.unwrap_or(manifest_path), e))
        })
        .ok()
}

/// Every viewpoint's table: present, hash, decode; a bad one is named by viewpoint. Returns
/// the objects the top names (tables and ACH objects) and the tables by viewpoint.
fn check_tables(
    dir: &Path,
    top: &TopManifest,
    report: &mut Report,
) -> (Vec<ObjectRef>, Vec<Option<ViewTable>>) {
    let mut table_refs: Vec<ObjectRef> = Vec::new();
    let mut tables: Vec<Option<ViewTable>> = Vec::new();
    for v in &top.viewpoints {
        table_refs.push(v.table.clone());
        table_refs.extend(v.ach.clone());
        let (path, got) = check_table(dir, &v.table, v.index);
        match got {
            Ok(mut table) => {
                report.tables_checked += 1;
                if let Some(ach) = &v.ach {
                    match check_ach(dir, ach, v.index) {
                        (_, Ok(segments)) => table.segments = segments,
                        (path, Err(what)) => report.problems.push(problem(
                            path,
                            format!("ACH lists of viewpoint {}: {what}", v.index),
                        )),
                    }
                }
                tables.push(Some(table));
            }
            Err(what) => {
                report.problems.push(problem(
                    path,
                    format!("table of viewpoint {}: {what}", v.index),
                ));
                tables.push(None);
            }
        }
    }
    (table_refs, tables)
}

/// An object the manifest references: its size, the PTMs and the mesh ranges inside it.
type Wanted<'a> = (u64, Vec<&'a PtmRef>, Vec<&'a PackRange>);

/// Every object the manifest references, with the PTM ranges inside it; bad references are
/// problems of the manifest.
fn wanted_objects<'a>(
    dir: &Path,
    table_refs: &'a [ObjectRef],
    manifest: Option<&'a Manifest>,
    report: &mut Report,
) -> BTreeMap<String, Wanted<'a>> {
    let mut wanted: BTreeMap<String, Wanted> = BTreeMap::new();
    let mut bad_refs = Vec::new();
    for obj in table_refs {
        if object_rel_path(&obj.hash).is_none() {
            bad_refs.push(format!("invalid table hash {:?}", obj.hash));
            continue;
        }
        wanted
            .entry(obj.hash.clone())
            .or_insert((obj.size, Vec::new(), Vec::new()));
    }
    if let Some(m) = manifest {
        for_each_object(m, &mut |obj, ptm, mesh| {
            if object_rel_path(&obj.hash).is_none() {
                bad_refs.push(format!("invalid object hash {:?}", obj.hash));
                return;
            }
            let e = wanted
                .entry(obj.hash.clone())
                .or_insert((obj.size, Vec::new(), Vec::new()));
            if e.0 != obj.size {
                bad_refs.push(format!(
                    "object {} listed with sizes {} and {}",
                    obj.hash, e.0, obj.size
                ));
            }
            // A payload stored once is checked once, however many tiles point at it.
            if let Some(p) = ptm {
                if !e.1.iter().any(|q| q.levels == p.levels) {
                    e.1.push(p);
                }
            }
            if let Some(r) = mesh {
                if !e.2.contains(&r) {
                    e.2.push(r);
                }
            }
        });
    }
    for what in bad_refs {
        report.problems.push(problem(dir.join(MANIFEST_FILE), what));
    }
    report.objects_referenced = wanted.len();
    wanted
}

/// Every file under objects/: its name, place, hash and size, and the ranges inside the
/// objects the manifest references (decoded when `decode` is `Some(cleared)`); then the
/// unreferenced and the missing objects.
fn check_objects(
    dir: &Path,
    wanted: &BTreeMap<String, Wanted>,
    decode: Option<bool>,
    report: &mut Report,
) {
    let objects = dir.join("objects");
    let mut seen = BTreeMap::new();
    let mut unreferenced = Vec::new();
    match fs::read_dir(&objects) {
        Err(e) => {
            if !wanted.is_empty() || e.kind() != std::io::ErrorKind::NotFound {
                report
                    .problems
                    .push(problem(objects.clone(), e.to_string()));
            }
        }
        Ok(entries) => {
            let mut subdirs: Vec<_> = entries.filter_map(Result::ok).collect();
            subdirs.sort_by_key(|e| e.file_name());
            for sub in subdirs {
                let sub_path = sub.path();
                if super::is_temp_name(&sub.file_name().to_string_lossy()) {
                    report.stray.push(problem(sub_path, TEMP_NOTE.into()));
                    continue;
                }
                let Ok(files) = fs::read_dir(&sub_path) else {
                    report
                        .notes
                        .push(problem(sub_path, "not a directory of objects".into()));
                    continue;
                };
                let mut files: Vec<_> = files.filter_map(Result::ok).collect();
                files.sort_by_key(|e| e.file_name());
                for f in files {
                    let name = f.file_name().to_string_lossy().into_owned();
                    let path = f.path();
                    match check_object_file(dir, &path, &name, wanted, decode, report) {
                        ObjectFile::Skipped => {}
                        ObjectFile::Unreferenced => {
                            let size = f.metadata().map_or(0, |m| m.len());
                            report.unreferenced.push((path.clone(), size));
                            unreferenced.push(path);
                            seen.insert(name, ());
                        }
                        ObjectFile::Referenced => {
                            seen.insert(name, ());
                        }
                    }
                }
            }
        }
    }
    // Unreferenced objects are harmless (a writer without a stage keeps each tile's own
    // objects beside the packs; older builds left them): listed one by one when few, counted
    // when many.
    if unreferenced.len() <= 8 {
        for path in unreferenced {
            report
                .notes
                .push(problem(path, "not referenced by the manifest".into()));
        }
    } else {
        report.notes.push(problem(
            objects.clone(),
            format!(
                "{} objects not referenced by the manifest (tiles' own objects of a \
                 writer without a stage, or left from earlier builds)",
                unreferenced.len()
            ),
        ));
    }
    for hash in wanted.keys() {
        if !seen.contains_key(hash) {
            let rel = object_rel_path(hash).expect("checked above");
            report.problems.push(problem(
                dir.join(rel),
                "missing (referenced by the manifest)".into(),
            ));
        }
    }
}

/// What [`check_object_file`] made of a file under objects/.
enum ObjectFile {
    /// A temporary file, a misnamed or misplaced one, or one that could not be read.
    Skipped,
    /// An object the manifest does not reference.
    Unreferenced,
    /// An object the manifest references.
    Referenced,
}

/// One file `name` at `path` under objects/: its name, place and hash, and, when the
/// manifest references it, its size and the ranges inside it.
fn check_object_file(
    dir: &Path,
    path: &Path,
    name: &str,
    wanted: &BTreeMap<String, Wanted>,
    decode: Option<bool>,
    report: &mut Report,
) -> ObjectFile {
    let path = path.to_path_buf();
    if super::is_temp_name(name) {
        report.stray.push(problem(path, TEMP_NOTE.into()));
        return ObjectFile::Skipped;
    }
    let Some(rel) = object_rel_path(name) else {
        report
            .problems
            .push(problem(path, "not an object name (64 hex digits)".into()));
        return ObjectFile::Skipped;
    };
    if dir.join(&rel) != path {
        report.problems.push(problem(
            path,
            format!("object stored in the wrong directory (belongs in {rel})"),
        ));
        return ObjectFile::Skipped;
    }
    let bytes = match fs::read(&path) {
        Ok(b) => b,
        Err(e) => {
            report.problems.push(problem(path, e.to_string()));
            return ObjectFile::Skipped;
        }
    };
    report.files_checked += 1;
    report.bytes_checked += bytes.len() as u64;
    let got = hash_hex(&bytes);
    if got != name {
        report.problems.push(problem(
            path.clone(),
            format!("content hash is {got}: the file is damaged"),
        ));
    }
    let Some((size, ptms, meshes)) = wanted.get(name) else {
        return ObjectFile::Unreferenced;
    };
    if bytes.len() as u64 != *size {
        report.problems.push(problem(
            path.clone(),
            format!("size {} but the manifest says {size}", bytes.len()),
        ));
    }
    for p in ptms {
        check_ptm(&path, &bytes, p, report);
        if let Some(cleared) = decode {
            decode_ptm(&path, &bytes, p, cleared, report);
        }
    }
    for r in meshes {
        if check_mesh_range(&path, &bytes, r, report) && decode.is_some() {
            decode_mesh_range(&path, &bytes, r, report);
        }
    }
    ObjectFile::Referenced
}

/// Removes the stray temporary files when `opts` asks for it. Only the holder of the
/// directory's lock may remove them: a build that is writing holds it, and its files in
/// flight are not leftovers.
fn remove_stray(dir: &Path, opts: VerifyOptions, report: &mut Report) {
    if !opts.remove_temp || report.stray.is_empty() {
        return;
    }
    // Held until the files are removed.
    let _lock = match super::lock_dir(dir) {
        Ok(lock) => lock,
        Err(e) => {
            report.problems.push(problem(
                dir.to_path_buf(),
                format!("stray temporary files not removed: {e}"),
            ));
            return;
        }
    };
    for s in &report.stray {
        let gone = if s.path.is_dir() {
            fs::remove_dir_all(&s.path)
        } else {
            fs::remove_file(&s.path)
        };
        match gone {
            Ok(()) => report.removed.push(s.path.clone()),
            Err(e) => report.problems.push(problem(
                s.path.clone(),
                format!("stray temporary file could not be removed: {e}"),
            )),
        }
    }
}

fn problem(path: PathBuf, what: String) -> Problem {
    Problem { path, what }
}

const TEMP_NOTE: &str = "temporary file of an interrupted write (not part of the database)";

/// `manifest.json.gz` must decompress to exactly `manifest` (the bytes of manifest.json, when
/// readable); a missing one is only a note (databases written before it existed).
fn check_manifest_gz(dir: &Path, manifest: Option<&[u8]>, report: &mut Report) {
    let path = dir.join(MANIFEST_GZ_FILE);
    let gz = match fs::read(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            report.notes.push(Problem {
                path,
                what: "absent (a database written before it existed): servers send \
                       manifest.json uncompressed"
                    .into(),
            });
            return;
        }
        Err(e) => {
            report.problems.push(Problem {
                path,
                what: e.to_string(),
            });
            return;
        }
        Ok(gz) => gz,
    };
    // One byte more than manifest.json is enough to tell "longer"; without it, 1 GiB.
    let limit = manifest.map_or(1 << 30, |m| m.len() as u64 + 1);
    // The gzip header's time, flags and OS bytes are outside its CRC: compare them with what
    // the writer puts there, so a flipped byte in them is caught too.
    let header = gzip(b"").unwrap_or_default();
    let what = match (gunzip_limited(&gz, limit), manifest) {
        (Err(e), _) => format!("{e}: the file is damaged"),
        (Ok(_), _) if gz.len() < 10 || gz[..10] != header[..header.len().min(10)] => format!(
            "gzip header {:02x?} differs from the writer's {:02x?}: the file is damaged",
            &gz[..gz.len().min(10)],
            &header[..header.len().min(10)]
        ),
        (Ok(plain), Some(m)) if plain != m => format!(
            "decompresses to {} bytes that differ from manifest.json ({} bytes){}: the file is damaged or stale",
            plain.len(),
            m.len(),
            plain
                .iter()
                .zip(m)
                .position(|(a, b)| a != b)
                .map_or(String::new(), |i| format!(", first at byte {i}"))
        ),
        (Ok(_), _) => return,
    };
    report.problems.push(Problem { path, what });
}

/// Checks each level range of a PTM object and that the PTM header agrees with the manifest.
fn check_ptm(path: &Path, bytes: &[u8], p: &PtmRef, report: &mut Report) {
    let mut push = |what: String| {
        report.problems.push(Problem {
            path: path.to_path_buf(),
            what,
        })
    };
    for (g, l) in p.levels.iter().enumerate() {
        let Some(range) = level_bytes(bytes, l) else {
            push(format!(
                "level group {g}: range {}+{} outside the file",
                l.offset, l.len
            ));
            continue;
        };
        let end = l.offset + l.len;
        if !hash_matches(range, &l.hash) {
            let got = hash_hex(range);
            push(format!(
                "level group {g} (level {}, bytes {}..{end}): hash is {got}, manifest says {}",
                l.level, l.offset, l.hash
            ));
        }
    }
    // The PTM's bytes: the whole object, or (in a pack) the span of its ranges.
    let start = p
        .levels
        .first()
        .map_or(0, |l| l.offset)
        .min(bytes.len() as u64) as usize;
    let end = p
        .levels
        .last()
        .map_or(0, |l| l.offset.saturating_add(l.len))
        .clamp(start as u64, bytes.len() as u64) as usize;
    let span = &bytes[start..end];
    let mut dec = ptm::Decoder::new(ptm::Limits::default());
    let header_len = p
        .levels
        .first()
        .map_or(0, |l| l.len as usize)
        .min(span.len());
    match dec.push(&span[..header_len]) {
        Err(e) => push(format!("PTM header: {e}")),
        Ok(_) => {
            if let Some(h) = dec.header() {
                if (h.width, h.height, h.channels) != (p.width, p.height, p.channels)
                    || p.levels.iter().any(|l| l.level >= h.levels as u32)
                    || p.levels.len() > h.levels as usize
                    || h.file_len() != span.len() as u64
                {
                    push(format!(
                        "PTM header says {}×{}×{} with {} levels and {} bytes; manifest says {}×{}×{} with {} levels",
                        h.width, h.height, h.channels, h.levels, h.file_len(), p.width, p.height, p.channels, p.levels.len()
                    ));
                }
            } else {
                push("PTM header incomplete in level group 0".into());
            }
        }
    }
    report.level_ranges_checked += p.levels.len();
}

/// The bytes of level group `l` inside its object's `bytes`, if the range lies in them.
fn level_bytes<'a>(bytes: &'a [u8], l: &tracks::manifest::LevelRef) -> Option<&'a [u8]> {
    let end = l.offset.checked_add(l.len)?;
    bytes.get(usize::try_from(l.offset).ok()?..usize::try_from(end).ok()?)
}

/// Decode `p`'s level groups in order to its finest level; with `cleared` (format 5) its
/// texels with alpha 0 must hold colour 0. Ranges outside the file were reported by
/// [`check_ptm`] and are not decoded again.
fn decode_ptm(path: &Path, bytes: &[u8], p: &PtmRef, cleared: bool, report: &mut Report) {
    let mut dec = ptm::Decoder::new(ptm::Limits::default());
    for (g, l) in p.levels.iter().enumerate() {
        let Some(range) = level_bytes(bytes, l) else {
            return;
        };
        if let Err(e) = dec.push(range) {
            report.problems.push(Problem {
                path: path.to_path_buf(),
                what: format!(
                    "PTM at bytes {}.. (level group {g}, level {}) does not decode: {e}",
                    p.levels.first().map_or(0, |f| f.offset),
                    l.level
                ),
            });
            return;
        }
    }
    report.ptms_decoded += 1;
    let Some(img) = dec.finest() else {
        return;
    };
    if cleared && img.channels() == 4 {
        let stray = colour_under_empty_texels(img.data());
        if stray > 0 {
            report.problems.push(Problem {
                path: path.to_path_buf(),
                what: format!(
                    "PTM at bytes {}..: {stray} texel(s) with alpha 0 hold colour; a format-5 \
                     database stores colour 0 there (readers divide coarse levels by alpha)",
                    p.levels.first().map_or(0, |f| f.offset)
                ),
            });
        }
    }
}

/// Texels of interleaved RGBA bytes with alpha 0 and some colour.
pub(super) fn colour_under_empty_texels(rgba: &[u8]) -> usize {
    rgba.chunks_exact(4)
        .filter(|p| p[3] == 0 && p[..3] != [0, 0, 0])
        .count()
}

/// Decodes a mesh whose range was checked.
fn decode_mesh_range(path: &Path, bytes: &[u8], r: &PackRange, report: &mut Report) {
    let b = &bytes[r.offset as usize..(r.offset + r.len) as usize];
    match codec::mesh::decode_mesh(b) {
        Ok(_) => report.meshes_decoded += 1,
        Err(e) => report.problems.push(Problem {
            path: path.to_path_buf(),
            what: format!("mesh at bytes {}+{} does not decode: {e}", r.offset, r.len),
        }),
    }
}

/// A mesh's range inside its pack must lie in the file and match its checksum (true when it
/// does).
fn check_mesh_range(path: &Path, bytes: &[u8], r: &PackRange, report: &mut Report) -> bool {
    let what = match r
        .offset
        .checked_add(r.len)
        .filter(|&e| e <= bytes.len() as u64)
    {
        None => format!("mesh range {}+{} outside the file", r.offset, r.len),
        Some(end) if !hash_matches(&bytes[r.offset as usize..end as usize], &r.hash) => {
            format!(
                "mesh range {}..{end}: checksum does not match {}",
                r.offset, r.hash
            )
        }
        Some(_) => {
            report.level_ranges_checked += 1;
            return true;
        }
    };
    report.problems.push(Problem {
        path: path.to_path_buf(),
        what,
    });
    false
}

/// Reads, hash-checks and decodes one table: its path and the table or what is wrong.
fn check_table(
    dir: &Path,
    obj: &ObjectRef,
    viewpoint: usize,
) -> (PathBuf, Result<ViewTable, String>) {
    check_object(dir, obj, "table", |b| {
        decode_table(b, viewpoint).map_err(|e| e.to_string())
    })
}

/// Reads, hash-checks and decodes a viewpoint's ACH object.
fn check_ach(
    dir: &Path,
    obj: &ObjectRef,
    viewpoint: usize,
) -> (PathBuf, Result<Vec<SegmentEntry>, String>) {
    check_object(dir, obj, "ACH object", |b| {
        decode_ach(b, viewpoint).map_err(|e| e.to_string())
    })
}

/// Reads and hash-checks one object the top manifest names, then decodes it.
fn check_object<T>(
    dir: &Path,
    obj: &ObjectRef,
    what: &str,
    decode: impl FnOnce(&[u8]) -> Result<T, String>,
) -> (PathBuf, Result<T, String>) {
    let Some(rel) = object_rel_path(&obj.hash) else {
        return (
            dir.join(MANIFEST_FILE),
            Err(format!("invalid {what} hash {:?}", obj.hash)),
        );
    };
    let path = dir.join(rel);
    let got = match fs::read(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err("missing (referenced by the manifest)".to_string())
        }
        Err(e) => Err(e.to_string()),
        Ok(bytes) if bytes.len() as u64 != obj.size => Err(format!(
            "size {} but the manifest says {}",
            bytes.len(),
            obj.size
        )),
        Ok(bytes) if hash_hex(&bytes) != obj.hash => Err(format!(
            "content hash is {}: the file is damaged",
            hash_hex(&bytes)
        )),
        Ok(bytes) => decode(&bytes),
    };
    (path, got)
}

#[allow(clippy::type_complexity)]
fn for_each_object<'m>(
    m: &'m Manifest,
    f: &mut dyn FnMut(&'m ObjectRef, Option<&'m PtmRef>, Option<&'m PackRange>),
) {
    for v in crate::split::unique_viewpoints(m) {
        for b in &v.background {
            f(&b.ptm.object, Some(&b.ptm), None);
        }
        for tile in &v.tiles {
            if let Some(p) = &tile.ptm {
                f(&p.object, Some(p), None);
            }
            if let Some((o, r)) = tile.mesh_at() {
                f(o, None, r);
            }
        }
    }
}

/// The message of an error whose path is reported separately.
fn strip_path(e: &DbError) -> String {
    match e {
        DbError::Io { error, .. } => error.to_string(),
        DbError::Format { message, .. } => message.clone(),
        DbError::Request(m) => m.clone(),
    }
}
