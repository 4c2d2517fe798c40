//! Depth meshes of one tile: a regular grid and an adaptive Delaunay mesh (`spade`).
//!
//! Vertices sit on pixel centres: `[x, y, r]` with `x, y` continuous face-pixel coordinates
//! (pixel `(i, j)` has its centre at `(i + 0.5, j + 0.5)`) and `r` the radial depth in metres.
//! A triangle stands for the flat 3D triangle through `dir(x, y) · r` of its vertices, which
//! is what a renderer draws. Seen from the reference viewpoint, the inverse *planar* depth
//! `q = |F + uR + vU| / r` of a flat triangle is affine in face pixels, which is how depth is
//! interpolated here.
//!
//! A tile's mesh covers the lattice of pixel centres from its own first pixel up to the first
//! pixel of the next tile on the same face, so neighbouring tiles of one face join without
//! cracks; the outer half pixel at each face edge, and isolated pixels that no triangle can
//! span (a near pixel with a discontinuity all round inside a farther surface), stay
//! uncovered and are counted in [`MeshStats::uncovered_pixels`]. (The viewer
//! closes the outer half pixel of every outline, face edges included, with half-texel
//! skirts drawn beside the stored mesh and cut by the opacity mask; the stored meshes and
//! databases are unchanged.)
//!
//! Adaptive meshes may reach up to `FILL_RINGS` (two) pixels past the outline of the opaque
//! pixels, over a band whose depth is extrapolated from the surface: their vertices there are
//! never drawn as content (the opacity mask cuts), they only spare the mesh from tracing the
//! outline's staircase pixel by pixel.
//!
//! Depth error is measured as parallax in pixels at the track's largest baseline `B`:
//! `B · |1/r − 1/r_mesh| / θ_pixel` with `θ_pixel = (π/2)/N`. Two neighbouring opaque pixels
//! are separated by a *discontinuity* when neither side's linear extrapolation of `q`
//! predicts the other within `discontinuity_px` of such parallax; no triangle spans one.

use serde::{Deserialize, Serialize};
use tracks::cubemap::pixel_dir;
use tracks::{CubeMap, Face, PixelRect, TileGrid, TileId};

mod adaptive;
mod field;

pub(crate) use adaptive::adaptive_mesh;
pub(crate) use field::Field;

pub use tracks::TileMesh;

/// Parameters shared by both mesh builders.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshParams {
    /// Grid step in pixels (≥ 1) of the regular mesh.
    pub step: u32,
    /// Bound on the adaptive mesh's depth error, parallax pixels at `baseline_m`.
    pub max_error_px: f64,
    /// The track's largest baseline `B`, metres (0 for a single viewpoint: then every
    /// depth error is zero parallax and a bound of one pixel at 1 m is used instead).
    pub baseline_m: f64,
    /// Parallax (pixels at `baseline_m`) above which neighbours are a discontinuity.
    pub discontinuity_px: f64,
}

impl Default for MeshParams {
    fn default() -> Self {
        MeshParams {
            step: 4,
            max_error_px: 0.5,
            baseline_m: 1.0,
            discontinuity_px: 1.0,
        }
    }
}

/// What a mesh costs and how well it reproduces the depth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshStats {
    pub triangles: usize,
    pub vertices: usize,
    /// Opaque pixels inside some triangle.
    pub covered_pixels: usize,
    /// Opaque pixels of the tile inside no triangle.
    pub uncovered_pixels: usize,
    /// Largest and mean parallax error over covered pixels that touch no discontinuity.
    pub max_error_px: f64,
    pub mean_error_px: f64,
}

/// Pixels with centres inside triangle `t` (local lattice coordinates, edges inclusive),
/// with the barycentric weights of each.
///
/// The edge functions are evaluated without division (their sign is tested against the
/// tolerance scaled by the doubled area) and advanced by their constant steps along a row;
/// lattice triangles have integer corners, so the steps are exact.
fn raster(t: [(f64, f64); 3], w: usize, h: usize, mut visit: impl FnMut(usize, usize, [f64; 3])) {
    let [a, b, c] = t;
    let area = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
    if area.abs() < 1e-12 {
        return;
    }
    let xmin = a.0.min(b.0).min(c.0).ceil().max(0.0) as usize;
    let ymin = a.1.min(b.1).min(c.1).ceil().max(0.0) as usize;
    let xmax_f = a.0.max(b.0).max(c.0).floor();
    let ymax_f = a.1.max(b.1).max(c.1).floor();
    if xmax_f < 0.0 || ymax_f < 0.0 {
        return;
    }
    let xmax = (xmax_f as usize).min(w - 1);
    let ymax = (ymax_f as usize).min(h - 1);
    if xmin > xmax || ymin > ymax {
        return;
    }
    // Orient so that inside means non-negative edge functions.
    let sgn = area.signum();
    let inv = 1.0 / area;
    let tol = -1e-9 * area.abs();
    // n0(p) = (b − p) × (c − p), n1(p) = (c − p) × (a − p); steps per unit x and y.
    let n0 = |px: f64, py: f64| (b.0 - px) * (c.1 - py) - (b.1 - py) * (c.0 - px);
    let n1 = |px: f64, py: f64| (c.0 - px) * (a.1 - py) - (c.1 - py) * (a.0 - px);
    let (d0x, d1x) = (b.1 - c.1, c.1 - a.1);
    let d2x = -d0x - d1x;
    for j in ymin..=ymax {
        let py = j as f64;
        let x = xmin as f64;
        let (s0, s1) = (n0(x, py), n1(x, py));
        // The row's span from the three (oriented) edge functions, widened by one pixel on
        // each side against round-off; every pixel in it is still tested exactly below.
        // (Truncation instead of floor/ceil, so two pixels of margin; casts saturate.)
        let (mut lo, mut hi) = (0i64, (xmax - xmin) as i64);
        for (e, d) in [(s0, d0x), (s1, d1x), (area - s0 - s1, d2x)] {
            let (e, d) = (e * sgn, d * sgn);
            if d > 0.0 {
                lo = lo.max(((tol - e) / d) as i64 - 2);
            } else if d < 0.0 {
                hi = hi.min(((tol - e) / d) as i64 + 2);
            } else if e < tol {
                hi = -1;
            }
        }
        if hi < lo {
            continue;
        }
        let (lo, hi) = (lo as usize, hi as usize);
        let mut e0 = s0 + d0x * lo as f64;
        let mut e1 = s1 + d1x * lo as f64;
        for i in xmin + lo..=xmin + hi {
            let e2 = area - e0 - e1;
            if e0 * sgn >= tol && e1 * sgn >= tol && e2 * sgn >= tol {
                let w0 = e0 * inv;
                let w1 = e1 * inv;
                visit(i, j, [w0, w1, 1.0 - w0 - w1]);
            }
            e0 += d0x;
            e1 += d1x;
        }
    }
}

/// How far (pixels) adaptive meshes may reach beyond the surface into transparent pixels.
/// Two rings let a mesh edge run straight past the staircase of an outline that turns
/// slowly; the renderer's deeper-slab mask cut (0.45 from level 1 on) keeps coarse texture
/// levels from drawing a slab's blurred edge over the slab behind it there.
const FILL_RINGS: usize = 2;

/// Builder that deduplicates lattice vertices.
struct MeshOut<'f> {
    field: &'f Field,
    slot: Vec<u32>,
    mesh: TileMesh,
}

impl<'f> MeshOut<'f> {
    fn new(field: &'f Field) -> Self {
        MeshOut {
            field,
            slot: vec![u32::MAX; field.w * field.h],
            mesh: TileMesh::default(),
        }
    }
    fn v(&mut self, i: usize, j: usize) -> u32 {
        let k = self.field.idx(i, j);
        if self.slot[k] == u32::MAX {
            self.slot[k] = self.mesh.vertices.len() as u32;
            self.mesh.vertices.push(self.field.vertex(i, j));
        }
        self.slot[k]
    }
    fn tri(&mut self, a: (usize, usize), b: (usize, usize), c: (usize, usize)) {
        let (a, b, c) = (self.v(a.0, a.1), self.v(b.0, b.1), self.v(c.0, c.1));
        self.mesh.indices.extend([a, b, c]);
    }
}

/// A regular mesh with vertices every `step` pixels. A cell whose pixels are all opaque
/// and free of discontinuities becomes two triangles; any other cell falls back to
/// one-pixel cells, of which only triangles over three continuous opaque pixels are kept.
pub(crate) fn grid_mesh(field: &Field, step: u32) -> TileMesh {
    let step = step.max(1) as usize;
    let axis = |len: usize| -> Vec<usize> {
        let mut v: Vec<usize> = (0..len).step_by(step).collect();
        if *v.last().unwrap_or(&0) != len - 1 {
            v.push(len - 1);
        }
        v
    };
    let (xs, ys) = (axis(field.w), axis(field.h));
    let mut out = MeshOut::new(field);
    let f = field;
    for b in 0..ys.len().saturating_sub(1) {
        for a in 0..xs.len().saturating_sub(1) {
            let (i0, i1, j0, j1) = (xs[a], xs[a + 1], ys[b], ys[b + 1]);
            let mut whole = true;
            'cell: for j in j0..=j1 {
                for i in i0..=i1 {
                    let k = f.idx(i, j);
                    if !f.valid[k] || (i < i1 && f.disc_right[k]) || (j < j1 && f.disc_down[k]) {
                        whole = false;
                        break 'cell;
                    }
                }
            }
            if whole {
                out.tri((i0, j0), (i1, j0), (i1, j1));
                out.tri((i0, j0), (i1, j1), (i0, j1));
                continue;
            }
            for j in j0..j1 {
                for i in i0..i1 {
                    unit_cell(f, &mut out, i, j);
                }
            }
        }
    }
    out.mesh
}

/// The two triangles of the one-pixel cell at `(i, j)`, each kept only over continuous
/// opaque pixels; the diagonal is chosen so that a single missing corner loses one triangle.
fn unit_cell(f: &Field, out: &mut MeshOut, i: usize, j: usize) {
    let k = f.idx(i, j);
    let (tl, tr, bl, br) = (k, k + 1, k + f.w, k + f.w + 1);
    let v = |m: usize| f.valid[m];
    let top = v(tl) && v(tr) && !f.disc_right[tl];
    let bottom = v(bl) && v(br) && !f.disc_right[bl];
    let left = v(tl) && v(bl) && !f.disc_down[tl];
    let right = v(tr) && v(br) && !f.disc_down[tr];
    let p = |m: usize| (m % f.w, m / f.w);
    if v(tl) && v(br) && (top && right || left && bottom) {
        // Diagonal tl–br.
        if top && right {
            out.tri(p(tl), p(tr), p(br));
        }
        if left && bottom {
            out.tri(p(tl), p(br), p(bl));
        }
    } else {
        // Diagonal tr–bl.
        if top && left {
            out.tri(p(tl), p(tr), p(bl));
        }
        if right && bottom {
            out.tri(p(tr), p(br), p(bl));
        }
    }
}

/// Measure a mesh against the field it was built from: every pixel centre inside a
/// triangle gets the triangle's inverse planar depth (affine over it, from the stored f32
/// vertex depths); the tests check the same numbers by 3D ray casting ([`rasterise_3d`]).
pub(crate) fn mesh_stats(f: &Field, mesh: &TileMesh) -> MeshStats {
    let mut q_mesh = vec![f64::NAN; f.w * f.h];
    for t in mesh.indices.chunks_exact(3) {
        let v = [0, 1, 2].map(|m| mesh.vertices[t[m] as usize]);
        let local = v.map(|[x, y, _]| (x as f64 - 0.5 - f.x0 as f64, y as f64 - 0.5 - f.y0 as f64));
        let qv = [0, 1, 2].map(|m| {
            let (i, j) = ((local[m].0 + 0.5) as usize, (local[m].1 + 0.5) as usize);
            f.dnorm[f.idx(i.min(f.w - 1), j.min(f.h - 1))] / v[m][2] as f64
        });
        raster(local, f.w, f.h, |i, j, b| {
            q_mesh[f.idx(i, j)] = b[0] * qv[0] + b[1] * qv[1] + b[2] * qv[2];
        });
    }
    let mut s = MeshStats {
        triangles: mesh.triangle_count(),
        vertices: mesh.vertices.len(),
        ..MeshStats::default()
    };
    let mut sum = 0.0;
    let mut counted = 0usize;
    for j in 0..f.h {
        for i in 0..f.w {
            let k = f.idx(i, j);
            if !f.valid[k] || !f.in_tile(i, j) {
                continue;
            }
            if q_mesh[k].is_nan() {
                s.uncovered_pixels += 1;
                continue;
            }
            s.covered_pixels += 1;
            if !f.at_discontinuity(i, j) {
                let e = f.error_px(k, q_mesh[k]);
                s.max_error_px = s.max_error_px.max(e);
                sum += e;
                counted += 1;
            }
        }
    }
    s.mean_error_px = if counted > 0 {
        sum / counted as f64
    } else {
        0.0
    };
    s
}

/// Depth of `mesh` at the pixel centres of the window `(x0, y0, w, h)` of `face` (row-major,
/// `None` where no triangle covers the centre), by ray–plane intersection in 3D.
pub fn rasterise_3d(
    mesh: &TileMesh,
    face: Face,
    face_size: u32,
    window: (u32, u32, usize, usize),
) -> Vec<Option<f64>> {
    let (x0, y0, w, h) = window;
    let mut out = vec![None; w * h];
    for t in mesh.indices.chunks_exact(3) {
        let v = [0, 1, 2].map(|m| mesh.vertices[t[m] as usize]);
        let p3 = v.map(|[x, y, r]| {
            tracks::cubemap::subpixel_dir(face, x as f64, y as f64, face_size) * r as f64
        });
        let normal = (p3[1] - p3[0]).cross(p3[2] - p3[0]);
        let local = v.map(|[x, y, _]| (x as f64 - 0.5 - x0 as f64, y as f64 - 0.5 - y0 as f64));
        raster(local, w, h, |i, j, _| {
            let dir = pixel_dir(face, x0 + i as u32, y0 + j as u32, face_size);
            let denom = normal.dot(dir);
            if denom.abs() > 1e-300 {
                let r = normal.dot(p3[0]) / denom;
                if r.is_finite() && r > 0.0 {
                    out[j * w + i] = Some(r);
                }
            }
        });
    }
    out
}

/// Both meshes of one tile with their statistics (a mesh not built is empty, its stats zero).
pub struct TileMeshes {
    pub grid: TileMesh,
    pub grid_stats: MeshStats,
    pub adaptive: TileMesh,
    pub adaptive_stats: MeshStats,
}

/// Build the meshes of one tile of a slab layer: both, or `only` the one named.
pub fn mesh_tile(
    depth: &CubeMap<f32>,
    mask: &CubeMap<bool>,
    grid: TileGrid,
    tile: TileId,
    params: &MeshParams,
    only: Option<crate::tiles::MeshKind>,
) -> TileMeshes {
    use crate::tiles::MeshKind;
    let f = Field::build(
        depth,
        mask,
        grid,
        tile,
        params,
        only != Some(MeshKind::Grid),
    );
    let mut out = TileMeshes {
        grid: TileMesh::default(),
        grid_stats: MeshStats::default(),
        adaptive: TileMesh::default(),
        adaptive_stats: MeshStats::default(),
    };
    let rect = grid.pixel_rect(tile);
    if only != Some(MeshKind::Adaptive) {
        out.grid = grid_mesh(&f, params.step);
        cover_lone_pixels(&mut out.grid, depth, mask, rect);
        out.grid_stats = mesh_stats(&f, &out.grid);
    }
    if only != Some(MeshKind::Grid) {
        out.adaptive = adaptive_mesh(&f, params.max_error_px);
        cover_lone_pixels(&mut out.adaptive, depth, mask, rect);
        out.adaptive_stats = mesh_stats(&f, &out.adaptive);
    }
    out
}

/// Give every opaque pixel of the tile (`rect`) that no triangle covers a quad of
/// its own, corner to corner at its depth. A surface one or two pixels thin between two
/// depth discontinuities (a pole, a window frame, a roof edge seen end on) has vertices but
/// no triangle, since none may span a discontinuity; without the quad the slab behind showed
/// through it even at the reference viewpoint. Pixel centres on an edge or vertex of a
/// triangle count as covered (skirts reach half a texel past outlines).
pub fn cover_lone_pixels(
    mesh: &mut TileMesh,
    depth: &CubeMap<f32>,
    mask: &CubeMap<bool>,
    rect: PixelRect,
) {
    let PixelRect {
        face,
        x0,
        y0,
        x1,
        y1,
    } = rect;
    let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
    let mut covered = vec![false; w * h];
    for tri in mesh.indices.chunks_exact(3) {
        let p: Vec<[f64; 2]> = tri
            .iter()
            .map(|&i| {
                let v = mesh.vertices[i as usize];
                [v[0] as f64, v[1] as f64]
            })
            .collect();
        let area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if area.abs() < 1e-9 {
            continue;
        }
        let lo = |k: usize| p.iter().map(|q| q[k]).fold(f64::INFINITY, f64::min);
        let hi = |k: usize| p.iter().map(|q| q[k]).fold(f64::NEG_INFINITY, f64::max);
        let xs = (lo(0) - 0.5).floor().max(x0 as f64) as u32
            ..((hi(0) - 0.5).ceil() + 1.0).min(x1 as f64) as u32;
        let ys = (lo(1) - 0.5).floor().max(y0 as f64) as u32
            ..((hi(1) - 0.5).ceil() + 1.0).min(y1 as f64) as u32;
        for y in ys {
            for x in xs.clone() {
                let c = [x as f64 + 0.5, y as f64 + 0.5];
                let edge = |a: [f64; 2], b: [f64; 2]| {
                    ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) * area.signum()
                };
                let eps = -1e-6;
                if edge(p[0], p[1]) >= eps && edge(p[1], p[2]) >= eps && edge(p[2], p[0]) >= eps {
                    covered[(y - y0) as usize * w + (x - x0) as usize] = true;
                }
            }
        }
    }
    for y in y0..y1 {
        for x in x0..x1 {
            let d = *depth.get(face, x, y);
            if covered[(y - y0) as usize * w + (x - x0) as usize]
                || !*mask.get(face, x, y)
                || !(d.is_finite() && d > 0.0)
            {
                continue;
            }
            let base = mesh.vertices.len() as u32;
            let (fx, fy) = (x as f32, y as f32);
            mesh.vertices.extend([
                [fx, fy, d],
                [fx + 1.0, fy, d],
                [fx + 1.0, fy + 1.0, d],
                [fx, fy + 1.0, d],
            ]);
            mesh.indices
                .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boundaries::theta_pixel;
    use tracks::cubemap::pixel_dir;

    fn params(b: f64, err: f64) -> MeshParams {
        MeshParams {
            step: 4,
            max_error_px: err,
            baseline_m: b,
            discontinuity_px: 1.0,
        }
    }

    fn all_tiles(depth: &CubeMap<f32>, tile: u32, p: &MeshParams) -> Vec<(TileId, TileMeshes)> {
        let mask = depth.map(|d| d.is_finite());
        let grid = TileGrid::new(depth.face_size(), tile).unwrap();
        grid.tiles()
            .map(|t| (t, mesh_tile(depth, &mask, grid, t, p, None)))
            .collect()
    }

    /// Radial depth of the planes x = ±a, y = ±a, z = ±a (a box around the viewpoint).
    fn box_depth(n: u32, a: f64) -> CubeMap<f32> {
        CubeMap::from_fn(n, |f, x, y| {
            let d = pixel_dir(f, x, y, n);
            (a / d.abs().max_element()) as f32
        })
    }

    #[test]
    fn planes_are_reproduced_by_two_triangles_per_tile() {
        let p = params(5.0, 0.25);
        for (t, m) in all_tiles(&box_depth(16, 3.0), 8, &p) {
            assert_eq!(m.adaptive.triangle_count(), 2, "{t:?}");
            assert!(
                m.adaptive_stats.max_error_px < 1e-3,
                "{t:?} {:?}",
                m.adaptive_stats
            );
            assert!(m.grid_stats.max_error_px < 1e-3, "{t:?} {:?}", m.grid_stats);
            assert_eq!(m.adaptive_stats.uncovered_pixels, 0);
            assert_eq!(m.grid_stats.uncovered_pixels, 0);
            assert_eq!(m.grid_stats.covered_pixels, 64);
        }
    }

    /// Rolling hills in direction space plus a near box in front of face +x: smooth
    /// curvature and sharp discontinuities.
    fn bumpy_with_step(n: u32) -> CubeMap<f32> {
        CubeMap::from_fn(n, |f, x, y| {
            let d = pixel_dir(f, x, y, n);
            let r = 6.0 + 1.5 * (3.0 * d.x).sin() * (2.0 * d.y).cos() + d.z;
            if f == Face::PosX && (n / 4..n / 2).contains(&x) && y > n / 3 {
                1.2
            } else {
                r as f32
            }
        })
    }

    #[test]
    fn adaptive_mesh_error_is_within_the_bound_on_non_discontinuity_pixels() {
        let depth = bumpy_with_step(32);
        for bound in [0.25, 1.0, 4.0] {
            let p = params(2.0, bound);
            let mut tris = 0;
            for (t, m) in all_tiles(&depth, 16, &p) {
                let s = m.adaptive_stats;
                // f32 vertex depths add far less than 1e-3 px.
                assert!(s.max_error_px <= bound + 1e-3, "{t:?} bound {bound}: {s:?}");
                tris += s.triangles;
            }
            assert!(tris > 12, "refinement happened");
        }
        // A looser bound never needs more triangles.
        let count = |b: f64| -> usize {
            all_tiles(&depth, 16, &params(2.0, b))
                .iter()
                .map(|(_, m)| m.adaptive.triangle_count())
                .sum()
        };
        assert!(count(0.25) >= count(1.0) && count(1.0) >= count(4.0));
    }

    #[test]
    fn adaptive_meshes_overhang_a_round_outline_instead_of_tracing_it() {
        // A disk of a plane (radius 27 px) in the middle of a 64-pixel tile.
        let (n, radius) = (64u32, 27.0f64);
        let depth = box_depth(n, 3.0);
        let mask = CubeMap::from_fn(n, |_, x, y| {
            (x as f64 + 0.5 - 32.0).hypot(y as f64 + 0.5 - 32.0) <= radius
        });
        let grid = TileGrid::new(n, n).unwrap();
        let t = grid.tiles().next().unwrap();
        let p = params(2.0, 0.5);
        let f = Field::new(&depth, &mask, grid, t, &p);
        let mesh = adaptive_mesh(&f, 0.5);
        let stats = mesh_stats(&f, &mesh);
        assert_eq!(stats.uncovered_pixels, 0, "{stats:?}");
        assert!(stats.max_error_px < 1e-3, "{stats:?}");
        // Every vertex lies on the disk or within the filled band around it.
        for v in &mesh.vertices {
            let d = (v[0] as f64 - 32.0).hypot(v[1] as f64 - 32.0);
            assert!(d <= radius + FILL_RINGS as f64 * 1.5, "vertex {v:?} at {d}");
        }
        // Without the band the mesh must follow the staircase: far more triangles.
        let mut bare = Field::new(&depth, &mask, grid, t, &p);
        bare.ring.fill(0);
        let traced = adaptive_mesh(&bare, 0.5);
        assert_eq!(mesh_stats(&bare, &traced).uncovered_pixels, 0);
        assert!(
            2 * mesh.triangle_count() < traced.triangle_count(),
            "{} triangles with the band, {} without",
            mesh.triangle_count(),
            traced.triangle_count()
        );
    }

    #[test]
    fn filled_band_extends_a_plane_linearly() {
        // Half a tile of a tilted plane: the band's extrapolated inverse depth stays affine.
        let n = 32u32;
        let depth = box_depth(n, 3.0);
        let mask = CubeMap::from_fn(n, |_, x, _| x < 12);
        let grid = TileGrid::new(n, 16).unwrap();
        let t = grid.tiles().next().unwrap();
        let f = Field::new(&depth, &mask, grid, t, &params(2.0, 0.5));
        for j in 0..f.h {
            for ring in 1..=FILL_RINGS {
                let k = f.idx(11 + ring, j);
                assert!(f.filled(k) && !f.valid[k], "({}, {j})", 11 + ring);
                assert_eq!(f.ring[k] as usize, ring);
                let expect =
                    f.q[f.idx(11, j)] + ring as f64 * (f.q[f.idx(11, j)] - f.q[f.idx(10, j)]);
                assert!((f.q[k] - expect).abs() < 1e-9, "({}, {j})", 11 + ring);
            }
            assert!(!f.filled(f.idx(12 + FILL_RINGS, j)));
        }
    }

    #[test]
    fn no_triangle_spans_a_discontinuity() {
        let n = 32;
        let depth = bumpy_with_step(n);
        let p = params(2.0, 0.5);
        for (t, m) in all_tiles(&depth, 16, &p) {
            for mesh in [&m.grid, &m.adaptive] {
                for tri in mesh.indices.chunks_exact(3) {
                    let r: Vec<f32> = tri.iter().map(|&i| mesh.vertices[i as usize][2]).collect();
                    let near = r.iter().filter(|&&r| r == 1.2).count();
                    assert!(near == 0 || near == 3, "{t:?}: triangle depths {r:?}");
                }
            }
            // Both sides of the step are at least two pixels wide: everything is covered.
            assert_eq!(m.adaptive_stats.uncovered_pixels, 0, "{t:?}");
            assert_eq!(m.grid_stats.uncovered_pixels, 0, "{t:?}");
        }
    }

    #[test]
    fn rasterised_mesh_depth_matches_source_depth() {
        // The named acceptance test: re-rasterise each adaptive mesh over its tile and
        // compare with the source depth on every covered, non-discontinuity pixel.
        let n = 32;
        let depth = bumpy_with_step(n);
        let mask = depth.map(|d| d.is_finite());
        let (b, bound) = (3.0, 0.5);
        let p = params(b, bound);
        let grid = TileGrid::new(n, 8).unwrap();
        let theta = theta_pixel(n);
        let mut checked = 0;
        for t in grid.tiles() {
            let f = Field::new(&depth, &mask, grid, t, &p);
            let mesh = adaptive_mesh(&f, bound);
            let mut worst = 0.0f64;
            let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t);
            let w = (x1 - x0) as usize;
            let got = rasterise_3d(&mesh, t.face, n, (x0, y0, w, (y1 - y0) as usize));
            for (k, r) in got.iter().enumerate() {
                let (i, j) = (k % w, k / w);
                let Some(r) = r else { continue };
                if f.at_discontinuity(i, j) {
                    continue;
                }
                let src = *depth.get(t.face, x0 + i as u32, y0 + j as u32) as f64;
                let px = b * (1.0 / src - 1.0 / r).abs() / theta;
                assert!(px <= bound + 1e-3, "{t:?} ({i},{j}): {px} px");
                worst = worst.max(px);
                checked += 1;
            }
            // The builder's own measure (affine inverse planar depth) agrees with 3D.
            let stats = mesh_stats(&f, &mesh);
            assert!(
                (stats.max_error_px - worst).abs() < 1e-3,
                "{t:?}: {stats:?} vs {worst}"
            );
        }
        assert!(checked > 6 * 32 * 32 * 9 / 10, "{checked}");
    }
}
