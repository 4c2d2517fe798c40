//! Where tracks join and where they only nearly do: the points two tracks share, and the
//! near misses refused (see the module docs of [`super`]).

use glam::DVec3;

use super::{Shared, JOIN_TOLERANCE_M, JUNCTION_CLEARANCE_M, NEAR_MISS_M};
use crate::track::{Track, TrackError};

/// Closest point to `p` on the polyline `curve` (arc lengths `arcs`): distance and arc length.
pub(super) fn closest_on_curve(curve: &[DVec3], arcs: &[f64], p: DVec3) -> (f64, f64) {
    let mut best = (f64::INFINITY, 0.0);
    for (i, w) in curve.windows(2).enumerate() {
        let d = w[1] - w[0];
        let l2 = d.length_squared();
        let t = if l2 > 0.0 {
            ((p - w[0]).dot(d) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = w[0] + d * t;
        let dist = q.distance(p);
        if dist < best.0 {
            best = (dist, arcs[i] + t * (arcs[i + 1] - arcs[i]));
        }
    }
    best
}

/// The box of a curve grown by `margin`.
pub(super) fn bounds(curve: &[DVec3], margin: f64) -> (DVec3, DVec3) {
    let lo = curve.iter().fold(DVec3::INFINITY, |a, &p| a.min(p)) - DVec3::splat(margin);
    let hi = curve.iter().fold(DVec3::NEG_INFINITY, |a, &p| a.max(p)) + DVec3::splat(margin);
    (lo, hi)
}

pub(super) fn overlap(a: (DVec3, DVec3), b: (DVec3, DVec3)) -> bool {
    a.0.cmple(b.1).all() && b.0.cmple(a.1).all()
}

/// Every point two tracks share: a control point of one within the join tolerance of
/// another's curve, and both ends of a loop. Points within the tolerance of each other are one.
pub(super) fn shared_points(tracks: &[Track]) -> Result<Vec<Shared>, TrackError> {
    let boxes: Vec<(DVec3, DVec3)> = tracks
        .iter()
        .map(|t| bounds(t.curve(), NEAR_MISS_M))
        .collect();
    let mut shared: Vec<Shared> = Vec::new();
    let mut add = |p: DVec3, ti: usize, s: f64| {
        let k = match shared
            .iter()
            .position(|x| x.position.distance(p) <= JOIN_TOLERANCE_M)
        {
            Some(k) => k,
            None => {
                shared.push(Shared {
                    position: p,
                    at: Vec::new(),
                });
                shared.len() - 1
            }
        };
        let at = &mut shared[k].at;
        if !at
            .iter()
            .any(|&(t, s2)| t == ti && (s2 - s).abs() <= JOIN_TOLERANCE_M)
        {
            at.push((ti, s));
        }
    };
    for (a, ta) in tracks.iter().enumerate() {
        for (i, &p) in ta.points.iter().enumerate() {
            for (b, tb) in tracks.iter().enumerate() {
                if a == b || !overlap(boxes[a], boxes[b]) {
                    continue;
                }
                let (d, sb) = closest_on_curve(tb.curve(), tb.curve_arcs(), p);
                if d <= JOIN_TOLERANCE_M {
                    add(p, a, ta.point_arc(i));
                    add(p, b, sb);
                }
            }
        }
        // A loop: its last point is its first.
        let (first, last) = (ta.points[0], ta.points[ta.points.len() - 1]);
        if ta.points.len() > 2 && first.distance(last) <= JOIN_TOLERANCE_M {
            add(first, a, 0.0);
            add(first, a, ta.length());
        }
    }
    // A point shared with itself only (a control point on its own track) is no junction.
    shared.retain(|x| x.at.len() > 1);
    Ok(shared)
}

/// Refuses control points near another track but not on it, and tracks that pass close to
/// each other (or cross) away from their shared points.
pub(super) fn check_near_misses(tracks: &[Track], shared: &[Shared]) -> Result<(), TrackError> {
    let boxes: Vec<(DVec3, DVec3)> = tracks
        .iter()
        .map(|t| bounds(t.curve(), NEAR_MISS_M))
        .collect();
    let clear = |p: DVec3| {
        shared
            .iter()
            .all(|x| x.position.distance(p) > JUNCTION_CLEARANCE_M)
    };
    let refuse = |t: &Track, message: String| TrackError::Invalid {
        source_name: t.origin().source_name.clone(),
        line: t.origin().line,
        track: t.name.clone(),
        field: "points",
        message,
    };
    for (a, ta) in tracks.iter().enumerate() {
        for (b, tb) in tracks.iter().enumerate() {
            if a == b || !overlap(boxes[a], boxes[b]) {
                continue;
            }
            for (i, &p) in ta.points.iter().enumerate() {
                let (d, _) = closest_on_curve(tb.curve(), tb.curve_arcs(), p);
                if d > JOIN_TOLERANCE_M && d < NEAR_MISS_M && clear(p) {
                    return Err(refuse(
                        ta,
                        format!(
                            "point {i} {p} is {d:.4} m from track `{}` ({}): tracks meet only \
                             where a point of one lies on the other (within {} m); move it onto \
                             `{}` or at least {NEAR_MISS_M} m away",
                            tb.name,
                            tb.origin(),
                            JOIN_TOLERANCE_M,
                            tb.name
                        ),
                    ));
                }
            }
            if b < a {
                continue;
            }
            for wa in ta.curve().windows(2) {
                if !overlap(bounds(wa, NEAR_MISS_M), boxes[b]) {
                    continue;
                }
                for wb in tb.curve().windows(2) {
                    let (d, pa, _) = closest_between_segments(wa[0], wa[1], wb[0], wb[1]);
                    if d < NEAR_MISS_M && clear(pa) {
                        let what = if d <= JOIN_TOLERANCE_M {
                            "crosses".to_string()
                        } else {
                            format!("passes {d:.4} m from")
                        };
                        return Err(refuse(
                            ta,
                            format!(
                                "{what} track `{}` ({}) at {pa} with no point they share there: \
                                 add the crossing point to one of them, or keep them at least \
                                 {NEAR_MISS_M} m apart",
                                tb.name,
                                tb.origin()
                            ),
                        ));
                    }
                }
            }
        }
    }
    Ok(())
}

/// Closest points of segments `p1 q1` and `p2 q2`: their distance and the points.
pub(super) fn closest_between_segments(
    p1: DVec3,
    q1: DVec3,
    p2: DVec3,
    q2: DVec3,
) -> (f64, DVec3, DVec3) {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    let (s, t);
    if a <= 1e-24 && e <= 1e-24 {
        return (p1.distance(p2), p1, p2);
    }
    if a <= 1e-24 {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(r);
        if e <= 1e-24 {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let s0 = if denom > 1e-24 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            } else {
                t = t0;
                s = s0;
            }
        }
    }
    let (c1, c2) = (p1 + d1 * s, p2 + d2 * t);
    (c1.distance(c2), c1, c2)
}
