//! The binary viewpoint table (format 3): what a client needs to know about one viewpoint's
//! tiles, in a few bytes per tile.
//!
//! ```text
//! "RVTB" u8 version=3 u8 coding (0 plain, 1 gzip of the body)    header, never compressed
//! body:
//!   varint viewpoint
//!   u8 has_pack [32 B pack BLAKE3, varint pack size]             the pack, named once
//!   varint tiles, per tile:
//!     u8 face, varint tx, varint ty, varint slab,
//!     f32 depth_min (rounded down), f32 depth_max (rounded up),
//!     varint opaque_pixels, u8 flags (1 kept, 2 PTM, 4 mesh)
//!     mesh:  varint len, 8 B checksum
//!     PTM:   varint width, varint height, u8 channels, varint ranges,
//!            per range: varint level, varint width, varint height, varint len, 8 B checksum
//!   varint segments, per segment: varint to, varint entries,
//!     per entry: varint viewpoint, varint slab, u8 face, varint tx, varint ty, f32 ach
//! ```
//!
//! Integers are LEB128 varints, floats little-endian. Offsets are not stored: a viewpoint's
//! pack holds its tiles' payloads in table order (each tile's mesh, then its PTM ranges), so
//! every offset is the sum of the lengths before it, and the lengths must add up to the
//! pack's size. Checksums are the first 64 bits of the range's BLAKE3
//! ([`super::range_hash64`]). The body is gzipped only when that makes it smaller. Decoding
//! never panics: bad bytes give a [`TableError`] naming the field.

use tracks::manifest::{AchEntry, LevelRef, ObjectRef, PackRange, PtmRef, SegmentEntry, TileEntry};
use tracks::{Face, TileId};

use super::split::ViewTable;

/// First bytes of every table.
pub const MAGIC: &[u8; 4] = b"RVTB";
/// Table format written and read by this crate.
pub const TABLE_VERSION: u8 = 3;
/// Longest decoded table body accepted (a table of a face-4096 viewpoint is far below it).
pub const MAX_TABLE_BYTES: u64 = 64 << 20;

const KEPT: u8 = 1;
const HAS_PTM: u8 = 2;
const HAS_MESH: u8 = 4;

/// Why a table could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    #[error("table: {0}")]
    Gzip(#[from] super::GunzipError),
    #[error("table: not a viewpoint table (no RVTB header)")]
    Magic,
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

/// The bytes of a viewpoint's table. Every tile with a PTM must have its payloads in `pack`
/// (its `ptm.object`) in table order: mesh range then PTM ranges, from offset 0 up to the
/// pack's size; a tile without a PTM carries no payload.
pub fn encode_table(table: &ViewTable, pack: Option<&ObjectRef>) -> Result<Vec<u8>, TableError> {
    let mut b = Vec::with_capacity(64 + table.tiles.len() * 48);
    put_varint(&mut b, table.viewpoint as u64);
    match pack {
        Some(p) => {
            b.push(1);
            put_hash(&mut b, &p.hash, 32, "pack hash")?;
            put_varint(&mut b, p.size);
        }
        None => b.push(0),
    }
    put_varint(&mut b, table.tiles.len() as u64);
    let mut cursor = 0u64;
    for (i, t) in table.tiles.iter().enumerate() {
        put_tile_id(&mut b, t.tile);
        put_varint(&mut b, t.slab as u64);
        b.extend_from_slice(&f32_bound(t.depth_min, false).to_le_bytes());
        b.extend_from_slice(&f32_bound(t.depth_max, true).to_le_bytes());
        put_varint(&mut b, t.opaque_pixels as u64);
        let Some(ptm) = &t.ptm else {
            if t.mesh.is_some() || t.mesh_range.is_some() {
                return Err(TableError::Layout(format!(
                    "tile {i}: a mesh without a PTM has no place in the pack"
                )));
            }
            b.push(if t.kept { KEPT } else { 0 });
            continue;
        };
        if Some(&ptm.object) != pack {
            return Err(TableError::Layout(format!(
                "tile {i}: PTM in object {}, not in the viewpoint's pack",
                ptm.object.hash
            )));
        }
        if t.mesh.is_some() {
            return Err(TableError::Layout(format!(
                "tile {i}: mesh is an object of its own, not a range of the pack"
            )));
        }
        let mut flags = HAS_PTM;
        if t.kept {
            flags |= KEPT;
        }
        if t.mesh_range.is_some() {
            flags |= HAS_MESH;
        }
        b.push(flags);
        let mut take = |offset: u64, len: u64, what: &str| {
            if offset != cursor {
                return Err(TableError::Layout(format!(
                    "tile {i}: {what} at offset {offset}, expected {cursor} (payloads in table order)"
                )));
            }
            cursor += len;
            Ok(())
        };
        if let Some(m) = &t.mesh_range {
            take(m.offset, m.len, "mesh")?;
            put_varint(&mut b, m.len);
            put_hash(&mut b, &m.hash, 8, "mesh checksum")?;
        }
        put_varint(&mut b, ptm.width as u64);
        put_varint(&mut b, ptm.height as u64);
        b.push(ptm.channels);
        put_varint(&mut b, ptm.levels.len() as u64);
        for l in &ptm.levels {
            take(l.offset, l.len, "PTM range")?;
            put_varint(&mut b, l.level as u64);
            put_varint(&mut b, l.width as u64);
            put_varint(&mut b, l.height as u64);
            put_varint(&mut b, l.len);
            put_hash(&mut b, &l.hash, 8, "PTM range checksum")?;
        }
    }
    let pack_size = pack.map_or(0, |p| p.size);
    if cursor != pack_size {
        return Err(TableError::Layout(format!(
            "payloads take {cursor} bytes, the pack has {pack_size}"
        )));
    }
    put_varint(&mut b, table.segments.len() as u64);
    for s in &table.segments {
        put_varint(&mut b, s.to as u64);
        put_varint(&mut b, s.ach.len() as u64);
        for a in &s.ach {
            put_varint(&mut b, a.viewpoint as u64);
            put_varint(&mut b, a.slab as u64);
            put_tile_id(&mut b, a.tile);
            b.extend_from_slice(&(a.ach as f32).to_le_bytes());
        }
    }
    let mut out = Vec::with_capacity(b.len() + 6);
    out.extend_from_slice(MAGIC);
    out.push(TABLE_VERSION);
    let gz = super::gzip(&b).map_err(|e| TableError::Layout(format!("gzip: {e}")))?;
    if gz.len() < b.len() {
        out.push(1);
        out.extend_from_slice(&gz);
    } else {
        out.push(0);
        out.extend_from_slice(&b);
    }
    Ok(out)
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

/// Decodes a table object's bytes (already checked against its hash) for viewpoint `want`.
pub fn decode_table(bytes: &[u8], want: usize) -> Result<ViewTable, TableError> {
    if bytes.len() < 6 || &bytes[..4] != MAGIC {
        return Err(TableError::Magic);
    }
    if bytes[4] != TABLE_VERSION {
        return Err(TableError::Version { got: bytes[4] });
    }
    let unzipped;
    let body = match bytes[5] {
        0 => {
            if bytes.len() as u64 - 6 > MAX_TABLE_BYTES {
                return Err(TableError::Gzip(super::GunzipError::TooLarge {
                    limit: MAX_TABLE_BYTES,
                }));
            }
            &bytes[6..]
        }
        1 => {
            unzipped = super::gunzip_limited(&bytes[6..], MAX_TABLE_BYTES)?;
            &unzipped[..]
        }
        c => return Err(TableError::Coding(c)),
    };
    let mut r = Reader { b: body, at: 0 };
    let viewpoint = r.usize("viewpoint")?;
    if viewpoint != want {
        return Err(TableError::Viewpoint {
            got: viewpoint,
            want,
        });
    }
    let pack = match r.u8("pack flag")? {
        0 => None,
        1 => Some(ObjectRef {
            hash: r.hex(32, "pack hash")?,
            size: r.varint("pack size")?,
        }),
        f => return Err(r.invalid("pack flag", r.at - 1, format!("{f} (0 or 1)"))),
    };
    let n = r.count("tile count", 12)?;
    let mut tiles = Vec::with_capacity(n);
    let mut cursor = 0u64;
    let mut place = |r: &Reader, len: u64, what: &'static str| {
        let offset = cursor;
        cursor = cursor
            .checked_add(len)
            .ok_or_else(|| r.invalid(what, r.at, "lengths overflow"))?;
        Ok::<u64, TableError>(offset)
    };
    for _ in 0..n {
        let tile = r.tile_id()?;
        let slab = r.u32("slab")?;
        let depth_min = r.f32("depth_min")? as f64;
        let depth_max = r.f32("depth_max")? as f64;
        let opaque_pixels = r.u32("opaque_pixels")?;
        let flags_at = r.at;
        let flags = r.u8("tile flags")?;
        if flags & !(KEPT | HAS_PTM | HAS_MESH) != 0
            || (flags & HAS_MESH != 0 && flags & HAS_PTM == 0)
        {
            return Err(r.invalid("tile flags", flags_at, format!("{flags:#04x}")));
        }
        let mut mesh_range = None;
        let mut ptm = None;
        if flags & HAS_PTM != 0 {
            let pack = pack.as_ref().ok_or_else(|| {
                r.invalid(
                    "tile flags",
                    flags_at,
                    "a tile with a PTM in a table without a pack",
                )
            })?;
            if flags & HAS_MESH != 0 {
                let len = r.varint("mesh length")?;
                let offset = place(&r, len, "mesh length")?;
                mesh_range = Some(PackRange {
                    offset,
                    len,
                    hash: r.hex(8, "mesh checksum")?,
                });
            }
            let width = r.u32("PTM width")?;
            let height = r.u32("PTM height")?;
            let channels = r.u8("PTM channels")?;
            let count = r.count("PTM range count", 12)?;
            let mut levels = Vec::with_capacity(count);
            for _ in 0..count {
                let level = r.u32("PTM level")?;
                let lw = r.u32("PTM level width")?;
                let lh = r.u32("PTM level height")?;
                let len = r.varint("PTM range length")?;
                let offset = place(&r, len, "PTM range length")?;
                levels.push(LevelRef {
                    level,
                    width: lw,
                    height: lh,
                    offset,
                    len,
                    hash: r.hex(8, "PTM range checksum")?,
                });
            }
            ptm = Some(PtmRef {
                object: pack.clone(),
                width,
                height,
                channels,
                levels,
            });
        }
        tiles.push(TileEntry {
            tile,
            slab,
            depth_min,
            depth_max,
            opaque_pixels,
            kept: flags & KEPT != 0,
            ptm,
            mesh: None,
            mesh_range,
        });
    }
    let pack_size = pack.as_ref().map_or(0, |p| p.size);
    if cursor != pack_size {
        return Err(TableError::Layout(format!(
            "the tiles' lengths add up to {cursor} bytes, the pack has {pack_size}"
        )));
    }
    let ns = r.count("segment count", 2)?;
    let mut segments = Vec::with_capacity(ns);
    for _ in 0..ns {
        let to = r.usize("segment end")?;
        let ne = r.count("ACH entry count", 9)?;
        let mut ach = Vec::with_capacity(ne);
        for _ in 0..ne {
            ach.push(AchEntry {
                viewpoint: r.usize("ACH viewpoint")?,
                slab: r.u32("ACH slab")?,
                tile: r.tile_id()?,
                ach: r.f32("ACH value")? as f64,
            });
        }
        segments.push(SegmentEntry {
            from: viewpoint,
            to,
            ach,
        });
    }
    if r.at != body.len() {
        return Err(TableError::Trailing(body.len() - r.at));
    }
    Ok(ViewTable {
        viewpoint,
        tiles,
        segments,
    })
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

    /// What a table keeps of a tile: depths as f32 bounds, ACH as f32.
    fn as_stored(mut t: ViewTable) -> ViewTable {
        for tile in &mut t.tiles {
            tile.depth_min = f32_bound(tile.depth_min, false) as f64;
            tile.depth_max = f32_bound(tile.depth_max, true) as f64;
        }
        for s in &mut t.segments {
            for a in &mut s.ach {
                a.ach = a.ach as f32 as f64;
            }
        }
        t
    }

    fn sample(
        viewpoint: usize,
        tiles: Vec<TileEntry>,
        seed: u64,
    ) -> (ViewTable, Option<ObjectRef>) {
        let mut tiles = tiles;
        let pack = lay_out(&mut tiles, seed);
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
            let mut with_header = b"RVTB\x03\x00".to_vec();
            with_header.extend_from_slice(&bytes);
            let _ = decode_table(&with_header, 0);
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
            decode_table(b"RVTB\x03\x07xx", 0),
            Err(TableError::Coding(7))
        ));
        assert!(matches!(
            decode_table(b"RVTB\x03\x00", 0),
            Err(TableError::Truncated { .. })
        ));
        // A varint that never ends.
        assert!(matches!(
            decode_table(
                b"RVTB\x03\x00\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff",
                0
            ),
            Err(TableError::Invalid {
                what: "viewpoint",
                ..
            })
        ));
        // A tile count far beyond the bytes that follow: refused before any allocation.
        let mut b = b"RVTB\x03\x00\x00\x00".to_vec();
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
            crate::db::gunzip_limited(&good[6..], MAX_TABLE_BYTES).unwrap()
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
        let mut b = b"RVTB\x03\x01".to_vec();
        b.extend_from_slice(&crate::db::gzip(&zeros).unwrap());
        assert!(matches!(
            decode_table(&b, 0),
            Err(TableError::Gzip(crate::db::GunzipError::TooLarge { .. }))
        ));
    }
}
