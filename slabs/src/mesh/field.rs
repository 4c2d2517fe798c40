//! [`Field`]: the lattice of a tile's pixel centres with depth, discontinuities, connected
//! components and the filled band around the surface.

use tracks::cubemap::uv_from_pixel_f;
use tracks::{CubeMap, TileGrid, TileId};

use super::{MeshParams, FILL_RINGS};
use crate::boundaries::theta_pixel;

/// The lattice of pixel centres a tile's mesh spans, with per-pixel depth data.
pub(crate) struct Field {
    pub(super) x0: u32,
    pub(super) y0: u32,
    /// Tile's own pixel rectangle end (exclusive), face pixels.
    pub(super) x1: u32,
    pub(super) y1: u32,
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) valid: Vec<bool>,
    pub(super) r: Vec<f64>,
    pub(super) q: Vec<f64>,
    pub(super) dnorm: Vec<f64>,
    /// Discontinuity between `(i, j)` and `(i + 1, j)` / `(i, j + 1)`.
    pub(super) disc_right: Vec<bool>,
    pub(super) disc_down: Vec<bool>,
    /// Connected component over continuous edges; `u32::MAX` for transparent pixels (and for
    /// all pixels of a field built without components).
    pub(super) comp: Vec<u32>,
    /// The filled band: for transparent pixels within [`FILL_RINGS`] of the surface their ring
    /// (1 = next to the surface), 0 for all others. Band pixels have an extrapolated depth
    /// (`q`, `r` and `comp` set; `valid` stays false, so they count for neither coverage nor
    /// error): adaptive meshes may place vertices there and overhang them; the mask cuts.
    pub(super) ring: Vec<u8>,
    /// Parallax pixels per unit of `1/r`: `B / θ_pixel`.
    pub(super) px_per_inv_m: f64,
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
    pub(super) fn build(
        depth: &CubeMap<f32>,
        mask: &CubeMap<bool>,
        grid: TileGrid,
        tile: TileId,
        params: &MeshParams,
        components: bool,
    ) -> Field {
        let n = grid.face_size;
        let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
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
    pub(super) fn filled(&self, k: usize) -> bool {
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

    pub(super) fn idx(&self, i: usize, j: usize) -> usize {
        j * self.w + i
    }

    /// Whether pixel `(i, j)` touches a discontinuity edge.
    pub(super) fn at_discontinuity(&self, i: usize, j: usize) -> bool {
        let k = self.idx(i, j);
        self.disc_right[k]
            || self.disc_down[k]
            || (i > 0 && self.disc_right[k - 1])
            || (j > 0 && self.disc_down[k - self.w])
    }

    /// Whether local pixel `(i, j)` belongs to the tile itself (not the next tile's edge).
    pub(super) fn in_tile(&self, i: usize, j: usize) -> bool {
        self.x0 + (i as u32) < self.x1 && self.y0 + (j as u32) < self.y1
    }

    pub(super) fn error_px(&self, k: usize, q_mesh: f64) -> f64 {
        (self.q[k] - q_mesh).abs() * self.px_per_inv_m / self.dnorm[k]
    }

    /// Emit a vertex for local pixel `(i, j)`.
    pub(super) fn vertex(&self, i: usize, j: usize) -> [f32; 3] {
        [
            (self.x0 as f64 + i as f64 + 0.5) as f32,
            (self.y0 as f64 + j as f64 + 0.5) as f32,
            self.r[self.idx(i, j)] as f32,
        ]
    }
}
