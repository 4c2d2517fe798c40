//! The exact oracle: which slab tiles of each reference viewpoint are ever seen from the track.
//!
//! Visible points come from depth cube maps rendered at dense positions along each segment —
//! by casting rays through exact [`Geometry`] ([`RayCast`]) or from depth renders made
//! elsewhere, e.g. by POV-Ray ([`DepthRenders`]); both are a [`DepthSource`]. Every visible
//! point is reprojected into both reference viewpoints of its segment: its distance picks the
//! slab, and it marks the pixel of that slab's layer whose stored depth matches it (a point
//! the layer does not hold — hidden at the reference viewpoint even within its slab — marks
//! nothing). [`score`] then compares a culling decision with the marks.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::{cubemap::pixel_dir, CubeMap, Face, FaceCoord, TileGrid};

use crate::cull::ViewpointCull;
use crate::input::SlabLayer;
use crate::OcclusionError;

/// Exact scene geometry for the oracle.
pub trait Geometry: Sync {
    /// Distance along the unit `dir` from `origin` to the first surface hit, if one is within
    /// `t_max`.
    fn first_hit(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<f64>;
}

/// Where visible points come from: a radial depth cube map seen from a position.
pub trait DepthSource: Sync {
    /// Radial depth from `position`, `+inf` where nothing is hit.
    fn depth_from(&self, position: DVec3) -> Result<CubeMap<f32>, OcclusionError>;
}

/// Render a radial depth cube map by casting one ray per pixel centre.
pub fn depth_from_geometry<G: Geometry + ?Sized>(
    geom: &G,
    origin: DVec3,
    face_size: u32,
) -> CubeMap<f32> {
    let n = face_size as usize;
    let mut data = vec![f32::INFINITY; 6 * n * n];
    data.par_chunks_mut(n.max(1))
        .enumerate()
        .for_each(|(row, out)| {
            let face = Face::ALL[row / n];
            let y = (row % n) as u32;
            for (x, o) in out.iter_mut().enumerate() {
                let d = pixel_dir(face, x as u32, y, face_size);
                if let Some(t) = geom.first_hit(origin, d, f64::INFINITY) {
                    *o = t as f32;
                }
            }
        });
    CubeMap::from_vec(face_size, data).unwrap_or_else(|| CubeMap::filled(face_size, f32::INFINITY))
}

/// Visible points by ray casting through exact geometry at `face_size` rays per face side.
pub struct RayCast<'a, G: ?Sized> {
    pub geometry: &'a G,
    pub face_size: u32,
}

impl<G: Geometry + ?Sized> DepthSource for RayCast<'_, G> {
    fn depth_from(&self, position: DVec3) -> Result<CubeMap<f32>, OcclusionError> {
        Ok(depth_from_geometry(self.geometry, position, self.face_size))
    }
}

/// Visible points from depth renders made at the oracle positions beforehand.
pub struct DepthRenders {
    pub renders: Vec<(DVec3, CubeMap<f32>)>,
}

impl DepthSource for DepthRenders {
    fn depth_from(&self, position: DVec3) -> Result<CubeMap<f32>, OcclusionError> {
        let tol = 1e-9 * (1.0 + position.length());
        self.renders
            .iter()
            .find(|(p, _)| p.distance(position) <= tol)
            .map(|(_, d)| d.clone())
            .ok_or_else(|| OcclusionError::Input {
                what: "depth renders".into(),
                message: format!("no depth render at {position}"),
            })
    }
}

/// Per slab, the pixels of a reference viewpoint's layers that were seen (thread-safe bits).
#[derive(Debug)]
pub struct Visibility {
    face_size: u32,
    bits: Vec<Vec<AtomicU64>>,
}

impl Visibility {
    pub fn new(face_size: u32, slabs: usize) -> Visibility {
        let words = (6 * face_size as usize * face_size as usize).div_ceil(64);
        Visibility {
            face_size,
            bits: (0..slabs)
                .map(|_| (0..words).map(|_| AtomicU64::new(0)).collect())
                .collect(),
        }
    }

    pub fn face_size(&self) -> u32 {
        self.face_size
    }

    fn index(&self, face: Face, x: u32, y: u32) -> usize {
        let n = self.face_size as usize;
        (face.index() * n + y as usize) * n + x as usize
    }

    pub(crate) fn mark(&self, slab: usize, face: Face, x: u32, y: u32) {
        let i = self.index(face, x, y);
        self.bits[slab][i / 64].fetch_or(1 << (i % 64), Ordering::Relaxed);
    }

    pub fn is_visible(&self, slab: usize, face: Face, x: u32, y: u32) -> bool {
        let i = self.index(face, x, y);
        self.bits
            .get(slab)
            .is_some_and(|b| b[i / 64].load(Ordering::Relaxed) & (1 << (i % 64)) != 0)
    }

    /// Pixels of `slab` seen at least once.
    pub fn visible_pixels(&self, slab: usize) -> u64 {
        self.bits
            .get(slab)
            .map(|b| {
                b.iter()
                    .map(|w| w.load(Ordering::Relaxed).count_ones() as u64)
                    .sum()
            })
            .unwrap_or(0)
    }
}

/// How a reprojected point is matched to a layer pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchRule {
    /// Relative depth tolerance, plus `per_pixel_angle` pixel angles of the reference map
    /// (a surface slanted away from the view changes depth fast across one pixel).
    pub depth_tolerance: f64,
    pub per_pixel_angle: f64,
    /// Also try the pixels this far around the one the point falls in.
    pub search_radius: u32,
}

impl Default for MatchRule {
    fn default() -> Self {
        MatchRule {
            depth_tolerance: 0.01,
            per_pixel_angle: 2.0,
            search_radius: 1,
        }
    }
}

/// Mark, in `vis` (the visibility of the reference viewpoint at `reference` with `layers`),
/// every layer pixel that holds a point of `depth_at_x` (seen from `x`).
pub fn mark_visible(
    x: DVec3,
    depth_at_x: &CubeMap<f32>,
    reference: DVec3,
    layers: &[SlabLayer],
    rule: &MatchRule,
    vis: &Visibility,
) {
    let m = depth_at_x.face_size();
    let n = vis.face_size();
    let theta = std::f64::consts::FRAC_PI_2 / n as f64;
    let tol = rule.depth_tolerance + rule.per_pixel_angle * theta;
    let offset = x - reference;
    let mm = m as usize;
    depth_at_x
        .as_slice()
        .par_chunks(mm.max(1))
        .enumerate()
        .for_each(|(row, depths)| {
            let face = Face::ALL[row / mm];
            let y = (row % mm) as u32;
            for (px, &d) in depths.iter().enumerate() {
                if !d.is_finite() {
                    continue;
                }
                // Relative to the reference viewpoint, so positions far from the origin cancel.
                let rel = offset + d as f64 * pixel_dir(face, px as u32, y, m);
                let r = rel.length();
                let Some(c) = FaceCoord::from_dir(rel) else {
                    continue;
                };
                let (cx, cy) = c.to_pixel(n);
                // The pixel the point falls in, in whichever slab stores this surface there
                // (a surface crossing a slab boundary is split by pixel centres).
                let centre = layers
                    .iter()
                    .enumerate()
                    .filter(|(_, l)| *l.alpha.get(c.face, cx, cy) >= 128)
                    .map(|(k, l)| (k, (*l.depth.get(c.face, cx, cy) as f64 - r).abs()))
                    .filter(|&(_, e)| e <= tol * r)
                    .min_by(|a, b| a.1.total_cmp(&b.1));
                if let Some((k, _)) = centre {
                    vis.mark(k, c.face, cx, cy);
                    continue;
                }
                // Otherwise a neighbouring pixel of the slab the distance falls in.
                if let Some((k, l)) = layers.iter().enumerate().find(|(_, l)| l.range.contains(r)) {
                    if let Some((bx, by)) =
                        best_match(l, c.face, cx, cy, r, tol, rule.search_radius)
                    {
                        vis.mark(k, c.face, bx, by);
                    }
                }
            }
        });
}

fn best_match(
    l: &SlabLayer,
    face: Face,
    cx: u32,
    cy: u32,
    r: f64,
    tol: f64,
    radius: u32,
) -> Option<(u32, u32)> {
    let n = l.depth.face_size();
    let mut best: Option<(f64, u32, u32)> = None;
    for y in cy.saturating_sub(radius)..=(cy + radius).min(n - 1) {
        for x in cx.saturating_sub(radius)..=(cx + radius).min(n - 1) {
            if *l.alpha.get(face, x, y) < 128 {
                continue;
            }
            let err = (*l.depth.get(face, x, y) as f64 - r).abs();
            let dist = (x.abs_diff(cx) + y.abs_diff(cy)) as f64;
            if err <= tol * r && best.is_none_or(|(b, _, _)| dist < b) {
                best = Some((dist, x, y));
            }
        }
    }
    best.map(|(_, x, y)| (x, y))
}

/// `per_segment + 1` positions evenly spaced by arc length along a polyline, both ends
/// included (a single position for a one-point polyline).
pub fn segment_samples(path: &[DVec3], per_segment: usize) -> Vec<DVec3> {
    if path.len() < 2 || per_segment == 0 {
        return path.first().copied().into_iter().collect();
    }
    let arc = tracks::segment::arc_lengths(path);
    let len = *arc.last().unwrap_or(&0.0);
    (0..=per_segment)
        .map(|j| tracks::segment::point_at(path, &arc, len * j as f64 / per_segment as f64))
        .collect()
}

/// Where the oracle looks from along a polyline: both ends (the reference viewpoints, where
/// a viewer stops) and `per_segment` positions at arc-length fractions `(j + φ)/per_segment`,
/// `φ = (√5 − 1)/2`. The offset keeps them off every dyadic fraction of the segment — the
/// centres of the intervals the shrunk variant tests — so the oracle never looks from where
/// the method looked; with `per_segment` at least twice the method's base intervals per
/// segment it is also twice as dense as the method's base sampling.
pub fn oracle_positions(path: &[DVec3], per_segment: usize) -> Vec<DVec3> {
    const PHI: f64 = 0.618_033_988_749_894_8;
    if path.len() < 2 {
        return path.first().copied().into_iter().collect();
    }
    let arc = tracks::segment::arc_lengths(path);
    let len = *arc.last().unwrap_or(&0.0);
    let mut out = vec![path[0]];
    out.extend((0..per_segment).map(|j| {
        tracks::segment::point_at(path, &arc, len * (j as f64 + PHI) / per_segment as f64)
    }));
    out.extend(path.last().copied());
    out
}

/// Run the oracle over a whole track held in memory. `refs[i]` is reference viewpoint `i`
/// (position and layers); `between[i]` is the polyline from viewpoint `i` to `i + 1`
/// (both ends included), looked at from [`oracle_positions`]. Returns one [`Visibility`]
/// per viewpoint.
pub fn oracle_track(
    refs: &[(DVec3, &[SlabLayer])],
    between: &[Vec<DVec3>],
    source: &dyn DepthSource,
    per_segment: usize,
    rule: &MatchRule,
) -> Result<Vec<Visibility>, OcclusionError> {
    if refs.len() > 1 && between.len() != refs.len() - 1 {
        return Err(OcclusionError::Parameter {
            name: "between",
            message: format!("{} segments for {} viewpoints", between.len(), refs.len()),
        });
    }
    let vis: Vec<Visibility> = refs
        .iter()
        .map(|(_, l)| Visibility::new(l.first().map_or(1, |s| s.depth.face_size()), l.len()))
        .collect();
    if refs.len() == 1 {
        let (p, l) = refs[0];
        mark_visible(p, &source.depth_from(p)?, p, l, rule, &vis[0]);
    }
    for (i, path) in between.iter().enumerate() {
        for x in oracle_positions(path, per_segment) {
            let depth = source.depth_from(x)?;
            for j in [i, i + 1] {
                let (p, l) = refs[j];
                mark_visible(x, &depth, p, l, rule, &vis[j]);
            }
        }
    }
    Ok(vis)
}

/// The oracle's verdict on one slab of one viewpoint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SlabScore {
    pub slab: usize,
    pub kept: u64,
    pub culled: u64,
    /// Tiles with at least one pixel seen.
    pub visible_tiles: u64,
    /// Culled tiles that were seen, and their seen pixels.
    pub false_culls: u64,
    pub false_cull_pixels: u64,
    /// Kept tiles never seen (how far from tight the culling is).
    pub kept_never_visible: u64,
}

impl SlabScore {
    pub fn add(&mut self, o: &SlabScore) {
        self.kept += o.kept;
        self.culled += o.culled;
        self.visible_tiles += o.visible_tiles;
        self.false_culls += o.false_culls;
        self.false_cull_pixels += o.false_cull_pixels;
        self.kept_never_visible += o.kept_never_visible;
    }
}

/// Compare a viewpoint's culling decision with what the oracle saw.
pub fn score(decision: &ViewpointCull, grid: &TileGrid, vis: &Visibility) -> Vec<SlabScore> {
    decision
        .slabs
        .iter()
        .map(|d| {
            let seen = |id| {
                let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(id);
                let mut c = 0u64;
                for y in y0..y1 {
                    for x in x0..x1 {
                        c += u64::from(vis.is_visible(d.slab, id.face, x, y));
                    }
                }
                c
            };
            let mut s = SlabScore {
                slab: d.slab,
                kept: d.kept.len() as u64,
                culled: d.culled.len() as u64,
                ..SlabScore::default()
            };
            for t in &d.kept {
                if seen(t.id) > 0 {
                    s.visible_tiles += 1;
                } else {
                    s.kept_never_visible += 1;
                }
            }
            for t in &d.culled {
                let px = seen(t.id);
                if px > 0 {
                    s.visible_tiles += 1;
                    s.false_culls += 1;
                    s.false_cull_pixels += px;
                }
            }
            s
        })
        .collect()
}

/// The built-in ray tracer's scenes are exact geometry.
impl Geometry for prerender::scene::Scene {
    fn first_hit(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<f64> {
        prerender::scene::Scene::first_hit(self, origin, dir, t_max)
    }
}
