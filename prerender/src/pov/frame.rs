//! railview ↔ POV-Ray coordinate frames and the generated `mesh_camera` meshes.
//!
//! railview is right-handed with y up; POV-Ray is left-handed, and its scenes put "up" on
//! y or on z. The mappings (both orientation-reversing, so a scene is never mirrored):
//!
//! | scene up | POV-Ray `<X, Y, Z>` from railview `(x, y, z)` | railview from POV-Ray |
//! |---|---|---|
//! | [`UpAxis::Y`] | `<x, y, −z>` | `(X, Y, −Z)` |
//! | [`UpAxis::Z`] | `<−x, −z, y>` | `(−X, Z, −Y)` |
//!
//! The z-up row equals the y-up one followed by the matrix `<−1,0,0, 0,0,1, 0,1,0>`
//! (a proper rotation taking y to z) of the POV-Ray notes. Track files for imported scenes are
//! written in railview coordinates, so a POV-Ray camera `location <X, Y, Z>` in a y-up scene is
//! the track point `[X, Y, -Z]`.
//!
//! The mesh camera: one triangle per cube-map pixel, face-major as [`tracks::CubeMap`] stores
//! them, with dummy rows interleaved at block starts ([`MeshLayout`]). Each triangle has its
//! centroid at the origin and its normal along the pixel's direction
//! ([`tracks::cubemap::pixel_dir`] mapped into the scene's frame), so the rendered image *is*
//! the cube map, row for row, once the dummy rows are dropped.

use std::fmt::Write as _;

use glam::DVec3;
use tracks::cubemap::{pixel_dir, Face};

/// Which axis is "up" in a POV-Ray scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// y up (most POV-Ray scenes, e.g. the patio).
    Y,
    /// z up (e.g. `advanced/landscape.pov`, `balcony.pov`).
    Z,
}

impl UpAxis {
    /// POV-Ray coordinates of a railview point or direction.
    pub fn pov_from_railview(self, v: DVec3) -> DVec3 {
        match self {
            UpAxis::Y => DVec3::new(v.x, v.y, -v.z),
            UpAxis::Z => DVec3::new(-v.x, -v.z, v.y),
        }
    }

    /// railview coordinates of a POV-Ray point or direction.
    pub fn railview_from_pov(self, p: DVec3) -> DVec3 {
        match self {
            UpAxis::Y => DVec3::new(p.x, p.y, -p.z),
            UpAxis::Z => DVec3::new(-p.x, p.z, -p.y),
        }
    }

    /// `y` or `z`, as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        }
    }

    /// The SDL vectors of a spherical camera whose image centre looks along railview −z with
    /// railview +y up (used for equirectangular previews).
    pub fn spherical_camera_vectors(self) -> &'static str {
        match self {
            UpAxis::Y => "direction z up y right x",
            UpAxis::Z => "direction y up z right -x",
        }
    }
}

impl std::str::FromStr for UpAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "y" | "Y" => Ok(UpAxis::Y),
            "z" | "Z" => Ok(UpAxis::Z),
            other => Err(format!("up axis must be `y` or `z`, found `{other}`")),
        }
    }
}

/// Name of the declared mesh in a generated mesh-camera include.
pub const MESH_NAME: &str = "RvMeshCam";
/// Name of the declared near distance the dummy row refers to.
pub const NEAR_NAME: &str = "RvNear";

/// Render block size (`+BS`) of every mesh-camera render; the layout depends on it.
pub const BLOCK: u32 = 16;

/// Where the cube-map rows sit in a mesh-camera image.
///
/// Two POV-Ray 3.7.0 bugs shape it. (1) The mesh camera maps image row `j ≥ 1` to mesh face
/// row `j − 1` (image rows 0 and 1 both show face row 0). (2) A render thread decides which
/// objects its rays start inside (which switches fog, atmosphere and media on or off) from its
/// first ray only, and which block a thread takes first is a race. So every block's first
/// image row (rows `0, B, 2B, …` for blocks of `B` pixels) shows a *dummy* face row whose rays
/// start exactly at the camera centre; whichever block a thread starts with, its first ray is
/// then a camera-centre ray. Dummy triangles are centred at `<0, −RvNear, 0>` with normal +y,
/// so their rays start at the camera for any near distance.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshLayout {
    pub face_size: u32,
    /// Per mesh face row: `None` for a dummy row, else the cube-map row (face-major) it holds.
    pub rows: Vec<Option<u32>>,
}

impl MeshLayout {
    pub fn new(face_size: u32) -> MeshLayout {
        let total = 6 * face_size;
        let mut rows = Vec::with_capacity(total as usize + total as usize / BLOCK as usize + 2);
        let mut next = 0;
        while next < total {
            let f = rows.len() as u32;
            if f == 0 || (f + 1).is_multiple_of(BLOCK) {
                rows.push(None);
            } else {
                rows.push(Some(next));
                next += 1;
            }
        }
        MeshLayout { face_size, rows }
    }

    /// Image size `(width, height)` POV-Ray must render.
    pub fn image_size(&self) -> (u32, u32) {
        (self.face_size, self.rows.len() as u32 + 1)
    }

    /// The cube-map row shown by image row `j`, `None` for a dummy row.
    pub fn cube_row(&self, j: u32) -> Option<u32> {
        let f = j.checked_sub(1)?;
        self.rows.get(f as usize).copied().flatten()
    }
}

/// Where each of several positions' cube-map rows sit in one render of them all
/// (`mesh_camera` distribution 1, which takes the faces of its meshes in order, one a pixel).
///
/// A render spends about a second starting POV-Ray and parsing the scene however few pixels
/// it traces, so depth alone from many positions is cheapest in one run. The same two bugs as
/// [`MeshLayout`] shape the image: a *lead* of `BLOCK − 1` dummy rows at the first position
/// fills the first block (image rows 0 and 1 both show face row 0); then every position owns
/// [`BlockLayout::rows_per_position`] rows, a multiple of `BLOCK` that starts on a block, whose
/// local rows `0, B, 2B, …` and whose rows past its `6·N` cube rows are dummies at that
/// position. No block holds rays of two positions, and each block's first ray starts at the
/// centre of the position it renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockLayout {
    pub face_size: u32,
    pub positions: u32,
}

impl BlockLayout {
    pub fn new(face_size: u32, positions: u32) -> BlockLayout {
        BlockLayout {
            face_size,
            positions,
        }
    }

    /// Mesh rows each position owns: enough blocks of `BLOCK − 1` cube rows for `6·N`.
    pub fn rows_per_position(face_size: u32) -> u32 {
        BLOCK * (6 * face_size).div_ceil(BLOCK - 1)
    }

    /// The cube row of a position's local mesh row `r`, `None` for a dummy.
    pub fn local_row(face_size: u32, r: u32) -> Option<u32> {
        if r.is_multiple_of(BLOCK) {
            return None;
        }
        let c = r - r / BLOCK - 1;
        (c < 6 * face_size).then_some(c)
    }

    /// Image size `(width, height)` POV-Ray must render.
    pub fn image_size(&self) -> (u32, u32) {
        (
            self.face_size,
            BLOCK + self.positions * Self::rows_per_position(self.face_size),
        )
    }

    /// The position and cube row shown by image row `j`, `None` for a dummy row.
    pub fn cube_row(&self, j: u32) -> Option<(u32, u32)> {
        let i = j.checked_sub(BLOCK)?;
        let per = Self::rows_per_position(self.face_size);
        let k = i / per;
        (k < self.positions)
            .then(|| Self::local_row(self.face_size, i % per).map(|c| (k, c)))
            .flatten()
    }
}

/// Corners of a unit triangle centred on the origin whose mesh-camera ray goes along `dir`.
///
/// The corners sit at 90°, 330° and 210° in the basis `(u, v) = (ref × dir, dir × u)`, so
/// `(c − a) × (b − a)` (component formula) points along `+dir`; with this winding the
/// mesh camera shoots along `+dir` (verified against the analytic scene in
/// `prerender/tests/pov.rs`). The winding is a relation between components, independent of
/// the frame's handedness.
pub fn triangle_for_dir(dir: DVec3) -> [DVec3; 3] {
    let reference = if dir.y.abs() < 0.9 {
        DVec3::Y
    } else {
        DVec3::X
    };
    let u = reference.cross(dir).normalize();
    let v = dir.cross(u);
    [90.0f64, 330.0, 210.0].map(|deg| {
        let a = deg.to_radians();
        a.cos() * u + a.sin() * v
    })
}

/// SDL text of the mesh camera for `layout`, directions in `up`'s frame: one triangle per
/// cube-map pixel in [`tracks::CubeMap`] order, with the dummy rows of [`MeshLayout`].
pub fn write_mesh_camera(layout: &MeshLayout, up: UpAxis) -> String {
    let mut s = String::new();
    write_mesh(&mut s, MESH_NAME, layout.face_size, &layout.rows, up);
    s
}

/// Name of the declared mesh of one position in a [`BlockLayout`] render.
pub const BLOCK_MESH_NAME: &str = "RvMeshBlock";
/// Name of the declared lead of dummy rows of a [`BlockLayout`] render.
pub const LEAD_MESH_NAME: &str = "RvMeshLead";

/// SDL text of the meshes of a [`BlockLayout`] render at `face_size`: the lead and one
/// position's rows, each translated to its position by the camera.
pub fn write_block_meshes(face_size: u32, up: UpAxis) -> String {
    let per = BlockLayout::rows_per_position(face_size);
    let rows: Vec<Option<u32>> = (0..per)
        .map(|r| BlockLayout::local_row(face_size, r))
        .collect();
    let mut s = String::new();
    write_mesh(&mut s, BLOCK_MESH_NAME, face_size, &rows, up);
    write_mesh(
        &mut s,
        LEAD_MESH_NAME,
        face_size,
        &vec![None; BLOCK as usize - 1],
        up,
    );
    s
}

/// Append a declared `mesh2` of `rows` (`None`: a dummy row at the camera centre) to `s`.
fn write_mesh(s: &mut String, name: &str, n: u32, rows: &[Option<u32>], up: UpAxis) {
    let faces = rows.len() * n as usize;
    s.reserve(faces * 3 * 40 + 256);
    // Writing into a String cannot fail.
    let _ = writeln!(
        s,
        "// railview mesh camera: cube map {n}x{n}x6, up {}, block {BLOCK}, one triangle per pixel\n\
         #declare {name} = mesh2 {{\n  vertex_vectors {{ {},",
        up.name(),
        3 * faces
    );
    let mut first = true;
    for row in rows {
        for x in 0..n {
            let sep = if first { "" } else { "," };
            first = false;
            match row {
                None => {
                    let _ = writeln!(
                        s,
                        "{sep}<0,0-{NEAR_NAME},1>,<-0.8660254,0-{NEAR_NAME},-0.5>,<0.8660254,0-{NEAR_NAME},-0.5>"
                    );
                }
                Some(r) => {
                    let face = Face::from_index((r / n) as usize).unwrap_or(Face::PosX);
                    let dir = up.pov_from_railview(pixel_dir(face, x, r % n, n));
                    let t = triangle_for_dir(dir);
                    let _ = writeln!(
                        s,
                        "{sep}<{:.9},{:.9},{:.9}>,<{:.9},{:.9},{:.9}>,<{:.9},{:.9},{:.9}>",
                        t[0].x, t[0].y, t[0].z, t[1].x, t[1].y, t[1].z, t[2].x, t[2].y, t[2].z
                    );
                }
            }
        }
    }
    let _ = writeln!(s, "  }}\n  face_indices {{ {faces},");
    for k in 0..faces {
        let sep = if k == 0 { "" } else { "," };
        let _ = write!(s, "{sep}<{},{},{}>", 3 * k, 3 * k + 1, 3 * k + 2);
        if k % 8 == 7 {
            s.push('\n');
        }
    }
    s.push_str("\n  }\n}\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mappings_are_inverse_and_orientation_reversing() {
        let a = DVec3::new(0.3, -1.7, 2.9);
        let b = DVec3::new(-4.0, 0.5, 1.25);
        for up in [UpAxis::Y, UpAxis::Z] {
            assert_eq!(up.railview_from_pov(up.pov_from_railview(a)), a);
            // Handedness: the mapped cross product is the negated cross of the mapped vectors.
            let lhs = up.pov_from_railview(a.cross(b));
            let rhs = up.pov_from_railview(a).cross(up.pov_from_railview(b));
            assert!((lhs + rhs).length() < 1e-12, "{up:?}");
        }
        // Up maps to up.
        assert_eq!(UpAxis::Y.pov_from_railview(DVec3::Y), DVec3::Y);
        assert_eq!(UpAxis::Z.pov_from_railview(DVec3::Y), DVec3::Z);
    }

    #[test]
    fn triangle_normal_is_the_direction() {
        for dir in [
            DVec3::X,
            DVec3::NEG_Y,
            DVec3::Y,
            DVec3::new(0.3, 0.95, -0.1).normalize(),
            DVec3::new(-0.6, 0.2, 0.77).normalize(),
        ] {
            let [a, b, c] = triangle_for_dir(dir);
            let n = (c - a).cross(b - a).normalize();
            assert!((n - dir).length() < 1e-12, "{dir} -> {n}");
            assert!(((a + b + c) / 3.0).length() < 1e-12);
            for p in [a, b, c] {
                assert!((p.length() - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn mesh_text_counts_match() {
        let layout = MeshLayout::new(2);
        let text = write_mesh_camera(&layout, UpAxis::Z);
        let faces = layout.rows.len() * 2;
        assert!(text.contains(&format!("vertex_vectors {{ {},", 3 * faces)));
        assert!(text.contains(&format!("face_indices {{ {faces},")));
        assert_eq!(text.matches('<').count(), 3 * faces + faces);
        assert!(
            !text.contains(",\n  }"),
            "trailing comma is a POV-Ray parse error"
        );
    }

    #[test]
    fn a_block_render_gives_every_position_its_own_blocks_and_all_its_rows_once() {
        for n in [1, 2, 15, 16, 17, 64] {
            for positions in [1, 2, 5] {
                let layout = BlockLayout::new(n, positions);
                let (w, h) = layout.image_size();
                assert_eq!(w, n);
                let mut seen = vec![Vec::new(); positions as usize];
                let mut block_of = vec![None; h.div_ceil(BLOCK) as usize];
                for j in 0..h {
                    // Image row j ≥ 1 shows mesh row j − 1; row 0 shows mesh row 0 too.
                    if j % BLOCK == 0 {
                        assert_eq!(layout.cube_row(j), None, "n {n} image row {j}");
                    }
                    if let Some((k, r)) = layout.cube_row(j) {
                        seen[k as usize].push(r);
                        let b = &mut block_of[(j / BLOCK) as usize];
                        assert!(b.is_none() || *b == Some(k), "a block holds two positions");
                        *b = Some(k);
                    }
                }
                for rows in seen {
                    assert_eq!(rows, (0..6 * n).collect::<Vec<_>>(), "n {n}");
                }
                assert!(layout.cube_row(BLOCK - 1).is_none() && layout.cube_row(0).is_none());
            }
        }
        let text = write_block_meshes(2, UpAxis::Y);
        let per = BlockLayout::rows_per_position(2) as usize;
        let faces = 2 * per + 2 * (BLOCK as usize - 1);
        assert_eq!(text.matches('<').count(), 4 * faces);
        assert!(text.contains(BLOCK_MESH_NAME) && text.contains(LEAD_MESH_NAME));
    }

    #[test]
    fn every_block_starts_with_a_dummy_row_and_all_cube_rows_appear_once() {
        for n in [1, 2, 15, 16, 17, 64] {
            let layout = MeshLayout::new(n);
            let (w, h) = layout.image_size();
            assert_eq!(w, n);
            let mut seen = Vec::new();
            for j in 0..h {
                if j % BLOCK == 0 {
                    assert_eq!(layout.cube_row(j), None, "n {n} image row {j}");
                }
                seen.extend(layout.cube_row(j));
            }
            assert_eq!(seen, (0..6 * n).collect::<Vec<_>>(), "n {n}");
            // Image rows 0 and 1 both show face row 0 (the POV-Ray 3.7.0 row offset).
            assert_eq!(layout.cube_row(1), None);
        }
    }
}
