//! The culling pass of one reference viewpoint (the paper's §4 algorithm, on cube maps).
//!
//! # Why the conservative variant never drops a visible point
//!
//! Notation of the shared geometry note (`culling-and-slab-geometry.md`): reference viewpoint
//! `V` at the origin, cell points `X = V + b`, an occludee tile `T` of slab `k` with
//! directions `Ω_T` and radial depths `[r_min, r_max]`, occluders of the earlier slabs at
//! `d(ω) ≤ near_k`. Work in the frame of `T`'s face: planar depth `z` along its axis, image
//! coordinates `p = (u, v)` on the plane `z = 1` ([`crate::window`]), so a point at planar
//! depth `h` seen in direction `p` is `h·(p, 1)`; the occluders' planar depth is `z_o(p)`.
//!
//! Take an occludee point `P` (image `p_P ∈ Ω_T`, planar depth `h_P`) and a cell point `X`
//! (planar depth `b_z`). Follow the segment `X → P` by its planar depth `h`; its image `p(h)`
//! (where it is seen from `V`) moves monotonically along a line and `p(h_P) = p_P`. Let
//! `g(h) = h − z_o(p(h))`. If `p(h)` stays where the occluder map is opaque and continuous
//! for `h ∈ [h₀, h_P]`, with `g(h₀) ≤ 0` (the segment in front of the occluder there) and
//! `g(h_P) ≥ 0` (at `p_P` the occluder is nearer than `P`: `d(ω_P) ≤ near_k ≤ r_min`, same
//! direction, so also in planar depth), then `g` crosses zero: the segment meets the occluder
//! surface between `X` (`b_z < h₀`) and `P`, and `P` is hidden from `X`.
//!
//! The test makes this hold for every `X` and every opaque pixel of the tile at once:
//! - The cell's motion is cut into straight pieces ([`Cell::motion_pieces`]: each stretch of
//!   each path in `motion_steps` parts). For one piece and one plane `h₀`, the landing window
//!   `L` ([`crate::window::landing_window`]) bounds `p(h₀)` over every `X` of the piece and
//!   every occludee point (the crossing is monotone in `X` along the piece and in `h_P`, so
//!   the extremes bound it), and `L ∪ Ω` bounds the whole path `p(h)`, `h ∈ [h₀, h_P]`.
//! - `g(h₀) ≤ 0`: `h₀ ≤` a lower bound of `z_o` over `L` (block minima of radial occluder
//!   depth times the smallest cosine, [`WindowQuery::min_planar_depth`]); `h₀ ≤` the
//!   occludee's smallest planar depth, so `p(h)` is defined on `[h₀, h_P]`; every end of the
//!   piece in front of `h₀` (else no conclusion). `h₀` starts at the nearest occluder in front
//!   of the tile and moves towards the viewer, each time to the nearest occluder where the
//!   last plane's rays landed, until the condition holds (or gives up: keep).
//! - Opaque and continuous: every pixel of `L ∪ Ω` opaque after hole punching
//!   ([`crate::maps::HolePunch`]: the nearer pixel of every depth jump is a hole, so a ray
//!   cannot slip between a near and a far occluder), at α = 1.
//! - `Ω` is the bounding box of the layer's opaque pixels in the tile (pixels with nothing in
//!   this slab need not be hidden), grown by half a pixel: opacity is sampled at pixel
//!   centres, so a silhouette may end up to half a pixel inside an opaque pixel. When the
//!   tile's box fails, its pixels are split into quadrants (`subdivisions` times), each with
//!   its own box and depth range; all parts must pass.
//!
//! Using each piece's own landing occluders, instead of the nearest occluder anywhere in the
//! window of the whole cell, is what makes this tighter than bounding every occluder by
//! `d_lo`; the pieces near `V` land close to the tile. What the argument assumes: the
//! occluders between pixel centres are as the sampled map says (depth continuous where no
//! hole was punched); the oracle checks that on the test scenes.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::{Face, TileGrid};

use crate::input::{Cell, SlabLayer, TileInfo};
use crate::maps::{DiscontinuityRule, HolePunch, OcclusionMap, WindowQuery};
use crate::window::{
    extended_window, face_pieces, landing_window, offset_in_face, PixelRect, UvRect,
};
use crate::OcclusionError;

/// Which depths the extended projections use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// Per piece of the cell's motion, the occluders where its rays land (see the module
    /// doc), depth discontinuities of the occluders treated as holes, the tile's opaque
    /// pixels only. Zero false culls at α = 1 for surfaces the occlusion map resolves.
    Conservative,
    /// The paper's simplification: every occluder at the slab boundary, the occludee flat at
    /// its farthest depth (Figure 4c), opacity taken as is.
    Paper,
    /// Occluder shrinking along the segment against the scene's exact solids, refined where
    /// visibility changes ([`crate::shrunk`]): conservative for every point of the cell,
    /// including openings and occluders finer than a pixel. Needs the scene's geometry
    /// ([`crate::shrunk::cull_viewpoint_shrunk`]); α does not apply (always 1).
    Shrunk,
    /// Image-space occluder shrinking in depth renders from balls covering the cell
    /// ([`crate::rendered`]): for scenes whose solids are not at hand (POV-Ray imports).
    /// Needs the renders ([`crate::rendered::cull_from_segments`]); α does not apply.
    Rendered,
}

impl Variant {
    pub fn name(self) -> &'static str {
        match self {
            Variant::Conservative => "conservative",
            Variant::Paper => "paper",
            Variant::Shrunk => "shrunk",
            Variant::Rendered => "rendered",
        }
    }

    /// Every variant, in the order reports show them.
    pub const ALL: [Variant; 4] = [
        Variant::Shrunk,
        Variant::Rendered,
        Variant::Conservative,
        Variant::Paper,
    ];

    /// Whether α applies (the window-opacity variants); the others run at α = 1.
    pub fn takes_alpha(self) -> bool {
        matches!(self, Variant::Conservative | Variant::Paper)
    }

    /// Parse `shrunk`, `rendered`, `conservative` or `paper`.
    pub fn parse(s: &str) -> Option<Variant> {
        match s.trim() {
            "conservative" => Some(Variant::Conservative),
            "paper" => Some(Variant::Paper),
            "shrunk" => Some(Variant::Shrunk),
            "rendered" => Some(Variant::Rendered),
            _ => None,
        }
    }
}

/// Parameters of one culling run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CullParams {
    /// Opacity threshold: a tile is culled when the mean opacity over its window is ≥ α
    /// (1 = fully opaque; the paper's α-acceleration uses 0.9 and 0.8).
    pub alpha: f64,
    pub variant: Variant,
    /// Conservative variant: which occluder depth jumps are gaps.
    pub discontinuity: DiscontinuityRule,
    /// Conservative variant: rounds of "landing window → nearest occluder in it → landing
    /// window" before giving up and keeping the tile.
    pub max_iterations: u32,
    /// Conservative variant: each straight stretch of the cell's paths is cut into this many
    /// pieces, each tested with the occluders where its own rays land (more pieces: tighter
    /// windows, more work).
    pub motion_steps: u32,
    /// Conservative variant: when a tile's opaque pixels are not shown hidden as one block,
    /// split them into quadrants this many times (each part is tested with its own pixels'
    /// bounding box and depth range; all must be hidden).
    pub subdivisions: u32,
    /// Shrunk variant: sampling and refinement.
    pub shrunk: crate::shrunk::ShrunkParams,
    /// Rendered variant: depth renders per segment and what a pixel holds.
    pub rendered: crate::rendered::RenderedParams,
}

impl CullParams {
    /// Checked constructor: `alpha` must be in `(0, 1]`.
    pub fn new(alpha: f64, variant: Variant) -> Result<CullParams, OcclusionError> {
        if !(alpha > 0.0 && alpha <= 1.0) {
            return Err(OcclusionError::Parameter {
                name: "alpha",
                message: format!("must be in (0, 1], found {alpha}"),
            });
        }
        Ok(CullParams {
            alpha,
            variant,
            discontinuity: DiscontinuityRule::default(),
            max_iterations: 8,
            motion_steps: 4,
            subdivisions: 2,
            shrunk: crate::shrunk::ShrunkParams::default(),
            rendered: crate::rendered::RenderedParams::default(),
        })
    }
}

/// The decision for one slab of one viewpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabDecision {
    pub slab: usize,
    pub kept: Vec<TileInfo>,
    pub culled: Vec<TileInfo>,
}

impl SlabDecision {
    pub fn tiles_before(&self) -> usize {
        self.kept.len() + self.culled.len()
    }
    pub fn bytes_before(&self) -> u64 {
        self.bytes_after() + self.culled.iter().map(|t| t.bytes).sum::<u64>()
    }
    pub fn bytes_after(&self) -> u64 {
        self.kept.iter().map(|t| t.bytes).sum()
    }
}

/// The decisions for every slab of one viewpoint, nearest slab first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewpointCull {
    pub slabs: Vec<SlabDecision>,
}

/// Cull the tiles of one reference viewpoint's slab layers (`layers`, nearest first) for the
/// motion in `cell`. Slabs are processed front to back; each tile is tested against the
/// occlusion map of the tiles kept in earlier slabs, and the kept tiles of a slab join the map
/// once the whole slab is done.
///
/// The per-pixel buffers (about 19 bytes per cube-map pixel: 115 MB at 6 × 1024²) stay with
/// the calling thread for its next call; the decisions do not depend on them.
pub fn cull_viewpoint(
    cell: &Cell,
    grid: &TileGrid,
    layers: &[SlabLayer],
    params: &CullParams,
) -> Result<ViewpointCull, OcclusionError> {
    check_inputs(cell, grid, layers)?;
    if !params.variant.takes_alpha() {
        return Err(OcclusionError::Parameter {
            name: "variant",
            message: format!(
                "the {} variant needs the scene's solids or depth renders \
                 (cull_viewpoint_shrunk, cull_viewpoint_rendered)",
                params.variant.name()
            ),
        });
    }
    let n = grid.face_size;
    let offsets = cell.offsets();
    let offsets_face: Vec<Vec<_>> = Face::ALL
        .iter()
        .map(|&f| offsets.iter().map(|&b| offset_in_face(f, b)).collect())
        .collect();
    let radius = cell.radius();
    let motion: Vec<Vec<(glam::DVec3, glam::DVec3)>> = Face::ALL
        .iter()
        .map(|&f| {
            cell.motion_pieces(params.motion_steps)
                .iter()
                .rev()
                .map(|&(a, b)| (offset_in_face(f, a), offset_in_face(f, b)))
                .collect()
        })
        .collect();
    // The large per-pixel buffers come from this thread's scratch (see [`Scratch`]).
    let mut scratch = SCRATCH.with(|c| c.take()).unwrap_or_default();
    let Scratch {
        map,
        punch: punch_buf,
        query: query_buf,
    } = &mut *scratch;
    map.reset(n);
    let mut any_occluder = false;
    // Conservative variant: whether `punch_buf` holds this viewpoint's punched opacity, and
    // the tile rectangles that joined the map since it was last brought up to date.
    let mut punched = false;
    let mut joined = Vec::new();
    let mut out = Vec::with_capacity(layers.len());
    for (k, layer) in layers.iter().enumerate() {
        let keep: Vec<bool> = if !any_occluder || layer.tiles.is_empty() {
            vec![true; layer.tiles.len()]
        } else {
            let q = match params.variant {
                Variant::Conservative | Variant::Shrunk | Variant::Rendered => {
                    match punch_buf {
                        Some(p) if punched => p.update(map, &joined),
                        Some(p) => p.rebuild(map, params.discontinuity, radius),
                        None => {
                            *punch_buf = Some(HolePunch::new(map, params.discontinuity, radius))
                        }
                    }
                    punched = true;
                    joined.clear();
                    let opacity = punch_buf.as_ref().map_or(&map.opaque, |p| &p.opacity);
                    match query_buf {
                        Some(q) => {
                            q.rebuild(opacity, &map.opaque, &map.depth);
                            &*q
                        }
                        None => {
                            query_buf.insert(WindowQuery::new(opacity, &map.opaque, &map.depth))
                        }
                    }
                }
                Variant::Paper => match query_buf {
                    Some(q) => {
                        q.rebuild_opacity_only(&map.opaque);
                        &*q
                    }
                    None => query_buf.insert(WindowQuery::opacity_only(&map.opaque)),
                },
            };
            let ctx = TileCtx {
                grid,
                q,
                offsets_face: &offsets_face,
                motion: &motion,
                params,
                near: layer.range.near,
                layer,
            };
            layer
                .tiles
                .par_iter()
                .map(|t| match params.variant {
                    Variant::Conservative | Variant::Shrunk | Variant::Rendered => {
                        ctx.keep_conservative(t)
                    }
                    Variant::Paper => ctx.keep_paper(t),
                })
                .collect()
        };
        let mut d = SlabDecision {
            slab: k,
            kept: Vec::new(),
            culled: Vec::new(),
        };
        let first_new = joined.len();
        for (t, kept) in layer.tiles.iter().zip(keep) {
            if kept {
                let r = grid.pixel_rect(t.id);
                joined.push((r.face, (r.x0, r.y0, r.x1, r.y1)));
                any_occluder = true;
                d.kept.push(*t);
            } else {
                d.culled.push(*t);
            }
        }
        // The last slab's kept tiles occlude nothing further: the map is not needed.
        if k + 1 < layers.len() {
            map.add_rects(&joined[first_new..], &layer.alpha, &layer.depth);
        }
        out.push(d);
    }
    SCRATCH.with(|c| c.set(Some(scratch)));
    Ok(ViewpointCull { slabs: out })
}

/// The per-pixel buffers of one culling pass (about 115 MB at 6 × 1024²), kept per thread
/// and reused by the next [`cull_viewpoint`] on the same thread (each rayon worker, or the
/// caller's thread, holds one): allocating them afresh for every viewpoint cost more than
/// filling them. Nothing in them carries over between viewpoints: the map is reset, the
/// punched opacity rebuilt and the query rebuilt before use.
#[derive(Default)]
struct Scratch {
    map: OcclusionMap,
    punch: Option<HolePunch>,
    query: Option<WindowQuery>,
}

thread_local! {
    static SCRATCH: std::cell::Cell<Option<Box<Scratch>>> = const { std::cell::Cell::new(None) };
}

/// The oracle's depth tolerance at `face_size` (`depth_tolerance + per_pixel_angle` pixel
/// angles), checked to lie in `[0, 0.5)`.
pub(crate) fn content_tolerance(
    rule: &crate::oracle::MatchRule,
    face_size: u32,
) -> Result<f64, OcclusionError> {
    let tol = rule.depth_tolerance
        + rule.per_pixel_angle * std::f64::consts::FRAC_PI_2 / face_size as f64;
    if !(tol.is_finite() && (0.0..0.5).contains(&tol)) {
        return Err(OcclusionError::Parameter {
            name: "content",
            message: format!("depth tolerance {tol} must be in [0, 0.5)"),
        });
    }
    Ok(tol)
}

/// Every tile of the later slabs decided on its own, in parallel, by `keep` (whether to keep
/// it, and what it cost); the nearest slab kept whole. The result does not depend on thread
/// count or order. Returns the decisions and each later tile's cost, in slab and tile order.
pub(crate) fn decide_later_tiles<S: Send>(
    layers: &[SlabLayer],
    keep: impl Fn(usize, &TileInfo) -> (bool, S) + Sync,
) -> (ViewpointCull, Vec<S>) {
    use rayon::prelude::*;
    let jobs: Vec<(usize, usize)> = layers
        .iter()
        .enumerate()
        .skip(1)
        .flat_map(|(k, l)| (0..l.tiles.len()).map(move |i| (k, i)))
        .collect();
    let results: Vec<(bool, S)> = jobs
        .par_iter()
        .map(|&(k, i)| keep(k, &layers[k].tiles[i]))
        .collect();
    let mut out: Vec<SlabDecision> = layers
        .iter()
        .enumerate()
        .map(|(k, l)| SlabDecision {
            slab: k,
            kept: if k == 0 { l.tiles.clone() } else { Vec::new() },
            culled: Vec::new(),
        })
        .collect();
    let mut costs = Vec::with_capacity(jobs.len());
    for (&(k, i), (kept, cost)) in jobs.iter().zip(results) {
        let t = layers[k].tiles[i];
        if kept {
            out[k].kept.push(t);
        } else {
            out[k].culled.push(t);
        }
        costs.push(cost);
    }
    (ViewpointCull { slabs: out }, costs)
}

/// [`decide_later_tiles`] without threads, by slab and tile position: `keep(k, i)`.
pub(crate) fn decide_later_tiles_seq(
    layers: &[SlabLayer],
    keep: impl Fn(usize, usize) -> bool,
) -> (ViewpointCull, ()) {
    let slabs = layers
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let mut d = SlabDecision {
                slab: k,
                kept: Vec::new(),
                culled: Vec::new(),
            };
            for (i, t) in l.tiles.iter().enumerate() {
                if k == 0 || keep(k, i) {
                    d.kept.push(*t);
                } else {
                    d.culled.push(*t);
                }
            }
            d
        })
        .collect();
    (ViewpointCull { slabs }, ())
}

pub(crate) fn check_inputs(
    cell: &Cell,
    grid: &TileGrid,
    layers: &[SlabLayer],
) -> Result<(), OcclusionError> {
    if !cell.viewpoint.is_finite() || cell.paths.iter().flatten().any(|p| !p.is_finite()) {
        return Err(OcclusionError::Input {
            what: "culling input".into(),
            message: "cell positions must be finite".into(),
        });
    }
    check_layers(grid, layers)
}

/// The layers fit the grid, their slabs follow each other, their tiles' depth ranges are
/// numbers.
pub(crate) fn check_layers(grid: &TileGrid, layers: &[SlabLayer]) -> Result<(), OcclusionError> {
    let bad = |message: String| OcclusionError::Input {
        what: "culling input".into(),
        message,
    };
    for (k, l) in layers.iter().enumerate() {
        if l.alpha.face_size() != grid.face_size || l.depth.face_size() != grid.face_size {
            return Err(bad(format!(
                "slab {k}: maps are {}² / {}², tile grid is {}²",
                l.alpha.face_size(),
                l.depth.face_size(),
                grid.face_size
            )));
        }
        if k > 0 && l.range.near < layers[k - 1].range.far {
            return Err(bad(format!(
                "slab {k} ({}) starts before slab {} ends ({})",
                l.range.label(),
                k - 1,
                layers[k - 1].range.label()
            )));
        }
        if let Some(t) = l
            .tiles
            .iter()
            .find(|t| t.depth_min.is_nan() || t.depth_max.is_nan() || t.depth_min > t.depth_max)
        {
            return Err(bad(format!(
                "slab {k}: tile {:?} has depth range [{}, {}]",
                t.id, t.depth_min, t.depth_max
            )));
        }
    }
    Ok(())
}

struct TileCtx<'a> {
    grid: &'a TileGrid,
    q: &'a WindowQuery,
    offsets_face: &'a [Vec<glam::DVec3>],
    /// Per face, the cell's motion pieces in that face's frame, farthest first.
    motion: &'a [Vec<(glam::DVec3, glam::DVec3)>],
    params: &'a CullParams,
    near: f64,
    /// The layer whose tiles are tested (its opaque pixels are what must be hidden).
    layer: &'a SlabLayer,
}

impl TileCtx<'_> {
    fn pieces(&self, face: Face, w: UvRect) -> Vec<PixelRect> {
        face_pieces(face, w, self.grid.face_size)
    }

    fn min_planar(&self, pieces: &[PixelRect], along: Face) -> f64 {
        pieces
            .iter()
            .map(|p| self.q.min_planar_depth(p, along))
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether the mean opacity over the window reaches α.
    fn occluded(&self, pieces: &[PixelRect]) -> bool {
        let area: u64 = pieces.iter().map(|p| p.area()).sum();
        let opaque: u64 = pieces.iter().map(|p| self.q.opaque_count(p)).sum();
        if area == 0 {
            return false;
        }
        if self.params.alpha >= 1.0 {
            opaque == area
        } else {
            opaque as f64 >= self.params.alpha * area as f64
        }
    }

    /// Keep unless the tile's opaque pixels are hidden from every point of the cell: as one
    /// block, or else quadrant by quadrant (see the module doc).
    fn keep_conservative(&self, t: &TileInfo) -> bool {
        let tracks::PixelRect { x0, y0, x1, y1, .. } = self.grid.pixel_rect(t.id);
        !self.block_hidden(t.id.face, (x0, y0, x1, y1), self.params.subdivisions)
    }

    /// Whether the opaque pixels of the layer inside pixel rectangle `r` of `face` are hidden
    /// from the whole cell (`levels`: quadrant splits still allowed).
    fn block_hidden(&self, face: Face, r: (u32, u32, u32, u32), levels: u32) -> bool {
        let (x0, y0, x1, y1) = r;
        let n = self.grid.face_size as usize;
        let (alpha, depth) = (self.layer.alpha.face(face), self.layer.depth.face(face));
        // Bounding box and depth range of the opaque pixels.
        let (mut bx0, mut by0, mut bx1, mut by1) = (x1, y1, x0, y0);
        let (mut d_lo, mut d_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for y in y0..y1 {
            let row = y as usize * n;
            for x in x0..x1 {
                if alpha[row + x as usize] < 128 {
                    continue;
                }
                let d = depth[row + x as usize] as f64;
                if d.is_nan() {
                    return false;
                }
                (bx0, by0, bx1, by1) = (bx0.min(x), by0.min(y), bx1.max(x + 1), by1.max(y + 1));
                (d_lo, d_hi) = (d_lo.min(d), d_hi.max(d));
            }
        }
        if bx1 <= bx0 {
            return true;
        }
        let n32 = self.grid.face_size;
        let px = |x: u32| 2.0 * x as f64 / n32 as f64 - 1.0;
        let py = |y: u32| 1.0 - 2.0 * y as f64 / n32 as f64;
        // Grown by half a pixel on every side: opacity is sampled at pixel centres, so an
        // occluder's silhouette may end anywhere up to half a pixel inside an opaque pixel;
        // the grown rectangle reaches the neighbouring pixels in the opacity test.
        let dil = 1.0;
        let rect = UvRect {
            u0: px(bx0) - dil / n32 as f64,
            u1: px(bx1) + dil / n32 as f64,
            v0: py(by1) - dil / n32 as f64,
            v1: py(by0) + dil / n32 as f64,
        };
        // At α = 1 a rectangle that is not covered itself fails for every piece (each path
        // region contains it): go straight to its quadrants.
        let covered = self.params.alpha < 1.0 || self.occluded(&self.pieces(face, rect));
        if covered && self.rect_hidden(face, rect, d_lo, d_hi) {
            return true;
        }
        if levels == 0 || (bx1 - bx0 < 2 && by1 - by0 < 2) {
            return false;
        }
        let (mx, my) = ((bx0 + bx1).div_ceil(2), (by0 + by1).div_ceil(2));
        let xs: &[(u32, u32)] = if bx1 - bx0 >= 2 {
            &[(bx0, mx), (mx, bx1)]
        } else {
            &[(bx0, bx1)]
        };
        let ys: &[(u32, u32)] = if by1 - by0 >= 2 {
            &[(by0, my), (my, by1)]
        } else {
            &[(by0, by1)]
        };
        ys.iter().all(|&(ya, yb)| {
            xs.iter()
                .all(|&(xa, xb)| self.block_hidden(face, (xa, ya, xb, yb), levels - 1))
        })
    }

    /// Whether occludee points with directions in `rect` (on `face`) and radial depths in
    /// `[d_lo, d_hi]` are hidden from every piece of the cell's motion.
    fn rect_hidden(&self, face: Face, rect: UvRect, d_lo: f64, d_hi: f64) -> bool {
        // The occludee's planar depth range along `face`: radial depth times the cosine,
        // which over the rectangle is largest at its point nearest the face centre and
        // smallest at its farthest corner.
        let h_hi = if d_hi.is_finite() {
            d_hi / (1.0 + rect.min_norm2()).sqrt()
        } else {
            f64::INFINITY
        };
        let h_lo = d_lo / (1.0 + rect.max_norm2()).sqrt();
        // The first landing plane: the nearest occluder in front of the rectangle itself,
        // never behind the occludee.
        let h_start = self.min_planar(&self.pieces(face, rect), face).min(h_lo);
        self.motion[face.index()]
            .iter()
            .all(|&piece| self.piece_occluded(face, rect, piece, h_start, h_lo, h_hi))
    }

    /// Whether every ray from the motion piece `piece` to the tile crosses the occluders:
    /// some plane `h` where the rays land (window `L`) in front of every occluder there
    /// (`h ≤` nearest occluder planar depth over `L`), with the rectangle spanned by `L` and
    /// the tile fully opaque (at α = 1) after hole punching. Planes are tried from the tile's
    /// own nearest occluder towards the viewer, each next one the nearest occluder where the
    /// last one's rays landed.
    fn piece_occluded(
        &self,
        face: Face,
        rect: UvRect,
        piece: (glam::DVec3, glam::DVec3),
        h_start: f64,
        h_lo: f64,
        h_hi: f64,
    ) -> bool {
        let mut h = h_start;
        for _ in 0..self.params.max_iterations {
            if !(h.is_finite() && h > 0.0) {
                return false;
            }
            let Some(land) = landing_window(rect, piece, h, h_lo, h_hi.max(h_lo)) else {
                return false;
            };
            if !land.is_finite() {
                return false;
            }
            let h_land = self.min_planar(&self.pieces(face, land), face);
            if h_land >= h {
                return self.occluded(&self.pieces(face, land.union(rect)));
            }
            h = h_land;
        }
        false
    }

    fn keep_paper(&self, t: &TileInfo) -> bool {
        let face = t.id.face;
        let rect = UvRect::of_tile(self.grid, t.id);
        let (cu, cv) = rect.centre();
        let f = 1.0 / (1.0 + cu * cu + cv * cv).sqrt();
        let h1 = self.near * f;
        let h2 = (t.depth_max * f).max(h1);
        match extended_window(rect, &self.offsets_face[face.index()], h1, h2) {
            Some(win) if win.is_finite() => !self.occluded(&self.pieces(face, win)),
            _ => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{render_layers, BoxScene};
    use glam::DVec3;
    use tracks::SlabRange;

    /// The per-thread buffers carry nothing from one viewpoint to the next: culling A, then B
    /// (other layers, other face size), then A again on one thread gives the same decisions
    /// as culling A on a fresh thread, for both variants.
    #[test]
    fn reused_buffers_give_the_decisions_of_fresh_ones() {
        let scene = BoxScene::courtyard(DVec3::ZERO);
        let ranges = SlabRange::parse_list("0-5,5-11,11-inf").expect("ranges");
        let track: Vec<DVec3> = (0..4)
            .map(|i| DVec3::new(0.5 * i as f64, 1.7, 0.0))
            .collect();
        let (ga, gb) = (
            TileGrid::new(32, 4).expect("grid"),
            TileGrid::new(16, 4).expect("grid"),
        );
        let la = render_layers(&scene, track[1], &ga, &ranges).expect("layers");
        let lb = render_layers(&scene, track[2], &gb, &ranges).expect("layers");
        for variant in [Variant::Conservative, Variant::Paper] {
            let p = CullParams::new(1.0, variant).expect("alpha");
            let (ca, cb) = (Cell::straight(&track, 1), Cell::straight(&track, 2));
            let fresh = std::thread::scope(|s| {
                s.spawn(|| cull_viewpoint(&ca, &ga, &la, &p).expect("cull"))
                    .join()
                    .expect("thread")
            });
            let first = cull_viewpoint(&ca, &ga, &la, &p).expect("cull");
            let other = cull_viewpoint(&cb, &gb, &lb, &p).expect("cull");
            let again = cull_viewpoint(&ca, &ga, &la, &p).expect("cull");
            assert_eq!(first, fresh, "{variant:?}");
            assert_eq!(again, fresh, "{variant:?}");
            assert!(fresh.slabs[1].culled.len() + fresh.slabs[2].culled.len() > 0);
            assert!(other.slabs.iter().map(|s| s.tiles_before()).sum::<usize>() > 0);
        }
    }
}
