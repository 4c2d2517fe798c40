//! Segments against solids shrunk by a distance that varies along the segment: the query
//! behind occluder shrinking (Wonka, Wimmer & Schmalstieg 2000) in the culling crate.
//!
//! A solid eroded by `e` is the set of its points whose distance to its outside exceeds `e`.
//! For the convex solids here that is exact and simple, because each is an intersection of
//! half-spaces and eroding an intersection erodes each half-space: a box loses `e` on every
//! face; a sphere's radius shrinks by `e`; a capped cone or cylinder loses `e` at both caps and
//! `e·√(1 + k²)` of radius (`k` = change of radius per unit of height: the side's normal is
//! tilted, so a step `e` along it is a longer step across the axis).
//!
//! The functions take a line `o + s·d` (`d` unit) and an erosion `e(s) = e0 + g·s` that is
//! linear in `s`, and return an open interval of `s` within `(lo, hi)` whose points lie
//! inside the solid with inside distance greater than `e(s)` — `None` if there is none. Every
//! constraint is linear in `s` (faces, caps) or is "distance to a line or point below a
//! linear function of `s`", whose solutions form an interval (a convex function below a
//! linear one), found from a quadratic; so the answer is exact up to rounding, and callers
//! add a margin to `e` for that.

use glam::DVec3;

use crate::accel::Accel;
use crate::geom::Prim;
use crate::scene::Shape;

/// The solids of a scene as occluders for shrunk-segment queries: its boxes, spheres,
/// cylinders and cones (surfaces without volume — triangles, meshes, planes — are left out),
/// plus **fused boxes**: where two boxes touch or overlap along an axis over a common
/// cross-section, the box spanning both over that cross-section lies inside their union and
/// is added. Shrinking each solid alone loses the inside of a union (a segment running along
/// the face two buildings share is at distance 0 from each, deep inside the pair), so fused
/// boxes keep what touching solids hide together. Two rounds: rows of three fuse too.
pub struct Occluders {
    accel: Accel,
    /// Per accelerator primitive: the scene solids (indices into `solids`) whose interior a
    /// source segment must not enter for it to count — itself, or a fused box's parts.
    guards: Vec<Vec<u32>>,
    solids: Vec<Prim>,
    fused: usize,
}

impl Occluders {
    /// The occluders of `shapes`.
    pub fn new<'a>(shapes: impl IntoIterator<Item = &'a Shape>) -> Occluders {
        let mut solids = Vec::new();
        for s in shapes {
            match s {
                Shape::Box { .. } | Shape::Sphere { .. } | Shape::Cone { .. } => {
                    s.push_prims(&mut solids);
                }
                Shape::Plane { .. } | Shape::Triangle { .. } | Shape::Mesh(_) => {}
            }
        }
        let boxes: Vec<(usize, (DVec3, DVec3))> = solids
            .iter()
            .enumerate()
            .filter_map(|(i, p)| match *p {
                Prim::Box { min, max } => Some((i, (min, max))),
                _ => None,
            })
            .collect();
        let just: Vec<(DVec3, DVec3)> = boxes.iter().map(|b| b.1).collect();
        let fused = fuse_boxes(&just, 2, 4 * boxes.len() + 64);
        let mut prims = solids.clone();
        let mut guards: Vec<Vec<u32>> = (0..solids.len() as u32).map(|i| vec![i]).collect();
        for (bx, parts) in &fused {
            prims.push(Prim::Box {
                min: bx.0,
                max: bx.1,
            });
            guards.push(parts.iter().map(|&k| boxes[k].0 as u32).collect());
        }
        let (accel, ids) = Accel::build(prims);
        let guards = ids.iter().map(|&i| guards[i as usize].clone()).collect();
        Occluders {
            accel,
            guards,
            solids,
            fused: fused.len(),
        }
    }

    /// Solids taken from the scene, and fused boxes added.
    pub fn counts(&self) -> (usize, usize) {
        (self.solids.len(), self.fused)
    }

    /// Whether the segment from `from` to `to` passes through the interior of an occluder
    /// shrunk by `(1 − t)·erosion_from + t·erosion_to` at its point of parameter `t`, leaving
    /// out any occluder whose interior — or, for a fused box, the interior of one of its
    /// parts — the segment `source` (a single point when both ends are equal) enters: where
    /// the viewer is inside a solid, the argument for what it cannot see does not hold.
    pub fn blocks(
        &self,
        from: DVec3,
        to: DVec3,
        erosion_from: f64,
        erosion_to: f64,
        source: (DVec3, DVec3),
    ) -> bool {
        // The source segment, widened by a hair so that a single point works too.
        let sv = source.1 - source.0;
        let slen = sv.length();
        let sd = if slen > 0.0 { sv / slen } else { DVec3::X };
        let hair = 1e-9 * (1.0 + source.0.abs().max_element());
        let enters = |k: u32| {
            self.solids[k as usize]
                .eroded_span(source.0, sd, (-hair, slen + hair), 0.0, 0.0)
                .is_some()
        };
        self.accel
            .solid_blocks(from, to, erosion_from, erosion_to, |id| {
                self.guards[id].iter().any(|&k| enters(k))
            })
    }
}

/// A box, and the indices (into the input) of the boxes whose union holds it.
type Fused = ((DVec3, DVec3), Vec<usize>);

/// Boxes inside the union of touching or overlapping pairs of `boxes` (and, for `rounds`
/// above 1, of those with the boxes again), at most `cap` of them, none equal to or inside
/// a box already there, each with the input boxes it is made of. Deterministic: the order
/// of the input decides the order out.
fn fuse_boxes(boxes: &[(DVec3, DVec3)], rounds: usize, cap: usize) -> Vec<Fused> {
    let inside =
        |a: &(DVec3, DVec3), b: &(DVec3, DVec3)| a.0.cmpge(b.0).all() && a.1.cmple(b.1).all();
    let mut all: Vec<Fused> = boxes
        .iter()
        .enumerate()
        .map(|(i, b)| (*b, vec![i]))
        .collect();
    let mut out: Vec<Fused> = Vec::new();
    let mut frontier: Vec<Fused> = all.clone();
    for _ in 0..rounds {
        let mut next: Vec<Fused> = Vec::new();
        // Sweep along x: only boxes whose x ranges meet can fuse.
        let mut order: Vec<usize> = (0..all.len()).collect();
        order.sort_by(|&i, &j| all[i].0 .0.x.total_cmp(&all[j].0 .0.x).then(i.cmp(&j)));
        for (f, fparts) in &frontier {
            for &j in &order {
                let (b, bparts) = &all[j];
                if b.0.x > f.1.x {
                    break;
                }
                if b.1.x < f.0.x || (b.0 == f.0 && b.1 == f.1) {
                    continue;
                }
                for k in 0..3 {
                    let (o1, o2) = ((k + 1) % 3, (k + 2) % 3);
                    // Touching or overlapping along k; a common cross-section of positive area.
                    if f.0[k] > b.1[k] || b.0[k] > f.1[k] {
                        continue;
                    }
                    let mut lo = f.0.max(b.0);
                    let mut hi = f.1.min(b.1);
                    if !(hi[o1] > lo[o1] && hi[o2] > lo[o2]) {
                        continue;
                    }
                    lo[k] = f.0[k].min(b.0[k]);
                    hi[k] = f.1[k].max(b.1[k]);
                    let c = (lo, hi);
                    if all.iter().chain(&next).any(|a| inside(&c, &a.0)) {
                        continue;
                    }
                    let mut parts = fparts.clone();
                    parts.extend(bparts.iter().filter(|p| !fparts.contains(p)));
                    next.push((c, parts));
                    if out.len() + next.len() >= cap {
                        out.extend(next);
                        return out;
                    }
                }
            }
        }
        if next.is_empty() {
            break;
        }
        all.extend(next.iter().cloned());
        out.extend(next.iter().cloned());
        frontier = next;
    }
    out
}

/// An open interval of the line parameter.
pub type Span = (f64, f64);

/// The part of `(lo, hi)` where `a·s > c` (all of it, none of it, or a half-line's part).
#[inline]
fn half_line(a: f64, c: f64, span: Span) -> Span {
    let (mut lo, mut hi) = span;
    if a > 0.0 {
        lo = lo.max(c / a);
    } else if a < 0.0 {
        hi = hi.min(c / a);
    } else if c >= 0.0 {
        // 0 > c is false: nothing.
        return (0.0, 0.0);
    }
    (lo, hi)
}

/// Whether an interval is open and non-empty beyond rounding.
#[inline]
fn nonempty(span: Span) -> bool {
    let (lo, hi) = span;
    lo.is_finite() && hi.is_finite() && hi - lo > 1e-12 * (1.0 + lo.abs().max(hi.abs()))
}

/// The (up to two) open intervals where `A s² + 2B s + C < 0`.
fn below_zero(a: f64, b: f64, c: f64) -> [Option<Span>; 2] {
    const ALL: Span = (f64::NEG_INFINITY, f64::INFINITY);
    if !(a.is_finite() && b.is_finite() && c.is_finite()) {
        return [None, None];
    }
    if a == 0.0 {
        // 2B s + C < 0.
        return if b > 0.0 {
            [Some((f64::NEG_INFINITY, -c / (2.0 * b))), None]
        } else if b < 0.0 {
            [Some((-c / (2.0 * b), f64::INFINITY)), None]
        } else if c < 0.0 {
            [Some(ALL), None]
        } else {
            [None, None]
        };
    }
    let disc = b * b - a * c;
    if disc <= 0.0 {
        // No sign change: negative everywhere when the parabola opens downwards.
        return if a < 0.0 {
            [Some(ALL), None]
        } else {
            [None, None]
        };
    }
    let q = -(b + disc.sqrt().copysign(b));
    let (r0, r1) = if q == 0.0 {
        (0.0, 0.0)
    } else {
        let (x, y) = (q / a, c / q);
        (x.min(y), x.max(y))
    };
    if a > 0.0 {
        [Some((r0, r1)), None]
    } else {
        [Some((f64::NEG_INFINITY, r0)), Some((r1, f64::INFINITY))]
    }
}

/// Intersect `span` with where `|q0 + s·q1|² < (ρ0 + ρ1·s)²` and `ρ0 + ρ1·s > 0`, i.e. where
/// the distance `|q0 + s·q1|` is below `ρ0 + ρ1·s`; the first non-empty part.
fn within_distance(q0: DVec3, q1: DVec3, rho0: f64, rho1: f64, span: Span) -> Option<Span> {
    let span = half_line(rho1, -rho0, span);
    if !nonempty(span) {
        return None;
    }
    let a = q1.length_squared() - rho1 * rho1;
    let b = q0.dot(q1) - rho0 * rho1;
    let c = q0.length_squared() - rho0 * rho0;
    below_zero(a, b, c)
        .into_iter()
        .flatten()
        .map(|(x, y)| (span.0.max(x), span.1.min(y)))
        .find(|s| nonempty(*s))
}

/// Points of `o + s·d`, `s ∈ (lo, hi)`, inside the box `[min, max]` with inside distance
/// above `e0 + g·s`.
pub fn box_span(
    min: DVec3,
    max: DVec3,
    o: DVec3,
    d: DVec3,
    span: Span,
    e0: f64,
    g: f64,
) -> Option<Span> {
    let mut s = span;
    for k in 0..3 {
        // o + s d − min > e0 + g s   and   max − o − s d > e0 + g s.
        s = half_line(d[k] - g, e0 + min[k] - o[k], s);
        s = half_line(-d[k] - g, e0 + o[k] - max[k], s);
        if !nonempty(s) {
            return None;
        }
    }
    Some(s)
}

/// Points of `o + s·d` inside the ball `|x − center| < radius` with inside distance above
/// `e0 + g·s`.
pub fn sphere_span(
    center: DVec3,
    radius: f64,
    o: DVec3,
    d: DVec3,
    span: Span,
    e0: f64,
    g: f64,
) -> Option<Span> {
    within_distance(o - center, d, radius - e0, -g, span)
}

/// Points of `o + s·d` inside the capped truncated cone (a cylinder when `r0 == r1`) from
/// `base` along the unit `axis` for `height`, radius `r0` at the base and `r1` at the top,
/// with inside distance above `e0 + g·s`.
#[allow(clippy::too_many_arguments)]
pub fn cone_span(
    base: DVec3,
    axis: DVec3,
    height: f64,
    r0: f64,
    r1: f64,
    o: DVec3,
    d: DVec3,
    span: Span,
    e0: f64,
    g: f64,
) -> Option<Span> {
    let m = o - base;
    let (mz, dz) = (m.dot(axis), d.dot(axis));
    // Caps: z > e and height − z > e.
    let s = half_line(dz - g, e0 - mz, span);
    let s = half_line(-dz - g, e0 + mz - height, s);
    if !nonempty(s) {
        return None;
    }
    // Side: distance to the axis below r(z) − e·√(1 + k²).
    let k = (r1 - r0) / height;
    let c = (1.0 + k * k).sqrt();
    let rho0 = r0 + k * mz - c * e0;
    let rho1 = k * dz - c * g;
    within_distance(m - axis * mz, d - axis * dz, rho0, rho1, s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn solids_block_shrunk_and_sources_inside_them_do_not_count() {
        let one = |shape: Shape| Occluders::new([&shape]);
        let wall = one(Shape::Box {
            min: DVec3::new(-5.0, -5.0, 4.0),
            max: DVec3::new(5.0, 5.0, 5.0),
        });
        let (a, b) = (DVec3::ZERO, DVec3::new(0.0, 0.0, 10.0));
        let here = (a, a);
        // 1 m thick: shrunk by up to 0.5 m it still blocks, from both ends.
        assert!(wall.blocks(a, b, 0.0, 0.0, here));
        assert!(wall.blocks(a, b, 0.49, 0.49, here));
        assert!(!wall.blocks(a, b, 0.51, 0.51, here));
        // Erosion 0 at the start and 1 at the end: 0.45 at the wall's middle.
        assert!(wall.blocks(a, b, 0.0, 1.0, here));
        assert!(!wall.blocks(a, b, 0.0, 1.2, here));
        // Stopping short of the wall, or passing beside it: nothing.
        assert!(!wall.blocks(a, DVec3::new(0.0, 0.0, 3.9), 0.0, 0.0, here));
        assert!(!wall.blocks(a, DVec3::new(40.0, 0.0, 10.0), 0.0, 0.0, here));
        // A source segment that enters the wall leaves it out; one touching its face does not.
        let into = (DVec3::new(0.0, 0.0, 3.0), DVec3::new(0.0, 0.0, 4.2));
        assert!(!wall.blocks(a, b, 0.0, 0.0, into));
        let touching = (DVec3::new(-1.0, 0.0, 4.0), DVec3::new(1.0, 0.0, 4.0));
        assert!(wall.blocks(DVec3::new(0.0, 0.0, 3.999), b, 0.0, 0.0, touching));
        // Surfaces without volume never block.
        let tri = one(Shape::Triangle {
            a: DVec3::new(-5.0, -5.0, 4.0),
            b: DVec3::new(5.0, -5.0, 4.0),
            c: DVec3::new(0.0, 5.0, 4.0),
        });
        assert!(!tri.blocks(a, b, 0.0, 0.0, here));
        assert_eq!(tri.counts(), (0, 0));
        let cyl = one(Shape::Cone {
            base: DVec3::new(0.0, -3.0, 4.0),
            top: DVec3::new(0.0, 3.0, 4.0),
            radius_base: 0.3,
            radius_top: 0.3,
        });
        assert!(cyl.blocks(a, b, 0.29, 0.29, here));
        assert!(!cyl.blocks(a, b, 0.31, 0.29, here));
    }

    /// Two boxes sharing a face hide, together, a segment that runs along that face: the
    /// fused box spans both. Boxes a hair apart do not fuse (the gap is an opening).
    #[test]
    fn touching_boxes_fuse_and_separate_ones_do_not() {
        let bx = |x0: f64, x1: f64, y1: f64| Shape::Box {
            min: DVec3::new(x0, 0.0, 5.0),
            max: DVec3::new(x1, y1, 9.0),
        };
        // Along the shared face x = 0, from the front (z < 5) to behind (z > 9).
        let (a, b) = (DVec3::new(0.0, 1.0, 0.0), DVec3::new(0.0, 1.0, 12.0));
        let here = (a, a);
        let pair = [bx(-2.0, 0.0, 3.0), bx(0.0, 2.0, 4.0)];
        let fused = Occluders::new(pair.iter());
        assert_eq!(fused.counts(), (2, 1));
        assert!(fused.blocks(a, b, 0.5, 0.5, here));
        for s in &pair {
            assert!(!Occluders::new([s]).blocks(a, b, 0.01, 0.01, here));
        }
        // Above the lower box's top (y = 3) only one box is there: not fused.
        let high = (DVec3::new(0.0, 3.5, 0.0), DVec3::new(0.0, 3.5, 12.0));
        assert!(!fused.blocks(high.0, high.1, 0.01, 0.01, (high.0, high.0)));
        let apart = [bx(-2.0, -1e-9, 3.0), bx(0.0, 2.0, 4.0)];
        let a2 = Occluders::new(apart.iter());
        assert_eq!(a2.counts(), (2, 0));
        assert!(!a2.blocks(a, b, 0.0, 0.0, here));
        // A track inside one part leaves the fused box out too (the viewer is inside a solid).
        let inside_low = (DVec3::new(-1.0, 1.0, 6.0), DVec3::new(-1.0, 1.0, 6.0));
        assert!(!fused.blocks(a, b, 0.5, 0.5, inside_low));
        // A row of three fuses end to end in the second round.
        // Each 1 m wide: a pair leaves 1 m of clearance, the row 1.5 m.
        let row = [bx(-1.5, -0.5, 3.0), bx(-0.5, 0.5, 3.0), bx(0.5, 1.5, 3.0)];
        let (c, d) = (DVec3::new(-2.0, 1.5, 7.0), DVec3::new(2.0, 1.5, 7.0));
        assert!(Occluders::new(row.iter()).blocks(c, d, 1.2, 1.2, (c, c)));
        assert!(!Occluders::new(row[..2].iter()).blocks(c, d, 1.2, 1.2, (c, c)));
    }

    fn inside_box(min: DVec3, max: DVec3, p: DVec3) -> f64 {
        (p - min).min(max - p).min_element()
    }

    #[test]
    fn box_erosion_moves_every_face() {
        let (min, max) = (DVec3::new(0.0, -1.0, -1.0), DVec3::new(2.0, 1.0, 1.0));
        // Along x through the middle: inside for x ∈ (0, 2); eroded by 0.5: (0.5, 1.5).
        let o = DVec3::new(-3.0, 0.0, 0.0);
        let s = box_span(min, max, o, DVec3::X, (0.0, 10.0), 0.5, 0.0).unwrap();
        assert!(
            (s.0 - 3.5).abs() < 1e-12 && (s.1 - 4.5).abs() < 1e-12,
            "{s:?}"
        );
        // Eroded by 1 (half the thickness) nothing is left.
        assert!(box_span(min, max, o, DVec3::X, (0.0, 10.0), 1.0, 0.0).is_none());
        // Erosion growing along the ray: e(s) = 0.1 s: inside distance min(x, 2 − x, 1) with
        // x = s − 3 exceeds 0.1 s for s ∈ (10/3, 50/11).
        let s = box_span(min, max, o, DVec3::X, (0.0, 10.0), 0.0, 0.1).unwrap();
        assert!(
            (s.0 - 10.0 / 3.0).abs() < 1e-12 && (s.1 - 50.0 / 11.0).abs() < 1e-12,
            "{s:?}"
        );
        // The span is cut to (lo, hi).
        let s = box_span(min, max, o, DVec3::X, (0.0, 4.0), 0.5, 0.0).unwrap();
        assert!((s.1 - 4.0).abs() < 1e-12);
        assert!(box_span(min, max, o, DVec3::X, (0.0, 3.4), 0.5, 0.0).is_none());
    }

    #[test]
    fn spheres_and_cylinders_shrink_by_the_erosion() {
        let o = DVec3::new(-5.0, 0.0, 0.0);
        let s = sphere_span(DVec3::ZERO, 2.0, o, DVec3::X, (0.0, 100.0), 0.5, 0.0).unwrap();
        assert!(
            (s.0 - 3.5).abs() < 1e-12 && (s.1 - 6.5).abs() < 1e-12,
            "{s:?}"
        );
        assert!(sphere_span(DVec3::ZERO, 2.0, o, DVec3::X, (0.0, 100.0), 2.0, 0.0).is_none());
        // A cylinder of radius 1 along y from 0 to 4, crossed sideways at height y.
        let cyl = |e: f64, y: f64| {
            cone_span(
                DVec3::ZERO,
                DVec3::Y,
                4.0,
                1.0,
                1.0,
                DVec3::new(-5.0, y, 0.0),
                DVec3::X,
                (0.0, 100.0),
                e,
                0.0,
            )
        };
        let s = cyl(0.25, 2.0).unwrap();
        assert!(
            (s.0 - 4.25).abs() < 1e-12 && (s.1 - 5.75).abs() < 1e-12,
            "{s:?}"
        );
        // 0.3 from the cap: an erosion of 0.3 or more leaves nothing there.
        assert!(cyl(0.29, 3.7).is_some());
        assert!(cyl(0.31, 3.7).is_none());
        assert!(cyl(1.0, 2.0).is_none());
        // Along the axis: inside for y ∈ (0, 4), eroded by 0.5 → (0.5, 3.5).
        let s = cone_span(
            DVec3::ZERO,
            DVec3::Y,
            4.0,
            1.0,
            1.0,
            DVec3::new(0.0, -1.0, 0.0),
            DVec3::Y,
            (0.0, 100.0),
            0.5,
            0.0,
        )
        .unwrap();
        assert!(
            (s.0 - 1.5).abs() < 1e-12 && (s.1 - 4.5).abs() < 1e-12,
            "{s:?}"
        );
    }

    /// Inside distance of a capped cone, from its definition: the least distance to the
    /// caps' planes and to the side (measured across the side's tilted normal).
    fn inside_cone(axis_len: f64, r0: f64, r1: f64, p: DVec3) -> f64 {
        let k = (r1 - r0) / axis_len;
        let z = p.y;
        let radial = (p.x * p.x + p.z * p.z).sqrt();
        let side = (r0 + k * z - radial) / (1.0 + k * k).sqrt();
        z.min(axis_len - z).min(side)
    }

    proptest! {
        /// Every point of a returned span is inside with room to spare, and points well
        /// outside the span (sampled along the line) are not: the spans agree with a direct
        /// evaluation of the inside distance.
        #[test]
        fn spans_agree_with_the_inside_distance(
            o in (-4.0f64..4.0, -4.0f64..8.0, -4.0f64..4.0),
            d in (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0),
            e0 in 0.0f64..0.6, e1 in 0.0f64..0.6,
            r0 in 0.2f64..2.0, r1 in 0.0f64..2.0, h in 0.5f64..5.0,
            bx in (0.2f64..3.0, 0.2f64..3.0, 0.2f64..3.0),
        ) {
            let o = DVec3::new(o.0, o.1, o.2);
            let Some(d) = DVec3::new(d.0, d.1, d.2).try_normalize() else { return Ok(()) };
            let len = 12.0;
            let g = (e1 - e0) / len;
            let e = |s: f64| e0 + g * s;
            let (bmin, bmax) = (-DVec3::new(bx.0, bx.1, bx.2), DVec3::new(bx.0, bx.1, bx.2) * 0.5);
            type Inside = Box<dyn Fn(DVec3) -> f64>;
            let cases: Vec<(Option<Span>, Inside)> = vec![
                (box_span(bmin, bmax, o, d, (0.0, len), e0, g), Box::new(move |p| inside_box(bmin, bmax, p))),
                (sphere_span(DVec3::ONE, r0, o, d, (0.0, len), e0, g), Box::new(move |p: DVec3| r0 - p.distance(DVec3::ONE))),
                (cone_span(DVec3::ZERO, DVec3::Y, h, r0, r1, o, d, (0.0, len), e0, g), Box::new(move |p| inside_cone(h, r0, r1, p))),
            ];
            for (span, inside) in cases {
                let n = 400;
                // Inner points of (0, len) only: the span is open at its ends.
                for i in 1..n {
                    let s = len * i as f64 / n as f64;
                    let margin = inside(o + d * s) - e(s);
                    match span {
                        Some((a, b)) if s > a && s < b => prop_assert!(margin > -1e-9, "s {s} in {a}..{b}: {margin}"),
                        Some((a, b)) if margin > 1e-9 => {
                            // Outside the returned part: then it was another part of a convex
                            // set, which cannot be.
                            prop_assert!(false, "s {s} outside {a}..{b} but inside by {margin}");
                        }
                        None => prop_assert!(margin <= 1e-9, "s {s} inside by {margin} but no span"),
                        _ => {}
                    }
                }
            }
        }
    }
}
