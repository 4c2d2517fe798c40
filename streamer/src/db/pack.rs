//! Packs: one object per viewpoint holding the payloads of its background tiles and tiles —
//! each background tile's PTM level groups, then each tile's mesh and PTM level groups, tile
//! after tile in table order — so that the viewpoint's table names
//! one object once and describes every payload by a length and a 32-bit checksum
//! ([`super::table`]). A static host serves a tile's part as a byte range of the pack.
//!
//! [`pack_tiles`] builds a pack from tiles whose payloads are stored anywhere (objects of
//! their own as `railview build` writes them, or an earlier pack) and returns the tiles
//! rewritten to point into it. Tiny coarse level groups are merged with the next finer one
//! as long as the range stays within [`MERGE_UP_TO`] bytes: they always travel together
//! anyway, and each range costs a checksum in the table and a piece in a request.

use tracks::manifest::{BackgroundTile, LevelRef, ObjectRef, PackRange, PtmRef, TileEntry};

use super::{hash_hex, hash_matches, range_hash32, DbError};

/// Consecutive level groups are merged into one range while it stays within this many bytes
/// (the coarse levels of a tile: far below one round trip's worth at the link speeds the
/// walk is measured at — 2 ms at 2 Mbit/s against a 50 ms latency). Every range costs every
/// client a length and a checksum in the table, fetched or not. On castle 128 (32 px tiles,
/// format-4 tables, 2 Mbit/s walk): 160 bytes → tables 166.9 kB, 256 → 150.7 kB, 512 →
/// 117.0 kB, with the same first frame (0.67 s) and needed fraction with prefetch (0.986).
pub const MERGE_UP_TO: u64 = 512;

/// Reads `len` bytes at `offset` of a stored object (checked by the caller's means).
pub type ReadFn<'a> = dyn FnMut(&ObjectRef, u64, u64) -> Result<Vec<u8>, DbError> + 'a;

/// The pack of `tiles` (in their order) and the tiles rewritten to point into it: every PTM
/// names the pack as its object, level groups merged ([`MERGE_UP_TO`]) with 32-bit
/// checksums, meshes become [`TileEntry::mesh_range`]. A tile without a PTM keeps no payload
/// (no client can draw a mesh without its colour). Source ranges that carry a checksum are
/// checked against it.
pub fn pack_tiles(
    tiles: &[TileEntry],
    read: &mut ReadFn<'_>,
) -> Result<(Vec<u8>, Vec<TileEntry>), DbError> {
    let mut pack: Vec<u8> = Vec::new();
    let mut out = Vec::with_capacity(tiles.len());
    for t in tiles {
        let mut e = t.clone();
        e.mesh = None;
        e.mesh_range = None;
        let Some(p) = &t.ptm else {
            out.push(e);
            continue;
        };
        let mesh = match (&t.mesh, &t.mesh_range) {
            (Some(m), _) => Some(read(m, 0, m.size)?),
            (None, Some(r)) => Some(checked(read(&p.object, r.offset, r.len)?, &r.hash, p)?),
            (None, None) => None,
        };
        if let Some(b) = mesh {
            e.mesh_range = Some(PackRange {
                offset: pack.len() as u64,
                len: b.len() as u64,
                hash: range_hash32(&b),
            });
            pack.extend_from_slice(&b);
        }
        let mut levels: Vec<LevelRef> = Vec::with_capacity(p.levels.len());
        for l in &p.levels {
            let b = checked(read(&p.object, l.offset, l.len)?, &l.hash, p)?;
            let offset = pack.len() as u64;
            pack.extend_from_slice(&b);
            match levels.last_mut() {
                Some(last) if last.len + l.len <= MERGE_UP_TO => {
                    last.len += l.len;
                    last.level = l.level;
                    last.width = l.width;
                    last.height = l.height;
                }
                _ => levels.push(LevelRef {
                    offset,
                    hash: String::new(),
                    ..l.clone()
                }),
            }
        }
        for l in &mut levels {
            l.hash = range_hash32(&pack[l.offset as usize..(l.offset + l.len) as usize]);
        }
        e.ptm = Some(PtmRef {
            levels,
            ..p.clone()
        });
        out.push(e);
    }
    let obj = ObjectRef {
        hash: hash_hex(&pack),
        size: pack.len() as u64,
    };
    for e in &mut out {
        if let Some(p) = &mut e.ptm {
            p.object = obj.clone();
        }
    }
    Ok((pack, out))
}

/// A viewpoint's pack and its background tiles and tiles pointing into it.
pub type PackedViewpoint = (Vec<u8>, Vec<BackgroundTile>, Vec<TileEntry>);

/// [`pack_tiles`] for a whole viewpoint: its background tiles' payloads first, then its
/// tiles'; returns the pack and both lists rewritten to point into it.
pub fn pack_viewpoint(
    background: &[BackgroundTile],
    tiles: &[TileEntry],
    read: &mut ReadFn<'_>,
) -> Result<PackedViewpoint, DbError> {
    let mut all: Vec<TileEntry> = background
        .iter()
        .map(super::table::background_entry)
        .collect();
    all.extend_from_slice(tiles);
    let (pack, mut out) = pack_tiles(&all, read)?;
    let tiles = out.split_off(background.len());
    let background = background
        .iter()
        .zip(out)
        .map(|(b, e)| BackgroundTile {
            tile: b.tile,
            ptm: e.ptm.unwrap_or_else(|| b.ptm.clone()),
        })
        .collect();
    Ok((pack, background, tiles))
}

/// `bytes` when they match `hash` (an empty hash: nothing to check against).
fn checked(bytes: Vec<u8>, hash: &str, p: &PtmRef) -> Result<Vec<u8>, DbError> {
    if hash.is_empty() || hash_matches(&bytes, hash) {
        Ok(bytes)
    } else {
        Err(DbError::Request(format!(
            "a range of object {} does not match its checksum {hash}",
            p.object.hash
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use tracks::{Face, TileId};

    fn tile(tx: u32, ptm: Option<PtmRef>, mesh: Option<ObjectRef>) -> TileEntry {
        TileEntry {
            tile: TileId {
                face: Face::ALL[0],
                tx,
                ty: 0,
            },
            slab: 0,
            depth_min: 1.0,
            depth_max: 2.0,
            opaque_pixels: 4,
            kept: true,
            ptm,
            mesh,
            mesh_range: None,
        }
    }

    fn level(level: u32, offset: u64, len: u64, bytes: &[u8]) -> LevelRef {
        LevelRef {
            level,
            width: 32 >> level,
            height: 32 >> level,
            offset,
            len,
            hash: range_hash32(&bytes[offset as usize..(offset + len) as usize]),
        }
    }

    #[test]
    fn packs_in_order_merging_tiny_coarse_levels_and_repacks_to_the_same_bytes() {
        let ptm_bytes: Vec<u8> = (0..2000u32).map(|i| (i * 7) as u8).collect();
        let mesh_bytes: Vec<u8> = (0..300u32).map(|i| (i * 3) as u8).collect();
        let ptm_obj = ObjectRef {
            hash: hash_hex(&ptm_bytes),
            size: 2000,
        };
        let mesh_obj = ObjectRef {
            hash: hash_hex(&mesh_bytes),
            size: 300,
        };
        let levels = vec![
            level(4, 0, 40, &ptm_bytes),
            level(3, 40, 50, &ptm_bytes),
            level(2, 90, 50, &ptm_bytes),
            level(1, 140, 400, &ptm_bytes),
            level(0, 540, 1460, &ptm_bytes),
        ];
        let ptm = PtmRef {
            object: ptm_obj.clone(),
            width: 32,
            height: 32,
            channels: 4,
            levels,
        };
        let tiles = vec![
            tile(0, Some(ptm.clone()), Some(mesh_obj.clone())),
            tile(1, None, Some(mesh_obj.clone())),
            tile(2, Some(ptm), None),
        ];
        let mut store: HashMap<String, Vec<u8>> = HashMap::new();
        store.insert(ptm_obj.hash.clone(), ptm_bytes.clone());
        store.insert(mesh_obj.hash.clone(), mesh_bytes.clone());
        let mut read = |o: &ObjectRef, off: u64, len: u64| {
            Ok(store[&o.hash][off as usize..(off + len) as usize].to_vec())
        };
        let (pack, out) = pack_tiles(&tiles, &mut read).unwrap();
        assert_eq!(pack.len(), 300 + 2000 + 2000);
        assert_eq!(&pack[..300], &mesh_bytes[..]);
        assert_eq!(&pack[300..2300], &ptm_bytes[..]);
        let p0 = out[0].ptm.as_ref().unwrap();
        // 40 + 50 + 50 merged (140 bytes; with the 400 they would pass 512), then 400 and
        // 1460 alone.
        assert_eq!(
            p0.levels
                .iter()
                .map(|l| (l.level, l.offset, l.len))
                .collect::<Vec<_>>(),
            vec![(2, 300, 140), (1, 440, 400), (0, 840, 1460)]
        );
        assert_eq!(p0.object.hash, hash_hex(&pack));
        assert!(out[1].mesh_range.is_none() && out[1].mesh.is_none());
        assert_eq!(out[2].ptm.as_ref().unwrap().levels[0].offset, 2300);
        // Packing a pack again gives the same pack and tiles.
        let mut read2 = |o: &ObjectRef, off: u64, len: u64| {
            assert_eq!(o.hash, hash_hex(&pack));
            Ok(pack[off as usize..(off + len) as usize].to_vec())
        };
        let (again, out2) = pack_tiles(&out, &mut read2).unwrap();
        assert_eq!(again, pack);
        assert_eq!(out2, out);
    }

    #[test]
    fn a_damaged_source_range_is_refused() {
        let bytes = vec![5u8; 100];
        let obj = ObjectRef {
            hash: hash_hex(&bytes),
            size: 100,
        };
        let mut l = level(0, 0, 100, &bytes);
        l.hash = range_hash32(b"other");
        let t = tile(
            0,
            Some(PtmRef {
                object: obj,
                width: 32,
                height: 32,
                channels: 4,
                levels: vec![l],
            }),
            None,
        );
        let mut read = |_: &ObjectRef, off: u64, len: u64| {
            Ok(bytes[off as usize..(off + len) as usize].to_vec())
        };
        assert!(pack_tiles(&[t], &mut read).is_err());
    }
}
