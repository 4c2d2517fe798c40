//! db: the walkthrough database — a directory of immutable content-addressed objects plus a
//! manifest (types in [`tracks::manifest`]) — and everything that reads or writes it; no
//! network, no async. Stored split ([`split`]) and in pieces ([`index`], format 9): a small
//! root, the graph of tracks in spatial chunks under a quadtree of node objects, one binary
//! tile table per viewpoint ([`table`]), one pack per viewpoint ([`pack`]) holding its tiles'
//! meshes and PTM level groups, and the ACH lists of the segments starting at each viewpoint
//! ([`ach`]); tables, ACH lists and packs are objects. The payloads' own formats are
//! [`codec`]'s.
//!
//! Main types: [`DbWriter`] (puts objects; [`DbWriter::finish`] packs each viewpoint's tiles,
//! splits the manifest and writes the top last), [`Database`] (opens a database — the top and
//! every table, assembled into one [`tracks::manifest::Manifest`] whose tiles point into their
//! viewpoint's pack — and reads objects, byte ranges and single PTM level groups with their
//! checksums), [`verify()`] → [`Report`] (every file's hash and size, every table, every
//! range's checksum), [`prune()`] (removes the objects an earlier build left that the
//! manifest no longer references), [`split::TopManifest`] / [`split::ViewTable`], [`ach`] (average
//! coverage hints per track segment) and [`baseline`] (what a database is weighed against:
//! each panorama as PNG colour and PNG16 disparity). Ranges inside a pack carry 32-bit
//! checksums ([`range_hash32`]; background PTMs, listed in the top, 128-bit ones,
//! [`range_hash`]); objects keep their full BLAKE3.
//!
//! ```
//! use db::{gunzip_limited, gzip, hash_hex, hash_matches, range_hash32};
//!
//! let payload = b"one level group";
//! // An object is named by its BLAKE3; a range in a pack by its first 32 bits.
//! assert!(hash_matches(payload, &hash_hex(payload)));
//! assert!(hash_matches(payload, &range_hash32(payload)));
//! // The manifest's gzip copy decompresses within a limit.
//! let gz = gzip(payload).unwrap();
//! assert_eq!(gunzip_limited(&gz, 1 << 20).unwrap(), payload);
//! assert!(db::Database::open(std::path::Path::new("/no/such/database")).is_err());
//! ```
//!
//! ```text
//! DB/manifest.json          the root of the index ([`index::RootManifest`], format 9),
//!                           written last, atomically
//! DB/manifest.json.blake3   lowercase hex BLAKE3 of manifest.json (so a flipped byte in the
//!                           manifest is caught too), written right after it
//! DB/manifest.json.gz       gzip of manifest.json's exact bytes, written after it: what a
//!                           server sends a client that accepts gzip (nginx `gzip_static`
//!                           serves the same file); optional (older databases lack it)
//! DB/objects/HH/HASH        payloads named by their BLAKE3; HH = the hash's first two digits
//!                           (the index's nodes and chunks, each viewpoint's table, ACH
//!                           lists and pack; a writer without
//!                           a stage, [`DbWriter::with_stage`], also leaves the tiles' own PTM
//!                           and mesh objects here, which the manifest no longer refers to)
//! ```
//!
//! Every file is written to a temporary name in its final directory and renamed into place, so
//! a killed writer never leaves a file that looks complete. Objects already present with the
//! right size are not rewritten, which is what makes `build` resumable.

pub mod ach;
pub mod baseline;
pub mod index;
pub mod pack;
mod prune;
mod read;
pub mod split;
pub mod table;
mod verify;

use std::collections::HashMap;
use std::fs;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

use tracks::manifest::{object_rel_path, LevelRef, Manifest, ObjectRef, PtmRef, ViewpointEntry};

use codec::ptm;

pub use prune::{prune, Pruned};
pub use read::{
    check_index, parse_root, read_index, read_limited, read_manifest, read_piece, read_pieces,
    read_root, read_tables, read_top, Database,
};
pub use split::{TopManifest, ViewTable, OLDEST_READ_VERSION, TOP_VERSION};
pub use verify::{verify, verify_with, Problem, Report, VerifyOptions};

/// Name of the manifest file in a database directory.
pub const MANIFEST_FILE: &str = "manifest.json";
/// Name of the manifest's checksum file.
pub const MANIFEST_HASH_FILE: &str = "manifest.json.blake3";
/// Name of the gzip-compressed copy of the manifest.
pub const MANIFEST_GZ_FILE: &str = "manifest.json.gz";

/// Errors of the database layer; each names the file at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DbError {
    /// The I/O error is part of the message (not a separate source, so it prints once).
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: io::Error },
    /// The file's content is wrong (bad JSON, wrong hash or size, unknown version, …).
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    /// A request that does not fit the database (bad hash, range outside an object, …).
    #[error("{0}")]
    Request(String),
}

impl DbError {
    fn io(path: &Path, error: io::Error) -> DbError {
        DbError::Io {
            path: path.to_path_buf(),
            error,
        }
    }
    fn format(path: &Path, message: impl Into<String>) -> DbError {
        DbError::Format {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// Lowercase hex BLAKE3 of `bytes`.
pub fn hash_hex(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// Whether a file name is a temporary file of an interrupted write: a leading `.` and a
/// `.tmp` marker (this writer's `.NAME.tmp.RANDOM`, the `tempfile` crate's `.tmpXXXXXX`).
pub fn is_temp_name(name: &str) -> bool {
    // A superset of `railview_files::is_temporary`, which marks `.NAME.tmp.RANDOM`.
    name.starts_with('.') && name.contains(".tmp")
}

/// Removes every temporary file of an interrupted write from `root`, `root/objects/` and
/// every `root/objects/HH/`; returns what it removed. Only for a writer that holds the
/// directory's lock ([`DbWriter::create`]): no other writer can be running there, so every
/// temporary file is a killed writer's leftover.
fn remove_temp_files(root: &Path) -> Result<Vec<PathBuf>, DbError> {
    let mut dirs = vec![root.to_path_buf(), root.join("objects")];
    if let Ok(rd) = fs::read_dir(root.join("objects")) {
        let mut subs: Vec<PathBuf> = rd
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
            .map(|e| e.path())
            .collect();
        subs.sort();
        dirs.extend(subs);
    }
    let mut removed = Vec::new();
    for dir in dirs {
        let Ok(rd) = fs::read_dir(&dir) else {
            continue;
        };
        for e in rd.filter_map(Result::ok) {
            let name = e.file_name().to_string_lossy().into_owned();
            if is_temp_name(&name) && e.file_type().is_ok_and(|t| t.is_file()) {
                let path = e.path();
                match fs::remove_file(&path) {
                    Ok(()) => removed.push(path),
                    Err(err) if err.kind() == std::io::ErrorKind::NotFound => {}
                    Err(err) => return Err(DbError::io(&path, err)),
                }
            }
        }
    }
    removed.sort();
    Ok(removed)
}

/// Takes the exclusive lock of a database (or stage) directory for one writer: an advisory
/// lock on the directory itself, so nothing is added to what a host serves, released by the
/// kernel when the writer exits or is killed.
fn lock_dir(dir: &Path) -> Result<fs::File, DbError> {
    let handle = fs::File::open(dir).map_err(|e| DbError::io(dir, e))?;
    match handle.try_lock() {
        Ok(()) => Ok(handle),
        Err(fs::TryLockError::WouldBlock) => Err(DbError::io(
            dir,
            std::io::Error::new(
                std::io::ErrorKind::WouldBlock,
                "another build is writing this directory (wait for it to end)",
            ),
        )),
        Err(fs::TryLockError::Error(e)) => Err(DbError::io(dir, e)),
    }
}

/// Writes `bytes` to `path` whole: a uniquely named temporary file in the same directory
/// (`.NAME.tmp.RANDOM`, which verify recognises as a leftover), fsync, rename. Safe with
/// several writers at once, on one host or many sharing a file system.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DbError> {
    railview_files::write(path, bytes).map_err(|e| DbError::io(path, e))
}

/// Builds a database directory; objects first, the manifest last ([`DbWriter::finish`]).
#[derive(Debug)]
pub struct DbWriter {
    root: PathBuf,
    /// Where [`DbWriter::put_staged`] keeps the tiles' own objects, which the packs replace
    /// ([`DbWriter::with_stage`]); `None`: in the database beside everything else.
    stage: Option<PathBuf>,
    /// Objects written by this writer, and their bytes.
    pub objects_written: u64,
    pub bytes_written: u64,
    /// Objects that were already present (resumed or shared content).
    pub objects_reused: u64,
    /// Payloads that [`DbWriter::finish`] found already in an earlier pack, and their bytes
    /// (stored once, pointed at again).
    pub payloads_shared: u64,
    pub bytes_shared: u64,
    /// Whether a payload already in an earlier viewpoint's pack is pointed at there (the
    /// default, the smaller database) or stored again in each pack that needs it, so that
    /// every viewpoint's payloads lie in its own pack (and no two viewpoints' tiles share a
    /// byte range a client could tell apart only by its checksum).
    pub share_across_viewpoints: bool,
    /// Side of the index's chunks, metres ([`index::DEFAULT_CELL_M`] unless set).
    pub cell: f64,
    /// Temporary files of an earlier, killed writer removed on opening.
    pub leftovers_removed: Vec<PathBuf>,
    /// The directory locks held while this writer lives ([`lock_dir`]).
    _locks: Vec<fs::File>,
}

impl DbWriter {
    /// Opens (creating if needed) a database directory for writing, and removes the
    /// temporary files a killed writer left there. It holds the directory's lock while it
    /// lives, so a second writer of the same database fails at once instead of removing the
    /// first one's temporary files. An existing manifest is left in place until
    /// [`DbWriter::finish`] replaces it.
    pub fn create(root: &Path) -> Result<DbWriter, DbError> {
        let objects = root.join("objects");
        fs::create_dir_all(&objects).map_err(|e| DbError::io(&objects, e))?;
        let lock = lock_dir(root)?;
        let leftovers_removed = remove_temp_files(root)?;
        Ok(DbWriter {
            root: root.to_path_buf(),
            stage: None,
            objects_written: 0,
            bytes_written: 0,
            objects_reused: 0,
            payloads_shared: 0,
            share_across_viewpoints: true,
            cell: index::DEFAULT_CELL_M,
            bytes_shared: 0,
            leftovers_removed,
            _locks: vec![lock],
        })
    }

    /// Keep the objects stored with [`DbWriter::put_staged`] (each tile's PTM and mesh, which
    /// [`DbWriter::finish`] copies into its viewpoint's pack) under `stage/objects/` instead
    /// of the database, so the database holds only what its manifest refers to while a
    /// resumed build still finds them.
    pub fn with_stage(mut self, stage: &Path) -> Result<DbWriter, DbError> {
        if stage.is_dir() {
            self._locks.push(lock_dir(stage)?);
            self.leftovers_removed.extend(remove_temp_files(stage)?);
        }
        self.stage = Some(stage.to_path_buf());
        Ok(self)
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The directory holding staged objects: the stage when set, else the database.
    pub fn stage_root(&self) -> &Path {
        self.stage.as_deref().unwrap_or(&self.root)
    }

    /// Stores `bytes` as an object named by its hash; reuses an existing object of that name
    /// and size.
    pub fn put(&mut self, bytes: &[u8]) -> Result<ObjectRef, DbError> {
        let root = self.root.clone();
        self.put_in(&root, bytes)
    }

    /// [`DbWriter::put`] for an object that only [`DbWriter::finish`] reads (it goes into a
    /// pack): kept in the stage when one is set.
    pub fn put_staged(&mut self, bytes: &[u8]) -> Result<ObjectRef, DbError> {
        let root = self.stage_root().to_path_buf();
        self.put_in(&root, bytes)
    }

    fn put_in(&mut self, root: &Path, bytes: &[u8]) -> Result<ObjectRef, DbError> {
        let hash = hash_hex(bytes);
        let rel = object_rel_path(&hash).expect("blake3 hex is a valid object name");
        let path = root.join(rel);
        let obj = ObjectRef {
            hash,
            size: bytes.len() as u64,
        };
        // An object of the name and size is reused once its bytes are checked: objects are
        // written unsynced, so one a crash cut off before the build's flush may be torn.
        if fs::metadata(&path).is_ok_and(|m| m.is_file() && m.len() == obj.size)
            && fs::read(&path).is_ok_and(|b| hash_hex(&b) == obj.hash)
        {
            self.objects_reused += 1;
            return Ok(obj);
        }
        railview_files::write_unsynced(&path, bytes).map_err(|e| DbError::io(&path, e))?;
        self.objects_written += 1;
        self.bytes_written += obj.size;
        Ok(obj)
    }

    /// Stores an encoded PTM and describes its level groups for the manifest. Its image must
    /// hold colour 0 wherever alpha is 0 ([`clear_masked`]; the format promises it).
    pub fn put_ptm(&mut self, enc: &ptm::Encoded, channels: u8) -> Result<PtmRef, DbError> {
        let object = self.put(&enc.bytes)?;
        Ok(ptm_ref(object, enc, channels))
    }

    /// [`DbWriter::put_ptm`] for a tile's PTM, which goes into a pack
    /// ([`DbWriter::put_staged`]).
    pub fn put_ptm_staged(&mut self, enc: &ptm::Encoded, channels: u8) -> Result<PtmRef, DbError> {
        let object = self.put_staged(&enc.bytes)?;
        Ok(ptm_ref(object, enc, channels))
    }

    /// Packs each viewpoint's background tiles and tiles ([`pack::pack_viewpoint`]: their
    /// payloads read back from the objects [`DbWriter::put`] stored, or from an earlier
    /// pack; a payload an earlier viewpoint's pack holds is not stored again) into one
    /// object, splits the
    /// packed manifest ([`split::split`]) and stores each viewpoint's table as an object,
    /// then writes the top manifest (compact JSON, atomically), its checksum file and its
    /// gzip copy: the database is complete. The tiles' own objects stay where they are (a
    /// resumed build finds them): in the stage when one is set ([`DbWriter::with_stage`]),
    /// else in the database, unreferenced by the manifest. Returns the packed manifest
    /// as [`Database::open`] reads it back.
    pub fn finish(&mut self, manifest: &Manifest) -> Result<Manifest, DbError> {
        self.finish_owned(manifest.clone())
    }

    /// [`DbWriter::finish`] on a manifest it may pack in place (no copy of every tile
    /// entry: a city's build holds one).
    pub fn finish_owned(&mut self, mut packed: Manifest) -> Result<Manifest, DbError> {
        let mut payloads = pack::Payloads::default();
        // Each viewpoint packed once, in id order (a junction is listed by every track
        // through it); the packed entry replaces it on every track, so it is kept for the
        // viewpoints listed more than once.
        let mut done: HashMap<usize, ViewpointEntry> = HashMap::new();
        let mut order: Vec<(usize, usize, usize)> = packed
            .tracks
            .iter()
            .enumerate()
            .flat_map(|(ti, t)| {
                t.viewpoints
                    .iter()
                    .enumerate()
                    .map(move |(vi, v)| (v.index, ti, vi))
            })
            .collect();
        order.sort_unstable();
        let listed = |k: usize| order.get(k).map(|o| o.0);
        let repeated: Vec<bool> = (0..order.len())
            .map(|k| {
                let id = listed(k);
                (k > 0 && listed(k - 1) == id) || listed(k + 1) == id
            })
            .collect();
        for (k, &(_, ti, vi)) in order.iter().enumerate() {
            let v = &mut packed.tracks[ti].viewpoints[vi];
            if let Some(p) = done.get(&v.index) {
                v.background = p.background.clone();
                v.tiles = p.tiles.clone();
                continue;
            }
            {
                if !self.share_across_viewpoints {
                    payloads.forget_placed();
                }
                let mut cache: HashMap<String, Vec<u8>> = HashMap::new();
                let roots = [self.stage_root().to_path_buf(), self.root.clone()];
                let mut read = |o: &ObjectRef, offset: u64, len: u64| {
                    read_stored(&roots, &mut cache, o, offset, len)
                };
                let (bytes, background, tiles) =
                    pack::pack_viewpoint(&v.background, &v.tiles, &mut read, &mut payloads)?;
                if !bytes.is_empty() {
                    self.put(&bytes)?;
                }
                v.background = background;
                v.tiles = tiles;
                if repeated[k] {
                    done.insert(v.index, v.clone());
                }
            }
        }
        self.payloads_shared = payloads.shared;
        self.bytes_shared = payloads.bytes_shared;
        let path = self.root.join(MANIFEST_FILE);
        let (top, tables) =
            split::split(&packed).map_err(|e| DbError::format(&path, e.to_string()))?;
        for v in &tables {
            self.put(&v.table)?;
            if let Some(ach) = &v.ach {
                self.put(ach)?;
            }
        }
        let (root, pieces) =
            index::pieces(&top, self.cell).map_err(|e| DbError::format(&path, e))?;
        for p in &pieces {
            self.put(p)?;
        }
        let mut json =
            serde_json::to_vec(&root).map_err(|e| DbError::format(&path, e.to_string()))?;
        json.push(b'\n');
        // Every object on the disk before the manifest that names them.
        for root in [self.stage_root().to_path_buf(), self.root.clone()] {
            if root.is_dir() {
                railview_files::sync_file_system(&root).map_err(|e| DbError::io(&root, e))?;
            }
        }
        write_atomic(&path, &json)?;
        write_atomic(
            &self.root.join(MANIFEST_HASH_FILE),
            format!("{}\n", hash_hex(&json)).as_bytes(),
        )?;
        let gz_path = self.root.join(MANIFEST_GZ_FILE);
        write_atomic(
            &gz_path,
            &gzip(&json).map_err(|e| DbError::io(&gz_path, e))?,
        )?;
        // What a reader gets: depths and ACH values as the tables store them.
        read_tables(&self.root, &top)
    }
}

/// `len` bytes at `offset` of a stored object; each object is read once (per `cache`) and
/// checked against its size and full hash.
fn read_stored(
    roots: &[PathBuf],
    cache: &mut HashMap<String, Vec<u8>>,
    o: &ObjectRef,
    offset: u64,
    len: u64,
) -> Result<Vec<u8>, DbError> {
    if !cache.contains_key(&o.hash) {
        let rel = o
            .rel_path()
            .ok_or_else(|| DbError::Request(format!("invalid object hash {:?}", o.hash)))?;
        // The first root that has it (the stage, then the database).
        let path = roots
            .iter()
            .map(|r| r.join(&rel))
            .find(|p| p.is_file())
            .unwrap_or_else(|| roots.last().map_or(PathBuf::from(&rel), |r| r.join(&rel)));
        let bytes = fs::read(&path).map_err(|e| DbError::io(&path, e))?;
        if bytes.len() as u64 != o.size || hash_hex(&bytes) != o.hash {
            return Err(DbError::format(
                &path,
                format!("does not match its name and size {}", o.size),
            ));
        }
        cache.insert(o.hash.clone(), bytes);
    }
    let bytes = &cache[&o.hash];
    offset
        .checked_add(len)
        .filter(|&e| e <= bytes.len() as u64)
        .map(|e| bytes[offset as usize..e as usize].to_vec())
        .ok_or_else(|| {
            DbError::Request(format!(
                "range {offset}+{len} outside object {} of {} bytes",
                o.hash, o.size
            ))
        })
}

/// `bytes` gzip-compressed at the best level (written once, served many times).
pub fn gzip(bytes: &[u8]) -> io::Result<Vec<u8>> {
    let mut enc = flate2::write::GzEncoder::new(
        Vec::with_capacity(bytes.len() / 3),
        flate2::Compression::best(),
    );
    enc.write_all(bytes)?;
    enc.finish()
}

/// Why [`gunzip_limited`] failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GunzipError {
    /// Not gzip, truncated, or a bad CRC/length trailer.
    #[error("not valid gzip: {0}")]
    Invalid(io::Error),
    /// The decompressed data would be longer than the limit.
    #[error("decompresses to more than {limit} bytes")]
    TooLarge { limit: u64 },
}

/// Decompresses a whole gzip stream (every member) holding at most `limit` bytes: a body
/// that would expand further stops at `limit + 1` bytes with [`GunzipError::TooLarge`], so
/// hostile input cannot exhaust memory. The trailer's CRC-32 and length are checked.
pub fn gunzip_limited(gz: &[u8], limit: u64) -> Result<Vec<u8>, GunzipError> {
    let dec = flate2::read::MultiGzDecoder::new(gz);
    let mut out = Vec::with_capacity(gz.len().saturating_mul(4).min(limit as usize));
    dec.take(limit.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(GunzipError::Invalid)?;
    if out.len() as u64 > limit {
        return Err(GunzipError::TooLarge { limit });
    }
    Ok(out)
}

/// Checksum of a byte range inside an object: the first 128 bits (32 hex digits) of its
/// BLAKE3 (background PTMs, listed in the top manifest).
pub fn range_hash(bytes: &[u8]) -> String {
    let mut h = hash_hex(bytes);
    h.truncate(32);
    h
}

/// Checksum of a byte range inside a viewpoint's pack: the first 32 bits (8 hex digits) of
/// its BLAKE3. The table that lists the range is itself checked by its full hash from the
/// top manifest, so a range checksum only guards against transit or storage damage — never
/// an adversary choosing bytes to collide (the server that could choose them also serves the
/// manifest) — and 32 bits make an undetected random error a 1-in-4·10⁹ event, the strength
/// of the CRC-32 that gzip, PNG and Ethernet rely on. Wider checksums cost the client in
/// every table: one per range of every tile, whether the tile is ever fetched or not (they
/// were 40 % of castle 128's tables at 64 bits).
pub fn range_hash32(bytes: &[u8]) -> String {
    let mut h = hash_hex(bytes);
    h.truncate(8);
    h
}

/// The first 64 bits (16 hex digits) of a range's BLAKE3: the checksums of format-3 tables
/// (format-4 tables still read them).
pub fn range_hash64(bytes: &[u8]) -> String {
    let mut h = hash_hex(bytes);
    h.truncate(16);
    h
}

/// Whether `bytes` hash to `expected`: a full (64 hex digits) or truncated range (32, 16 or
/// 8 hex digits) BLAKE3 checksum; anything else never matches.
pub fn hash_matches(bytes: &[u8], expected: &str) -> bool {
    let h = blake3::hash(bytes).to_hex();
    match expected.len() {
        64 | 32 | 16 | 8 => &h.as_str()[..expected.len()] == expected,
        _ => false,
    }
}

/// Whether `h` is a valid range checksum (8, 16, 32 or 64 lowercase hex digits).
pub fn valid_range_hash(h: &str) -> bool {
    matches!(h.len(), 8 | 16 | 32 | 64)
        && h.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The manifest entry of an encoded PTM stored as `object`.
pub fn ptm_ref(object: ObjectRef, enc: &ptm::Encoded, channels: u8) -> PtmRef {
    let levels = enc
        .groups
        .iter()
        .map(|g| {
            let range = g.offset as usize..(g.offset + g.len) as usize;
            LevelRef {
                level: g.level,
                width: g.width,
                height: g.height,
                offset: g.offset,
                len: g.len,
                hash: range_hash(&enc.bytes[range]),
            }
        })
        .collect::<Vec<_>>();
    let (width, height) = levels.last().map_or((0, 0), |l| (l.width, l.height));
    PtmRef {
        object,
        width,
        height,
        channels,
        levels,
    }
}

/// Alpha of a background texel where the viewpoint sees sky itself (its panorama's depth is
/// infinite there).
pub const SKY_SEEN_ALPHA: u8 = 255;
/// Alpha of a background texel holding the sky behind the viewpoint's own occluders (the
/// track's complete sky, `prerender::sky`): a renderer draws it only to fill what no
/// reference covers. One below [`SKY_SEEN_ALPHA`], so that the coarse levels' division by
/// the alpha ([`unpremultiply`]) changes its colour by at most one step.
pub const SKY_BEHIND_ALPHA: u8 = 254;

/// Clear the colour of every RGBA texel whose alpha is 0, as format 5 stores every PTM.
///
/// The PTM pyramid averages each channel on its own (eq. 1), so a coarse level's colour is
/// then the covered texels' colour times their coverage, which its alpha is: a reader that
/// divides by the alpha ([`unpremultiply`]) draws a coarse level's outline in the colour of
/// what it covers, where a colour left under alpha 0 (black, or a renderer's background)
/// would darken or tint it. The opaque texels and every alpha are unchanged.
pub fn clear_masked(rgba: &mut [u8]) {
    for p in rgba.chunks_exact_mut(4) {
        if p[3] == 0 {
            p[..3].fill(0);
        }
    }
}

/// Divide the colour of every partly covered RGBA texel (0 < alpha < 255) of a coarse PTM
/// level of a format-5 database by its alpha ([`clear_masked`]): the mean colour of the
/// opaque texels it covers. Texels with alpha 0 or 255 are unchanged.
pub fn unpremultiply(rgba: &mut [u8]) {
    for p in rgba.chunks_exact_mut(4) {
        let a = u32::from(p[3]);
        if a == 0 || a == 255 {
            continue;
        }
        for c in &mut p[..3] {
            *c = ((u32::from(*c) * 255 + a / 2) / a).min(255) as u8;
        }
    }
}

#[cfg(test)]
mod tests;
