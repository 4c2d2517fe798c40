//! The `shrunk` variant: occluder shrinking along the track, with sampling refined where
//! visibility changes. Conservative for every point of the cell, not only sampled ones, and
//! tested against the scene's exact solids rather than the reference viewpoint's depth
//! image, so openings and occluders count whatever their size and however they fall
//! between pixel centres.
//!
//! # What a tile holds
//!
//! A tile of slab `k` must be kept when any of its points can be seen from any point `X` of
//! the cell (the track from the previous to the next reference viewpoint). Its points are
//! what its opaque pixels stand for, taken as the independent oracle ([`crate::oracle`])
//! takes them, so that the oracle can never count a culled tile as seen. With `V` the
//! reference viewpoint, `r_p` a pixel's stored radial depth and `τ` the [`MatchRule`]
//! tolerance (`depth_tolerance + per_pixel_angle · π/2/N`), the oracle attributes a surface
//! point `Y` seen from some `X` to pixel `p` when
//! - `Y`'s direction from `V` falls in `p`'s footprint and `|Y − V|` lies in the band
//!   `[r_p/(1 + τ), r_p/(1 − τ)]`, or
//! - `Y`'s direction falls in a neighbouring pixel `c` (within the search radius `R`, same
//!   face), no layer at `c` has a depth whose band holds `|Y − V|`, and `|Y − V|` lies in
//!   `p`'s band and in slab `k`'s range.
//!
//! So for each footprint pixel `c` of the tile grown by `R` the tile holds `footprint(c) ×`
//! a union of distance intervals: the band of `c` itself (if it is the tile's), and for
//! each tile pixel `q ≠ c` within `R`, `q`'s band within the slab's range minus the bands of
//! every layer at `c`. These pieces cover every point the oracle could ever attribute to
//! the tile (the last condition mostly removes the neighbours' share: on a continuous
//! surface the bands at `c` already hold them).
//!
//! # Lemma (occluder shrinking; Wonka, Wimmer & Schmalstieg 2000, in our form)
//!
//! Take a segment from `X` to `P`, its point `Q = X + t·(P − X)` at some `t ∈ (0, 1)`, and
//! an occluder `S` whose interior holds the ball around `Q` of radius `c = (1 − t)·ε + t·δ`.
//! Then for every `X'` with `|X' − X| ≤ ε` and every `P'` with `|P' − P| ≤ δ` the segment
//! `X' → P'` passes through `Q' = X' + t·(P' − X')`, and `|Q' − Q| = |(1 − t)(X' − X) +
//! t(P' − P)| ≤ c`: `Q'` lies inside `S`. `S` is a solid of the scene, or a box inside the
//! union of two touching ones (whose boundary is made of their surfaces). If `X'` is not
//! inside `S`, the segment enters `S` before `Q'`: it crosses a surface strictly before
//! `P'`, and `P'` is hidden from `X'` (a viewer on a surface looking into its solid sees it
//! at distance 0).
//!
//! Points farther along the line cost nothing. Write a target point as `P' = P + α·u + w`,
//! `u = (P − X)/L`, `L = |P − X|`, `α ∈ [0, α_max]`, `|w| ≤ w_max`: at parameter `t/κ`,
//! `κ = (L + α)/L ≥ 1`, the segment `X' → P'` lies at `Q + (1 − t/κ)(X' − X) + (t/κ)·w`,
//! within `(1 − t)·ε + t·δ` of `Q` for `δ = ε·α_max/(L + α_max) + w_max`. So a box of
//! targets is handled by one segment from `X` to its point `P_c` nearest along `u`, with `δ`
//! from the box's extent across `u` (`w_max`, at a corner) and along it (`α_max`).
//!
//! # Why no point of the segment can see a culled tile
//!
//! Each straight stretch of the cell starts as [`ShrunkParams::base_intervals`] intervals;
//! an interval `[X_a, X_b]` lies in the ball of radius `ε = |X_b − X_a|/2` around its centre
//! `X`. What the tile holds starts as one group: a box around the footprint of the grown
//! tile times every band that reaches it (in a frame along its mean direction; the box
//! allows for the footprint's bulge between its corner directions). For each (interval,
//! group) pair, [`Solids::blocks`] asks whether the segment `X → P_c` passes through an
//! occluder shrunk by `(1 − t)·ε + t·δ` at parameter `t` — exact arithmetic on boxes,
//! spheres, cylinders and cones shrunk by a linearly varying distance, never a depth image
//! ([`prerender::erode`]) — leaving out any occluder whose interior the interval enters (the
//! lemma's "`X'` not inside `S`"). If so, by the lemma no point of the interval sees any
//! point of the group. A tile is culled only when every pair of a cover of the cell by
//! intervals and of the tile's pieces by groups is shown hidden: every point of the cell
//! lies in an interval, every point the tile holds in a group. Different pairs may be
//! hidden by different occluders, so occluders fuse (a row of columns hides what no single
//! column does).
//!
//! When a pair is not shown hidden, the exact segment from `X` to a stored point of the
//! group is cast ([`Solids::sees`]): if nothing is in the way the tile is seen and kept at
//! once. Otherwise the pair is refined where visibility changes — the interval halved when
//! `ε` is the larger term of the shrink distance, else the group split: a rectangle into
//! quarters, down to single footprint pixels, whose exact pieces are then built; a pixel
//! with several bands into one group per band; a band into halves (a long band seen from
//! aside is wide across the line of sight, and its far part may lie inside the very solid
//! whose surface it is on). A pair that cannot be refined further — a single band, halved
//! four times, under an interval of [`ShrunkParams::min_interval_m`] or one much
//! shorter than the band is wide — or a tile that runs out of
//! [`ShrunkParams::max_tests_per_tile`] keeps the tile. Every way out but "all pairs
//! hidden" keeps: culling needs the proof, keeping never does. Each tile is decided on its
//! own, so the result depends neither on thread count nor on order.
//!
//! Cases the argument settles by itself:
//! - **Occluders thinner than the shrink distance** (a column thinner than twice `(1 − t)ε +
//!   tδ` where the segment crosses it, or a wall thinner than that) vanish from the shrunk
//!   scene: the segment is not counted as blocked, the pair is refined and, if the occluder
//!   stays too thin even for the smallest pairs, the tile is kept. Thin occluders only ever
//!   keep more; a tile they hide together with others is culled when the pairs they hide
//!   alone are small enough.
//! - **Openings narrower than a pixel** (a slit that falls between the reference viewpoint's
//!   pixel centres) are in the scene's solids, not in a depth image: a segment through the
//!   slit passes through no solid and is not blocked, however the slit falls on the pixels.
//! - **Touching solids** hide together: the face two boxes share is inside their union
//!   (fused boxes, [`prerender::erode::Occluders`]), not an opening.
//! - **Surfaces without volume** (triangles, meshes, planes) have no inside and never block:
//!   what only they hide is kept (a ground plane hides nothing stored anyway: the track and
//!   the stored points are on the same side of it).
//! - **An occluder touching the track**: touching is not entering, so it still blocks; a
//!   track that runs into a solid leaves that solid out for the intervals inside it.
//! - **Nothing in front**: a tile with a pixel that the earlier slabs leave uncovered is
//!   seen from `V` itself and kept without a test.
//!
//! What it takes as given: the layers' stored depths and masks are what the scene holds at
//! the pixel centres (the tracer made them). A point the viewer draws between pixel centres,
//! on a surface whose depth changes by more than `τ` across a pixel (a grazing surface),
//! counts only as far as some pixel's band reaches it — as for the oracle.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::TileGrid;

use crate::cull::ViewpointCull;
use crate::input::{Cell, SlabLayer};
use crate::oracle::MatchRule;
use crate::OcclusionError;

mod search;

use search::Ctx;

/// Exact solid geometry, asked about segments (the shrunk variant's only view of the scene).
pub trait Solids: Sync {
    /// Whether nothing lies strictly between `from` and `to` (a point on a surface): `to` is
    /// seen from `from`. Used only to keep tiles early, so erring towards "seen" is safe.
    fn sees(&self, from: DVec3, to: DVec3) -> bool;
    /// Whether the segment from `from` to `to` passes through the interior of a solid shrunk
    /// by `(1 − t)·e_from + t·e_to` at its point of parameter `t`, a solid whose interior
    /// the segment `source` does not enter. Must never answer `true` wrongly.
    fn blocks(
        &self,
        from: DVec3,
        to: DVec3,
        e_from: f64,
        e_to: f64,
        source: (DVec3, DVec3),
    ) -> bool;
}

/// A point on a surface, reached from `from` unless something lies in front of it; the
/// last part in `1e-5` of the way is not looked at (the point's own surface).
fn sees_via<G: crate::oracle::Geometry + ?Sized>(g: &G, from: DVec3, to: DVec3) -> bool {
    let v = to - from;
    let len = v.length();
    if !(len > 0.0 && len.is_finite()) {
        return true;
    }
    g.first_hit(from, v / len, len * (1.0 - 1e-5)).is_none()
}

/// A scene as the shrunk variant sees it: exact first hits for "is this point seen" and the
/// scene's solids, with touching boxes fused ([`prerender::erode::Occluders`]), for the
/// shrunk-segment tests.
pub struct SceneSolids<'a, G: ?Sized> {
    geometry: &'a G,
    occluders: prerender::erode::Occluders,
}

impl<'a> SceneSolids<'a, prerender::scene::Scene> {
    /// A built-in or TOML scene: its boxes, spheres, cylinders and cones occlude.
    pub fn new(scene: &'a prerender::scene::Scene) -> Self {
        SceneSolids {
            geometry: scene,
            occluders: prerender::erode::Occluders::new(
                scene.desc().objects.iter().map(|o| &o.shape),
            ),
        }
    }
}

impl<'a> SceneSolids<'a, crate::synth::BoxScene> {
    /// An analytic box scene: its boxes occlude (the ground plane has no inside).
    pub fn boxes(scene: &'a crate::synth::BoxScene) -> Self {
        let shapes: Vec<prerender::scene::Shape> = scene
            .boxes
            .iter()
            .map(|b| prerender::scene::Shape::Box {
                min: b.min,
                max: b.max,
            })
            .collect();
        SceneSolids {
            geometry: scene,
            occluders: prerender::erode::Occluders::new(shapes.iter()),
        }
    }
}

impl<G: crate::oracle::Geometry + ?Sized> SceneSolids<'_, G> {
    /// Solids taken from the scene, and fused boxes added.
    pub fn counts(&self) -> (usize, usize) {
        self.occluders.counts()
    }

    /// The scene these solids come from.
    pub fn scene(&self) -> &G {
        self.geometry
    }
}

impl<G: crate::oracle::Geometry + ?Sized> Solids for SceneSolids<'_, G> {
    fn sees(&self, from: DVec3, to: DVec3) -> bool {
        sees_via(self.geometry, from, to)
    }
    fn blocks(
        &self,
        from: DVec3,
        to: DVec3,
        e_from: f64,
        e_to: f64,
        source: (DVec3, DVec3),
    ) -> bool {
        self.occluders.blocks(from, to, e_from, e_to, source)
    }
}

/// Knobs of the shrunk variant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShrunkParams {
    /// Each straight stretch of the cell starts as this many equal intervals (the base
    /// sampling; refined from there where a pair is not settled).
    pub base_intervals: u32,
    /// Intervals are not halved below this length, metres.
    pub min_interval_m: f64,
    /// Segment tests per tile before giving up (and keeping it).
    pub max_tests_per_tile: u32,
    /// What a pixel holds: the oracle's rule for attributing a seen point to a pixel.
    pub content: MatchRule,
}

impl Default for ShrunkParams {
    fn default() -> Self {
        ShrunkParams {
            base_intervals: 4,
            min_interval_m: 1e-3,
            max_tests_per_tile: 4096,
            content: MatchRule::default(),
        }
    }
}

/// What happened to the tiles of one run, summed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShrunkStats {
    /// Later-slab tiles decided.
    pub tiles: u64,
    /// Kept because a pixel is seen from the reference viewpoint itself (nothing in front).
    pub kept_direct: u64,
    /// Kept because a segment from a track point to a stored point is free.
    pub kept_seen: u64,
    /// Kept without proof either way (refinement floor or test budget reached).
    pub kept_undecided: u64,
    /// Culled: every (interval, pixel group) pair shown hidden.
    pub culled: u64,
    /// Shrunk-segment tests and free-segment tests cast.
    pub block_tests: u64,
    pub see_tests: u64,
}

impl ShrunkStats {
    pub fn add(&mut self, o: &ShrunkStats) {
        self.tiles += o.tiles;
        self.kept_direct += o.kept_direct;
        self.kept_seen += o.kept_seen;
        self.kept_undecided += o.kept_undecided;
        self.culled += o.culled;
        self.block_tests += o.block_tests;
        self.see_tests += o.see_tests;
    }
}

/// Cull one reference viewpoint's layers (nearest first) for the motion in `cell`, against
/// exact `solids`. The nearest slab is kept whole (it is what `V` sees); every tile of a
/// later slab is decided on its own, so the result does not depend on thread count or on
/// the order tiles, slabs or viewpoints are processed in.
pub fn cull_viewpoint_shrunk(
    cell: &Cell,
    grid: &TileGrid,
    layers: &[SlabLayer],
    params: &ShrunkParams,
    solids: &dyn Solids,
) -> Result<(ViewpointCull, ShrunkStats), OcclusionError> {
    crate::cull::check_inputs(cell, grid, layers)?;
    let tol = crate::cull::content_tolerance(&params.content, grid.face_size)?;
    if params.base_intervals == 0 || params.min_interval_m.is_nan() || params.min_interval_m <= 0.0
    {
        return Err(OcclusionError::Parameter {
            name: "shrunk",
            message: "base intervals must be at least 1 and the smallest interval positive".into(),
        });
    }
    let v = cell.viewpoint;
    let stretches: Vec<(DVec3, DVec3)> = cell
        .motion_pieces(params.base_intervals)
        .into_iter()
        .map(|(a, b)| (v + a, v + b))
        .collect();
    let ctx = Ctx {
        v,
        grid,
        layers,
        stretches: &stretches,
        params,
        solids,
        tol,
    };
    let (cull, costs) = crate::cull::decide_later_tiles(layers, |k, t| ctx.decide(k, t));
    let mut stats = ShrunkStats::default();
    for s in &costs {
        stats.add(s);
    }
    Ok((cull, stats))
}
