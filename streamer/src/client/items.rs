//! A track of a manifest flattened into streamable items (tiles and backgrounds), each a list
//! of checked parts, plus the ACH lists of its segments in item numbers.

use std::collections::HashMap;

use tracks::manifest::{object_rel_path, Manifest, PtmRef};

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

/// A tile (or a viewpoint's background) and its parts: mesh first, then PTM groups.
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    /// Position of the viewpoint in the track's `viewpoints`.
    pub viewpoint: usize,
    /// Position in that viewpoint's `tiles`; `None` for the background.
    pub tile: Option<usize>,
    /// Arc length of the viewpoint.
    pub s: f64,
    pub parts: Vec<Part>,
    pub info: ItemInfo,
    /// The whole PTM object (for whole-file downloads).
    pub whole: Part,
}

/// The items of one track.
#[derive(Clone, Debug)]
pub struct ItemTable {
    pub items: Vec<Item>,
    /// Arc length of each viewpoint.
    pub vp_s: Vec<f64>,
    /// Per segment, `(item, ach)` in the manifest's (descending) order.
    pub segment_ach: Vec<Vec<(usize, f64)>>,
    by_tile: HashMap<(usize, usize), usize>,
    background: HashMap<usize, usize>,
}

fn check_hash(h: &str, field: &str) -> Result<(), ClientError> {
    object_rel_path(h)
        .map(|_| ())
        .ok_or_else(|| ClientError::Manifest(format!("{field}: `{h}` is not a valid hash")))
}

fn ptm_parts(p: &PtmRef, field: &str) -> Result<(Vec<Part>, Vec<u32>, Part), ClientError> {
    check_hash(&p.object.hash, &format!("{field}.object.hash"))?;
    let mut parts = Vec::new();
    let mut levels = Vec::new();
    for (g, l) in p.levels.iter().enumerate() {
        let f = format!("{field}.levels[{g}]");
        check_hash(&l.hash, &format!("{f}.hash"))?;
        if l.len == 0
            || l.offset
                .checked_add(l.len)
                .is_none_or(|e| e > p.object.size)
        {
            return Err(ClientError::Manifest(format!(
                "{f}: range {}+{} outside the object of {} bytes",
                l.offset, l.len, p.object.size
            )));
        }
        parts.push(Part {
            key: FetchKey {
                object: p.object.hash.clone(),
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
            "{field}: PTM without levels"
        )));
    }
    let whole = Part {
        key: FetchKey {
            object: p.object.hash.clone(),
            range: None,
        },
        hash: p.object.hash.clone(),
        bytes: p.object.size,
        mem: parts.iter().map(|x| x.mem).sum(),
    };
    Ok((parts, levels, whole))
}

impl ItemTable {
    /// Flatten track `track` of `m`. Tiles that were culled or have no PTM are skipped.
    pub fn new(m: &Manifest, track: usize) -> Result<ItemTable, ClientError> {
        let t = m
            .tracks
            .get(track)
            .ok_or_else(|| ClientError::Manifest(format!("no track {track}")))?;
        let mut items = Vec::new();
        let mut by_tile = HashMap::new();
        let mut background = HashMap::new();
        for (vi, vp) in t.viewpoints.iter().enumerate() {
            for (ti, tile) in vp.tiles.iter().enumerate() {
                let Some(ptm) = tile.ptm.as_ref().filter(|_| tile.kept) else {
                    continue;
                };
                let field = format!("tracks[{track}].viewpoints[{vi}].tiles[{ti}]");
                let (mut parts, levels, whole) = ptm_parts(ptm, &format!("{field}.ptm"))?;
                let mut first = 0;
                if let Some(mesh) = &tile.mesh {
                    check_hash(&mesh.hash, &format!("{field}.mesh.hash"))?;
                    parts.insert(
                        0,
                        Part {
                            key: FetchKey {
                                object: mesh.hash.clone(),
                                range: None,
                            },
                            hash: mesh.hash.clone(),
                            bytes: mesh.size,
                            mem: mesh.size,
                        },
                    );
                    first = 1;
                }
                by_tile.insert((vi, ti), items.len());
                items.push(make_item(vi, Some(ti), vp.s, parts, first, levels, whole));
            }
            if let Some(bg) = &vp.background {
                let field = format!("tracks[{track}].viewpoints[{vi}].background");
                let (parts, levels, whole) = ptm_parts(bg, &field)?;
                background.insert(vi, items.len());
                items.push(make_item(vi, None, vp.s, parts, 0, levels, whole));
            }
        }
        let index_of: HashMap<usize, usize> = t
            .viewpoints
            .iter()
            .enumerate()
            .map(|(i, v)| (v.index, i))
            .collect();
        let mut key_to_tile: HashMap<(usize, u32, tracks::TileId), usize> = HashMap::new();
        for (vi, vp) in t.viewpoints.iter().enumerate() {
            for (ti, tile) in vp.tiles.iter().enumerate() {
                key_to_tile.insert((vi, tile.slab, tile.tile), ti);
            }
        }
        let segment_ach = t
            .segments
            .iter()
            .map(|seg| {
                seg.ach
                    .iter()
                    .filter_map(|a| {
                        let vi = *index_of.get(&a.viewpoint)?;
                        let ti = *key_to_tile.get(&(vi, a.slab, a.tile))?;
                        let item = *by_tile.get(&(vi, ti))?;
                        (a.ach.is_finite() && a.ach > 0.0).then_some((item, a.ach))
                    })
                    .collect()
            })
            .collect();
        Ok(ItemTable {
            items,
            vp_s: t.viewpoints.iter().map(|v| v.s).collect(),
            segment_ach,
            by_tile,
            background,
        })
    }

    /// Item of tile `tile` (position in `viewpoints[vp].tiles`).
    pub fn tile_item(&self, vp: usize, tile: usize) -> Option<usize> {
        self.by_tile.get(&(vp, tile)).copied()
    }

    /// Item of a viewpoint's background.
    pub fn background_item(&self, vp: usize) -> Option<usize> {
        self.background.get(&vp).copied()
    }

    /// The size/memory table [`super::plan`] works on.
    pub fn infos(&self) -> Vec<ItemInfo> {
        self.items.iter().map(|i| i.info.clone()).collect()
    }
}

fn make_item(
    viewpoint: usize,
    tile: Option<usize>,
    s: f64,
    parts: Vec<Part>,
    first_level_part: usize,
    levels: Vec<u32>,
    whole: Part,
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
        s,
        parts,
        info,
        whole,
    }
}
