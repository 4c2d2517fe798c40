//! Packs: one object per viewpoint holding the payloads of its background tiles and tiles —
//! each background tile's PTM level groups, then each tile's mesh and PTM level groups, tile
//! after tile in table order — so that the viewpoint's table names
//! one object once and describes every payload by a length and a 32-bit checksum
//! ([`super::table`]). A static host serves a tile's part as a byte range of the pack.
//!
//! Every payload (a mesh, or a PTM's level groups together) is stored once in a database:
//! the first viewpoint, in track order, whose pack needs it holds it, and every later tile
//! with the same bytes — a sky tile seen from every viewpoint, a far wall that no step along
//! the track changes — points at that range ([`Payloads`]). This is the one placement rule;
//! the tables name the earlier packs their tiles point into.
//!
//! [`pack_tiles`] builds a pack from tiles whose payloads are stored anywhere (objects of
//! their own as `railview build` writes them, or an earlier pack) and returns the tiles
//! rewritten to point into it. Tiny coarse level groups are merged with the next finer one
//! as long as the range stays within [`MERGE_UP_TO`] bytes: they always travel together
//! anyway, and each range costs a checksum in the table and a piece in a request.

use std::collections::HashMap;

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

/// Where a payload already lies.
#[derive(Clone, Debug)]
enum Placed {
    Mesh(ObjectRef, PackRange),
    Ptm(ObjectRef, Vec<LevelRef>),
}

/// The payloads stored so far in a database's packs, by the BLAKE3 of their bytes: a later
/// tile with the same bytes points at them instead of storing them again.
#[derive(Debug, Default)]
pub struct Payloads {
    placed: HashMap<[u8; 32], Placed>,
    /// Bytes not stored again, and payloads pointed at.
    pub bytes_shared: u64,
    pub shared: u64,
}

impl Payloads {
    /// Forgets where the payloads stored so far lie (the counters stay): the next pack
    /// stores its own copy of each.
    pub fn forget_placed(&mut self) {
        self.placed.clear();
    }
}

/// The own pack before its hash is known (replaced once the pack is complete).
fn pending() -> ObjectRef {
    ObjectRef {
        hash: String::new(),
        size: 0,
    }
}

/// The pack of `tiles` (in their order) and the tiles rewritten to point into it: every PTM
/// names the pack as its object, level groups merged ([`MERGE_UP_TO`]) with 32-bit
/// checksums, meshes become [`TileEntry::mesh_range`] — except payloads `payloads` already
/// holds, which point where they lie (an earlier pack, or an earlier range of this one). A
/// tile without a PTM keeps no payload (no client can draw a mesh without its colour). Source
/// ranges that carry a checksum are checked against it. The new payloads join `payloads`.
pub fn pack_tiles(
    tiles: &[TileEntry],
    read: &mut ReadFn<'_>,
    payloads: &mut Payloads,
) -> Result<(Vec<u8>, Vec<TileEntry>), DbError> {
    let mut pack: Vec<u8> = Vec::new();
    let mut out = Vec::with_capacity(tiles.len());
    // Payloads placed in this pack, by hash, before its own hash is known.
    let mut fresh: Vec<[u8; 32]> = Vec::new();
    for t in tiles {
        let mut e = t.clone();
        e.mesh = None;
        e.mesh_range = None;
        let Some(p) = &t.ptm else {
            out.push(e);
            continue;
        };
        let mesh = match t.mesh_at() {
            Some((o, None)) => Some(read(o, 0, o.size)?),
            Some((o, Some(r))) => Some(checked(read(o, r.offset, r.len)?, &r.hash, o)?),
            None => None,
        };
        if let Some(b) = mesh {
            let key = *blake3::hash(&b).as_bytes();
            match payloads.placed.get(&key) {
                Some(Placed::Mesh(o, r)) => {
                    payloads.bytes_shared += b.len() as u64;
                    payloads.shared += 1;
                    e.mesh = Some(o.clone());
                    e.mesh_range = Some(r.clone());
                }
                _ => {
                    let r = PackRange {
                        offset: pack.len() as u64,
                        len: b.len() as u64,
                        hash: range_hash32(&b),
                    };
                    pack.extend_from_slice(&b);
                    payloads
                        .placed
                        .insert(key, Placed::Mesh(pending(), r.clone()));
                    fresh.push(key);
                    e.mesh = Some(pending());
                    e.mesh_range = Some(r);
                }
            }
        }
        let mut bytes = Vec::new();
        for l in &p.levels {
            bytes.push(checked(
                read(&p.object, l.offset, l.len)?,
                &l.hash,
                &p.object,
            )?);
        }
        let key = {
            let mut h = blake3::Hasher::new();
            for b in &bytes {
                h.update(b);
            }
            *h.finalize().as_bytes()
        };
        if let Some(Placed::Ptm(o, levels)) = payloads.placed.get(&key) {
            payloads.bytes_shared += bytes.iter().map(|b| b.len() as u64).sum::<u64>();
            payloads.shared += 1;
            e.ptm = Some(PtmRef {
                object: o.clone(),
                levels: levels.clone(),
                ..p.clone()
            });
            out.push(e);
            continue;
        }
        let mut levels: Vec<LevelRef> = Vec::with_capacity(p.levels.len());
        for (l, b) in p.levels.iter().zip(&bytes) {
            let offset = pack.len() as u64;
            pack.extend_from_slice(b);
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
        payloads
            .placed
            .insert(key, Placed::Ptm(pending(), levels.clone()));
        fresh.push(key);
        e.ptm = Some(PtmRef {
            object: pending(),
            levels,
            ..p.clone()
        });
        out.push(e);
    }
    let obj = ObjectRef {
        hash: hash_hex(&pack),
        size: pack.len() as u64,
    };
    let own = |o: &mut ObjectRef| {
        if o.hash.is_empty() {
            *o = obj.clone();
        }
    };
    for e in &mut out {
        if let Some(p) = &mut e.ptm {
            own(&mut p.object);
        }
        if let Some(m) = &mut e.mesh {
            own(m);
        }
        // A mesh in the same object as its PTM is named by the PTM alone.
        if e.mesh.is_some() && e.mesh == e.ptm.as_ref().map(|p| p.object.clone()) {
            e.mesh = None;
        }
    }
    for key in fresh {
        match payloads.placed.get_mut(&key) {
            Some(Placed::Mesh(o, _)) | Some(Placed::Ptm(o, _)) => own(o),
            None => {}
        }
    }
    Ok((pack, out))
}

/// A viewpoint's pack and its background tiles and tiles pointing into it.
pub type PackedViewpoint = (Vec<u8>, Vec<BackgroundTile>, Vec<TileEntry>);

/// [`pack_tiles`] for a whole viewpoint: its background tiles' payloads first, then its
/// tiles'; returns the pack and both lists rewritten to point into it (or where their
/// payloads already lie).
pub fn pack_viewpoint(
    background: &[BackgroundTile],
    tiles: &[TileEntry],
    read: &mut ReadFn<'_>,
    payloads: &mut Payloads,
) -> Result<PackedViewpoint, DbError> {
    let mut all: Vec<TileEntry> = background
        .iter()
        .map(super::table::background_entry)
        .collect();
    all.extend_from_slice(tiles);
    let (pack, mut out) = pack_tiles(&all, read, payloads)?;
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
fn checked(bytes: Vec<u8>, hash: &str, o: &ObjectRef) -> Result<Vec<u8>, DbError> {
    if hash.is_empty() || hash_matches(&bytes, hash) {
        Ok(bytes)
    } else {
        Err(DbError::Request(format!(
            "a range of object {} does not match its checksum {hash}",
            o.hash
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
        let (pack, out) = pack_tiles(&tiles, &mut read, &mut Payloads::default()).unwrap();
        // Tile 2's PTM is tile 0's: stored once.
        assert_eq!(pack.len(), 300 + 2000);
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
        assert_eq!(out[2].ptm.as_ref(), Some(p0));
        // Packing a pack again gives the same pack and tiles.
        let mut read2 = |o: &ObjectRef, off: u64, len: u64| {
            assert_eq!(o.hash, hash_hex(&pack));
            Ok(pack[off as usize..(off + len) as usize].to_vec())
        };
        let (again, out2) = pack_tiles(&out, &mut read2, &mut Payloads::default()).unwrap();
        assert_eq!(again, pack);
        assert_eq!(out2, out);
    }

    #[test]
    fn a_repeated_payload_is_stored_once_and_pointed_at() {
        let ptm_bytes: Vec<u8> = (0..600u32).map(|i| (i * 13) as u8).collect();
        let other: Vec<u8> = (0..600u32).map(|i| (i * 17 + 1) as u8).collect();
        let mesh_bytes: Vec<u8> = (0..90u32).map(|i| (i * 5) as u8).collect();
        let mut store: HashMap<String, Vec<u8>> = HashMap::new();
        let obj = |b: &[u8], store: &mut HashMap<String, Vec<u8>>| {
            store.insert(hash_hex(b), b.to_vec());
            ObjectRef {
                hash: hash_hex(b),
                size: b.len() as u64,
            }
        };
        let ptm = |o: ObjectRef| PtmRef {
            object: o,
            width: 32,
            height: 32,
            channels: 4,
            levels: vec![level(1, 0, 100, &ptm_bytes), level(0, 100, 500, &ptm_bytes)],
        };
        let (p1, p2, m) = (
            obj(&ptm_bytes, &mut store),
            obj(&other, &mut store),
            obj(&mesh_bytes, &mut store),
        );
        let mut p2ref = ptm(p2);
        for l in &mut p2ref.levels {
            l.hash = range_hash32(&other[l.offset as usize..(l.offset + l.len) as usize]);
        }
        let mut read = |o: &ObjectRef, off: u64, len: u64| {
            Ok(store[&o.hash][off as usize..(off + len) as usize].to_vec())
        };
        let mut payloads = Payloads::default();
        // Viewpoint A: the PTM and the mesh, then the same PTM again in the same pack.
        let a = vec![
            tile(0, Some(ptm(p1.clone())), Some(m.clone())),
            tile(1, Some(ptm(p1.clone())), None),
        ];
        let (pack_a, out_a) = pack_tiles(&a, &mut read, &mut payloads).unwrap();
        assert_eq!(
            pack_a.len(),
            90 + 600,
            "the repeated PTM is not stored twice"
        );
        let pa = out_a[0].ptm.as_ref().unwrap();
        assert_eq!(out_a[1].ptm.as_ref().unwrap(), pa);
        assert!(
            out_a[0].mesh.is_none(),
            "the mesh lies in the PTM's own pack"
        );
        // Viewpoint B: the same mesh with another PTM, then the first PTM again.
        let b = vec![
            tile(0, Some(p2ref), Some(m.clone())),
            tile(1, Some(ptm(p1)), None),
        ];
        let (pack_b, out_b) = pack_tiles(&b, &mut read, &mut payloads).unwrap();
        assert_eq!(pack_b.len(), 600);
        let obj_a = ObjectRef {
            hash: hash_hex(&pack_a),
            size: pack_a.len() as u64,
        };
        assert_eq!(out_b[0].mesh.as_ref(), Some(&obj_a));
        assert_eq!(out_b[0].mesh_range, out_a[0].mesh_range);
        assert_eq!(
            out_b[0].ptm.as_ref().unwrap().object.hash,
            hash_hex(&pack_b)
        );
        assert_eq!(out_b[1].ptm.as_ref().unwrap(), pa);
        assert_eq!(
            (payloads.shared, payloads.bytes_shared),
            (3, 600 + 90 + 600)
        );
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
        assert!(pack_tiles(&[t], &mut read, &mut Payloads::default()).is_err());
    }
}
