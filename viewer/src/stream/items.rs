//! The session's items as the walkthrough holds them: what each is in the views, its parts
//! consumed and waiting, its decoder; decoding the parts a step takes, and placing the
//! level decoded into its view.

use std::collections::HashMap;
use std::time::Instant;

use bytes::Bytes;
use codec::ptm::{Decoder, Limits};
use streamer::client::LiveSession;
use tracks::manifest::tile_key;
use tracks::{PixelRect, TileId};

use super::{StreamError, StreamedWalkthrough};
use crate::refview::ViewTile;
use crate::source::{image_rgba, paste_tile, tile_mesh_from_bytes, SourceError};

/// What an item is in the views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Kind {
    Tile {
        tile: TileId,
        slab: u32,
    },
    Background {
        tile: TileId,
    },
    /// An item whose entry could not be used (never consumed).
    Unusable,
}

/// What the walkthrough holds of one session item.
pub(super) struct ItemState {
    /// Position of the view in `walk.views`.
    pub(super) view: usize,
    pub(super) kind: Kind,
    /// Parts received and not yet consumed (they may arrive out of order).
    pub(super) waiting: HashMap<usize, Bytes>,
    /// Parts consumed (a prefix).
    pub(super) next: usize,
    pub(super) first_level_part: usize,
    /// What the decoder may allocate (a fresh decoder after eviction takes the same).
    pub(super) limits: Limits,
    pub(super) decoder: Decoder,
    pub(super) mesh: Option<tracks::TileMesh>,
    /// Finest level shown.
    pub(super) level: Option<u32>,
    pub(super) loaded_at: Option<Instant>,
    pub(super) failed: bool,
}

impl ItemState {
    /// An item of view `view` whose entry could not be used: never consumed.
    pub(super) fn failed(view: usize) -> ItemState {
        ItemState {
            view,
            kind: Kind::Unusable,
            waiting: HashMap::new(),
            next: 0,
            first_level_part: 0,
            limits: Limits::default(),
            decoder: Decoder::new(Limits::default()),
            mesh: None,
            level: None,
            loaded_at: None,
            failed: true,
        }
    }
}

/// The state of session item `i` (nothing received yet).
pub(super) fn item_state(session: &LiveSession, i: usize) -> Result<ItemState, StreamError> {
    let m = session.manifest();
    let entry = &m.tracks[session.track()];
    let it = &session.table().items[i];
    let kind = match (it.tile, it.background) {
        (Some(ti), _) => {
            let t = &entry.viewpoints[it.viewpoint].tiles[ti];
            if t.slab as usize >= m.slabs.len() {
                return Err(StreamError::Manifest(format!(
                    "{}: slab {} beyond the manifest's {} slabs",
                    tile_key(entry.viewpoints[it.viewpoint].index, t.slab, t.tile),
                    t.slab,
                    m.slabs.len()
                )));
            }
            Kind::Tile {
                tile: t.tile,
                slab: t.slab,
            }
        }
        (None, Some(bi)) => Kind::Background {
            tile: entry.viewpoints[it.viewpoint].background[bi].tile,
        },
        (None, None) => Kind::Unusable,
    };
    // Bound what a bad server can make us decode to what the item should be: at most one
    // tile square (RGBA, all levels: 4/3 of the base, doubled for headroom).
    let limits = Limits {
        max_side: m.tile_size.max(1),
        max_decoded_bytes: 8 * u64::from(m.tile_size).pow(2),
    };
    Ok(ItemState {
        view: it.viewpoint,
        kind,
        waiting: HashMap::new(),
        next: 0,
        first_level_part: it.info.first_level_part,
        limits,
        decoder: Decoder::new(limits),
        mesh: None,
        level: None,
        loaded_at: None,
        failed: false,
    })
}

impl StreamedWalkthrough {
    /// The next `count` parts of `item` in order, each from those that arrived for it or
    /// from the session's cache (fewer when one is in neither).
    pub(super) fn take_parts(&mut self, item: usize, count: usize) -> Vec<Bytes> {
        let it = &mut self.items[item];
        let mut out = Vec::new();
        while out.len() < count {
            let next = it.next + out.len();
            let data = match it.waiting.remove(&next) {
                Some(data) => data,
                None => match self.session.part_bytes(item, next) {
                    Some(data) => data.clone(),
                    None => break,
                },
            };
            out.push(data);
        }
        out
    }

    /// Put a tile's (or background tile's) newly decoded finest level into its view: the
    /// layer and the face rectangle that changed.
    pub(super) fn place(
        &mut self,
        item: usize,
        d: Decoded,
        what: &str,
        now: Instant,
    ) -> Result<Option<(usize, PixelRect)>, SourceError> {
        let it = &self.items[item];
        let view = it.view;
        // Levels of the views as laid out.
        let view_level = d.level.saturating_sub(self.layout_level);
        let pixels = (&d.rgba[..], d.width, d.height, view_level);
        match it.kind {
            Kind::Unusable => Ok(None),
            Kind::Background { tile } => {
                self.lay_out(view);
                paste_tile(&mut self.dense[view][0], self.grid, tile, pixels, what)?;
                let it = &mut self.items[item];
                it.level = Some(d.level);
                it.loaded_at = Some(now);
                Ok(Some((0, self.grid.pixel_rect(tile))))
            }
            Kind::Tile { tile, slab } => {
                let joined = self.tile_items[view].iter().position(|&i| i == item);
                if joined.is_none() && it.mesh.is_none() {
                    return Ok(None);
                }
                let layer = slab as usize + 1;
                self.lay_out(view);
                paste_tile(&mut self.dense[view][layer], self.grid, tile, pixels, what)?;
                let it = &mut self.items[item];
                it.level = Some(d.level);
                it.loaded_at = Some(now);
                let v = &mut self.walk.views[view];
                match joined {
                    Some(slot) => v.tiles[slot].finest_level = view_level,
                    None => {
                        // The view's tile holds the mesh from now on.
                        let mesh = it.mesh.take().unwrap_or_default();
                        let mut vt = ViewTile::new(tile, slab, mesh, v.face_size);
                        vt.finest_level = view_level;
                        let key = |t: &ViewTile| (t.slab, self.grid.tile_index(t.tile));
                        let slot = v.tiles.partition_point(|t| key(t) < key(&vt));
                        v.tiles.insert(slot, vt);
                        self.tile_items[view].insert(slot, item);
                    }
                }
                Ok(Some((layer, self.grid.pixel_rect(tile))))
            }
        }
    }

    pub(super) fn item_name(&self, item: usize) -> String {
        let it = &self.items[item];
        let vp = self.walk.views.get(it.view).map_or(it.view, |v| v.index);
        match it.kind {
            Kind::Tile { tile, slab } => tile_key(vp, slab, tile),
            Kind::Background { tile } => format!(
                "viewpoint {vp} background tile {}-{}-{}",
                tile.face.short_name(),
                tile.tx,
                tile.ty
            ),
            Kind::Unusable => format!("viewpoint {vp} item {item}"),
        }
    }
}

/// An item's finest level, decoded ([`decode_parts`]).
pub(super) struct Decoded {
    level: u32,
    rgba: Vec<u8>,
    width: u32,
    height: u32,
}

/// Feed `parts` (the item's next parts, in order) to its mesh and decoder; its finest level
/// when that became finer than the one shown (a coarse level divided by its coverage when
/// `premultiplied`, see [`db::clear_masked`]). Views laid out `k` levels coarser
/// than the database take level `k` where a finer one arrived, and meshes scaled to them.
/// Items are independent, so a step decodes them in parallel.
pub(super) fn decode_parts(
    it: &mut ItemState,
    parts: Vec<Bytes>,
    what: &str,
    premultiplied: bool,
    k: u32,
) -> Result<Option<Decoded>, SourceError> {
    for data in parts {
        if it.next < it.first_level_part {
            let mut mesh = tile_mesh_from_bytes(&data, what)?;
            if k > 0 {
                let scale = 1.0 / (1u32 << k) as f32;
                for v in &mut mesh.vertices {
                    v[0] *= scale;
                    v[1] *= scale;
                }
            }
            it.mesh = Some(mesh);
        } else {
            it.decoder.push(&data).map_err(|e| SourceError::Format {
                what: what.to_string(),
                message: e.to_string(),
            })?;
        }
        it.next += 1;
    }
    let level = it.decoder.finest_level().map(|l| l.max(k));
    if level == it.level || level.is_none() {
        return Ok(None);
    }
    let level = level.unwrap_or(k);
    let Some(img) = it.decoder.level(level) else {
        return Ok(None);
    };
    let mut rgba = image_rgba(img);
    if premultiplied && level > 0 {
        db::unpremultiply(&mut rgba);
    }
    let d = Decoded {
        level,
        rgba,
        width: img.width(),
        height: img.height(),
    };
    // The finest level the views take decoded: nothing more will come for this item, its
    // decoder's levels are no longer needed.
    if level == k {
        it.decoder = Decoder::new(it.limits);
    }
    Ok(Some(d))
}

pub(super) fn mesh_bytes(m: &tracks::TileMesh) -> u64 {
    (std::mem::size_of_val(&m.vertices[..]) + std::mem::size_of_val(&m.indices[..])) as u64
}

/// Decoded bytes an item holds: its decoder's levels, its mesh and the parts waiting.
pub(super) fn item_bytes(it: &ItemState) -> u64 {
    let levels = it.decoder.header().map_or(0, |h| u32::from(h.levels));
    let decoded: usize = (0..levels)
        .filter_map(|l| it.decoder.level(l))
        .map(|img| img.data().len())
        .sum();
    let waiting: usize = it.waiting.values().map(|b| b.len()).sum();
    (decoded + waiting) as u64 + it.mesh.as_ref().map_or(0, mesh_bytes)
}
