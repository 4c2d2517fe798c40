//! Ray queries over all primitives of a scene: an `obvhs` compressed wide BVH (f32) over the
//! bounded primitives plus a list of unbounded ones (planes), with every hit distance computed
//! exactly in f64.
//!
//! The f32 BVH only decides which primitives to test, never the answer, so it must be
//! conservative: it lives in its own frame (scene-box centre at the origin, scaled by a power
//! of two so the scene spans about 2²⁰ units; obvhs skips nodes that end within 1e-4 units of
//! the ray origin, which is then ~1e-10 of the scene size), primitive boxes are padded by a
//! few f32 ulps of the scene's size, the f32 ray starts at most a little outside the scene box (a ray from far away is advanced to
//! the box in f64 first), and traversal bounds carry the same pad. Ties between primitives at
//! exactly the same distance go to the lower primitive id, so every query that asks for "the
//! first hit in an interval" gets the same primitive whatever order the BVH visits leaves in.

use std::time::Duration;

use glam::{DVec3, Vec3A};
use obvhs::{
    aabb::Aabb,
    cwbvh::{builder::build_cwbvh, CwBvh},
    ray::{Ray, RayHit},
    BvhBuildParams,
};

use crate::geom::Prim;

/// A hit: distance along the unit ray, primitive id and surface part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Radial distance from the ray origin, metres.
    pub t: f64,
    pub(crate) prim: u32,
    pub(crate) part: u8,
}

impl Hit {
    #[inline]
    fn better_than(&self, other: &Option<Hit>) -> bool {
        match other {
            None => true,
            Some(o) => self.t < o.t || (self.t == o.t && self.prim < o.prim),
        }
    }
}

pub(crate) struct Accel {
    /// Bounded primitives in BVH order, then unbounded ones.
    pub prims: Vec<Prim>,
    bounded: usize,
    bvh: Option<CwBvh>,
    /// Scene box (f64) of the bounded primitives.
    lo: DVec3,
    hi: DVec3,
    /// Conservative pad, metres.
    pad: f64,
    /// BVH frame: `(world - centre) * scale`.
    centre: DVec3,
    scale: f64,
}

impl Accel {
    /// Build over `prims`; returns the accelerator and, for each primitive in its order, the
    /// index it had in `prims` (so callers can keep per-primitive data in the same order).
    pub fn build(prims: Vec<Prim>) -> (Accel, Vec<u32>) {
        let mut bounded: Vec<(u32, Prim, DVec3, DVec3)> = Vec::new();
        let mut unbounded: Vec<(u32, Prim)> = Vec::new();
        for (i, p) in prims.into_iter().enumerate() {
            match p.bounds() {
                Some((lo, hi)) => bounded.push((i as u32, p, lo, hi)),
                None => unbounded.push((i as u32, p)),
            }
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for (_, _, a, b) in &bounded {
            lo = lo.min(*a);
            hi = hi.max(*b);
        }
        let (centre, size) = if bounded.is_empty() {
            (DVec3::ZERO, 1.0)
        } else {
            (0.5 * (lo + hi), hi.distance(lo).max(1e-30))
        };
        let pad = 4e-6 * size;
        let scale = 2f64.powi((2f64.powi(20) / size).log2().round() as i32);
        let to_bvh = |p: DVec3| ((p - centre) * scale).as_vec3();
        let (order, bvh): (Vec<usize>, Option<CwBvh>) = if bounded.is_empty() {
            (Vec::new(), None)
        } else {
            let aabbs: Vec<Aabb> = bounded
                .iter()
                .map(|(_, _, a, b)| Aabb {
                    min: to_bvh(*a - pad).into(),
                    max: to_bvh(*b + pad).into(),
                })
                .collect();
            let bvh = build_cwbvh(
                &aabbs,
                BvhBuildParams::medium_build(),
                &mut Duration::default(),
            );
            (
                bvh.primitive_indices.iter().map(|&i| i as usize).collect(),
                Some(bvh),
            )
        };
        let mut out = Vec::with_capacity(order.len() + unbounded.len());
        let mut ids = Vec::with_capacity(out.capacity());
        for &i in &order {
            out.push(bounded[i].1.clone());
            ids.push(bounded[i].0);
        }
        let n_bounded = out.len();
        for (i, p) in unbounded {
            out.push(p);
            ids.push(i);
        }
        (
            Accel {
                prims: out,
                bounded: n_bounded,
                bvh,
                lo,
                hi,
                pad,
                centre,
                scale,
            },
            ids,
        )
    }

    /// The f32 traversal ray for `o + t d`: starts at `o + shift·d`; `None` if the ray misses
    /// the scene box.
    #[inline]
    fn f32_ray(&self, o: DVec3, d: DVec3) -> Option<(Ray, f64)> {
        // Slab test against the padded scene box, in f64.
        let inv = d.recip();
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        for k in 0..3 {
            let (a, b) = (self.lo[k] - self.pad, self.hi[k] + self.pad);
            if d[k] == 0.0 {
                if o[k] < a || o[k] > b {
                    return None;
                }
                continue;
            }
            let (ta, tb) = ((a - o[k]) * inv[k], (b - o[k]) * inv[k]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 > t1 || t1 < 0.0 {
            return None;
        }
        // Start a little before the box so f32 rounding of the origin cannot matter.
        let margin = 0.01 * self.hi.distance(self.lo) + self.pad;
        let shift = (t0 - margin).max(0.0);
        let origin = ((o + d * shift) - self.centre) * self.scale;
        let ray = Ray::new_inf(Vec3A::from(origin.as_vec3()), Vec3A::from(d.as_vec3()));
        Some((ray, shift))
    }

    #[inline]
    fn bound32(&self, t: f64, shift: f64) -> f32 {
        if t.is_finite() {
            ((((t - shift) * (1.0 + 1e-6)) + self.pad) * self.scale) as f32
        } else {
            f32::INFINITY
        }
    }

    /// The first hit with `lo <= t < hi` along the unit ray `o + t d`.
    pub fn closest(&self, o: DVec3, d: DVec3, lo: f64, hi: f64) -> Option<Hit> {
        let inv = d.recip();
        let mut best: Option<Hit> = None;
        for (i, p) in self.prims.iter().enumerate().skip(self.bounded) {
            if let Some((t, part)) = p.crossings_inv(o, d, inv).first_in(lo, hi) {
                let h = Hit {
                    t,
                    prim: i as u32,
                    part,
                };
                if h.better_than(&best) {
                    best = Some(h);
                }
            }
        }
        let Some(bvh) = &self.bvh else { return best };
        let Some((mut ray, shift)) = self.f32_ray(o, d) else {
            return best;
        };
        let limit = best.map_or(hi, |b| b.t.min(hi));
        ray.tmax = self.bound32(limit, shift);
        let mut rh = RayHit::none();
        bvh.ray_traverse(ray, &mut rh, |_, id| {
            let limit = best.map_or(hi, |b| b.t.min(hi));
            // `<=` on the limit so an exact tie can still go to a lower id.
            let c = self.prims[id].crossings_inv(o, d, inv);
            for k in 0..2 {
                let t = c.t[k];
                if t >= lo && t <= limit && t < hi {
                    let h = Hit {
                        t,
                        prim: id as u32,
                        part: c.part[k],
                    };
                    if h.better_than(&best) {
                        best = Some(h);
                        return self.bound32(t, shift);
                    }
                    break;
                }
            }
            f32::INFINITY
        });
        best
    }

    /// Whether anything lies at `lo <= t < hi` along the ray (shadow rays).
    pub fn occluded(&self, o: DVec3, d: DVec3, lo: f64, hi: f64) -> bool {
        let inv = d.recip();
        for p in &self.prims[self.bounded..] {
            if p.crossings_inv(o, d, inv).first_in(lo, hi).is_some() {
                return true;
            }
        }
        let Some(bvh) = &self.bvh else { return false };
        let Some((mut ray, shift)) = self.f32_ray(o, d) else {
            return false;
        };
        ray.tmax = self.bound32(hi, shift);
        !bvh.ray_traverse_miss(ray, |_, id| {
            if self.prims[id]
                .crossings_inv(o, d, inv)
                .first_in(lo, hi)
                .is_some()
            {
                0.0
            } else {
                f32::INFINITY
            }
        })
    }

    /// Whether the segment from `o` to `p` passes through a solid primitive's interior at
    /// inside distance above `e0 + (e1 − e0)·t` at its point of parameter `t ∈ (0, 1)`,
    /// leaving out the primitives (by index in this accelerator) that `excluded` names.
    /// Triangles and planes have no interior and never count.
    pub fn solid_blocks(
        &self,
        o: DVec3,
        p: DVec3,
        e0: f64,
        e1: f64,
        excluded: impl Fn(usize) -> bool,
    ) -> bool {
        let v = p - o;
        let len = v.length();
        if !(len > 0.0 && len.is_finite() && e0.is_finite() && e1.is_finite()) {
            return false;
        }
        let d = v / len;
        let g = (e1 - e0) / len;
        // Unbounded primitives are planes: never solid.
        let Some(bvh) = &self.bvh else { return false };
        let Some((mut ray, shift)) = self.f32_ray(o, d) else {
            return false;
        };
        ray.tmax = self.bound32(len, shift);
        !bvh.ray_traverse_miss(ray, |_, id| {
            if self.prims[id]
                .eroded_span(o, d, (0.0, len), e0, g)
                .is_some()
                && !excluded(id)
            {
                0.0
            } else {
                f32::INFINITY
            }
        })
    }

    /// For each interval `[ranges[k].0, ranges[k].1)`, the first hit in it, in one traversal.
    /// `ranges` must be sorted and not overlap.
    pub fn first_in_each(
        &self,
        o: DVec3,
        d: DVec3,
        ranges: &[(f64, f64)],
        out: &mut [Option<Hit>],
    ) {
        debug_assert_eq!(ranges.len(), out.len());
        out.iter_mut().for_each(|h| *h = None);
        let inv = d.recip();
        let consider = |id: usize, p: &Prim, out: &mut [Option<Hit>]| {
            let c = p.crossings_inv(o, d, inv);
            for (k, &(lo, hi)) in ranges.iter().enumerate() {
                if let Some((t, part)) = c.first_in(lo, hi) {
                    let h = Hit {
                        t,
                        prim: id as u32,
                        part,
                    };
                    if h.better_than(&out[k]) {
                        out[k] = Some(h);
                    }
                }
            }
        };
        for (i, p) in self.prims.iter().enumerate().skip(self.bounded) {
            consider(i, p, out);
        }
        let Some(bvh) = &self.bvh else { return };
        let Some((ray, shift)) = self.f32_ray(o, d) else {
            return;
        };
        let bound = |out: &[Option<Hit>]| -> f64 {
            ranges
                .iter()
                .zip(out)
                .map(|(r, h)| h.map_or(r.1, |h| h.t))
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let mut state = bvh.new_ray_traversal(ray);
        state.ray.tmax = self.bound32(bound(out), shift);
        state.ray.tmin = 0.0;
        let mut rh = RayHit::none();
        while bvh.ray_traverse_dynamic(&mut state, &mut rh, |_, id| {
            consider(id, &self.prims[id], out);
            self.bound32(bound(out), shift)
        }) {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Brute force over every primitive: what the BVH must reproduce exactly.
    fn brute(prims: &[Prim], o: DVec3, d: DVec3, lo: f64, hi: f64) -> Option<Hit> {
        let inv = d.recip();
        let mut best: Option<Hit> = None;
        for (i, p) in prims.iter().enumerate() {
            if let Some((t, part)) = p.crossings_inv(o, d, inv).first_in(lo, hi) {
                let h = Hit {
                    t,
                    prim: i as u32,
                    part,
                };
                if h.better_than(&best) {
                    best = Some(h);
                }
            }
        }
        best
    }

    fn prim_strategy(scale: f64, offset: DVec3) -> impl Strategy<Value = Prim> {
        let v = move || {
            (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
                .prop_map(move |(x, y, z)| offset + DVec3::new(x, y, z) * scale)
        };
        prop_oneof![
            (v(), 0.001f64..0.2).prop_map(move |(c, r)| Prim::Sphere {
                center: c,
                radius: r * scale
            }),
            (v(), 0.001f64..0.3, 0.001f64..0.3, 0.001f64..0.3).prop_map(move |(c, a, b, e)| {
                let h = DVec3::new(a, b, e) * scale;
                Prim::Box {
                    min: c - h,
                    max: c + h,
                }
            }),
            (v(), v(), v()).prop_filter_map("degenerate", |(a, b, c)| {
                let (e1, e2) = (b - a, c - a);
                e1.cross(e2)
                    .try_normalize()
                    .map(|normal| Prim::Triangle { a, e1, e2, normal })
            }),
            (v(), v(), 0.0f64..0.2, 0.01f64..0.2).prop_filter_map(
                "degenerate",
                move |(b, t, r0, r1)| {
                    let axis = (t - b).try_normalize()?;
                    Some(Prim::Cone {
                        base: b,
                        axis,
                        height: t.distance(b),
                        r0: r0 * scale,
                        r1: r1 * scale,
                    })
                }
            ),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// The f32 BVH never loses the exact first hit, at any scale or distance from the
        /// origin, for rays from inside or far outside the scene.
        #[test]
        fn bvh_matches_brute_force(
            (scale, offset, prims) in (prop_oneof![Just(1e-3), Just(1.0), Just(1e5)],
                prop_oneof![Just(DVec3::ZERO), Just(DVec3::new(1e5, -2e4, 3e5))])
                .prop_flat_map(|(s, o)| (Just(s), Just(o), proptest::collection::vec(prim_strategy(s, o), 1..60))),
            origin in (-3.0f64..3.0, -3.0f64..3.0, -3.0f64..3.0),
            dirs in proptest::collection::vec((-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0), 32),
        ) {
            let (accel, ids) = Accel::build(prims.clone());
            let ordered: Vec<Prim> = ids.iter().map(|&i| prims[i as usize].clone()).collect();
            prop_assert_eq!(&ordered, &accel.prims);
            let o = offset + DVec3::new(origin.0, origin.1, origin.2) * scale;
            for (x, y, z) in dirs {
                let Some(d) = DVec3::new(x, y, z).try_normalize() else { continue };
                let want = brute(&accel.prims, o, d, 0.0, f64::INFINITY);
                prop_assert_eq!(accel.closest(o, d, 0.0, f64::INFINITY), want);
                prop_assert_eq!(accel.occluded(o, d, 0.0, f64::INFINITY), want.is_some());
                let ranges = [(0.0, 0.5 * scale), (0.5 * scale, 2.0 * scale), (2.0 * scale, f64::INFINITY)];
                let mut out = [None; 3];
                accel.first_in_each(o, d, &ranges, &mut out);
                for (k, r) in ranges.iter().enumerate() {
                    prop_assert_eq!(out[k], brute(&accel.prims, o, d, r.0, r.1), "slab {}", k);
                }
            }
        }
    }

    /// Regression: obvhs skips BVH nodes ending within 1e-4 units of the ray origin, which
    /// lost surfaces 25 µm from the camera before the BVH got its own scaled frame.
    #[test]
    fn surfaces_micrometres_from_the_origin_are_found() {
        let prims = vec![
            Prim::Box {
                min: DVec3::new(2e-5, -1e-3, -1e-3),
                max: DVec3::new(3e-3, 1e-3, 1e-3),
            },
            Prim::Sphere {
                center: DVec3::new(0.0, 0.0, 5.0),
                radius: 1.0,
            },
        ];
        let (a, _) = Accel::build(prims);
        let h = a
            .closest(DVec3::ZERO, DVec3::X, 0.0, f64::INFINITY)
            .unwrap();
        assert_eq!(h.t, 2e-5);
        assert!(a.occluded(DVec3::ZERO, DVec3::X, 0.0, f64::INFINITY));
        let h = a
            .closest(
                DVec3::new(0.0, 0.0, 4.0 - 1e-6),
                DVec3::Z,
                0.0,
                f64::INFINITY,
            )
            .unwrap();
        assert!((h.t - 1e-6).abs() < 1e-15, "{}", h.t);
    }

    #[test]
    fn only_planes_and_empty_scenes_work() {
        let (a, _) = Accel::build(vec![Prim::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        }]);
        let h = a
            .closest(DVec3::Y, DVec3::NEG_Y, 0.0, f64::INFINITY)
            .unwrap();
        assert_eq!(h.t, 1.0);
        let (e, _) = Accel::build(Vec::new());
        assert!(e
            .closest(DVec3::Y, DVec3::NEG_Y, 0.0, f64::INFINITY)
            .is_none());
        assert!(!e.occluded(DVec3::Y, DVec3::NEG_Y, 0.0, f64::INFINITY));
    }
}
