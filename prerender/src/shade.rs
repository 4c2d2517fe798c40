//! Shading: textures, direct light from the sun and point lights (with shadow rays against
//! the whole scene), sky ambient, the sky itself, and linear → sRGB8.

use std::sync::OnceLock;

use glam::DVec3;

use crate::accel::Hit;
use crate::scene::{Material, Scene, Sky, Texture};

/// Angular radius of the sun disc drawn in the sky (cosine).
const SUN_DISC_COS: f64 = 0.99993; // ≈ 0.68°

/// Linear colour of the sky in unit direction `d`.
pub(crate) fn sky_color(scene: &Scene, d: DVec3) -> DVec3 {
    let sky: &Sky = &scene.desc().sky;
    let y = d.y.clamp(-1.0, 1.0);
    let mut c = if y >= 0.0 {
        sky.horizon.lerp(sky.zenith, y.sqrt())
    } else {
        sky.horizon.lerp(sky.ground, (-y * 6.0).min(1.0))
    };
    if let Some(sun) = &scene.desc().sun {
        let cos = d.dot(sun.direction);
        if cos > SUN_DISC_COS {
            c = DVec3::splat(1.0);
        } else if cos > 0.0 {
            c += sun.color * 0.08 * cos.powi(64);
        }
    }
    c
}

/// Linear colour of the surface hit by the unit ray `o + t d`.
pub(crate) fn shade(scene: &Scene, o: DVec3, d: DVec3, hit: &Hit, shadows: bool) -> DVec3 {
    let prim = &scene.accel.prims[hit.prim as usize];
    let p = o + d * hit.t;
    let mut n = prim.normal(p, hit.part);
    if n.dot(d) > 0.0 {
        n = -n;
    }
    let desc = scene.desc();
    let mat = &desc.materials[scene.prim_material[hit.prim as usize] as usize];
    let albedo = albedo(mat, p, n);
    let sky = &desc.sky;
    // Hemisphere ambient: more from the sky above than from the ground below.
    let up = 0.5 + 0.5 * n.y;
    let mut light =
        (sky.zenith.lerp(sky.horizon, 0.5) * up + sky.ground * (1.0 - up)) * sky.ambient;
    let eps = 1e-7 * (p.abs().max_element() + hit.t) + 1e-300;
    let start = p + n * eps;
    if let Some(sun) = &desc.sun {
        let ndl = n.dot(sun.direction);
        if ndl > 0.0 && !(shadows && scene.occluded(start, sun.direction, 0.0, f64::INFINITY)) {
            light += sun.color * ndl;
        }
    }
    for l in &desc.lights {
        let v = l.position - start;
        let dist = v.length();
        if dist == 0.0 || !dist.is_finite() {
            continue;
        }
        let dir = v / dist;
        let ndl = n.dot(dir);
        let add = l.color * (ndl / (dist * dist));
        // A light adding less than 0.2% to what is already there changes no sRGB8 level
        // worth a shadow ray.
        if ndl > 0.0
            && add.max_element() > 2e-3 * light.max_element()
            && !(shadows && scene.occluded(start, dir, 0.0, dist * (1.0 - 1e-9)))
        {
            light += add;
        }
    }
    albedo * light
}

/// Planar texture coordinates: `p` projected on the axis plane most facing `n`; the first
/// coordinate runs horizontally and, on walls, the second is height. Returns the dominant
/// axis too (1 = horizontal surface).
#[inline]
fn planar(p: DVec3, n: DVec3) -> (f64, f64, usize) {
    let a = n.abs();
    if a.y >= a.x && a.y >= a.z {
        (p.x, p.z, 1)
    } else if a.x >= a.z {
        (p.z, p.y, 0)
    } else {
        (p.x, p.y, 2)
    }
}

#[inline]
fn hash3(x: i64, y: i64, z: i64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1].
pub(crate) fn value_noise(p: DVec3) -> f64 {
    let f = p.floor();
    let t = p - f;
    let s = t * t * (DVec3::splat(3.0) - 2.0 * t);
    let (x, y, z) = (f.x as i64, f.y as i64, f.z as i64);
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = (if dx == 1 { s.x } else { 1.0 - s.x })
                    * (if dy == 1 { s.y } else { 1.0 - s.y })
                    * (if dz == 1 { s.z } else { 1.0 - s.z });
                acc += w * hash3(x + dx, y + dy, z + dz);
            }
        }
    }
    acc
}

fn albedo(m: &Material, p: DVec3, n: DVec3) -> DVec3 {
    match &m.texture {
        Texture::Solid => m.color,
        Texture::Checker { color2, size } => {
            let (u, v, _) = planar(p, n);
            let k = (u / size).floor() as i64 + (v / size).floor() as i64;
            if k.rem_euclid(2) == 0 {
                m.color
            } else {
                *color2
            }
        }
        Texture::Noise { color2, size } => {
            let q = p / *size;
            let v = 0.65 * value_noise(q) + 0.35 * value_noise(q * 2.7 + 17.0);
            m.color.lerp(*color2, v)
        }
        Texture::Bricks {
            mortar,
            width,
            height,
            joint,
        } => {
            let (u, v, axis) = planar(p, n);
            if axis == 1 {
                return m.color;
            }
            let row = (v / height).floor();
            let shift = if (row as i64).rem_euclid(2) == 1 {
                0.5 * width
            } else {
                0.0
            };
            let col = ((u + shift) / width).floor();
            let fu = (u + shift) - col * width;
            let fv = v - row * height;
            if fu < *joint || fv < *joint {
                *mortar
            } else {
                m.color * (0.85 + 0.3 * hash3(row as i64, col as i64, axis as i64))
            }
        }
        Texture::Windows {
            glass,
            spacing,
            size,
        } => {
            let (u, v, axis) = planar(p, n);
            if axis == 1 {
                return m.color;
            }
            let (cu, cv) = ((u / spacing[0]).floor(), (v / spacing[1]).floor());
            let fu = u - cu * spacing[0] - 0.5 * spacing[0];
            let fv = v - cv * spacing[1] - 0.5 * spacing[1];
            if fu.abs() < 0.5 * size[0] && fv.abs() < 0.5 * size[1] {
                let lit = hash3(cu as i64, cv as i64, axis as i64 + 7);
                if lit > 0.85 {
                    DVec3::new(1.0, 0.85, 0.5)
                } else {
                    *glass * (0.7 + 0.6 * lit)
                }
            } else {
                m.color
            }
        }
        Texture::Image { image, size } => {
            let (u, v, _) = planar(p, n);
            let fu = (u / size).rem_euclid(1.0);
            let fv = 1.0 - (v / size).rem_euclid(1.0);
            let x = ((fu * image.width as f64) as u32).min(image.width - 1);
            let y = ((fv * image.height as f64) as u32).min(image.height - 1);
            let t = image.texels[(y * image.width + x) as usize];
            m.color * DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
        }
    }
}

const LUT_SIZE: usize = 8192;

fn srgb_lut() -> &'static [u8; LUT_SIZE] {
    static LUT: OnceLock<[u8; LUT_SIZE]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0u8; LUT_SIZE];
        for (i, v) in t.iter_mut().enumerate() {
            let c = i as f64 / (LUT_SIZE - 1) as f64;
            let s = if c <= 0.003_130_8 {
                12.92 * c
            } else {
                1.055 * c.powf(1.0 / 2.4) - 0.055
            };
            *v = (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8;
        }
        t
    })
}

/// Linear RGB (clamped to [0, 1]) → sRGB8.
#[inline]
pub(crate) fn to_srgb8(c: DVec3) -> [u8; 3] {
    let lut = srgb_lut();
    let q = |x: f64| {
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
        lut[(x * (LUT_SIZE - 1) as f64 + 0.5) as usize]
    };
    [q(c.x), q(c.y), q(c.z)]
}

/// sRGB8 → linear, exact inverse of the transfer curve (for image textures).
pub(crate) fn srgb8_to_linear(v: u8) -> f32 {
    let s = v as f64 / 255.0;
    (if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_end_points_and_monotone() {
        assert_eq!(to_srgb8(DVec3::ZERO), [0, 0, 0]);
        assert_eq!(to_srgb8(DVec3::ONE), [255, 255, 255]);
        assert_eq!(to_srgb8(DVec3::splat(f64::NAN)), [0, 0, 0]);
        let mut last = 0;
        for i in 0..=100 {
            let v = to_srgb8(DVec3::splat(i as f64 / 100.0))[0];
            assert!(v >= last);
            last = v;
        }
        assert_eq!(to_srgb8(DVec3::splat(srgb8_to_linear(128) as f64))[0], 128);
    }

    #[test]
    fn noise_is_bounded_and_continuous() {
        for i in 0..200 {
            let p = DVec3::new(i as f64 * 0.37, i as f64 * -0.11, 3.3);
            let a = value_noise(p);
            let b = value_noise(p + 1e-6);
            assert!((0.0..=1.0).contains(&a));
            assert!((a - b).abs() < 1e-4);
        }
    }
}
