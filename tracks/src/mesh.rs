//! [`TileMesh`]: a tile's depth mesh, the one mesh type of the workspace — what the slab
//! stage builds (`slabs::mesh`), what the mesh codec writes and reads (`codec::mesh`), and
//! what the viewer draws.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::cubemap::{subpixel_dir, Face};

/// A tile's depth mesh: vertices `[x, y, r]` — continuous face-pixel position (level-0
/// pixel units, pixel corners at integers) and radial depth from the reference viewpoint in
/// metres — and triangles as vertex index triples (counter-clockwise in image coordinates is
/// not guaranteed).
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

/// A vertex's position on its face, pixels.
pub fn pos_in_face(v: [f32; 3]) -> [f32; 2] {
    [v[0], v[1]]
}

/// A vertex's position relative to its reference viewpoint, metres.
pub fn pos_from_ref(v: [f32; 3], face: Face, face_size: u32) -> DVec3 {
    subpixel_dir(face, v[0] as f64, v[1] as f64, face_size) * v[2] as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vertex_at_the_face_centre_lies_along_the_face_axis() {
        let p = pos_from_ref([8.0, 8.0, 3.0], Face::PosX, 16);
        assert!((p - DVec3::new(3.0, 0.0, 0.0)).length() < 1e-9, "{p}");
        assert_eq!(pos_in_face([1.5, 2.5, 9.0]), [1.5, 2.5]);
    }
}
