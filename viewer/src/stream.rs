//! A walkthrough streamed from `railview serve`: reference views whose tiles appear as their
//! mesh and PTM levels arrive.
//!
//! [`StreamedWalkthrough`] wraps a [`LiveSession`] (downloads, cache, budgets) and a
//! [`Walkthrough`] that starts with every view empty (transparent layers, no tiles). Each
//! [`StreamedWalkthrough::step`] hands the position and camera (and the GPU's visible-pixel
//! counts, see [`StreamedWalkthrough::live_counts`]) to the session and folds what arrived
//! into the views: an item's parts are consumed in order (mesh, then PTM level groups into an
//! incremental [`codec::ptm::Decoder`]); a tile joins its view once its mesh and coarsest
//! level are in, and is upgraded in place as finer levels decode (the coarse level stands in,
//! nearest, and [`crate::refview::ViewTile::finest_level`] keeps the renderer from sampling
//! finer than what arrived). A background is pasted at whatever level has arrived. The parts taken in a step
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

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::time::{Duration, Instant};

use streamer::client::{
    next_segment, LiveConfig, LiveCount, LiveError, LiveSession, MotionTracker,
};
use tracks::{CubeMap, PerspectiveCamera, PixelRect, TileGrid};

use crate::feedback::ViewCounts;
use crate::plan::FramePlan;
use crate::refview::RefView;
use crate::source::{manifest_track, SourceError, Walkthrough};
use items::{item_state, ItemState};
use memory::{full_view_bytes, placeholder_layers};

mod items;
mod memory;
mod redecode;
mod step;

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

/// What one [`StreamedWalkthrough::step`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepReport {
    /// `RefView::index` of every view whose content changed as a whole (laid out, dropped
    /// back to placeholders, or no longer needed before anything of it arrived): re-upload
    /// these.
    pub changed_views: Vec<usize>,
    /// Tile arrivals: `(RefView::index, layer, texel rectangles per mip level)` as
    /// [`crate::texture::Layer::update_region`] returned them, for
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
    /// before they are pasted ([`db::unpremultiply`]).
    premultiplied: bool,
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
        let current = session.track();
        let tracks: Vec<tracks::Track> = m
            .tracks
            .iter()
            .map(manifest_track)
            .collect::<Result<_, _>>()?;
        let track = tracks
            .get(current)
            .cloned()
            .ok_or_else(|| StreamError::Manifest(format!("no track {current}")))?;
        let n = m.face_size;
        let grid = TileGrid::new(n, m.tile_size).ok_or_else(|| {
            StreamError::Manifest(format!(
                "face size {n} and tile size {} do not make a tile grid",
                m.tile_size
            ))
        })?;
        let layer_count = m.slabs.len() + 1;
        let premultiplied = session.top().coarse_levels_premultiplied();
        let views: Vec<RefView> = db::split::unique_viewpoints(m)
            .into_iter()
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
        let stops = m
            .tracks
            .iter()
            .map(|t| t.viewpoints.iter().map(|v| (v.index, v.s)).collect())
            .collect();
        let mut walk = Walkthrough {
            scene: m.scene.clone(),
            track,
            views,
            slabs: m.slabs.clone(),
            bytes: 0,
            tracks,
            stops,
            current,
        };
        walk.set_track(current);
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

    /// Largest decoded state of a step so far (see [`StreamedWalkthrough::decoded_bytes`]).
    pub fn decoded_peak(&self) -> u64 {
        self.decoded_peak
    }

    /// The PTM level the views are laid out at (0: full resolution).
    pub fn layout_level(&self) -> u32 {
        self.layout_level
    }

    /// The camera goes onto track `t` of the network (see [`Walkthrough::set_track`]); the
    /// session follows at the next step.
    pub fn set_track(&mut self, t: usize) {
        self.walk.set_track(t);
    }

    /// The branch the user chose for the next junction, for the session's prefetch.
    pub fn set_branch(&mut self, branch: Option<tracks::network::Branch>) {
        self.session.set_branch(branch);
    }

    /// Positions in `walk.views` of the pair around `s` (what arrives for them is kept) and
    /// of the views [`StreamedWalkthrough::plan`] draws for `camera` instead where that pair
    /// shows next to nothing ([`crate::plan::stand_ins`]).
    fn drawn_views(&self, s: f64, camera: &PerspectiveCamera) -> BTreeSet<usize> {
        let s = if s.is_finite() { s } else { 0.0 };
        let (order, vp_s) = self.walk.order_and_arcs();
        let around = crate::plan::blend_pair(&vp_s, s);
        // Kept whenever they hold much more of the frustum than the pair around `s`, whether
        // drawn yet or not (the session's count of the pixels shown wavers from step to step,
        // and an evicted view would not come back without the server).
        let shown = self
            .stand_ins(camera, s, usize::MAX, 0.0)
            .and_then(|ok| crate::plan::blend_pair_among(&vp_s, s, &|k| ok[order[k]]));
        around
            .into_iter()
            .chain(shown)
            .flat_map(|(a, b, _)| [order[a], order[b]])
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
        let (order, arcs) = self.walk.order_and_arcs();
        let all = crate::plan::frustum_counts(&self.walk.views, camera, max_slabs);
        let counts: Vec<usize> = order
            .iter()
            .map(|&v| all.get(v).copied().unwrap_or(0))
            .collect();
        let on_track = crate::plan::stand_ins(&arcs, &counts, s, shown)?;
        // By position in `views`: only the current track's can stand in.
        let mut ok = vec![false; self.walk.views.len()];
        for (k, &v) in order.iter().enumerate() {
            ok[v] = on_track[k];
        }
        Some(ok)
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
        let order = self.walk.order();
        match self.stand_ins(camera, s, budget.max_slabs, shown) {
            Some(ok) => {
                crate::plan::plan_frame_on(&self.walk.views, &order, camera, s, budget, &|v| ok[v])
            }
            None => self.walk.plan(camera, s, budget),
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
        let (order, vp_s) = self.walk.order_and_arcs();
        let mut out = drawn.clone();
        if self.session.prefetch() {
            let horizon = self.session.config().schedule.prefetch_horizon_s;
            if let Some(next) = next_segment(&self.motion, &vp_s, s, horizon) {
                out.extend([order[next], order[next + 1]]);
            }
        }
        out.retain(|&v| v < self.walk.views.len());
        out
    }

    /// Set every tile's [`crate::refview::ViewTile::highlight`]: 1 when its latest level
    /// arrived, fading to 0 over [`HIGHLIGHT`] (the renderer tints by it; no re-upload
    /// needed).
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
