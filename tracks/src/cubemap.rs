//! Cube-map addressing shared by all crates.
//!
//! A face looks along `forward`, with `right` and `up` spanning its image plane at distance 1
//! (90° field of view). Right-handed: `right = forward × up`. Pixel `(x, y)` has `x` growing
//! along `right` and `y` growing *down* (against `up`), origin at the top-left corner; pixel
//! centres are at half-integers. Face-plane coordinates `(u, v)` in `[-1, 1]` map to the image
//! as `x = (u + 1) / 2 · N`, `y = (1 − v) / 2 · N`.
//!
//! | face | forward | up | right |
//! |---|---|---|---|
//! | `PosX` | +x | +y | +z |
//! | `NegX` | −x | +y | −z |
//! | `PosY` | +y | +z | +x |
//! | `NegY` | −y | −z | +x |
//! | `PosZ` | +z | +y | −x |
//! | `NegZ` | −z | +y | +x |
//!
//! A [`CubeMap<T>`] stores the six faces face-major (`Face::index` order), each face row-major
//! from the top row; on disk the same order is one image of `N × 6N` pixels.

use glam::DVec3;

use crate::rect::PixelRect;
use serde::{Deserialize, Serialize};

/// One of the six cube faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Face {
    PosX,
    NegX,
    PosY,
    NegY,
    PosZ,
    NegZ,
}

impl Face {
    /// All faces in storage order.
    pub const ALL: [Face; 6] = [
        Face::PosX,
        Face::NegX,
        Face::PosY,
        Face::NegY,
        Face::PosZ,
        Face::NegZ,
    ];

    /// Storage index 0..6.
    pub fn index(self) -> usize {
        self as usize
    }

    /// The face with storage index `i`, if `i < 6`.
    pub fn from_index(i: usize) -> Option<Face> {
        Face::ALL.get(i).copied()
    }

    /// Short name used in file names and reports (`px`, `nx`, …).
    pub fn short_name(self) -> &'static str {
        ["px", "nx", "py", "ny", "pz", "nz"][self.index()]
    }

    /// Direction the face looks along (unit, world space).
    pub fn forward(self) -> DVec3 {
        match self {
            Face::PosX => DVec3::X,
            Face::NegX => DVec3::NEG_X,
            Face::PosY => DVec3::Y,
            Face::NegY => DVec3::NEG_Y,
            Face::PosZ => DVec3::Z,
            Face::NegZ => DVec3::NEG_Z,
        }
    }

    /// Image-up direction of the face (unit, world space).
    pub fn up(self) -> DVec3 {
        match self {
            Face::PosX | Face::NegX | Face::PosZ | Face::NegZ => DVec3::Y,
            Face::PosY => DVec3::Z,
            Face::NegY => DVec3::NEG_Z,
        }
    }

    /// Image-right direction of the face (unit, world space): `forward × up`.
    pub fn right(self) -> DVec3 {
        self.forward().cross(self.up())
    }

    /// Unnormalised world direction through face-plane point `(u, v)`, `u, v ∈ [-1, 1]`.
    pub fn dir_from_uv(self, u: f64, v: f64) -> DVec3 {
        self.forward() + u * self.right() + v * self.up()
    }

    /// Face-plane coordinates of a world direction as seen by this face; `None` when the
    /// direction does not point into the face's half-space.
    pub fn uv_from_dir(self, dir: DVec3) -> Option<(f64, f64)> {
        let z = dir.dot(self.forward());
        if z <= 0.0 || !z.is_finite() {
            return None;
        }
        Some((dir.dot(self.right()) / z, dir.dot(self.up()) / z))
    }
}

/// A continuous position on a face: `(u, v)` in face-plane coordinates, `[-1, 1]` on the face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceCoord {
    pub face: Face,
    pub u: f64,
    pub v: f64,
}

impl FaceCoord {
    /// The face a direction falls on (major axis; ties broken x before y before z, positive
    /// before negative, so every direction has exactly one face) and its `(u, v)` there.
    /// `None` for zero or non-finite directions.
    pub fn from_dir(dir: DVec3) -> Option<FaceCoord> {
        if !dir.is_finite() || dir == DVec3::ZERO {
            return None;
        }
        let a = dir.abs();
        let face = if a.x >= a.y && a.x >= a.z {
            if dir.x > 0.0 {
                Face::PosX
            } else {
                Face::NegX
            }
        } else if a.y >= a.z {
            if dir.y > 0.0 {
                Face::PosY
            } else {
                Face::NegY
            }
        } else if dir.z > 0.0 {
            Face::PosZ
        } else {
            Face::NegZ
        };
        let (u, v) = face.uv_from_dir(dir)?;
        Some(FaceCoord {
            face,
            u: u.clamp(-1.0, 1.0),
            v: v.clamp(-1.0, 1.0),
        })
    }

    /// Continuous pixel position `(x, y)` on a face of `face_size` pixels (pixel centres at
    /// half-integers).
    pub fn to_pixel_f(self, face_size: u32) -> (f64, f64) {
        let n = face_size as f64;
        ((self.u + 1.0) * 0.5 * n, (1.0 - self.v) * 0.5 * n)
    }

    /// The pixel `(x, y)` containing this position, clamped onto the face.
    pub fn to_pixel(self, face_size: u32) -> (u32, u32) {
        let (x, y) = self.to_pixel_f(face_size);
        let max = face_size.saturating_sub(1) as f64;
        (
            x.floor().clamp(0.0, max) as u32,
            y.floor().clamp(0.0, max) as u32,
        )
    }

    /// Unit world direction.
    pub fn dir(self) -> DVec3 {
        self.face.dir_from_uv(self.u, self.v).normalize()
    }
}

/// Face-plane coordinates of the point `(x, y)` in pixel units on a face of `face_size`.
pub fn uv_from_pixel_f(x: f64, y: f64, face_size: u32) -> (f64, f64) {
    let n = face_size as f64;
    (2.0 * x / n - 1.0, 1.0 - 2.0 * y / n)
}

/// Unit world direction through the centre of pixel `(x, y)` of `face`.
pub fn pixel_dir(face: Face, x: u32, y: u32, face_size: u32) -> DVec3 {
    let (u, v) = uv_from_pixel_f(x as f64 + 0.5, y as f64 + 0.5, face_size);
    face.dir_from_uv(u, v).normalize()
}

/// Unit world direction through sub-pixel position `(x, y)` (pixel units) of `face`.
pub fn subpixel_dir(face: Face, x: f64, y: f64, face_size: u32) -> DVec3 {
    let (u, v) = uv_from_pixel_f(x, y, face_size);
    face.dir_from_uv(u, v).normalize()
}

/// Solid angle of one pixel at `(x, y)`, steradians (sums to 4π over the cube).
pub fn pixel_solid_angle(x: u32, y: u32, face_size: u32) -> f64 {
    // Exact: area integral of the (u, v) patch via the arctan formula.
    fn f(u: f64, v: f64) -> f64 {
        (u * v / (u * u + v * v + 1.0).sqrt()).atan()
    }
    let (u0, v1) = uv_from_pixel_f(x as f64, y as f64, face_size);
    let (u1, v0) = uv_from_pixel_f(x as f64 + 1.0, y as f64 + 1.0, face_size);
    f(u1, v1) - f(u0, v1) - f(u1, v0) + f(u0, v0)
}

/// Six square faces of `face_size²` values, face-major, rows from the top.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CubeMap<T> {
    face_size: u32,
    data: Vec<T>,
}

impl<T: Clone> CubeMap<T> {
    /// A cube map with every texel set to `value`.
    pub fn filled(face_size: u32, value: T) -> Self {
        let n = face_size as usize;
        CubeMap {
            face_size,
            data: vec![value; 6 * n * n],
        }
    }
}

impl<T> CubeMap<T> {
    /// Wrap `data` (length `6·N²`, face-major); `None` if the length does not match.
    pub fn from_vec(face_size: u32, data: Vec<T>) -> Option<Self> {
        let n = face_size as usize;
        (data.len() == 6 * n * n).then_some(CubeMap { face_size, data })
    }

    /// Build by calling `f(face, x, y)` for every texel.
    pub fn from_fn(face_size: u32, mut f: impl FnMut(Face, u32, u32) -> T) -> Self {
        let mut data = Vec::with_capacity(6 * face_size as usize * face_size as usize);
        for face in Face::ALL {
            for y in 0..face_size {
                for x in 0..face_size {
                    data.push(f(face, x, y));
                }
            }
        }
        CubeMap { face_size, data }
    }

    pub fn face_size(&self) -> u32 {
        self.face_size
    }

    /// Index of texel `(face, x, y)` in [`CubeMap::as_slice`].
    pub fn index(&self, face: Face, x: u32, y: u32) -> usize {
        let n = self.face_size as usize;
        (face.index() * n + y as usize) * n + x as usize
    }

    pub fn get(&self, face: Face, x: u32, y: u32) -> &T {
        &self.data[self.index(face, x, y)]
    }

    pub fn get_mut(&mut self, face: Face, x: u32, y: u32) -> &mut T {
        let i = self.index(face, x, y);
        &mut self.data[i]
    }

    /// The texels of one face, row-major from the top.
    pub fn face(&self, face: Face) -> &[T] {
        let n2 = self.face_size as usize * self.face_size as usize;
        &self.data[face.index() * n2..(face.index() + 1) * n2]
    }

    pub fn face_mut(&mut self, face: Face) -> &mut [T] {
        let n2 = self.face_size as usize * self.face_size as usize;
        &mut self.data[face.index() * n2..(face.index() + 1) * n2]
    }

    /// All texels, face-major: also the row order of the `N × 6N` image on disk.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Map every texel.
    pub fn map<U>(&self, f: impl FnMut(&T) -> U) -> CubeMap<U> {
        CubeMap {
            face_size: self.face_size,
            data: self.data.iter().map(f).collect(),
        }
    }
}

/// A tile: a square block of one face, `tile_size` pixels on a side (edge tiles may be
/// smaller when the face size is not a multiple of the tile size).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TileId {
    pub face: Face,
    pub tx: u32,
    pub ty: u32,
}

/// The tile grid of a cube map: `tile_size` (a power of two) over faces of `face_size`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileGrid {
    pub face_size: u32,
    pub tile_size: u32,
}

impl TileGrid {
    /// `None` unless `tile_size` is a power of two and both sizes are non-zero.
    pub fn new(face_size: u32, tile_size: u32) -> Option<TileGrid> {
        (face_size > 0 && tile_size.is_power_of_two()).then_some(TileGrid {
            face_size,
            tile_size,
        })
    }

    /// Tiles along one side of a face.
    pub fn tiles_per_side(&self) -> u32 {
        self.face_size.div_ceil(self.tile_size)
    }

    /// Tiles over the whole cube.
    pub fn tile_count(&self) -> usize {
        let t = self.tiles_per_side() as usize;
        6 * t * t
    }

    /// Dense index of a tile, face-major then rows then columns.
    pub fn tile_index(&self, t: TileId) -> usize {
        let n = self.tiles_per_side() as usize;
        (t.face.index() * n + t.ty as usize) * n + t.tx as usize
    }

    /// Inverse of [`TileGrid::tile_index`].
    pub fn tile_at(&self, index: usize) -> Option<TileId> {
        let n = self.tiles_per_side() as usize;
        let face = Face::from_index(index / (n * n))?;
        let r = index % (n * n);
        Some(TileId {
            face,
            tx: (r % n) as u32,
            ty: (r / n) as u32,
        })
    }

    /// All tiles in index order.
    pub fn tiles(&self) -> impl Iterator<Item = TileId> + '_ {
        (0..self.tile_count()).filter_map(|i| self.tile_at(i))
    }

    /// The tile containing pixel `(x, y)` of `face`.
    pub fn tile_of_pixel(&self, face: Face, x: u32, y: u32) -> TileId {
        TileId {
            face,
            tx: x / self.tile_size,
            ty: y / self.tile_size,
        }
    }

    /// The pixels a tile covers (ends exclusive).
    pub fn pixel_rect(&self, t: TileId) -> PixelRect {
        let x0 = t.tx * self.tile_size;
        let y0 = t.ty * self.tile_size;
        PixelRect {
            face: t.face,
            x0,
            y0,
            x1: (x0 + self.tile_size).min(self.face_size),
            y1: (y0 + self.tile_size).min(self.face_size),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn faces_are_right_handed_and_orthonormal() {
        for f in Face::ALL {
            let (r, u, fw) = (f.right(), f.up(), f.forward());
            assert!((r.length() - 1.0).abs() < 1e-15);
            assert_eq!(r.dot(u), 0.0);
            assert_eq!(r.dot(fw), 0.0);
            // right × up = -forward in a right-handed frame looking down -z.
            assert_eq!(r.cross(u), -fw);
        }
    }

    #[test]
    fn face_centres_and_corners() {
        for f in Face::ALL {
            let c = FaceCoord::from_dir(f.forward()).unwrap();
            assert_eq!(c.face, f);
            assert_eq!((c.u, c.v), (0.0, 0.0));
            assert_eq!(c.to_pixel(4), (2, 2));
        }
        // Top-left pixel of +z looks towards +y and +x (right of +z is -x, so left is +x).
        let d = pixel_dir(Face::PosZ, 0, 0, 2);
        assert!(d.x > 0.0 && d.y > 0.0 && d.z > 0.0);
    }

    #[test]
    fn edge_directions_have_exactly_one_face() {
        let d = DVec3::new(1.0, 1.0, 0.3);
        let c = FaceCoord::from_dir(d).unwrap();
        assert_eq!(c.face, Face::PosX);
        assert_eq!(c.v, 1.0);
        let corner = FaceCoord::from_dir(DVec3::new(-1.0, -1.0, -1.0)).unwrap();
        assert_eq!(corner.face, Face::NegX);
        assert!(FaceCoord::from_dir(DVec3::ZERO).is_none());
        assert!(FaceCoord::from_dir(DVec3::new(f64::NAN, 0.0, 1.0)).is_none());
    }

    #[test]
    fn solid_angles_sum_to_sphere() {
        let n = 16;
        let mut s = 0.0;
        for y in 0..n {
            for x in 0..n {
                s += pixel_solid_angle(x, y, n);
            }
        }
        assert!((6.0 * s - 4.0 * std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn tile_grid_with_partial_edge_tiles() {
        let g = TileGrid::new(10, 4).unwrap();
        assert_eq!(g.tiles_per_side(), 3);
        assert_eq!(g.tile_count(), 54);
        let t = g.tile_of_pixel(Face::NegY, 9, 5);
        let r = g.pixel_rect(t);
        assert_eq!((r.x0, r.y0, r.x1, r.y1), (8, 4, 10, 8));
        for i in 0..g.tile_count() {
            assert_eq!(g.tile_index(g.tile_at(i).unwrap()), i);
        }
        assert!(TileGrid::new(10, 3).is_none());
        assert!(g.tile_at(54).is_none());
    }

    #[test]
    fn cubemap_layout_is_face_major() {
        let m = CubeMap::from_fn(3, |f, x, y| (f.index(), x, y));
        assert_eq!(*m.get(Face::NegY, 2, 1), (3, 2, 1));
        assert_eq!(m.as_slice()[m.index(Face::PosZ, 0, 2)], (4, 0, 2));
        assert_eq!(m.face(Face::NegZ).len(), 9);
        assert!(CubeMap::from_vec(3, vec![0u8; 53]).is_none());
    }

    proptest! {
        #[test]
        fn pixel_direction_round_trip(face in 0usize..6, x in 0u32..64, y in 0u32..64) {
            let face = Face::from_index(face).unwrap();
            let d = pixel_dir(face, x, y, 64);
            let c = FaceCoord::from_dir(d).unwrap();
            prop_assert_eq!(c.face, face);
            prop_assert_eq!(c.to_pixel(64), (x, y));
        }

        #[test]
        fn direction_round_trip(x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0) {
            let d = DVec3::new(x, y, z);
            prop_assume!(d.length() > 1e-6);
            let c = FaceCoord::from_dir(d).unwrap();
            prop_assert!((c.dir() - d.normalize()).length() < 1e-12);
        }
    }
}
