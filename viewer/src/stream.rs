//! A walkthrough streamed from `railview serve`: reference views whose tiles appear as their
//! mesh and PTM levels arrive.
//!
//! [`StreamedWalkthrough`] wraps a [`LiveSession`] (downloads, cache, budgets) and a
//! [`Walkthrough`] that starts with every view empty (transparent layers, no tiles). Each
//! [`StreamedWalkthrough::step`] hands the position and camera (and the GPU's visible-pixel
//! counts, see [`StreamedWalkthrough::live_counts`]) to the session and folds what arrived
//! into the views: an item's parts are consumed in order (mesh, then PTM level groups into an
//! incremental [`Decoder`]); a tile joins its view once its mesh and coarsest level are in,
//! and is upgraded in place as finer levels decode (the coarse level stands in, nearest, and
//! [`crate::refview::ViewTile::finest_level`] keeps the renderer from sampling finer than what
//! arrived). A background is pasted at whatever level has arrived. Only the layers that
//! changed are rebuilt, and the step reports which views changed so the renderer re-uploads
//! just those ([`crate::gpu::Renderer::invalidate_view`]). Each tile's
//! [`crate::refview::ViewTile::highlight`] is 1 when a level of it arrives and fades to 0 over
//! [`HIGHLIGHT`], for the renderer's highlight overlay.
//!
//! Decoded textures stay in the views after the session's cache evicts their bytes: what was
//! shown stays shown (the cache budget bounds downloaded bytes, not GPU memory).

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::time::{Duration, Instant};

use bytes::Bytes;
use streamer::client::{LiveConfig, LiveCount, LiveError, LiveSession};
use streamer::ptm::{Decoder, Limits};
use tracks::manifest::tile_key;
use tracks::{CubeMap, PerspectiveCamera, TileGrid, TileId};

use crate::feedback::ViewCounts;
use crate::plan::FramePlan;
use crate::refview::{RefView, ViewTile};
use crate::source::{
    background_map, image_rgba, manifest_track, paste_tile, tile_mesh_from_bytes, SourceError,
    Walkthrough,
};
use crate::texture::{dilate_masked, FaceRect, Layer};

/// How long a newly loaded tile stays highlighted.
pub const HIGHLIGHT: Duration = Duration::from_secs(1);

/// Errors connecting a streamed walkthrough.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    #[error(transparent)]
    Live(#[from] LiveError),
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error("manifest: {0}")]
    Manifest(String),
}

/// What an item is in the views.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Tile { tile: TileId, slab: u32 },
    Background,
}

struct ItemState {
    /// Position of the view in `walk.views`.
    view: usize,
    kind: Kind,
    /// Parts received and not yet consumed (they may arrive out of order).
    waiting: HashMap<usize, Bytes>,
    /// Parts consumed (a prefix).
    next: usize,
    first_level_part: usize,
    decoder: Decoder,
    mesh: Option<crate::refview::TileMesh>,
    /// Finest level shown.
    level: Option<u32>,
    loaded_at: Option<Instant>,
    failed: bool,
}

/// What one [`StreamedWalkthrough::step`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepReport {
    /// `RefView::index` of every view whose content changed as a whole (a background
    /// arrived): re-upload these.
    pub changed_views: Vec<usize>,
    /// Tile arrivals: `(RefView::index, layer, texel rectangles per mip level)` as
    /// [`Layer::update_region`] returned them, for
    /// [`crate::gpu::Renderer::update_layer_region`]; one entry per tile.
    pub regions: Vec<(usize, usize, Vec<FaceRect>)>,
    /// Parts that arrived.
    pub arrivals: usize,
    /// Tiles or backgrounds that became visible or sharper.
    pub upgraded: usize,
}

impl StepReport {
    /// Bring `renderer`'s copies of `views` up to date: whole re-uploads for
    /// [`StepReport::changed_views`], region writes for [`StepReport::regions`] (a view that
    /// is not uploaded in that shape is re-uploaded whole at its next draw instead).
    pub fn apply(&self, renderer: &mut crate::gpu::Renderer, views: &[crate::RefView]) {
        for v in &self.changed_views {
            renderer.invalidate_view(*v);
        }
        for (index, layer, rects) in &self.regions {
            if self.changed_views.contains(index) {
                continue;
            }
            let written = views
                .iter()
                .find(|v| v.index == *index)
                .is_some_and(|v| renderer.update_layer_region(v, *layer, rects));
            if !written {
                renderer.invalidate_view(*index);
            }
        }
    }
}

/// A recently loaded tile, for highlighting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecentTile {
    /// Position in `walk.views` and in that view's `tiles`.
    pub view: usize,
    pub tile: usize,
    /// Seconds since its latest level arrived.
    pub age_s: f64,
}

/// A walkthrough filled from a server while it is shown (see the module docs).
pub struct StreamedWalkthrough {
    pub walk: Walkthrough,
    session: LiveSession,
    grid: TileGrid,
    items: Vec<ItemState>,
    /// Per view: level-0 RGBA of every layer (background, then one per slab).
    dense: Vec<Vec<CubeMap<[u8; 4]>>>,
    /// Per view: the item of each entry of `walk.views[v].tiles`.
    tile_items: Vec<Vec<usize>>,
    /// Arrival times of parts over the last seconds (for the UI).
    arrivals: VecDeque<(Instant, usize)>,
    /// Problems with received data (bytes that passed their checksum but do not decode).
    pub errors: Vec<String>,
}

/// The state of session item `i` (nothing received yet).
fn item_state(session: &LiveSession, i: usize) -> Result<ItemState, StreamError> {
    let m = session.manifest();
    let entry = &m.tracks[session.track()];
    let n = m.face_size;
    let it = &session.table().items[i];
    let kind = match it.tile {
        Some(ti) => {
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
        None => Kind::Background,
    };
    // Bound what a bad server can make us decode to what the item should be: a tile
    // is at most one tile square, a background one cube map (RGBA, all levels: 4/3 of
    // the base, doubled for headroom).
    let limits = match &kind {
        Kind::Tile { .. } => Limits {
            max_side: m.tile_size.max(1),
            max_decoded_bytes: 8 * u64::from(m.tile_size).pow(2),
        },
        Kind::Background => Limits {
            max_side: n.saturating_mul(6).max(1),
            max_decoded_bytes: 8 * 6 * u64::from(n).pow(2),
        },
    };
    Ok(ItemState {
        view: it.viewpoint,
        kind,
        waiting: HashMap::new(),
        next: 0,
        first_level_part: it.info.first_level_part,
        decoder: Decoder::new(limits),
        mesh: None,
        level: None,
        loaded_at: None,
        failed: false,
    })
}

impl StreamedWalkthrough {
    /// Connect to `url` and lay out the (still empty) views of `track`.
    pub fn connect(
        url: &str,
        track: Option<&str>,
        config: LiveConfig,
    ) -> Result<StreamedWalkthrough, StreamError> {
        let session = LiveSession::connect(url, track, config)?;
        Self::with_session(session)
    }

    /// Lay out the views of the session's track.
    pub fn with_session(session: LiveSession) -> Result<StreamedWalkthrough, StreamError> {
        let m = session.manifest();
        let entry = &m.tracks[session.track()];
        let track = manifest_track(entry)?;
        let n = m.face_size;
        let grid = TileGrid::new(n, m.tile_size).ok_or_else(|| {
            StreamError::Manifest(format!(
                "face size {n} and tile size {} do not make a tile grid",
                m.tile_size
            ))
        })?;
        let layer_count = m.slabs.len() + 1;
        let empty = CubeMap::filled(n, [0u8; 4]);
        let empty_layer = Layer::from_rgba(empty.clone());
        let views: Vec<RefView> = entry
            .viewpoints
            .iter()
            .map(|vp| RefView {
                index: vp.index,
                s: vp.s,
                position: vp.position,
                face_size: n,
                tile_size: m.tile_size,
                layers: vec![empty_layer.clone(); layer_count],
                tiles: Vec::new(),
            })
            .collect();
        let mut items = Vec::with_capacity(session.table().items.len());
        for i in 0..session.table().items.len() {
            items.push(item_state(&session, i)?);
        }
        let dense = vec![vec![empty; layer_count]; views.len()];
        let tile_items = vec![Vec::new(); views.len()];
        let walk = Walkthrough {
            scene: m.scene.clone(),
            track,
            views,
            slabs: m.slabs.clone(),
            bytes: 0,
        };
        Ok(StreamedWalkthrough {
            walk,
            session,
            grid,
            items,
            dense,
            tile_items,
            arrivals: VecDeque::new(),
            errors: Vec::new(),
        })
    }

    pub fn session(&self) -> &LiveSession {
        &self.session
    }

    pub fn session_mut(&mut self) -> &mut LiveSession {
        &mut self.session
    }

    /// One frame: update the session at `s` / `camera` (with the GPU's counts when given)
    /// and fold what arrived into the views.
    pub fn step(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> StepReport {
        let arrived = self.session.update(s, camera, live);
        // Tiles of viewpoint tables that arrived: new items (appended, never renumbered).
        for i in self.items.len()..self.session.table().items.len() {
            match item_state(&self.session, i) {
                Ok(state) => self.items.push(state),
                Err(e) => {
                    self.errors.push(e.to_string());
                    self.items.push(ItemState {
                        view: self.session.table().items[i].viewpoint,
                        kind: Kind::Background,
                        waiting: HashMap::new(),
                        next: 0,
                        first_level_part: 0,
                        decoder: Decoder::new(Limits::default()),
                        mesh: None,
                        level: None,
                        loaded_at: None,
                        failed: true,
                    });
                }
            }
        }
        let now = Instant::now();
        let mut report = StepReport {
            arrivals: arrived.len(),
            ..Default::default()
        };
        let mut touched = BTreeSet::new();
        for a in arrived {
            self.walk.bytes += a.data.len() as u64;
            self.arrivals.push_back((now, a.data.len()));
            if let Some(it) = self.items.get_mut(a.item) {
                if a.part >= it.next && !it.failed {
                    it.waiting.insert(a.part, a.data);
                    touched.insert(a.item);
                }
            }
        }
        while self
            .arrivals
            .front()
            .is_some_and(|(t, _)| now.duration_since(*t) > Duration::from_secs(10))
        {
            self.arrivals.pop_front();
        }
        // (view, layer) pairs whose dense map changed as a whole, and tile rectangles.
        let mut dirty: BTreeSet<(usize, usize)> = BTreeSet::new();
        let mut rects: Vec<(usize, usize, FaceRect)> = Vec::new();
        for item in touched {
            match self.consume(item, now) {
                Ok(Some((layer, rect))) => {
                    let v = self.items[item].view;
                    match rect {
                        Some(r) => rects.push((v, layer, r)),
                        None => {
                            dirty.insert((v, layer));
                        }
                    }
                    report.upgraded += 1;
                }
                Ok(None) => {}
                Err(e) => {
                    self.items[item].failed = true;
                    self.errors.push(e.to_string());
                }
            }
        }
        let mut views = BTreeSet::new();
        for &(v, layer) in &dirty {
            let map = &self.dense[v][layer];
            self.walk.views[v].layers[layer] = Layer::from_rgba(dilate_masked(map));
            views.insert(self.walk.views[v].index);
        }
        // A tile redoes the dilation and mip texels around its own rectangle only (the
        // whole layer is rebuilt above when it changed as a whole in this step anyway).
        for (v, layer, rect) in rects {
            if dirty.contains(&(v, layer)) {
                continue;
            }
            let per_level =
                self.walk.views[v].layers[layer].update_region(&self.dense[v][layer], rect);
            if !per_level.is_empty() {
                report
                    .regions
                    .push((self.walk.views[v].index, layer, per_level));
            }
        }
        report.changed_views = views.into_iter().collect();
        self.fade_highlights(now);
        report
    }

    /// Set every tile's [`ViewTile::highlight`]: 1 when its latest level arrived, fading to 0
    /// over [`HIGHLIGHT`] (the renderer tints by it; no re-upload needed).
    fn fade_highlights(&mut self, now: Instant) {
        for (v, items) in self.tile_items.iter().enumerate() {
            for (slot, &item) in items.iter().enumerate() {
                let h = self.items[item].loaded_at.map_or(0.0, |t| {
                    (1.0 - now.duration_since(t).as_secs_f64() / HIGHLIGHT.as_secs_f64())
                        .clamp(0.0, 1.0)
                });
                if let Some(tile) = self.walk.views[v].tiles.get_mut(slot) {
                    tile.highlight = h as f32;
                }
            }
        }
    }

    /// Consume the parts of `item` that are next in order; returns the layer that changed
    /// and, for a tile, the face rectangle that changed (`None`: the whole layer).
    fn consume(
        &mut self,
        item: usize,
        now: Instant,
    ) -> Result<Option<(usize, Option<FaceRect>)>, SourceError> {
        let what = self.item_name(item);
        let it = &mut self.items[item];
        let before = it.level;
        while let Some(data) = it.waiting.remove(&it.next) {
            if it.next < it.first_level_part {
                it.mesh = Some(tile_mesh_from_bytes(&data, &what)?);
            } else {
                it.decoder.push(&data).map_err(|e| SourceError::Format {
                    what: what.clone(),
                    message: e.to_string(),
                })?;
            }
            it.next += 1;
        }
        let level = it.decoder.finest_level();
        if level == before || level.is_none() {
            return Ok(None);
        }
        let Some(img) = it.decoder.finest() else {
            return Ok(None);
        };
        let level = level.unwrap_or(0);
        let rgba = image_rgba(img);
        let (w, h) = (img.width(), img.height());
        let view = it.view;
        match it.kind {
            Kind::Background => {
                let n = self.walk.views[view].face_size;
                self.dense[view][0] = background_map((&rgba, w, h), n, &what)?;
                let it = &mut self.items[item];
                it.level = Some(level);
                it.loaded_at = Some(now);
                Ok(Some((0, None)))
            }
            Kind::Tile { tile, slab } => {
                let Some(mesh) = it.mesh.clone() else {
                    return Ok(None);
                };
                let layer = slab as usize + 1;
                paste_tile(
                    &mut self.dense[view][layer],
                    self.grid,
                    tile,
                    (&rgba, w, h, level),
                    &what,
                )?;
                let it = &mut self.items[item];
                it.level = Some(level);
                it.loaded_at = Some(now);
                let v = &mut self.walk.views[view];
                match self.tile_items[view].iter().position(|&i| i == item) {
                    Some(slot) => v.tiles[slot].finest_level = level,
                    None => {
                        let mut vt = ViewTile::new(tile, slab, mesh, v.face_size);
                        vt.finest_level = level;
                        let key = |t: &ViewTile| (t.slab, self.grid.tile_index(t.tile));
                        let slot = v.tiles.partition_point(|t| key(t) < key(&vt));
                        v.tiles.insert(slot, vt);
                        self.tile_items[view].insert(slot, item);
                    }
                }
                let (x0, y0, x1, y1) = self.grid.pixel_rect(tile);
                let rect = FaceRect {
                    face: tile.face,
                    x0,
                    y0,
                    x1,
                    y1,
                };
                Ok(Some((layer, Some(rect))))
            }
        }
    }

    fn item_name(&self, item: usize) -> String {
        let it = &self.items[item];
        let vp = self.walk.views.get(it.view).map_or(it.view, |v| v.index);
        match it.kind {
            Kind::Tile { tile, slab } => tile_key(vp, slab, tile),
            Kind::Background => format!("viewpoint {vp} background"),
        }
    }

    /// The session item shown by tile `tile` of view `view` (positions in `walk.views`).
    pub fn tile_item(&self, view: usize, tile: usize) -> Option<usize> {
        self.tile_items.get(view)?.get(tile).copied()
    }

    /// Live counts for the session from the GPU feedback of `plan` (drawn from
    /// `self.walk.views`): every tile of every counted pass, weighted by the pass's blend
    /// weight, with the level the pass samples; tiles drawn but hidden count zero; the
    /// pixels no tile covers count for the view's background. A tile in
    /// the frustum that is drawn coarser than needed counts at least one pixel: its coarse
    /// opacity mask (averaged texels under the 0.5 threshold) may hide it entirely, and a
    /// tile that is never counted would never be refined.
    pub fn live_counts(&self, plan: &FramePlan, counts: &[ViewCounts]) -> Vec<LiveCount> {
        let mut by_item: HashMap<usize, LiveCount> = HashMap::new();
        for c in counts {
            let Some(pass) = plan.passes.iter().find(|p| p.view == c.view) else {
                continue;
            };
            let needed = pass.uniforms.params[0].max(0.0).floor() as u32;
            let mut add = |slot: usize, px: f64| {
                if let Some(item) = self.tile_item(c.view, slot) {
                    let e = by_item.entry(item).or_insert(LiveCount {
                        item,
                        pixels: 0.0,
                        needed_level: needed,
                    });
                    e.pixels += px;
                    e.needed_level = e.needed_level.min(needed);
                }
            };
            for (slot, &px) in c.pixels.iter().enumerate() {
                add(slot, px as f64 * pass.weight);
            }
            let tiles = self
                .walk
                .views
                .get(c.view)
                .map_or(&[][..], |v| &v.tiles[..]);
            for &slot in &pass.visible {
                let hidden = c.pixels.get(slot).is_none_or(|&px| px == 0);
                if hidden && tiles.get(slot).is_some_and(|t| t.finest_level > needed) {
                    add(slot, 1.0);
                }
            }
            // Pixels no tile of this view covers show its background (or a hole).
            let covered: u64 = c.pixels.iter().map(|&p| p as u64).sum();
            let open = (plan.width as u64 * plan.height as u64).saturating_sub(covered);
            let bg = self
                .session
                .table()
                .background_item(c.view)
                .filter(|_| open > 0);
            if let Some(item) = bg {
                let e = by_item.entry(item).or_insert(LiveCount {
                    item,
                    pixels: 0.0,
                    needed_level: needed,
                });
                e.pixels += open as f64 * pass.weight.max(0.1);
                e.needed_level = e.needed_level.min(needed);
            }
        }
        let mut out: Vec<LiveCount> = by_item.into_values().collect();
        out.sort_by_key(|c| c.item);
        out
    }

    /// Tiles whose latest level arrived less than `max_age` ago.
    pub fn recent_tiles(&self, max_age: Duration) -> Vec<RecentTile> {
        let now = Instant::now();
        let mut out = Vec::new();
        for (v, items) in self.tile_items.iter().enumerate() {
            for (slot, &item) in items.iter().enumerate() {
                if let Some(t) = self.items[item].loaded_at {
                    let age = now.duration_since(t);
                    if age <= max_age {
                        out.push(RecentTile {
                            view: v,
                            tile: slot,
                            age_s: age.as_secs_f64(),
                        });
                    }
                }
            }
        }
        out
    }

    /// Whether every item of the current segment (its ACH tiles and the backgrounds of its
    /// two viewpoints) shows at least its coarsest level.
    pub fn segment_showable(&self) -> bool {
        self.session.stats().coarse_fraction >= 1.0
    }

    /// Finest level shown per item (`None`: nothing yet).
    pub fn item_levels(&self) -> Vec<Option<u32>> {
        self.items.iter().map(|i| i.level).collect()
    }

    /// Bytes of parts that arrived over the last `window`.
    pub fn recent_bytes(&self, window: Duration) -> u64 {
        let now = Instant::now();
        self.arrivals
            .iter()
            .filter(|(t, _)| now.duration_since(*t) <= window)
            .map(|a| a.1 as u64)
            .sum()
    }
}
