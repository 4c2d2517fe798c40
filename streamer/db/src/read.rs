//! Reading a database: the top manifest checked against its checksum file and the limits,
//! every viewpoint's table and ACH object checked against its hash, assembled into one
//! [`Manifest`]; objects, byte ranges and PTM level groups read with their checksums.

use std::fs;
use std::io::{self, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use tracks::manifest::{object_rel_path, Manifest, ObjectRef, PtmRef};

use crate::index::{self, RootManifest};
use crate::split::{self, TopManifest, ViewTable, OLDEST_READ_VERSION, TOP_VERSION};
use crate::{hash_hex, hash_matches, DbError, MANIFEST_FILE, MANIFEST_HASH_FILE};

/// A database opened for reading.
#[derive(Debug, Clone)]
pub struct Database {
    root: PathBuf,
    top: TopManifest,
    manifest: Manifest,
}

impl Database {
    /// Reads and checks `DIR/manifest.json` (against its checksum file when present) and
    /// every viewpoint's table (hash, decode).
    pub fn open(dir: &Path) -> Result<Database, DbError> {
        let top = read_top(dir)?;
        let manifest = read_tables(dir, &top)?;
        Ok(Database {
            root: dir.to_path_buf(),
            top,
            manifest,
        })
    }

    /// The top manifest as stored (`manifest.json`).
    pub fn top(&self) -> &TopManifest {
        &self.top
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Path of the object with this hash; `None` for anything that is not a valid hash.
    pub fn object_path(&self, hash: &str) -> Option<PathBuf> {
        object_rel_path(hash).map(|rel| self.root.join(rel))
    }

    /// The whole object, checked against its size and hash.
    pub fn read_object(&self, obj: &ObjectRef) -> Result<Vec<u8>, DbError> {
        read_object_in(&self.root, obj)
    }

    /// `len` bytes at `offset` of an object (not hash-checked: ranges carry their own hash).
    pub fn read_range(&self, obj: &ObjectRef, offset: u64, len: u64) -> Result<Vec<u8>, DbError> {
        let end = offset
            .checked_add(len)
            .filter(|&e| e <= obj.size)
            .ok_or_else(|| {
                DbError::Request(format!(
                    "range {offset}+{len} outside object {} of {} bytes",
                    obj.hash, obj.size
                ))
            })?;
        let path = self
            .object_path(&obj.hash)
            .ok_or_else(|| DbError::Request(format!("invalid object hash {:?}", obj.hash)))?;
        let mut f = fs::File::open(&path).map_err(|e| DbError::io(&path, e))?;
        let mut buf = vec![0u8; (end - offset) as usize];
        f.seek(SeekFrom::Start(offset))
            .and_then(|_| f.read_exact(&mut buf))
            .map_err(|e| DbError::io(&path, e))?;
        Ok(buf)
    }

    /// A range of a pack, checked against its checksum.
    pub fn read_checked_range(
        &self,
        obj: &ObjectRef,
        r: &tracks::manifest::PackRange,
    ) -> Result<Vec<u8>, DbError> {
        let bytes = self.read_range(obj, r.offset, r.len)?;
        if !hash_matches(&bytes, &r.hash) {
            let path = self.object_path(&obj.hash).unwrap_or_default();
            return Err(DbError::format(
                &path,
                format!(
                    "bytes {}..{}: checksum does not match {}",
                    r.offset,
                    r.offset + r.len,
                    r.hash
                ),
            ));
        }
        Ok(bytes)
    }

    /// Every tile's PTM, in track and viewpoint order.
    fn ptms(&self) -> impl Iterator<Item = &PtmRef> {
        let viewpoints = self.manifest().tracks.iter().flat_map(|t| &t.viewpoints);
        viewpoints.flat_map(|v| v.tiles.iter().filter_map(|t| t.ptm.as_ref()))
    }

    /// The most level groups any tile's PTM has (0 without textures).
    pub fn most_level_groups(&self) -> usize {
        self.ptms().map(|p| p.levels.len()).max().unwrap_or(0)
    }

    /// How the textures are coded, from the first PTM's header: `lossless`, `lossy near=N`,
    /// or `no textures`.
    pub fn texture_coding(&self) -> Result<String, DbError> {
        let Some(first) = self.ptms().next() else {
            return Ok("no textures".into());
        };
        let bytes = self.read_level(first, 0)?;
        let mut dec = codec::ptm::Decoder::new(codec::ptm::Limits::default());
        let path = self.object_path(&first.object.hash).unwrap_or_default();
        dec.push(&bytes)
            .map_err(|e| DbError::format(&path, format!("PTM header: {e}")))?;
        Ok(match dec.header().map_or(0, |h| h.near) {
            0 => "lossless".into(),
            n => format!("lossy near={n}"),
        })
    }

    /// Stream chunk `group` of a PTM (0 = header + lowest level), checked against its hash.
    pub fn read_level(&self, ptm: &PtmRef, group: usize) -> Result<Vec<u8>, DbError> {
        let l = ptm.levels.get(group).ok_or_else(|| {
            DbError::Request(format!(
                "PTM {} has {} level groups, not {}",
                ptm.object.hash,
                ptm.levels.len(),
                group + 1
            ))
        })?;
        let bytes = self.read_range(&ptm.object, l.offset, l.len)?;
        if !hash_matches(&bytes, &l.hash) {
            let got = hash_hex(&bytes);
            let path = self.object_path(&ptm.object.hash).unwrap_or_default();
            return Err(DbError::format(
                &path,
                format!(
                    "level group {group} (bytes {}..{}) hash is {got}, manifest says {}",
                    l.offset,
                    l.offset + l.len,
                    l.hash
                ),
            ));
        }
        Ok(bytes)
    }
}

/// Reads the whole manifest: the top ([`read_top`]) and every viewpoint's table, assembled.
pub fn read_manifest(dir: &Path) -> Result<Manifest, DbError> {
    read_tables(dir, &read_top(dir)?)
}

/// Reads every table the top manifest refers to (hash-checked, decoded) and assembles the
/// full manifest.
pub fn read_tables(dir: &Path, top: &TopManifest) -> Result<Manifest, DbError> {
    let db = Database {
        root: dir.to_path_buf(),
        top: top.clone(),
        manifest: split::assemble(top, &[]),
    };
    let mut tables = Vec::with_capacity(top.viewpoints.len());
    for v in &top.viewpoints {
        let bytes = db.read_object(&v.table)?;
        let path = db.object_path(&v.table.hash).unwrap_or_default();
        let mut table = split::decode_table(&bytes, v.index)
            .map_err(|e| DbError::format(&path, format!("viewpoint {}: {e}", v.index)))?;
        if let Some(ach) = &v.ach {
            let bytes = db.read_object(ach)?;
            let path = db.object_path(&ach.hash).unwrap_or_default();
            table.segments = split::decode_ach(&bytes, v.index).map_err(|e| {
                DbError::format(&path, format!("ACH lists of viewpoint {}: {e}", v.index))
            })?;
        }
        tables.push(table);
    }
    let refs: Vec<Option<&ViewTable>> = tables.iter().map(Some).collect();
    Ok(split::assemble(top, &refs))
}

/// Reads `DIR/manifest.json` (the root of the index, format 9), checking its checksum file
/// when present and its version, then every piece of the index ([`read_pieces`]): the top
/// manifest, whole.
pub fn read_top(dir: &Path) -> Result<TopManifest, DbError> {
    let (root, _) = read_root(dir)?;
    read_pieces(dir, root)
}

/// Reads and checks `DIR/manifest.json` (against its checksum file when present): the root
/// of the index and the bytes it was parsed from.
pub fn read_root(dir: &Path) -> Result<(RootManifest, Vec<u8>), DbError> {
    let path = dir.join(MANIFEST_FILE);
    let bytes = read_limited(&path, tracks::limits::MAX_MANIFEST_BYTES)?;
    let hash_path = dir.join(MANIFEST_HASH_FILE);
    match fs::read_to_string(&hash_path) {
        Ok(text) => {
            let got = hash_hex(&bytes);
            if text.trim() != got {
                return Err(DbError::format(
                    &path,
                    format!("content hash {got} does not match {}", hash_path.display()),
                ));
            }
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(DbError::io(&hash_path, e)),
    }
    Ok((parse_root(&path, &bytes)?, bytes))
}

/// Every node and chunk of `root`'s index, read from `DIR/objects/` (each within
/// [`index::MAX_PIECE_BYTES`], checked against its hash), assembled into the top manifest
/// and checked as a whole.
pub fn read_pieces(dir: &Path, root: RootManifest) -> Result<TopManifest, DbError> {
    Ok(read_index(dir, root)?.0)
}

/// [`read_pieces`], with the references of the pieces read (the index's own objects).
pub fn read_index(
    dir: &Path,
    root: RootManifest,
) -> Result<(TopManifest, Vec<ObjectRef>), DbError> {
    let path = dir.join(MANIFEST_FILE);
    let mut refs = Vec::new();
    let top = index::read_all(root, |r: &ObjectRef| {
        refs.push(r.clone());
        read_piece(dir, r)
    })
    .map_err(|e| DbError::format(&path, e))?;
    Ok((top, refs))
}

/// Checks every piece of `root`'s index and every table and ACH object it names (present,
/// hash, decode) one chunk at a time, holding no more than a chunk and the tree's frontier:
/// what a server checks before it serves a database, without keeping the graph. The error
/// names the damaged file.
pub fn check_index(dir: &Path, root: &RootManifest) -> Result<(), DbError> {
    let mut todo: Vec<(index::PieceAt, ObjectRef)> = root.index.root_piece().into_iter().collect();
    let mut seen = 0usize;
    while let Some((at, r)) = todo.pop() {
        let bytes = read_piece(dir, &r)?;
        let path = dir.join(r.rel_path().unwrap_or_default());
        let named = |e: String| DbError::format(&path, e);
        if at.level > 0 {
            let node = index::decode_node(&bytes, &at).map_err(named)?;
            todo.extend(node.children_at().map(|(a, c)| (a, c.clone())));
            continue;
        }
        let chunk = index::decode_chunk(&bytes, &at, root).map_err(named)?;
        seen += chunk.viewpoints.len();
        if seen > root.viewpoints {
            return Err(named(format!(
                "the chunks hold more than the root's {} viewpoints",
                root.viewpoints
            )));
        }
        for v in &chunk.viewpoints {
            // Read and decode each object; a failure names its file.
            let named = |o: &ObjectRef, e: String| {
                DbError::format(&dir.join(o.rel_path().unwrap_or_default()), e)
            };
            let bytes = read_object_in(dir, &v.table)?;
            split::decode_table(&bytes, v.index)
                .map_err(|e| named(&v.table, format!("viewpoint {}: {e}", v.index)))?;
            if let Some(ach) = &v.ach {
                split::decode_ach(&read_object_in(dir, ach)?, v.index)
                    .map_err(|e| named(ach, format!("ACH lists of viewpoint {}: {e}", v.index)))?;
            }
        }
    }
    Ok(())
}

/// The whole object `obj` of the database in `dir`, checked against its size and hash.
fn read_object_in(dir: &Path, obj: &ObjectRef) -> Result<Vec<u8>, DbError> {
    let path = obj
        .rel_path()
        .map(|rel| dir.join(rel))
        .ok_or_else(|| DbError::Request(format!("invalid object hash {:?}", obj.hash)))?;
    let bytes = fs::read(&path).map_err(|e| DbError::io(&path, e))?;
    if bytes.len() as u64 != obj.size {
        return Err(DbError::format(
            &path,
            format!("size {} (manifest says {})", bytes.len(), obj.size),
        ));
    }
    let got = hash_hex(&bytes);
    if got != obj.hash {
        return Err(DbError::format(&path, format!("content hash is {got}")));
    }
    Ok(bytes)
}

/// One piece of the index from `DIR/objects/`, checked against its reference.
pub fn read_piece(dir: &Path, r: &ObjectRef) -> Result<Vec<u8>, DbError> {
    let rel = r
        .rel_path()
        .ok_or_else(|| DbError::Request(format!("invalid object hash {:?}", r.hash)))?;
    let path = dir.join(rel);
    let bytes = read_limited(&path, index::MAX_PIECE_BYTES)?;
    if bytes.len() as u64 != r.size || hash_hex(&bytes) != r.hash {
        return Err(DbError::format(
            &path,
            format!(
                "{} bytes hashing to {}; the index names {} bytes hashing to {}",
                bytes.len(),
                hash_hex(&bytes),
                r.size,
                r.hash
            ),
        ));
    }
    Ok(bytes)
}

/// The bytes of `path`, refused unread when the file is larger than `limit`.
pub fn read_limited(path: &Path, limit: u64) -> Result<Vec<u8>, DbError> {
    let mut f = fs::File::open(path).map_err(|e| DbError::io(path, e))?;
    let len = f.metadata().map_err(|e| DbError::io(path, e))?.len();
    if len > limit {
        return Err(DbError::format(
            path,
            format!("{len} bytes; at most {limit} are read"),
        ));
    }
    let mut out = Vec::with_capacity(len as usize);
    (&mut f)
        .take(limit + 1)
        .read_to_end(&mut out)
        .map_err(|e| DbError::io(path, e))?;
    if out.len() as u64 > limit {
        return Err(DbError::format(
            path,
            format!("more than {limit} bytes; at most {limit} are read"),
        ));
    }
    Ok(out)
}

/// Parses root bytes read from `path` (`manifest.json`) and checks the version and the
/// limits: format 9 is read; older ones are refused with a request to rebuild the database.
pub fn parse_root(path: &Path, bytes: &[u8]) -> Result<RootManifest, DbError> {
    #[derive(serde::Deserialize)]
    struct Version {
        version: u32,
    }
    let v: Version = serde_json::from_slice(bytes)
        .map_err(|e| DbError::format(path, format!("line {}: {e}", e.line())))?;
    if !(OLDEST_READ_VERSION..=TOP_VERSION).contains(&v.version) {
        let hint = if v.version < OLDEST_READ_VERSION {
            " (format 9 keeps the graph of tracks in spatial chunks reached through a small \
             root, so that a client reads only what is near): rebuild the database with \
             `railview build` (it resumes from its work directory and re-encodes only)"
        } else {
            ""
        };
        let reads = if OLDEST_READ_VERSION == TOP_VERSION {
            format!("format {TOP_VERSION}")
        } else {
            format!("formats {OLDEST_READ_VERSION} to {TOP_VERSION}")
        };
        return Err(DbError::format(
            path,
            format!(
                "manifest format {}{hint}; this build reads {reads}",
                v.version
            ),
        ));
    }
    index::parse_root(bytes).map_err(|e| DbError::format(path, e))
}
