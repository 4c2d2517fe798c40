//! The `rendered` variant: culling from depth renders along the track, for scenes whose
//! solids are not at hand (POV-Ray imports). Each segment of the track is covered by balls;
//! a depth cube map is rendered from every ball's centre (by POV-Ray, or by casting rays); a
//! tile is culled when every ball's render shows each of its pixels hidden from every point
//! of that ball, behind an occluder surface that no ray from the ball can get around.
//!
//! # What a tile holds
//!
//! As for the shrunk variant ([`crate::shrunk`]): the points the oracle could attribute to
//! its opaque pixels. For a pixel of stored radial depth `r` that is its footprint grown by
//! the oracle's search radius `R` pixels on every side, times the band `[r/(1 + τ), r/(1 −
//! τ)]` (`τ` from the [`MatchRule`]). Call that region `Π`.
//!
//! # Lemma (a continuous occluder surface seen from a ball's centre)
//!
//! Take a ball of radius `ε` around `C`, the depth cube map `D` rendered from `C` (first hit
//! along each direction, `+∞` for none), a point `P` with `|P − C| > D(dir(P − C))`, and a
//! point `X'` of the ball. Let `r₀ ≤ min D` over the cone of directions within `γ = β +
//! asin(ε/r₀)` of a direction `u`, where every point of `Π` lies within `β` of `u` seen from
//! `C`, and `r₀ > 2ε`. Then:
//! - Points `Y = X' + s(P − X')` of the segment have `Y − C = (1 − s)(X' − C) + s(P − C)`:
//!   their offset across the line `C → P` is at most `ε`, so where `|Y − C| ≥ r₀ > 2ε` their
//!   direction lies within `asin(ε/r₀)` of `dir(P − C)`, hence within `γ` of `u`. The points
//!   with `|Y − C| ≥ r₀` are the segment's final stretch (`|Y − C|` is convex along the
//!   segment and starts below `r₀`).
//! - On that stretch `f(Y) = |Y − C| − D(dir(Y − C))` starts at `f ≤ 0` (its first point is at
//!   distance `r₀ ≤ D`) and ends at `f(P) > 0`. If `D` is continuous over the cone, `f` is
//!   continuous there and vanishes at some `Y` strictly before `P`: `Y` is a surface point
//!   (the first hit from `C` in its direction), and the segment from `X'` meets it before
//!   reaching `P`. `P` is hidden from `X'`.
//!
//! So `P` is hidden from the whole ball when (1) every pixel of `D` over the `γ`-cone holds a
//! surface that is continuous with its neighbours — no depth discontinuity that opens, over
//! the ball, a gap a ray could slip through behind the nearer side (the conservative
//! variant's [`DiscontinuityRule`] with the ball's radius: the nearer pixel of each such
//! jump counts as a hole), and no sky; (2) every pixel over the `β`-cone is nearer than the
//! nearest point of `Π`; (3) `r₀` and `γ` are found by iterating "cone → nearest depth in
//! it → cone" until the nearest depth no longer drops. This is image-space occluder
//! shrinking: a surface counts only where it extends `asin(ε/r₀)` beyond the directions
//! of `P`, the angle over which the ball sees around its edge.
//!
//! A tile is culled only when every pixel of it passes for every ball; balls cover the cell
//! (each piece of a segment lies in the ball around its middle with half its length as
//! radius). Occluders fuse only where their renders join into one continuous surface: a
//! row of columns hides nothing by itself at any one ball, but each ball is small, so
//! what the row hides from every ball is still culled.
//!
//! # Where it holds and where it is only as good as the sampling
//!
//! The argument is exact for the surface `D` describes. `D` is known at pixel centres only:
//! between two neighbouring centres whose depths do not jump, the surface is taken to be
//! continuous. An opening narrower than a pixel of the render that falls between pixel
//! centres, or an occluder thinner than a pixel that the render misses or catches, is where
//! the result is only as good as the sampling — as for the oracle, which looks from depth
//! renders at the same face size. Depths are POV-Ray's decoded fog-trick distances, good to
//! about 2e-5 relative; the tests leave a 1e-4 relative margin.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::cubemap::subpixel_dir;
use tracks::{CubeMap, Face, FaceCoord, TileGrid};

use crate::cull::ViewpointCull;
use crate::input::{Cell, SlabLayer, TileInfo};
use crate::maps::{hole_punched, DiscontinuityRule, OcclusionMap};
use crate::oracle::MatchRule;
use crate::OcclusionError;

/// Largest cone (radians) a test looks over; wider ones keep the tile.
const MAX_CONE: f64 = 0.35;
/// Rounds of "cone → nearest depth → cone" before giving up.
const MAX_ROUNDS: u32 = 6;
/// Relative margin on the depths compared (decoded depths, f32 storage).
const DEPTH_MARGIN: f64 = 1e-4;

/// Every point within `radius` of `centre`: a piece of the cell.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ball {
    pub centre: DVec3,
    pub radius: f64,
}

/// Balls covering the polyline `path` (both ends included): `pieces` equal pieces by arc
/// length, each in the ball around its middle whose radius is half its arc length. A
/// single point is one ball of radius 0.
pub fn cover(path: &[DVec3], pieces: usize) -> Vec<Ball> {
    if path.len() < 2 || pieces == 0 {
        return path
            .first()
            .map(|&centre| Ball {
                centre,
                radius: 0.0,
            })
            .into_iter()
            .collect();
    }
    let arc = tracks::segment::arc_lengths(path);
    let len = *arc.last().unwrap_or(&0.0);
    let h = len / pieces as f64;
    (0..pieces)
        .map(|j| Ball {
            centre: tracks::segment::point_at(path, &arc, h * (j as f64 + 0.5)),
            // A point at arc distance h/2 is at most h/2 away; the margin covers rounding.
            radius: 0.5 * h * (1.0 + 1e-9) + 1e-12,
        })
        .collect()
}

/// The two balls covering the halves of piece `j` of [`cover`]`(path, pieces)`: where the
/// piece's own ball cannot be rendered (its centre inside a solid), its halves may be.
pub fn halves(path: &[DVec3], pieces: usize, j: usize) -> [Ball; 2] {
    let arc = tracks::segment::arc_lengths(path);
    let len = *arc.last().unwrap_or(&0.0);
    let h = len / pieces.max(1) as f64;
    [0.25, 0.75].map(|f| Ball {
        centre: tracks::segment::point_at(path, &arc, h * (j as f64 + f)),
        radius: 0.25 * h * (1.0 + 1e-9) + 1e-12,
    })
}

/// The balls covering `path` ([`cover`], `per_segment` of them) with their depth renders,
/// made by `render` from each ball's centre.
pub fn render_balls<E>(
    path: &[DVec3],
    params: &RenderedParams,
    mut render: impl FnMut(DVec3) -> Result<CubeMap<f32>, E>,
) -> Result<Vec<BallView>, E> {
    cover(path, params.per_segment)
        .into_iter()
        .map(|b| Ok(BallView::new(b, render(b.centre)?, params.discontinuity)))
        .collect()
}

/// Knobs of the rendered variant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderedParams {
    /// Balls (depth renders) per track segment.
    pub per_segment: usize,
    /// Which depth jumps of a render are gaps.
    pub discontinuity: DiscontinuityRule,
    /// What a pixel holds: the oracle's rule for attributing a seen point to a pixel.
    pub content: MatchRule,
}

impl Default for RenderedParams {
    fn default() -> Self {
        RenderedParams {
            per_segment: 32,
            discontinuity: DiscontinuityRule::default(),
            content: MatchRule::default(),
        }
    }
}

/// A depth render from a ball's centre, ready for tests: its depth and where it shows a
/// continuous surface.
#[derive(Clone, Debug)]
pub struct BallView {
    pub ball: Ball,
    depth: CubeMap<f32>,
    /// 1 where a surface is hit and no gap opens to a neighbour over the ball.
    solid: CubeMap<u8>,
}

impl BallView {
    /// The render `depth` (radial, from `ball.centre`, `+inf` for nothing) of `ball`.
    pub fn new(ball: Ball, depth: CubeMap<f32>, rule: DiscontinuityRule) -> BallView {
        let map = OcclusionMap {
            opaque: depth.map(|d| u8::from(d.is_finite() && *d > 0.0)),
            depth: depth.clone(),
        };
        let solid = hole_punched(&map, rule, ball.radius);
        BallView { ball, depth, solid }
    }

    pub fn face_size(&self) -> u32 {
        self.depth.face_size()
    }

    /// Whether every point of a region is hidden from every point of the ball (the lemma of
    /// the module docs). `corners`: points whose convex hull holds the region, up to
    /// `bulge` metres; `nearest`: a lower bound on the region's distance from the centre.
    fn hides(&self, corners: &[DVec3], bulge: f64, nearest: f64) -> bool {
        let (c, eps) = (self.ball.centre, self.ball.radius);
        if nearest.is_nan() || nearest <= 2.0 * eps {
            return false;
        }
        let mut sum = DVec3::ZERO;
        for q in corners {
            let l = (*q - c).length();
            if l.is_nan() || l <= 0.0 {
                return false;
            }
            sum += (*q - c) / l;
        }
        let u = sum.normalize_or_zero();
        if u == DVec3::ZERO {
            return false;
        }
        let beta = corners
            .iter()
            .map(|q| u.angle_between(*q - c))
            .fold(0.0, f64::max)
            + (bulge / nearest).min(1.0).asin();
        // (2) the directions of the region: every surface nearer than its nearest point.
        let Some((lo, hi)) = self.depth_range(u, beta, false) else {
            return false;
        };
        if hi * (1.0 + DEPTH_MARGIN) >= nearest {
            return false;
        }
        // (1) and (3): the grown cone continuous, its nearest depth stable.
        let mut r0 = lo;
        for _ in 0..MAX_ROUNDS {
            if r0.is_nan() || r0 <= 2.0 * eps {
                return false;
            }
            let gamma = beta + (eps / r0).asin();
            if gamma > MAX_CONE {
                return false;
            }
            let Some((m, _)) = self.depth_range(u, gamma, true) else {
                return false;
            };
            if m >= r0 {
                return true;
            }
            r0 = m * (1.0 - DEPTH_MARGIN);
        }
        false
    }

    /// Nearest and farthest depth over the pixels covering the cone of half-angle `angle`
    /// around `u`; `None` where one of them shows nothing (or, with `solid`, a gap).
    fn depth_range(&self, u: DVec3, angle: f64, solid: bool) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        let ok = cone_pixels(u, angle, self.face_size(), |face, x, y| {
            let d = *self.depth.get(face, x, y) as f64;
            if !d.is_finite() || (solid && *self.solid.get(face, x, y) == 0) {
                return false;
            }
            lo = lo.min(d);
            hi = hi.max(d);
            true
        });
        (ok && lo.is_finite()).then_some((lo, hi))
    }
}

/// Visit every pixel (of a cube map `n` pixels a side) that a direction within `angle` of
/// the unit `u` can fall in — a box per face, grown by a pixel — until `f` says stop;
/// whether it never did.
fn cone_pixels(u: DVec3, angle: f64, n: u32, mut f: impl FnMut(Face, u32, u32) -> bool) -> bool {
    let (e1, e2) = u.any_orthonormal_pair();
    let t = angle.tan();
    // Sample the cone's boundary; if it stays on one face the box of the samples (plus a
    // pixel for the boundary between samples) holds the cone. Else sample the inside on a
    // grid finer than the smallest pixel (0.94/n radians at a face's corner).
    let mut boxes: [Option<(i64, i64, i64, i64)>; 6] = [None; 6];
    let add = |boxes: &mut [Option<(i64, i64, i64, i64)>; 6], d: DVec3| {
        if let Some(fc) = FaceCoord::from_dir(d) {
            let (px, py) = fc.to_pixel_f(n);
            let (px, py) = (px.floor() as i64, py.floor() as i64);
            let b = &mut boxes[fc.face.index()];
            *b = Some(match *b {
                None => (px, py, px, py),
                Some((x0, y0, x1, y1)) => (x0.min(px), y0.min(py), x1.max(px), y1.max(py)),
            });
        }
    };
    const RING: usize = 24;
    for i in 0..RING {
        let phi = std::f64::consts::TAU * i as f64 / RING as f64;
        add(&mut boxes, u + t * (phi.cos() * e1 + phi.sin() * e2));
    }
    add(&mut boxes, u);
    if boxes.iter().filter(|b| b.is_some()).count() > 1 {
        let step = 0.9 / n as f64;
        let k = (t / step).ceil() as i64;
        for i in -k..=k {
            for j in -k..=k {
                let (a, b) = (i as f64 * step, j as f64 * step);
                if a * a + b * b <= (t + step) * (t + step) {
                    add(&mut boxes, u + a * e1 + b * e2);
                }
            }
        }
    }
    let last = n as i64 - 1;
    for face in Face::ALL {
        let Some((x0, y0, x1, y1)) = boxes[face.index()] else {
            continue;
        };
        for y in (y0 - 1).max(0)..=(y1 + 1).min(last) {
            for x in (x0 - 1).max(0)..=(x1 + 1).min(last) {
                if !f(face, x as u32, y as u32) {
                    return false;
                }
            }
        }
    }
    true
}

/// What happened to the tiles of one run, summed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RenderedStats {
    /// Later-slab tiles decided.
    pub tiles: u64,
    /// Culled: every pixel hidden from every ball.
    pub culled: u64,
    /// Depth renders looked at.
    pub renders: u64,
    /// (pixel, ball) tests made.
    pub tests: u64,
}

impl RenderedStats {
    pub fn add(&mut self, o: &RenderedStats) {
        self.tiles += o.tiles;
        self.culled += o.culled;
        self.renders += o.renders;
        self.tests += o.tests;
    }
}

/// Cull one reference viewpoint's layers (nearest first) against depth renders `views`
/// whose balls cover `cell`. The nearest slab is kept whole; every later tile is decided on
/// its own. With no views nothing is proven and everything is kept.
pub fn cull_viewpoint_rendered(
    cell: &Cell,
    grid: &TileGrid,
    layers: &[SlabLayer],
    views: &[&BallView],
    params: &RenderedParams,
) -> Result<(ViewpointCull, RenderedStats), OcclusionError> {
    crate::cull::check_inputs(cell, grid, layers)?;
    let tol = crate::cull::content_tolerance(&params.content, grid.face_size)?;
    let search = params.content.search_radius;
    let (cull, costs) = crate::cull::decide_later_tiles(layers, |k, tile| {
        let (hidden, tests) =
            hidden_tile(cell.viewpoint, grid, &layers[k], tile, views, tol, search);
        (!hidden, (hidden, tests))
    });
    let stats = RenderedStats {
        tiles: costs.len() as u64,
        culled: costs.iter().filter(|(hidden, _)| *hidden).count() as u64,
        renders: views.len() as u64,
        tests: costs.iter().map(|(_, t)| t).sum(),
    };
    Ok((cull, stats))
}

/// Whether every opaque pixel of `tile` is hidden from every ball; the tests made.
fn hidden_tile(
    v: DVec3,
    grid: &TileGrid,
    layer: &SlabLayer,
    tile: &TileInfo,
    views: &[&BallView],
    tol: f64,
    search: u32,
) -> (bool, u64) {
    if views.is_empty() {
        return (false, 0);
    }
    let n = grid.face_size;
    let rect = grid.pixel_rect(tile.id);
    let face = tile.id.face;
    let grow = search as f64;
    let mut tests = 0u64;
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            if *layer.alpha.get(face, x, y) < 128 {
                continue;
            }
            let r = *layer.depth.get(face, x, y) as f64;
            if !(r.is_finite() && r > 0.0) {
                return (false, tests);
            }
            let (r_lo, r_hi) = (r / (1.0 + tol), r / (1.0 - tol));
            let (x0, y0) = (x as f64 - grow, y as f64 - grow);
            let (x1, y1) = (x as f64 + 1.0 + grow, y as f64 + 1.0 + grow);
            let dirs = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                .map(|(px, py)| subpixel_dir(face, px, py, n).normalize());
            let d0 = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, n).normalize();
            // Half-angle of the cone from `V` that holds the grown footprint.
            let half = dirs
                .iter()
                .map(|d| d0.angle_between(*d))
                .fold(0.0, f64::max);
            let corners: Vec<DVec3> = dirs
                .iter()
                .flat_map(|d| [v + r_lo * *d, v + r_hi * *d])
                .collect();
            // The far face bulges past the corners' hull by at most this much.
            let bulge = r_hi * (1.0 - half.cos());
            for view in views {
                tests += 1;
                let nearest = nearest_distance(view.ball.centre - v, d0, half, r_lo, r_hi);
                if !view.hides(&corners, bulge, nearest) {
                    return (false, tests);
                }
            }
        }
    }
    (true, tests)
}

/// A lower bound on the distance from `V + b` to the points `V + s·d`, `s ∈ [r_lo, r_hi]`,
/// `d` within `half` of `d0`: with `s` free in that range and `d·b` at most `|b|·cos(max(0,
/// ∠(d0, b) − half))`, the distance is smallest at `s = clamp(d·b)`.
fn nearest_distance(b: DVec3, d0: DVec3, half: f64, r_lo: f64, r_hi: f64) -> f64 {
    let bl = b.length();
    if bl == 0.0 {
        return r_lo;
    }
    let a = (d0.angle_between(b) - half).max(0.0);
    let along = bl * a.cos();
    let s = along.clamp(r_lo, r_hi);
    // |s·d − b|² = s² − 2·s·(d·b) + |b|², with d·b ≤ along.
    (s * s - 2.0 * s * along + bl * bl).max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn balls_cover_the_path() {
        let path = [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(2.0, 1.0, 0.0),
        ];
        let balls = cover(&path, 6);
        assert_eq!(balls.len(), 6);
        for i in 0..=300 {
            let s = 3.0 * i as f64 / 300.0;
            let p = if s <= 2.0 {
                DVec3::new(s, 0.0, 0.0)
            } else {
                DVec3::new(2.0, s - 2.0, 0.0)
            };
            assert!(
                balls.iter().any(|b| b.centre.distance(p) <= b.radius),
                "{p} is in no ball"
            );
        }
        assert_eq!(
            cover(&path[..1], 4),
            vec![Ball {
                centre: DVec3::ZERO,
                radius: 0.0
            }]
        );
    }

    #[test]
    fn the_nearest_distance_is_a_lower_bound() {
        let d0 = DVec3::new(1.0, 0.1, 0.0).normalize();
        let half = 0.05;
        for b in [
            DVec3::new(0.5, 0.3, 0.0),
            DVec3::new(-1.0, 0.0, 0.2),
            DVec3::new(3.0, 0.3, 0.0),
            DVec3::new(0.0, 0.0, 0.0),
        ] {
            let bound = nearest_distance(b, d0, half, 2.0, 2.5);
            for i in 0..=10 {
                for j in 0..=10 {
                    let (e1, e2) = d0.any_orthonormal_pair();
                    let a = half * 0.99 * (i as f64 / 5.0 - 1.0) / 2f64.sqrt();
                    let c = half * 0.99 * (j as f64 / 5.0 - 1.0) / 2f64.sqrt();
                    let d = (d0 + a.tan() * e1 + c.tan() * e2).normalize();
                    for s in [2.0, 2.1, 2.3, 2.5] {
                        let dist = (s * d - b).length();
                        assert!(dist >= bound - 1e-12, "{b}: {dist} < {bound}");
                    }
                }
            }
        }
    }

    #[test]
    fn cone_pixels_hold_every_direction_of_the_cone() {
        let n = 16;
        for u in [
            DVec3::new(1.0, 0.2, 0.1),
            DVec3::new(1.0, 0.98, 0.97),
            DVec3::new(0.3, -1.0, 0.99),
        ] {
            let u = u.normalize();
            let angle = 0.2;
            let mut seen = std::collections::HashSet::new();
            cone_pixels(u, angle, n, |f, x, y| {
                seen.insert((f, x, y));
                true
            });
            let (e1, e2) = u.any_orthonormal_pair();
            for i in 0..=40 {
                for j in 0..=40 {
                    let (a, b) = (i as f64 / 20.0 - 1.0, j as f64 / 20.0 - 1.0);
                    let d = u + angle.tan() * (a * e1 + b * e2);
                    if u.angle_between(d) > angle {
                        continue;
                    }
                    let fc = FaceCoord::from_dir(d).unwrap();
                    let (x, y) = fc.to_pixel(n);
                    assert!(seen.contains(&(fc.face, x, y)), "{d} not covered");
                }
            }
        }
    }
}
