//! Colour and depth lookups in a reference panorama by direction, in linear light.
//!
//! Texel centres are at half-integers ([`tracks::cubemap`]). Filters read texels beyond a
//! face's edge from the neighbouring face (the texel whose centre the off-face direction falls
//! in), so lookups are continuous across face borders up to the distortion of one texel.

use std::sync::LazyLock;

use glam::DVec3;
use tracks::cubemap::{subpixel_dir, FaceCoord};
use tracks::{CubeMap, Face};

use crate::Filter;

/// Linear RGB, `f32` per channel.
pub(crate) type Linear = [f32; 3];

/// sRGB byte → linear (a table of the standard curve).
pub(crate) fn srgb_to_linear(c: u8) -> f32 {
    static TABLE: LazyLock<[f32; 256]> = LazyLock::new(|| {
        std::array::from_fn(|b| {
            let c = b as f64 / 255.0;
            let l = if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            };
            l as f32
        })
    });
    TABLE[c as usize]
}

/// Linear → sRGB byte (standard curve, clamped to [0, 1], rounded; NaN gives 0).
pub(crate) fn linear_to_srgb(c: f32) -> u8 {
    if c.is_nan() {
        return 0;
    }
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round().clamp(0.0, 255.0) as u8
}

/// A linear colour as sRGB bytes.
pub(crate) fn encode(c: Linear) -> [u8; 3] {
    c.map(linear_to_srgb)
}

/// The cube-map index of texel `(x, y)` of `face`, where `x` and `y` may lie outside the face
/// (a few texels at most): such a texel is the one on the neighbouring face that holds the
/// centre's direction.
fn texel_index<T>(map: &CubeMap<T>, face: Face, x: i64, y: i64) -> usize {
    let n = map.face_size();
    if (0..n as i64).contains(&x) && (0..n as i64).contains(&y) {
        return map.index(face, x as u32, y as u32);
    }
    let dir = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, n);
    match FaceCoord::from_dir(dir) {
        Some(c) => {
            let (cx, cy) = c.to_pixel(n);
            map.index(c.face, cx, cy)
        }
        None => {
            // Unreachable for the small offsets used here; clamp onto the face to stay total.
            let max = n.saturating_sub(1) as i64;
            map.index(face, x.clamp(0, max) as u32, y.clamp(0, max) as u32)
        }
    }
}

/// Where a direction falls: the face and the continuous texel coordinates relative to texel
/// centres (texel `(i, j)`'s centre is at `(i, j)`).
fn locate(dir: DVec3, n: u32) -> Option<(Face, f64, f64)> {
    let c = FaceCoord::from_dir(dir)?;
    let (x, y) = c.to_pixel_f(n);
    Some((c.face, x - 0.5, y - 0.5))
}

/// The colour of the surface at `to_point` (from the reference's position), filtered in
/// linear light over the texels that lie on that surface: those whose depth is within a ratio
/// of `1 + same_surface` of `|to_point|`, weights renormalised, so colours of another surface
/// across a silhouette do not bleed in. Bicubic falls back to bilinear where a texel of its
/// 4×4 is off the surface; with no texel on it, the plain filter. `None` only for a zero or
/// non-finite direction.
pub(crate) fn surface_color(
    color: &CubeMap<[u8; 3]>,
    depth: &CubeMap<f32>,
    to_point: DVec3,
    filter: Filter,
    same_surface: f64,
) -> Option<Linear> {
    let n = color.face_size();
    let (face, x, y) = locate(to_point, n)?;
    let r = to_point.length();
    let on_surface = |at: usize| {
        let d = depth.as_slice()[at] as f64;
        d.is_finite() && d.max(r) <= d.min(r) * (1.0 + same_surface)
    };
    let (ix, iy) = (x.floor(), y.floor());
    let (fx, fy) = (x - ix, y - iy);
    let (ix, iy) = (ix as i64, iy as i64);
    if filter == Filter::Bicubic {
        let (wx, wy) = (catmull_rom(fx), catmull_rom(fy));
        let texels: [usize; 16] = std::array::from_fn(|k| {
            texel_index(
                color,
                face,
                ix + (k % 4) as i64 - 1,
                iy + (k / 4) as i64 - 1,
            )
        });
        if texels.iter().all(|&at| on_surface(at)) {
            let weights = texels
                .iter()
                .enumerate()
                .map(|(k, &at)| (at, wx[k % 4] * wy[k / 4]));
            return Some(weighted(color, weights).map(|c| c.max(0.0)));
        }
    }
    let texels: [(usize, f64); 4] = std::array::from_fn(|k| {
        let (i, j) = ((k % 2) as i64, (k / 2) as i64);
        let w = [1.0 - fx, fx][k % 2] * [1.0 - fy, fy][k / 2];
        (texel_index(color, face, ix + i, iy + j), w)
    });
    let total: f64 = texels.iter().filter(|t| on_surface(t.0)).map(|t| t.1).sum();
    if total > 0.0 {
        let masked = texels
            .iter()
            .map(|&(at, w)| (at, if on_surface(at) { w / total } else { 0.0 }));
        return Some(weighted(color, masked));
    }
    Some(weighted(color, texels.into_iter()))
}

/// `Σ w · colour[at]` in linear light.
fn weighted(color: &CubeMap<[u8; 3]>, texels: impl Iterator<Item = (usize, f64)>) -> Linear {
    let mut sum = [0.0f64; 3];
    for (at, w) in texels {
        let c = color.as_slice()[at].map(srgb_to_linear);
        for k in 0..3 {
            sum[k] += w * c[k] as f64;
        }
    }
    sum.map(|s| s as f32)
}

/// The colour along `dir` (any length, non-zero), filtered in linear light over all texels
/// (what a lookup without depth gives). `None` only for a zero or non-finite direction.
pub(crate) fn color(color: &CubeMap<[u8; 3]>, dir: DVec3, filter: Filter) -> Option<Linear> {
    let (face, x, y) = locate(dir, color.face_size())?;
    let (ix, iy) = (x.floor(), y.floor());
    let (fx, fy) = (x - ix, y - iy);
    let (ix, iy) = (ix as i64, iy as i64);
    let at =
        |i: usize, j: usize, o: i64| texel_index(color, face, ix + i as i64 - o, iy + j as i64 - o);
    let c = match filter {
        Filter::Bilinear => {
            let (wx, wy) = ([1.0 - fx, fx], [1.0 - fy, fy]);
            weighted(
                color,
                (0..4).map(|k| (at(k % 2, k / 2, 0), wx[k % 2] * wy[k / 2])),
            )
        }
        Filter::Bicubic => {
            let (wx, wy) = (catmull_rom(fx), catmull_rom(fy));
            weighted(
                color,
                (0..16).map(|k| (at(k % 4, k / 4, 1), wx[k % 4] * wy[k / 4])),
            )
        }
    };
    Some(c.map(|v| v.max(0.0)))
}

/// Catmull-Rom weights of the texels at offsets −1, 0, 1, 2 for a fraction `t` in [0, 1).
fn catmull_rom(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Whether a depth is sky: not a finite number (+inf by convention).
pub(crate) fn is_sky(depth: f32) -> bool {
    !depth.is_finite()
}

/// The sky colour along `dir` when the reference sees sky there (the depth texel holding the
/// direction is sky): bilinear over the neighbouring sky texels only (weights renormalised),
/// so foreground colours never bleed into the sky. `None` when the reference sees a surface
/// (or nothing: a zero direction).
pub(crate) fn sky(color: &CubeMap<[u8; 3]>, depth: &CubeMap<f32>, dir: DVec3) -> Option<Linear> {
    let n = depth.face_size();
    let c = FaceCoord::from_dir(dir)?;
    let (px, py) = c.to_pixel(n);
    let nearest = depth.index(c.face, px, py);
    if !is_sky(depth.as_slice()[nearest]) {
        return None;
    }
    let (face, x, y) = locate(dir, n)?;
    let (ix, iy) = (x.floor(), y.floor());
    let (fx, fy) = (x - ix, y - iy);
    let (ix, iy) = (ix as i64, iy as i64);
    let mut sum = [0.0f64; 3];
    let mut total = 0.0;
    for (j, wy) in [1.0 - fy, fy].into_iter().enumerate() {
        for (i, wx) in [1.0 - fx, fx].into_iter().enumerate() {
            let at = texel_index(depth, face, ix + i as i64, iy + j as i64);
            if !is_sky(depth.as_slice()[at]) {
                continue;
            }
            let w = wx * wy;
            let c = color.as_slice()[at].map(srgb_to_linear);
            for k in 0..3 {
                sum[k] += w * c[k] as f64;
            }
            total += w;
        }
    }
    if total <= 0.0 {
        return Some(color.as_slice()[nearest].map(srgb_to_linear));
    }
    Some(sum.map(|s| (s / total) as f32))
}
