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
//! Adaptive meshes may reach up to [`FILL_RINGS`] pixels past the outline of the opaque
//! pixels, over a band whose depth is extrapolated from the surface: their vertices there are
//! never drawn as content (the opacity mask cuts), they only spare the mesh from tracing the
//! outline's staircase pixel by pixel.
//!
//! Depth error is measured as parallax in pixels at the track's largest baseline `B`:
//! `B · |1/r − 1/r_mesh| / θ_pixel` with `θ_pixel = (π/2)/N`. Two neighbouring opaque pixels
//! are separated by a *discontinuity* when neither side's linear extrapolation of `q`
//! predicts the other within `discontinuity_px` of such parallax; no triangle spans one.

use serde::{Deserialize, Serialize};
use spade::{DelaunayTriangulation, Point2, Triangulation};
use tracks::cubemap::{pixel_dir, uv_from_pixel_f};
use tracks::{CubeMap, Face, TileGrid, TileId};

use crate::boundaries::theta_pixel;

/// A tile's depth mesh: vertices `[x, y, r]` (face pixels, radial metres), triangles as
/// index triples (counter-clockwise in image coordinates is not guaranteed).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TileMesh {
    pub vertices: Vec<[f32; 3]>,
    pub indices: Vec<u32>,
}

impl TileMesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

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

/// The lattice of pixel centres a tile's mesh spans, with per-pixel depth data.
pub(crate) struct Field {
    x0: u32,
    y0: u32,
    /// Tile's own pixel rectangle end (exclusive), face pixels.
    x1: u32,
    y1: u32,
    w: usize,
    h: usize,
    valid: Vec<bool>,
    r: Vec<f64>,
    q: Vec<f64>,
    dnorm: Vec<f64>,
    /// Discontinuity between `(i, j)` and `(i + 1, j)` / `(i, j + 1)`.
    disc_right: Vec<bool>,
    disc_down: Vec<bool>,
    /// Connected component over continuous edges; `u32::MAX` for transparent pixels (and for
    /// all pixels of a field built without components).
    comp: Vec<u32>,
    /// The filled band: for transparent pixels within [`FILL_RINGS`] of the surface their ring
    /// (1 = next to the surface), 0 for all others. Band pixels have an extrapolated depth
    /// (`q`, `r` and `comp` set; `valid` stays false, so they count for neither coverage nor
    /// error): adaptive meshes may place vertices there and overhang them; the mask cuts.
    ring: Vec<u8>,
    /// Parallax pixels per unit of `1/r`: `B / θ_pixel`.
    px_per_inv_m: f64,
}

impl Field {
    #[cfg(test)]
    pub(crate) fn new(
        depth: &CubeMap<f32>,
        mask: &CubeMap<bool>,
        grid: TileGrid,
        tile: TileId,
        params: &MeshParams,
    ) -> Field {
        Field::build(depth, mask, grid, tile, params, true)
    }

    /// The field; connected components (only the adaptive mesh needs them) when `components`.
    fn build(
        depth: &CubeMap<f32>,
        mask: &CubeMap<bool>,
        grid: TileGrid,
        tile: TileId,
        params: &MeshParams,
        components: bool,
    ) -> Field {
        let n = grid.face_size;
        let (x0, y0, x1, y1) = grid.pixel_rect(tile);
        let xe = x1.min(n - 1);
        let ye = y1.min(n - 1);
        let (w, h) = ((xe - x0 + 1) as usize, (ye - y0 + 1) as usize);
        let face = tile.face;
        let b = if params.baseline_m > 0.0 {
            params.baseline_m
        } else {
            1.0
        };
        let px_per_inv_m = b / theta_pixel(n);
        // Inverse planar depth over the lattice plus a one-pixel border (NaN where
        // transparent or off the face), for second differences across the lattice edges.
        let (pw, ph) = (w + 2, h + 2);
        let mut pq = vec![f64::NAN; pw * ph];
        // |F + uR + vU|² = 1 + u² + v², with u by column and v by row of the padded lattice.
        let u2: Vec<f64> = (0..pw)
            .map(|pi| {
                let (u, _) = uv_from_pixel_f(x0 as f64 + pi as f64 - 0.5, 0.0, n);
                u * u
            })
            .collect();
        let v2: Vec<f64> = (0..ph)
            .map(|pj| {
                let (_, v) = uv_from_pixel_f(0.0, y0 as f64 + pj as f64 - 0.5, n);
                v * v
            })
            .collect();
        let fd = depth.face(face);
        let fm = mask.face(face);
        let nn = n as usize;
        // Padded columns that lie on the face.
        let pi_lo = if x0 == 0 { 1 } else { 0 };
        let pi_hi = pw.min(nn + 1 - x0 as usize);
        for pj in 0..ph {
            let y = y0 as i64 + pj as i64 - 1;
            if y < 0 || y >= n as i64 {
                continue;
            }
            let row = y as usize * nn + x0 as usize;
            for pi in pi_lo..pi_hi {
                let src = row + pi - 1;
                let d = fd[src] as f64;
                if fm[src] && d.is_finite() && d > 0.0 {
                    pq[pj * pw + pi] = (1.0 + u2[pi] + v2[pj]).sqrt() / d;
                }
            }
        }
        let len = w * h;
        let mut f = Field {
            x0,
            y0,
            x1,
            y1,
            w,
            h,
            valid: vec![false; len],
            r: vec![f64::INFINITY; len],
            q: vec![0.0; len],
            dnorm: vec![1.0; len],
            disc_right: vec![false; len],
            disc_down: vec![false; len],
            comp: vec![u32::MAX; len],
            ring: vec![0; len],
            px_per_inv_m,
        };
        let thr = params.discontinuity_px;
        // Residual of the jump a→b given the pixels before a and after b (NaN = missing).
        let resid = |qp: f64, qa: f64, qb: f64, qn: f64| -> f64 {
            let e1 = if qp.is_nan() {
                (qb - qa).abs()
            } else {
                (qb - (2.0 * qa - qp)).abs()
            };
            let e2 = if qn.is_nan() {
                (qa - qb).abs()
            } else {
                (qa - (2.0 * qb - qn)).abs()
            };
            e1.min(e2)
        };
        for j in 0..h {
            for i in 0..w {
                let k = j * w + i;
                let pk = (j + 1) * pw + i + 1;
                let dn = (1.0 + u2[i + 1] + v2[j + 1]).sqrt();
                f.dnorm[k] = dn;
                let qa = pq[pk];
                if qa.is_nan() {
                    continue;
                }
                f.valid[k] = true;
                f.q[k] = qa;
                f.r[k] = fd[(y0 as usize + j) * nn + x0 as usize + i] as f64;
                let s = px_per_inv_m / dn;
                if i + 1 < w && !pq[pk + 1].is_nan() {
                    f.disc_right[k] = resid(pq[pk - 1], qa, pq[pk + 1], pq[pk + 2]) * s > thr;
                }
                if j + 1 < h && !pq[pk + pw].is_nan() {
                    f.disc_down[k] = resid(pq[pk - pw], qa, pq[pk + pw], pq[pk + 2 * pw]) * s > thr;
                }
            }
        }
        if components {
            f.label_components();
            f.fill(FILL_RINGS);
        }
        f
    }

    /// Extrapolate the surface `rings` pixels into the transparent pixels around it, ring by
    /// ring: each new pixel continues a neighbour linearly (from the pixel behind it in the same
    /// direction, when that one is known and of the same component) or repeats it; of several
    /// neighbours the nearest surface (largest `q`) wins.
    fn fill(&mut self, rings: usize) {
        let (w, h) = (self.w, self.h);
        let known = |f: &Field, k: usize| f.valid[k] || f.filled(k);
        for ring in 1..=rings {
            let mut new: Vec<(usize, f64, u32)> = Vec::new();
            for j in 0..h {
                for i in 0..w {
                    let k = j * w + i;
                    if known(self, k) {
                        continue;
                    }
                    let mut best: Option<(f64, u32)> = None;
                    let dirs: [(i64, i64); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
                    for (dx, dy) in dirs {
                        let (ni, nj) = (i as i64 + dx, j as i64 + dy);
                        if ni < 0 || nj < 0 || ni >= w as i64 || nj >= h as i64 {
                            continue;
                        }
                        let nk = nj as usize * w + ni as usize;
                        if !known(self, nk) {
                            continue;
                        }
                        let qn = self.q[nk];
                        let (bi, bj) = (ni + dx, nj + dy);
                        let mut q = qn;
                        if bi >= 0 && bj >= 0 && bi < w as i64 && bj < h as i64 {
                            let bk = bj as usize * w + bi as usize;
                            if known(self, bk) && self.comp[bk] == self.comp[nk] {
                                q = (2.0 * qn - self.q[bk]).clamp(0.5 * qn, 2.0 * qn);
                            }
                        }
                        if best.is_none_or(|(bq, _)| q > bq) {
                            best = Some((q, self.comp[nk]));
                        }
                    }
                    if let Some((q, c)) = best {
                        new.push((k, q, c));
                    }
                }
            }
            if new.is_empty() {
                break;
            }
            for (k, q, c) in new {
                self.ring[k] = ring as u8;
                self.q[k] = q;
                self.r[k] = self.dnorm[k] / q;
                self.comp[k] = c;
            }
        }
    }

    /// Whether pixel `k` lies in the filled band.
    fn filled(&self, k: usize) -> bool {
        self.ring[k] > 0
    }

    fn label_components(&mut self) {
        let (w, h) = (self.w, self.h);
        let mut next = 0u32;
        let mut stack = Vec::new();
        for start in 0..w * h {
            if !self.valid[start] || self.comp[start] != u32::MAX {
                continue;
            }
            self.comp[start] = next;
            stack.push((start, start % w, start / w));
            while let Some((k, i, j)) = stack.pop() {
                let mut visit = |m: usize, mi: usize, mj: usize, open: bool| {
                    if open && self.valid[m] && self.comp[m] == u32::MAX {
                        self.comp[m] = next;
                        stack.push((m, mi, mj));
                    }
                };
                if i + 1 < w {
                    visit(k + 1, i + 1, j, !self.disc_right[k]);
                }
                if i > 0 {
                    visit(k - 1, i - 1, j, !self.disc_right[k - 1]);
                }
                if j + 1 < h {
                    visit(k + w, i, j + 1, !self.disc_down[k]);
                }
                if j > 0 {
                    visit(k - w, i, j - 1, !self.disc_down[k - w]);
                }
            }
            next += 1;
        }
    }

    fn idx(&self, i: usize, j: usize) -> usize {
        j * self.w + i
    }

    /// Whether pixel `(i, j)` touches a discontinuity edge.
    fn at_discontinuity(&self, i: usize, j: usize) -> bool {
        let k = self.idx(i, j);
        self.disc_right[k]
            || self.disc_down[k]
            || (i > 0 && self.disc_right[k - 1])
            || (j > 0 && self.disc_down[k - self.w])
    }

    /// Whether local pixel `(i, j)` belongs to the tile itself (not the next tile's edge).
    fn in_tile(&self, i: usize, j: usize) -> bool {
        self.x0 + (i as u32) < self.x1 && self.y0 + (j as u32) < self.y1
    }

    fn error_px(&self, k: usize, q_mesh: f64) -> f64 {
        (self.q[k] - q_mesh).abs() * self.px_per_inv_m / self.dnorm[k]
    }

    /// Emit a vertex for local pixel `(i, j)`.
    fn vertex(&self, i: usize, j: usize) -> [f32; 3] {
        [
            (self.x0 as f64 + i as f64 + 0.5) as f32,
            (self.y0 as f64 + j as f64 + 0.5) as f32,
            self.r[self.idx(i, j)] as f32,
        ]
    }
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

/// A fast hasher for small integer keys (lattice indices of a tile): multiply–rotate mixing.
#[derive(Default)]
struct LatticeHasher(u64);

impl std::hash::Hasher for LatticeHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_usize(&mut self, v: usize) {
        self.write_u64(v as u64);
    }
}

type LatticeHash = std::hash::BuildHasherDefault<LatticeHasher>;

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

/// An adaptive mesh: a Delaunay triangulation of the lattice, refined by inserting the worst
/// pixel of every triangle whose error exceeds `max_error_px`, that covers a transparent
/// pixel beyond the filled band ([`FILL_RINGS`]) or another continuous surface, or whose
/// corners are not one continuous surface. A triangle of one surface may have corners in the
/// filled band and overhang transparent pixels there: the renderer's opacity mask cuts the
/// outline, so the mesh need not follow its staircase pixel by pixel (on the synthetic street
/// this halves the triangles). A triangle whose corners are not one surface is refined only
/// while it covers an opaque pixel, at its outermost filled pixel if it has one (the mesh
/// then ends in the band), else at the opaque pixel nearest its centre; without an opaque
/// pixel it is dropped. Every lattice point can be inserted, so refinement ends.
pub(crate) fn adaptive_mesh(field: &Field, max_error_px: f64) -> TileMesh {
    let f = field;
    let (w, h) = (f.w, f.h);
    let mut tri: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
    let mut is_vertex = vec![false; w * h];
    let mut pending: Vec<(usize, usize)> = vec![(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)];
    let mut keep: Vec<[(usize, usize); 3]> = Vec::new();
    // Final verdicts (kept or dropped) by vertex triple: a triangle that survives an
    // insertion pass unchanged covers the same pixels, so it need not be rasterised again.
    let mut settled: std::collections::HashMap<[usize; 3], bool, LatticeHash> = Default::default();
    // Opaque vertices already refined towards (see below).
    let mut reached = vec![false; w * h];
    loop {
        pending.retain(|&(i, j)| !is_vertex[f.idx(i, j)]);
        if pending.is_empty() {
            // An opaque vertex that no kept triangle uses (a lone pixel on a corner of the
            // lattice, a vertex from the start) is covered by refining towards it: its
            // opaque or filled neighbours become vertices, and the triangles between them
            // and it are one surface.
            let mut used = vec![false; w * h];
            for t in &keep {
                for &(i, j) in t {
                    used[f.idx(i, j)] = true;
                }
            }
            for j in 0..h {
                for i in 0..w {
                    let k = f.idx(i, j);
                    if !is_vertex[k] || !f.valid[k] || used[k] || reached[k] || !f.in_tile(i, j) {
                        continue;
                    }
                    reached[k] = true;
                    for nj in j.saturating_sub(1)..(j + 2).min(h) {
                        for ni in i.saturating_sub(1)..(i + 2).min(w) {
                            let n = f.idx(ni, nj);
                            if !is_vertex[n] && (f.valid[n] || f.filled(n)) {
                                pending.push((ni, nj));
                            }
                        }
                    }
                }
            }
        }
        pending.sort_unstable();
        pending.dedup();
        if pending.is_empty() {
            break;
        }
        for &(i, j) in &pending {
            is_vertex[f.idx(i, j)] = true;
            // Lattice points are distinct and finite: insertion cannot fail.
            tri.insert(Point2::new(i as f64, j as f64)).ok();
        }
        pending.clear();
        keep.clear();
        for face in tri.inner_faces() {
            let pos = face.positions();
            let c: [(usize, usize); 3] = pos.map(|p| ((p.x + 0.5) as usize, (p.y + 0.5) as usize));
            let ks = c.map(|(i, j)| f.idx(i, j));
            let mut key = ks;
            key.sort_unstable();
            if let Some(&kept) = settled.get(&key) {
                if kept {
                    keep.push(c);
                }
                continue;
            }
            let surface = ks.iter().all(|&k| f.valid[k] || f.filled(k))
                && ks.iter().any(|&k| f.valid[k])
                && f.comp[ks[0]] == f.comp[ks[1]]
                && f.comp[ks[1]] == f.comp[ks[2]];
            let comp = f.comp[ks[0]];
            let qs = ks.map(|k| f.q[k]);
            // Worst offending pixel: (badness class, error), larger is worse.
            let mut worst: Option<((usize, usize), u8, f64)> = None;
            let mut has_opaque = false;
            let centre = (
                (c[0].0 + c[1].0 + c[2].0) as f64 / 3.0,
                (c[0].1 + c[1].1 + c[2].1) as f64 / 3.0,
            );
            let pts = c.map(|(i, j)| (i as f64, j as f64));
            raster(pts, w, h, |i, j, bary| {
                let k = f.idx(i, j);
                if is_vertex[k] {
                    return;
                }
                let (class, err) = if !surface {
                    // Refined only to cover opaque pixels: at the outermost filled pixels
                    // first (the mesh may end there, the mask cuts), else at opaque pixels
                    // near the centre.
                    if f.valid[k] {
                        has_opaque = true;
                    } else if !f.filled(k) {
                        return;
                    }
                    let d = (i as f64 - centre.0).powi(2) + (j as f64 - centre.1).powi(2);
                    (if f.filled(k) { 2 + f.ring[k] } else { 1 }, -d)
                } else if f.filled(k) {
                    return;
                } else if !f.valid[k] || f.comp[k] != comp {
                    (3, 0.0)
                } else {
                    let qm = bary[0] * qs[0] + bary[1] * qs[1] + bary[2] * qs[2];
                    let e = f.error_px(k, qm);
                    if e <= max_error_px {
                        return;
                    }
                    (2, e)
                };
                if worst.is_none_or(|(_, wc, we)| (class, err) > (wc, we)) {
                    worst = Some(((i, j), class, err));
                }
            });
            if !surface && !has_opaque {
                worst = None;
            }
            match worst {
                Some((p, _, _)) => pending.push(p),
                None => {
                    settled.insert(key, surface);
                    if surface {
                        keep.push(c);
                    }
                }
            }
        }
    }
    let mut out = MeshOut::new(f);
    for [a, b, c] in keep {
        out.tri(a, b, c);
    }
    out.mesh
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
        cover_lone_pixels(&mut out.grid, depth, mask, tile.face, rect);
        out.grid_stats = mesh_stats(&f, &out.grid);
    }
    if only != Some(MeshKind::Grid) {
        out.adaptive = adaptive_mesh(&f, params.max_error_px);
        cover_lone_pixels(&mut out.adaptive, depth, mask, tile.face, rect);
        out.adaptive_stats = mesh_stats(&f, &out.adaptive);
    }
    out
}

/// Give every opaque pixel of the tile (`rect` on `face`) that no triangle covers a quad of
/// its own, corner to corner at its depth. A surface one or two pixels thin between two
/// depth discontinuities (a pole, a window frame, a roof edge seen end on) has vertices but
/// no triangle, since none may span a discontinuity; without the quad the slab behind showed
/// through it even at the reference viewpoint. Pixel centres on an edge or vertex of a
/// triangle count as covered (skirts reach half a texel past outlines).
pub fn cover_lone_pixels(
    mesh: &mut TileMesh,
    depth: &CubeMap<f32>,
    mask: &CubeMap<bool>,
    face: Face,
    (x0, y0, x1, y1): (u32, u32, u32, u32),
) {
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
            let (x0, y0, x1, y1) = grid.pixel_rect(t);
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
