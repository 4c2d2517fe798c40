//! Half-texel skirts around meshes whose vertices sit on pixel centres.
//!
//! The adaptive meshes of `slabs::mesh` (what databases store) span the lattice of pixel
//! centres of a tile's slab pixels, so the outer half texel of every outline pixel lies
//! outside all triangles: along cube-face edges, at slab boundaries (between slab `k`'s last
//! pixel centre and slab `k + 1`'s first), at depth discontinuities and against the sky. The
//! sky (or a hole) showed through there as cracks one texel wide. Grid meshes
//! ([`super::tile_mesh`]) end on pixel corners and let the opacity mask cut the outline
//! exactly; [`skirt`] gives a centre-lattice mesh the same reach: every boundary edge gets a
//! strip moved half a texel outwards (per axis, so the strip ends on the texel corners), and
//! every boundary vertex a corner patch joining its strips, clamped to the face. The mask
//! (bilinear alpha ≥ the cut inside an opaque texel, see `render.wgsl`) then cuts the outline
//! as it does for grid meshes. Skirt vertices keep their edge vertex's radial depth: exact at
//! the reference viewpoint (projective texturing), half a texel of depth off between.
//!
//! Adaptive meshes now reach up to two pixels past most outlines (`slabs::mesh`, the filled
//! band), so their boundary edges mostly lie on transparent pixels, where a skirt changes
//! nothing; skirts still close face edges, tile borders whose neighbour is not kept, lone
//! outline vertices and the meshes of databases built before.

use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

use tracks::{PixelRect, TileGrid};

use super::{pos_in_face, RefView, TileMesh};

/// Whether `c` lies on a pixel centre (`k + 0.5`).
fn on_centre(c: f32) -> bool {
    (c - c.floor() - 0.5).abs() < 1e-4
}

/// The skirts of every tile of `view` ([`skirt`]), with the borders shared with a kept
/// neighbour of the same slab and face.
pub fn view_skirts(view: &RefView) -> Vec<(Vec<[f32; 3]>, Vec<u32>)> {
    let n = view.face_size;
    let Some(grid) = TileGrid::new(n, view.tile_size) else {
        return view
            .tiles
            .iter()
            .map(|t| {
                let face = PixelRect {
                    face: t.tile.face,
                    x0: 0,
                    y0: 0,
                    x1: n,
                    y1: n,
                };
                skirt(&t.mesh, n, face, [false; 4])
            })
            .collect();
    };
    let kept: HashSet<(u32, usize, u32, u32)> = view
        .tiles
        .iter()
        .map(|t| (t.slab, t.tile.face.index(), t.tile.tx, t.tile.ty))
        .collect();
    // Tiles on every core: a view's skirts were a fifth of its upload.
    view.tiles
        .par_iter()
        .map(|t| {
            let (f, tx, ty) = (t.tile.face.index(), t.tile.tx, t.tile.ty);
            let has = |dx: i64, dy: i64| {
                let (x, y) = (tx as i64 + dx, ty as i64 + dy);
                x >= 0 && y >= 0 && kept.contains(&(t.slab, f, x as u32, y as u32))
            };
            let shared = [has(-1, 0), has(0, -1), has(1, 0), has(0, 1)];
            skirt(&t.mesh, n, grid.pixel_rect(t.tile), shared)
        })
        .collect()
}

/// The extra vertices and triangles (indices into `mesh.vertices` followed by the extra
/// vertices) that close the half-texel gap around `mesh`, the mesh of the tile covering
/// pixels `rect` of a face of `face_size` pixels.
/// Only boundary edges whose two ends sit on pixel centres get a skirt (grid meshes, whose
/// vertices sit on corners, get none), and none along a border shared with the next tile
/// of the face where `shared` (left, top, right, bottom) says that tile is kept (the lines
/// through the first pixel centres of this tile, `x0 + 0.5`, and of the next, `x1 + 0.5`;
/// the same in y): the neighbour's mesh meets this one there.
pub fn skirt(
    mesh: &TileMesh,
    face_size: u32,
    rect: PixelRect,
    shared: [bool; 4],
) -> (Vec<[f32; 3]>, Vec<u32>) {
    let n = face_size as f32;
    let verts = &mesh.vertices;
    let PixelRect { x0, y0, x1, y1, .. } = rect;
    let shared = |c: f32, lo: u32, hi: u32, first: usize| {
        (shared[first] && c == lo as f32 + 0.5) || (shared[first + 2] && c == hi as f32 + 0.5)
    };
    // Every edge: how many triangles use it and the opposite vertex of the last one.
    let mut edges: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    for t in mesh.indices.chunks_exact(3) {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_insert((0, c));
            e.0 += 1;
            e.1 = c;
        }
    }
    let mut boundary: Vec<(u32, u32, [f32; 2])> = edges
        .into_iter()
        .filter(|(_, (count, _))| *count == 1)
        .filter_map(|((a, b), (_, c))| {
            let (pa, pb, pc) = (
                pos_in_face(*verts.get(a as usize)?),
                pos_in_face(*verts.get(b as usize)?),
                pos_in_face(*verts.get(c as usize)?),
            );
            if !pa.iter().chain(&pb).all(|&x| on_centre(x)) {
                return None;
            }
            let along_x = pa[1] == pb[1] && shared(pa[1], y0, y1, 1);
            let along_y = pa[0] == pb[0] && shared(pa[0], x0, x1, 0);
            if along_x || along_y {
                return None;
            }
            let d = [pb[0] - pa[0], pb[1] - pa[1]];
            let mut normal = [d[1], -d[0]];
            if normal[0] * (pc[0] - pa[0]) + normal[1] * (pc[1] - pa[1]) > 0.0 {
                normal = [-normal[0], -normal[1]];
            }
            let step = |x: f32| {
                if x.abs() < 1e-6 {
                    0.0
                } else {
                    0.5 * x.signum()
                }
            };
            Some((a, b, [step(normal[0]), step(normal[1])]))
        })
        .collect();
    // A deterministic order (the map's is not).
    boundary.sort_by_key(|&(a, b, _)| (a, b));
    let base = verts.len() as u32;
    let mut extra: Vec<[f32; 3]> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let add = |extra: &mut Vec<[f32; 3]>, v: u32, o: [f32; 2]| -> u32 {
        let p = verts[v as usize];
        extra.push([
            (p[0] + o[0]).clamp(0.0, n),
            (p[1] + o[1]).clamp(0.0, n),
            p[2],
        ]);
        base + extra.len() as u32 - 1
    };
    let mut offsets: HashMap<u32, Vec<[f32; 2]>> = HashMap::new();
    for &(a, b, o) in &boundary {
        let (a2, b2) = (add(&mut extra, a, o), add(&mut extra, b, o));
        indices.extend([a, b, b2, a, b2, a2]);
        offsets.entry(a).or_default().push(o);
        offsets.entry(b).or_default().push(o);
    }
    let mut corners: Vec<(u32, Vec<[f32; 2]>)> = offsets.into_iter().collect();
    corners.sort_by_key(|c| c.0);
    for (v, os) in corners {
        for i in 0..os.len() {
            for j in i + 1..os.len() {
                let (o1, o2) = (os[i], os[j]);
                if o1 == o2 {
                    continue;
                }
                let sum = |x: f32| {
                    if x.abs() < 1e-6 {
                        0.0
                    } else {
                        0.5 * x.signum()
                    }
                };
                let oc = [sum(o1[0] + o2[0]), sum(o1[1] + o2[1])];
                let (p1, pc, p2) = (
                    add(&mut extra, v, o1),
                    add(&mut extra, v, oc),
                    add(&mut extra, v, o2),
                );
                indices.extend([v, p1, pc, v, pc, p2]);
            }
        }
    }
    (extra, indices)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels `[x0, x1) × [y0, y1)` of a face.
    fn rect(x0: u32, y0: u32, x1: u32, y1: u32) -> PixelRect {
        PixelRect {
            face: tracks::Face::PosZ,
            x0,
            y0,
            x1,
            y1,
        }
    }

    fn v(x: f32, y: f32) -> [f32; 3] {
        [x, y, 2.0]
    }

    /// Area covered by the union of triangles, by sampling a fine grid over the face.
    fn covered(verts: &[[f32; 3]], idx: &[u32], x: f32, y: f32) -> bool {
        idx.chunks_exact(3).any(|t| {
            let p = [t[0], t[1], t[2]].map(|i| pos_in_face(verts[i as usize]));
            let cross = |a: [f32; 2], b: [f32; 2], c: [f32; 2]| {
                (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            };
            let q = [x, y];
            let (d0, d1, d2) = (
                cross(p[0], p[1], q),
                cross(p[1], p[2], q),
                cross(p[2], p[0], q),
            );
            (d0 >= 0.0 && d1 >= 0.0 && d2 >= 0.0) || (d0 <= 0.0 && d1 <= 0.0 && d2 <= 0.0)
        })
    }

    #[test]
    fn a_centre_lattice_square_reaches_its_pixel_corners() {
        // Pixels (1..=3, 1..=3): centres 1.5..3.5, two triangles.
        let mesh = TileMesh {
            vertices: vec![v(1.5, 1.5), v(3.5, 1.5), v(3.5, 3.5), v(1.5, 3.5)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (extra, idx) = skirt(&mesh, 8, rect(0, 0, 8, 8), [false; 4]);
        let all: Vec<[f32; 3]> = mesh.vertices.iter().chain(&extra).copied().collect();
        let tris: Vec<u32> = mesh.indices.iter().chain(&idx).copied().collect();
        // Every point of pixels 1..=3 (corners 1.0..4.0) is covered, nothing beyond.
        for k in 0..=60 {
            for l in 0..=60 {
                let (x, y) = (0.5 + k as f32 * 0.06, 0.5 + l as f32 * 0.06);
                let inside = (1.0..=4.0).contains(&x) && (1.0..=4.0).contains(&y);
                let strictly_outside = !(0.98..=4.02).contains(&x) || !(0.98..=4.02).contains(&y);
                let c = covered(&all, &tris, x, y);
                if inside {
                    assert!(c, "({x}, {y}) not covered");
                }
                if strictly_outside {
                    assert!(!c, "({x}, {y}) covered");
                }
            }
        }
        assert!(extra.iter().all(|v| v[2] == 2.0));
    }

    #[test]
    fn skirts_stop_at_the_face_edge() {
        let mesh = TileMesh {
            vertices: vec![v(0.5, 0.5), v(7.5, 0.5), v(7.5, 7.5), v(0.5, 7.5)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (extra, _) = skirt(&mesh, 8, rect(0, 0, 8, 8), [false; 4]);
        let xs = extra.iter().flat_map(|v| pos_in_face(*v));
        let (lo, hi) = xs.fold((f32::MAX, f32::MIN), |(a, b), x| (a.min(x), b.max(x)));
        assert_eq!((lo, hi), (0.0, 8.0));
    }

    #[test]
    fn borders_shared_with_the_next_tiles_get_no_skirt() {
        // Tile (4..8, 4..8) of a 12-pixel face: its mesh spans centres 4.5..8.5 (up to the
        // next tiles' first pixels); all four neighbours are kept.
        let mesh = TileMesh {
            vertices: vec![v(4.5, 4.5), v(8.5, 4.5), v(8.5, 8.5), v(4.5, 8.5)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (extra, idx) = skirt(&mesh, 12, rect(4, 4, 8, 8), [true; 4]);
        assert!(extra.is_empty() && idx.is_empty());
        // The last tile of the face (8..12): its right border is the face edge.
        let mesh = TileMesh {
            vertices: vec![v(8.5, 4.5), v(11.5, 4.5), v(11.5, 8.5), v(8.5, 8.5)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (extra, idx) = skirt(&mesh, 12, rect(8, 4, 12, 8), [true; 4]);
        assert_eq!(idx.len(), 6);
        assert!(extra.iter().all(|v| v[0] == 12.0));
        // Without kept neighbours every border gets a skirt.
        let mesh = TileMesh {
            vertices: vec![v(4.5, 4.5), v(8.5, 4.5), v(8.5, 8.5), v(4.5, 8.5)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (_, idx) = skirt(&mesh, 12, rect(4, 4, 8, 8), [false; 4]);
        assert_eq!(idx.len(), 4 * 6 + 4 * 6);
    }

    #[test]
    fn corner_lattice_meshes_get_no_skirt() {
        let mesh = TileMesh {
            vertices: vec![v(0.0, 0.0), v(4.0, 0.0), v(4.0, 4.0), v(0.0, 4.0)],
            indices: vec![0, 1, 2, 0, 2, 3],
        };
        let (extra, idx) = skirt(&mesh, 8, rect(0, 0, 8, 8), [false; 4]);
        assert!(extra.is_empty() && idx.is_empty());
    }
}
