//! `nature`: open country with little occlusion.
//!
//! Rolling terrain (a triangle mesh from smooth value noise, flattened along the path),
//! scattered trees (conifers: cone crowns; broadleaves: sphere crowns), half-buried rocks,
//! and a ring of large far hills. Track `main` winds across the meadow.

use std::sync::Arc;

use glam::DVec3;
use tracks::{Sampling, Smoothing, Track, TrackSet};

use super::{Builder, Rng};
use crate::scene::{Mesh, SceneDesc, Shape, Sky, Sun, Texture};

/// Seed of the built-in `nature`.
pub const SEED: u64 = 0x0057_0A7E;

const EXTENT: f64 = 160.0;
const CELLS: usize = 40;
const EYE: f64 = 1.7;

fn track_points() -> Vec<DVec3> {
    [(-32.0, 16.0), (-12.0, 2.0), (8.0, 4.0), (30.0, -12.0)]
        .iter()
        .map(|&(x, z)| DVec3::new(x, EYE, z))
        .collect()
}

/// Distance in the ground plane from `(x, z)` to the track's control polyline.
fn dist_to_path(x: f64, z: f64, pts: &[DVec3]) -> f64 {
    let p = DVec3::new(x, 0.0, z);
    pts.windows(2)
        .map(|w| {
            let (a, b) = (
                w[0] * DVec3::new(1.0, 0.0, 1.0),
                w[1] * DVec3::new(1.0, 0.0, 1.0),
            );
            let t = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
            p.distance(a + (b - a) * t)
        })
        .fold(f64::INFINITY, f64::min)
}

/// Terrain height; zero near the path, rolling hills away from it.
fn height(x: f64, z: f64, pts: &[DVec3], seed_offset: f64) -> f64 {
    let q = DVec3::new(x / 28.0 + seed_offset, 0.0, z / 28.0);
    let n = 0.7 * crate::shade::value_noise(q) + 0.3 * crate::shade::value_noise(q * 2.3 + 5.0);
    let d = dist_to_path(x, z, pts);
    let w = ((d - 4.0) / 18.0).clamp(0.0, 1.0);
    let w = w * w * (3.0 - 2.0 * w);
    (n - 0.35) * 9.0 * w
}

/// The scene description and its tracks.
pub fn generate(seed: u64) -> (SceneDesc, TrackSet) {
    let mut rng = Rng::new(seed);
    let seed_offset = (seed % 1000) as f64 * 0.731;
    let mut b = Builder::default();
    lighting(&mut b);
    let m = Palette::new(&mut b);
    let pts = track_points();
    terrain(&mut b, &pts, seed_offset, m.grass);
    path(&mut b, &pts, m.path);
    trees(&mut b, &mut rng, &pts, seed_offset, &m);
    rocks(&mut b, &mut rng, &pts, seed_offset, m.rock);
    far_hills(&mut b, &mut rng, m.hills);
    let main = Track::new(
        "main",
        pts,
        Smoothing::CatmullRom,
        Sampling::Spacing(2.5),
        "builtin:nature",
    )
    .expect("nature track is valid");
    (b.desc, TrackSet { tracks: vec![main] })
}

/// A blue sky and a low sun.
fn lighting(b: &mut Builder) {
    b.desc.sky = Sky {
        zenith: DVec3::new(0.15, 0.30, 0.65),
        horizon: DVec3::new(0.65, 0.75, 0.85),
        ground: DVec3::new(0.25, 0.28, 0.20),
        ambient: 0.35,
    };
    b.desc.sun = Some(Sun {
        direction: DVec3::new(-0.5, 0.6, 0.4),
        color: DVec3::new(1.0, 0.93, 0.8),
    });
}

/// The materials (indices into the builder's list), created in this order.
struct Palette {
    grass: usize,
    path: usize,
    bark: usize,
    needles: usize,
    leaves: usize,
    rock: usize,
    hills: usize,
}

impl Palette {
    fn new(b: &mut Builder) -> Palette {
        let grass = b.material(
            "meadow",
            [0.20, 0.36, 0.10],
            Texture::Noise {
                color2: DVec3::new(0.36, 0.46, 0.16),
                size: 3.0,
            },
        );
        let path = b.material(
            "path",
            [0.45, 0.38, 0.28],
            Texture::Noise {
                color2: DVec3::new(0.55, 0.48, 0.36),
                size: 0.6,
            },
        );
        let bark = b.material("bark", [0.28, 0.19, 0.11], Texture::Solid);
        let needles = b.material(
            "needles",
            [0.06, 0.20, 0.08],
            Texture::Noise {
                color2: DVec3::new(0.10, 0.28, 0.10),
                size: 0.5,
            },
        );
        let leaves = b.material(
            "leaves",
            [0.16, 0.34, 0.08],
            Texture::Noise {
                color2: DVec3::new(0.30, 0.46, 0.12),
                size: 0.7,
            },
        );
        let rock = b.material(
            "rock",
            [0.42, 0.41, 0.40],
            Texture::Noise {
                color2: DVec3::new(0.58, 0.56, 0.52),
                size: 0.5,
            },
        );
        let hills = b.material(
            "far_hills",
            [0.20, 0.30, 0.22],
            Texture::Noise {
                color2: DVec3::new(0.30, 0.38, 0.30),
                size: 25.0,
            },
        );
        Palette {
            grass,
            path,
            bark,
            needles,
            leaves,
            rock,
            hills,
        }
    }
}

/// The terrain mesh: a `CELLS`² grid over ±`EXTENT`, heights from [`height`].
fn terrain(b: &mut Builder, pts: &[DVec3], seed_offset: f64, grass: usize) {
    let n = CELLS;
    let step = 2.0 * EXTENT / n as f64;
    let mut positions = Vec::with_capacity((n + 1) * (n + 1));
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (-EXTENT + i as f64 * step, -EXTENT + j as f64 * step);
            positions.push(DVec3::new(x, height(x, z, pts, seed_offset), z));
        }
    }
    let mut triangles = Vec::with_capacity(2 * n * n);
    let idx = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            triangles.push([idx(i, j), idx(i, j + 1), idx(i + 1, j)]);
            triangles.push([idx(i + 1, j), idx(i, j + 1), idx(i + 1, j + 1)]);
        }
    }
    b.add(
        Shape::Mesh(Arc::new(Mesh {
            positions,
            triangles,
        })),
        grass,
    );
}

/// The path: thin boxes along the straight pieces (terrain is flat there).
fn path(b: &mut Builder, pts: &[DVec3], path: usize) {
    for w in pts.windows(2) {
        let (a, c) = (w[0], w[1]);
        let len = a.distance(c);
        let steps = (len / 1.5).ceil() as usize;
        for k in 0..steps {
            let p = a.lerp(c, (k as f64 + 0.5) / steps as f64);
            b.boxed(
                DVec3::new(p.x - 0.9, -0.1, p.z - 0.9),
                DVec3::new(p.x + 0.9, 0.015, p.z + 0.9),
                path,
            );
        }
    }
}

/// 140 trees away from the path, half conifers (cone crowns), half broadleaves (spheres).
fn trees(b: &mut Builder, rng: &mut Rng, pts: &[DVec3], seed_offset: f64, m: &Palette) {
    let mut placed = 0;
    while placed < 140 {
        let (x, z) = (rng.range(-110.0, 110.0), rng.range(-110.0, 110.0));
        if dist_to_path(x, z, pts) < 6.0 {
            continue;
        }
        placed += 1;
        let y = height(x, z, pts, seed_offset) - 0.3;
        let trunk = rng.range(1.8, 3.5);
        let base = DVec3::new(x, y, z);
        if rng.f() < 0.5 {
            b.cylinder(base, base + DVec3::Y * (trunk + 0.5), 0.22, m.bark);
            let r = rng.range(1.4, 2.2);
            b.cone(
                base + DVec3::Y * trunk,
                base + DVec3::Y * (trunk + rng.range(4.0, 7.0)),
                r,
                m.needles,
            );
        } else {
            b.cylinder(base, base + DVec3::Y * (trunk + 0.8), 0.28, m.bark);
            let r = rng.range(1.5, 2.6);
            b.add(
                Shape::Sphere {
                    center: base + DVec3::Y * (trunk + r * 0.8),
                    radius: r,
                },
                m.leaves,
            );
        }
    }
}

/// 40 half-buried rocks away from the path.
fn rocks(b: &mut Builder, rng: &mut Rng, pts: &[DVec3], seed_offset: f64, rock: usize) {
    let mut placed = 0;
    while placed < 40 {
        let (x, z) = (rng.range(-80.0, 80.0), rng.range(-80.0, 80.0));
        let r = rng.range(0.4, 1.6);
        if dist_to_path(x, z, pts) < 3.0 + r {
            continue;
        }
        placed += 1;
        let y = height(x, z, pts, seed_offset) - 0.4 * r;
        b.add(
            Shape::Sphere {
                center: DVec3::new(x, y, z),
                radius: r,
            },
            rock,
        );
    }
}

/// Far hills: big spheres sunk below the horizon, beyond the terrain.
fn far_hills(b: &mut Builder, rng: &mut Rng, hills: usize) {
    for k in 0..14 {
        let a = k as f64 / 14.0 * std::f64::consts::TAU + rng.range(-0.1, 0.1);
        let dist = rng.range(380.0, 600.0);
        let r = rng.range(120.0, 220.0);
        b.add(
            Shape::Sphere {
                center: DVec3::new(a.cos() * dist, -r * 0.75, a.sin() * dist),
                radius: r,
            },
            hills,
        );
    }
}
