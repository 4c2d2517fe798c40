//! Exact (f64) ray–primitive intersection.
//!
//! Every closed primitive here is convex, so a ray crosses its surface at most twice; a
//! [`Crossings`] holds those crossings sorted, each with the part of the surface it is on
//! (a box face axis, a cylinder cap or side), so the normal can be recomputed exactly for
//! whichever crossing a renderer keeps. Open surfaces (triangles, planes) cross once.

use glam::DVec3;

/// Surface crossings of one ray with one primitive, sorted by `t` (unused slots are `+inf`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Crossings {
    pub t: [f64; 2],
    pub part: [u8; 2],
}

impl Crossings {
    pub const NONE: Crossings = Crossings {
        t: [f64::INFINITY, f64::INFINITY],
        part: [0, 0],
    };

    fn one(t: f64, part: u8) -> Crossings {
        if t.is_finite() {
            Crossings {
                t: [t, f64::INFINITY],
                part: [part, 0],
            }
        } else {
            Crossings::NONE
        }
    }

    /// First crossing with `lo <= t < hi`: `(t, part)`.
    #[inline]
    pub fn first_in(&self, lo: f64, hi: f64) -> Option<(f64, u8)> {
        for i in 0..2 {
            let t = self.t[i];
            if t >= lo && t < hi {
                return Some((t, self.part[i]));
            }
        }
        None
    }
}

/// A primitive prepared for intersection.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Prim {
    Sphere {
        center: DVec3,
        radius: f64,
    },
    Box {
        min: DVec3,
        max: DVec3,
    },
    /// Truncated cone (a cylinder when `r0 == r1`), capped, from `base` along unit `axis`.
    Cone {
        base: DVec3,
        axis: DVec3,
        height: f64,
        r0: f64,
        r1: f64,
    },
    Triangle {
        a: DVec3,
        e1: DVec3,
        e2: DVec3,
        normal: DVec3,
    },
    Plane {
        point: DVec3,
        normal: DVec3,
    },
}

/// Roots of `a t² + 2 b t + c = 0`, sorted, computed without cancellation.
#[inline]
fn quadratic(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    if a == 0.0 {
        if b == 0.0 {
            return None;
        }
        let t = -c / (2.0 * b);
        return Some((t, t));
    }
    let disc = b * b - a * c;
    if disc < 0.0 || disc.is_nan() {
        return None;
    }
    let q = -(b + disc.sqrt().copysign(b));
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    Some(if t0 <= t1 { (t0, t1) } else { (t1, t0) })
}

impl Prim {
    /// Axis-aligned bounds; `None` for unbounded primitives (planes).
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        match *self {
            Prim::Sphere { center, radius } => Some((center - radius, center + radius)),
            Prim::Box { min, max } => Some((min, max)),
            Prim::Cone {
                base,
                axis,
                height,
                r0,
                r1,
            } => {
                let top = base + axis * height;
                // Extent of a disc of radius r with normal `axis` along each world axis.
                let e = (DVec3::ONE - axis * axis).max(DVec3::ZERO).powf(0.5);
                let (lo0, hi0) = (base - e * r0, base + e * r0);
                let (lo1, hi1) = (top - e * r1, top + e * r1);
                Some((lo0.min(lo1), hi0.max(hi1)))
            }
            Prim::Triangle { a, e1, e2, .. } => {
                let (b, c) = (a + e1, a + e2);
                Some((a.min(b).min(c), a.max(b).max(c)))
            }
            Prim::Plane { .. } => None,
        }
    }

    /// All surface crossings of the ray `o + t d` (`d` unit), any sign of `t`.
    #[cfg(test)]
    pub fn crossings(&self, o: DVec3, d: DVec3) -> Crossings {
        self.crossings_inv(o, d, d.recip())
    }

    /// [`Prim::crossings`] with the ray's precomputed `inv = 1 / d`.
    #[inline]
    pub fn crossings_inv(&self, o: DVec3, d: DVec3, inv: DVec3) -> Crossings {
        match *self {
            Prim::Sphere { center, radius } => {
                let oc = o - center;
                let b = oc.dot(d);
                // (|oc| - r)(|oc| + r) keeps its precision when the origin is near the surface.
                let len = oc.length();
                let c = (len - radius) * (len + radius);
                match quadratic(1.0, b, c) {
                    Some((t0, t1)) => Crossings {
                        t: [t0, t1],
                        part: [0, 0],
                    },
                    None => Crossings::NONE,
                }
            }
            Prim::Box { min, max } => {
                let ta = (min - o) * inv;
                let tb = (max - o) * inv;
                let mut t0 = f64::NEG_INFINITY;
                let mut t1 = f64::INFINITY;
                let (mut p0, mut p1) = (0u8, 0u8);
                for k in 0..3 {
                    if d[k] == 0.0 {
                        if o[k] < min[k] || o[k] > max[k] {
                            return Crossings::NONE;
                        }
                        continue;
                    }
                    let (near, far) = if ta[k] <= tb[k] {
                        (ta[k], tb[k])
                    } else {
                        (tb[k], ta[k])
                    };
                    if near > t0 {
                        t0 = near;
                        p0 = k as u8;
                    }
                    if far < t1 {
                        t1 = far;
                        p1 = k as u8;
                    }
                }
                if t0 <= t1 && t0.is_finite() && t1.is_finite() {
                    Crossings {
                        t: [t0, t1],
                        part: [p0, p1],
                    }
                } else {
                    Crossings::NONE
                }
            }
            Prim::Cone {
                base,
                axis,
                height,
                r0,
                r1,
            } => cone_crossings(o - base, d, axis, height, r0, r1),
            Prim::Triangle { a, e1, e2, .. } => {
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det == 0.0 || !det.is_finite() {
                    return Crossings::NONE;
                }
                let inv = 1.0 / det;
                let s = o - a;
                let u = s.dot(p) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return Crossings::NONE;
                }
                let q = s.cross(e1);
                let v = d.dot(q) * inv;
                if v < 0.0 || u + v > 1.0 {
                    return Crossings::NONE;
                }
                Crossings::one(e2.dot(q) * inv, 0)
            }
            Prim::Plane { point, normal } => {
                let den = d.dot(normal);
                if den == 0.0 {
                    return Crossings::NONE;
                }
                Crossings::one((point - o).dot(normal) / den, 0)
            }
        }
    }

    /// The part of `o + s·d`, `s ∈ span`, inside this primitive with inside distance above
    /// `e0 + g·s` ([`crate::erode`]). Only solids have an inside: triangles and planes (no
    /// volume) give `None` for every erosion.
    pub fn eroded_span(
        &self,
        o: DVec3,
        d: DVec3,
        span: crate::erode::Span,
        e0: f64,
        g: f64,
    ) -> Option<crate::erode::Span> {
        use crate::erode::{box_span, cone_span, sphere_span};
        match *self {
            Prim::Sphere { center, radius } => sphere_span(center, radius, o, d, span, e0, g),
            Prim::Box { min, max } => box_span(min, max, o, d, span, e0, g),
            Prim::Cone {
                base,
                axis,
                height,
                r0,
                r1,
            } => cone_span(base, axis, height, r0, r1, o, d, span, e0, g),
            Prim::Triangle { .. } | Prim::Plane { .. } => None,
        }
    }

    /// Outward (geometric) unit normal at point `p` on the part `part` of the surface.
    pub fn normal(&self, p: DVec3, part: u8) -> DVec3 {
        match *self {
            Prim::Sphere { center, .. } => (p - center).normalize_or(DVec3::Y),
            Prim::Box { min, max } => {
                let k = part as usize;
                let mut n = DVec3::ZERO;
                n[k] = if (p[k] - min[k]).abs() <= (p[k] - max[k]).abs() {
                    -1.0
                } else {
                    1.0
                };
                n
            }
            Prim::Cone {
                base,
                axis,
                r0,
                r1,
                height,
            } => match part {
                1 => -axis,
                2 => axis,
                _ => {
                    let q = p - base;
                    let radial =
                        (q - axis * q.dot(axis)).normalize_or(axis.any_orthonormal_vector());
                    let k = (r1 - r0) / height;
                    (radial - axis * k).normalize()
                }
            },
            Prim::Triangle { normal, .. } => normal,
            Prim::Plane { normal, .. } => normal,
        }
    }
}

/// Crossings of a capped truncated cone; origin `o` relative to the base centre.
/// Parts: 0 side, 1 base cap, 2 top cap.
#[inline]
fn cone_crossings(o: DVec3, d: DVec3, axis: DVec3, h: f64, r0: f64, r1: f64) -> Crossings {
    let k = (r1 - r0) / h;
    let oz = o.dot(axis);
    let dz = d.dot(axis);
    let or = o - axis * oz;
    let dr = d - axis * dz;
    let ro = r0 + k * oz;
    let a = dr.dot(dr) - k * k * dz * dz;
    let b = or.dot(dr) - k * ro * dz;
    let c = or.dot(or) - ro * ro;
    let mut ts = [f64::INFINITY; 4];
    let mut parts = [0u8; 4];
    let mut n = 0;
    if let Some((t0, t1)) = quadratic(a, b, c) {
        for t in [t0, t1] {
            let z = oz + t * dz;
            if (0.0..=h).contains(&z) && r0 + k * z >= 0.0 && t.is_finite() {
                ts[n] = t;
                parts[n] = 0;
                n += 1;
            }
        }
        if n == 2 && ts[0] == ts[1] {
            n = 1;
        }
    }
    if dz != 0.0 {
        for (z, r, part) in [(0.0, r0, 1u8), (h, r1, 2u8)] {
            let t = (z - oz) / dz;
            let q = or + dr * t;
            if q.length_squared() <= r * r && t.is_finite() {
                ts[n] = t;
                parts[n] = part;
                n += 1;
            }
        }
    }
    if n == 0 {
        return Crossings::NONE;
    }
    let (mut imin, mut imax) = (0, 0);
    for i in 1..n {
        if ts[i] < ts[imin] {
            imin = i;
        }
        if ts[i] > ts[imax] {
            imax = i;
        }
    }
    Crossings {
        t: [
            ts[imin],
            if imax == imin {
                f64::INFINITY
            } else {
                ts[imax]
            },
        ],
        part: [parts[imin], parts[imax]],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_from_outside_and_inside() {
        let s = Prim::Sphere {
            center: DVec3::new(10.0, 0.0, 0.0),
            radius: 2.0,
        };
        let c = s.crossings(DVec3::ZERO, DVec3::X);
        assert_eq!(c.t, [8.0, 12.0]);
        assert_eq!(c.first_in(9.0, 100.0), Some((12.0, 0)));
        let c = s.crossings(DVec3::new(10.0, 0.0, 0.0), DVec3::Y);
        assert_eq!(c.first_in(0.0, f64::INFINITY).map(|h| h.0), Some(2.0));
    }

    #[test]
    fn box_axis_parallel_ray_in_face_plane_misses_cleanly() {
        let b = Prim::Box {
            min: DVec3::new(1.0, -1.0, -1.0),
            max: DVec3::new(3.0, 1.0, 1.0),
        };
        let c = b.crossings(DVec3::ZERO, DVec3::X);
        assert_eq!(c.t, [1.0, 3.0]);
        assert_eq!(b.normal(DVec3::new(1.0, 0.0, 0.0), c.part[0]), -DVec3::X);
        assert_eq!(
            b.crossings(DVec3::new(0.0, 2.0, 0.0), DVec3::X),
            Crossings::NONE
        );
    }

    #[test]
    fn cylinder_side_and_caps() {
        let cyl = Prim::Cone {
            base: DVec3::ZERO,
            axis: DVec3::Y,
            height: 2.0,
            r0: 1.0,
            r1: 1.0,
        };
        let c = cyl.crossings(DVec3::new(-5.0, 1.0, 0.0), DVec3::X);
        assert_eq!(c.t, [4.0, 6.0]);
        assert_eq!(c.part, [0, 0]);
        let c = cyl.crossings(DVec3::new(0.0, 5.0, 0.0), DVec3::NEG_Y);
        assert_eq!(c.t, [3.0, 5.0]);
        assert_eq!(c.part, [2, 1]);
        // A cone: radius 1 at the base, 0 at the apex (y = 2); at y = 1 the radius is 0.5.
        let cone = Prim::Cone {
            base: DVec3::ZERO,
            axis: DVec3::Y,
            height: 2.0,
            r0: 1.0,
            r1: 0.0,
        };
        let c = cone.crossings(DVec3::new(-5.0, 1.0, 0.0), DVec3::X);
        assert!((c.t[0] - 4.5).abs() < 1e-12 && (c.t[1] - 5.5).abs() < 1e-12);
    }

    #[test]
    fn triangle_is_two_sided() {
        let t = Prim::Triangle {
            a: DVec3::new(0.0, 0.0, -5.0),
            e1: DVec3::new(1.0, 0.0, 0.0),
            e2: DVec3::new(0.0, 1.0, 0.0),
            normal: DVec3::Z,
        };
        let c = t.crossings(DVec3::new(0.2, 0.2, 0.0), DVec3::NEG_Z);
        assert_eq!(c.first_in(0.0, f64::INFINITY), Some((5.0, 0)));
        let c = t.crossings(DVec3::new(0.2, 0.2, -10.0), DVec3::Z);
        assert_eq!(c.first_in(0.0, f64::INFINITY), Some((5.0, 0)));
        assert_eq!(
            t.crossings(DVec3::new(0.9, 0.9, 0.0), DVec3::NEG_Z),
            Crossings::NONE
        );
    }
}
