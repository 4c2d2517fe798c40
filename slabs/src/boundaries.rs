//! Choosing slab boundaries at the valleys of a track's depth histogram, and how many.
//!
//! A slab exists to hold surfaces that a viewer half a segment away from a reference
//! viewpoint can see but the viewpoint itself cannot. Two depth clusters around a valley of
//! the histogram, with representative depths `z_near < z_far`, slide against each other by
//!
//! ```text
//! δ = (B/2) · (1/z_near − 1/z_far)      radians, B = longest segment of the track
//! ```
//!
//! as the viewer moves `B/2` off the reference viewpoint (Yang & Crawfis' eq. (1) in angular
//! form). When `δ` is below about one pixel, `θ_pixel = (π/2)/N` for faces of `N` pixels,
//! nothing hidden behind the near cluster can be revealed and the valley needs no boundary;
//! otherwise the far cluster gets its own slab. The ratio `δ/θ_pixel` plays the role of
//! Meyer & Neyret's `h·tan(a)/e` (slice spacing × viewing slope over the feature size): at
//! most 1 means fewer layers suffice.
//!
//! Candidates are (a) runs of empty bins between finite depths and (b) local minima of
//! the smoothed histogram at most `valley_ratio` of the lower of the highest peaks on either
//! side. A depth cluster only needs its own slab where something nearer hides it, so the
//! low-res depth maps are also scanned for *occlusion edges*: neighbouring pixels whose
//! depths jump (inverse planar depth off both sides' linear prediction, so sloping ground
//! is no edge) by a gap that opens wider than the pixel threshold at `B/2`. Each edge
//! `(z_near, z_far]` wants a boundary inside it; the fewest candidates that separate them
//! are found by greedy interval stabbing (by far end), and a candidate is placed only if
//! the solid angle it newly reveals (gap × edge length, summed) is at least
//! `min_edge_fraction` of the panorama. The report gives, per candidate, both numbers: the
//! cluster parallax `δ/θ_pixel` and the revealed fraction.

use serde::{Deserialize, Serialize};
use tracks::{CubeMap, SlabRange};

use crate::histogram::DepthHistogram;

/// Knobs of [`choose`]; `Default` gives the values the CLI uses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChooseParams {
    /// Histogram bins over `log10(depth)`.
    pub bins: usize,
    /// Passes of the `[1 2 1]/4` smoothing kernel before looking for minima.
    pub smoothing_passes: usize,
    /// A local minimum is a candidate only if it is at most this fraction of the lower of
    /// the highest peaks on either side.
    pub valley_ratio: f64,
    /// A boundary is placed when the parallax between its clusters exceeds this many pixels.
    pub threshold_px: f64,
    /// A boundary must separate occlusion edges (gaps wider than `threshold_px` at `B/2`)
    /// that reveal at least this fraction of the panorama's solid angle.
    pub min_edge_fraction: f64,
}

impl Default for ChooseParams {
    fn default() -> Self {
        ChooseParams {
            bins: 128,
            smoothing_passes: 2,
            valley_ratio: 0.9,
            threshold_px: 1.0,
            min_edge_fraction: 1e-3,
        }
    }
}

/// Why a candidate was or was not made a boundary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// `gap` (empty bins) or `valley` (local minimum).
    pub kind: String,
    /// Depth the boundary would sit at, metres.
    pub depth_m: f64,
    /// Representative (mode) depths of the clusters on either side when it was decided.
    pub near_cluster_m: f64,
    pub far_cluster_m: f64,
    /// `(B/2)·(1/near − 1/far)`, radians.
    pub parallax_rad: f64,
    /// The same in pixels of the full-resolution face (`parallax_rad / θ_pixel`).
    pub parallax_px: f64,
    /// Smoothed histogram value at the candidate over the lower neighbouring peak.
    pub valley_depth_ratio: f64,
    /// Solid angle (per viewpoint) that opens up at `B/2` along occlusion edges whose near
    /// side is in front of the candidate and far side behind it, as a fraction of 4π.
    pub edge_fraction: f64,
    pub accepted: bool,
    pub reason: String,
}

/// The criterion's numbers: what a report prints to say why the slabs are what they are.
/// Read back, a field the file lacks takes its default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CriterionReport {
    /// Longest segment `B` of the track, metres.
    pub max_spacing_m: f64,
    /// `B/2`: how far a viewer gets from its nearest reference viewpoint.
    pub half_baseline_m: f64,
    pub face_size: u32,
    /// `(π/2)/N`.
    pub theta_pixel_rad: f64,
    pub threshold_px: f64,
    /// [`ChooseParams::min_edge_fraction`].
    pub min_edge_fraction: f64,
    /// Candidates nearest first.
    pub candidates: Vec<Candidate>,
    /// Fraction of the average panorama's solid angle that is sky.
    pub sky_fraction: f64,
    /// Occlusion edges no boundary separates (no valley inside them, or too rare to pay
    /// for a slab), as a fraction of the panorama's solid angle.
    pub unresolved_edge_fraction: f64,
    /// Set when the choice was given, not computed (`--slabs LIST`).
    pub manual: bool,
    /// One line per decision for people.
    pub summary: String,
}

/// The chosen slabs (nearest first; empty when every pixel is sky) with the reasons.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabChoice {
    pub slabs: Vec<SlabRange>,
    pub criterion: CriterionReport,
    pub histogram: DepthHistogram,
}

/// Parallax of a far cluster against a near one seen from `b` metres off the viewpoint.
pub fn cluster_parallax_rad(b_m: f64, near_m: f64, far_m: f64) -> f64 {
    b_m * (1.0 / near_m - 1.0 / far_m)
}

/// Angular size of one pixel at the centre of a face of `face_size` pixels (`(π/2)/N`).
pub fn theta_pixel(face_size: u32) -> f64 {
    std::f64::consts::FRAC_PI_2 / face_size.max(1) as f64
}

struct Cand {
    kind: &'static str,
    bin: usize,
    depth_m: f64,
    ratio: f64,
}

/// Choose slab boundaries from the low-resolution depth of every reference viewpoint of a
/// track. `max_spacing_m` is the longest segment between consecutive viewpoints (0 for a
/// single viewpoint), `face_size` the full-resolution face size the layers will have.
pub fn choose(
    lowres_depths: &[CubeMap<f32>],
    max_spacing_m: f64,
    face_size: u32,
    params: &ChooseParams,
) -> SlabChoice {
    let hist = DepthHistogram::build(lowres_depths, params.bins);
    let b = baseline(max_spacing_m);
    let edges = occlusion_edges(
        lowres_depths,
        b / 2.0,
        theta_pixel(face_size) * params.threshold_px,
    );
    choose_with_edges(hist, &edges, max_spacing_m, face_size, params)
}

/// The baseline `B` the boundaries are chosen for: the largest spacing of neighbouring
/// viewpoints, 0 when there is none (one viewpoint) or it is not finite.
fn baseline(max_spacing_m: f64) -> f64 {
    if max_spacing_m.is_finite() {
        max_spacing_m.max(0.0)
    } else {
        0.0
    }
}

/// [`choose`] over `count` maps that `read(k)` gives one at a time (twice each: the depth
/// range and the edges first, then the histogram), so that a track of any length needs one
/// map in memory at once, not all. The same choice as [`choose`] on all of them.
pub fn choose_streamed<E>(
    count: usize,
    mut read: impl FnMut(usize) -> Result<CubeMap<f32>, E>,
    max_spacing_m: f64,
    face_size: u32,
    params: &ChooseParams,
) -> Result<SlabChoice, E> {
    let half_baseline = baseline(max_spacing_m) / 2.0;
    let min_gap = theta_pixel(face_size) * params.threshold_px;
    let views = count.max(1) as f64;
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    let mut edges = Vec::new();
    for k in 0..count {
        let m = read(k)?;
        let (a, b) = crate::histogram::depth_range(&m);
        (lo, hi) = (lo.min(a), hi.max(b));
        map_occlusion_edges(&m, half_baseline, min_gap, views, &mut edges);
    }
    let mut hist = DepthHistogram::over(lo, hi, params.bins);
    for k in 0..count {
        hist.add(&read(k)?, views);
    }
    Ok(choose_with_edges(
        hist,
        &edges,
        max_spacing_m,
        face_size,
        params,
    ))
}

/// A pair of neighbouring low-res pixels across which the surface jumps: a viewer `B/2`
/// off the viewpoint sees a gap open between them wider than the threshold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OcclusionEdge {
    pub near_m: f64,
    pub far_m: f64,
    /// Solid angle a viewer `B/2` away sees open up along this edge (the gap angle times
    /// the edge's length), divided by the number of viewpoints.
    pub weight_sr: f64,
}

/// Occlusion edges of every map: horizontal and vertical neighbours on one face, both
/// finite, whose inverse planar depth `q = |D|/r` is predicted by neither side's linear
/// extrapolation within `min_gap_rad / half_baseline_m` of inverse depth (a plane has zero
/// second difference of `q`, so sloping ground is not an edge). Sky neighbours are not
/// edges: sky is the background layer.
pub fn occlusion_edges(
    maps: &[CubeMap<f32>],
    half_baseline_m: f64,
    min_gap_rad: f64,
) -> Vec<OcclusionEdge> {
    let mut out = Vec::new();
    let views = maps.len().max(1) as f64;
    for m in maps {
        map_occlusion_edges(m, half_baseline_m, min_gap_rad, views, &mut out);
    }
    out
}

/// [`occlusion_edges`] of one map `m` of `views`, appended to `out` (each edge's weight is
/// divided by `views`).
pub fn map_occlusion_edges(
    m: &CubeMap<f32>,
    half_baseline_m: f64,
    min_gap_rad: f64,
    views: f64,
    out: &mut Vec<OcclusionEdge>,
) {
    if half_baseline_m <= 0.0 {
        return;
    }
    let n = m.face_size();
    let dn = |x: u32, y: u32| -> f64 {
        let (u, v) = tracks::cubemap::uv_from_pixel_f(x as f64 + 0.5, y as f64 + 0.5, n);
        (1.0 + u * u + v * v).sqrt()
    };
    for face in tracks::Face::ALL {
        let q = |x: i64, y: i64| -> Option<(f64, f64)> {
            if x < 0 || y < 0 || x >= n as i64 || y >= n as i64 {
                return None;
            }
            let r = *m.get(face, x as u32, y as u32) as f64;
            (r.is_finite() && r > 0.0).then(|| (dn(x as u32, y as u32) / r, r))
        };
        for y in 0..n as i64 {
            for x in 0..n as i64 {
                let Some((qa, ra)) = q(x, y) else { continue };
                for (dx, dy) in [(1i64, 0i64), (0, 1)] {
                    let Some((qb, rb)) = q(x + dx, y + dy) else {
                        continue;
                    };
                    let e1 = q(x - dx, y - dy)
                        .map_or((qb - qa).abs(), |(qp, _)| (qb - (2.0 * qa - qp)).abs());
                    let e2 = q(x + 2 * dx, y + 2 * dy)
                        .map_or((qa - qb).abs(), |(qn, _)| (qa - (2.0 * qb - qn)).abs());
                    // Residual in inverse radial depth, then the gap it opens at B/2.
                    let resid = e1.min(e2) / dn(x as u32, y as u32);
                    let gap = half_baseline_m * (1.0 / ra.min(rb) - 1.0 / ra.max(rb));
                    if half_baseline_m * resid > min_gap_rad && gap > min_gap_rad {
                        out.push(OcclusionEdge {
                            near_m: ra.min(rb),
                            far_m: ra.max(rb),
                            // Solid angle revealed at B/2: gap × edge length.
                            weight_sr: gap
                                * tracks::cubemap::pixel_solid_angle(x as u32, y as u32, n).sqrt()
                                / views,
                        });
                    }
                }
            }
        }
    }
}

/// [`choose`] on a histogram and occlusion edges already computed.
pub fn choose_with_edges(
    hist: DepthHistogram,
    edges: &[OcclusionEdge],
    max_spacing_m: f64,
    face_size: u32,
    params: &ChooseParams,
) -> SlabChoice {
    let b = baseline(max_spacing_m);
    let theta = theta_pixel(face_size);
    let all = hist.total() + hist.sky_sr + hist.invalid_sr;
    let mut report = CriterionReport {
        max_spacing_m: b,
        half_baseline_m: b / 2.0,
        face_size,
        theta_pixel_rad: theta,
        threshold_px: params.threshold_px,
        min_edge_fraction: params.min_edge_fraction,
        candidates: Vec::new(),
        sky_fraction: if all > 0.0 { hist.sky_sr / all } else { 0.0 },
        unresolved_edge_fraction: 0.0,
        manual: false,
        summary: String::new(),
    };
    if hist.total() <= 0.0 {
        report.summary =
            "no finite depth: every pixel is sky, no slab (sky is the background layer)".into();
        return SlabChoice {
            slabs: Vec::new(),
            criterion: report,
            histogram: hist,
        };
    }
    let smooth = hist.smoothed(params.smoothing_passes);
    let cands = find_candidates(&hist, &smooth, params.valley_ratio);
    let placement = stab_edges(&cands, edges, params.min_edge_fraction);
    let live: Vec<usize> = (0..cands.len())
        .filter(|&ci| placement.placed[ci])
        .collect();
    let clusters = Clusters {
        hist: &hist,
        cands: &cands,
        half_baseline_m: b / 2.0,
    };
    report.candidates = clusters.describe(edges, &placement, &live, theta, params);
    let slabs = slabs_at(&cands, &live);
    report.unresolved_edge_fraction = placement.unresolved;
    report.summary = format!(
        "{} slab(s) from {} candidate valley(s), occlusion edges left in one slab: {:.2e} of the panorama; B/2 = {:.3} m, θ_pixel = {:.3e} rad (N = {}), threshold {} px",
        slabs.len(),
        cands.len(),
        placement.unresolved,
        b / 2.0,
        theta,
        face_size,
        params.threshold_px
    );
    SlabChoice {
        slabs,
        criterion: report,
        histogram: hist,
    }
}

/// Solid angle of a whole panorama (per viewpoint): edge weights are fractions of it.
const PANORAMA_SR: f64 = 4.0 * std::f64::consts::PI;

/// Whether a boundary at candidate `c` separates the two sides of edge `e`.
fn stabs(c: &Cand, e: &OcclusionEdge) -> bool {
    e.near_m < c.depth_m && e.far_m >= c.depth_m
}

/// Which candidates became boundaries, and what the edges they separate reveal.
struct Placement {
    /// Per candidate: placed as a boundary.
    placed: Vec<bool>,
    /// Per candidate: the fraction of the panorama it newly separated when placed (0 if not).
    placed_gain: Vec<f64>,
    /// Edges no placed boundary separates, as a fraction of the panorama.
    unresolved: f64,
}

/// Interval stabbing: every occlusion edge (near, far] wants a boundary inside it, so that its
/// two sides land in different slabs. Greedy by far end picks the fewest candidates that
/// separate them (optimal for stabbing intervals with points); a candidate that would separate
/// less than `min_edge_fraction` of the panorama is not worth a slab, and its edge is left
/// unresolved.
fn stab_edges(cands: &[Cand], edges: &[OcclusionEdge], min_edge_fraction: f64) -> Placement {
    let mut order: Vec<usize> = (0..edges.len()).collect();
    order.sort_by(|&i, &j| edges[i].far_m.total_cmp(&edges[j].far_m));
    let mut stabbed = vec![false; edges.len()];
    let mut placed = vec![false; cands.len()];
    let gain = |ci: usize, stabbed: &[bool]| -> f64 {
        edges
            .iter()
            .zip(stabbed)
            .filter(|(e, s)| !**s && stabs(&cands[ci], e))
            .map(|(e, _)| e.weight_sr)
            .sum::<f64>()
            / PANORAMA_SR
    };
    let mut gains: Vec<f64> = (0..cands.len()).map(|ci| gain(ci, &stabbed)).collect();
    let mut placed_gain = vec![0.0; cands.len()];
    for &ei in &order {
        if stabbed[ei] {
            continue;
        }
        let e = &edges[ei];
        let Some(ci) = (0..cands.len()).rev().find(|&ci| stabs(&cands[ci], e)) else {
            continue;
        };
        if placed[ci] || gains[ci] < min_edge_fraction {
            continue;
        }
        placed[ci] = true;
        placed_gain[ci] = gains[ci];
        for (k, e) in edges.iter().enumerate() {
            if stabs(&cands[ci], e) {
                stabbed[k] = true;
            }
        }
        gains = (0..cands.len()).map(|ci| gain(ci, &stabbed)).collect();
    }
    let unresolved: f64 = edges
        .iter()
        .zip(&stabbed)
        .filter(|(_, s)| !**s)
        .map(|(e, _)| e.weight_sr)
        .sum::<f64>()
        / PANORAMA_SR;
    Placement {
        placed,
        placed_gain,
        unresolved,
    }
}

/// The depth clusters between candidate boundaries of a histogram.
struct Clusters<'a> {
    hist: &'a DepthHistogram,
    cands: &'a [Cand],
    half_baseline_m: f64,
}

impl Clusters<'_> {
    /// Mode of bins lo..hi (exclusive) by the raw weights; fall back to the centre.
    fn mode_depth(&self, lo: usize, hi: usize) -> f64 {
        let mut best = (lo, -1.0);
        for i in lo..hi {
            if self.hist.weights[i] > best.1 {
                best = (i, self.hist.weights[i]);
            }
        }
        self.hist.centre_m(best.0)
    }

    /// Representative depths of the clusters either side of `live[k]` among `live`, and their
    /// parallax.
    fn evaluate(&self, live: &[usize], k: usize) -> (f64, f64, f64) {
        let (cands, bins) = (self.cands, self.hist.bins());
        let c = &cands[live[k]];
        let lo = if k == 0 {
            0
        } else {
            cands[live[k - 1]].bin + 1
        };
        let hi = if k + 1 == live.len() {
            bins
        } else {
            cands[live[k + 1]].bin
        };
        let near = self.mode_depth(lo, c.bin.max(lo + 1).min(bins));
        let far = self.mode_depth(
            (c.bin + 1).min(hi.saturating_sub(1)),
            hi.max(c.bin + 2).min(bins),
        );
        (
            near,
            far,
            cluster_parallax_rad(self.half_baseline_m, near, far),
        )
    }

    /// The report of every candidate, each against the clusters between its placed
    /// neighbours (`live`: the placed candidates in order).
    fn describe(
        &self,
        edges: &[OcclusionEdge],
        placement: &Placement,
        live: &[usize],
        theta: f64,
        params: &ChooseParams,
    ) -> Vec<Candidate> {
        let cands = self.cands;
        let placed = &placement.placed;
        let mut decided = Vec::with_capacity(cands.len());
        for (ci, c) in cands.iter().enumerate() {
            let mut with: Vec<usize> = live.to_vec();
            if !placed[ci] {
                with.push(ci);
                with.sort_unstable();
            }
            let k = with.iter().position(|&x| x == ci).unwrap_or(0);
            let (near, far, p) = self.evaluate(&with, k);
            let px = p / theta;
            // Fraction of the panorama across all edges this candidate would separate.
            let all_edges = edges
                .iter()
                .filter(|e| stabs(c, e))
                .map(|e| e.weight_sr)
                .sum::<f64>()
                / PANORAMA_SR
                + 0.0; // an empty sum is -0.0
            let reason = if placed[ci] {
                format!(
                    "separates occlusion edges covering {:.2e} of the panorama that no nearer boundary separates (clusters {near:.3} m / {far:.3} m slide {px:.3} px)",
                    placement.placed_gain[ci]
                )
            } else if all_edges < params.min_edge_fraction {
                format!(
                    "occlusion edges across {:.3} m cover {all_edges:.2e} < {:.1e} of the panorama: the surfaces on either side are continuous or too small to matter",
                    c.depth_m, params.min_edge_fraction
                )
            } else {
                format!(
                    "its occlusion edges ({all_edges:.2e}) are separated by a placed boundary already, or leave less than {:.1e} for it",
                    params.min_edge_fraction
                )
            };
            decided.push(Candidate {
                kind: c.kind.into(),
                depth_m: c.depth_m,
                near_cluster_m: near,
                far_cluster_m: far,
                parallax_rad: p,
                parallax_px: px,
                valley_depth_ratio: c.ratio,
                edge_fraction: all_edges,
                accepted: placed[ci],
                reason,
            });
        }
        decided
    }
}

/// Slabs from 0 to infinity split at the placed candidates `live` (a candidate no deeper than
/// the previous boundary adds none).
fn slabs_at(cands: &[Cand], live: &[usize]) -> Vec<SlabRange> {
    let mut slabs = Vec::new();
    let mut near = 0.0;
    for &k in live {
        let d = cands[k].depth_m;
        if let Some(r) = SlabRange::new(near, d) {
            slabs.push(r);
            near = d;
        }
    }
    slabs.extend(SlabRange::new(near, f64::INFINITY));
    slabs
}

/// Report for a manual `--slabs` list: no candidates, the list as given.
pub fn manual(
    slabs: Vec<SlabRange>,
    lowres_depths: &[CubeMap<f32>],
    max_spacing_m: f64,
    face_size: u32,
    params: &ChooseParams,
) -> SlabChoice {
    let mut c = choose(lowres_depths, max_spacing_m, face_size, params);
    c.criterion.manual = true;
    c.criterion.summary = format!(
        "{} slab(s) given on the command line; the automatic choice would have been {} ({})",
        slabs.len(),
        c.slabs.len(),
        c.criterion.summary
    );
    c.slabs = slabs;
    c
}

/// The automatic choice with `delta` boundaries fewer (`delta < 0`) or more (`delta > 0`):
/// what `--slabs fewer` / `more` build, to measure what the parallax criterion's choice is
/// worth. Fewer drops the placed boundaries that reveal the least (smallest revealed fraction,
/// then smallest parallax); more places the rejected candidates that would reveal the most,
/// and when none is left splits the slab holding the most surface at its median log depth.
/// Never fewer than one slab while there is finite depth.
pub fn adjust(choice: &SlabChoice, delta: i32) -> Vec<SlabRange> {
    let mut bounds: Vec<f64> = choice
        .slabs
        .iter()
        .skip(1)
        .map(|s| s.near)
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    let cands = &choice.criterion.candidates;
    let rank = |c: &&Candidate| (c.edge_fraction, c.parallax_px);
    let by_need = |a: &&Candidate, b: &&Candidate| {
        let (x, y) = (rank(a), rank(b));
        x.0.total_cmp(&y.0).then(x.1.total_cmp(&y.1))
    };
    if delta < 0 {
        let mut placed: Vec<&Candidate> = cands
            .iter()
            .filter(|c| c.accepted && bounds.contains(&c.depth_m))
            .collect();
        placed.sort_by(by_need);
        for c in placed.iter().take(delta.unsigned_abs() as usize) {
            bounds.retain(|d| *d != c.depth_m);
        }
        // Boundaries without a candidate record (none in an automatic choice) go last.
        let extra = (delta.unsigned_abs() as usize).saturating_sub(placed.len());
        for _ in 0..extra {
            bounds.pop();
        }
    } else if delta > 0 {
        let mut rejected: Vec<&Candidate> = cands
            .iter()
            .filter(|c| !c.accepted && !bounds.contains(&c.depth_m))
            .collect();
        rejected.sort_by(|a, b| by_need(b, a));
        for k in 0..delta as usize {
            match rejected.get(k) {
                Some(c) => bounds.push(c.depth_m),
                None => {
                    if let Some(d) = split_depth(&choice.histogram, &bounds) {
                        bounds.push(d);
                    }
                }
            }
        }
    }
    bounds.sort_by(f64::total_cmp);
    bounds.dedup();
    if choice.slabs.is_empty() {
        return Vec::new();
    }
    let mut slabs = Vec::new();
    let mut near = 0.0;
    for d in bounds {
        if let Some(r) = SlabRange::new(near, d) {
            slabs.push(r);
            near = d;
        }
    }
    slabs.extend(SlabRange::new(near, f64::INFINITY));
    slabs
}

/// A new boundary: the median log depth of the slab (between `bounds`) that holds the most
/// binned surface, if that median lies strictly inside it.
fn split_depth(hist: &DepthHistogram, bounds: &[f64]) -> Option<f64> {
    let mut edges = vec![0.0];
    let mut sorted = bounds.to_vec();
    sorted.sort_by(f64::total_cmp);
    edges.extend(sorted);
    edges.push(f64::INFINITY);
    let bins_in = |lo: f64, hi: f64| -> Vec<usize> {
        (0..hist.bins())
            .filter(|&i| {
                let c = hist.centre_m(i);
                c > lo && c < hi
            })
            .collect()
    };
    let (lo, hi) = edges.windows(2).map(|w| (w[0], w[1])).max_by(|a, b| {
        let w = |r: &(f64, f64)| {
            bins_in(r.0, r.1)
                .iter()
                .map(|&i| hist.weights[i])
                .sum::<f64>()
        };
        w(a).total_cmp(&w(b))
    })?;
    let bins = bins_in(lo, hi);
    let total: f64 = bins.iter().map(|&i| hist.weights[i]).sum();
    let mut acc = 0.0;
    for &i in &bins {
        acc += hist.weights[i];
        if acc >= total / 2.0 {
            let d = hist.centre_m(i);
            return (d > lo && d < hi && total > 0.0).then_some(d);
        }
    }
    None
}

fn find_candidates(hist: &DepthHistogram, smooth: &[f64], valley_ratio: f64) -> Vec<Cand> {
    let n = hist.bins();
    let w = &hist.weights;
    let first = w.iter().position(|&v| v > 0.0).unwrap_or(0);
    let last = w.iter().rposition(|&v| v > 0.0).unwrap_or(0);
    let mut out = Vec::new();
    // Split [first, last] into runs of non-empty bins separated by empty gaps.
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut i = first;
    while i <= last {
        let start = i;
        while i <= last && w[i] > 0.0 {
            i += 1;
        }
        runs.push((start, i));
        let gap_start = i;
        while i <= last && w[i] <= 0.0 {
            i += 1;
        }
        if i <= last && i > gap_start {
            // Boundary in the middle of the gap (geometric mean of its edges).
            let depth = (hist.edge_m(gap_start) * hist.edge_m(i)).sqrt();
            out.push(Cand {
                kind: "gap",
                bin: (gap_start + i) / 2,
                depth_m: depth,
                ratio: 0.0,
            });
        }
    }
    for (a, b) in runs {
        // Local minima inside the run with enough prominence on both sides.
        for j in a + 1..b.saturating_sub(1) {
            if !(smooth[j] < smooth[j - 1] && smooth[j] <= smooth[j + 1]) {
                continue;
            }
            let left = smooth[a..j].iter().cloned().fold(0.0, f64::max);
            let right = smooth[j + 1..b].iter().cloned().fold(0.0, f64::max);
            let peak = left.min(right);
            if peak > 0.0 && smooth[j] <= valley_ratio * peak {
                out.push(Cand {
                    kind: "valley",
                    bin: j,
                    depth_m: hist.centre_m(j),
                    ratio: smooth[j] / peak,
                });
            }
        }
    }
    out.sort_by_key(|c| c.bin);
    out.dedup_by_key(|c| c.bin);
    debug_assert!(out.iter().all(|c| c.bin < n));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The left third of every face at `near` (a wall edge in front of a far surface),
    /// everything else at `far`.
    fn two_depths(n: u32, near: f32, far: f32) -> CubeMap<f32> {
        CubeMap::from_fn(n, |_, x, _| if x < n / 3 { near } else { far })
    }

    #[test]
    fn close_clusters_with_long_baseline_get_two_slabs() {
        let m = two_depths(16, 2.0, 50.0);
        let c = choose(&[m], 4.0, 256, &ChooseParams::default());
        assert_eq!(c.slabs.len(), 2, "{:#?}", c.criterion);
        assert!(c.slabs[0].near == 0.0 && c.slabs[0].far > 2.0 && c.slabs[0].far < 50.0);
        assert_eq!(c.slabs[1].far, f64::INFINITY);
        let acc: Vec<_> = c
            .criterion
            .candidates
            .iter()
            .filter(|c| c.accepted)
            .collect();
        assert_eq!(acc.len(), 1);
        // (B/2)(1/2 − 1/50) = 0.96 rad, far above one pixel.
        assert!((acc[0].parallax_rad - 2.0 * (0.5 - 0.02)).abs() < 0.1);
    }

    #[test]
    fn maps_read_one_at_a_time_give_the_choice_of_all_at_once() {
        let maps = [
            two_depths(16, 2.0, 50.0),
            two_depths(16, 3.0, 40.0),
            CubeMap::from_fn(16, |f, x, y| {
                if f == tracks::Face::PosY {
                    f32::INFINITY
                } else {
                    1.0 + (x * y) as f32 * 0.5
                }
            }),
        ];
        for spacing in [4.0, 0.0, f64::INFINITY] {
            let all = choose(&maps, spacing, 256, &ChooseParams::default());
            let mut reads = 0;
            let one = choose_streamed(
                maps.len(),
                |k| {
                    reads += 1;
                    Ok::<_, ()>(maps[k].clone())
                },
                spacing,
                256,
                &ChooseParams::default(),
            )
            .unwrap();
            assert_eq!(one, all, "spacing {spacing}");
            assert_eq!(reads, 2 * maps.len());
        }
        // A map that cannot be read stops the choice with its error.
        let err = choose_streamed(
            2,
            |k| if k == 1 { Err(k) } else { Ok(maps[0].clone()) },
            4.0,
            256,
            &ChooseParams::default(),
        );
        assert_eq!(err.unwrap_err(), 1);
    }

    #[test]
    fn distant_clusters_or_no_baseline_need_one_slab() {
        let m = two_depths(16, 1000.0, 5000.0);
        // (0.5)(1e-3 − 2e-4) = 4e-4 rad < (π/2)/256 = 6.1e-3 rad.
        let c = choose(std::slice::from_ref(&m), 1.0, 256, &ChooseParams::default());
        assert_eq!(c.slabs.len(), 1);
        assert!(c.criterion.candidates.iter().all(|c| !c.accepted));
        assert!(!c.criterion.candidates.is_empty());
        let single = choose(
            &[two_depths(16, 2.0, 50.0)],
            0.0,
            256,
            &ChooseParams::default(),
        );
        assert_eq!(single.slabs.len(), 1);
    }

    #[test]
    fn fewer_and_more_move_one_boundary() {
        // Three depth clusters, two boundaries between them.
        let m = CubeMap::from_fn(24, |_, x, _| match x {
            0..8 => 2.0,
            8..16 => 12.0,
            _ => 200.0,
        });
        let c = choose(&[m], 4.0, 512, &ChooseParams::default());
        assert_eq!(c.slabs.len(), 3, "{:#?}", c.criterion);
        let fewer = adjust(&c, -1);
        assert_eq!(fewer.len(), 2);
        assert!(fewer
            .iter()
            .all(|s| c.slabs.iter().any(|t| t.near == s.near)));
        let more = adjust(&c, 1);
        assert_eq!(more.len(), 4, "{more:?}");
        for w in more.windows(2) {
            assert_eq!(w[0].far, w[1].near);
        }
        assert_eq!(adjust(&c, 0), c.slabs);
        // Never below one slab.
        assert_eq!(adjust(&c, -5).len(), 1);
    }

    #[test]
    fn higher_resolution_needs_more_slabs() {
        let m = two_depths(16, 100.0, 200.0);
        // δ = 0.5 · 0.005 = 2.5e-3 rad: below a pixel at N = 256, above at N = 2048.
        let lo = choose(std::slice::from_ref(&m), 1.0, 256, &ChooseParams::default());
        let hi = choose(&[m], 1.0, 2048, &ChooseParams::default());
        assert_eq!((lo.slabs.len(), hi.slabs.len()), (1, 2));
    }
}
