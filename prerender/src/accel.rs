//! Ray queries over all primitives of a scene: an `obvhs` compressed wide BVH (f32) over the
//! bounded primitives plus a list of unbounded ones (planes), with every hit distance computed
//! exactly in f64.
//!
//! The f32 BVH only decides which primitives to test, never the answer, so it must be
//! conservative: primitive boxes are padded by a few f32 ulps of the scene's magnitude, the
//! f32 ray starts at most a little outside the scene box (a ray from far away is advanced to
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
    /// Conservative pad in f32 traversal units, metres.
    pad: f64,
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
        let magnitude = if bounded.is_empty() {
            1.0
        } else {
            lo.abs()
                .max(hi.abs())
                .max_element()
                .max(hi.distance(lo))
                .max(1e-30)
        };
        let pad = 4e-6 * magnitude;
        let (order, bvh): (Vec<usize>, Option<CwBvh>) = if bounded.is_empty() {
            (Vec::new(), None)
        } else {
            let aabbs: Vec<Aabb> = bounded
                .iter()
                .map(|(_, _, a, b)| Aabb {
                    min: (*a - pad).as_vec3().into(),
                    max: (*b + pad).as_vec3().into(),
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
        let origin = o + d * shift;
        let ray = Ray::new_inf(Vec3A::from(origin.as_vec3()), Vec3A::from(d.as_vec3()));
        Some((ray, shift))
    }

    #[inline]
    fn bound32(&self, t: f64, shift: f64) -> f32 {
        if t.is_finite() {
            (((t - shift) * (1.0 + 1e-6)) + self.pad) as f32
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
