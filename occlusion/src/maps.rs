//! The occlusion map of one reference viewpoint and the O(1) window queries on it.
//!
//! [`OcclusionMap`] holds, per pixel, whether a kept tile of an earlier slab is opaque there
//! and the nearest such occluder's radial depth. [`WindowQuery`] is built from it once per
//! slab: per face a summed-area table of the (optionally hole-punched) opacity, so the mean
//! opacity over any pixel rectangle costs four reads, and block-minimum grids of occluder
//! planar depth along each face axis, so the nearest occluder over a rectangle is bounded
//! from below by reading the blocks it touches.

use rayon::prelude::*;
use tracks::{cubemap::subpixel_dir, CubeMap, Face, FaceCoord};

use crate::window::PixelRect;

/// Side of the blocks of the depth-minimum grids, pixels: 8 at 1024² faces, down to single
/// pixels at 128² and below (where a block would span many degrees).
fn block_size(face_size: u32) -> u32 {
    (face_size / 128).clamp(1, 8)
}

/// Opacity and nearest occluder depth of the kept tiles of the slabs processed so far.
#[derive(Clone, Debug)]
pub struct OcclusionMap {
    /// 1 where some kept earlier tile is opaque.
    pub opaque: CubeMap<u8>,
    /// Radial depth of the nearest opaque kept occluder, `+inf` where none.
    pub depth: CubeMap<f32>,
}

impl Default for OcclusionMap {
    /// An empty map of empty faces ([`OcclusionMap::reset`] sizes it).
    fn default() -> Self {
        OcclusionMap::new(0)
    }
}

impl OcclusionMap {
    /// An empty map (nothing occludes yet).
    pub fn new(face_size: u32) -> Self {
        OcclusionMap {
            opaque: CubeMap::filled(face_size, 0),
            depth: CubeMap::filled(face_size, f32::INFINITY),
        }
    }

    pub fn face_size(&self) -> u32 {
        self.opaque.face_size()
    }

    /// Empty the map again (nothing occludes), keeping its buffers; resized when
    /// `face_size` differs.
    pub fn reset(&mut self, face_size: u32) {
        if self.face_size() != face_size {
            *self = OcclusionMap::new(face_size);
            return;
        }
        self.opaque.as_mut_slice().fill(0);
        self.depth.as_mut_slice().fill(f32::INFINITY);
    }

    /// Add the opaque pixels of rectangle `(x0, y0, x1, y1)` of `face` from a slab layer.
    pub fn add_rect(
        &mut self,
        face: Face,
        rect: PixelBox,
        layer_alpha: &CubeMap<u8>,
        layer_depth: &CubeMap<f32>,
    ) {
        let n = self.face_size() as usize;
        let base = face.index() * n * n;
        let (mo, md) = (self.opaque.as_mut_slice(), self.depth.as_mut_slice());
        add_rect_in_face(
            &mut mo[base..base + n * n],
            &mut md[base..base + n * n],
            n,
            rect,
            layer_alpha.face(face),
            layer_depth.face(face),
        );
    }

    /// [`OcclusionMap::add_rect`] for every rectangle of `rects`, the faces in parallel (the
    /// result does not depend on the order: opacity is set, depth takes the minimum).
    pub fn add_rects(
        &mut self,
        rects: &[(Face, PixelBox)],
        layer_alpha: &CubeMap<u8>,
        layer_depth: &CubeMap<f32>,
    ) {
        let n = self.face_size() as usize;
        let nn = n * n;
        self.opaque
            .as_mut_slice()
            .par_chunks_mut(nn)
            .zip(self.depth.as_mut_slice().par_chunks_mut(nn))
            .enumerate()
            .for_each(|(fi, (mo, md))| {
                let face = Face::ALL[fi];
                let (la, ld) = (layer_alpha.face(face), layer_depth.face(face));
                for &(_, r) in rects.iter().filter(|(f, _)| *f == face) {
                    add_rect_in_face(mo, md, n, r, la, ld);
                }
            });
    }
}

/// The opaque pixels (alpha ≥ 128) of rectangle `r` of one face's layer into one face's map.
fn add_rect_in_face(mo: &mut [u8], md: &mut [f32], n: usize, r: PixelBox, la: &[u8], ld: &[f32]) {
    let (x0, y0, x1, y1) = r;
    for y in y0 as usize..y1 as usize {
        let row = y * n + x0 as usize..y * n + x1 as usize;
        let dst = mo[row.clone()].iter_mut().zip(&mut md[row.clone()]);
        // Selects instead of branches, so that the loop vectorises.
        for ((o, od), (&a, &d)) in dst.zip(la[row.clone()].iter().zip(&ld[row])) {
            let on = a >= 128;
            *o = if on { 1 } else { *o };
            *od = if on && d < *od { d } else { *od };
        }
    }
}

/// When two neighbouring occluder pixels are treated as a gap rather than one surface.
///
/// Inverse depth changes at a steady rate across a plane (exactly for planar depth, closely
/// for radial depth over a few pixels), also a plane seen at a grazing angle, and changes
/// rate without jumping at a crease. So a step in `1/d` from a pixel to its farther neighbour
/// is a gap when it is more than `slope_factor` times the steps just before and just after
/// it in the same direction (a missing step counts as zero), and when it opens by more than
/// `min_parallax_px` pixels over the cell: `B·(1/d_near − 1/d_far) > min_parallax_px·θ_pixel`
/// (θ_pixel = (π/2)/N, `B` the cell's largest offset).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscontinuityRule {
    pub slope_factor: f64,
    pub min_parallax_px: f64,
}

impl Default for DiscontinuityRule {
    fn default() -> Self {
        DiscontinuityRule {
            slope_factor: 1.5,
            min_parallax_px: 0.25,
        }
    }
}

/// The pixel across the edge of pixel `(x, y)` of `face` in direction `(dx, dy)` (one of the
/// four neighbours), on whichever face it falls.
pub fn neighbour(face: Face, x: u32, y: u32, dx: i32, dy: i32, n: u32) -> (Face, u32, u32) {
    let (nx, ny) = (x as i64 + dx as i64, y as i64 + dy as i64);
    if nx >= 0 && ny >= 0 && nx < n as i64 && ny < n as i64 {
        return (face, nx as u32, ny as u32);
    }
    let d = subpixel_dir(face, nx as f64 + 0.5, ny as f64 + 0.5, n);
    match FaceCoord::from_dir(d) {
        Some(c) => {
            let (px, py) = c.to_pixel(n);
            (c.face, px, py)
        }
        None => (face, x, y),
    }
}

/// Opacity with the nearer pixel of every depth discontinuity punched out (treated as a
/// hole), so that a window counted fully opaque has a continuous occluder surface.
pub fn hole_punched(map: &OcclusionMap, rule: DiscontinuityRule, cell_radius: f64) -> CubeMap<u8> {
    HolePunch::new(map, rule, cell_radius).opacity
}

/// A pixel rectangle `(x0, y0, x1, y1)` of one face, ends excluded.
pub type PixelBox = (u32, u32, u32, u32);

/// The hole-punched opacity of an [`OcclusionMap`] ([`hole_punched`]), kept up to date as
/// tiles join the map: [`HolePunch::update`] recomputes only the pixels whose neighbourhood
/// changed (two pixels around the new tiles, and the faces' border rings when a new tile
/// reaches one), with the same arithmetic as the full pass.
#[derive(Clone, Debug)]
pub struct HolePunch {
    rule: DiscontinuityRule,
    cell_radius: f64,
    /// Inverse depth of every occluder pixel, NaN where there is none.
    inv: CubeMap<f64>,
    /// The punched opacity (1: opaque, part of a continuous surface).
    pub opacity: CubeMap<u8>,
}

fn inverse_depth(o: u8, d: f32) -> f64 {
    if o != 0 {
        1.0 / d as f64
    } else {
        f64::NAN
    }
}

impl HolePunch {
    /// Punch the whole map.
    pub fn new(map: &OcclusionMap, rule: DiscontinuityRule, cell_radius: f64) -> HolePunch {
        let n = map.face_size();
        let mut p = HolePunch {
            rule,
            cell_radius,
            inv: CubeMap::filled(n, f64::NAN),
            opacity: map.opaque.clone(),
        };
        p.rebuild(map, rule, cell_radius);
        p
    }

    /// Punch the whole map again, as [`HolePunch::new`] would, reusing this one's buffers.
    pub fn rebuild(&mut self, map: &OcclusionMap, rule: DiscontinuityRule, cell_radius: f64) {
        let n = map.face_size();
        let nn = n as usize * n as usize;
        self.rule = rule;
        self.cell_radius = cell_radius;
        if self.inv.face_size() != n {
            self.inv = CubeMap::filled(n, f64::NAN);
        }
        self.inv
            .as_mut_slice()
            .par_chunks_mut(nn)
            .enumerate()
            .for_each(|(fi, out)| {
                let face = Face::ALL[fi];
                let (od, dd) = (map.opaque.face(face), map.depth.face(face));
                for ((w, &o), &d) in out.iter_mut().zip(od).zip(dd) {
                    *w = inverse_depth(o, d);
                }
            });
        if self.opacity.face_size() == n {
            self.opacity
                .as_mut_slice()
                .copy_from_slice(map.opaque.as_slice());
        } else {
            self.opacity = map.opaque.clone();
        }
        let inv = &self.inv;
        let ctx = PunchCtx::new(inv, rule, cell_radius);
        self.opacity
            .as_mut_slice()
            .par_chunks_mut(nn)
            .enumerate()
            .for_each(|(fi, face_px)| {
                let face = Face::ALL[fi];
                let fi_inv = inv.face(face);
                let nu = n as usize;
                for y in 0..n {
                    let inner_row = y >= 2 && y + 2 < n;
                    for x in 0..n {
                        let i = (y * n + x) as usize;
                        if face_px[i] == 0 {
                            continue;
                        }
                        if inner_row && x >= 2 && x + 2 < n {
                            // No neighbour farther by enough to open a gap: no gap (the same
                            // test as the first one in `gap`, on the farthest neighbour).
                            let far = fi_inv[i - 1]
                                .min(fi_inv[i + 1])
                                .min(fi_inv[i - nu])
                                .min(fi_inv[i + nu]);
                            let opens = cell_radius * (fi_inv[i] - far) > ctx.min_parallax;
                            if !opens {
                                continue;
                            }
                        }
                        if ctx.gap(face, x, y) {
                            face_px[i] = 0;
                        }
                    }
                }
            });
    }

    /// Bring the punched opacity up to date after the pixel rectangles `changed`
    /// (`(face, (x0, y0, x1, y1))`) of `map` changed.
    pub fn update(&mut self, map: &OcclusionMap, changed: &[(Face, PixelBox)]) {
        let n = map.face_size();
        let nu = n as usize;
        self.inv
            .as_mut_slice()
            .par_chunks_mut(nu * nu)
            .enumerate()
            .for_each(|(fi, inv)| {
                let face = Face::ALL[fi];
                let (od, dd) = (map.opaque.face(face), map.depth.face(face));
                for &(_, (x0, y0, x1, y1)) in changed.iter().filter(|(f, _)| *f == face) {
                    for y in y0 as usize..y1 as usize {
                        let row = y * nu + x0 as usize..y * nu + x1 as usize;
                        let src = od[row.clone()].iter().zip(&dd[row.clone()]);
                        for (w, (&o, &d)) in inv[row].iter_mut().zip(src) {
                            *w = inverse_depth(o, d);
                        }
                    }
                }
            });
        let grow = |(x0, y0, x1, y1): (u32, u32, u32, u32)| {
            (
                x0.saturating_sub(2),
                y0.saturating_sub(2),
                (x1 + 2).min(n),
                (y1 + 2).min(n),
            )
        };
        let rings = changed
            .iter()
            .any(|&(_, (x0, y0, x1, y1))| x0 < 2 || y0 < 2 || x1 + 2 > n || y1 + 2 > n);
        let nn = n as usize * n as usize;
        let ctx = PunchCtx::new(&self.inv, self.rule, self.cell_radius);
        let opaque = &map.opaque;
        self.opacity
            .as_mut_slice()
            .par_chunks_mut(nn)
            .enumerate()
            .for_each(|(fi, face_px)| {
                let face = Face::ALL[fi];
                let od = opaque.face(face);
                let mut redo = |x: u32, y: u32| {
                    let i = (y * n + x) as usize;
                    face_px[i] = u8::from(od[i] != 0 && !ctx.gap(face, x, y));
                };
                for &(f, r) in changed {
                    if f != face {
                        continue;
                    }
                    let (x0, y0, x1, y1) = grow(r);
                    for y in y0..y1 {
                        for x in x0..x1 {
                            redo(x, y);
                        }
                    }
                }
                if rings {
                    for y in 0..n {
                        if y < 2 || y + 2 >= n {
                            (0..n).for_each(|x| redo(x, y));
                        } else {
                            // n ≥ 5 here: the two first and two last pixels.
                            (0..2).chain(n - 2..n).for_each(|x| redo(x, y));
                        }
                    }
                }
            });
    }
}

/// The punching rule on inverse depths.
struct PunchCtx<'a> {
    /// The whole map of inverse depths (`None` where they are read one by one).
    inv: Option<&'a CubeMap<f64>>,
    n: u32,
    rule: DiscontinuityRule,
    cell_radius: f64,
    min_parallax: f64,
}

impl PunchCtx<'_> {
    fn new(inv: &CubeMap<f64>, rule: DiscontinuityRule, cell_radius: f64) -> PunchCtx<'_> {
        let n = inv.face_size();
        PunchCtx {
            inv: Some(inv),
            n,
            rule,
            cell_radius,
            min_parallax: rule.min_parallax_px * std::f64::consts::FRAC_PI_2 / n as f64,
        }
    }

    /// Whether the pair (nearer `wp`, farther `wq`) with the steps `before` and `after` in
    /// the same direction is a gap.
    fn is_gap(&self, wp: f64, wq: f64, before: f64, after: f64) -> bool {
        let s = wp - wq;
        // Only the nearer pixel of a pair is punched; it must open a gap.
        s > 0.0
            && self.cell_radius * s > self.min_parallax
            && s > self.rule.slope_factor * before.max(after) + 1e-6 * wp
    }

    fn step(&self, face: Face, x: u32, y: u32, dx: i32, dy: i32) -> (Face, u32, u32) {
        let n = self.n;
        let inside = (x > 0 || dx >= 0)
            && (y > 0 || dy >= 0)
            && (x + 1 < n || dx <= 0)
            && (y + 1 < n || dy <= 0);
        if inside {
            (face, (x as i32 + dx) as u32, (y as i32 + dy) as u32)
        } else {
            neighbour(face, x, y, dx, dy, n)
        }
    }

    /// Whether the occluder pixel `(x, y)` of `face` is the nearer side of a gap.
    fn gap(&self, face: Face, x: u32, y: u32) -> bool {
        let n = self.n;
        let Some(map) = self.inv else {
            return false;
        };
        let fi = map.face(face);
        let nu = n as usize;
        let i = y as usize * nu + x as usize;
        let wp = fi[i];
        if wp.is_nan() {
            return false;
        }
        if x >= 2 && y >= 2 && x + 2 < n && y + 2 < n {
            // Fast path: all five pixels on this face. No neighbour farther by enough to open
            // a gap (the first test below, on the farthest neighbour): no gap.
            let far = fi[i - 1].min(fi[i + 1]).min(fi[i - nu]).min(fi[i + nu]);
            let opens = self.cell_radius * (wp - far) > self.min_parallax;
            if !opens {
                return false;
            }
            for st in [-1isize, 1, -(nu as isize), nu as isize] {
                let at = |k: isize| fi[(i as isize + k * st) as usize];
                let wq = at(1);
                // Most pairs are no gap: same surface, or opening too little.
                if wq.is_nan()
                    || wp - wq <= 0.0
                    || self.cell_radius * (wp - wq) <= self.min_parallax
                {
                    continue;
                }
                let (wb, wa) = (at(-1), at(2));
                let before = if wb.is_nan() { 0.0 } else { (wb - wp).abs() };
                let after = if wa.is_nan() { 0.0 } else { (wq - wa).abs() };
                if self.is_gap(wp, wq, before, after) {
                    return true;
                }
            }
            return false;
        }
        let inv = |f: Face, x: u32, y: u32| *map.get(f, x, y);
        self.gap_by(&inv, face, x, y, wp)
    }

    /// [`PunchCtx::gap`] through any inverse-depth lookup (NaN: no occluder), face edges
    /// included.
    fn gap_by(
        &self,
        inv: &dyn Fn(Face, u32, u32) -> f64,
        face: Face,
        x: u32,
        y: u32,
        wp: f64,
    ) -> bool {
        let w = |(f, x, y): (Face, u32, u32)| {
            let v = inv(f, x, y);
            (!v.is_nan()).then_some(v)
        };
        for (dx, dy) in [(-1i32, 0i32), (1, 0), (0, -1), (0, 1)] {
            let q = self.step(face, x, y, dx, dy);
            let Some(wq) = w(q) else { continue };
            // Most pairs are no gap (the first tests of `is_gap`, which need no neighbour
            // beyond): same surface, or opening too little.
            if wp - wq <= 0.0 || self.cell_radius * (wp - wq) <= self.min_parallax {
                continue;
            }
            let before = w(self.step(face, x, y, -dx, -dy)).map_or(0.0, |wb| (wb - wp).abs());
            // Past a face edge the direction of travel turns: no "after" step.
            let after = if q.0 == face {
                w(self.step(q.0, q.1, q.2, dx, dy)).map_or(0.0, |wa| (wq - wa).abs())
            } else {
                0.0
            };
            if self.is_gap(wp, wq, before, after) {
                return true;
            }
        }
        false
    }
}

/// Whether the occluder pixel `at` is the nearer side of a gap under `rule` for a cell of
/// `cell_radius` ([`hole_punched`]'s rule), with inverse depths read through `inv` (NaN: no
/// occluder) — for maps filled in on demand.
pub(crate) fn gap_at(
    inv: &dyn Fn(Face, u32, u32) -> f64,
    n: u32,
    rule: DiscontinuityRule,
    cell_radius: f64,
    at: (Face, u32, u32),
) -> bool {
    let ctx = PunchCtx {
        inv: None,
        n,
        rule,
        cell_radius,
        min_parallax: rule.min_parallax_px * std::f64::consts::FRAC_PI_2 / n as f64,
    };
    let wp = inv(at.0, at.1, at.2);
    !wp.is_nan() && ctx.gap_by(inv, at.0, at.1, at.2, wp)
}

/// Per-face summed-area table of opacity and block-minimum occluder depth.
#[derive(Clone, Debug)]
pub struct WindowQuery {
    n: u32,
    /// Per face `(n + 1)²` prefix sums, face-major.
    sat: Vec<u32>,
    block: u32,
    blocks: u32,
    /// `planar_min[level]`: per (face, axis) a grid of `side(level)²` minima; level 0 has one
    /// cell per block, each level above halves the side (min of 2 × 2).
    planar_min: Vec<Vec<f32>>,
    /// Per (face, axis, block) the smallest cosine between the block's directions and the
    /// axis (depends on the face size only: kept across rebuilds); empty until needed.
    min_cos: Vec<f64>,
}

/// Per face, per axis (`Face::ALL` order), per block of `block` pixels: the smallest cosine
/// between the block's directions and the axis, at a corner (the cosine is monotonic in `u`
/// and in `v` over a face).
fn block_min_cos(n: u32, block: u32, blocks: u32) -> Vec<f64> {
    let bb = blocks as usize * blocks as usize;
    let mut out = vec![0.0; 36 * bb];
    out.par_chunks_mut(6 * bb)
        .enumerate()
        .for_each(|(fi, out)| {
            let face = Face::ALL[fi];
            let nf = n as f64;
            for by in 0..blocks {
                for bx in 0..blocks {
                    let bi = (by * blocks + bx) as usize;
                    let (x0, x1) = ((bx * block) as f64, ((bx + 1) * block).min(n) as f64);
                    let (y0, y1) = ((by * block) as f64, ((by + 1) * block).min(n) as f64);
                    let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)].map(|(x, y)| {
                        face.dir_from_uv(2.0 * x / nf - 1.0, 1.0 - 2.0 * y / nf)
                            .normalize()
                    });
                    for along in Face::ALL {
                        out[along.index() * bb + bi] = corners
                            .iter()
                            .map(|d| d.dot(along.forward()))
                            .fold(f64::INFINITY, f64::min);
                    }
                }
            }
        });
    out
}

/// Per face `(n + 1)²` prefix sums of `opacity`, written into `sat` (reused when it has the
/// right size: every entry is overwritten).
fn summed_area(opacity: &CubeMap<u8>, mut sat: Vec<u32>) -> Vec<u32> {
    let n = opacity.face_size();
    let w = n as usize + 1;
    if sat.len() != 6 * w * w {
        sat = vec![0u32; 6 * w * w];
    }
    sat.par_chunks_mut(w * w).enumerate().for_each(|(fi, s)| {
        let face = opacity.face(Face::ALL[fi]);
        s[..w].fill(0);
        for row in s.chunks_exact_mut(w) {
            row[0] = 0;
        }
        for (y, src) in face.chunks_exact(n as usize).enumerate() {
            let (above, below) = s.split_at_mut((y + 1) * w);
            let prev = &above[y * w..];
            let cur = &mut below[..w];
            let mut row = 0u32;
            for x in 0..n as usize {
                row += src[x] as u32;
                cur[x + 1] = prev[x + 1] + row;
            }
        }
    });
    sat
}

impl WindowQuery {
    /// Opacity queries only (the paper's variant never asks for depths): every depth bound
    /// is `-inf`.
    pub fn opacity_only(opacity: &CubeMap<u8>) -> Self {
        Self::opacity_only_reusing(opacity, Vec::new())
    }

    /// [`WindowQuery::opacity_only`] into this query's buffers.
    pub fn rebuild_opacity_only(&mut self, opacity: &CubeMap<u8>) {
        let sat = std::mem::take(&mut self.sat);
        let min_cos = std::mem::take(&mut self.min_cos);
        *self = Self::opacity_only_reusing(opacity, sat);
        self.min_cos = min_cos;
    }

    fn opacity_only_reusing(opacity: &CubeMap<u8>, sat: Vec<u32>) -> Self {
        let n = opacity.face_size();
        WindowQuery {
            n,
            sat: summed_area(opacity, sat),
            block: n.max(1),
            blocks: 1,
            planar_min: vec![vec![f32::NEG_INFINITY; 36]],
            min_cos: Vec::new(),
        }
    }

    /// Build from the 0/1 opacity the mean is taken over (`opacity`, possibly hole-punched),
    /// and the occluders (`opaque`, `depth`) the nearest depth is taken over.
    pub fn new(opacity: &CubeMap<u8>, opaque: &CubeMap<u8>, depth: &CubeMap<f32>) -> Self {
        Self::new_reusing(opacity, opaque, depth, Vec::new(), Vec::new())
    }

    /// [`WindowQuery::new`] into this query's buffers (the summed-area tables, the largest).
    pub fn rebuild(&mut self, opacity: &CubeMap<u8>, opaque: &CubeMap<u8>, depth: &CubeMap<f32>) {
        let sat = std::mem::take(&mut self.sat);
        // The cosines depend on the face size only.
        let min_cos = if self.n == opacity.face_size() {
            std::mem::take(&mut self.min_cos)
        } else {
            Vec::new()
        };
        *self = Self::new_reusing(opacity, opaque, depth, sat, min_cos);
    }

    fn new_reusing(
        opacity: &CubeMap<u8>,
        opaque: &CubeMap<u8>,
        depth: &CubeMap<f32>,
        sat: Vec<u32>,
        min_cos: Vec<f64>,
    ) -> Self {
        let n = opacity.face_size();
        let sat = summed_area(opacity, sat);
        let block = block_size(n);
        let blocks = n.div_ceil(block);
        let bb = blocks as usize * blocks as usize;
        let min_cos = if min_cos.len() == 36 * bb {
            min_cos
        } else {
            block_min_cos(n, block, blocks)
        };
        // Per face, the block minimum of radial occluder depth …
        let mut radial_min = vec![f32::INFINITY; 6 * bb];
        radial_min
            .par_chunks_mut(bb)
            .enumerate()
            .for_each(|(fi, out)| {
                let face = Face::ALL[fi];
                let d = depth.face(face);
                let o = opaque.face(face);
                let b = block as usize;
                for (y, (dr, or)) in d
                    .chunks_exact(n as usize)
                    .zip(o.chunks_exact(n as usize))
                    .enumerate()
                {
                    let row = &mut out[(y as u32 / block * blocks) as usize..][..blocks as usize];
                    for (slot, (dc, oc)) in row.iter_mut().zip(dr.chunks(b).zip(or.chunks(b))) {
                        let m = dc
                            .iter()
                            .zip(oc)
                            .map(|(&d, &o)| if o != 0 { d } else { f32::INFINITY })
                            .fold(f32::INFINITY, f32::min);
                        if m < *slot {
                            *slot = m;
                        }
                    }
                }
            });
        // … times the smallest cosine between the block and each face axis bounds the planar
        // depth from below.
        let mut planar_min = vec![f32::INFINITY; 36 * bb];
        planar_min
            .par_chunks_mut(6 * bb)
            .zip(min_cos.par_chunks(6 * bb))
            .enumerate()
            .for_each(|(fi, (out, cos))| {
                let radial = &radial_min[fi * bb..(fi + 1) * bb];
                for (bi, &dmin) in radial.iter().enumerate() {
                    let dmin = dmin as f64;
                    if !dmin.is_finite() {
                        continue;
                    }
                    for along in 0..6 {
                        let c = cos[along * bb + bi];
                        out[along * bb + bi] = if c > 0.0 {
                            (dmin * c) as f32
                        } else {
                            f32::NEG_INFINITY
                        };
                    }
                }
            });
        let mut levels = vec![planar_min];
        let mut side = blocks as usize;
        while side > 1 {
            let up = side.div_ceil(2);
            let prev = levels.last().map(|l| l.as_slice()).unwrap_or(&[]);
            let mut next = vec![f32::INFINITY; 36 * up * up];
            for g in 0..36 {
                for y in 0..side {
                    for x in 0..side {
                        let v = prev[g * side * side + y * side + x];
                        let slot = &mut next[g * up * up + (y / 2) * up + x / 2];
                        if v < *slot {
                            *slot = v;
                        }
                    }
                }
            }
            levels.push(next);
            side = up;
        }
        WindowQuery {
            n,
            sat,
            block,
            blocks,
            planar_min: levels,
            min_cos,
        }
    }

    /// Opaque pixels inside `r`.
    pub fn opaque_count(&self, r: &PixelRect) -> u64 {
        let w = self.n as usize + 1;
        let s = &self.sat[r.face.index() * w * w..(r.face.index() + 1) * w * w];
        let at = |x: u32, y: u32| s[y as usize * w + x as usize] as i64;
        (at(r.x1, r.y1) - at(r.x0, r.y1) - at(r.x1, r.y0) + at(r.x0, r.y0)) as u64
    }

    /// A lower bound on the planar depth along `along`'s forward axis of the opaque
    /// occluders inside `r` (`+inf` if none; ≤ 0 if some occluder lies beside or behind
    /// that axis's plane through the viewpoint). Rounded down to f32 conservatively.
    pub fn min_planar_depth(&self, r: &PixelRect, along: Face) -> f64 {
        // The finest level at which the rectangle spans at most 4 cells a side.
        let (b0x, b1x) = (r.x0 / self.block, r.x1.div_ceil(self.block));
        let (b0y, b1y) = (r.y0 / self.block, r.y1.div_ceil(self.block));
        let mut level = 0usize;
        while level + 1 < self.planar_min.len() && ((b1x - 1) >> level) - (b0x >> level) >= 4
            || level + 1 < self.planar_min.len() && ((b1y - 1) >> level) - (b0y >> level) >= 4
        {
            level += 1;
        }
        let side = (self.blocks as usize).div_ceil(1 << level);
        let g = r.face.index() * 6 + along.index();
        let b = &self.planar_min[level][g * side * side..(g + 1) * side * side];
        let mut m = f32::INFINITY;
        for by in (b0y >> level)..=((b1y - 1) >> level) {
            for bx in (b0x >> level)..=((b1x - 1) >> level) {
                m = m.min(b[by as usize * side + bx as usize]);
            }
        }
        // f32 rounding of d·cos may round up by half an ulp: step one ulp down.
        let m = m as f64;
        if m.is_finite() && m > 0.0 {
            m * (1.0 - 1e-6)
        } else {
            m
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sat_counts_and_block_minimum() {
        let n = 20;
        let opaque = CubeMap::from_fn(n, |f, x, y| u8::from(f == Face::NegY && x >= 3 && y < 10));
        let depth = CubeMap::from_fn(n, |_, x, y| 5.0 + x as f32 + 0.5 * y as f32);
        let q = WindowQuery::new(&opaque, &opaque, &depth);
        let r = PixelRect {
            face: Face::NegY,
            x0: 0,
            y0: 0,
            x1: 20,
            y1: 20,
        };
        assert_eq!(q.opaque_count(&r), 17 * 10);
        let r2 = PixelRect {
            x0: 5,
            y0: 2,
            x1: 9,
            y1: 12,
            ..r
        };
        assert_eq!(q.opaque_count(&r2), 4 * 8);
        // Along the face's own axis: planar depth d·cos of the nearest pixel (5, 2) at
        // depth 11 bounds it; the 8-pixel blocks reach back to x = 3 (depth 8) at worst.
        let z = q.min_planar_depth(&r2, Face::NegY);
        let near = 11.0 * tracks::cubemap::pixel_dir(Face::NegY, 5, 2, n).dot(Face::NegY.forward());
        assert!(z <= near && z >= 8.0 * 0.5, "{z} {near}");
        let px = PixelRect {
            face: Face::PosX,
            ..r
        };
        assert_eq!(q.min_planar_depth(&px, Face::PosX), f64::INFINITY);
        // Along a neighbour's axis the same pixels are partly beside it: nearer.
        assert!(q.min_planar_depth(&r2, Face::PosX) < z);
    }

    #[test]
    fn pyramid_minimum_bounds_every_pixel_below() {
        let n = 256;
        let opaque = CubeMap::from_fn(n, |_, x, y| u8::from((x * 7 + y * 3) % 11 != 0));
        let depth = CubeMap::from_fn(n, |f, x, y| {
            2.0 + ((x * 31 + y * 17 + f.index() as u32 * 5) % 97) as f32 * 0.25
        });
        let q = WindowQuery::new(&opaque, &opaque, &depth);
        for (k, face) in Face::ALL.into_iter().enumerate() {
            let (x0, y0) = (3 + 37 * k as u32, 11 + 23 * k as u32);
            for (w, h) in [(1, 1), (5, 9), (40, 3), (120, 200)] {
                let r = PixelRect {
                    face,
                    x0,
                    y0,
                    x1: (x0 + w).min(n),
                    y1: (y0 + h).min(n),
                };
                let mut brute = f64::INFINITY;
                for y in r.y0..r.y1 {
                    for x in r.x0..r.x1 {
                        if *opaque.get(face, x, y) != 0 {
                            let c = tracks::cubemap::pixel_dir(face, x, y, n).dot(face.forward());
                            brute = brute.min(*depth.get(face, x, y) as f64 * c);
                        }
                    }
                }
                let z = q.min_planar_depth(&r, face);
                assert!(z <= brute && z > 0.0, "{face:?} {r:?}: {z} > {brute}");
            }
        }
    }

    #[test]
    fn neighbours_across_face_edges() {
        let n = 8;
        // Left of +x's left column is +z's right column (+x's right is +z, so its left is −z…
        // check by direction instead of by table).
        for face in Face::ALL {
            for (x, y, dx, dy) in [(0, 3, -1, 0), (7, 3, 1, 0), (3, 0, 0, -1), (3, 7, 0, 1)] {
                let (f2, x2, y2) = neighbour(face, x, y, dx, dy, n);
                assert_ne!(f2, face);
                let a = tracks::cubemap::pixel_dir(face, x, y, n);
                let b = tracks::cubemap::pixel_dir(f2, x2, y2, n);
                // Adjacent pixels are about one pixel angle apart.
                assert!(a.angle_between(b) < 2.5 * std::f64::consts::FRAC_PI_2 / n as f64);
            }
        }
    }

    /// The punching rule pixel by pixel, every neighbour found through [`neighbour`] and every
    /// inverse depth computed where it is used: what the fast path must reproduce.
    fn punched_reference(map: &OcclusionMap, rule: DiscontinuityRule, radius: f64) -> CubeMap<u8> {
        let n = map.face_size();
        let min_parallax = rule.min_parallax_px * std::f64::consts::FRAC_PI_2 / n as f64;
        let w = |(f, x, y): (Face, u32, u32)| {
            (*map.opaque.get(f, x, y) != 0).then(|| 1.0 / *map.depth.get(f, x, y) as f64)
        };
        CubeMap::from_fn(n, |face, x, y| {
            let Some(wp) = w((face, x, y)) else { return 0 };
            for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                let q = neighbour(face, x, y, dx, dy, n);
                let Some(wq) = w(q) else { continue };
                let before = w(neighbour(face, x, y, -dx, -dy, n)).map_or(0.0, |b| (b - wp).abs());
                let after = if q.0 == face {
                    w(neighbour(q.0, q.1, q.2, dx, dy, n)).map_or(0.0, |a| (wq - a).abs())
                } else {
                    0.0
                };
                let s = wp - wq;
                if s > 0.0
                    && radius * s > min_parallax
                    && s > rule.slope_factor * before.max(after) + 1e-6 * wp
                {
                    return 0;
                }
            }
            1
        })
    }

    #[test]
    fn hole_punching_matches_the_per_pixel_reference() {
        let n = 24;
        let mut m = OcclusionMap::new(n);
        let mut state = 12345u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        for i in 0..m.opaque.as_slice().len() {
            let (o, d) = (rnd(), rnd());
            m.opaque.as_mut_slice()[i] = u8::from(o < 0.85);
            // Smooth ramps with occasional jumps.
            let base = 3.0 + (i % 7) as f64 * 0.1;
            m.depth.as_mut_slice()[i] = if d < 0.2 {
                (base * 4.0) as f32
            } else {
                base as f32
            };
        }
        // 0.02 m of motion opens the 1/3 − 1/12 jumps by less than a quarter pixel: no holes.
        for radius in [0.0, 0.02, 1.0] {
            let fast = hole_punched(&m, DiscontinuityRule::default(), radius);
            let slow = punched_reference(&m, DiscontinuityRule::default(), radius);
            assert_eq!(fast.as_slice(), slow.as_slice(), "radius {radius}");
            let holes = m
                .opaque
                .as_slice()
                .iter()
                .zip(fast.as_slice())
                .filter(|(a, b)| a != b);
            assert_eq!(holes.count() > 0, radius >= 1.0, "radius {radius}");
        }
    }

    #[test]
    fn updating_the_punched_map_equals_punching_it_again() {
        let n = 20;
        let mut state = 777u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        let layer_alpha = CubeMap::from_fn(n, |_, _, _| 0u8).map(|_| u8::from(rnd() < 0.9) * 255);
        let layer_depth = CubeMap::from_fn(n, |_, x, y| 2.0 + 0.05 * (x + y) as f32).map(|&d| {
            if rnd() < 0.15 {
                d * 3.0
            } else {
                d
            }
        });
        let mut m = OcclusionMap::new(n);
        let rule = DiscontinuityRule::default();
        // Start from a few rectangles, then add more, some on face borders.
        let first = [(Face::PosX, (3, 4, 12, 15)), (Face::NegZ, (0, 0, 20, 6))];
        let more = [
            (Face::PosX, (10, 0, 20, 9)),
            (Face::PosY, (5, 5, 9, 9)),
            (Face::NegY, (0, 12, 20, 20)),
            (Face::PosZ, (18, 2, 20, 20)),
        ];
        for &(f, r) in &first {
            m.add_rect(f, r, &layer_alpha, &layer_depth);
        }
        let mut p = HolePunch::new(&m, rule, 1.0);
        for &(f, r) in &more {
            m.add_rect(f, r, &layer_alpha, &layer_depth);
        }
        p.update(&m, &more);
        let fresh = HolePunch::new(&m, rule, 1.0);
        assert_eq!(p.opacity.as_slice(), fresh.opacity.as_slice());
        assert_ne!(fresh.opacity.as_slice(), m.opaque.as_slice(), "some holes");
    }

    /// A map of random opaque pixels with smooth depth and occasional jumps.
    fn random_map(n: u32, seed: u64) -> OcclusionMap {
        let mut state = seed;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        let mut m = OcclusionMap::new(n);
        for i in 0..m.opaque.as_slice().len() {
            m.opaque.as_mut_slice()[i] = u8::from(rnd() < 0.8);
            let base = 2.0 + (i % 13) as f32 * 0.05;
            m.depth.as_mut_slice()[i] = if rnd() < 0.1 { base * 5.0 } else { base };
        }
        m
    }

    #[test]
    fn add_rects_equals_adding_one_by_one() {
        let n = 24;
        let src = random_map(n, 99);
        let alpha = src.opaque.map(|&o| o * 200);
        let rects = [
            (Face::PosX, (0, 0, 8, 8)),
            (Face::NegZ, (4, 10, 24, 24)),
            (Face::PosX, (6, 6, 20, 12)),
            (Face::PosY, (0, 16, 8, 24)),
        ];
        let mut one = random_map(n, 5);
        let mut all = one.clone();
        for &(f, r) in &rects {
            one.add_rect(f, r, &alpha, &src.depth);
        }
        all.add_rects(&rects, &alpha, &src.depth);
        assert_eq!(one.opaque.as_slice(), all.opaque.as_slice());
        assert_eq!(one.depth.as_slice(), all.depth.as_slice());
        // Reset empties it, whatever it held.
        all.reset(n);
        assert_eq!(
            all.opaque.as_slice(),
            OcclusionMap::new(n).opaque.as_slice()
        );
        assert!(all.depth.as_slice().iter().all(|d| *d == f32::INFINITY));
    }

    #[test]
    fn rebuilding_in_used_buffers_equals_building_afresh() {
        let n = 20;
        let rule = DiscontinuityRule::default();
        let (a, b) = (random_map(n, 1), random_map(n, 2));
        // Punch: buffers that held another map (and another radius) give the same result.
        let mut p = HolePunch::new(&a, rule, 0.3);
        p.rebuild(&b, rule, 1.0);
        let fresh = HolePunch::new(&b, rule, 1.0);
        assert_eq!(p.opacity.as_slice(), fresh.opacity.as_slice());
        assert_ne!(fresh.opacity.as_slice(), b.opaque.as_slice(), "some holes");
        // A buffer of another face size is replaced.
        let mut small = HolePunch::new(&random_map(8, 3), rule, 1.0);
        small.rebuild(&b, rule, 1.0);
        assert_eq!(small.opacity.as_slice(), fresh.opacity.as_slice());
        // Queries: every table equal to a fresh build.
        let same = |x: &WindowQuery, y: &WindowQuery| {
            assert_eq!((x.n, x.block, x.blocks), (y.n, y.block, y.blocks));
            assert_eq!(x.sat, y.sat);
            assert_eq!(x.planar_min, y.planar_min);
        };
        let mut q = WindowQuery::new(&a.opaque, &a.opaque, &a.depth);
        q.rebuild(&fresh.opacity, &b.opaque, &b.depth);
        same(&q, &WindowQuery::new(&fresh.opacity, &b.opaque, &b.depth));
        q.rebuild_opacity_only(&a.opaque);
        same(&q, &WindowQuery::opacity_only(&a.opaque));
        let m8 = random_map(8, 3);
        let mut q8 = WindowQuery::new(&m8.opaque, &m8.opaque, &m8.depth);
        q8.rebuild(&b.opaque, &b.opaque, &b.depth);
        same(&q8, &WindowQuery::new(&b.opaque, &b.opaque, &b.depth));
    }

    /// Many small updates reaching face edges and corners, each compared with punching the
    /// whole map again (what crosses an edge must be redone on the neighbouring face).
    #[test]
    fn updates_at_face_edges_and_corners_equal_punching_again() {
        let n = 16;
        let rule = DiscontinuityRule::default();
        for seed in [11u64, 12, 13] {
            let src = random_map(n, seed);
            let alpha = src.opaque.map(|&o| o * 255);
            let mut m = OcclusionMap::new(n);
            // Start from a partial map so later rectangles create and hide gaps.
            m.add_rects(&[(Face::PosZ, (4, 4, 12, 12))], &alpha, &src.depth);
            let mut p = HolePunch::new(&m, rule, 1.0);
            let mut state = seed;
            let mut rnd = move |k: u32| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 33) % k as u64) as u32
            };
            for _ in 0..12 {
                let mut batch = Vec::new();
                for _ in 0..3 {
                    let face = Face::ALL[rnd(6) as usize];
                    // Corners, edges and thin strips along them.
                    let (w, h) = (1 + rnd(5), 1 + rnd(5));
                    let x0 = [0, n - w, rnd(n - w + 1)][rnd(3) as usize];
                    let y0 = [0, n - h, rnd(n - h + 1)][rnd(3) as usize];
                    batch.push((face, (x0, y0, x0 + w, y0 + h)));
                }
                m.add_rects(&batch, &alpha, &src.depth);
                p.update(&m, &batch);
                let fresh = HolePunch::new(&m, rule, 1.0);
                assert_eq!(p.opacity.as_slice(), fresh.opacity.as_slice(), "{batch:?}");
            }
            let fresh = HolePunch::new(&m, rule, 1.0);
            assert_ne!(fresh.opacity.as_slice(), m.opaque.as_slice(), "some holes");
        }
    }

    #[test]
    fn depth_jump_becomes_a_hole_on_the_near_side() {
        let n = 16;
        let mut m = OcclusionMap::new(n);
        m.opaque = CubeMap::filled(n, 1);
        m.depth = CubeMap::from_fn(n, |_, x, _| if x < 8 { 10.0 } else { 40.0 });
        let h = hole_punched(&m, DiscontinuityRule::default(), 1.0);
        assert_eq!(
            *h.get(Face::PosZ, 7, 5),
            0,
            "near side of the jump is a hole"
        );
        assert_eq!(*h.get(Face::PosZ, 8, 5), 1, "far side stays");
        assert_eq!(*h.get(Face::PosZ, 3, 5), 1);
        // Without motion there is no parallax, so no hole.
        let h0 = hole_punched(&m, DiscontinuityRule::default(), 0.0);
        assert_eq!(*h0.get(Face::PosZ, 7, 5), 1);
    }
}
