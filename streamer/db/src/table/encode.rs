//! Encoding of a viewpoint's table (the layout is in the [module docs](super)).

use tracks::manifest::{ObjectRef, TileEntry};
use tracks::{Face, TileId};

use super::{
    background_entry, tile_index, usual_shape, TableError, HAS_MESH, HAS_PTM, KEPT, MAGIC,
    MAX_OTHER_PACKS, TABLE_VERSION, USUAL_SHAPE,
};
use crate::split::ViewTable;

pub(super) fn put_varint(out: &mut Vec<u8>, mut v: u64) {
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
pub(super) fn f32_bound(x: f64, up: bool) -> f32 {
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
pub(super) fn f16_bound(x: f64, up: bool) -> Option<u16> {
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
        put_positions(b, tiles, &indices, ascending);
        put_flags(b, tiles, what)?;
        for t in tiles {
            put_varint(b, t.opaque_pixels as u64);
        }
        put_depths(b, tiles, depths16.as_deref());
        put_shapes(b, tiles);
        put_lengths(b, tiles);
        self.sources(tiles, what)?;
        put_checksums(&mut self.b, tiles, self.hash_bytes)
    }

    /// The sources column, then the offsets column: the pack in table order, or where a
    /// payload already lies.
    fn sources(&mut self, tiles: &[TileEntry], what: &str) -> Result<(), TableError> {
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
        Ok(())
    }
}

/// The positions column: gaps between ascending indices, or each tile's place written out.
fn put_positions(b: &mut Vec<u8>, tiles: &[TileEntry], indices: &[u64], ascending: bool) {
    let mut prev: Option<u64> = None;
    for (t, &i) in tiles.iter().zip(indices) {
        if ascending {
            put_varint(b, prev.map_or(i, |p| i - p - 1));
            prev = Some(i);
        } else {
            put_tile_id(b, t.tile);
            put_varint(b, t.slab as u64);
        }
    }
}

/// The flags column, checking each tile's payloads against the pack.
fn put_flags(b: &mut Vec<u8>, tiles: &[TileEntry], what: &str) -> Result<(), TableError> {
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
    Ok(())
}

/// The depths column: f16 bounds when every tile has them, else f32 bounds.
fn put_depths(b: &mut Vec<u8>, tiles: &[TileEntry], depths16: Option<&[(u16, u16)]>) {
    match depths16 {
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
}

/// The PTM shapes column.
fn put_shapes(b: &mut Vec<u8>, tiles: &[TileEntry]) {
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
}

/// The lengths column.
fn put_lengths(b: &mut Vec<u8>, tiles: &[TileEntry]) {
    for t in tiles {
        if let Some(m) = &t.mesh_range {
            put_varint(b, m.len);
        }
        for l in t.ptm.iter().flat_map(|p| &p.levels) {
            put_varint(b, l.len);
        }
    }
}

/// The checksums column.
fn put_checksums(
    b: &mut Vec<u8>,
    tiles: &[TileEntry],
    hash_bytes: usize,
) -> Result<(), TableError> {
    for t in tiles {
        if let Some(m) = &t.mesh_range {
            put_hash(b, &m.hash, hash_bytes, "mesh checksum")?;
        }
        for l in t.ptm.iter().flat_map(|p| &p.levels) {
            put_hash(b, &l.hash, hash_bytes, "PTM range checksum")?;
        }
    }
    Ok(())
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

/// Header, coding byte and the body, gzipped when that is smaller.
pub(super) fn framed(magic: &[u8; 4], version: u8, b: Vec<u8>) -> Vec<u8> {
    let mut out = Vec::with_capacity(b.len() + 6);
    out.extend_from_slice(magic);
    out.push(version);
    match crate::gzip(&b) {
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
