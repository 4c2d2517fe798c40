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
//! arrived). A background is pasted at whatever level has arrived. The parts taken in a step
//! are decoded for all items at once on every core (each item has its own decoder), then
//! placed in order. Only the texels around each tile that arrived are rebuilt, and the step
//! reports them so the renderer writes just those ([`StepReport::regions`]); views laid out
//! or dropped are re-uploaded whole ([`crate::gpu::Renderer::invalidate_view`]). Each tile's
//! [`crate::refview::ViewTile::highlight`] is 1 when a level of it arrives and fades to 0 over
//! [`HIGHLIGHT`], for the renderer's highlight overlay.
//!
//! A session may read a server or a database directory alike ([`streamer::client::Source`]).
//!
//! Decoded memory is bounded too (the session's cache bounds downloaded bytes only). A view
//! is laid out lazily: until its first background or tile level is consumed its layers are
//! 1×1-face transparent placeholders and it holds no dense maps, so it draws as nothing yet.
//! When the decoded state of all views ([`StreamedWalkthrough::decoded_bytes`]: layers with
//! mips, dense maps, decoders, meshes) exceeds
//! [`StreamedWalkthrough::decoded_budget_bytes`], the views farthest along the track from the
//! position are dropped back to placeholders (never the two around the position nor those
//! of the predicted next segment) and their items start over; the step reports them in
//! [`StepReport::changed_views`] so the renderer forgets their GPU copies too. When the
//! walker comes back, the views are consumed again from the session's cache, and what left
//! the cache is downloaded again (the session asks for what its cache lacks).
//!
//! Decoding is spread over several steps so that neither a returning view nor a burst of
//! arrivals costs one long frame: every part a step consumes, whether it arrived in this
//! step or is taken from the session's cache, counts against
//! [`StreamedWalkthrough::redecode_budget`] per step (the decoded texels of the PTM levels,
//! as the session's item table counts them, plus [`REDECODE_PART_BYTES`] per part for its
//! fixed cost; at least one part per step).
//! The parts are taken first for the pair of views drawn, then the other protected views;
//! within those, every item's mesh and coarsest level before any item's finer levels (the
//! PTM decoder gives the coarse levels first, so a view being re-filled draws from whatever
//! levels it has, coarse everywhere before sharp anywhere), nearest view first. The rest
//! waits, arrived parts beside their item and the others in the cache, for the next steps
//! ([`StepReport::backlog`]); nothing is skipped, so
//! the views end as the one-step path leaves them. A partially re-filled view is reported as
//! any streamed one is: whole when it is laid out again, by tile regions afterwards.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::time::{Duration, Instant};

use bytes::Bytes;
use rayon::prelude::*;
use streamer::client::{
    next_segment, LiveConfig, LiveCount, LiveError, LiveSession, MotionTracker,
};
use streamer::ptm::{Decoder, Limits};
use tracks::manifest::tile_key;
use tracks::{CubeMap, PerspectiveCamera, TileGrid, TileId};

use crate::feedback::ViewCounts;
use crate::plan::FramePlan;
use crate::refview::{RefView, ViewTile};
use crate::source::{
    image_rgba, manifest_track, paste_tile, tile_mesh_from_bytes, SourceError, Walkthrough,
};
use crate::texture::Layer;
use tracks::PixelRect;

mod redecode;

/// How long a newly loaded tile stays highlighted.
pub const HIGHLIGHT: Duration = Duration::from_secs(1);

/// Default of [`StreamedWalkthrough::redecode_budget`]: 1 MiB per step, counted as
/// decoded texels plus [`REDECODE_PART_BYTES`] per part. On the synthetic street at face 512
/// (16-pixel tiles, the `redecode_step_times` measurement in `viewer/tests/stream.rs`, a
/// loaded 2-core machine) that is about 200 parts and a median of 11 ms per step for choosing,
/// decoding, pasting and updating tile regions, where decoding a returning view in one step
/// took up to 630 ms; a returning face-1024 view (tens of megabytes) is re-filled over some
/// dozens of frames, the coarse levels of all its tiles within the first ones. The same
/// budget spreads a burst of arrivals (a fast link delivers a segment's parts within a few
/// steps).
pub const DEFAULT_REDECODE_BUDGET: u64 = 1 << 20;

/// What one part counts against [`StreamedWalkthrough::redecode_budget`] besides its decoded
/// bytes: the fixed cost of decoding, pasting and updating a tile's region, in the same units.
pub const REDECODE_PART_BYTES: u64 = 4096;

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

struct ItemState {
    /// Position of the view in `walk.views`.
    view: usize,
    kind: Kind,
    /// Parts received and not yet consumed (they may arrive out of order).
    waiting: HashMap<usize, Bytes>,
    /// Parts consumed (a prefix).
    next: usize,
    first_level_part: usize,
    /// What the decoder may allocate (a fresh decoder after eviction takes the same).
    limits: Limits,
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
    /// `RefView::index` of every view whose content changed as a whole (laid out, dropped
    /// back to placeholders, or no longer needed before anything of it arrived): re-upload
    /// these.
    pub changed_views: Vec<usize>,
    /// Tile arrivals: `(RefView::index, layer, texel rectangles per mip level)` as
    /// [`Layer::update_region`] returned them, for
    /// [`crate::gpu::Renderer::update_layer_region`]; one entry per tile.
    pub regions: Vec<(usize, usize, Vec<PixelRect>)>,
    /// Parts that arrived.
    pub arrivals: usize,
    /// Tiles or backgrounds that became visible or sharper.
    pub upgraded: usize,
    /// `RefView::index` of the views whose decoded state was dropped to stay within
    /// [`StreamedWalkthrough::decoded_budget_bytes`] (also in `changed_views`).
    pub evicted: Vec<usize>,
    /// [`StreamedWalkthrough::decoded_bytes`] after the step.
    pub decoded_bytes: u64,
    /// Parts consumed in this step (arrived in it, or taken from the session's cache:
    /// re-decoding after an eviction, or parts that arrived while their view was not
    /// needed, or in a step whose budget was spent), and what they count against
    /// [`StreamedWalkthrough::redecode_budget`] (decoded bytes as the session's item table
    /// counts them, plus [`REDECODE_PART_BYTES`] each): at most the budget unless it is a
    /// single part.
    pub redecoded_parts: usize,
    pub redecoded_bytes: u64,
    /// Items of the views needed now (or with parts that arrived) whose next parts wait
    /// (arrived, or in the session's cache) for later steps, the per-step budget being spent.
    pub backlog: usize,
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
    /// The tile grid of the views as laid out: the database's, `layout_level` levels
    /// coarser when the memory budget asks for it.
    grid: TileGrid,
    /// The database's face and tile sizes.
    db_grid: TileGrid,
    /// PTM level the views are laid out at (0: full resolution; see
    /// [`StreamedWalkthrough::set_memory_budget`]).
    layout_level: u32,
    /// Largest [`StepReport::decoded_bytes`] so far.
    decoded_peak: u64,
    items: Vec<ItemState>,
    /// Per view: level-0 RGBA of every layer (background, then one per slab); empty while
    /// the view is not laid out (placeholder layers).
    dense: Vec<Vec<CubeMap<[u8; 4]>>>,
    /// Per view: the item of each entry of `walk.views[v].tiles`.
    tile_items: Vec<Vec<usize>>,
    /// Per view: every item of that viewpoint.
    view_items: Vec<Vec<usize>>,
    /// Layers per view (background + slabs).
    layer_count: usize,
    /// Decoded bytes above which the farthest views are dropped (see the module docs).
    /// Defaults to [`StreamedWalkthrough::full_view_bytes`] × 4: the two views drawn and the
    /// predicted next two; [`StreamedWalkthrough::set_memory_budget`] sets it and lays the
    /// views out coarser when four do not fit.
    pub decoded_budget_bytes: u64,
    /// Decoded bytes of parts taken from the session's cache per step (see the module docs
    /// and [`StreamedWalkthrough::set_redecode_budget`]).
    redecode_budget: u64,
    /// Motion along the track, predicted as the session does for its prefetch.
    motion: MotionTracker,
    start: Instant,
    /// Views protected from eviction at the previous step.
    protected: BTreeSet<usize>,
    /// Views laid out since the last report.
    fresh: BTreeSet<usize>,
    /// Arrival times of parts over the last seconds (for the UI).
    arrivals: VecDeque<(Instant, usize)>,
    /// Problems with received data (bytes that passed their checksum but do not decode).
    pub errors: Vec<String>,
    /// Coarse PTM levels hold colour × coverage (format 5 on): divided by the coverage
    /// before they are pasted ([`streamer::db::unpremultiply`]).
    premultiplied: bool,
}

/// The state of session item `i` (nothing received yet).
fn item_state(session: &LiveSession, i: usize) -> Result<ItemState, StreamError> {
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
        let premultiplied = session.top().coarse_levels_premultiplied();
        let views: Vec<RefView> = entry
            .viewpoints
            .iter()
            .map(|vp| RefView {
                index: vp.index,
                s: vp.s,
                position: vp.position,
                face_size: n,
                tile_size: m.tile_size,
                layers: placeholder_layers(layer_count),
                tiles: Vec::new(),
            })
            .collect();
        let mut items = Vec::with_capacity(session.table().items.len());
        let mut view_items = vec![Vec::new(); views.len()];
        for i in 0..session.table().items.len() {
            let state = item_state(&session, i)?;
            if let Some(list) = view_items.get_mut(state.view) {
                list.push(i);
            }
            items.push(state);
        }
        let dense = vec![Vec::new(); views.len()];
        let tile_items = vec![Vec::new(); views.len()];
        let decoded_budget_bytes = 4 * full_view_bytes(n, layer_count);
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
            db_grid: grid,
            layout_level: 0,
            decoded_peak: 0,
            items,
            dense,
            tile_items,
            view_items,
            layer_count,
            decoded_budget_bytes,
            redecode_budget: DEFAULT_REDECODE_BUDGET,
            motion: MotionTracker::new(),
            start: Instant::now(),
            protected: BTreeSet::new(),
            fresh: BTreeSet::new(),
            arrivals: VecDeque::new(),
            errors: Vec::new(),
            premultiplied,
        })
    }

    pub fn session(&self) -> &LiveSession {
        &self.session
    }

    pub fn session_mut(&mut self) -> &mut LiveSession {
        &mut self.session
    }

    /// Hold the decoded views within `bytes` (decoded layers, dense maps, meshes and the
    /// renderer's copy of the layers): the views are laid out at the finest resolution at
    /// which the views that must be held — the pair drawn and the predicted next pair, four
    /// views — fit, and the session fetches no finer PTM level. The same rule for every
    /// database, so memory follows the budget, not the database: a face-512 database laid out
    /// in 96 MiB is drawn from its level 1 (faces of 256), one at face 192 at full
    /// resolution. Views already laid out start over. Returns the layout level.
    pub fn set_memory_budget(&mut self, bytes: u64) -> u32 {
        let (n, t) = (self.db_grid.face_size, self.db_grid.tile_size);
        let max_k = t.max(1).ilog2().min(n.trailing_zeros());
        let k = (0..=max_k)
            .find(|&k| 4 * full_view_bytes(n >> k, self.layer_count) <= bytes)
            .unwrap_or(max_k);
        self.decoded_budget_bytes = bytes;
        if k != self.layout_level {
            for v in 0..self.walk.views.len() {
                self.evict(v);
                self.fresh.insert(v);
            }
            self.layout_level = k;
            self.grid = TileGrid::new(n >> k, t >> k).unwrap_or(self.db_grid);
            for v in &mut self.walk.views {
                v.face_size = self.grid.face_size;
                v.tile_size = self.grid.tile_size;
            }
            self.session.set_finest_level((k > 0).then_some(k));
        }
        k
    }

    /// Largest decoded state of a step so far (see [`StreamedWalkthrough::decoded_bytes`]).
    pub fn decoded_peak(&self) -> u64 {
        self.decoded_peak
    }

    /// The PTM level the views are laid out at (0: full resolution).
    pub fn layout_level(&self) -> u32 {
        self.layout_level
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
            let view = self.session.table().items[i].viewpoint;
            if let Some(list) = self.view_items.get_mut(view) {
                list.push(i);
            }
            match item_state(&self.session, i) {
                Ok(state) => self.items.push(state),
                Err(e) => {
                    self.errors.push(e.to_string());
                    self.items.push(ItemState {
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
                    });
                }
            }
        }
        let now = Instant::now();
        let mut report = StepReport {
            arrivals: arrived.len(),
            ..Default::default()
        };
        let drawn = self.drawn_views(s, camera);
        let protected = self.protected_views(s, &drawn, now);
        // Views that stopped being drawn before anything of them arrived: the renderer may
        // hold a placeholder upload of them.
        let mut views: BTreeSet<usize> = self
            .protected
            .difference(&protected)
            .filter(|&&v| !self.laid_out(v))
            .filter_map(|&v| self.walk.views.get(v).map(|rv| rv.index))
            .collect();
        let mut touched = BTreeSet::new();
        for a in arrived {
            self.walk.bytes += a.data.len() as u64;
            self.arrivals.push_back((now, a.data.len()));
            let Some(it) = self.items.get_mut(a.item) else {
                continue;
            };
            // Parts of a view that is neither laid out nor needed soon stay in the session's
            // cache only (consumed from there when the view is needed).
            let wanted = protected.contains(&it.view)
                || self.dense.get(it.view).is_some_and(|d| !d.is_empty());
            if a.part >= it.next && !it.failed && wanted {
                it.waiting.insert(a.part, a.data);
                touched.insert(a.item);
            }
        }
        // Items of the views needed now whose next part is in the session's cache (e.g. they
        // were evicted here, or arrived while their view was not needed).
        for &v in &protected {
            for &i in self.view_items.get(v).map_or(&[][..], |l| &l[..]) {
                let it = &self.items[i];
                if !it.failed
                    && (it.waiting.contains_key(&it.next)
                        || self.session.part_bytes(i, it.next).is_some())
                {
                    touched.insert(i);
                }
            }
        }
        // Parts that arrived in earlier steps and wait for a step with budget left: taken in
        // turn, as they would have been at once, even where their view is no longer needed
        // (a view that received them may stand in later, e.g. with the server gone; the
        // decoded budget evicts what is too far).
        for (i, it) in self.items.iter().enumerate() {
            if !it.failed && it.waiting.contains_key(&it.next) {
                touched.insert(i);
            }
        }
        while self
            .arrivals
            .front()
            .is_some_and(|(t, _)| now.duration_since(*t) > Duration::from_secs(10))
        {
            self.arrivals.pop_front();
        }
        let plan = self.plan_redecode(&touched, &drawn, &protected, s);
        report.redecoded_parts = plan.parts;
        report.redecoded_bytes = plan.bytes;
        report.backlog = plan.backlog;
        // The parts each touched item takes in this step, decoded for all items at once on
        // every core (each item has its own decoder), then placed into the views in order.
        let work: Vec<(usize, Vec<Bytes>, String)> = touched
            .iter()
            .map(|&item| {
                let count = plan.allowed.get(&item).copied().unwrap_or(0);
                (item, self.take_parts(item, count), self.item_name(item))
            })
            .collect();
        let mut work = work.into_iter().peekable();
        let mut jobs = Vec::new();
        for (i, it) in self.items.iter_mut().enumerate() {
            if let Some((_, parts, what)) = work.next_if(|w| w.0 == i) {
                jobs.push((i, it, parts, what));
            }
        }
        let premultiplied = self.premultiplied;
        let k = self.layout_level;
        let decoded: Vec<(usize, String, Result<Option<Decoded>, SourceError>)> = jobs
            .into_par_iter()
            .map(|(i, it, parts, what)| {
                let d = decode_parts(it, parts, &what, premultiplied, k);
                (i, what, d)
            })
            .collect();
        // Tile rectangles that changed.
        let mut rects: Vec<(usize, usize, PixelRect)> = Vec::new();
        for (item, what, d) in decoded {
            match d.and_then(|d| match d {
                Some(d) => self.place(item, d, &what, now),
                None => Ok(None),
            }) {
                Ok(Some((layer, rect))) => {
                    rects.push((self.items[item].view, layer, rect));
                    report.upgraded += 1;
                }
                Ok(None) => {}
                Err(e) => {
                    self.items[item].failed = true;
                    self.errors.push(e.to_string());
                }
            }
        }
        // A tile redoes the dilation and mip texels around its own rectangle only; the
        // layers that changed are redone in parallel.
        let mut by_layer: BTreeMap<(usize, usize), Vec<PixelRect>> = BTreeMap::new();
        for (v, layer, rect) in rects {
            by_layer.entry((v, layer)).or_default().push(rect);
        }
        let mut jobs = Vec::new();
        for (v, (view, dense)) in self.walk.views.iter_mut().zip(&self.dense).enumerate() {
            for (l, (layer, map)) in view.layers.iter_mut().zip(dense).enumerate() {
                if let Some(rects) = by_layer.remove(&(v, l)) {
                    jobs.push((view.index, l, layer, map, rects));
                }
            }
        }
        let regions: Vec<Vec<(usize, usize, Vec<PixelRect>)>> = jobs
            .into_par_iter()
            .map(|(index, l, layer, map, rects)| {
                rects
                    .into_iter()
                    .map(|r| (index, l, layer.update_region(map, r)))
                    .filter(|r| !r.2.is_empty())
                    .collect()
            })
            .collect();
        report.regions.extend(regions.into_iter().flatten());
        // Views laid out in this step changed shape: uploaded whole.
        views.extend(
            std::mem::take(&mut self.fresh)
                .into_iter()
                .map(|v| self.walk.views[v].index),
        );
        // Decoded bytes per view, counted once a step (every item of every view).
        let mut per_view: Vec<u64> = (0..self.walk.views.len())
            .map(|v| self.view_decoded_bytes(v))
            .collect();
        for v in self.evict_over_budget(s, &protected, &per_view) {
            let index = self.walk.views[v].index;
            report.evicted.push(index);
            views.insert(index);
            per_view[v] = self.view_decoded_bytes(v);
        }
        report.regions.retain(|r| !report.evicted.contains(&r.0));
        self.protected = protected;
        report.changed_views = views.into_iter().collect();
        report.decoded_bytes = per_view.iter().sum();
        self.decoded_peak = self.decoded_peak.max(report.decoded_bytes);
        self.fade_highlights(now);
        report
    }

    /// Positions in `walk.views` of the pair around `s` (what arrives for them is kept) and
    /// of the views [`StreamedWalkthrough::plan`] draws for `camera` instead where that pair
    /// shows next to nothing ([`crate::plan::stand_ins`]).
    fn drawn_views(&self, s: f64, camera: &PerspectiveCamera) -> BTreeSet<usize> {
        let s = if s.is_finite() { s } else { 0.0 };
        let vp_s: Vec<f64> = self.walk.views.iter().map(|v| v.s).collect();
        let around = crate::plan::blend_pair(&vp_s, s);
        // Kept whenever they hold much more of the frustum than the pair around `s`, whether
        // drawn yet or not (the session's count of the pixels shown wavers from step to step,
        // and an evicted view would not come back without the server).
        let shown = self
            .stand_ins(camera, s, usize::MAX, 0.0)
            .and_then(|ok| crate::plan::blend_pair_among(&vp_s, s, &|v| ok[v]));
        around
            .into_iter()
            .chain(shown)
            .flat_map(|(a, b, _)| [a, b])
            .collect()
    }

    /// [`crate::plan::stand_ins`] for `camera` at `s`, `shown` the fraction of the visible
    /// pixels the pair around `s` shows.
    fn stand_ins(
        &self,
        camera: &PerspectiveCamera,
        s: f64,
        max_slabs: usize,
        shown: f64,
    ) -> Option<Vec<bool>> {
        let arcs: Vec<f64> = self.walk.views.iter().map(|v| v.s).collect();
        let counts = crate::plan::frustum_counts(&self.walk.views, camera, max_slabs);
        crate::plan::stand_ins(&arcs, &counts, s, shown)
    }

    /// The frame at `s`: [`crate::plan_frame`], except that where the views around `s`
    /// show too little of the frame while others that arrived earlier show much more (the
    /// walk went on past what arrived, e.g. the server is gone), the nearest of those are
    /// drawn instead of a mostly black frame ([`crate::plan::stand_ins`]). They are kept from
    /// eviction meanwhile.
    pub fn plan(
        &self,
        camera: &PerspectiveCamera,
        s: f64,
        budget: crate::DrawBudget,
    ) -> Result<FramePlan, crate::PlanError> {
        let shown = self.session.stats().visible_fraction;
        match self.stand_ins(camera, s, budget.max_slabs, shown) {
            Some(ok) => {
                crate::plan::plan_frame_among(&self.walk.views, camera, s, budget, &|v| ok[v])
            }
            None => crate::plan_frame(&self.walk.views, camera, s, budget),
        }
    }

    /// Positions in `walk.views` of the views kept at `s`: those `drawn` there
    /// ([`StreamedWalkthrough::drawn_views`]) and those of the segment the session
    /// prefetches (the motion predicted as it does).
    fn protected_views(
        &mut self,
        s: f64,
        drawn: &BTreeSet<usize>,
        now: Instant,
    ) -> BTreeSet<usize> {
        let t = now.duration_since(self.start).as_secs_f64();
        let s = if s.is_finite() { s } else { 0.0 };
        self.motion.observe(t, s);
        let vp_s: Vec<f64> = self.walk.views.iter().map(|v| v.s).collect();
        let mut out = drawn.clone();
        if self.session.prefetch() {
            let horizon = self.session.config().schedule.prefetch_horizon_s;
            if let Some(next) = next_segment(&self.motion, &vp_s, s, horizon) {
                out.extend([next, next + 1]);
            }
        }
        out.retain(|&v| v < vp_s.len());
        out
    }

    /// Whether view `v` (position in `walk.views`) has its full-size layers and dense maps.
    fn laid_out(&self, v: usize) -> bool {
        self.dense.get(v).is_some_and(|d| !d.is_empty())
    }

    /// Give view `v` its full-size (transparent) layers and dense maps, when it has none.
    fn lay_out(&mut self, v: usize) {
        if self.laid_out(v) {
            return;
        }
        let n = self.walk.views[v].face_size;
        self.dense[v] = vec![CubeMap::filled(n, [0u8; 4]); self.layer_count];
        self.walk.views[v].layers = vec![empty_layer(n); self.layer_count];
        self.fresh.insert(v);
    }

    /// Drop the decoded state of the views farthest along the track from `s` (never those
    /// in `protected`) until the total is within the budget (`per_view`: the decoded bytes
    /// of each view); returns the views dropped.
    fn evict_over_budget(
        &mut self,
        s: f64,
        protected: &BTreeSet<usize>,
        per_view: &[u64],
    ) -> Vec<usize> {
        let mut total: u64 = per_view.iter().sum();
        let mut out = Vec::new();
        if total <= self.decoded_budget_bytes {
            return out;
        }
        let mut order: Vec<usize> = (0..per_view.len())
            .filter(|v| !protected.contains(v) && per_view[*v] > 0)
            .collect();
        let dist = |v: usize| (self.walk.views[v].s - s).abs();
        order.sort_by(|&a, &b| dist(b).total_cmp(&dist(a)).then(b.cmp(&a)));
        for v in order {
            if total <= self.decoded_budget_bytes {
                break;
            }
            self.evict(v);
            total = total.saturating_sub(per_view[v]);
            out.push(v);
        }
        out
    }

    /// Back to nothing decoded for view `v`: placeholder layers, no tiles, its items start
    /// over (their parts are consumed again from the session's cache or downloaded again).
    fn evict(&mut self, v: usize) {
        let view = &mut self.walk.views[v];
        view.layers = placeholder_layers(self.layer_count);
        view.tiles = Vec::new();
        self.tile_items[v] = Vec::new();
        self.dense[v] = Vec::new();
        self.fresh.remove(&v);
        for &i in &self.view_items[v] {
            let it = &mut self.items[i];
            it.waiting = HashMap::new();
            it.next = 0;
            it.decoder = Decoder::new(it.limits);
            it.mesh = None;
            it.level = None;
            it.loaded_at = None;
        }
    }

    /// Decoded bytes held for view `v`: its layers (all mip levels; counted twice, for the
    /// renderer's copy) and dense maps when laid out, its tiles' meshes, and its items'
    /// decoders, meshes and parts waiting.
    pub fn view_decoded_bytes(&self, v: usize) -> u64 {
        let Some(view) = self.walk.views.get(v) else {
            return 0;
        };
        let maps = if self.laid_out(v) {
            let layers: u64 = view
                .layers
                .iter()
                .flat_map(|l| &l.levels)
                .map(map_bytes)
                .sum();
            // The layers twice: here and in the renderer's textures (which a software
            // rasteriser keeps in main memory too).
            2 * layers + self.dense[v].iter().map(map_bytes).sum::<u64>()
        } else {
            0
        };
        let tiles: u64 = view.tiles.iter().map(|t| mesh_bytes(&t.mesh)).sum();
        let items: u64 = self.view_items[v]
            .iter()
            .map(|&i| item_bytes(&self.items[i]))
            .sum();
        maps + tiles + items
    }

    /// Decoded bytes held over all views (see [`StreamedWalkthrough::view_decoded_bytes`]).
    pub fn decoded_bytes(&self) -> u64 {
        (0..self.walk.views.len())
            .map(|v| self.view_decoded_bytes(v))
            .sum()
    }

    /// Bytes of one laid-out view's layers (with mips, here and in the renderer) and dense
    /// maps: what a view costs once anything of it arrived (decoders and meshes come on top).
    pub fn full_view_bytes(&self) -> u64 {
        full_view_bytes(self.grid.face_size, self.layer_count)
    }

    /// Positions in `walk.views` of the views laid out (holding decoded layers).
    pub fn laid_out_views(&self) -> Vec<usize> {
        (0..self.walk.views.len())
            .filter(|&v| self.laid_out(v))
            .collect()
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

    /// The parts of `item` that are next in order (received, or at most `cached` of them
    /// taken from the session's cache), out of its waiting list.
    /// The next `count` parts of `item` in order, each from those that arrived for it or
    /// from the session's cache (fewer when one is in neither).
    fn take_parts(&mut self, item: usize, count: usize) -> Vec<Bytes> {
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
    fn place(
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
                Ok(Some((0, PixelRect::of_tile(self.grid, tile))))
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
                Ok(Some((layer, PixelRect::of_tile(self.grid, tile))))
            }
        }
    }

    fn item_name(&self, item: usize) -> String {
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

    /// The session item shown by tile `tile` of view `view` (positions in `walk.views`).
    pub fn tile_item(&self, view: usize, tile: usize) -> Option<usize> {
        self.tile_items.get(view)?.get(tile).copied()
    }

    /// Live counts for the session from the GPU feedback of `plan` (drawn from
    /// `self.walk.views`): every tile of every counted pass, weighted by the pass's blend
    /// weight, with the level the pass samples; tiles drawn but hidden count zero. The pixels
    /// no tile covers are not located by the pass: the background tiles they show get their
    /// counts from the session's CPU estimate (which the session merges with these). A tile in
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
            // The session counts levels of the database; the views may be laid out coarser.
            let needed_db = needed + self.layout_level;
            let mut add = |slot: usize, px: f64| {
                if let Some(item) = self.tile_item(c.view, slot) {
                    let e = by_item.entry(item).or_insert(LiveCount {
                        item,
                        pixels: 0.0,
                        needed_level: needed_db,
                    });
                    e.pixels += px;
                    e.needed_level = e.needed_level.min(needed_db);
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

/// An item's finest level, decoded ([`decode_parts`]).
struct Decoded {
    level: u32,
    rgba: Vec<u8>,
    width: u32,
    height: u32,
}

/// Feed `parts` (the item's next parts, in order) to its mesh and decoder; its finest level
/// when that became finer than the one shown (a coarse level divided by its coverage when
/// `premultiplied`, see [`streamer::db::clear_masked`]). Views laid out `k` levels coarser
/// than the database take level `k` where a finer one arrived, and meshes scaled to them.
/// Items are independent, so a step decodes them in parallel.
fn decode_parts(
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
                    v.pos_in_face = [v.pos_in_face[0] * scale, v.pos_in_face[1] * scale];
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
        streamer::db::unpremultiply(&mut rgba);
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

/// Transparent layers with 1×1 faces for a view not laid out: they draw as nothing (no
/// tiles reference them) at a few bytes each.
fn placeholder_layers(count: usize) -> Vec<Layer> {
    vec![Layer::from_rgba(CubeMap::filled(1, [0u8; 4])); count]
}

/// A transparent layer of face size `n` with its mip chain, as [`Layer::from_rgba`] of a
/// transparent map builds it, without the downsampling passes.
fn empty_layer(n: u32) -> Layer {
    let mut levels = vec![CubeMap::filled(n, [0u8; 4])];
    let mut m = n;
    while m >= 2 && m.is_multiple_of(2) {
        m /= 2;
        levels.push(CubeMap::filled(m, [0u8; 4]));
    }
    Layer { levels }
}

/// Bytes of one laid-out view of face size `n` with `layers` layers: each layer's mip chain
/// (twice: decoded here and uploaded to the renderer) and its dense level-0 map.
fn full_view_bytes(n: u32, layers: usize) -> u64 {
    // 6 faces × 4 bytes per texel, halving as `Layer::from_rgba` does.
    let face = |m: u32| 24 * u64::from(m).pow(2);
    let mut layer = face(n);
    let mut m = n;
    while m >= 2 && m.is_multiple_of(2) {
        m /= 2;
        layer += face(m);
    }
    let dense = face(n);
    layers as u64 * (2 * layer + dense)
}

fn map_bytes(m: &CubeMap<[u8; 4]>) -> u64 {
    std::mem::size_of_val(m.as_slice()) as u64
}

fn mesh_bytes(m: &crate::refview::TileMesh) -> u64 {
    (std::mem::size_of_val(&m.vertices[..]) + std::mem::size_of_val(&m.indices[..])) as u64
}

/// Decoded bytes an item holds: its decoder's levels, its mesh and the parts waiting.
fn item_bytes(it: &ItemState) -> u64 {
    let levels = it.decoder.header().map_or(0, |h| u32::from(h.levels));
    let decoded: usize = (0..levels)
        .filter_map(|l| it.decoder.level(l))
        .map(|img| img.data().len())
        .sum();
    let waiting: usize = it.waiting.values().map(|b| b.len()).sum();
    (decoded + waiting) as u64 + it.mesh.as_ref().map_or(0, mesh_bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_layers_match_the_mip_chain_of_a_transparent_map() {
        for n in [1, 2, 6, 16, 24] {
            let built = Layer::from_rgba(CubeMap::filled(n, [0u8; 4]));
            assert_eq!(empty_layer(n), built, "face {n}");
            let bytes: u64 =
                2 * built.levels.iter().map(map_bytes).sum::<u64>() + map_bytes(&built.levels[0]);
            assert_eq!(full_view_bytes(n, 3), 3 * bytes, "face {n}");
        }
    }

    #[test]
    fn placeholder_layers_are_tiny_and_transparent() {
        let layers = placeholder_layers(3);
        assert_eq!(layers.len(), 3);
        for l in &layers {
            assert_eq!(l.levels.len(), 1);
            assert_eq!(l.face_size(), 1);
            assert!(l.levels[0].as_slice().iter().all(|p| *p == [0u8; 4]));
        }
    }

    #[test]
    fn a_face_1024_view_with_two_slabs() {
        // Layer with mips 33.5 MB (here and in the renderer), dense map 25.2 MB, three layers.
        let b = full_view_bytes(1024, 3);
        assert_eq!(b, 3 * (2 * 33_554_424 + 25_165_824));
    }
}
