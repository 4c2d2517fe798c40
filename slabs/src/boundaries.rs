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
//! The candidates are (a) runs of empty bins between finite depths and (b) local minima of
//! the smoothed histogram that are at most `valley_ratio` of the lower of the two peaks on
//! either side. Starting from all candidates, the one with the smallest parallax is removed
//! (merging its two clusters, whose representative depth is the merged mode) while it fails
//! the test, so the result is the fewest boundaries that all pass.

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
}

impl Default for ChooseParams {
    fn default() -> Self {
        ChooseParams {
            bins: 128,
            smoothing_passes: 2,
            valley_ratio: 0.5,
            threshold_px: 1.0,
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
    pub accepted: bool,
    pub reason: String,
}

/// The criterion's numbers: what a report prints to say why the slabs are what they are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CriterionReport {
    /// Longest segment `B` of the track, metres.
    pub max_spacing_m: f64,
    /// `B/2`: how far a viewer gets from its nearest reference viewpoint.
    pub half_baseline_m: f64,
    pub face_size: u32,
    /// `(π/2)/N`.
    pub theta_pixel_rad: f64,
    pub threshold_px: f64,
    /// Candidates nearest first.
    pub candidates: Vec<Candidate>,
    /// Fraction of the average panorama's solid angle that is sky.
    pub sky_fraction: f64,
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
    choose_from_histogram(hist, max_spacing_m, face_size, params)
}

/// [`choose`] on a histogram already built.
pub fn choose_from_histogram(
    hist: DepthHistogram,
    max_spacing_m: f64,
    face_size: u32,
    params: &ChooseParams,
) -> SlabChoice {
    let b = if max_spacing_m.is_finite() {
        max_spacing_m.max(0.0)
    } else {
        0.0
    };
    let theta = theta_pixel(face_size);
    let all = hist.total() + hist.sky_sr + hist.invalid_sr;
    let mut report = CriterionReport {
        max_spacing_m: b,
        half_baseline_m: b / 2.0,
        face_size,
        theta_pixel_rad: theta,
        threshold_px: params.threshold_px,
        candidates: Vec::new(),
        sky_fraction: if all > 0.0 { hist.sky_sr / all } else { 0.0 },
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
    let mode_depth = |lo: usize, hi: usize| -> f64 {
        // Mode of bins lo..hi (exclusive) by the raw weights; fall back to the centre.
        let mut best = (lo, -1.0);
        for i in lo..hi {
            if hist.weights[i] > best.1 {
                best = (i, hist.weights[i]);
            }
        }
        hist.centre_m(best.0)
    };
    // Live candidates; repeatedly drop the weakest failing one.
    let mut live: Vec<usize> = (0..cands.len()).collect();
    let mut decided: Vec<Option<Candidate>> = (0..cands.len()).map(|_| None).collect();
    let evaluate = |live: &[usize], k: usize| -> (f64, f64, f64) {
        let c = &cands[live[k]];
        let lo = if k == 0 {
            0
        } else {
            cands[live[k - 1]].bin + 1
        };
        let hi = if k + 1 == live.len() {
            hist.bins()
        } else {
            cands[live[k + 1]].bin
        };
        let near = mode_depth(lo, c.bin.max(lo + 1).min(hist.bins()));
        let far = mode_depth(
            (c.bin + 1).min(hi.saturating_sub(1)),
            hi.max(c.bin + 2).min(hist.bins()),
        );
        (near, far, cluster_parallax_rad(b / 2.0, near, far))
    };
    loop {
        let mut weakest: Option<(usize, f64, f64, f64)> = None;
        for k in 0..live.len() {
            let (near, far, p) = evaluate(&live, k);
            if weakest.is_none_or(|w| p < w.3) {
                weakest = Some((k, near, far, p));
            }
        }
        let Some((k, near, far, p)) = weakest else {
            break;
        };
        let px = p / theta;
        if px > params.threshold_px {
            break;
        }
        let c = &cands[live[k]];
        decided[live[k]] = Some(Candidate {
            kind: c.kind.into(),
            depth_m: c.depth_m,
            near_cluster_m: near,
            far_cluster_m: far,
            parallax_rad: p,
            parallax_px: px,
            valley_depth_ratio: c.ratio,
            accepted: false,
            reason: format!(
                "parallax {px:.3} px <= {} px: nothing behind {near:.3} m is revealed within {:.3} m of a viewpoint",
                params.threshold_px,
                b / 2.0
            ),
        });
        live.remove(k);
    }
    for k in 0..live.len() {
        let (near, far, p) = evaluate(&live, k);
        let c = &cands[live[k]];
        let px = p / theta;
        decided[live[k]] = Some(Candidate {
            kind: c.kind.into(),
            depth_m: c.depth_m,
            near_cluster_m: near,
            far_cluster_m: far,
            parallax_rad: p,
            parallax_px: px,
            valley_depth_ratio: c.ratio,
            accepted: true,
            reason: format!(
                "parallax {px:.3} px > {} px: surfaces near {far:.3} m can be disoccluded behind {near:.3} m",
                params.threshold_px
            ),
        });
    }
    report.candidates = decided.into_iter().flatten().collect();
    let mut slabs = Vec::new();
    let mut near = 0.0;
    for &k in &live {
        let d = cands[k].depth_m;
        if let Some(r) = SlabRange::new(near, d) {
            slabs.push(r);
            near = d;
        }
    }
    slabs.extend(SlabRange::new(near, f64::INFINITY));
    report.summary = format!(
        "{} slab(s) from {} candidate valley(s): B/2 = {:.3} m, θ_pixel = {:.3e} rad (N = {}), threshold {} px",
        slabs.len(),
        cands.len(),
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
    use tracks::Face;

    /// Faces ±x at `near`, everything else at `far`.
    fn two_depths(n: u32, near: f32, far: f32) -> CubeMap<f32> {
        CubeMap::from_fn(n, |f, _, _| {
            if matches!(f, Face::PosX | Face::NegX) {
                near
            } else {
                far
            }
        })
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
    fn distant_clusters_or_no_baseline_need_one_slab() {
        let m = two_depths(16, 1000.0, 5000.0);
        // (0.5)(1e-3 − 2e-4) = 4e-4 rad < (π/2)/256 = 6.1e-3 rad.
        let c = choose(&[m.clone()], 1.0, 256, &ChooseParams::default());
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
    fn higher_resolution_needs_more_slabs() {
        let m = two_depths(16, 100.0, 200.0);
        // δ = 0.5 · 0.005 = 2.5e-3 rad: below a pixel at N = 256, above at N = 2048.
        let lo = choose(&[m.clone()], 1.0, 256, &ChooseParams::default());
        let hi = choose(&[m], 1.0, 2048, &ChooseParams::default());
        assert_eq!((lo.slabs.len(), hi.slabs.len()), (1, 2));
    }
}
