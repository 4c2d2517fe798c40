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

use std::collections::HashMap;

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::cubemap::{pixel_dir, subpixel_dir};
use tracks::{Face, TileGrid};

use crate::cull::{SlabDecision, ViewpointCull};
use crate::input::{Cell, SlabLayer, TileInfo};
use crate::oracle::MatchRule;
use crate::OcclusionError;

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
    let n = grid.face_size;
    let tol = params.content.depth_tolerance
        + params.content.per_pixel_angle * std::f64::consts::FRAC_PI_2 / n as f64;
    if !(tol.is_finite() && (0.0..0.5).contains(&tol)) {
        return Err(OcclusionError::Parameter {
            name: "content",
            message: format!("depth tolerance {tol} must be in [0, 0.5)"),
        });
    }
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
    let jobs: Vec<(usize, usize)> = layers
        .iter()
        .enumerate()
        .skip(1)
        .flat_map(|(k, l)| (0..l.tiles.len()).map(move |i| (k, i)))
        .collect();
    let results: Vec<(bool, ShrunkStats)> = jobs
        .par_iter()
        .map(|&(k, i)| ctx.decide(k, &layers[k].tiles[i]))
        .collect();
    let mut stats = ShrunkStats::default();
    let mut out: Vec<SlabDecision> = layers
        .iter()
        .enumerate()
        .map(|(k, l)| SlabDecision {
            slab: k,
            kept: if k == 0 { l.tiles.clone() } else { Vec::new() },
            culled: Vec::new(),
        })
        .collect();
    for (&(k, i), (keep, s)) in jobs.iter().zip(&results) {
        stats.add(s);
        let t = layers[k].tiles[i];
        if *keep {
            out[k].kept.push(t);
        } else {
            out[k].culled.push(t);
        }
    }
    Ok((ViewpointCull { slabs: out }, stats))
}

struct Ctx<'a> {
    v: DVec3,
    grid: &'a TileGrid,
    layers: &'a [SlabLayer],
    /// Base intervals of the cell, world coordinates.
    stretches: &'a [(DVec3, DVec3)],
    params: &'a ShrunkParams,
    solids: &'a dyn Solids,
    tol: f64,
}

/// The tile under test: its face, its opaque pixels' stored depths (NaN where transparent)
/// over the tile's pixel rectangle, and the footprint rectangle of what it holds (the tile
/// grown by the search radius, clamped to the face).
struct TileData {
    face: Face,
    slab: usize,
    tile: (u32, u32, u32, u32),
    depth: Vec<f64>,
    rect: (u32, u32, u32, u32),
}

impl TileData {
    fn depth_at(&self, x: u32, y: u32) -> f64 {
        let (x0, y0, x1, _) = self.tile;
        self.depth[((y - y0) * (x1 - x0) + (x - x0)) as usize]
    }
}

/// A piece of what a tile holds at one footprint pixel: a distance band (the union of the
/// overlapping bands that reach the pixel) and a stored point of a pixel it came from.
#[derive(Clone, Copy, Debug)]
struct Piece {
    s0: f64,
    s1: f64,
    sample: DVec3,
}

/// A group of what a tile holds: the box that holds all of it (frame `f, e1, e2` relative
/// to `V`, ranges per axis), a stored point to look at, and how it splits.
#[derive(Clone, Copy, Debug)]
struct Group {
    frame: [DVec3; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    sample: DVec3,
    split: Split,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Split {
    /// Several footprint pixels: quarter the rectangle.
    Quarters,
    /// One footprint pixel holding several bands: one group per band.
    Pieces,
    /// One band: halve it (a long band seen from aside is wide across the line of sight;
    /// its far part may also lie inside the solid whose surface it is on).
    Band,
    /// Not split further.
    No,
}

/// What a group holds: every footprint pixel of a rectangle (bounded coarsely: its
/// footprint times the union of the bands that reach it), or part `j` of `2^level` of the
/// band of piece `k` of footprint pixel `(x, y)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Key {
    Rect(u32, u32, u32, u32),
    Piece {
        x: u32,
        y: u32,
        k: u16,
        level: u8,
        j: u32,
    },
}

/// How many times a piece's band may be halved.
const BAND_LEVELS: u8 = 4;

/// A work item: an interval of a stretch (parameters `t0..t1`) and a group.
#[derive(Clone, Copy, Debug)]
struct Pair {
    stretch: u32,
    t0: f64,
    t1: f64,
    key: Key,
}

enum Outcome {
    Hidden,
    Seen,
    Undecided,
}

/// The band `[r/(1 + τ), r/(1 − τ)]` of a stored distance.
fn band(r: f64, tol: f64) -> (f64, f64) {
    (r / (1.0 + tol), r / (1.0 - tol))
}

impl Ctx<'_> {
    /// Keep (`true`) or cull one tile of slab `k`, with what it took.
    fn decide(&self, k: usize, tile: &TileInfo) -> (bool, ShrunkStats) {
        let mut stats = ShrunkStats {
            tiles: 1,
            ..ShrunkStats::default()
        };
        let id = tile.id;
        let layer = &self.layers[k];
        let n = self.grid.face_size;
        let rr = self.params.content.search_radius;
        let (x0, y0, x1, y1) = self.grid.pixel_rect(id);
        let mut depth = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
        let mut any = false;
        for y in y0..y1 {
            for x in x0..x1 {
                if *layer.alpha.get(id.face, x, y) < 128 {
                    depth.push(f64::NAN);
                    continue;
                }
                // Nothing of the earlier slabs in front: seen from V itself.
                if self.layers[..k]
                    .iter()
                    .all(|l| *l.alpha.get(id.face, x, y) < 128)
                {
                    stats.kept_direct = 1;
                    return (true, stats);
                }
                depth.push(*layer.depth.get(id.face, x, y) as f64);
                any = true;
            }
        }
        if !any {
            stats.culled = 1;
            return (false, stats);
        }
        let t = TileData {
            face: id.face,
            slab: k,
            tile: (x0, y0, x1, y1),
            depth,
            rect: (
                x0.saturating_sub(rr),
                y0.saturating_sub(rr),
                (x1 + rr).min(n),
                (y1 + rr).min(n),
            ),
        };
        match self.search(&t, &mut stats) {
            Outcome::Hidden => {
                stats.culled = 1;
                (false, stats)
            }
            Outcome::Seen => {
                stats.kept_seen = 1;
                (true, stats)
            }
            Outcome::Undecided => {
                stats.kept_undecided = 1;
                (true, stats)
            }
        }
    }

    /// The tile's pixels whose content can reach footprint rectangle `r`: those within the
    /// search radius of it.
    fn reaching(&self, t: &TileData, r: (u32, u32, u32, u32)) -> (u32, u32, u32, u32) {
        let rr = self.params.content.search_radius;
        let (tx0, ty0, tx1, ty1) = t.tile;
        (
            r.0.saturating_sub(rr).max(tx0),
            r.1.saturating_sub(rr).max(ty0),
            (r.2 + rr).min(tx1),
            (r.3 + rr).min(ty1),
        )
    }

    /// What the oracle could put in footprint pixel `(x, y)` and attribute to one of the
    /// tile's pixels: its own band at the pixel itself; at a neighbour, the part of the
    /// band in the slab's range that no layer at `(x, y)` holds itself (only then does
    /// the oracle search the neighbours). Overlapping bands merged, nearest first.
    fn pieces(&self, t: &TileData, x: u32, y: u32) -> Vec<Piece> {
        let n = self.grid.face_size;
        let layer = &self.layers[t.slab];
        let (qx0, qy0, qx1, qy1) = self.reaching(t, (x, y, x + 1, y + 1));
        let mut bands: Vec<Piece> = Vec::new();
        for qy in qy0..qy1 {
            for qx in qx0..qx1 {
                let r = t.depth_at(qx, qy);
                if r.is_nan() {
                    continue;
                }
                let sample = self.v + pixel_dir(t.face, qx, qy, n) * r;
                let (s0, s1) = band(r, self.tol);
                if (qx, qy) == (x, y) {
                    bands.push(Piece { s0, s1, sample });
                    continue;
                }
                let mut parts = [(0.0, 0.0); 8];
                parts[0] = (s0.max(layer.range.near), s1.min(layer.range.far));
                let mut count = usize::from(parts[0].1 > parts[0].0);
                for l in self.layers {
                    // A cut adds at most one part; with no room left, keep the parts whole.
                    if count < parts.len() && *l.alpha.get(t.face, x, y) >= 128 {
                        let cut = band(*l.depth.get(t.face, x, y) as f64, self.tol);
                        count = subtract(&mut parts, count, cut);
                    }
                }
                bands.extend(
                    parts[..count]
                        .iter()
                        .map(|&(s0, s1)| Piece { s0, s1, sample }),
                );
            }
        }
        bands.sort_by(|a, b| a.s0.total_cmp(&b.s0).then(a.s1.total_cmp(&b.s1)));
        let mut out: Vec<Piece> = Vec::with_capacity(bands.len());
        for b in bands {
            match out.last_mut() {
                Some(c) if b.s0 <= c.s1 => c.s1 = c.s1.max(b.s1),
                _ => out.push(b),
            }
        }
        out
    }

    /// The box of a group, in a frame along its mean direction.
    fn group(
        &self,
        t: &TileData,
        key: Key,
        pieces: &mut HashMap<(u32, u32), Vec<Piece>>,
    ) -> Option<Group> {
        let n = self.grid.face_size;
        let face = t.face;
        let (rect, s0, s1, sample, split) = match key {
            Key::Rect(x0, y0, x1, y1) if x1 - x0 > 1 || y1 - y0 > 1 => {
                // Every band that reaches the rectangle, and the stored point nearest its
                // centre.
                let (qx0, qy0, qx1, qy1) = self.reaching(t, (x0, y0, x1, y1));
                let (cx, cy) = (0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64);
                let (mut s0, mut s1) = (f64::INFINITY, f64::NEG_INFINITY);
                let mut nearest: Option<(f64, u32, u32, f64)> = None;
                for qy in qy0..qy1 {
                    for qx in qx0..qx1 {
                        let r = t.depth_at(qx, qy);
                        if r.is_nan() {
                            continue;
                        }
                        let (a, b) = band(r, self.tol);
                        (s0, s1) = (s0.min(a), s1.max(b));
                        let dd = (qx as f64 + 0.5 - cx).powi(2) + (qy as f64 + 0.5 - cy).powi(2);
                        if nearest.is_none_or(|p| dd < p.0) {
                            nearest = Some((dd, qx, qy, r));
                        }
                    }
                }
                let (_, qx, qy, r) = nearest?;
                let sample = self.v + pixel_dir(face, qx, qy, n) * r;
                ((x0, y0, x1, y1), s0, s1, sample, Split::Quarters)
            }
            Key::Rect(x, y, ..) => {
                let ps = pieces.entry((x, y)).or_insert_with(|| self.pieces(t, x, y));
                match ps.as_slice() {
                    [] => return None,
                    [p] => ((x, y, x + 1, y + 1), p.s0, p.s1, p.sample, Split::Band),
                    [first, .., last] => (
                        (x, y, x + 1, y + 1),
                        first.s0,
                        last.s1,
                        first.sample,
                        Split::Pieces,
                    ),
                }
            }
            Key::Piece { x, y, k, level, j } => {
                let ps = pieces.entry((x, y)).or_insert_with(|| self.pieces(t, x, y));
                let p = *ps.get(k as usize)?;
                let step = (p.s1 - p.s0) / (1u32 << level) as f64;
                let s0 = p.s0 + step * j as f64;
                let s1 = if j + 1 == 1 << level { p.s1 } else { s0 + step };
                let split = if level < BAND_LEVELS && s1 - s0 > 1e-3 * s1 {
                    Split::Band
                } else {
                    Split::No
                };
                ((x, y, x + 1, y + 1), s0, s1, p.sample, split)
            }
        };
        let (x0, y0, x1, y1) = rect;
        let f = subpixel_dir(face, 0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64, n);
        let e1 = (face.right() - f * face.right().dot(f)).normalize();
        let e2 = f.cross(e1);
        let (fx0, fy0, fx1, fy1) = (x0 as f64, y0 as f64, x1 as f64, y1 as f64);
        let corners = [
            subpixel_dir(face, fx0, fy0, n),
            subpixel_dir(face, fx1, fy0, n),
            subpixel_dir(face, fx1, fy1, n),
            subpixel_dir(face, fx0, fy1, n),
        ];
        // Every direction of the footprint is a normalised convex combination of the
        // corners, whose length before normalising is at least the cosine of the widest
        // angle between two corners (its dot product with any corner is).
        let wide = corners[0]
            .dot(corners[2])
            .min(corners[1].dot(corners[3]))
            .max(1e-3);
        // Along f: at least s0 · (smallest cosine, at a corner); at most s1.
        let min_cos = corners
            .iter()
            .map(|c| c.dot(f))
            .fold(f64::INFINITY, f64::min);
        let mut lo = [
            if min_cos >= 0.0 {
                s0 * min_cos
            } else {
                s1 * min_cos
            },
            0.0,
            0.0,
        ];
        let mut hi = [s1, 0.0, 0.0];
        // Across: corner values, grown for the footprint's bulge between corners.
        for (axis, e) in [(1, e1), (2, e2)] {
            let (mut m, mut mm) = (f64::INFINITY, f64::NEG_INFINITY);
            for c in &corners {
                let w = c.dot(e);
                m = m.min(w);
                mm = mm.max(w);
            }
            hi[axis] = if mm >= 0.0 { s1 * mm / wide } else { s0 * mm };
            lo[axis] = if m <= 0.0 { s1 * m / wide } else { s0 * m };
        }
        Some(Group {
            frame: [f, e1, e2],
            lo,
            hi,
            sample,
            split,
        })
    }

    /// The groups a group splits into.
    fn children(
        &self,
        key: Key,
        split: Split,
        pieces: &HashMap<(u32, u32), Vec<Piece>>,
    ) -> Vec<Key> {
        match (key, split) {
            (Key::Rect(x0, y0, x1, y1), Split::Quarters) => quarters((x0, y0, x1, y1))
                .into_iter()
                .map(|(a, b, c, d)| Key::Rect(a, b, c, d))
                .collect(),
            (Key::Rect(x, y, ..), Split::Pieces) => (0..pieces.get(&(x, y)).map_or(0, Vec::len))
                .map(|k| Key::Piece {
                    x,
                    y,
                    k: k as u16,
                    level: 0,
                    j: 0,
                })
                .collect(),
            (Key::Rect(x, y, ..), Split::Band) => (0..2)
                .map(|j| Key::Piece {
                    x,
                    y,
                    k: 0,
                    level: 1,
                    j,
                })
                .collect(),
            (Key::Piece { x, y, k, level, j }, Split::Band) => (0..2)
                .map(|h| Key::Piece {
                    x,
                    y,
                    k,
                    level: level + 1,
                    j: 2 * j + h,
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Refine (interval, group) pairs until all are hidden, a stored point is seen, or no
    /// more can be learnt.
    fn search(&self, t: &TileData, stats: &mut ShrunkStats) -> Outcome {
        let mut groups: HashMap<Key, Option<Group>> = HashMap::new();
        let mut pieces: HashMap<(u32, u32), Vec<Piece>> = HashMap::new();
        let (rx0, ry0, rx1, ry1) = t.rect;
        let root = Key::Rect(rx0, ry0, rx1, ry1);
        let mut stack: Vec<Pair> = (0..self.stretches.len() as u32)
            .rev()
            .map(|s| Pair {
                stretch: s,
                t0: 0.0,
                t1: 1.0,
                key: root,
            })
            .collect();
        let mut tests = 0u32;
        while let Some(pair) = stack.pop() {
            if tests >= self.params.max_tests_per_tile {
                return Outcome::Undecided;
            }
            let g = match groups.get(&pair.key) {
                Some(g) => *g,
                None => {
                    let g = self.group(t, pair.key, &mut pieces);
                    groups.insert(pair.key, g);
                    g
                }
            };
            let Some(g) = g else { continue };
            let (a, b) = self.stretches[pair.stretch as usize];
            let (xa, xb) = (a.lerp(b, pair.t0), a.lerp(b, pair.t1));
            let x = 0.5 * (xa + xb);
            let eps = 0.5 * xa.distance(xb);
            let aim = target(&g, self.v, x, eps);
            if let Some((pc, delta, _)) = aim {
                tests += 1;
                stats.block_tests += 1;
                let margin = 1e-6 + 1e-9 * (x.abs().max_element() + pc.distance(x));
                if self
                    .solids
                    .blocks(x, pc, eps + margin, delta + margin, (xa, xb))
                {
                    continue;
                }
            }
            // Not shown hidden: is the group's stored point simply seen?
            tests += 1;
            stats.see_tests += 1;
            if self.solids.sees(x, g.sample) {
                return Outcome::Seen;
            }
            // Refine the larger term of the shrink distance; a single piece whose own
            // extent dominates gains nothing from smaller intervals.
            let w_max = aim.map_or(f64::INFINITY, |a| a.2);
            let can_split = g.split != Split::No;
            let can_halve = 2.0 * eps > self.params.min_interval_m
                && (can_split || aim.is_none() || eps > 0.125 * w_max);
            if can_halve && (!can_split || aim.is_none() || eps >= w_max) {
                let tm = 0.5 * (pair.t0 + pair.t1);
                stack.push(Pair { t0: tm, ..pair });
                stack.push(Pair { t1: tm, ..pair });
            } else if can_split {
                for key in self.children(pair.key, g.split, &pieces).into_iter().rev() {
                    stack.push(Pair { key, ..pair });
                }
            } else {
                return Outcome::Undecided;
            }
        }
        Outcome::Hidden
    }
}

/// The point `P_c` to aim at from `x` (interval radius `eps`) for a group's box, the
/// shrink distance `δ` at it and the box's extent across the line of sight (`w_max`);
/// `None` when `x` is not in front of the box.
fn target(g: &Group, v: DVec3, x: DVec3, eps: f64) -> Option<(DVec3, f64, f64)> {
    let [f, e1, e2] = g.frame;
    let mid = [
        0.5 * (g.lo[0] + g.hi[0]),
        0.5 * (g.lo[1] + g.hi[1]),
        0.5 * (g.lo[2] + g.hi[2]),
    ];
    let half = [
        0.5 * (g.hi[0] - g.lo[0]),
        0.5 * (g.hi[1] - g.lo[1]),
        0.5 * (g.hi[2] - g.lo[2]),
    ];
    if half.iter().any(|h| !(h.is_finite() && *h >= 0.0)) {
        return None;
    }
    let c = v + f * mid[0] + e1 * mid[1] + e2 * mid[2];
    let to_c = c - x;
    let dist = to_c.length();
    if !(dist > 0.0 && dist.is_finite()) {
        return None;
    }
    let u = to_c / dist;
    let uf = [u.dot(f) * half[0], u.dot(e1) * half[1], u.dot(e2) * half[2]];
    let reach = uf[0].abs() + uf[1].abs() + uf[2].abs();
    let l = dist - reach;
    if l.is_nan() || l <= 0.0 {
        return None;
    }
    // Across the line of sight: the corner with the smallest |corner · u| is the widest.
    let h2 = half[0] * half[0] + half[1] * half[1] + half[2] * half[2];
    let min_along = [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
        .iter()
        .map(|(s1, s2)| (uf[0] + s1 * uf[1] + s2 * uf[2]).abs())
        .fold(f64::INFINITY, f64::min);
    let w_max = (h2 - min_along * min_along).max(0.0).sqrt();
    let span = 2.0 * reach;
    let delta = eps * span / (l + span) + w_max;
    Some((c - u * reach, delta, w_max))
}

/// Remove `cut` from the first `count` intervals of `parts` (closed intervals; ends kept,
/// so the parts cover a little more, never less); returns the new count. At most one
/// interval splits per cut, so eight places hold the cuts of seven layers.
fn subtract(parts: &mut [(f64, f64); 8], count: usize, cut: (f64, f64)) -> usize {
    let mut out = [(0.0, 0.0); 8];
    let mut m = 0;
    for &(a, b) in &parts[..count] {
        let mut push = |p: (f64, f64)| {
            if m < out.len() {
                out[m] = p;
                m += 1;
            }
        };
        if cut.1 < a || cut.0 > b {
            push((a, b));
            continue;
        }
        if cut.0 > a {
            push((a, cut.0));
        }
        if cut.1 < b {
            push((cut.1, b));
        }
    }
    *parts = out;
    m
}

/// The non-empty quarters (or halves, for a one-pixel-wide rectangle) of a rectangle.
fn quarters((x0, y0, x1, y1): (u32, u32, u32, u32)) -> Vec<(u32, u32, u32, u32)> {
    let (mx, my) = ((x0 + x1).div_ceil(2), (y0 + y1).div_ceil(2));
    let xs: &[(u32, u32)] = if x1 - x0 >= 2 {
        &[(x0, mx), (mx, x1)]
    } else {
        &[(x0, x1)]
    };
    let ys: &[(u32, u32)] = if y1 - y0 >= 2 {
        &[(y0, my), (my, y1)]
    } else {
        &[(y0, y1)]
    };
    ys.iter()
        .flat_map(|&(ya, yb)| xs.iter().map(move |&(xa, xb)| (xa, ya, xb, yb)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subtracting_bands() {
        let start = || {
            let mut p = [(0.0, 0.0); 8];
            p[0] = (1.0, 5.0);
            p[1] = (7.0, 9.0);
            p
        };
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (2.0, 3.0)), 3);
        assert_eq!(p[..3], [(1.0, 2.0), (3.0, 5.0), (7.0, 9.0)]);
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (0.0, 8.0)), 1);
        assert_eq!(p[0], (8.0, 9.0));
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (5.5, 6.5)), 2);
        assert_eq!(p[..2], [(1.0, 5.0), (7.0, 9.0)]);
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (0.0, 10.0)), 0);
    }

    #[test]
    fn quarters_cover_the_rectangle_once() {
        for r in [(0, 0, 8, 8), (3, 5, 4, 9), (2, 2, 7, 3), (0, 0, 1, 1)] {
            let q = quarters(r);
            let area: u32 = q.iter().map(|&(a, b, c, d)| (c - a) * (d - b)).sum();
            assert_eq!(area, (r.2 - r.0) * (r.3 - r.1), "{r:?} {q:?}");
        }
    }

    /// The lemma's target: every corner of the box lies at `P_c + α·u + w` with `α ≥ 0`
    /// and `|w| ≤ w_max`, and `P_c` is on the line from `x` through the box centre.
    #[test]
    fn target_covers_every_corner_of_the_box() {
        let f = DVec3::new(0.3, 0.2, 1.0).normalize();
        let e1 = DVec3::X.cross(f).normalize();
        let e2 = f.cross(e1);
        let g = Group {
            frame: [f, e1, e2],
            lo: [9.0, -0.4, -0.2],
            hi: [12.5, 0.3, 0.5],
            sample: DVec3::ZERO,
            split: Split::Quarters,
        };
        let v = DVec3::new(1.0, 2.0, 3.0);
        for x in [
            v,
            v + DVec3::new(2.0, 0.0, -1.0),
            v + DVec3::new(-3.0, 0.5, 2.0),
        ] {
            let (pc, delta, w_max) = target(&g, v, x, 0.25).unwrap();
            let u = (pc - x).normalize();
            assert!(delta >= w_max);
            for i in 0..8 {
                let a = if i & 1 == 0 { g.lo[0] } else { g.hi[0] };
                let b = if i & 2 == 0 { g.lo[1] } else { g.hi[1] };
                let c = if i & 4 == 0 { g.lo[2] } else { g.hi[2] };
                let corner = v + f * a + e1 * b + e2 * c;
                let rel = corner - pc;
                let along = rel.dot(u);
                let across = (rel - u * along).length();
                assert!(along >= -1e-9, "{x} corner {i}: α = {along}");
                assert!(across <= w_max + 1e-9, "{x} corner {i}: {across} > {w_max}");
            }
        }
    }
}
