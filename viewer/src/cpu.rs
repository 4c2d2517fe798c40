//! CPU reference of the GPU path: executes a [`FramePlan`] with the same math as
//! `render.wgsl`/`composite.wgsl` (f32 uniforms, projective texturing from the reference
//! viewpoint, reversed-Z depth test, opacity mask at 0.5, trilinear sampling with the same
//! clamping) but without wgpu: near-plane clipping, edge-function rasterisation at pixel
//! centres and perspective-correct interpolation are done here.
//!
//! It is slow and meant for small images: tests compare it with the GPU and state the
//! tolerance (rasterisation tie rules at shared edges and texture-filter precision differ).
//! It draws the full tile meshes (`FramePlan::mesh_level` is ignored), each view on its own
//! as the GPU does for frames with tile ids, and no debug overlays.

use glam::{Mat4, Vec3, Vec4};
use tracks::Face;

use crate::frame::Frame;
use crate::plan::{FramePlan, ViewPass, NEAR_M};
use crate::refview::stretch::{split_stretched, STRETCH_PUSH};
use crate::refview::RefView;
use crate::texture::{linear_to_srgb, Layer};

fn face_of(d: Vec3) -> Face {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        if d.x > 0.0 {
            Face::PosX
        } else {
            Face::NegX
        }
    } else if a.y >= a.z {
        if d.y > 0.0 {
            Face::PosY
        } else {
            Face::NegY
        }
    } else if d.z > 0.0 {
        Face::PosZ
    } else {
        Face::NegZ
    }
}

fn basis(f: Face) -> (Vec3, Vec3, Vec3) {
    (f.forward().as_vec3(), f.right().as_vec3(), f.up().as_vec3())
}

fn pixel_on_face(f: Face, d: Vec3, n: f32) -> (f64, f64) {
    let (fw, r, u) = basis(f);
    let z = d.dot(fw);
    let (uu, vv) = (d.dot(r) / z, d.dot(u) / z);
    (((uu + 1.0) * 0.5 * n) as f64, ((1.0 - vv) * 0.5 * n) as f64)
}

/// A view's background layer `bg` along the ray through the centre of pixel `(x, y)` of a
/// `width × height` frame with the pass uniforms `u`, at the frame's level of detail (as
/// `background_of` in `render.wgsl`).
fn background_at(
    u: &crate::plan::ViewUniforms,
    bg: &Layer,
    (x, y): (u32, u32),
    (width, height): (u32, u32),
) -> [f32; 4] {
    let v3 = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
    let ndc_x = (x as f32 + 0.5) / width as f32 * 2.0 - 1.0;
    let ndc_y = 1.0 - (y as f32 + 0.5) / height as f32 * 2.0;
    let d = v3(u.ray_forward) + ndc_x * v3(u.ray_right) + ndc_y * v3(u.ray_up);
    let f = face_of(d);
    let (px, py) = pixel_on_face(f, d, u.origin_rel[3]);
    bg.sample(u.params[0], f, px, py)
}

/// One view pass: colour (linear RGB) with the distance to the camera in alpha (0 = hole),
/// and the drawn tile per pixel (index + 1, 0 = none).
pub struct PassImage {
    pub color: Vec<[f32; 4]>,
    pub tile: Vec<u32>,
    /// What the pass's tile meshes cost in fragments (overdraw).
    pub fragments: Fragments,
}

/// Mesh fragments of one view pass, in the plan's drawing order (front slab first): how
/// many pixel centres the triangles cover (`rasterised`), how many of those pass the depth
/// test when drawn (`shaded`: what a rasteriser with early depth testing shades) and how many
/// of those the opacity mask keeps (`kept`); `covered` = pixels a tile drew at the end.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fragments {
    pub rasterised: u64,
    pub shaded: u64,
    pub kept: u64,
    pub covered: u64,
}

/// Execute one view pass.
pub fn view_pass(pass: &ViewPass, view: &RefView, width: u32, height: u32) -> PassImage {
    let (w, h) = (width as usize, height as usize);
    let u = &pass.uniforms;
    let n = u.origin_rel[3];
    let lod = u.params[0];
    let mut color = vec![[0.0f32; 4]; w * h];
    let mut depth = vec![0.0f32; w * h];
    let mut tile_id = vec![0u32; w * h];
    let mut fragments = Fragments::default();
    let v3 = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
    let m = Mat4::from_cols_array_2d(&u.clip_from_cam);
    let origin = v3(u.origin_rel);
    let skirts = crate::refview::view_skirts(view);
    for &ti in &pass.visible {
        let tile = &view.tiles[ti];
        let face = tile.tile.face;
        let Some(layer) = view.layers.get(tile.slab as usize + 1) else {
            continue;
        };
        let tile_lod = lod.max(pass.tile_min_level.get(ti).copied().unwrap_or(0) as f32);
        let (fw, r, up) = basis(face);
        let (skirt_verts, skirt_idx) = &skirts[ti];
        // Stretched triangles on their own vertices, pushed back (`refview::stretch`, as
        // `vs_mesh`): clip z divided, the distance multiplied by STRETCH_PUSH.
        let (stretched, full) = split_stretched(&tile.mesh, face, view.face_size);
        let (own, skirt_n) = (tile.mesh.vertices.len() as u32, skirt_verts.len() as u32);
        let verts: Vec<(Vec4, Vec3, f32)> = tile
            .mesh
            .vertices
            .iter()
            .chain(skirt_verts)
            .map(|v| (v, 1.0))
            .chain(stretched.iter().map(|v| (v, STRETCH_PUSH)))
            .map(|(v, push)| {
                let uu = 2.0 * v[0] / n - 1.0;
                let vv = 1.0 - 2.0 * v[1] / n;
                let p = (fw + uu * r + vv * up).normalize() * v[2];
                let mut c = m * (p + origin).extend(1.0);
                c.z /= push;
                (c, p, push)
            })
            .collect();
        let indices: Vec<u32> = full
            .iter()
            .map(|&i| if i >= own { i + skirt_n } else { i })
            .chain(skirt_idx.iter().copied())
            .collect();
        for tri in indices.chunks_exact(3) {
            let push = verts[tri[0] as usize].2;
            let at = |i: u32| (verts[i as usize].0, verts[i as usize].1);
            let poly = clip_near([at(tri[0]), at(tri[1]), at(tri[2])]);
            for k in 1..poly.len().saturating_sub(1) {
                raster(
                    [poly[0], poly[k], poly[k + 1]],
                    (width, height),
                    &mut |idx, z, p| {
                        fragments.rasterised += 1;
                        if z <= depth[idx] {
                            return;
                        }
                        fragments.shaded += 1;
                        let (px, py) = pixel_on_face(face, p, n);
                        let c = layer.sample(tile_lod, face, px, py);
                        let level = tile_lod.min((layer.levels.len() - 1) as f32);
                        let cut = if tile.slab == 0 || level < 1.0 {
                            0.5
                        } else {
                            0.45
                        };
                        if c[3] >= cut {
                            fragments.kept += 1;
                            depth[idx] = z;
                            let dist = ((p + origin).length() * push).clamp(1e-3, SKY_DISTANCE);
                            color[idx] = [c[0], c[1], c[2], dist];
                            tile_id[idx] = ti as u32 + 1;
                        }
                    },
                );
            }
        }
    }
    // Background where no tile drew (as the GPU, after the meshes).
    if let Some(bg) = view.layers.first() {
        for y in 0..h {
            for x in 0..w {
                let c = background_at(u, bg, (x as u32, y as u32), (width, height));
                if c[3] > SEEN_SKY && depth[y * w + x] == 0.0 {
                    color[y * w + x] = [c[0], c[1], c[2], SKY_DISTANCE];
                }
            }
        }
    }
    fragments.covered = tile_id.iter().filter(|&&t| t > 0).count() as u64;
    PassImage {
        color,
        tile: tile_id,
        fragments,
    }
}

/// Sutherland–Hodgman against the near plane `w ≥ NEAR_M` (the GPU's `z ≤ w` with
/// `z = NEAR_M`).
fn clip_near(tri: [(Vec4, Vec3); 3]) -> Vec<(Vec4, Vec3)> {
    let near = NEAR_M as f32;
    let mut out = Vec::with_capacity(4);
    for i in 0..3 {
        let (a, b) = (tri[i], tri[(i + 1) % 3]);
        let (da, db) = (a.0.w - near, b.0.w - near);
        if da >= 0.0 {
            out.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            let t = da / (da - db);
            out.push((a.0.lerp(b.0, t), a.1.lerp(b.1, t)));
        }
    }
    out
}

/// Rasterise one clipped triangle: `frag(pixel index, ndc depth, interpolated p_ref)` for
/// every pixel centre inside it.
fn raster(tri: [(Vec4, Vec3); 3], size: (u32, u32), frag: &mut impl FnMut(usize, f32, Vec3)) {
    let (w, h) = (size.0 as f32, size.1 as f32);
    let s: Vec<(f32, f32, f32, f32)> = tri
        .iter()
        .map(|(c, _)| {
            let iw = 1.0 / c.w;
            (
                (c.x * iw + 1.0) * 0.5 * w,
                (1.0 - c.y * iw) * 0.5 * h,
                c.z * iw,
                iw,
            )
        })
        .collect();
    let area = (s[1].0 - s[0].0) * (s[2].1 - s[0].1) - (s[2].0 - s[0].0) * (s[1].1 - s[0].1);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let minx = s.iter().map(|p| p.0).fold(f32::INFINITY, f32::min).max(0.0);
    let maxx = s
        .iter()
        .map(|p| p.0)
        .fold(f32::NEG_INFINITY, f32::max)
        .min(w);
    let miny = s.iter().map(|p| p.1).fold(f32::INFINITY, f32::min).max(0.0);
    let maxy = s
        .iter()
        .map(|p| p.1)
        .fold(f32::NEG_INFINITY, f32::max)
        .min(h);
    if minx >= maxx || miny >= maxy {
        return;
    }
    let (x0, x1) = (
        (minx - 0.5).floor().max(0.0) as u32,
        (maxx as u32).min(size.0 - 1),
    );
    let (y0, y1) = (
        (miny - 0.5).floor().max(0.0) as u32,
        (maxy as u32).min(size.1 - 1),
    );
    let edge = |a: usize, b: usize, x: f32, y: f32| {
        (s[b].0 - s[a].0) * (y - s[a].1) - (s[b].1 - s[a].1) * (x - s[a].0)
    };
    for py in y0..=y1 {
        for px in x0..=x1 {
            let (x, y) = (px as f32 + 0.5, py as f32 + 0.5);
            let b0 = edge(1, 2, x, y) / area;
            let b1 = edge(2, 0, x, y) / area;
            let b2 = edge(0, 1, x, y) / area;
            if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                continue;
            }
            let z = b0 * s[0].2 + b1 * s[1].2 + b2 * s[2].2;
            let (q0, q1, q2) = (b0 * s[0].3, b1 * s[1].3, b2 * s[2].3);
            let p = (tri[0].1 * q0 + tri[1].1 * q1 + tri[2].1 * q2) / (q0 + q1 + q2);
            frag(py as usize * size.0 as usize + px as usize, z, p);
        }
    }
}

/// Distance written for the sky (as `SKY_DISTANCE` in `cube.wgsl`).
pub const SKY_DISTANCE: f32 = 60000.0;
/// A background texel's alpha above which its reference sees sky itself (as `SEEN_SKY` in
/// `cube.wgsl`; below: the sky behind its occluders, for the fill alone).
pub const SEEN_SKY: f32 = 0.998;
/// The offsets at which the fill probes each direction for a covered pixel (as
/// `FILL_STEPS` in `render.wgsl`).
pub const FILL_STEPS: [i64; 12] = [1, 2, 3, 4, 6, 8, 11, 16, 22, 30, 40, 48];
/// Output alpha of a filled pixel (as `FILLED_ALPHA` in `render.wgsl`).
pub const FILLED_ALPHA: u8 = 128;
/// Depth preference of the blend (as `SHARPNESS` in `composite.wgsl`).
pub const SHARPNESS: f32 = 20.0;

/// Blend of view passes exactly as `fs_blend`: alpha of a pass is 0 for a hole, else the
/// distance to the camera.
pub fn blend(passes: &[(f32, Vec<[f32; 4]>)], width: u32, height: u32) -> Frame {
    let count = (width * height) as usize;
    let mut rgba = Vec::with_capacity(count * 4);
    let empty = vec![[0.0f32; 4]; count];
    let a = passes.first().map_or(&empty, |p| &p.1);
    let b = passes.get(1).map_or(&empty, |p| &p.1);
    let (wa0, wb0) = (
        passes.first().map_or(0.0, |p| p.0),
        passes.get(1).map_or(0.0, |p| p.0),
    );
    for i in 0..count {
        let (pa, pb) = (a[i], b[i]);
        let ca = if pa[3] > 0.0 { 1.0 } else { 0.0 };
        let cb = if pb[3] > 0.0 { 1.0 } else { 0.0 };
        if ca + cb == 0.0 {
            rgba.extend_from_slice(&[0, 0, 0, 0]);
            continue;
        }
        let mut dmin = pa[3].max(pb[3]);
        if ca > 0.0 {
            dmin = dmin.min(pa[3]);
        }
        if cb > 0.0 {
            dmin = dmin.min(pb[3]);
        }
        let na = ca * (-SHARPNESS * (pa[3] / dmin - 1.0)).max(-80.0).exp();
        let nb = cb * (-SHARPNESS * (pb[3] / dmin - 1.0)).max(-80.0).exp();
        let (mut wa, mut wb) = (wa0 * na, wb0 * nb);
        if wa + wb <= 0.0 {
            (wa, wb) = (ca, cb);
        }
        let c: [f32; 3] = std::array::from_fn(|k| (pa[k] * wa + pb[k] * wb) / (wa + wb));
        rgba.extend_from_slice(&[
            linear_to_srgb(c[0]),
            linear_to_srgb(c[1]),
            linear_to_srgb(c[2]),
            255,
        ]);
    }
    Frame {
        width,
        height,
        rgba,
    }
}

/// Execute a plan on the CPU: both view passes, their blend, then the fill ([`fill`]).
pub fn render(plan: &FramePlan, views: &[RefView]) -> Frame {
    let drawn: Vec<(&ViewPass, &RefView)> = plan
        .passes
        .iter()
        .take(2)
        .filter_map(|p| Some((p, views.get(p.view)?)))
        .collect();
    let passes: Vec<(f32, Vec<[f32; 4]>)> = drawn
        .iter()
        .map(|(p, v)| {
            (
                p.weight as f32,
                view_pass(p, v, plan.width, plan.height).color,
            )
        })
        .collect();
    let mut frame = blend(&passes, plan.width, plan.height);
    // The heavier view's complete sky (the first of equal weights), as the GPU's group 0.
    let heavy = match drawn.len() {
        2 if drawn[1].0.weight > drawn[0].0.weight => Some(drawn[1]),
        0 => None,
        _ => Some(drawn[0]),
    };
    if let Some((p, v)) = heavy {
        let sky = complete_sky(p, v, plan.width, plan.height);
        let distance: Vec<f32> = (0..frame.rgba.len() / 4)
            .map(|i| {
                passes
                    .iter()
                    .map(|(_, c)| c[i][3])
                    .filter(|d| *d > 0.0)
                    .fold(0.0f32, |m, d| if m == 0.0 { d } else { m.min(d) })
            })
            .collect();
        fill(&mut frame, &distance, &sky);
    }
    frame
}

/// The background of `view` in the direction of every pixel of `pass`'s camera (linear
/// RGB), where it has any sky, seen or behind its occluders.
fn complete_sky(pass: &ViewPass, view: &RefView, width: u32, height: u32) -> Vec<Option<[f32; 3]>> {
    let Some(bg) = view.layers.first() else {
        return vec![None; (width * height) as usize];
    };
    let mut out = Vec::with_capacity((width * height) as usize);
    for y in 0..height {
        for x in 0..width {
            let c = background_at(&pass.uniforms, bg, (x, y), (width, height));
            out.push((c[3] > 0.0).then_some([c[0], c[1], c[2]]));
        }
    }
    out
}

/// Fill the pixels no view covers (alpha 0) from the farther side, as `fs_fill`: the
/// first covered pixel probed to the left, right, above and below (at [`FILL_STEPS`]); of
/// those the farthest (`distance`, 0 = none; sky at [`SKY_DISTANCE`]) gives its colour, or,
/// where it is sky or none is found, `sky` in the pixel's own direction where there is
/// any. Filled pixels get alpha [`FILLED_ALPHA`].
pub fn fill(frame: &mut Frame, distance: &[f32], sky: &[Option<[f32; 3]>]) {
    let (w, h) = (frame.width as i64, frame.height as i64);
    let covered = |x: i64, y: i64, rgba: &[u8]| rgba[((y * w + x) * 4 + 3) as usize] > 0;
    let src = frame.rgba.clone();
    for y in 0..h {
        for x in 0..w {
            if covered(x, y, &src) {
                continue;
            }
            let mut best: Option<(f32, i64)> = None;
            for (dx, dy) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                for k in FILL_STEPS {
                    let (qx, qy) = (x + dx * k, y + dy * k);
                    if qx < 0 || qy < 0 || qx >= w || qy >= h {
                        break;
                    }
                    if covered(qx, qy, &src) {
                        let q = qy * w + qx;
                        let d = distance[q as usize];
                        if best.is_none_or(|(bd, _)| d > bd) {
                            best = Some((d, q));
                        }
                        break;
                    }
                }
            }
            let i = ((y * w + x) * 4) as usize;
            let from_sky = best.is_none_or(|(d, _)| d >= SKY_DISTANCE);
            let own_sky = sky[(y * w + x) as usize];
            if let (true, Some(c)) = (from_sky, own_sky) {
                frame.rgba[i..i + 4].copy_from_slice(&[
                    linear_to_srgb(c[0]),
                    linear_to_srgb(c[1]),
                    linear_to_srgb(c[2]),
                    FILLED_ALPHA,
                ]);
            } else if let Some((_, q)) = best {
                let j = (q * 4) as usize;
                let c = [src[j], src[j + 1], src[j + 2]];
                frame.rgba[i..i + 4].copy_from_slice(&[c[0], c[1], c[2], FILLED_ALPHA]);
            }
        }
    }
}

/// The plain panorama of the first pass's view, as `fs_panorama`.
pub fn render_panorama(plan: &FramePlan, views: &[RefView]) -> Frame {
    let (w, h) = (plan.width, plan.height);
    let mut rgba = vec![0u8; (w * h * 4) as usize];
    let Some(pass) = plan.passes.first() else {
        return Frame {
            width: w,
            height: h,
            rgba,
        };
    };
    let Some(layer): Option<&Layer> = views.get(pass.view).and_then(|v| v.layers.first()) else {
        return Frame {
            width: w,
            height: h,
            rgba,
        };
    };
    for y in 0..h {
        for x in 0..w {
            let c = background_at(&pass.uniforms, layer, (x, y), (w, h));
            let i = ((y * w + x) * 4) as usize;
            rgba[i..i + 4].copy_from_slice(&[
                linear_to_srgb(c[0]),
                linear_to_srgb(c[1]),
                linear_to_srgb(c[2]),
                255,
            ]);
        }
    }
    Frame {
        width: w,
        height: h,
        rgba,
    }
}
