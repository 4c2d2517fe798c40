//! The viewpoints of a manifest (every track of a network, each viewpoint once, by id)
//! flattened into streamable items (tiles and background tiles), each a list of checked parts,
//! plus the ACH lists of the network's segments in item numbers. The table grows as
//! viewpoints' tables arrive: a tile whose table is missing has no item yet and so cannot be
//! requested.

use std::collections::HashMap;

/// The table's lookups: looked up for every ACH entry and tile as tables arrive.
type FastMap<K, V> = HashMap<K, V, foldhash::fast::RandomState>;

use tracks::manifest::{
    object_rel_path, AchEntry, BackgroundTile, Manifest, PtmRef, SegmentEntry, TileEntry,
};

use super::budget::ItemInfo;
use super::http::{ClientError, FetchKey};

/// One download: a key, the hash its bytes must have, its size and its memory cost.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    pub key: FetchKey,
    pub hash: String,
    pub bytes: u64,
    pub mem: u64,
}

/// A tile (or a tile of a viewpoint's background) and its parts: mesh first, then PTM groups.
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    /// The viewpoint's id.
    pub viewpoint: usize,
    /// Position in that viewpoint's `tiles`; `None` for a background tile.
    pub tile: Option<usize>,
    /// Position in that viewpoint's `background`; `None` for a tile.
    pub background: Option<usize>,
    pub parts: Vec<Part>,
    pub info: ItemInfo,
}

/// A segment's `(from, to)` viewpoint ids and its raw ACH list once its table is in.
type SegmentSlot = ((usize, usize), Option<Vec<AchEntry>>);

/// The items of every viewpoint of a manifest. It grows as viewpoints' tables arrive
/// ([`ItemTable::add_viewpoint`]): items are only ever appended, so an item number stays valid
/// for the whole session.
#[derive(Clone, Debug)]
pub struct ItemTable {
    pub items: Vec<Item>,
    /// Per segment of the network (track by track, in order), `(item, ach)` in the
    /// manifest's (descending) order; entries whose tile's table has not arrived yet are left
    /// out (they come in when it does).
    pub segment_ach: Vec<Vec<(usize, f64)>>,
    by_tile: FastMap<(usize, usize), usize>,
    /// `(viewpoint, background tile position)` → item.
    by_background: FastMap<(usize, usize), usize>,
    /// Whether each viewpoint's table has been added.
    loaded: Vec<bool>,
    /// `(viewpoint, slab, tile)` → position in that viewpoint's tiles.
    key_to_tile: FastMap<(usize, u32, tracks::TileId), usize>,
    /// Per segment: its `(from, to)` ids and its raw ACH list once known.
    segments: Vec<SegmentSlot>,
    /// Per segment: the viewpoints its raw ACH list names (sorted, distinct), so a table that
    /// arrives re-resolves only the lists that name it.
    segment_refs: Vec<Vec<usize>>,
    /// Whether parts with the same checksum and length share one key
    /// ([`ItemTable::set_share_parts`]), and the key of each such pair so far.
    share_parts: bool,
    shared: FastMap<(String, u64), FetchKey>,
}

impl ItemTable {
    /// Every viewpoint of `m` with its tiles. Tiles that were culled or have no PTM are
    /// skipped.
    pub fn new(m: &Manifest) -> Result<ItemTable, ClientError> {
        let mut table = ItemTable::empty(m)?;
        for vp in db::split::unique_viewpoints(m) {
            let segs: Vec<SegmentEntry> = m
                .tracks
                .iter()
                .flat_map(|t| &t.segments)
                .filter(|s| s.from == vp.index)
                .cloned()
                .collect();
            table.add_viewpoint(vp.index, &vp.background, &vp.tiles, &segs)?;
        }
        Ok(table)
    }

    /// No items yet, the viewpoints and segments known (`m`'s tiles, backgrounds and ACH lists
    /// are ignored: they come with the viewpoints' tables).
    pub fn empty(m: &Manifest) -> Result<ItemTable, ClientError> {
        let count = db::split::unique_viewpoints(m)
            .last()
            .map_or(0, |v| v.index + 1);
        if count > tracks::limits::MAX_VIEWPOINTS {
            return Err(ClientError::Manifest(format!(
                "{count} viewpoints; at most {}",
                tracks::limits::MAX_VIEWPOINTS
            )));
        }
        let segments: Vec<SegmentSlot> = m
            .tracks
            .iter()
            .flat_map(|t| &t.segments)
            .map(|seg| ((seg.from, seg.to), None))
            .collect();
        Ok(ItemTable {
            items: Vec::new(),
            segment_ach: vec![Vec::new(); segments.len()],
            segment_refs: vec![Vec::new(); segments.len()],
            by_tile: FastMap::default(),
            by_background: FastMap::default(),
            loaded: vec![false; count],
            key_to_tile: FastMap::default(),
            segments,
            share_parts: true,
            shared: FastMap::default(),
        })
    }

    /// Whether parts with the same checksum and length share one fetch key — the first one
    /// added — so identical bytes are fetched and cached once (on by default; it applies to
    /// viewpoints added afterwards). Many payloads are alike from one viewpoint to the next:
    /// on castle 128 meshes above all (flat or distant surfaces; 69 % of the meshes a walk
    /// needs repeat another viewpoint's) and some level groups. A database writes each of
    /// them once (the later tiles point at the same range of an earlier pack, so they share
    /// one key whatever this says); this also joins copies a database stores in several
    /// packs (`DbWriter::share_across_viewpoints` off). Bytes fetched under the shared key
    /// are checked against that part's checksum, which is the other part's too, so nothing
    /// unchecked is ever shown.
    pub fn set_share_parts(&mut self, on: bool) {
        self.share_parts = on;
    }

    /// Viewpoints (by id), loaded or not.
    pub fn viewpoints(&self) -> usize {
        self.loaded.len()
    }

    /// Whether viewpoint `vp`'s table has been added.
    pub fn has_viewpoint(&self, vp: usize) -> bool {
        self.loaded.get(vp).copied().unwrap_or(false)
    }

    /// Viewpoints whose tables are still missing.
    pub fn missing_viewpoints(&self) -> Vec<usize> {
        (0..self.loaded.len())
            .filter(|&v| !self.loaded[v])
            .collect()
    }

    /// Adds viewpoint `vi`'s background tiles and tiles (its table's `background` and
    /// `tiles`, positions as in the table) and the ACH lists of the segments starting there;
    /// the new items are appended. A viewpoint already added is left as it is. On error
    /// nothing is added.
    pub fn add_viewpoint(
        &mut self,
        vi: usize,
        background: &[BackgroundTile],
        tiles: &[TileEntry],
        segments: &[SegmentEntry],
    ) -> Result<std::ops::Range<usize>, ClientError> {
        let start = self.items.len();
        if vi >= self.loaded.len() {
            return Err(ClientError::Manifest(format!("no viewpoint {vi}")));
        }
        if self.loaded[vi] {
            return Ok(start..start);
        }
        let mut new_background = Vec::with_capacity(background.len());
        for (bi, bg) in background.iter().enumerate() {
            let field = || format!("viewpoints[{vi}].background[{bi}]");
            let (parts, levels) = ptm_parts(&bg.ptm, &|| format!("{}.ptm", field()))?;
            new_background.push(make_item(vi, None, Some(bi), parts, 0, levels));
        }
        let mut new_items = Vec::new();
        for (ti, tile) in tiles.iter().enumerate() {
            let Some(ptm) = tile.ptm.as_ref().filter(|_| tile.kept) else {
                continue;
            };
            // Field names only for the error messages: built when one is needed (a manifest
            // of 22 000 tiles made 130 000 of them, a fifth of adding its tables).
            let field = || format!("viewpoints[{vi}].tiles[{ti}]");
            let (mut parts, levels) = ptm_parts(ptm, &|| format!("{}.ptm", field()))?;
            let mut first = 0;
            let mesh = match tile.mesh_at() {
                Some((mesh, None)) => {
                    check_hash(&mesh.hash, || format!("{}.mesh.hash", field()))?;
                    Some(Part {
                        key: FetchKey {
                            object: mesh.hash.as_str().into(),
                            range: None,
                        },
                        hash: mesh.hash.clone(),
                        bytes: mesh.size,
                        mem: mesh.size,
                    })
                }
                Some((object, Some(r))) => {
                    let f = || format!("{}.mesh_range", field());
                    check_range(object, r.offset, r.len, &r.hash, f)?;
                    Some(Part {
                        key: FetchKey {
                            object: object.hash.as_str().into(),
                            range: Some((r.offset, r.len)),
                        },
                        hash: r.hash.clone(),
                        bytes: r.len,
                        mem: r.len,
                    })
                }
                None => None,
            };
            if let Some(m) = mesh {
                parts.insert(0, m);
                first = 1;
            }
            new_items.push((ti, make_item(vi, Some(ti), None, parts, first, levels)));
        }
        for (ti, tile) in tiles.iter().enumerate() {
            self.key_to_tile.insert((vi, tile.slab, tile.tile), ti);
        }
        if self.share_parts {
            let items = new_background
                .iter_mut()
                .chain(new_items.iter_mut().map(|(_, it)| it));
            for part in items.flat_map(|it| it.parts.iter_mut()) {
                let key = self
                    .shared
                    .entry((part.hash.clone(), part.bytes))
                    .or_insert_with(|| part.key.clone());
                part.key = key.clone();
            }
        }
        for (bi, item) in new_background.into_iter().enumerate() {
            self.by_background.insert((vi, bi), self.items.len());
            self.items.push(item);
        }
        for (ti, item) in new_items {
            self.by_tile.insert((vi, ti), self.items.len());
            self.items.push(item);
        }
        self.loaded[vi] = true;
        // Lists already known that name this viewpoint: its tiles can now be resolved.
        let naming: Vec<usize> = (0..self.segments.len())
            .filter(|&k| self.segment_refs[k].binary_search(&vi).is_ok())
            .collect();
        for k in naming {
            self.resolve_segment(k);
        }
        self.add_segments(vi, segments);
        Ok(start..self.items.len())
    }

    /// Adds the ACH lists of segments starting at viewpoint `vi` (its ACH object), whether or
    /// not its table is in; entries whose tile's table has not arrived wait for it.
    pub fn add_segments(&mut self, vi: usize, segments: &[SegmentEntry]) {
        for seg in segments.iter().filter(|sg| sg.from == vi) {
            let found: Vec<usize> = (0..self.segments.len())
                .filter(|&k| self.segments[k].0 == (vi, seg.to))
                .collect();
            for k in found {
                let mut refs: Vec<usize> = seg
                    .ach
                    .iter()
                    .map(|a| a.viewpoint)
                    .filter(|&v| v < self.loaded.len())
                    .collect();
                refs.sort_unstable();
                refs.dedup();
                self.segment_refs[k] = refs;
                self.segments[k].1 = Some(seg.ach.clone());
                self.resolve_segment(k);
            }
        }
    }

    /// Recomputes `segment_ach[k]` from its raw list and the tiles known so far.
    fn resolve_segment(&mut self, k: usize) {
        let Some((_, Some(raw))) = self.segments.get(k) else {
            return;
        };
        self.segment_ach[k] = raw
            .iter()
            .filter_map(|a| {
                let vi = a.viewpoint;
                let ti = *self.key_to_tile.get(&(vi, a.slab, a.tile))?;
                let item = *self.by_tile.get(&(vi, ti))?;
                (a.ach.is_finite() && a.ach > 0.0).then_some((item, a.ach))
            })
            .collect();
    }

    /// Item of tile `tile` (position in viewpoint `vp`'s `tiles`).
    pub fn tile_item(&self, vp: usize, tile: usize) -> Option<usize> {
        self.by_tile.get(&(vp, tile)).copied()
    }

    /// Item of background tile `tile` (position in viewpoint `vp`'s `background`).
    pub fn background_item(&self, vp: usize, tile: usize) -> Option<usize> {
        self.by_background.get(&(vp, tile)).copied()
    }

    /// Items of viewpoint `vp`'s background tiles known so far.
    pub fn background_items(&self, vp: usize) -> impl Iterator<Item = usize> + '_ {
        (0..)
            .map(move |bi| self.background_item(vp, bi))
            .take_while(Option::is_some)
            .flatten()
    }

    /// The size/memory table [`super::plan`] works on.
    pub fn infos(&self) -> Vec<ItemInfo> {
        self.items.iter().map(|i| i.info.clone()).collect()
    }
}

fn check_hash(h: &str, field: impl FnOnce() -> String) -> Result<(), ClientError> {
    object_rel_path(h)
        .map(|_| ())
        .ok_or_else(|| ClientError::Manifest(format!("{}: `{h}` is not a valid hash", field())))
}

/// A range's checksum and bounds inside `object`.
fn check_range(
    object: &tracks::manifest::ObjectRef,
    offset: u64,
    len: u64,
    hash: &str,
    f: impl FnOnce() -> String,
) -> Result<(), ClientError> {
    if !db::valid_range_hash(hash) {
        return Err(ClientError::Manifest(format!(
            "{}.hash: `{hash}` is not a valid checksum",
            f()
        )));
    }
    if len == 0 || offset.checked_add(len).is_none_or(|e| e > object.size) {
        return Err(ClientError::Manifest(format!(
            "{}: range {offset}+{len} outside the object of {} bytes",
            f(),
            object.size
        )));
    }
    Ok(())
}

fn ptm_parts(p: &PtmRef, field: &dyn Fn() -> String) -> Result<(Vec<Part>, Vec<u32>), ClientError> {
    check_hash(&p.object.hash, || format!("{}.object.hash", field()))?;
    let mut parts = Vec::new();
    let mut levels = Vec::new();
    for (g, l) in p.levels.iter().enumerate() {
        check_range(&p.object, l.offset, l.len, &l.hash, || {
            format!("{}.levels[{g}]", field())
        })?;
        parts.push(Part {
            key: FetchKey {
                object: p.object.hash.as_str().into(),
                range: Some((l.offset, l.len)),
            },
            hash: l.hash.clone(),
            bytes: l.len,
            mem: l.width as u64 * l.height as u64 * p.channels.max(1) as u64,
        });
        levels.push(l.level);
    }
    if parts.is_empty() {
        return Err(ClientError::Manifest(format!(
            "{}: PTM without levels",
            field()
        )));
    }
    Ok((parts, levels))
}

fn make_item(
    viewpoint: usize,
    tile: Option<usize>,
    background: Option<usize>,
    parts: Vec<Part>,
    first_level_part: usize,
    levels: Vec<u32>,
) -> Item {
    let info = ItemInfo {
        part_bytes: parts.iter().map(|p| p.bytes).collect(),
        part_mem: parts.iter().map(|p| p.mem).collect(),
        first_level_part,
        levels,
    };
    Item {
        viewpoint,
        tile,
        background,
        parts,
        info,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::manifest::{
        LevelRef, ObjectRef, PackRange, TrackEntry, ViewpointEntry, MANIFEST_VERSION,
    };
    use tracks::{Face, TileId};

    /// A viewpoint with one tile in its own pack: a 100-byte mesh with checksum `mesh`, then
    /// one 50-byte level whose checksum is the viewpoint's own.
    fn viewpoint(index: usize, mesh: &str) -> ViewpointEntry {
        let object = ObjectRef {
            hash: format!("{:064x}", index + 1),
            size: 150,
        };
        ViewpointEntry {
            index,
            s: 2.0 * index as f64,
            position: glam::DVec3::new(0.0, 1.7, 2.0 * index as f64),
            background: Vec::new(),
            tiles: vec![TileEntry {
                tile: TileId {
                    face: Face::ALL[0],
                    tx: 0,
                    ty: 0,
                },
                slab: 0,
                depth_min: 1.0,
                depth_max: 2.0,
                opaque_pixels: 256,
                kept: true,
                ptm: Some(PtmRef {
                    object,
                    width: 16,
                    height: 16,
                    channels: 4,
                    levels: vec![LevelRef {
                        level: 0,
                        width: 16,
                        height: 16,
                        offset: 100,
                        len: 50,
                        hash: format!("{:08x}", 1000 + index),
                    }],
                }),
                mesh: None,
                mesh_range: Some(PackRange {
                    offset: 0,
                    len: 100,
                    hash: mesh.to_string(),
                }),
            }],
        }
    }

    fn manifest(meshes: [&str; 2]) -> Manifest {
        Manifest {
            version: MANIFEST_VERSION,
            scene: "test".into(),
            face_size: 16,
            tile_size: 16,
            slabs: Vec::new(),
            cull_alpha: None,
            cull_variant: None,
            tracks: vec![TrackEntry {
                name: "main".into(),
                track_toml: String::new(),
                length: 2.0,
                viewpoints: vec![viewpoint(0, meshes[0]), viewpoint(1, meshes[1])],
                segments: vec![SegmentEntry {
                    from: 0,
                    to: 1,
                    ach: Vec::new(),
                }],
            }],
        }
    }

    fn keys(share: bool, meshes: [&str; 2]) -> Vec<Vec<FetchKey>> {
        let m = manifest(meshes);
        let mut table = ItemTable::empty(&m).unwrap();
        table.set_share_parts(share);
        for (vi, v) in m.tracks[0].viewpoints.iter().enumerate() {
            table
                .add_viewpoint(vi, &v.background, &v.tiles, &[])
                .unwrap();
        }
        table
            .items
            .iter()
            .map(|it| it.parts.iter().map(|p| p.key.clone()).collect())
            .collect()
    }

    #[test]
    fn a_bad_reference_is_named_by_its_field() {
        let mut m = manifest(["abcdef01", "abcdef02"]);
        let tile = &mut m.tracks[0].viewpoints[1].tiles[0];
        tile.ptm.as_mut().unwrap().levels[0].hash = "zz".into();
        let v = &m.tracks[0].viewpoints[1];
        let mut table = ItemTable::empty(&m).unwrap();
        let e = table
            .add_viewpoint(1, &v.background, &v.tiles, &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("viewpoints[1].tiles[0].ptm.levels[0].hash: `zz`"),
            "{e}"
        );
        // Nothing was added.
        assert!(table.items.is_empty());
        let mut m = manifest(["abcdef01", "abcdef02"]);
        m.tracks[0].viewpoints[0].tiles[0]
            .mesh_range
            .as_mut()
            .unwrap()
            .len = 1 << 40;
        let v = &m.tracks[0].viewpoints[0];
        let e = ItemTable::empty(&m)
            .unwrap()
            .add_viewpoint(0, &v.background, &v.tiles, &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("viewpoints[0].tiles[0].mesh_range: range 0+1099511627776"),
            "{e}"
        );
    }

    #[test]
    fn identical_parts_share_the_first_key_and_others_keep_their_own() {
        let k = keys(true, ["abcdef01", "abcdef01"]);
        assert_eq!(k.len(), 2);
        // The same mesh in both packs: both items fetch it from the first viewpoint's pack.
        assert_eq!(k[0][0], k[1][0]);
        assert_eq!(k[1][0].object.as_ref(), format!("{:064x}", 1));
        // Levels with their own checksums stay in their own packs.
        assert_ne!(k[0][1], k[1][1]);
        assert_eq!(k[1][1].object.as_ref(), format!("{:064x}", 2));
        // Different checksums, or sharing switched off: every part its own key.
        let k = keys(true, ["abcdef01", "abcdef02"]);
        assert_ne!(k[0][0], k[1][0]);
        let k = keys(false, ["abcdef01", "abcdef01"]);
        assert_ne!(k[0][0], k[1][0]);
        assert_eq!(k[1][0].object.as_ref(), format!("{:064x}", 2));
    }
}
