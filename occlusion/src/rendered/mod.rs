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
//! # Balls where they are needed ([`hidden_from_segment`])
//!
//! A segment's balls are halved where a tile needs smaller ones: a tile hidden from a ball is
//! hidden from its halves, so testing a tile against the coarsest balls it passes proves as
//! much as the finest everywhere. A tile starts at the first level whose balls span at most
//! [`RenderedParams::max_parallax_px`] pixels at the occluders the viewpoint sees in front of
//! it; a tile the viewpoint itself sees, or whose pixel a ball's centre sees, is kept at
//! once. Tests go a block at a time (the whole tile as one region, then quarters), and for
//! scenes whose geometry is at hand a ball's depth is cast ray by ray where a test looks
//! ([`BallDepth::Rays`]) rather than rendered whole.
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

use std::sync::atomic::{AtomicU32, AtomicU8, Ordering};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, Face, FaceCoord};

use crate::cull::ViewpointCull;
use crate::input::SlabLayer;
use crate::maps::{hole_punched, DiscontinuityRule, OcclusionMap};
use crate::oracle::MatchRule;
use crate::OcclusionError;

mod segment;
pub use segment::{hidden_from_segment, SegmentEnd, SegmentVerdict};

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

/// Knobs of the rendered variant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderedParams {
    /// Balls per track segment at the finest level: a tile is kept when some ball of this
    /// size neither hides it nor sees it. Renders are made only where tiles need them.
    pub per_segment: usize,
    /// Balls per track segment at the coarsest level, each split in two down to
    /// `per_segment`.
    pub coarse_per_segment: usize,
    /// A ball proves nothing behind an occluder from which its radius spans more than this
    /// many pixels of the render: a slit narrower than a pixel from the ball's centre must
    /// stay about that narrow from every point of the ball.
    pub max_parallax_px: f64,
    /// Which depth jumps of a render are gaps.
    pub discontinuity: DiscontinuityRule,
    /// What a pixel holds: the oracle's rule for attributing a seen point to a pixel.
    pub content: MatchRule,
}

impl Default for RenderedParams {
    fn default() -> Self {
        RenderedParams {
            per_segment: 64,
            coarse_per_segment: 2,
            max_parallax_px: 16.0,
            discontinuity: DiscontinuityRule::default(),
            content: MatchRule::default(),
        }
    }
}

impl RenderedParams {
    /// Balls per segment at the top level and the levels of halving below it, so that the
    /// finest level has at least `per_segment` balls.
    pub fn levels(&self) -> (usize, u32) {
        let coarse = self.coarse_per_segment.clamp(1, self.per_segment.max(1));
        let mut levels = 0;
        while (coarse << levels) < self.per_segment && levels < 20 {
            levels += 1;
        }
        (coarse, levels)
    }
}

/// Where a ball's depth comes from.
pub enum BallDepth<'a> {
    /// A whole cube map rendered ahead (radial depth from the centre, `+inf` for nothing).
    Map(CubeMap<f32>),
    /// Rays cast from the centre through pixel centres when a test first looks there, each
    /// kept: the same depths as a whole render, for the pixels the tests need.
    Rays(&'a dyn crate::oracle::Geometry),
}

/// A ball's depth and where it shows a continuous surface, whole or filled in on demand.
enum Store<'a> {
    Map {
        depth: CubeMap<f32>,
        /// 1 where a surface is hit and no gap opens to a neighbour over the ball.
        solid: CubeMap<u8>,
    },
    Lazy {
        geometry: &'a dyn crate::oracle::Geometry,
        /// `f32` bits of each pixel's depth; [`UNKNOWN`] until cast.
        depth: Vec<AtomicU32>,
        /// 0 until known, then 1 (a gap or nothing) or 2 (solid).
        solid: Vec<AtomicU8>,
    },
}

/// Bits no depth has (a NaN): the pixel's ray is not cast yet.
const UNKNOWN: u32 = 0x7fc0_dead;

/// A depth render from a ball's centre, ready for tests: its depth and where it shows a
/// continuous surface.
pub struct BallView<'a> {
    pub ball: Ball,
    n: u32,
    store: Store<'a>,
    rule: DiscontinuityRule,
    /// Largest angle (radians) the ball may subtend, seen from the occluder it relies on.
    max_parallax: f64,
}

impl<'a> BallView<'a> {
    /// The depth of `ball` at `n` pixels a face side. `max_parallax_px`: the most pixels of
    /// the render the ball's radius may span at the distance of an occluder it relies on
    /// ([`RenderedParams::max_parallax_px`]).
    pub fn new(
        ball: Ball,
        depth: BallDepth<'a>,
        n: u32,
        rule: DiscontinuityRule,
        max_parallax_px: f64,
    ) -> BallView<'a> {
        let store = match depth {
            BallDepth::Map(depth) => {
                let map = OcclusionMap {
                    opaque: depth.map(|d| u8::from(d.is_finite() && *d > 0.0)),
                    depth: depth.clone(),
                };
                let solid = hole_punched(&map, rule, ball.radius);
                Store::Map { depth, solid }
            }
            BallDepth::Rays(geometry) => {
                let cells = 6 * n as usize * n as usize;
                Store::Lazy {
                    geometry,
                    depth: (0..cells).map(|_| AtomicU32::new(UNKNOWN)).collect(),
                    solid: (0..cells).map(|_| AtomicU8::new(0)).collect(),
                }
            }
        };
        let n = match &store {
            Store::Map { depth, .. } => depth.face_size(),
            Store::Lazy { .. } => n,
        };
        let max_parallax = max_parallax_px.max(0.0) * std::f64::consts::FRAC_PI_2 / n.max(1) as f64;
        BallView {
            ball,
            n,
            store,
            rule,
            max_parallax,
        }
    }

    /// Radial depth through pixel `(x, y)` of `face`.
    pub fn depth(&self, face: Face, x: u32, y: u32) -> f32 {
        match &self.store {
            Store::Map { depth, .. } => *depth.get(face, x, y),
            Store::Lazy {
                geometry, depth, ..
            } => {
                let i = self.index(face, x, y);
                let bits = depth[i].load(Ordering::Relaxed);
                if bits != UNKNOWN {
                    return f32::from_bits(bits);
                }
                let dir = tracks::cubemap::pixel_dir(face, x, y, self.n);
                let d = geometry
                    .first_hit(self.ball.centre, dir, f64::INFINITY)
                    .map_or(f32::INFINITY, |t| t as f32);
                depth[i].store(d.to_bits(), Ordering::Relaxed);
                d
            }
        }
    }

    /// Whether pixel `(x, y)` of `face` shows a surface with no gap to a neighbour over the
    /// ball ([`hole_punched`]'s rule).
    fn solid(&self, face: Face, x: u32, y: u32) -> bool {
        match &self.store {
            Store::Map { solid, .. } => *solid.get(face, x, y) != 0,
            Store::Lazy { solid, .. } => {
                let i = self.index(face, x, y);
                match solid[i].load(Ordering::Relaxed) {
                    1 => false,
                    2 => true,
                    _ => {
                        let inv = |f: Face, x: u32, y: u32| {
                            let d = self.depth(f, x, y);
                            if d.is_finite() && d > 0.0 {
                                1.0 / d as f64
                            } else {
                                f64::NAN
                            }
                        };
                        let d = self.depth(face, x, y);
                        let ok = d.is_finite()
                            && d > 0.0
                            && !crate::maps::gap_at(
                                &inv,
                                self.n,
                                self.rule,
                                self.ball.radius,
                                (face, x, y),
                            );
                        solid[i].store(if ok { 2 } else { 1 }, Ordering::Relaxed);
                        ok
                    }
                }
            }
        }
    }

    fn index(&self, face: Face, x: u32, y: u32) -> usize {
        let n = self.n as usize;
        (face.index() * n + y as usize) * n + x as usize
    }

    pub fn face_size(&self) -> u32 {
        self.n
    }

    /// Whether the point `p` is what the ball's centre sees in its direction (the first hit
    /// there lies within `tol` of its distance, relative).
    pub(crate) fn sees(&self, p: DVec3, tol: f64) -> bool {
        let q = p - self.ball.centre;
        let r = q.length();
        let Some(c) = FaceCoord::from_dir(q) else {
            return false;
        };
        let (x, y) = c.to_pixel(self.n);
        let d = self.depth(c.face, x, y) as f64;
        (d - r).abs() <= tol * r
    }

    /// Whether every point of a region is hidden from every point of the ball (the lemma of
    /// the module docs). `corners`: points whose convex hull holds the region, up to
    /// `bulge` metres; `nearest`: a lower bound on the region's distance from the centre.
    pub(crate) fn hides(&self, corners: &[DVec3], bulge: f64, nearest: f64) -> bool {
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
        if beta > MAX_CONE {
            return false;
        }
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
            if r0.is_nan() || r0 <= 2.0 * eps || eps > self.max_parallax * r0 {
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
            let d = self.depth(face, x, y) as f64;
            if !d.is_finite() || (solid && !self.solid(face, x, y)) {
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
/// the unit `u` can fall in — per face, the box of the cone's part on the face, grown by a
/// pixel — until `f` says stop; whether it never did. (The box of rim samples that land on
/// a face, as this once was, misses the part of a cone past a face edge between samples.)
///
/// The cone's section by its tangent plane at `u` is a disc; a polygon of points around its
/// rim, clipped to each face's pyramid of directions (four planes through the origin), holds
/// the cone's part on that face up to the sagitta between rim points, which their number
/// keeps under half a pixel and the grown pixel covers.
fn cone_pixels(u: DVec3, angle: f64, n: u32, mut f: impl FnMut(Face, u32, u32) -> bool) -> bool {
    const MAX_RING: usize = 128;
    let (e1, e2) = u.any_orthonormal_pair();
    let t = angle.tan();
    let pixel = std::f64::consts::FRAC_PI_2 / n.max(1) as f64;
    // Rim points whose chord sagitta, angle·(1 − cos(π/ring)) ≈ angle·(π/ring)²/2, stays
    // under half a pixel.
    let ring = ((std::f64::consts::PI / (pixel / angle.max(1e-12)).sqrt()).ceil() as usize)
        .clamp(12, MAX_RING);
    let (ds, dc) = (std::f64::consts::TAU / ring as f64).sin_cos();
    let mut rim = Vec::with_capacity(ring + 8);
    let (mut c, mut s) = (1.0f64, 0.0f64);
    for _ in 0..ring {
        rim.push(u + t * (c * e1 + s * e2));
        (c, s) = (c * dc - s * ds, c * ds + s * dc);
    }
    let nf = n as f64;
    let last = n as i64 - 1;
    let mut poly = Vec::with_capacity(ring + 8);
    let mut next = Vec::with_capacity(ring + 8);
    for face in Face::ALL {
        let (fwd, right, up) = (face.forward(), face.right(), face.up());
        if u.dot(fwd) <= 0.0 {
            // A cone of at most MAX_CONE (20°) cannot reach a face all of whose directions
            // are within 55° of a direction more than a right angle from `u`.
            continue;
        }
        poly.clear();
        poly.extend_from_slice(&rim);
        for plane in [fwd - right, fwd + right, fwd - up, fwd + up] {
            clip(&poly, plane, &mut next);
            std::mem::swap(&mut poly, &mut next);
            if poly.is_empty() {
                break;
            }
        }
        if poly.is_empty() {
            continue;
        }
        let (mut u0, mut v0, mut u1, mut v1) = (1.0f64, 1.0f64, -1.0f64, -1.0f64);
        for d in &poly {
            let z = d.dot(fwd).max(1e-300);
            let (a, b) = (d.dot(right) / z, d.dot(up) / z);
            u0 = u0.min(a);
            u1 = u1.max(a);
            v0 = v0.min(b);
            v1 = v1.max(b);
        }
        let px = |a: f64| ((a.clamp(-1.0, 1.0) + 1.0) * 0.5 * nf).floor() as i64;
        let py = |b: f64| ((1.0 - b.clamp(-1.0, 1.0)) * 0.5 * nf).floor() as i64;
        let (x0, x1) = ((px(u0) - 1).max(0), (px(u1) + 1).min(last));
        let (y0, y1) = ((py(v1) - 1).max(0), (py(v0) + 1).min(last));
        for y in y0..=y1 {
            for x in x0..=x1 {
                if !f(face, x as u32, y as u32) {
                    return false;
                }
            }
        }
    }
    true
}

/// The convex polygon `poly` (points of one plane) clipped to the half-space `d·plane ≥ 0`.
fn clip(poly: &[DVec3], plane: DVec3, out: &mut Vec<DVec3>) {
    out.clear();
    let k = poly.len();
    for i in 0..k {
        let (a, b) = (poly[i], poly[(i + 1) % k]);
        let (da, db) = (a.dot(plane), b.dot(plane));
        if da >= 0.0 {
            out.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            out.push(a + (b - a) * (da / (da - db)));
        }
    }
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
    /// Milliseconds spent waiting for whole depth renders (POV-Ray runs); 0 where depth is
    /// cast ray by ray where the tests look.
    #[serde(default)]
    pub render_ms: u64,
}

impl RenderedStats {
    pub fn add(&mut self, o: &RenderedStats) {
        self.tiles += o.tiles;
        self.culled += o.culled;
        self.renders += o.renders;
        self.tests += o.tests;
        self.render_ms += o.render_ms;
    }
}

/// One viewpoint's decisions from the verdicts of the segments that touch it: a later tile
/// is culled when every segment hides it (`hidden[j][k][i]`: segment `j`, slab `k`, tile `i`
/// of `layers[k].tiles`). With no segment nothing is proven and everything is kept.
pub fn cull_from_segments(
    layers: &[SlabLayer],
    hidden: &[&[Vec<bool>]],
) -> Result<ViewpointCull, OcclusionError> {
    for (j, h) in hidden.iter().enumerate() {
        let fits =
            h.len() == layers.len() && h.iter().zip(layers).all(|(x, l)| x.len() == l.tiles.len());
        if !fits {
            return Err(OcclusionError::Input {
                what: "segment verdicts".into(),
                message: format!("verdict {j} does not match the viewpoint's layers"),
            });
        }
    }
    let (cull, ()) = crate::cull::decide_later_tiles_seq(layers, |k, i| {
        hidden.is_empty() || hidden.iter().any(|h| !h[k][i])
    });
    Ok(cull)
}

/// A lower bound on the distance from `V + b` to the points `V + s·d`, `s ∈ [r_lo, r_hi]`,
/// `d` within `half` of `d0`: with `s` free in that range and `d·b` at most `|b|·cos(max(0,
/// ∠(d0, b) − half))`, the distance is smallest at `s = clamp(d·b)`.
pub(crate) fn nearest_distance(b: DVec3, d0: DVec3, half: f64, r_lo: f64, r_hi: f64) -> f64 {
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
        for n in [16, 48, 200] {
            for u in [
                DVec3::new(1.0, 0.2, 0.1),
                DVec3::new(1.0, 0.98, 0.97),
                DVec3::new(0.3, -1.0, 0.99),
                DVec3::new(-0.7, 0.69, 0.1),
                DVec3::new(0.0, 0.0, -1.0),
            ] {
                for angle in [0.004, 0.05, 0.2, MAX_CONE] {
                    let u = u.normalize();
                    let mut seen = std::collections::HashSet::new();
                    cone_pixels(u, angle, n, |f, x, y| {
                        seen.insert((f, x, y));
                        true
                    });
                    let (e1, e2) = u.any_orthonormal_pair();
                    for i in 0..=60 {
                        for j in 0..=60 {
                            let (a, b) = (i as f64 / 30.0 - 1.0, j as f64 / 30.0 - 1.0);
                            let d = u + angle.tan() * (a * e1 + b * e2);
                            if u.angle_between(d) > angle {
                                continue;
                            }
                            let fc = FaceCoord::from_dir(d).unwrap();
                            let (x, y) = fc.to_pixel(n);
                            assert!(
                                seen.contains(&(fc.face, x, y)),
                                "n {n}, {u} ± {angle}: {d} not covered"
                            );
                        }
                    }
                }
            }
        }
    }
}
