//! Decoding of a viewpoint's table (the layout is in the [module docs](super)); the
//! [`Reader`] and the tile numbering are shared with the ACH object.

use tracks::manifest::{BackgroundTile, LevelRef, ObjectRef, PackRange, PtmRef, TileEntry};
use tracks::{Face, TileId};

use super::{
    TableError, HAS_MESH, HAS_PTM, KEPT, MAGIC, MAX_OTHER_PACKS, MAX_TABLE_BYTES, TABLE_VERSION,
    USUAL_SHAPE,
};
use crate::split::ViewTable;

/// A cursor over a table body.
pub(super) struct Reader<'a> {
    pub(super) b: &'a [u8],
    pub(super) at: usize,
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

    pub(super) fn f32(&mut self, what: &'static str) -> Result<f32, TableError> {
        let s = self.take(4, what)?;
        Ok(f32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    fn f16(&mut self, what: &'static str) -> Result<f64, TableError> {
        let s = self.take(2, what)?;
        Ok(half::f16::from_bits(u16::from_le_bytes([s[0], s[1]])).to_f64())
    }

    pub(super) fn varint(&mut self, what: &'static str) -> Result<u64, TableError> {
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

    pub(super) fn usize(&mut self, what: &'static str) -> Result<usize, TableError> {
        let start = self.at;
        let v = self.varint(what)?;
        usize::try_from(v).map_err(|_| self.invalid(what, start, format!("{v} is too large")))
    }

    /// A count of records of at least `min_bytes` each: never more than the bytes left hold.
    pub(super) fn count(
        &mut self,
        what: &'static str,
        min_bytes: usize,
    ) -> Result<usize, TableError> {
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

    pub(super) fn invalid(
        &self,
        what: &'static str,
        at: usize,
        message: impl Into<String>,
    ) -> TableError {
        TableError::Invalid {
            what,
            at,
            message: message.into(),
        }
    }
}

/// What decoding one table needs besides its bytes.
pub(super) struct Dec {
    pub(super) n: u64,
    pub(super) hash_bytes: usize,
    pub(super) pack: Option<ObjectRef>,
    /// Earlier packs the table names.
    pub(super) others: Vec<ObjectRef>,
    pub(super) cursor: u64,
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

    pub(super) fn position(
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

    /// One list of tiles (see [`Enc::tiles`](super::encode)): its codings, its count and
    /// its columns.
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
        let mut tiles = self.positions(r, count, explicit)?;
        let flags = self.flags(r, &mut tiles)?;
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
        read_shapes(r, &mut tiles, &flags)?;
        read_lengths(r, &mut tiles, &flags)?;
        self.sources(r, &mut tiles)?;
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

    /// The positions column: `count` tiles at their places, every other field empty.
    fn positions(
        &self,
        r: &mut Reader,
        count: usize,
        explicit: bool,
    ) -> Result<Vec<TileEntry>, TableError> {
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
        Ok(tiles)
    }

    /// The flags column: sets `kept` and returns every tile's flags.
    fn flags(&self, r: &mut Reader, tiles: &mut [TileEntry]) -> Result<Vec<u8>, TableError> {
        let mut flags = Vec::with_capacity(tiles.len());
        for t in tiles {
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
        Ok(flags)
    }

    /// The sources column, then the offsets of those not next in the pack: places every
    /// tile's mesh and PTM ranges.
    fn sources(&mut self, r: &mut Reader, tiles: &mut [TileEntry]) -> Result<(), TableError> {
        let mut sources = Vec::new();
        for t in tiles.iter() {
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
        for t in tiles {
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
        Ok(())
    }
}

/// The PTM shapes column: each PTM tile's size, channels and ranges (their levels and sizes
/// read or, in the usual shape, implied), the object still a placeholder.
fn read_shapes(r: &mut Reader, tiles: &mut [TileEntry], flags: &[u8]) -> Result<(), TableError> {
    let placeholder = ObjectRef {
        hash: String::new(),
        size: 0,
    };
    for (t, &f) in tiles.iter_mut().zip(flags) {
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
    Ok(())
}

/// The lengths column.
fn read_lengths(r: &mut Reader, tiles: &mut [TileEntry], flags: &[u8]) -> Result<(), TableError> {
    for (t, &f) in tiles.iter_mut().zip(flags) {
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
    Ok(())
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
                return Err(TableError::Gzip(crate::GunzipError::TooLarge {
                    limit: MAX_TABLE_BYTES,
                }));
            }
            Ok(&bytes[6..])
        }
        1 => {
            *unzipped = crate::gunzip_limited(&bytes[6..], MAX_TABLE_BYTES)?;
            Ok(&unzipped[..])
        }
        c => Err(TableError::Coding(c)),
    }
}

/// A framed object's body ([`unframe`]) read up to just after its viewpoint number, which
/// must be `want`.
pub(super) fn open_body<'a>(
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
