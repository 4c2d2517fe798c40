//! Where an arc length falls on a track, and how the two reference views around it are
//! blended: the one rule every crate uses (the renderer, the streaming client's visibility
//! estimate and prefetch, the walk simulator, the culling's cells).
//!
//! - [`locate`]: the piece of a sorted list of arc lengths that holds `s` and the fraction
//!   along it;
//! - [`point_at`] / [`arc_lengths`]: positions on a polyline by arc length;
//! - [`smooth_weight`], [`blend_pair`], [`blend_weights`]: the blend of the two views
//!   around `s`, smoothstep across each segment;
//! - [`segment_at`]: the segment that holds `s`.
//!
//! ```
//! use tracks::segment::{blend_weights, locate, segment_at};
//! let arcs = [0.0, 5.0, 10.0];
//! let at = locate(&arcs, 7.5).unwrap();
//! assert_eq!((at.index, at.t), (1, 0.5));
//! assert_eq!(segment_at(&arcs, 7.5), Some(1));
//! // Half way along a segment both views weigh the same; at its ends one view alone.
//! assert_eq!(blend_weights(&arcs, 7.5), vec![(1, 0.5), (2, 0.5)]);
//! assert_eq!(blend_weights(&arcs, 5.0), vec![(1, 1.0), (2, 0.0)]);
//! ```

use glam::DVec3;

/// Where an arc length lies among sorted arc lengths: on the piece from `index` to
/// `index + 1`, at fraction `t ∈ [0, 1]` of its length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentPos {
    pub index: usize,
    pub t: f64,
}

/// The piece of `arcs` (sorted, non-decreasing) that holds `s`: the last arc length not
/// above `s` starts it (the first piece before the track, the last one after it), and `t`
/// is the fraction along it, clamped to `[0, 1]` (0 on a zero-length piece or for a NaN
/// `s`). `None` with fewer than two arc lengths.
pub fn locate(arcs: &[f64], s: f64) -> Option<SegmentPos> {
    let n = arcs.len();
    if n < 2 {
        return None;
    }
    let s = if s.is_nan() { arcs[0] } else { s };
    let index = arcs
        .partition_point(|&a| a <= s)
        .saturating_sub(1)
        .min(n - 2);
    let (a0, a1) = (arcs[index], arcs[index + 1]);
    let t = if a1 > a0 {
        ((s - a0) / (a1 - a0)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some(SegmentPos { index, t })
}

/// Index of the segment holding `s` ([`locate`]'s piece): segment `i` spans
/// `[arcs[i], arcs[i + 1]]`. `None` when there is no segment.
pub fn segment_at(arcs: &[f64], s: f64) -> Option<usize> {
    locate(arcs, s).map(|p| p.index)
}

/// Cumulative arc lengths of a polyline (0 at its first vertex).
pub fn arc_lengths(curve: &[DVec3]) -> Vec<f64> {
    let mut arc = Vec::with_capacity(curve.len());
    let mut s = 0.0;
    for (i, p) in curve.iter().enumerate() {
        if i > 0 {
            s += curve[i - 1].distance(*p);
        }
        arc.push(s);
    }
    arc
}

/// Position at arc length `s` on a polyline whose vertices have arc lengths `arc`
/// ([`arc_lengths`]); clamped to its ends.
pub fn point_at(curve: &[DVec3], arc: &[f64], s: f64) -> DVec3 {
    match locate(&arc[..arc.len().min(curve.len())], s) {
        Some(p) => curve[p.index].lerp(curve[p.index + 1], p.t),
        None => curve.first().copied().unwrap_or(DVec3::ZERO),
    }
}

/// The smooth blend weight of the second view at fraction `t ∈ [0, 1]` of a segment:
/// `3t² − 2t³` (smoothstep). It is exactly 0 and 1 at the reference samples, so a reference
/// sample is reproduced by its own view alone; its slope vanishes there, so the image changes
/// slowly near samples, where the reference view is most accurate, and the weights are C¹
/// across samples (no visible kink when a segment ends and the next begins). A linear ramp
/// would be exact at samples too but kinks there; a nearest-view switch would pop.
pub fn smooth_weight(t: f64) -> f64 {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    t * t * (3.0 - 2.0 * t)
}

/// The two views around arc length `s` and the weight of the second, `(a, b, w_b)`: the
/// segment's first view and its second weighted by [`smooth_weight`]; past the end of the
/// track the last view alone (`(n − 1, n − 2, 0)`), before its start the first alone. One
/// view: `(0, 0, 0)`; none: `None`.
pub fn blend_pair(arcs: &[f64], s: f64) -> Option<(usize, usize, f64)> {
    match arcs.len() {
        0 => None,
        1 => Some((0, 0, 0.0)),
        _ => {
            let p = locate(arcs, s)?;
            if p.t >= 1.0 {
                Some((p.index + 1, p.index, 0.0))
            } else {
                Some((p.index, p.index + 1, smooth_weight(p.t)))
            }
        }
    }
}

/// The blend weights of the two views bounding the segment that holds `s`, in segment
/// order: `[(i, 1 − w), (i + 1, w)]` with `w` = [`smooth_weight`] of the fraction along it
/// (the same weights [`blend_pair`] gives); the single view of a one-view track.
pub fn blend_weights(arcs: &[f64], s: f64) -> Vec<(usize, f64)> {
    match arcs.len() {
        0 => Vec::new(),
        1 => vec![(0, 1.0)],
        _ => match locate(arcs, s) {
            Some(p) => {
                let w = smooth_weight(p.t);
                vec![(p.index, 1.0 - w), (p.index + 1, w)]
            }
            None => Vec::new(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_follows_the_segments_and_clamps_outside() {
        let arcs = [0.0, 2.0, 5.0, 5.0, 9.0];
        assert_eq!(locate(&arcs, -1.0), Some(SegmentPos { index: 0, t: 0.0 }));
        assert_eq!(locate(&arcs, 1.0), Some(SegmentPos { index: 0, t: 0.5 }));
        assert_eq!(locate(&arcs, 2.0), Some(SegmentPos { index: 1, t: 0.0 }));
        // A zero-length piece is skipped over: 5.0 starts the last one.
        assert_eq!(locate(&arcs, 5.0), Some(SegmentPos { index: 3, t: 0.0 }));
        assert_eq!(locate(&arcs, 7.0), Some(SegmentPos { index: 3, t: 0.5 }));
        assert_eq!(locate(&arcs, 99.0), Some(SegmentPos { index: 3, t: 1.0 }));
        assert_eq!(
            locate(&arcs, f64::NAN),
            Some(SegmentPos { index: 0, t: 0.0 })
        );
        assert_eq!(locate(&[1.0], 1.0), None);
        assert_eq!(locate(&[], 1.0), None);
        assert_eq!(segment_at(&[0.0, 5.0, 10.0, 15.0], 15.0), Some(2));
    }

    #[test]
    fn points_on_a_polyline_by_arc_length() {
        let curve = [DVec3::ZERO, DVec3::X * 3.0, DVec3::new(3.0, 0.0, 4.0)];
        let arc = arc_lengths(&curve);
        assert_eq!(arc, vec![0.0, 3.0, 7.0]);
        assert_eq!(point_at(&curve, &arc, 1.5), DVec3::X * 1.5);
        assert_eq!(point_at(&curve, &arc, 5.0), DVec3::new(3.0, 0.0, 2.0));
        assert_eq!(point_at(&curve, &arc, -4.0), DVec3::ZERO);
        assert_eq!(point_at(&curve, &arc, 40.0), curve[2]);
        assert_eq!(point_at(&curve[..1], &arc[..1], 2.0), DVec3::ZERO);
    }

    #[test]
    fn the_blend_is_smoothstep_and_both_forms_agree() {
        assert_eq!(smooth_weight(0.0), 0.0);
        assert_eq!(smooth_weight(1.0), 1.0);
        assert_eq!(smooth_weight(0.5), 0.5);
        assert!((smooth_weight(0.25) - 0.15625).abs() < 1e-12);
        assert_eq!(smooth_weight(f64::NAN), 0.0);
        let arcs = [0.0, 2.5, 5.0];
        assert_eq!(blend_pair(&arcs, 2.5), Some((1, 2, 0.0)));
        let (a, b, w) = blend_pair(&arcs, 3.125).unwrap();
        assert_eq!((a, b), (1, 2));
        assert!((w - 0.15625).abs() < 1e-12);
        assert_eq!(blend_pair(&arcs, -3.0), Some((0, 1, 0.0)));
        assert_eq!(blend_pair(&arcs, 5.0), Some((2, 1, 0.0)));
        assert_eq!(blend_pair(&arcs, 99.0), Some((2, 1, 0.0)));
        assert_eq!(blend_pair(&[4.0], 1.0), Some((0, 0, 0.0)));
        assert_eq!(blend_pair(&[], 1.0), None);
        // The weights of the pair and of the list are the same weights.
        for k in 0..=60 {
            let s = -0.5 + k as f64 * 0.1;
            let (a, b, w) = blend_pair(&arcs, s).unwrap();
            let list = blend_weights(&arcs, s);
            let weight_of = |v: usize| list.iter().find(|x| x.0 == v).map_or(0.0, |x| x.1);
            assert!((weight_of(b) - w).abs() < 1e-12, "s {s}");
            assert!((weight_of(a) - (1.0 - w)).abs() < 1e-12, "s {s}");
        }
        assert_eq!(blend_weights(&[3.0], 0.0), vec![(0, 1.0)]);
        assert!(blend_weights(&[], 0.0).is_empty());
    }
}
