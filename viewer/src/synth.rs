//! A small analytic scene (boxes over a ground disc, sky) with its own exact ray caster, for
//! tests, golden images and `eval` when no prerendered database is at hand.
//!
//! [`Scene::cube_layers`] renders what a reference viewpoint sees per slab (surfaces nearer
//! than the slab's near bound removed, clipped at its far bound), [`Scene::perspective`] the
//! ground truth for any camera, and [`views_along`] turns a list of viewpoints into
//! [`RefView`]s exactly as a prerender directory would.

use glam::DVec3;
use tracks::cubemap::pixel_dir;
use tracks::{CubeMap, PerspectiveCamera, SlabRange};

use crate::refview::{DenseLayer, LayerMeshing, RefView, ViewError};

/// A surface of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Axis-aligned box.
    Cuboid {
        min: DVec3,
        max: DVec3,
        color: [u8; 3],
    },
    /// Horizontal disc at height `y` around the origin.
    Ground { y: f64, radius: f64, color: [u8; 3] },
}

/// A dense slab layer: colour (alpha = opacity mask) and radial depth (`+inf` = empty).
pub type SlabLayer = (CubeMap<[u8; 4]>, CubeMap<f32>);

/// Shapes and a sky colour.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub shapes: Vec<Shape>,
    pub sky: [u8; 3],
}

/// A ray hit: distance along the unit ray and sRGB colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub color: [u8; 3],
}

fn shade(base: [u8; 3], p: DVec3, scale: f64) -> [u8; 3] {
    // A checker of period `scale` so that resampling and parallax errors show.
    let k = (p / scale).floor();
    let odd = (k.x + k.y + k.z).rem_euclid(2.0) as u8;
    base.map(|c| {
        if odd == 1 {
            c
        } else {
            (c as u16 * 3 / 4) as u8
        }
    })
}

impl Shape {
    /// Nearest intersection with `t ≥ t_min` (a box entered before `t_min` shows its far
    /// side, as when the surfaces nearer than a slab are removed).
    fn hit(&self, o: DVec3, d: DVec3, t_min: f64) -> Option<Hit> {
        match *self {
            Shape::Cuboid { min, max, color } => {
                let inv = d.recip();
                let t0 = (min - o) * inv;
                let t1 = (max - o) * inv;
                let (lo, hi) = (t0.min(t1), t0.max(t1));
                let enter = lo.max_element();
                let exit = hi.min_element();
                if enter > exit || exit < t_min {
                    return None;
                }
                let t = if enter >= t_min { enter } else { exit };
                let size = (max - min).min_element().max(1e-3);
                Some(Hit {
                    t,
                    color: shade(color, o + d * t + DVec3::splat(1e-7), size / 4.0),
                })
            }
            Shape::Ground { y, radius, color } => {
                if d.y == 0.0 {
                    return None;
                }
                let t = (y - o.y) / d.y;
                let p = o + d * t;
                (t >= t_min && t.is_finite() && p.x * p.x + p.z * p.z <= radius * radius).then(
                    || Hit {
                        t,
                        color: shade(color, p, 1.0),
                    },
                )
            }
        }
    }
}

impl Scene {
    /// The nearest hit at distance `≥ t_min` along the unit ray.
    pub fn hit(&self, o: DVec3, d: DVec3, t_min: f64) -> Option<Hit> {
        self.shapes
            .iter()
            .filter_map(|s| s.hit(o, d, t_min))
            .min_by(|a, b| a.t.total_cmp(&b.t))
    }

    /// A street: ground, a near pillar that hides part of a wall, the wall, and a tall tower
    /// far behind (three depth ranges, so slabs matter).
    pub fn street() -> Scene {
        let cuboid = |min: [f64; 3], max: [f64; 3], color| Shape::Cuboid {
            min: DVec3::from(min),
            max: DVec3::from(max),
            color,
        };
        Scene {
            shapes: vec![
                Shape::Ground {
                    y: 0.0,
                    radius: 300.0,
                    color: [90, 140, 70],
                },
                cuboid([-0.6, 0.0, -4.0], [0.2, 3.0, -3.2], [200, 60, 50]),
                cuboid([1.5, 0.0, -3.5], [2.1, 2.5, -2.9], [220, 180, 60]),
                cuboid([-8.0, 0.0, -14.0], [8.0, 4.0, -12.0], [160, 160, 190]),
                cuboid([-3.0, 0.0, -60.0], [6.0, 30.0, -50.0], [120, 90, 160]),
            ],
            sky: [130, 180, 235],
        }
    }

    /// The slab boundaries that suit [`Scene::street`]: pillars, wall, tower.
    pub fn street_slabs() -> Vec<SlabRange> {
        vec![
            SlabRange {
                near: 0.0,
                far: 6.0,
            },
            SlabRange {
                near: 6.0,
                far: 30.0,
            },
            SlabRange {
                near: 30.0,
                far: f64::INFINITY,
            },
        ]
    }

    /// Background cube map (the complete sky, as databases hold it: alpha
    /// [`db::SKY_SEEN_ALPHA`] where nothing is hit, [`db::SKY_BEHIND_ALPHA`] behind the
    /// surfaces) and one dense layer per slab (colour with mask, radial depth) at viewpoint
    /// `pos`.
    pub fn cube_layers(
        &self,
        pos: DVec3,
        face_size: u32,
        slabs: &[SlabRange],
    ) -> (CubeMap<[u8; 4]>, Vec<SlabLayer>) {
        let background = CubeMap::from_fn(face_size, |f, x, y| {
            let d = pixel_dir(f, x, y, face_size);
            let [r, g, b] = self.sky;
            match self.hit(pos, d, 0.0) {
                Some(_) => [r, g, b, db::SKY_BEHIND_ALPHA],
                None => [r, g, b, db::SKY_SEEN_ALPHA],
            }
        });
        let layers = slabs
            .iter()
            .map(|slab| {
                let hits = CubeMap::from_fn(face_size, |f, x, y| {
                    let d = pixel_dir(f, x, y, face_size);
                    self.hit(pos, d, slab.near).filter(|h| h.t < slab.far)
                });
                let color = hits.map(|h| match h {
                    Some(h) => [h.color[0], h.color[1], h.color[2], 255],
                    None => [0, 0, 0, 0],
                });
                let depth = hits.map(|h| h.map_or(f32::INFINITY, |h| h.t as f32));
                (color, depth)
            })
            .collect();
        (background, layers)
    }

    /// Ground truth for `camera`: sRGB RGB per pixel, rows from the top.
    pub fn perspective(&self, camera: &PerspectiveCamera) -> Vec<[u8; 3]> {
        let (w, h) = (camera.width.max(1), camera.height.max(1));
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let d = camera.pixel_dir(x, y);
                self.hit(camera.position, d, 0.0)
                    .map_or(self.sky, |h| h.color)
            })
            .collect()
    }
}

/// Reference views of `scene` at `(s, position)` samples.
pub fn views_along(
    scene: &Scene,
    samples: &[(f64, DVec3)],
    face_size: u32,
    tile_size: u32,
    slabs: &[SlabRange],
    params: LayerMeshing,
) -> Result<Vec<RefView>, ViewError> {
    samples
        .iter()
        .enumerate()
        .map(|(i, &(s, pos))| {
            let (bg, layers) = scene.cube_layers(pos, face_size, slabs);
            let dense: Vec<DenseLayer<'_>> = layers
                .iter()
                .map(|(c, d)| DenseLayer { color: c, depth: d })
                .collect();
            RefView::from_layers(i, s, pos, tile_size, params, &bg, &dense)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_hits_front_then_back_when_front_is_removed() {
        let s = Scene {
            shapes: vec![Shape::Cuboid {
                min: DVec3::new(-1.0, -1.0, -6.0),
                max: DVec3::new(1.0, 1.0, -4.0),
                color: [255, 0, 0],
            }],
            sky: [0, 0, 255],
        };
        let h = s.hit(DVec3::ZERO, DVec3::NEG_Z, 0.0).unwrap();
        assert!((h.t - 4.0).abs() < 1e-12);
        let h = s.hit(DVec3::ZERO, DVec3::NEG_Z, 5.0).unwrap();
        assert!((h.t - 6.0).abs() < 1e-12);
        assert!(s.hit(DVec3::ZERO, DVec3::NEG_Z, 7.0).is_none());
        assert!(s.hit(DVec3::ZERO, DVec3::Z, 0.0).is_none());
    }

    #[test]
    fn slab_layers_partition_the_visible_surface() {
        let scene = Scene::street();
        let slabs = Scene::street_slabs();
        let pos = DVec3::new(0.0, 1.7, 0.0);
        let (bg, layers) = scene.cube_layers(pos, 8, &slabs);
        // Every direction is sky or has its first hit in exactly one slab's depth range.
        for (i, b) in bg.as_slice().iter().enumerate() {
            let first: Vec<bool> = layers
                .iter()
                .zip(&slabs)
                .map(|((_, d), s)| {
                    let d = d.as_slice()[i] as f64;
                    d.is_finite() && s.contains(d)
                })
                .collect();
            assert!(
                b[3] == db::SKY_SEEN_ALPHA || first.iter().any(|&x| x),
                "texel {i}"
            );
        }
    }
}
