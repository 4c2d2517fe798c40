//! Renderers: cube maps of colour and radial depth, slab layers in one pass, a fast low-res
//! depth pass, and perspective ground truth.
//!
//! Every pixel is computed independently from its direction (rows run in parallel with rayon),
//! so serial and parallel runs give identical pixels. Depth is the exact radial distance of
//! the surface hit by the pixel-centre ray (`+inf` for sky); colour is sRGB8, averaged in
//! linear light over `supersample²` stratified rays when `supersample > 1`.
//!
//! ```
//! use prerender::render::{composite_layers, render_cube, render_sky, render_slabs, RenderOptions};
//! use prerender::scenes::builtin;
//! use tracks::SlabRange;
//!
//! let castle = builtin("castle").unwrap();
//! let at = castle.tracks.get("main").unwrap().viewpoints()[3].position;
//! let opts = RenderOptions { face_size: 8, supersample: 1, shadows: true };
//! let cube = render_cube(&castle.scene, at, opts);
//! let slabs = SlabRange::parse_list("0-10,10-inf").unwrap();
//! let layers = render_slabs(&castle.scene, at, &slabs, opts);
//! let (color, depth) = composite_layers(&layers, &render_sky(&castle.scene, 8, 1));
//! assert_eq!((color, depth), (cube.color, cube.depth));
//! ```

use glam::DVec3;
use rayon::prelude::*;
use tracks::cubemap::{subpixel_dir, Face};
use tracks::{CubeMap, PerspectiveCamera, SlabRange};

use crate::accel::Hit;
use crate::scene::Scene;
use crate::shade::{shade, sky_color, to_srgb8};

/// What to render at a viewpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderOptions {
    /// Pixels along one side of a cube face.
    pub face_size: u32,
    /// Rays per pixel along each axis for colour (1 = pixel centre only).
    pub supersample: u32,
    /// Trace shadow rays towards the lights.
    pub shadows: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            face_size: 512,
            supersample: 1,
            shadows: true,
        }
    }
}

/// A rendered cube map.
#[derive(Clone, Debug, PartialEq)]
pub struct CubeRender {
    pub color: CubeMap<[u8; 3]>,
    /// Radial distance, metres; `+inf` = sky.
    pub depth: CubeMap<f32>,
    /// Rays traced from the viewpoint (not counting shadow rays).
    pub primary_rays: u64,
}

/// One slab's layer at a viewpoint.
#[derive(Clone, Debug, PartialEq)]
pub struct SlabLayer {
    pub range: SlabRange,
    /// sRGB8 colour; alpha 255 where the slab holds a surface, 0 where empty.
    pub color: CubeMap<[u8; 4]>,
    /// Radial depth of the slab's surface, `+inf` where empty.
    pub depth: CubeMap<f32>,
}

/// A perspective ground-truth image (row-major, `width × height`).
#[derive(Clone, Debug, PartialEq)]
pub struct PerspectiveRender {
    pub width: u32,
    pub height: u32,
    pub color: Vec<[u8; 3]>,
    /// Radial distance from the camera position, `+inf` = sky.
    pub depth: Vec<f32>,
}

#[inline]
fn depth_f32(h: Option<Hit>) -> f32 {
    h.map_or(f32::INFINITY, |h| h.t as f32)
}

/// Linear colour seen along one ray (surface or sky).
#[inline]
fn ray_color(scene: &Scene, o: DVec3, d: DVec3, shadows: bool) -> (DVec3, Option<Hit>) {
    match scene.hit_in(o, d, 0.0, f64::INFINITY) {
        Some(h) => (shade(scene, o, d, &h, shadows), Some(h)),
        None => (sky_color(scene, d), None),
    }
}

/// Colour (sRGB8) and radial depth seen along one unit ray: what a pixel-centre ray gives.
pub fn trace_ray(scene: &Scene, origin: DVec3, dir: DVec3, shadows: bool) -> ([u8; 3], f32) {
    let (c, h) = ray_color(scene, origin, dir, shadows);
    (to_srgb8(c), depth_f32(h))
}

/// Subpixel offsets (within a pixel, in pixel units) of a `ss × ss` stratified grid.
fn offsets(ss: u32) -> Vec<(f64, f64)> {
    let ss = ss.max(1);
    let mut v = Vec::with_capacity((ss * ss) as usize);
    for j in 0..ss {
        for i in 0..ss {
            v.push(((i as f64 + 0.5) / ss as f64, (j as f64 + 0.5) / ss as f64));
        }
    }
    v
}

/// Colour and depth for one pixel, given a map from continuous pixel position to direction.
#[inline]
fn pixel(
    scene: &Scene,
    o: DVec3,
    x: u32,
    y: u32,
    offs: &[(f64, f64)],
    shadows: bool,
    dir: impl Fn(f64, f64) -> DVec3,
) -> ([u8; 3], f32) {
    let centre = dir(x as f64 + 0.5, y as f64 + 0.5);
    if offs.len() == 1 {
        let (c, h) = ray_color(scene, o, centre, shadows);
        return (to_srgb8(c), depth_f32(h));
    }
    let depth = depth_f32(scene.hit_in(o, centre, 0.0, f64::INFINITY));
    let mut sum = DVec3::ZERO;
    for &(dx, dy) in offs {
        sum += ray_color(scene, o, dir(x as f64 + dx, y as f64 + dy), shadows).0;
    }
    (to_srgb8(sum / offs.len() as f64), depth)
}

fn rays_per_pixel(ss: u32) -> u64 {
    let ss = ss.max(1) as u64;
    if ss == 1 {
        1
    } else {
        ss * ss + 1
    }
}

/// Render colour and depth of the full cube map seen from `position`.
pub fn render_cube(scene: &Scene, position: DVec3, opts: RenderOptions) -> CubeRender {
    let n = opts.face_size;
    let offs = offsets(opts.supersample);
    let rows: Vec<(Vec<[u8; 3]>, Vec<f32>)> = (0..6 * n)
        .into_par_iter()
        .map(|r| {
            let face = Face::ALL[(r / n) as usize];
            let y = r % n;
            (0..n)
                .map(|x| {
                    pixel(scene, position, x, y, &offs, opts.shadows, |px, py| {
                        subpixel_dir(face, px, py, n)
                    })
                })
                .unzip()
        })
        .collect();
    let (color, depth): (Vec<_>, Vec<_>) = rows.into_iter().unzip();
    let color = color.into_iter().flatten().collect();
    let depth = depth.into_iter().flatten().collect();
    CubeRender {
        color: CubeMap::from_vec(n, color).expect("6·N² colour texels"),
        depth: CubeMap::from_vec(n, depth).expect("6·N² depth texels"),
        primary_rays: 6 * (n as u64) * (n as u64) * rays_per_pixel(opts.supersample),
    }
}

/// The sky alone (what shows where every slab is empty), sRGB8.
pub fn render_sky(scene: &Scene, face_size: u32, supersample: u32) -> CubeMap<[u8; 3]> {
    let offs = offsets(supersample);
    CubeMap::from_fn(face_size, |face, x, y| {
        if offs.len() == 1 {
            let d = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, face_size);
            return to_srgb8(sky_color(scene, d));
        }
        let mut sum = DVec3::ZERO;
        for &(dx, dy) in &offs {
            sum += sky_color(
                scene,
                subpixel_dir(face, x as f64 + dx, y as f64 + dy, face_size),
            );
        }
        to_srgb8(sum / offs.len() as f64)
    })
}

/// Render one layer per slab in a single traversal per ray: layer `k` holds the first
/// surface whose radial distance lies in `slabs[k]` (nearer surfaces removed, lighting and
/// shadows from the whole scene). `slabs` must be sorted and not overlap (as
/// [`SlabRange::parse_list`] returns them). Mask and depth come from the pixel-centre ray.
/// With `supersample > 1`, the layer that the pixel-centre ray sees first holds the
/// anti-aliased colour of the whole pixel (every subsample ray's first surface, or sky), so
/// the layers composited front to back give the anti-aliased panorama; a layer hidden behind
/// it averages the subsample rays whose hit falls in its slab.
pub fn render_slabs(
    scene: &Scene,
    position: DVec3,
    slabs: &[SlabRange],
    opts: RenderOptions,
) -> Vec<SlabLayer> {
    let n = opts.face_size;
    let k = slabs.len();
    let ranges: Vec<(f64, f64)> = slabs.iter().map(|s| (s.near, s.far)).collect();
    let offs = offsets(opts.supersample);
    let rows: Vec<Vec<([u8; 4], f32)>> = (0..6 * n)
        .into_par_iter()
        .map(|r| {
            let face = Face::ALL[(r / n) as usize];
            let y = r % n;
            let mut out = Vec::with_capacity(n as usize * k);
            let mut hits = vec![None; k];
            let mut sub = vec![None; k];
            let mut sums = vec![(DVec3::ZERO, 0u32); k];
            for x in 0..n {
                let d = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, n);
                scene.hits_in_ranges(position, d, &ranges, &mut hits);
                // The pixel's anti-aliased colour: each subsample ray's first surface in any
                // slab (or the sky), averaged.
                let mut seen = DVec3::ZERO;
                if offs.len() > 1 {
                    sums.iter_mut().for_each(|s| *s = (DVec3::ZERO, 0));
                    for &(dx, dy) in &offs {
                        let ds = subpixel_dir(face, x as f64 + dx, y as f64 + dy, n);
                        scene.hits_in_ranges(position, ds, &ranges, &mut sub);
                        let mut first = true;
                        for (s, h) in sums.iter_mut().zip(&sub) {
                            if let Some(h) = h {
                                let c = shade(scene, position, ds, h, opts.shadows);
                                s.0 += c;
                                s.1 += 1;
                                if first {
                                    seen += c;
                                    first = false;
                                }
                            }
                        }
                        if first {
                            seen += sky_color(scene, ds);
                        }
                    }
                }
                let front = hits.iter().position(Option::is_some);
                for (i, h) in hits.iter().enumerate() {
                    out.push(match h {
                        None => ([0, 0, 0, 0], f32::INFINITY),
                        Some(h) => {
                            let c = if offs.len() > 1 && front == Some(i) {
                                seen / offs.len() as f64
                            } else if offs.len() > 1 && sums[i].1 > 0 {
                                sums[i].0 / sums[i].1 as f64
                            } else {
                                shade(scene, position, d, h, opts.shadows)
                            };
                            let [r, g, b] = to_srgb8(c);
                            ([r, g, b, 255], h.t as f32)
                        }
                    });
                }
            }
            out
        })
        .collect();
    let mut colors = vec![Vec::with_capacity(6 * (n * n) as usize); k];
    let mut depths = vec![Vec::with_capacity(6 * (n * n) as usize); k];
    for row in rows {
        for px in row.chunks_exact(k.max(1)) {
            for (i, &(c, d)) in px.iter().enumerate() {
                colors[i].push(c);
                depths[i].push(d);
            }
        }
    }
    slabs
        .iter()
        .zip(colors.into_iter().zip(depths))
        .map(|(range, (c, d))| SlabLayer {
            range: *range,
            color: CubeMap::from_vec(n, c).expect("6·N² slab texels"),
            depth: CubeMap::from_vec(n, d).expect("6·N² slab depths"),
        })
        .collect()
}

/// Composite slab layers front to back over `background`: at each texel the first layer whose
/// mask is set wins. Also returns the composited depth (`+inf` where only background shows).
pub fn composite_layers(
    layers: &[SlabLayer],
    background: &CubeMap<[u8; 3]>,
) -> (CubeMap<[u8; 3]>, CubeMap<f32>) {
    let mut color = background.clone();
    let mut depth = CubeMap::filled(background.face_size(), f32::INFINITY);
    for i in 0..color.as_slice().len() {
        if let Some(l) = layers.iter().find(|l| l.color.as_slice()[i][3] == 255) {
            let [r, g, b, _] = l.color.as_slice()[i];
            color.as_mut_slice()[i] = [r, g, b];
            depth.as_mut_slice()[i] = l.depth.as_slice()[i];
        }
    }
    (color, depth)
}

/// Depth only, pixel centres, no shading: the fast low-resolution pass.
pub fn render_depth_lowres(scene: &Scene, position: DVec3, face_size: u32) -> CubeMap<f32> {
    let n = face_size;
    let rows: Vec<Vec<f32>> = (0..6 * n)
        .into_par_iter()
        .map(|r| {
            let face = Face::ALL[(r / n) as usize];
            let y = r % n;
            (0..n)
                .map(|x| {
                    let d = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, n);
                    depth_f32(scene.hit_in(position, d, 0.0, f64::INFINITY))
                })
                .collect()
        })
        .collect();
    CubeMap::from_vec(n, rows.into_iter().flatten().collect()).expect("6·N² depths")
}

/// A perspective view (camera convention of [`tracks::camera`]).
pub fn render_perspective(
    scene: &Scene,
    camera: &PerspectiveCamera,
    supersample: u32,
) -> PerspectiveRender {
    let offs = offsets(supersample);
    let (w, h) = (camera.width, camera.height);
    let rows: Vec<(Vec<[u8; 3]>, Vec<f32>)> = (0..h)
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| {
                    pixel(scene, camera.position, x, y, &offs, true, |px, py| {
                        camera.ray_dir(px, py)
                    })
                })
                .unzip()
        })
        .collect();
    let (color, depth): (Vec<_>, Vec<_>) = rows.into_iter().unzip();
    PerspectiveRender {
        width: w,
        height: h,
        color: color.into_iter().flatten().collect(),
        depth: depth.into_iter().flatten().collect(),
    }
}

#[cfg(test)]
#[path = "render_tests.rs"]
mod tests;
