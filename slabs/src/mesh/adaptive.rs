//! The adaptive mesh: a Delaunay triangulation (`spade`) of a tile's lattice, refined until
//! it meets the error bound and covers the surface.

use spade::{DelaunayTriangulation, Point2, Triangulation};

use super::{raster, Field, MeshOut, TileMesh};

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

/// An adaptive mesh: a Delaunay triangulation of the lattice, refined by inserting the worst
/// pixel of every triangle whose error exceeds `max_error_px`, that covers a transparent
/// pixel beyond the filled band ([`FILL_RINGS`](super::FILL_RINGS)) or another continuous
/// surface, or whose corners are not one continuous surface. A triangle of one surface may
/// have corners in the filled band and overhang transparent pixels there: the renderer's
/// opacity mask cuts the outline, so the mesh need not follow its staircase pixel by pixel (on
/// the synthetic street this halves the triangles). A triangle whose corners are not one
/// surface is refined only while it covers an opaque pixel, at its outermost filled pixel if it
/// has one (the mesh then ends in the band), else at the opaque pixel nearest its centre;
/// without an opaque pixel it is dropped. Every lattice point can be inserted, so refinement
/// ends.
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
