//! Analytic scenes (boxes and a ground plane) and slab layers rendered from them: known
//! geometry for tests, benchmarks and the oracle's own checks.

use glam::DVec3;
use tracks::{CubeMap, SlabRange, TileGrid};

use crate::input::{raw_rgba_bytes, SlabLayer};
use crate::oracle::{depth_from_geometry, Geometry};
use crate::OcclusionError;

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    pub fn new(a: DVec3, b: DVec3) -> Aabb {
        Aabb {
            min: a.min(b),
            max: a.max(b),
        }
    }

    /// Distance to the first box surface the ray meets within `[0, t_max]`: the entry, or
    /// the exit when it starts inside (the back face is what a clipped view sees).
    pub fn hit(&self, o: DVec3, d: DVec3, t_max: f64) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, t_max);
        for a in 0..3 {
            let (o, d, lo, hi) = (o[a], d[a], self.min[a], self.max[a]);
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let (mut ta, mut tb) = ((lo - o) / d, (hi - o) / d);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
            if t0 > t1 {
                return None;
            }
        }
        if t0 > 0.0 {
            Some(t0)
        } else {
            // Inside: the exit, unless it lies beyond t_max.
            let mut t_exit = f64::INFINITY;
            for a in 0..3 {
                if d[a] > 0.0 {
                    t_exit = t_exit.min((self.max[a] - o[a]) / d[a]);
                } else if d[a] < 0.0 {
                    t_exit = t_exit.min((self.min[a] - o[a]) / d[a]);
                }
            }
            (t_exit <= t_max).then_some(t_exit)
        }
    }
}

/// Boxes over an optional ground plane `y = ground`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BoxScene {
    pub boxes: Vec<Aabb>,
    pub ground: Option<f64>,
}

impl Geometry for BoxScene {
    fn first_hit(&self, origin: DVec3, dir: DVec3, t_max: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        let mut t_lim = t_max;
        if let Some(g) = self.ground {
            if dir.y < 0.0 && origin.y > g {
                let t = (g - origin.y) / dir.y;
                if t <= t_lim {
                    best = Some(t);
                    t_lim = t;
                }
            }
        }
        for b in &self.boxes {
            if let Some(t) = b.hit(origin, dir, t_lim) {
                best = Some(t);
                t_lim = t;
            }
        }
        best
    }
}

impl BoxScene {
    /// A dense scene in the manner of a castle courtyard, around a track along +x at
    /// height 1.7 from x = 0 to 8 (offset by `origin`): a wall with doorways on each
    /// side, rows of buildings behind, an outer wall, ground.
    pub fn courtyard(origin: DVec3) -> BoxScene {
        let mut boxes = Vec::new();
        let o = origin;
        for side in [-1.0, 1.0] {
            // Inner wall 3 m from the track: 9 m pieces with 0.8 m doorways.
            let mut x = -12.0;
            while x < 20.0 {
                boxes.push(Aabb::new(
                    o + DVec3::new(x, 0.0, side * 3.0),
                    o + DVec3::new(x + 9.0, 4.0, side * 3.4),
                ));
                x += 9.8;
            }
            // Buildings behind, then the outer wall.
            for i in 0..6 {
                let x = -10.0 + 5.0 * i as f64;
                boxes.push(Aabb::new(
                    o + DVec3::new(x, 0.0, side * 7.0),
                    o + DVec3::new(x + 3.0, 6.0, side * 9.0),
                ));
            }
            boxes.push(Aabb::new(
                o + DVec3::new(-30.0, 0.0, side * 14.0),
                o + DVec3::new(30.0, 10.0, side * 15.0),
            ));
        }
        // End walls.
        for x in [-14.0, 22.0] {
            boxes.push(Aabb::new(
                o + DVec3::new(x, 0.0, -15.0),
                o + DVec3::new(x + 1.0, 10.0, 15.0),
            ));
        }
        BoxScene {
            boxes,
            ground: Some(o.y),
        }
    }

    /// An open scene: a few thin posts and rocks on a ground plane.
    pub fn open_field(origin: DVec3) -> BoxScene {
        let o = origin;
        let mut boxes = Vec::new();
        for i in 0..8 {
            let a = i as f64 * 0.8;
            let p = o + DVec3::new(4.0 + 9.0 * a.cos(), 0.0, 9.0 * a.sin());
            boxes.push(Aabb::new(p, p + DVec3::new(0.3, 3.0, 0.3)));
        }
        boxes.push(Aabb::new(
            o + DVec3::new(2.0, 0.0, 4.0),
            o + DVec3::new(3.0, 0.8, 5.0),
        ));
        boxes.push(Aabb::new(
            o + DVec3::new(12.0, 0.0, -20.0),
            o + DVec3::new(13.0, 2.0, -19.0),
        ));
        BoxScene {
            boxes,
            ground: Some(o.y),
        }
    }
}

/// The slab layers at `position`: for slab `[near, far)`, the first surface along each pixel
/// ray beyond radial distance `near`, clipped at `far` (every nearer surface removed).
pub fn render_layers<G: Geometry + ?Sized>(
    geom: &G,
    position: DVec3,
    grid: &TileGrid,
    ranges: &[SlabRange],
) -> Result<Vec<SlabLayer>, OcclusionError> {
    let shifted = ShiftedStart { geom };
    ranges
        .iter()
        .map(|r| {
            let depth = shifted.render(position, grid.face_size, *r);
            let alpha = depth.map(|d| if d.is_finite() { 255u8 } else { 0 });
            SlabLayer::from_maps(*r, alpha, depth, grid, raw_rgba_bytes)
        })
        .collect()
}

struct ShiftedStart<'a, G: ?Sized> {
    geom: &'a G,
}

impl<G: Geometry + ?Sized> ShiftedStart<'_, G> {
    fn render(&self, position: DVec3, n: u32, r: SlabRange) -> CubeMap<f32> {
        struct Clip<'b, G: ?Sized> {
            g: &'b G,
            r: SlabRange,
        }
        impl<G: Geometry + ?Sized> Geometry for Clip<'_, G> {
            fn first_hit(&self, o: DVec3, d: DVec3, _t_max: f64) -> Option<f64> {
                let t = self
                    .g
                    .first_hit(o + self.r.near * d, d, self.r.far - self.r.near)?;
                let t = t + self.r.near;
                (t < self.r.far).then_some(t)
            }
        }
        depth_from_geometry(&Clip { g: self.geom, r }, position, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_hits() {
        let b = Aabb::new(DVec3::new(1.0, -1.0, -1.0), DVec3::new(2.0, 1.0, 1.0));
        assert_eq!(b.hit(DVec3::ZERO, DVec3::X, 10.0), Some(1.0));
        assert_eq!(b.hit(DVec3::ZERO, DVec3::NEG_X, 10.0), None);
        assert_eq!(b.hit(DVec3::ZERO, DVec3::X, 0.5), None);
        assert_eq!(b.hit(DVec3::new(1.5, 0.0, 0.0), DVec3::X, 10.0), Some(0.5));
        assert_eq!(b.hit(DVec3::new(0.0, 2.0, 0.0), DVec3::X, 10.0), None);
    }

    #[test]
    fn layers_hold_what_lies_beyond_their_near_bound() {
        let s = BoxScene {
            boxes: vec![
                Aabb::new(DVec3::new(2.0, -5.0, -5.0), DVec3::new(3.0, 5.0, 5.0)),
                Aabb::new(DVec3::new(6.0, -5.0, -5.0), DVec3::new(7.0, 5.0, 5.0)),
            ],
            ground: None,
        };
        let g = TileGrid::new(8, 4).unwrap();
        let ranges = SlabRange::parse_list("0-4,4-inf").unwrap();
        let l = render_layers(&s, DVec3::ZERO, &g, &ranges).unwrap();
        let c = tracks::FaceCoord::from_dir(DVec3::X).unwrap().to_pixel(8);
        let d0 = *l[0].depth.get(tracks::Face::PosX, c.0, c.1);
        let d1 = *l[1].depth.get(tracks::Face::PosX, c.0, c.1);
        assert!(
            (d0 - 2.0).abs() < 0.2 && (d1 - 6.0).abs() < 0.6,
            "{d0} {d1}"
        );
    }
}
