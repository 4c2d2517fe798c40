//! The binary viewpoint table (format 4): what a client needs to know about one viewpoint's
//! tiles, in a few bytes per tile; and the viewpoint's ACH object, the ACH lists of the
//! segments starting there, which only clients that rank tiles by ACH fetch.
//!
//! ```text
//! "RVTB" u8 version=5 u8 coding (0 plain, 1 gzip of the body)    header, never compressed
//! body:
//!   varint viewpoint
//!   u8 has_pack [32 B pack BLAKE3, varint pack size]             the pack, named once
//!   varint k, k × (32 B BLAKE3, varint size)                     earlier packs it points into
//!   u8 checksum bytes (4 or 8), varint grid side n
//!   the background tiles, then the tiles, each list as:
//!   u8 depth coding (0 f32, 1 f16), u8 position coding (0 ascending gaps, 1 explicit),
//!   varint count, then one column after another (each over the whole list):
//!     positions   gaps: varint (index − previous index − 1), index = ((slab·6 + face)·n + ty)·n + tx
//!                 explicit: u8 face, varint tx, varint ty, varint slab
//!     flags       u8 (1 kept, 2 PTM, 4 mesh, 8 PTM levels in the usual shape)
//!     opaque      varint opaque pixels
//!     depths      depth_min rounded down, depth_max rounded up (f16 or f32)
//!     PTM shapes  per PTM tile: varint width, varint height, u8 channels, varint ranges,
//!                 unless flag 8: per range varint level, varint width, varint height
//!     lengths     per tile: varint mesh length, varint length of each PTM range
//!     sources     per tile: varint where its mesh lies, then where its PTM's ranges lie
//!                 (one after another): 0 next in the pack, 1 an earlier range of the pack,
//!                 2 + i the i-th earlier pack
//!     offsets     per payload whose source is not 0: varint offset of its first byte
//!     checksums   per tile: mesh, then each PTM range
//!   (a background tile is a kept PTM without mesh in slab 0 at infinite depth)
//!
//! "RVAC" u8 version=1 u8 coding                                   the ACH object
//! body:
//!   varint viewpoint, varint grid side n, varint segments, per segment: varint to,
//!   varint entries, then per entry varint (index · 4 + whose: 0 this viewpoint, 1 `to`,
//!   2 another, whose number follows as a varint), then per entry f32 ach
//! ```
//!
//! Integers are LEB128 varints, floats little-endian. Columns rather than records: gzip finds
//! the repeats of a column (flags, shapes, depths of neighbouring tiles) where interleaved
//! fields hide them. Offsets are stored only for payloads stored once elsewhere (see
//! [`super::pack`]): a viewpoint's pack holds its background tiles' payloads, then its
//! tiles' (each tile's mesh, then its PTM ranges) in table order, so every other offset is
//! the sum of the lengths before it, and those lengths must add up to the pack's size. The usual shape of a PTM's ranges (flag 8) is ranges of consecutive levels ending at
//! level 0, each `level_dims` of the PTM's size, so neither levels nor sizes are written.
//! Checksums are the first 32 (or 64) bits of the range's BLAKE3 ([`super::range_hash32`]).
//! Depths are stored as f16 when every finite depth of the list stays finite and
//! non-negative that way, always rounded outwards. The ACH lists live in an object of their
//! own because a client that ranks tiles by what it sees never reads them (castle 128: a
//! sixth of the tables' bytes). Bodies are gzipped only when that makes them smaller.
//! Decoding never panics: bad bytes give a [`TableError`] naming the field.

use tracks::manifest::{
    AchEntry, BackgroundTile, LevelRef, ObjectRef, PackRange, PtmRef, SegmentEntry, TileEntry,
};
use tracks::{Face, TileId};

use super::split::ViewTable;

/// First bytes of every table.
pub const MAGIC: &[u8; 4] = b"RVTB";
/// Table format written and read by this crate (5: payloads may lie in earlier packs).
pub const TABLE_VERSION: u8 = 5;
/// Most earlier packs a table may point into.
pub const MAX_OTHER_PACKS: usize = 1 << 16;
/// Longest decoded table body accepted (a table of a face-4096 viewpoint is far below it).
pub const MAX_TABLE_BYTES: u64 = 64 << 20;

const KEPT: u8 = 1;
const HAS_PTM: u8 = 2;
const HAS_MESH: u8 = 4;
const USUAL_SHAPE: u8 = 8;

impl From<super::GunzipError> for TableError {
    fn from(e: super::GunzipError) -> TableError {
        TableError::Gzip(e)
    }
}

/// Why a table could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    #[error("table: {0}")]
    Gzip(super::GunzipError),
    #[error("table: not a viewpoint table (no RVTB header)")]
    Magic,
    #[error("ACH lists: not an ACH object (no RVAC header)")]
    AchMagic,
    #[error("table: format {got}, this build reads format {TABLE_VERSION}: rebuild the database with `railview build`")]
    Version { got: u8 },
    #[error("table: unknown body coding {0}")]
    Coding(u8),
    #[error("table: ends inside {what} (byte {at})")]
    Truncated { what: &'static str, at: usize },
    #[error("table: {what} at byte {at}: {message}")]
    Invalid {
        what: &'static str,
        at: usize,
        message: String,
    },
    #[error("table: {0} bytes after the end")]
    Trailing(usize),
    #[error("table is for viewpoint {got}, expected {want}")]
    Viewpoint { got: usize, want: usize },
    /// The tiles' payloads do not lie in the pack in table order (encoding) or their lengths
    /// do not add up to the pack's size (decoding).
    #[error("table: {0}")]
    Layout(String),
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn put_hash(out: &mut Vec<u8>, hex: &str, bytes: usize, what: &str) -> Result<(), TableError> {
    let ok = hex.len() == 2 * bytes
        && hex
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
    if !ok {
        return Err(TableError::Layout(format!(
            "{what}: `{hex}` is not {} lowercase hex digits",
            2 * bytes
        )));
    }
    for i in 0..bytes {
        // Two hex digits checked above.
        out.push(u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap_or(0));
    }
    Ok(())
}

fn put_tile_id(out: &mut Vec<u8>, t: TileId) {
    out.push(Face::ALL.iter().position(|&f| f == t.face).unwrap_or(0) as u8);
    put_varint(out, t.tx as u64);
    put_varint(out, t.ty as u64);
}

/// `x` as the largest f32 not above it (`up`: the smallest not below it).
fn f32_bound(x: f64, up: bool) -> f32 {
    let f = x as f32;
    if up && (f as f64) < x {
        f.next_up()
    } else if !up && (f as f64) > x {
        f.next_down()
    } else {
        f
    }
}

/// `x` (≥ 0) as f16 bits rounded outwards (`up`: the smallest f16 not below it); `None` when
/// a finite `x` has no finite f16 on that side or is negative. Infinities and NaN map to
/// themselves.
fn f16_bound(x: f64, up: bool) -> Option<u16> {
    if x.is_nan() {
        return Some(half::f16::NAN.to_bits());
    }
    if x == f64::INFINITY {
        return Some(half::f16::INFINITY.to_bits());
    }
    if x < 0.0 || x.is_infinite() {
        return None;
    }
    let mut bits = half::f16::from_f64(x).to_bits();
    let v = half::f16::from_bits(bits).to_f64();
    if up && v < x {
        bits += 1;
    } else if !up && v > x {
        // v > x ≥ 0, so bits > 0.
        bits -= 1;
    }
    half::f16::from_bits(bits).is_finite().then_some(bits)
}

/// The linear index of a tile position in a grid of side `n`, `None` on overflow.
fn tile_index(n: u64, slab: u32, t: TileId) -> Option<u64> {
    let face = Face::ALL.iter().position(|&f| f == t.face).unwrap_or(0) as u64;
    (slab as u64)
        .checked_mul(6)?
        .checked_add(face)?
        .checked_mul(n)?
        .checked_add(t.ty as u64)?
        .checked_mul(n)?
        .checked_add(t.tx as u64)
}

/// Whether a PTM's ranges have the usual shape: consecutive levels ending at level 0, each of
/// `level_dims` of the PTM's size.
fn usual_shape(p: &PtmRef) -> bool {
    let k = p.levels.len();
    p.levels.iter().enumerate().all(|(i, l)| {
        l.level as usize == k - 1 - i
            && codec::ptm::level_dims(p.width, p.height, l.level) == (l.width, l.height)
    })
}

/// A background tile as tables and packs handle it: a kept tile without mesh, depth or slab.
pub(super) fn background_entry(b: &BackgroundTile) -> TileEntry {
    TileEntry {
        tile: b.tile,
        slab: 0,
        depth_min: f64::INFINITY,
        depth_max: f64::INFINITY,
        opaque_pixels: 0,
        kept: true,
        ptm: Some(b.ptm.clone()),
        mesh: None,
        mesh_range: None,
    }
}

/// Context of encoding one table.
struct Enc<'a> {
    b: Vec<u8>,
    n: u64,
    hash_bytes: usize,
    pack: Option<&'a ObjectRef>,
    /// Earlier packs the tiles point into.
    others: Vec<&'a ObjectRef>,
    /// Bytes of the pack taken by the payloads written so far.
    cursor: u64,
}

impl Enc<'_> {
    /// The source code (see the module docs) and explicit offset of a payload of `len`
    /// bytes at `offset` of `o`; advances the pack's cursor for the next payload in it.
    fn source(
        &mut self,
        o: &ObjectRef,
        offset: u64,
        len: u64,
        what: impl Fn() -> String,
    ) -> Result<(u64, Option<u64>), TableError> {
        let end = offset.checked_add(len);
        if Some(o) == self.pack {
            if offset == self.cursor {
                self.cursor += len;
                return Ok((0, None));
            }
            if end.is_some_and(|e| e <= self.cursor) {
                return Ok((1, Some(offset)));
            }
            return Err(TableError::Layout(format!(
                "{}: at offset {offset}, expected {} (payloads in table order)",
                what(),
                self.cursor
            )));
        }
        match self.others.iter().position(|&x| x == o) {
            Some(i) if end.is_some_and(|e| e <= o.size) => Ok((2 + i as u64, Some(offset))),
            Some(_) => Err(TableError::Layout(format!(
                "{}: range {offset}+{len} outside object {} of {} bytes",
                what(),
                o.hash,
                o.size
            ))),
            None => Err(TableError::Layout(format!(
                "{}: in object {}, neither the viewpoint's pack nor one the table names",
                what(),
                o.hash
            ))),
        }
    }

    fn index(&self, slab: u32, t: TileId) -> Result<u64, TableError> {
        tile_index(self.n, slab, t).ok_or_else(|| {
            TableError::Layout(format!(
                "tile {:?} {} {} of slab {slab} cannot be numbered",
                t.face, t.tx, t.ty
            ))
        })
    }

    /// One list of tiles: its codings, its count and its columns (see the module docs).
    fn tiles(&mut self, tiles: &[TileEntry], what: &str) -> Result<(), TableError> {
        let mut indices = Vec::with_capacity(tiles.len());
        for t in tiles {
            indices.push(self.index(t.slab, t.tile)?);
        }
        let ascending = indices.windows(2).all(|w| w[0] < w[1]);
        let depths16: Option<Vec<(u16, u16)>> = tiles
            .iter()
            .map(|t| {
                Some((
                    f16_bound(t.depth_min, false)?,
                    f16_bound(t.depth_max, true)?,
                ))
            })
            .collect();
        let b = &mut self.b;
        b.push(u8::from(depths16.is_some()));
        b.push(u8::from(!ascending));
        put_varint(b, tiles.len() as u64);
        // Positions.
        let mut prev: Option<u64> = None;
        for (t, &i) in tiles.iter().zip(&indices) {
            if ascending {
                put_varint(b, prev.map_or(i, |p| i - p - 1));
                prev = Some(i);
            } else {
                put_tile_id(b, t.tile);
                put_varint(b, t.slab as u64);
            }
        }
        // Flags, checking each tile's payloads against the pack.
        for (i, t) in tiles.iter().enumerate() {
            let Some(ptm) = &t.ptm else {
                if t.mesh.is_some() || t.mesh_range.is_some() {
                    return Err(TableError::Layout(format!(
                        "{what} {i}: a mesh without a PTM has no place in the pack"
                    )));
                }
                b.push(if t.kept { KEPT } else { 0 });
                continue;
            };
            if t.mesh.is_some() && t.mesh_range.is_none() {
                return Err(TableError::Layout(format!(
                    "{what} {i}: mesh is an object of its own, not a range of a pack"
                )));
            }
            let mut flags = HAS_PTM;
            if t.kept {
                flags |= KEPT;
            }
            if t.mesh_range.is_some() {
                flags |= HAS_MESH;
            }
            if usual_shape(ptm) {
                flags |= USUAL_SHAPE;
            }
            b.push(flags);
        }
        for t in tiles {
            put_varint(b, t.opaque_pixels as u64);
        }
        match &depths16 {
            Some(d) => {
                for (lo, hi) in d {
                    b.extend_from_slice(&lo.to_le_bytes());
                    b.extend_from_slice(&hi.to_le_bytes());
                }
            }
            None => {
                for t in tiles {
                    b.extend_from_slice(&f32_bound(t.depth_min, false).to_le_bytes());
                    b.extend_from_slice(&f32_bound(t.depth_max, true).to_le_bytes());
                }
            }
        }
        // PTM shapes.
        for ptm in tiles.iter().filter_map(|t| t.ptm.as_ref()) {
            put_varint(b, ptm.width as u64);
            put_varint(b, ptm.height as u64);
            b.push(ptm.channels);
            put_varint(b, ptm.levels.len() as u64);
            if !usual_shape(ptm) {
                for l in &ptm.levels {
                    put_varint(b, l.level as u64);
                    put_varint(b, l.width as u64);
                    put_varint(b, l.height as u64);
                }
            }
        }
        // Lengths.
        for t in tiles {
            if let Some(m) = &t.mesh_range {
                put_varint(&mut self.b, m.len);
            }
            for l in t.ptm.iter().flat_map(|p| &p.levels) {
                put_varint(&mut self.b, l.len);
            }
        }
        // Sources and offsets: the pack in table order, or where a payload already lies.
        let mut offsets = Vec::new();
        for (i, t) in tiles.iter().enumerate() {
            if let Some((o, Some(m))) = t.mesh_at() {
                let (code, at) = self.source(o, m.offset, m.len, || format!("{what} {i}: mesh"))?;
                put_varint(&mut self.b, code);
                offsets.extend(at);
            }
            if let Some(p) = &t.ptm {
                let first = p.levels.first().map_or(0, |l| l.offset);
                let mut end = first;
                for l in &p.levels {
                    if l.offset != end {
                        return Err(TableError::Layout(format!(
                            "{what} {i}: PTM ranges not one after another (at {}, expected {end})",
                            l.offset
                        )));
                    }
                    end += l.len;
                }
                let (code, at) =
                    self.source(&p.object, first, end - first, || format!("{what} {i}: PTM"))?;
                put_varint(&mut self.b, code);
                offsets.extend(at);
            }
        }
        for o in offsets {
            put_varint(&mut self.b, o);
        }
        let b = &mut self.b;
        // Checksums.
        for t in tiles {
            if let Some(m) = &t.mesh_range {
                put_hash(b, &m.hash, self.hash_bytes, "mesh checksum")?;
            }
            for l in t.ptm.iter().flat_map(|p| &p.levels) {
                put_hash(b, &l.hash, self.hash_bytes, "PTM range checksum")?;
            }
        }
        Ok(())
    }
}

/// The bytes of a viewpoint's table. The payloads in `pack` lie in table order — the
/// background tiles' PTM ranges, then each tile's mesh range and PTM ranges — from offset 0
/// up to the pack's size, except those that point back at an earlier range of it; any other
/// payload lies in another object (an earlier viewpoint's pack), which the table names. A
/// PTM's ranges lie one after another; a tile without a PTM carries no payload. Checksums
/// must all be 8 or all be 16 hex digits.
pub fn encode_table(table: &ViewTable, pack: Option<&ObjectRef>) -> Result<Vec<u8>, TableError> {
    let background: Vec<TileEntry> = table.background.iter().map(background_entry).collect();
    let tiles = &table.tiles;
    // Checksum width: that of the first one, the same for all.
    let first_hash = background
        .iter()
        .chain(tiles)
        .find_map(|t| {
            t.mesh_range.as_ref().map(|m| m.hash.len()).or_else(|| {
                t.ptm
                    .as_ref()
                    .and_then(|p| p.levels.first())
                    .map(|l| l.hash.len())
            })
        })
        .unwrap_or(8);
    let hash_bytes = match first_hash {
        8 => 4,
        16 => 8,
        n => {
            return Err(TableError::Layout(format!(
                "checksums of {n} hex digits (8 or 16 expected)"
            )))
        }
    };
    // Grid side: big enough for every position of the tiles.
    let n = background
        .iter()
        .chain(tiles)
        .map(|t| t.tile)
        .map(|t| t.tx.max(t.ty) as u64 + 1)
        .max()
        .unwrap_or(0);
    // Earlier packs, in the order the tiles first point into them.
    let mut others: Vec<&ObjectRef> = Vec::new();
    for t in background.iter().chain(tiles) {
        let objects = t
            .mesh_at()
            .map(|(o, _)| o)
            .into_iter()
            .chain(t.ptm.as_ref().map(|p| &p.object));
        for o in objects {
            if Some(o) != pack && !others.contains(&o) {
                others.push(o);
            }
        }
    }
    if others.len() > MAX_OTHER_PACKS {
        return Err(TableError::Layout(format!(
            "{} earlier packs (at most {MAX_OTHER_PACKS})",
            others.len()
        )));
    }
    let mut e = Enc {
        b: Vec::with_capacity(64 + (background.len() + tiles.len()) * 24),
        n,
        hash_bytes,
        pack,
        others: Vec::new(),
        cursor: 0,
    };
    put_varint(&mut e.b, table.viewpoint as u64);
    match pack {
        Some(p) => {
            e.b.push(1);
            put_hash(&mut e.b, &p.hash, 32, "pack hash")?;
            put_varint(&mut e.b, p.size);
        }
        None => e.b.push(0),
    }
    put_varint(&mut e.b, others.len() as u64);
    for o in &others {
        put_hash(&mut e.b, &o.hash, 32, "earlier pack hash")?;
        put_varint(&mut e.b, o.size);
    }
    e.others = others;
    e.b.push(hash_bytes as u8);
    put_varint(&mut e.b, n);
    e.tiles(&background, "background tile")?;
    e.tiles(tiles, "tile")?;
    let pack_size = pack.map_or(0, |p| p.size);
    if e.cursor != pack_size {
        return Err(TableError::Layout(format!(
            "payloads take {} bytes, the pack has {pack_size}",
            e.cursor
        )));
    }
    Ok(framed(MAGIC, TABLE_VERSION, e.b))
}

/// A cursor over a table body.
struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], TableError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or(TableError::Truncated { what, at: self.at })?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u8(&mut self, what: &'static str) -> Result<u8, TableError> {
        Ok(self.take(1, what)?[0])
    }

    fn f32(&mut self, what: &'static str) -> Result<f32, TableError> {
        let s = self.take(4, what)?;
        Ok(f32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    fn f16(&mut self, what: &'static str) -> Result<f64, TableError> {
        let s = self.take(2, what)?;
        Ok(half::f16::from_bits(u16::from_le_bytes([s[0], s[1]])).to_f64())
    }

    fn varint(&mut self, what: &'static str) -> Result<u64, TableError> {
        let start = self.at;
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let byte = self.u8(what)?;
            let bits = (byte & 0x7f) as u64;
            if shift == 63 && bits > 1 {
                break;
            }
            v |= bits << shift;
            if byte & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(self.invalid(what, start, "varint longer than 64 bits"))
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, TableError> {
        let start = self.at;
        let v = self.varint(what)?;
        u32::try_from(v).map_err(|_| self.invalid(what, start, format!("{v} exceeds 32 bits")))
    }

    fn usize(&mut self, what: &'static str) -> Result<usize, TableError> {
        let start = self.at;
        let v = self.varint(what)?;
        usize::try_from(v).map_err(|_| self.invalid(what, start, format!("{v} is too large")))
    }

    /// A count of records of at least `min_bytes` each: never more than the bytes left hold.
    fn count(&mut self, what: &'static str, min_bytes: usize) -> Result<usize, TableError> {
        let start = self.at;
        let n = self.usize(what)?;
        let left = self.b.len() - self.at;
        if n > left / min_bytes.max(1) {
            return Err(self.invalid(
                what,
                start,
                format!("{n} records cannot fit in the {left} bytes left"),
            ));
        }
        Ok(n)
    }

    fn hex(&mut self, n: usize, what: &'static str) -> Result<String, TableError> {
        let s = self.take(n, what)?;
        Ok(s.iter().map(|b| format!("{b:02x}")).collect())
    }

    fn tile_id(&mut self) -> Result<TileId, TableError> {
        let start = self.at;
        let f = self.u8("tile face")?;
        let face = *Face::ALL
            .get(f as usize)
            .ok_or_else(|| self.invalid("tile face", start, format!("face {f} (0–5)")))?;
        Ok(TileId {
            face,
            tx: self.u32("tile x")?,
            ty: self.u32("tile y")?,
        })
    }

    fn invalid(&self, what: &'static str, at: usize, message: impl Into<String>) -> TableError {
        TableError::Invalid {
            what,
            at,
            message: message.into(),
        }
    }
}

/// What decoding one table needs besides its bytes.
struct Dec {
    n: u64,
    hash_bytes: usize,
    pack: Option<ObjectRef>,
    /// Earlier packs the table names.
    others: Vec<ObjectRef>,
    cursor: u64,
}

impl Dec {
    /// The object and offset of a payload of `len` bytes from its source `code` (checked
    /// against the table's objects): the next bytes of the pack, or an offset read from the
    /// offsets column, inside the pack's bytes so far or another object.
    fn place(
        &mut self,
        r: &mut Reader,
        code: u64,
        len: u64,
        what: &'static str,
    ) -> Result<(ObjectRef, u64), TableError> {
        let pack = self.pack.clone().unwrap_or(ObjectRef {
            hash: String::new(),
            size: 0,
        });
        if code == 0 {
            let offset = self.cursor;
            self.cursor = offset
                .checked_add(len)
                .ok_or_else(|| r.invalid(what, r.at, "lengths overflow"))?;
            return Ok((pack, offset));
        }
        let at = r.at;
        let offset = r.varint("payload offset")?;
        let end = offset
            .checked_add(len)
            .ok_or_else(|| r.invalid("payload offset", at, "offset overflows"))?;
        if code == 1 {
            // Only an earlier range of the pack; the pack's size is checked at the end.
            if end > self.cursor {
                return Err(r.invalid(
                    "payload offset",
                    at,
                    format!(
                        "{what} at {offset}+{len}, beyond the {} bytes of the pack before it",
                        self.cursor
                    ),
                ));
            }
            return Ok((pack, offset));
        }
        let o = &self.others[(code - 2) as usize];
        if end > o.size {
            return Err(r.invalid(
                "payload offset",
                at,
                format!(
                    "{what} at {offset}+{len}, outside an earlier pack of {} bytes",
                    o.size
                ),
            ));
        }
        Ok((o.clone(), offset))
    }

    fn position(
        &self,
        r: &Reader,
        at: usize,
        index: u64,
        what: &'static str,
    ) -> Result<(u32, TileId), TableError> {
        let n = self.n;
        let bad = || r.invalid(what, at, format!("{index} is outside a grid of side {n}"));
        if n == 0 {
            return Err(bad());
        }
        let tx = u32::try_from(index % n).map_err(|_| bad())?;
        let ty = u32::try_from((index / n) % n).map_err(|_| bad())?;
        let fs = index / n / n;
        let slab = u32::try_from(fs / 6).map_err(|_| bad())?;
        Ok((
            slab,
            TileId {
                face: Face::ALL[(fs % 6) as usize],
                tx,
                ty,
            },
        ))
    }

    /// One list of tiles (see [`Enc::tiles`]).
    fn tiles(&mut self, r: &mut Reader) -> Result<Vec<TileEntry>, TableError> {
        let depth16 = match r.u8("depth coding")? {
            c @ (0 | 1) => c == 1,
            c => return Err(r.invalid("depth coding", r.at - 1, format!("{c} (0 or 1)"))),
        };
        let explicit = match r.u8("position coding")? {
            c @ (0 | 1) => c == 1,
            c => return Err(r.invalid("position coding", r.at - 1, format!("{c} (0 or 1)"))),
        };
        // Every tile takes at least a position, flags, opaque pixels and two f16 depths.
        let count = r.count("tile count", 7)?;
        let mut tiles: Vec<TileEntry> = Vec::with_capacity(count);
        let mut next = 0u64;
        for _ in 0..count {
            let (slab, tile) = if explicit {
                let tile = r.tile_id()?;
                (r.u32("slab")?, tile)
            } else {
                let at = r.at;
                let gap = r.varint("tile position")?;
                let index = next
                    .checked_add(gap)
                    .ok_or_else(|| r.invalid("tile position", at, "positions overflow"))?;
                next = index.saturating_add(1);
                self.position(r, at, index, "tile position")?
            };
            tiles.push(TileEntry {
                tile,
                slab,
                depth_min: 0.0,
                depth_max: 0.0,
                opaque_pixels: 0,
                kept: false,
                ptm: None,
                mesh: None,
                mesh_range: None,
            });
        }
        let mut flags = Vec::with_capacity(count);
        for t in &mut tiles {
            let at = r.at;
            let f = r.u8("tile flags")?;
            if f & !(KEPT | HAS_PTM | HAS_MESH | USUAL_SHAPE) != 0
                || (f & (HAS_MESH | USUAL_SHAPE) != 0 && f & HAS_PTM == 0)
            {
                return Err(r.invalid("tile flags", at, format!("{f:#04x}")));
            }
            if f & HAS_PTM != 0 && self.pack.is_none() && self.others.is_empty() {
                return Err(r.invalid(
                    "tile flags",
                    at,
                    "a tile with a PTM in a table that names no pack",
                ));
            }
            t.kept = f & KEPT != 0;
            flags.push(f);
        }
        for t in &mut tiles {
            t.opaque_pixels = r.u32("opaque_pixels")?;
        }
        for t in &mut tiles {
            if depth16 {
                t.depth_min = r.f16("depth_min")?;
                t.depth_max = r.f16("depth_max")?;
            } else {
                t.depth_min = r.f32("depth_min")? as f64;
                t.depth_max = r.f32("depth_max")? as f64;
            }
        }
        let placeholder = ObjectRef {
            hash: String::new(),
            size: 0,
        };
        for (t, &f) in tiles.iter_mut().zip(&flags) {
            if f & HAS_PTM == 0 {
                continue;
            }
            let pack = &placeholder;
            let width = r.u32("PTM width")?;
            let height = r.u32("PTM height")?;
            let channels = r.u8("PTM channels")?;
            let at = r.at;
            let ranges = r.count("PTM range count", 2)?;
            let mut levels = Vec::with_capacity(ranges);
            for i in 0..ranges {
                let (level, w, h) = if f & USUAL_SHAPE != 0 {
                    let level = (ranges - 1 - i) as u32;
                    if level >= 32 {
                        return Err(r.invalid("PTM range count", at, format!("{ranges} levels")));
                    }
                    let (w, h) = codec::ptm::level_dims(width, height, level);
                    (level, w, h)
                } else {
                    (
                        r.u32("PTM level")?,
                        r.u32("PTM level width")?,
                        r.u32("PTM level height")?,
                    )
                };
                levels.push(LevelRef {
                    level,
                    width: w,
                    height: h,
                    offset: 0,
                    len: 0,
                    hash: String::new(),
                });
            }
            t.ptm = Some(PtmRef {
                object: pack.clone(),
                width,
                height,
                channels,
                levels,
            });
        }
        // Lengths.
        for (t, &f) in tiles.iter_mut().zip(&flags) {
            if f & HAS_MESH != 0 {
                t.mesh_range = Some(PackRange {
                    offset: 0,
                    len: r.varint("mesh length")?,
                    hash: String::new(),
                });
            }
            if let Some(p) = &mut t.ptm {
                for l in &mut p.levels {
                    l.len = r.varint("PTM range length")?;
                }
            }
        }
        // Sources, then the offsets of those not next in the pack.
        let mut sources = Vec::new();
        for t in &tiles {
            for _ in 0..usize::from(t.mesh_range.is_some()) + usize::from(t.ptm.is_some()) {
                let at = r.at;
                let code = r.varint("payload source")?;
                if code >= 2 + self.others.len() as u64 || (code < 2 && self.pack.is_none()) {
                    return Err(r.invalid(
                        "payload source",
                        at,
                        format!(
                            "{code}, but the table names {} earlier packs",
                            self.others.len()
                        ),
                    ));
                }
                sources.push(code);
            }
        }
        let mut sources = sources.into_iter();
        for t in &mut tiles {
            let mesh_len = t.mesh_range.as_ref().map(|m| m.len);
            if let Some(len) = mesh_len {
                let code = sources.next().unwrap_or(0);
                let (object, offset) = self.place(r, code, len, "mesh")?;
                let m = t.mesh_range.as_mut().expect("mesh present");
                m.offset = offset;
                t.mesh = Some(object);
            }
            if let Some(p) = &mut t.ptm {
                let len = p
                    .levels
                    .iter()
                    .try_fold(0u64, |a, l| a.checked_add(l.len))
                    .ok_or_else(|| r.invalid("PTM range length", r.at, "lengths overflow"))?;
                let code = sources.next().unwrap_or(0);
                let (object, mut offset) = self.place(r, code, len, "PTM")?;
                for l in &mut p.levels {
                    l.offset = offset;
                    offset += l.len;
                }
                p.object = object;
            }
            // A mesh in the PTM's object is named by the PTM alone.
            if t.mesh.is_some() && t.mesh.as_ref() == t.ptm.as_ref().map(|p| &p.object) {
                t.mesh = None;
            }
        }
        for t in &mut tiles {
            if let Some(m) = &mut t.mesh_range {
                m.hash = r.hex(self.hash_bytes, "mesh checksum")?;
            }
            if let Some(p) = &mut t.ptm {
                for l in &mut p.levels {
                    l.hash = r.hex(self.hash_bytes, "PTM range checksum")?;
                }
            }
        }
        Ok(tiles)
    }
}

/// Decodes a table object's bytes (already checked against its hash) for viewpoint `want`.
pub fn decode_table(bytes: &[u8], want: usize) -> Result<ViewTable, TableError> {
    let mut unzipped = Vec::new();
    let mut r = open_body(bytes, MAGIC, TABLE_VERSION, want, &mut unzipped)?;
    let viewpoint = want;
    let pack = match r.u8("pack flag")? {
        0 => None,
        1 => Some(ObjectRef {
            hash: r.hex(32, "pack hash")?,
            size: r.varint("pack size")?,
        }),
        f => return Err(r.invalid("pack flag", r.at - 1, format!("{f} (0 or 1)"))),
    };
    // Each earlier pack: a 32-byte hash and a varint size.
    let count = r.count("earlier pack count", 33)?;
    if count > MAX_OTHER_PACKS {
        return Err(r.invalid(
            "earlier pack count",
            r.at,
            format!("{count} (at most {MAX_OTHER_PACKS})"),
        ));
    }
    let mut others = Vec::with_capacity(count);
    for _ in 0..count {
        others.push(ObjectRef {
            hash: r.hex(32, "earlier pack hash")?,
            size: r.varint("earlier pack size")?,
        });
    }
    let hash_bytes = match r.u8("checksum bytes")? {
        c @ (4 | 8) => c as usize,
        c => return Err(r.invalid("checksum bytes", r.at - 1, format!("{c} (4 or 8)"))),
    };
    let n = r.varint("grid side")?;
    let mut d = Dec {
        n,
        hash_bytes,
        pack,
        others,
        cursor: 0,
    };
    let at = r.at;
    let background = d
        .tiles(&mut r)?
        .into_iter()
        .map(|t| match t.ptm {
            Some(ptm) if t.kept && t.mesh_range.is_none() && t.slab == 0 => {
                Ok(BackgroundTile { tile: t.tile, ptm })
            }
            _ => Err(r.invalid(
                "background tiles",
                at,
                "a background tile is a kept PTM without mesh in slab 0",
            )),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let tiles = d.tiles(&mut r)?;
    let pack_size = d.pack.as_ref().map_or(0, |p| p.size);
    if d.cursor != pack_size {
        return Err(TableError::Layout(format!(
            "the tiles' lengths add up to {} bytes, the pack has {pack_size}",
            d.cursor
        )));
    }
    if r.at != r.b.len() {
        return Err(TableError::Trailing(r.b.len() - r.at));
    }
    Ok(ViewTable {
        viewpoint,
        background,
        tiles,
        segments: Vec::new(),
    })
}

/// First bytes of every ACH object.
pub const ACH_MAGIC: &[u8; 4] = b"RVAC";
/// ACH object format written and read by this crate.
pub const ACH_VERSION: u8 = 1;

/// The bytes of the ACH object of viewpoint `viewpoint`: the ACH lists of the segments that
/// start there (see the module docs).
pub fn encode_ach(viewpoint: usize, segments: &[SegmentEntry]) -> Result<Vec<u8>, TableError> {
    let n = segments
        .iter()
        .flat_map(|s| s.ach.iter().map(|a| a.tile))
        .map(|t| t.tx.max(t.ty) as u64 + 1)
        .max()
        .unwrap_or(0);
    let mut b = Vec::with_capacity(16 + segments.iter().map(|s| s.ach.len() * 6).sum::<usize>());
    put_varint(&mut b, viewpoint as u64);
    put_varint(&mut b, n);
    put_varint(&mut b, segments.len() as u64);
    for s in segments {
        put_varint(&mut b, s.to as u64);
        put_varint(&mut b, s.ach.len() as u64);
        for a in &s.ach {
            let i = tile_index(n, a.slab, a.tile)
                .and_then(|i| i.checked_mul(4))
                .ok_or_else(|| {
                    TableError::Layout(format!(
                        "ACH entry {:?} {} {} of slab {} cannot be numbered",
                        a.tile.face, a.tile.tx, a.tile.ty, a.slab
                    ))
                })?;
            if a.viewpoint == viewpoint {
                put_varint(&mut b, i);
            } else if a.viewpoint == s.to {
                put_varint(&mut b, i + 1);
            } else {
                put_varint(&mut b, i + 2);
                put_varint(&mut b, a.viewpoint as u64);
            }
        }
        for a in &s.ach {
            b.extend_from_slice(&(a.ach as f32).to_le_bytes());
        }
    }
    Ok(framed(ACH_MAGIC, ACH_VERSION, b))
}

/// Header, coding byte and the body, gzipped when that is smaller.
fn framed(magic: &[u8; 4], version: u8, b: Vec<u8>) -> Vec<u8> {
    let mut out = Vec::with_capacity(b.len() + 6);
    out.extend_from_slice(magic);
    out.push(version);
    match super::gzip(&b) {
        Ok(gz) if gz.len() < b.len() => {
            out.push(1);
            out.extend_from_slice(&gz);
        }
        _ => {
            out.push(0);
            out.extend_from_slice(&b);
        }
    }
    out
}

/// The body of a framed object: checked magic and version, un-gzipped within the limit.
fn unframe<'a>(
    bytes: &'a [u8],
    magic: &[u8; 4],
    version: u8,
    unzipped: &'a mut Vec<u8>,
) -> Result<&'a [u8], TableError> {
    if bytes.len() < 6 || &bytes[..4] != magic {
        return Err(if magic == MAGIC {
            TableError::Magic
        } else {
            TableError::AchMagic
        });
    }
    if bytes[4] != version {
        return Err(TableError::Version { got: bytes[4] });
    }
    match bytes[5] {
        0 => {
            if bytes.len() as u64 - 6 > MAX_TABLE_BYTES {
                return Err(TableError::Gzip(super::GunzipError::TooLarge {
                    limit: MAX_TABLE_BYTES,
                }));
            }
            Ok(&bytes[6..])
        }
        1 => {
            *unzipped = super::gunzip_limited(&bytes[6..], MAX_TABLE_BYTES)?;
            Ok(&unzipped[..])
        }
        c => Err(TableError::Coding(c)),
    }
}

/// A framed object's body ([`unframe`]) read up to just after its viewpoint number, which
/// must be `want`.
fn open_body<'a>(
    bytes: &'a [u8],
    magic: &[u8; 4],
    version: u8,
    want: usize,
    unzipped: &'a mut Vec<u8>,
) -> Result<Reader<'a>, TableError> {
    let body = unframe(bytes, magic, version, unzipped)?;
    let mut r = Reader { b: body, at: 0 };
    let viewpoint = r.usize("viewpoint")?;
    if viewpoint != want {
        return Err(TableError::Viewpoint {
            got: viewpoint,
            want,
        });
    }
    Ok(r)
}

/// Decodes an ACH object's bytes (already checked against its hash) for viewpoint `want`.
pub fn decode_ach(bytes: &[u8], want: usize) -> Result<Vec<SegmentEntry>, TableError> {
    let mut unzipped = Vec::new();
    let mut r = open_body(bytes, ACH_MAGIC, ACH_VERSION, want, &mut unzipped)?;
    let viewpoint = want;
    let d = Dec {
        n: r.varint("grid side")?,
        hash_bytes: 4,
        pack: None,
        others: Vec::new(),
        cursor: 0,
    };
    let ns = r.count("segment count", 2)?;
    let mut segments = Vec::with_capacity(ns);
    for _ in 0..ns {
        let to = r.usize("segment end")?;
        // Each entry takes at least a one-byte code and an f32.
        let ne = r.count("ACH entry count", 5)?;
        let mut ach = Vec::with_capacity(ne);
        for _ in 0..ne {
            let at = r.at;
            let code = r.varint("ACH tile")?;
            let vp = match code % 4 {
                0 => viewpoint,
                1 => to,
                2 => r.usize("ACH viewpoint")?,
                w => return Err(r.invalid("ACH tile", at, format!("owner code {w} (0–2)"))),
            };
            let (slab, tile) = d.position(&r, at, code / 4, "ACH tile")?;
            ach.push(AchEntry {
                viewpoint: vp,
                slab,
                tile,
                ach: 0.0,
            });
        }
        for a in &mut ach {
            a.ach = r.f32("ACH value")? as f64;
        }
        segments.push(SegmentEntry {
            from: viewpoint,
            to,
            ach,
        });
    }
    if r.at != r.b.len() {
        return Err(TableError::Trailing(r.b.len() - r.at));
    }
    Ok(segments)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hex(n: usize, seed: u64) -> String {
        (0..n)
            .map(|i| {
                let d = (seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(i as u64 * 0x9e37_79b9)
                    >> 11)
                    % 16;
                char::from_digit(d as u32, 16).unwrap()
            })
            .collect()
    }

    prop_compose! {
        /// A tile before its place in the pack is known (offsets 0; see `lay_out`).
        fn tile()(face in 0usize..6, tx in 0u32..300, ty in 0u32..300, slab in 0u32..4,
                  d0 in 0.0f64..1e4, dd in 0.0f64..1e4, opaque in any::<u32>(), kept in any::<bool>(),
                  seed in any::<u64>(), mesh in any::<bool>(), levels in 0usize..7,
                  sizes in proptest::collection::vec(1u64..50_000, 8)) -> TileEntry {
            let levels: Vec<LevelRef> = (0..levels).map(|l| LevelRef {
                level: (levels - 1 - l) as u32, width: 1 << l, height: 1 << l,
                offset: 0, len: sizes[l], hash: hex(16, seed ^ l as u64),
            }).collect();
            let has_ptm = !levels.is_empty();
            TileEntry {
                tile: TileId { face: Face::ALL[face], tx, ty },
                slab,
                depth_min: d0,
                depth_max: d0 + dd,
                opaque_pixels: opaque,
                kept,
                ptm: has_ptm.then(|| PtmRef {
                    object: ObjectRef { hash: String::new(), size: 0 },
                    width: 1 << levels.len(),
                    height: 1 << levels.len(),
                    channels: 4,
                    levels,
                }),
                mesh: None,
                mesh_range: (mesh && has_ptm).then(|| PackRange {
                    offset: 0, len: sizes[7], hash: hex(16, !seed),
                }),
            }
        }
    }

    /// Places the tiles' payloads back to back and names the pack.
    fn lay_out(tiles: &mut [TileEntry], seed: u64) -> Option<ObjectRef> {
        let mut cursor = 0;
        for t in tiles.iter_mut() {
            if let Some(m) = &mut t.mesh_range {
                m.offset = cursor;
                cursor += m.len;
            }
            if let Some(p) = &mut t.ptm {
                for l in &mut p.levels {
                    l.offset = cursor;
                    cursor += l.len;
                }
            }
        }
        let pack = tiles.iter().any(|t| t.ptm.is_some()).then(|| ObjectRef {
            hash: hex(64, seed),
            size: cursor,
        });
        for t in tiles.iter_mut() {
            if let Some(p) = &mut t.ptm {
                p.object = pack.clone().unwrap();
            }
        }
        pack
    }

    /// [`lay_out`] with some payloads elsewhere: by `choices` per tile (mesh, then PTM) in the
    /// pack in order, pointing back at the pack's first bytes, or in one of two earlier packs.
    /// A mesh names its object only when the PTM's object is another one.
    fn lay_out_shared(tiles: &mut [TileEntry], choices: &[u8], seed: u64) -> Option<ObjectRef> {
        let others = [1u64, 2].map(|k| ObjectRef {
            hash: hex(64, seed.wrapping_add(k)),
            size: 1 << 30,
        });
        let own = ObjectRef {
            hash: hex(64, seed),
            size: 0,
        };
        let mut cursor = 0;
        let mut place = |len: u64, c: u8| -> (ObjectRef, u64) {
            match c % 4 {
                2 => (others[0].clone(), u64::from(c) * 1000),
                3 if len <= cursor => (own.clone(), 0),
                3 => (others[1].clone(), 7),
                _ => {
                    cursor += len;
                    (own.clone(), cursor - len)
                }
            }
        };
        for (t, &c) in tiles.iter_mut().zip(choices.iter().cycle()) {
            let mut mesh_obj = None;
            if let Some(m) = &mut t.mesh_range {
                let (o, at) = place(m.len, c);
                m.offset = at;
                mesh_obj = Some(o);
            }
            if let Some(p) = &mut t.ptm {
                let len: u64 = p.levels.iter().map(|l| l.len).sum();
                let (o, mut at) = place(len, c / 4);
                for l in &mut p.levels {
                    l.offset = at;
                    at += l.len;
                }
                p.object = o;
            }
            t.mesh = mesh_obj.filter(|o| Some(o) != t.ptm.as_ref().map(|p| &p.object));
        }
        let used = tiles.iter().any(|t| {
            t.ptm.as_ref().is_some_and(|p| p.object == own)
                || t.mesh_at().is_some_and(|(o, _)| *o == own)
        });
        let pack = used.then(|| ObjectRef {
            hash: own.hash.clone(),
            size: cursor,
        });
        for t in tiles.iter_mut() {
            for o in t
                .ptm
                .as_mut()
                .map(|p| &mut p.object)
                .into_iter()
                .chain(t.mesh.as_mut())
            {
                if *o == own {
                    *o = pack.clone().unwrap();
                }
            }
        }
        pack
    }

    /// What a table keeps of a tile: depths as f16 bounds when all fit, else f32; ACH as f32.
    fn as_stored(mut t: ViewTable) -> ViewTable {
        let f16 = |x: f64, up: bool| f16_bound(x, up).map(|b| half::f16::from_bits(b).to_f64());
        let all16 = t
            .tiles
            .iter()
            .all(|d| f16(d.depth_min, false).is_some() && f16(d.depth_max, true).is_some());
        for tile in &mut t.tiles {
            if all16 {
                tile.depth_min = f16(tile.depth_min, false).unwrap();
                tile.depth_max = f16(tile.depth_max, true).unwrap();
            } else {
                tile.depth_min = f32_bound(tile.depth_min, false) as f64;
                tile.depth_max = f32_bound(tile.depth_max, true) as f64;
            }
        }
        // The ACH lists travel in an object of their own.
        t.segments.clear();
        t
    }

    /// What an ACH object keeps of the lists: values as f32.
    fn ach_as_stored(mut segments: Vec<SegmentEntry>) -> Vec<SegmentEntry> {
        for s in &mut segments {
            for a in &mut s.ach {
                a.ach = a.ach as f32 as f64;
            }
        }
        segments
    }

    fn sample(
        viewpoint: usize,
        tiles: Vec<TileEntry>,
        seed: u64,
    ) -> (ViewTable, Option<ObjectRef>) {
        // Every third tile with a PTM lends it to a background tile too (payloads first).
        let mut all: Vec<TileEntry> = tiles
            .iter()
            .filter(|t| t.ptm.is_some())
            .step_by(3)
            .map(|t| {
                background_entry(&BackgroundTile {
                    tile: t.tile,
                    ptm: t.ptm.clone().unwrap(),
                })
            })
            .collect();
        let nb = all.len();
        all.extend(tiles);
        let pack = lay_out(&mut all, seed);
        let tiles = all.split_off(nb);
        let background = all
            .into_iter()
            .map(|t| BackgroundTile {
                tile: t.tile,
                ptm: t.ptm.unwrap(),
            })
            .collect();
        let ach = tiles
            .iter()
            .enumerate()
            .map(|(i, t)| AchEntry {
                viewpoint: viewpoint + i % 3,
                slab: t.slab,
                tile: t.tile,
                ach: 1.0 / (i as f64 + 1.5),
            })
            .collect();
        let segments = vec![SegmentEntry {
            from: viewpoint,
            to: viewpoint + 1,
            ach,
        }];
        (
            ViewTable {
                viewpoint,
                background,
                tiles,
                segments,
            },
            pack,
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        #[test]
        fn tables_round_trip(viewpoint in 0usize..100_000,
                             tiles in proptest::collection::vec(tile(), 0..40), seed in any::<u64>()) {
            let (table, pack) = sample(viewpoint, tiles, seed);
            let bytes = encode_table(&table, pack.as_ref()).unwrap();
            let got = decode_table(&bytes, viewpoint).unwrap();
            prop_assert_eq!(&got, &as_stored(table.clone()));
            // Depth bounds never shrink.
            for (g, t) in got.tiles.iter().zip(&table.tiles) {
                prop_assert!(g.depth_min <= t.depth_min && g.depth_max >= t.depth_max);
            }
            let other = matches!(decode_table(&bytes, viewpoint + 1),
                                 Err(TableError::Viewpoint { .. }));
            prop_assert!(other);
            // The ACH object: the same lists (f32 values), never taken for another viewpoint
            // or for a table.
            let ach = encode_ach(viewpoint, &table.segments).unwrap();
            prop_assert_eq!(decode_ach(&ach, viewpoint).unwrap(),
                            ach_as_stored(table.segments.clone()));
            let other = matches!(decode_ach(&ach, viewpoint + 1),
                                 Err(TableError::Viewpoint { .. }));
            prop_assert!(other);
            prop_assert!(matches!(decode_table(&ach, viewpoint), Err(TableError::Magic)));
            prop_assert!(matches!(decode_ach(&bytes, viewpoint), Err(TableError::AchMagic)));
        }

        /// Payloads stored once: some in earlier packs at any offset, some pointing back at an
        /// earlier range of the pack; the rest in the pack in table order.
        #[test]
        fn payloads_stored_elsewhere_round_trip(tiles in proptest::collection::vec(tile(), 0..30),
                                                 choices in proptest::collection::vec(0u8..16, 30),
                                                 seed in any::<u64>()) {
            let (mut table, _) = sample(9, tiles, seed);
            let pack = lay_out_shared(&mut table.tiles, &choices, seed);
            // Background tiles stay in the pack, first.
            let mut all: Vec<TileEntry> = table.background.iter().map(background_entry).collect();
            let mut cursor = 0;
            for t in &mut all {
                let p = t.ptm.as_mut().unwrap();
                for l in &mut p.levels {
                    l.offset = cursor;
                    cursor += l.len;
                }
            }
            // Shift the tiles' own-pack payloads past the background.
            let own = pack.as_ref().map(|p| p.hash.clone());
            let mut size = pack.as_ref().map_or(0, |p| p.size) + cursor;
            let any_background = !all.is_empty();
            if own.is_none() && any_background {
                size = cursor;
            }
            let pack = (own.is_some() || any_background).then(|| ObjectRef {
                hash: own.clone().unwrap_or_else(|| hex(64, seed.wrapping_add(7))),
                size,
            });
            for t in &mut table.tiles {
                let in_pack = |o: &ObjectRef| Some(&o.hash) == own.as_ref();
                if let Some(p) = &mut t.ptm {
                    if in_pack(&p.object) {
                        for l in &mut p.levels {
                            l.offset += cursor;
                        }
                    }
                }
                let mesh_in_pack = t.mesh_at().is_some_and(|(o, _)| in_pack(o));
                if let (true, Some(m)) = (mesh_in_pack, &mut t.mesh_range) {
                    m.offset += cursor;
                }
                let objects = t.ptm.as_mut().map(|p| &mut p.object).into_iter().chain(t.mesh.as_mut());
                for o in objects {
                    if in_pack(o) {
                        *o = pack.clone().unwrap();
                    }
                }
            }
            table.background = all
                .into_iter()
                .map(|t| BackgroundTile {
                    tile: t.tile,
                    ptm: PtmRef {
                        object: pack.clone().unwrap(),
                        ..t.ptm.unwrap()
                    },
                })
                .collect();
            let bytes = encode_table(&table, pack.as_ref()).unwrap();
            let got = decode_table(&bytes, 9).unwrap();
            prop_assert_eq!(&got, &as_stored(table.clone()));
        }

        /// Tiles in grid order (as `railview build` writes them) take the gap coding of
        /// positions; checksums of 32 bits; depths beyond f16 fall back to f32.
        #[test]
        fn sorted_tables_round_trip(tiles in proptest::collection::vec(tile(), 0..40),
                                    far in any::<bool>(), seed in any::<u64>()) {
            let mut tiles = tiles;
            tiles.sort_by_key(|t| tile_index(301, t.slab, t.tile));
            tiles.dedup_by_key(|t| tile_index(301, t.slab, t.tile));
            for t in &mut tiles {
                if let Some(m) = &mut t.mesh_range {
                    m.hash.truncate(8);
                }
                for l in t.ptm.iter_mut().flat_map(|p| p.levels.iter_mut()) {
                    l.hash.truncate(8);
                }
                if far {
                    t.depth_max *= 100.0;
                }
            }
            let (table, pack) = sample(11, tiles, seed);
            let bytes = encode_table(&table, pack.as_ref()).unwrap();
            let got = decode_table(&bytes, 11).unwrap();
            prop_assert_eq!(&got, &as_stored(table.clone()));
            for (g, t) in got.tiles.iter().zip(&table.tiles) {
                prop_assert!(g.depth_min <= t.depth_min && g.depth_max >= t.depth_max);
            }
        }

        #[test]
        fn damaged_or_cut_tables_never_panic(tiles in proptest::collection::vec(tile(), 1..12),
                                             at in any::<usize>(), bit in 0u8..8, cut in any::<usize>()) {
            let (table, pack) = sample(3, tiles, 7);
            let bytes = encode_table(&table, pack.as_ref()).unwrap();
            let mut flipped = bytes.clone();
            let i = at % flipped.len();
            flipped[i] ^= 1 << bit;
            let _ = decode_table(&flipped, 3);
            let _ = decode_table(&bytes[..cut % bytes.len()], 3);
        }

        #[test]
        fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = decode_table(&bytes, 0);
            let mut with_header = b"RVTB\x05\x00".to_vec();
            with_header.extend_from_slice(&bytes);
            let _ = decode_table(&with_header, 0);
            let _ = decode_ach(&bytes, 0);
            let mut with_header = b"RVAC\x01\x00".to_vec();
            with_header.extend_from_slice(&bytes);
            let _ = decode_ach(&with_header, 0);
        }

        #[test]
        fn damaged_or_cut_ach_objects_never_panic(tiles in proptest::collection::vec(tile(), 1..12),
                                                  at in any::<usize>(), bit in 0u8..8, cut in any::<usize>()) {
            let (table, _) = sample(3, tiles, 7);
            let bytes = encode_ach(3, &table.segments).unwrap();
            let mut flipped = bytes.clone();
            let i = at % flipped.len();
            flipped[i] ^= 1 << bit;
            let _ = decode_ach(&flipped, 3);
            let _ = decode_ach(&bytes[..cut % bytes.len()], 3);
        }
    }

    fn one_tile_table() -> Vec<u8> {
        let tile = TileEntry {
            tile: TileId {
                face: Face::ALL[2],
                tx: 1,
                ty: 2,
            },
            slab: 1,
            depth_min: 1.0,
            depth_max: 2.0,
            opaque_pixels: 9,
            kept: true,
            ptm: Some(PtmRef {
                object: ObjectRef {
                    hash: String::new(),
                    size: 0,
                },
                width: 8,
                height: 8,
                channels: 4,
                levels: vec![LevelRef {
                    level: 0,
                    width: 8,
                    height: 8,
                    offset: 0,
                    len: 100,
                    hash: hex(16, 1),
                }],
            }),
            mesh: None,
            mesh_range: None,
        };
        let (table, pack) = sample(5, vec![tile], 9);
        encode_table(&table, pack.as_ref()).unwrap()
    }

    /// The long fuzz run of the table decoder (tables whose payloads lie in the pack, earlier
    /// in it, or in earlier packs; damaged, cut or garbage):
    /// `TABLE_FUZZ_CASES=1000000 cargo test --release -p db --lib table_long_fuzz -- --ignored`.
    #[test]
    #[ignore = "long fuzz run; set TABLE_FUZZ_CASES"]
    fn table_long_fuzz() {
        use proptest::test_runner::{Config, TestRunner};
        let cases = std::env::var("TABLE_FUZZ_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(20_000);
        let mut runner = TestRunner::new(Config {
            cases,
            failure_persistence: None,
            ..Config::default()
        });
        let strategy = (
            proptest::collection::vec(tile(), 0..10),
            proptest::collection::vec(0u8..16, 10),
            any::<u64>(),
            proptest::collection::vec((any::<usize>(), any::<u8>()), 0..4),
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 0..64),
        );
        runner
            .run(&strategy, |(tiles, choices, seed, flips, cut, junk)| {
                let (mut table, _) = sample(4, tiles, seed);
                table.background.clear();
                let pack = lay_out_shared(&mut table.tiles, &choices, seed);
                let bytes = encode_table(&table, pack.as_ref()).unwrap();
                prop_assert_eq!(decode_table(&bytes, 4).unwrap(), as_stored(table));
                let mut damaged = bytes.clone();
                for (at, x) in flips {
                    let i = at % damaged.len();
                    damaged[i] ^= x.max(1);
                }
                damaged.truncate(cut % (damaged.len() + 1));
                let _ = decode_table(&damaged, 4);
                let mut garbage = b"RVTB\x05\x00".to_vec();
                garbage.extend_from_slice(&junk);
                let _ = decode_table(&garbage, 0);
                Ok(())
            })
            .unwrap();
    }

    #[test]
    fn named_bad_inputs_give_named_errors() {
        assert!(matches!(decode_table(b"", 0), Err(TableError::Magic)));
        assert!(matches!(
            decode_table(b"{\"v\":0}", 0),
            Err(TableError::Magic)
        ));
        assert!(matches!(
            decode_table(b"RVTB\x02\x00", 0),
            Err(TableError::Version { got: 2 })
        ));
        assert!(matches!(
            decode_table(b"RVTB\x05\x07xx", 0),
            Err(TableError::Coding(7))
        ));
        assert!(matches!(
            decode_table(b"RVTB\x05\x00", 0),
            Err(TableError::Truncated { .. })
        ));
        // A varint that never ends.
        assert!(matches!(
            decode_table(
                b"RVTB\x05\x00\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff",
                0
            ),
            Err(TableError::Invalid {
                what: "viewpoint",
                ..
            })
        ));
        // A tile count far beyond the bytes that follow: refused before any allocation.
        let mut b = b"RVTB\x05\x00\x00\x00\x00\x04\x00\x00\x00".to_vec();
        b.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0x0f]);
        assert!(matches!(
            decode_table(&b, 0),
            Err(TableError::Invalid {
                what: "tile count",
                ..
            })
        ));
        // Trailing bytes after a good body.
        let good = one_tile_table();
        let mut plain = good[..6].to_vec();
        plain[5] = 0;
        let body = if good[5] == 1 {
            crate::gunzip_limited(&good[6..], MAX_TABLE_BYTES).unwrap()
        } else {
            good[6..].to_vec()
        };
        plain.extend_from_slice(&body);
        assert_eq!(decode_table(&plain, 5).unwrap().tiles.len(), 1);
        plain.push(0);
        assert!(matches!(
            decode_table(&plain, 5),
            Err(TableError::Trailing(1))
        ));
    }

    #[test]
    fn lengths_must_add_up_to_the_pack() {
        let (mut table, pack) = sample(1, Vec::new(), 0);
        assert!(pack.is_none());
        let bytes = encode_table(&table, None).unwrap();
        assert!(decode_table(&bytes, 1).unwrap().tiles.is_empty());
        // A pack bigger than the tiles' payloads is refused on both sides.
        let big = ObjectRef {
            hash: hex(64, 3),
            size: 10,
        };
        assert!(matches!(
            encode_table(&table, Some(&big)),
            Err(TableError::Layout(_))
        ));
        // A tile whose PTM is not in the pack, or whose mesh is an object of its own.
        let bytes = one_tile_table();
        let mut t = decode_table(&bytes, 5).unwrap();
        let pack = t.tiles[0].ptm.as_ref().unwrap().object.clone();
        t.tiles[0].mesh = Some(pack.clone());
        assert!(matches!(
            encode_table(&t, Some(&pack)),
            Err(TableError::Layout(_))
        ));
        table.viewpoint = 5;
        table.tiles = t.tiles.clone();
        table.tiles[0].mesh = None;
        let other = ObjectRef {
            hash: hex(64, 4),
            size: 100,
        };
        assert!(matches!(
            encode_table(&table, Some(&other)),
            Err(TableError::Layout(_))
        ));
    }

    #[test]
    fn a_huge_table_is_refused_within_the_limit() {
        let zeros = vec![0u8; (MAX_TABLE_BYTES + 10) as usize];
        let mut b = b"RVTB\x05\x01".to_vec();
        b.extend_from_slice(&crate::gzip(&zeros).unwrap());
        assert!(matches!(
            decode_table(&b, 0),
            Err(TableError::Gzip(crate::GunzipError::TooLarge { .. }))
        ));
    }
}
