//! Stretched triangles: confidence in the blend.
//!
//! A tile mesh joins neighbouring vertices whatever their depths, so across a depth edge a
//! triangle spans from the near surface to the far one: its reference sees it edge-on, and
//! its texels (one row of the edge's colours) are stretched over the surface that a view
//! between samples sees in that gap. Where the other reference sees that surface properly,
//! the stretched sample must lose to it; where no reference sees it, the stretched sample
//! still fills the gap, from its far side's colours more than not.
//!
//! The rule (the same in `render.wgsl`'s `vs_mesh` and in [`crate::cpu`]): a triangle is
//! *stretched* when its reference sees it within [`STRETCH_COS`] of edge-on (the cosine
//! between its normal and the reference ray to its centroid). A stretched triangle counts
//! as [`STRETCH_PUSH`] times farther than it is, in its view's depth test and in the blend's
//! depth preference: against another view's surface at about its depth it gets a weight of
//! exp(−SHARPNESS (STRETCH_PUSH − 1)), nothing; against a hole it still draws. Its vertices
//! are copied with the flag [`STRETCHED_BIT`] set in the vertex's packed word, so the
//! vertex shader scales its depth; the coarser, decimated mesh levels keep the shared
//! vertices (a budget fallback, drawn without the rule).
//!
//! Surfaces that are really seen at a grazing angle (distant ground, a wall along the track)
//! are flagged too: both references see them about equally grazing, so neither gains, and
//! where one sees them more squarely its samples (less stretched) win, as they should.

use tracks::{Face, TileMesh};

use super::pos_from_ref;

/// A triangle whose normal makes a cosine below this with the reference ray is stretched
/// (about 87°: a step of a quarter of the depth over one pixel of a 128-pixel face).
pub const STRETCH_COS: f64 = 0.05;
/// How many times farther a stretched triangle counts.
pub const STRETCH_PUSH: f32 = 2.0;
/// Bit of a vertex's packed word (`tile << 3 | face`) marking a stretched triangle's copy.
pub const STRETCHED_BIT: u32 = 1 << 31;

/// Whether the triangle `tri` (vertices in face pixels and depth) of `face` is stretched.
pub fn is_stretched(tri: [[f32; 3]; 3], face: Face, face_size: u32) -> bool {
    let p = tri.map(|v| pos_from_ref(v, face, face_size));
    let n = (p[1] - p[0]).cross(p[2] - p[0]);
    let c = (p[0] + p[1] + p[2]) / 3.0;
    let (nl, cl) = (n.length(), c.length());
    if nl <= 0.0 || cl <= 0.0 || !nl.is_finite() || !cl.is_finite() {
        return false;
    }
    n.dot(c).abs() / (nl * cl) < STRETCH_COS
}

/// The mesh's triangles with the stretched ones on vertices of their own: the vertices
/// appended after `mesh.vertices` (three per stretched triangle) and every triangle's
/// indices (those of stretched triangles into the appended vertices, numbered from
/// `mesh.vertices.len()`).
pub fn split_stretched(mesh: &TileMesh, face: Face, face_size: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let n = mesh.vertices.len() as u32;
    let mut extra = Vec::new();
    let mut indices = Vec::with_capacity(mesh.indices.len());
    for tri in mesh.indices.chunks_exact(3) {
        let v = [tri[0], tri[1], tri[2]].map(|i| mesh.vertices.get(i as usize).copied());
        match v {
            [Some(a), Some(b), Some(c)] if is_stretched([a, b, c], face, face_size) => {
                let first = n + extra.len() as u32;
                extra.extend([a, b, c]);
                indices.extend([first, first + 1, first + 2]);
            }
            _ => indices.extend_from_slice(tri),
        }
    }
    (extra, indices)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_triangle_across_a_depth_edge_is_stretched_and_a_facing_one_is_not() {
        // Two pixels apart on the face, depths 5 m and 10 m: nearly along the ray.
        let across = [[60.0, 60.0, 5.0], [61.0, 60.0, 10.0], [60.0, 61.0, 5.0]];
        assert!(is_stretched(across, Face::PosZ, 128));
        let facing = [[60.0, 60.0, 5.0], [61.0, 60.0, 5.0], [60.0, 61.0, 5.0]];
        assert!(!is_stretched(facing, Face::PosZ, 128));
        // Degenerate: never stretched.
        let line = [[60.0, 60.0, 5.0], [60.0, 60.0, 5.0], [60.0, 61.0, 5.0]];
        assert!(!is_stretched(line, Face::PosZ, 128));
    }

    #[test]
    fn stretched_triangles_get_their_own_vertices() {
        let mesh = TileMesh {
            vertices: vec![
                [60.0, 60.0, 5.0],
                [61.0, 60.0, 5.0],
                [60.0, 61.0, 5.0],
                [61.0, 61.0, 20.0],
            ],
            indices: vec![0, 1, 2, 1, 3, 2],
        };
        let (extra, idx) = split_stretched(&mesh, Face::PosZ, 128);
        assert_eq!(&idx[..3], &[0, 1, 2]);
        assert_eq!(&idx[3..], &[4, 5, 6]);
        assert_eq!(
            extra,
            vec![mesh.vertices[1], mesh.vertices[3], mesh.vertices[2]]
        );
    }
}
