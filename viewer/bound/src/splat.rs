//! Splatting one reference panorama into the view: a z-buffer of view-space depth.
//!
//! Every reference pixel with a finite positive depth is a 3-D point. Its footprint on its
//! surface is the 3-D parallelogram `point ± h1 ± h2`, where `h1` and `h2` are half the steps
//! to its neighbours along the face's x and y axes (the forward neighbour, else the backward
//! one, when it lies on the same surface); the splat is that parallelogram's projection, a
//! convex quad. To first order it is the parallelogram spanned by the projected neighbours
//! that the recipe names, and unlike that it stays right near the camera plane, where
//! perspective is far from affine (a wall reaching past the camera's side would otherwise
//! smear across the whole view). Inside, inverse view depth is affine (exact for a planar
//! surface). An axis with no same-surface neighbour (a one-pixel feature), a corner behind the
//! near limit or a degenerate quad make the splat a square of the pixel's projected size at
//! the constant depth of its centre. Faces are walked row by row with three rows alive, so
//! memory is O(face size + view), not O(panorama).

use glam::DVec3;
use tracks::cubemap::pixel_dir;
use tracks::{Face, PerspectiveCamera};

use crate::{Reference, WarpOptions};

/// Points closer to the view camera than this (view-space depth, metres) are not splatted.
pub(crate) const NEAR_M: f64 = 0.01;

/// The view camera in the form the warp uses: `ray(x, y) = forward + sx·right + sy·up` with
/// `ray · forward = 1`, so the point at view depth `z` on a pixel's ray is `position + ray · z`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct View {
    pub position: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    pub forward: DVec3,
    /// Pixels per unit of image-plane coordinate at distance 1.
    pub focal: f64,
    pub width: usize,
    pub height: usize,
}

impl View {
    pub fn new(camera: &PerspectiveCamera) -> View {
        let (right, up, forward) = camera.basis();
        let tan = (camera.fov_deg.to_radians() * 0.5).tan();
        View {
            position: camera.position,
            right,
            up,
            forward,
            focal: camera.width as f64 / (2.0 * tan),
            width: camera.width as usize,
            height: camera.height as usize,
        }
    }

    /// The (unnormalised, `· forward = 1`) ray through the centre of pixel `(px, py)`.
    pub fn ray(&self, px: usize, py: usize) -> DVec3 {
        let sx = (px as f64 + 0.5 - self.width as f64 * 0.5) / self.focal;
        let sy = (self.height as f64 * 0.5 - (py as f64 + 0.5)) / self.focal;
        self.forward + sx * self.right + sy * self.up
    }

    /// Image position `(x, y)` (pixel units, centres at half-integers) and view depth of a
    /// point; `None` behind the near limit or when not finite.
    fn project(&self, p: DVec3) -> Option<Projected> {
        let d = p - self.position;
        let z = d.dot(self.forward);
        if !z.is_finite() || z < NEAR_M {
            return None;
        }
        let x = self.width as f64 * 0.5 + self.focal * d.dot(self.right) / z;
        let y = self.height as f64 * 0.5 - self.focal * d.dot(self.up) / z;
        (x.is_finite() && y.is_finite()).then_some(Projected { x, y, z })
    }
}

/// A point projected into the view.
#[derive(Clone, Copy, Debug)]
struct Projected {
    x: f64,
    y: f64,
    z: f64,
}

/// A reference pixel as a 3-D point.
#[derive(Clone, Copy, Debug)]
struct Texel {
    point: DVec3,
    /// Radial depth in the reference, metres.
    depth: f64,
    /// Where it lands in the view, if in front of the camera.
    projected: Option<Projected>,
    /// Side of the pixel's projected square, view pixels.
    size: f64,
}

/// The view-space depth of the nearest surface of `reference` at every view pixel (row-major),
/// `+inf` where it has none.
pub(crate) fn zbuffer(view: &View, reference: &Reference, opts: &WarpOptions) -> Vec<f32> {
    let mut z = vec![f32::INFINITY; view.width * view.height];
    let n = reference.depth.face_size() as usize;
    for face in Face::ALL {
        let row = |y: usize| texel_row(view, reference, face, y);
        let mut prev: Vec<Option<Texel>> = Vec::new();
        let mut cur = row(0);
        for y in 0..n {
            let next = if y + 1 < n { row(y + 1) } else { Vec::new() };
            for x in 0..n {
                let Some(t) = cur[x] else { continue };
                let Some(p) = t.projected else { continue };
                let same = |q: Option<&Option<Texel>>| {
                    q.copied()
                        .flatten()
                        .filter(|q| same_surface(t.depth, q.depth, opts.same_surface))
                };
                let h1 = half_step(
                    t,
                    same(cur.get(x + 1)),
                    same(x.checked_sub(1).map(|i| &cur[i])),
                );
                let h2 = half_step(t, same(next.get(x)), same(prev.get(x)));
                let drawn = match (h1, h2) {
                    (Some(h1), Some(h2)) => quad(view, &mut z, t.point, h1, h2, opts.margin_px),
                    _ => false,
                };
                if !drawn {
                    square(view, &mut z, p, t.size, opts.margin_px);
                }
                cover_centre(view, &mut z, p);
            }
            prev = std::mem::replace(&mut cur, next);
        }
    }
    z
}

/// The texels of one row of a face (`None` for sky or an invalid depth).
fn texel_row(view: &View, r: &Reference, face: Face, y: usize) -> Vec<Option<Texel>> {
    let n = r.depth.face_size();
    let depths = &r.depth.face(face)[y * n as usize..(y + 1) * n as usize];
    let half = n as f64 * 0.5;
    depths
        .iter()
        .enumerate()
        .map(|(x, &d)| {
            let depth = d as f64;
            if !depth.is_finite() || depth <= 0.0 {
                return None;
            }
            let point = r.position + pixel_dir(face, x as u32, y as u32, n) * depth;
            if !point.is_finite() {
                return None;
            }
            let projected = view.project(point);
            // Angular side of the pixel: its face-plane side 2/N foreshortened by
            // (1 + u² + v²)^(3/4) (the square root of its solid angle).
            let u = (x as f64 + 0.5 - half) / half;
            let v = (y as f64 + 0.5 - half) / half;
            let angle = (2.0 / n as f64) / (1.0 + u * u + v * v).powf(0.75);
            let size = projected.map_or(0.0, |p| angle * depth * view.focal / p.z);
            Some(Texel {
                point,
                depth,
                projected,
                size,
            })
        })
        .collect()
}

/// Whether two radial depths lie on one surface: their ratio within `1 + tolerance`.
fn same_surface(a: f64, b: f64, tolerance: f64) -> bool {
    a.max(b) <= a.min(b) * (1.0 + tolerance)
}

/// Half the 3-D step to the forward neighbour, else from the backward one.
fn half_step(t: Texel, forward: Option<Texel>, backward: Option<Texel>) -> Option<DVec3> {
    match (forward, backward) {
        (Some(f), _) => Some((f.point - t.point) * 0.5),
        (None, Some(b)) => Some((t.point - b.point) * 0.5),
        (None, None) => None,
    }
}

/// The pixel range whose centres lie in `[lo, hi]` along an axis of `len` pixels.
fn pixel_range(lo: f64, hi: f64, len: usize) -> std::ops::Range<usize> {
    let start = (lo - 0.5).ceil().clamp(0.0, len as f64) as usize;
    let end = ((hi - 0.5).floor() + 1.0).clamp(0.0, len as f64) as usize;
    start..end.max(start)
}

fn write(z: &mut [f32], i: usize, depth: f64) {
    let d = depth as f32;
    if d < z[i] {
        z[i] = d;
    }
}

/// The projection of the 3-D parallelogram `centre ± h1 ± h2` (the pixel's footprint on its
/// surface), grown by `margin` view pixels across each edge. Inverse view depth is affine over
/// the projection of a plane, so the depth is exact inside. `false` (nothing drawn) when a
/// corner is behind the near limit or the quad is degenerate.
fn quad(view: &View, z: &mut [f32], centre: DVec3, h1: DVec3, h2: DVec3, margin: f64) -> bool {
    let corners = [
        centre - h1 - h2,
        centre + h1 - h2,
        centre + h1 + h2,
        centre - h1 + h2,
    ];
    let mut c = [(0.0, 0.0, 0.0); 4];
    for (out, p) in c.iter_mut().zip(corners) {
        let Some(q) = view.project(p) else {
            return false;
        };
        *out = (q.x, q.y, 1.0 / q.z);
    }
    // Inverse depth as w0 + gx·(x − x0) + gy·(y − y0), from corners 0, 1 and 3.
    let (e1, e3) = (
        (c[1].0 - c[0].0, c[1].1 - c[0].1),
        (c[3].0 - c[0].0, c[3].1 - c[0].1),
    );
    let det = e1.0 * e3.1 - e1.1 * e3.0;
    if det.is_nan() || det.abs() <= 1e-12 {
        return false;
    }
    let (dw1, dw3) = (c[1].2 - c[0].2, c[3].2 - c[0].2);
    let gx = (dw1 * e3.1 - dw3 * e1.1) / det;
    let gy = (e1.0 * dw3 - e3.0 * dw1) / det;
    // Inward-facing edge lines: signed distance ≥ −margin inside the grown quad.
    let sign = det.signum();
    let edges: [(f64, f64, f64); 4] = std::array::from_fn(|i| {
        let (a, b) = (c[i], c[(i + 1) % 4]);
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = dx.hypot(dy).max(1e-300);
        // Distance of (x, y) from the line, positive inside: (dx·(y − ay) − dy·(x − ax))/len.
        (
            -dy * sign / len,
            dx * sign / len,
            (dy * a.0 - dx * a.1) * sign / len,
        )
    });
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y, _) in &c {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    let xs = pixel_range(x0 - margin, x1 + margin, view.width);
    for py in pixel_range(y0 - margin, y1 + margin, view.height) {
        let qy = py as f64 + 0.5;
        for px in xs.clone() {
            let qx = px as f64 + 0.5;
            if edges
                .iter()
                .any(|&(ex, ey, e0)| ex * qx + ey * qy + e0 < -margin)
            {
                continue;
            }
            let w = c[0].2 + gx * (qx - c[0].0) + gy * (qy - c[0].1);
            // Outside the quad (in the margin) the plane is extrapolated; keep it in front.
            let depth = if w > 0.0 {
                (1.0 / w).max(NEAR_M)
            } else {
                1.0 / c[0].2
            };
            write(z, py * view.width + px, depth);
        }
    }
    true
}

/// The square of the pixel's projected `size` (grown by `margin`), at constant depth.
fn square(view: &View, z: &mut [f32], p: Projected, size: f64, margin: f64) {
    let half = 0.5 * size + margin;
    let xs = pixel_range(p.x - half, p.x + half, view.width);
    let ys = pixel_range(p.y - half, p.y + half, view.height);
    for py in ys {
        for px in xs.clone() {
            write(z, py * view.width + px, p.z);
        }
    }
}

/// The view pixel holding the splat's centre is always covered.
fn cover_centre(view: &View, z: &mut [f32], p: Projected) {
    if p.x >= 0.0 && p.y >= 0.0 {
        let (px, py) = (p.x.floor() as usize, p.y.floor() as usize);
        if px < view.width && py < view.height {
            write(z, py * view.width + px, p.z);
        }
    }
}
