//! Extended projections on cube faces: where an occludee tile can appear, on the occluder's
//! depth, from any point of the cell.
//!
//! Everything here works in one face's frame: `(u, v)` on the plane at distance 1 along the
//! face's `forward` (the plane extends past `[-1, 1]`), planar depth `z` along `forward`.
//! A point of the occludee seen at `p` from the reference viewpoint at planar depth `h2`, seen
//! from `X = V + b` (`b = (bx, by, bz)` in the face frame), crosses the plane `z = h1` at
//!
//! ```text
//! t  = (h1 − bz) / (h2 − bz)
//! p' = ((1 − t)·(bx, by) + t·h2·p) / h1
//!    = p + (h2 − h1) / (h1·(h2 − bz)) · ((bx, by) − bz·p)
//! ```
//!
//! This is the paper's equation (1) on the image plane (for `bz = 0` the shift is
//! `b·(1/h1 − 1/h2)`, i.e. `s₁ = d·(h2 − h1)/h2` measured on the plane at `h1`), with
//! equations (2)–(5) replaced by the vector form: the point slides along the epipolar line
//! towards `(bx, by)/bz`, so no `tan β` appears and a track parallel to a face axis is not a
//! special case. For fixed `b` and `h2` the map `p ↦ p'` is a scaling about the epipole, so
//! the image of a tile rectangle is the rectangle of its corners' images; `p'` moves
//! monotonically along one line as `h2` grows or as `X` moves along a straight segment, so the
//! extremes are at the corners, the farthest occludee depth and the segment ends.

use glam::DVec3;
use tracks::{Face, TileGrid, TileId};

/// An axis-aligned rectangle in a face's (extended) plane coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvRect {
    pub u0: f64,
    pub u1: f64,
    pub v0: f64,
    pub v1: f64,
}

impl UvRect {
    /// The footprint of a tile on its face.
    pub fn of_tile(grid: &TileGrid, tile: TileId) -> UvRect {
        let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
        let n = grid.face_size as f64;
        UvRect {
            u0: 2.0 * x0 as f64 / n - 1.0,
            u1: 2.0 * x1 as f64 / n - 1.0,
            v0: 1.0 - 2.0 * y1 as f64 / n,
            v1: 1.0 - 2.0 * y0 as f64 / n,
        }
    }

    /// Grow to contain `(u, v)`.
    pub fn include(&mut self, u: f64, v: f64) {
        self.u0 = self.u0.min(u);
        self.u1 = self.u1.max(u);
        self.v0 = self.v0.min(v);
        self.v1 = self.v1.max(v);
    }

    /// The smallest rectangle holding both.
    pub fn union(self, o: UvRect) -> UvRect {
        UvRect {
            u0: self.u0.min(o.u0),
            u1: self.u1.max(o.u1),
            v0: self.v0.min(o.v0),
            v1: self.v1.max(o.v1),
        }
    }

    /// Whether `o` lies inside `self` (with a relative slack for rounding).
    pub fn contains(&self, o: &UvRect) -> bool {
        let e = 1e-12
            * (1.0
                + self
                    .u1
                    .abs()
                    .max(self.u0.abs())
                    .max(self.v0.abs())
                    .max(self.v1.abs()));
        o.u0 >= self.u0 - e && o.u1 <= self.u1 + e && o.v0 >= self.v0 - e && o.v1 <= self.v1 + e
    }

    pub fn centre(&self) -> (f64, f64) {
        (0.5 * (self.u0 + self.u1), 0.5 * (self.v0 + self.v1))
    }

    pub fn corners(&self) -> [(f64, f64); 4] {
        [
            (self.u0, self.v0),
            (self.u1, self.v0),
            (self.u1, self.v1),
            (self.u0, self.v1),
        ]
    }

    /// Largest `u² + v²` over the rectangle (a corner).
    pub fn max_norm2(&self) -> f64 {
        self.u0.abs().max(self.u1.abs()).powi(2) + self.v0.abs().max(self.v1.abs()).powi(2)
    }

    /// Smallest `u² + v²` over the rectangle (0 when it holds the face centre).
    pub fn min_norm2(&self) -> f64 {
        let nearest = |a: f64, b: f64| {
            if a <= 0.0 && b >= 0.0 {
                0.0
            } else {
                a.abs().min(b.abs())
            }
        };
        nearest(self.u0, self.u1).powi(2) + nearest(self.v0, self.v1).powi(2)
    }

    pub fn is_finite(&self) -> bool {
        self.u0.is_finite() && self.u1.is_finite() && self.v0.is_finite() && self.v1.is_finite()
    }
}

/// `b` (world offset of a cell point from the reference viewpoint) in `face`'s frame:
/// `(right, up, forward)` components.
pub fn offset_in_face(face: Face, b: DVec3) -> DVec3 {
    DVec3::new(b.dot(face.right()), b.dot(face.up()), b.dot(face.forward()))
}

/// Where the occludee point seen at `p` (planar depth `h2`, may be `+inf`) crosses the plane
/// at planar depth `h1`, seen from the cell point with face-frame offset `b`. `None` when the
/// cell point is not in front of that plane (`b.z ≥ h1`) or the inputs are not usable.
pub fn shifted(p: (f64, f64), b: DVec3, h1: f64, h2: f64) -> Option<(f64, f64)> {
    if !(h1 > 0.0 && h1.is_finite()) || b.z >= h1 || h2.is_nan() {
        return None;
    }
    // An occludee nearer than the plane is treated as lying on it (no shift): callers pass
    // h2 ≥ h1 by construction; this guards rounding.
    let h2 = h2.max(h1);
    let (u, v) = if h2.is_infinite() {
        // t → 0, t·h2 → h1 − bz.
        let w = h1 - b.z;
        ((b.x + w * p.0) / h1, (b.y + w * p.1) / h1)
    } else {
        let k = (h2 - h1) / (h1 * (h2 - b.z));
        (p.0 + k * (b.x - b.z * p.0), p.1 + k * (b.y - b.z * p.1))
    };
    (u.is_finite() && v.is_finite()).then_some((u, v))
}

/// The extended projection of a tile footprint `tile` (planar occludee depth at most `h2`) on
/// the plane at planar depth `h1`, over every cell point offset in `offsets_in_face` (the
/// reference viewpoint itself is always included). `None` when some cell point is not in
/// front of `h1`: then nothing can be concluded.
pub fn extended_window(
    tile: UvRect,
    offsets_in_face: &[DVec3],
    h1: f64,
    h2: f64,
) -> Option<UvRect> {
    let mut w = tile;
    for &b in offsets_in_face {
        for c in tile.corners() {
            let (u, v) = shifted(c, b, h1, h2)?;
            w.include(u, v);
        }
    }
    Some(w)
}

/// Where the rays from every point of one straight piece of the cell's motion (face-frame
/// offsets `piece.0` to `piece.1`) to every point of an occludee tile (footprint `tile`,
/// planar depth in `[h_lo, h_hi]`, `h_hi` may be `+inf`) cross the plane at planar depth `h`
/// (`h ≤ h_lo`): the bounding rectangle of the tile corners' images for both ends of the
/// piece and both depth extremes. Unlike [`extended_window`] it does not contain the tile
/// itself. `None` when an end of the piece is not in front of the plane.
///
/// The extremes suffice: for a fixed occludee point the crossing moves monotonically along a
/// line as the viewer moves along a straight piece (a central projection of a line, no pole
/// while the viewer is in front of the plane), and for a fixed viewer it moves monotonically
/// with the occludee's depth (`k = (h₂ − h)/(h·(h₂ − bz))` grows with `h₂` when `h > bz`);
/// so each coordinate is largest and smallest at a combination of extremes.
pub fn landing_window(
    tile: UvRect,
    piece: (DVec3, DVec3),
    h: f64,
    h_lo: f64,
    h_hi: f64,
) -> Option<UvRect> {
    let mut w: Option<UvRect> = None;
    for b in [piece.0, piece.1] {
        for h2 in [h_lo, h_hi] {
            for c in tile.corners() {
                let (u, v) = shifted(c, b, h, h2)?;
                match &mut w {
                    Some(r) => r.include(u, v),
                    None => {
                        w = Some(UvRect {
                            u0: u,
                            u1: u,
                            v0: v,
                            v1: v,
                        })
                    }
                }
            }
        }
    }
    w
}

/// A pixel rectangle on one face: the workspace's one rectangle type.
pub use tracks::PixelRect;

/// The faces a window on `face`'s extended plane touches, each with the pixel rectangle
/// that covers the window's part there (a superset: the part is clipped to the face exactly,
/// mapped through the projective map between the two face planes, and bounded). At most five
/// pieces: the face itself and its four neighbours (a window of directions in front of
/// `face` never reaches the opposite face).
pub fn face_pieces(face: Face, window: UvRect, face_size: u32) -> Vec<PixelRect> {
    let mut out = Vec::with_capacity(5);
    // A window strictly inside the face's square meets no other face: one piece, no clipping.
    if window.u0 > -1.0 && window.u1 < 1.0 && window.v0 > -1.0 && window.v1 < 1.0 {
        out.extend(pixel_cover(face, window, face_size));
        return out;
    }
    let corners = window.corners();
    for target in Face::ALL {
        if target.forward() == -face.forward() {
            continue;
        }
        // The direction through (u, v) is fw + u·r + v·up; a linear function w·dir is
        // a + b·u + c·v in the window's coordinates.
        let lin = |w: DVec3| (w.dot(face.forward()), w.dot(face.right()), w.dot(face.up()));
        let (tf, tr, tu) = (target.forward(), target.right(), target.up());
        let planes = [lin(tf - tr), lin(tf + tr), lin(tf - tu), lin(tf + tu)];
        let mut poly: Vec<(f64, f64)> = corners.to_vec();
        for (a, b, c) in planes {
            poly = clip(&poly, a, b, c);
            if poly.is_empty() {
                break;
            }
        }
        if poly.is_empty() {
            continue;
        }
        let mut bb: Option<UvRect> = None;
        for (u, v) in poly {
            let Some((tu_, tv_)) = target.uv_from_dir(face.dir_from_uv(u, v)) else {
                continue;
            };
            let (tu_, tv_) = (tu_.clamp(-1.0, 1.0), tv_.clamp(-1.0, 1.0));
            match &mut bb {
                None => {
                    bb = Some(UvRect {
                        u0: tu_,
                        u1: tu_,
                        v0: tv_,
                        v1: tv_,
                    })
                }
                Some(r) => r.include(tu_, tv_),
            }
        }
        if let Some(r) = bb {
            if let Some(px) = pixel_cover(target, r, face_size) {
                out.push(px);
            }
        }
    }
    out
}

/// Pixels whose area meets `r` (clamped to the face); `None` when empty.
fn pixel_cover(face: Face, r: UvRect, n: u32) -> Option<PixelRect> {
    let nf = n as f64;
    // Coordinates within rounding of a pixel boundary snap onto it, so an exact tile
    // footprint covers exactly its own pixels.
    let snap = |p: f64| {
        let r = p.round();
        if (p - r).abs() < 1e-7 {
            r
        } else {
            p
        }
    };
    let to_x = |u: f64| snap((u + 1.0) * 0.5 * nf);
    let to_y = |v: f64| snap((1.0 - v) * 0.5 * nf);
    let x0 = to_x(r.u0).floor().clamp(0.0, nf) as u32;
    let x1 = to_x(r.u1).ceil().clamp(0.0, nf) as u32;
    let y0 = to_y(r.v1).floor().clamp(0.0, nf) as u32;
    let y1 = to_y(r.v0).ceil().clamp(0.0, nf) as u32;
    (x1 > x0 && y1 > y0).then_some(PixelRect {
        face,
        x0,
        y0,
        x1,
        y1,
    })
}

/// Sutherland–Hodgman: keep the part of a convex polygon where `a + b·u + c·v ≥ 0`.
fn clip(poly: &[(f64, f64)], a: f64, b: f64, c: f64) -> Vec<(f64, f64)> {
    let f = |p: (f64, f64)| a + b * p.0 + c * p.1;
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let p = poly[i];
        let q = poly[(i + 1) % poly.len()];
        let (fp, fq) = (f(p), f(q));
        if fp >= 0.0 {
            out.push(p);
        }
        if (fp >= 0.0) != (fq >= 0.0) {
            let t = fp / (fp - fq);
            out.push((p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1)));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn sideways_motion_is_the_papers_equation_one() {
        // b along the image x axis, occluder plane h1 = 10, occludee plane h2 = 20:
        // s = d·(h2 − h1)/h2 on the plane at h1 = 1·10/20 = 0.5 m → 0.05 in face units.
        let p = shifted((0.2, -0.1), DVec3::new(1.0, 0.0, 0.0), 10.0, 20.0).unwrap();
        assert!(
            (p.0 - 0.25).abs() < 1e-15 && (p.1 + 0.1).abs() < 1e-15,
            "{p:?}"
        );
    }

    #[test]
    fn shifted_point_lies_on_the_ray_from_the_cell_point() {
        let b = DVec3::new(0.3, -0.7, 1.1);
        let (h1, h2) = (5.0, 13.0);
        let p = (0.4, 0.25);
        let q = shifted(p, b, h1, h2).unwrap();
        let target = DVec3::new(p.0 * h2, p.1 * h2, h2);
        let on_plane = DVec3::new(q.0 * h1, q.1 * h1, h1);
        // on_plane, b and target are collinear.
        let c = (on_plane - b).cross(target - b).length();
        assert!(c < 1e-12, "{c}");
    }

    #[test]
    fn landing_window_spans_the_piece_and_the_depth_range() {
        let tile = UvRect {
            u0: 0.1,
            u1: 0.2,
            v0: -0.1,
            v1: 0.0,
        };
        // No motion: the rays land on the tile itself.
        let w = landing_window(tile, (DVec3::ZERO, DVec3::ZERO), 4.0, 8.0, 20.0).unwrap();
        assert!(w.contains(&tile) && tile.contains(&w), "{w:?}");
        // Sideways along +u from 0.5 to 1 m: shifts b·(1/h − 1/h₂) between the extremes.
        let piece = (DVec3::new(0.5, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0));
        let w = landing_window(tile, piece, 4.0, 8.0, 20.0).unwrap();
        let (lo, hi) = (0.5 * (0.25 - 0.125), 1.0 * (0.25 - 0.05));
        assert!(
            (w.u0 - (0.1 + lo)).abs() < 1e-12 && (w.u1 - (0.2 + hi)).abs() < 1e-12,
            "{w:?}"
        );
        assert!((w.v0 + 0.1).abs() < 1e-12 && w.v1.abs() < 1e-12, "{w:?}");
        // A piece reaching the plane concludes nothing.
        let ahead = (DVec3::ZERO, DVec3::new(0.0, 0.0, 4.0));
        assert!(landing_window(tile, ahead, 4.0, 8.0, 20.0).is_none());
    }

    #[test]
    fn cell_point_behind_the_occluder_plane_concludes_nothing() {
        assert!(shifted((0.0, 0.0), DVec3::new(0.0, 0.0, 5.0), 5.0, 9.0).is_none());
        assert!(shifted((0.0, 0.0), DVec3::ZERO, 0.0, 9.0).is_none());
    }

    #[test]
    fn window_on_one_face_is_one_piece() {
        let g = TileGrid::new(64, 16).unwrap();
        let t = TileId {
            face: Face::PosZ,
            tx: 1,
            ty: 1,
        };
        let r = UvRect::of_tile(&g, t);
        let p = face_pieces(Face::PosZ, r, 64);
        assert_eq!(
            p,
            vec![PixelRect {
                face: Face::PosZ,
                x0: 16,
                y0: 16,
                x1: 32,
                y1: 32
            }]
        );
    }

    #[test]
    fn window_across_an_edge_reaches_the_neighbour() {
        // +z's right is −x: a window past u = 1 on +z lands on −x's left edge.
        let r = UvRect {
            u0: 0.9,
            u1: 1.2,
            v0: -0.1,
            v1: 0.1,
        };
        let p = face_pieces(Face::PosZ, r, 64);
        assert_eq!(p.len(), 2, "{p:?}");
        let nx = p.iter().find(|q| q.face == Face::NegX).unwrap();
        assert_eq!(nx.x0, 0);
        assert!(nx.x1 >= 5 && nx.x1 <= 7, "{nx:?}");
    }

    proptest! {
        /// Every direction inside a window falls in one of its pieces.
        #[test]
        fn pieces_cover_the_window(face in 0usize..6, u0 in -3.0f64..2.5, v0 in -3.0f64..2.5,
                                   du in 0.0f64..2.0, dv in 0.0f64..2.0, su in 0.0f64..1.0, sv in 0.0f64..1.0) {
            let face = Face::from_index(face).unwrap();
            let r = UvRect { u0, u1: u0 + du, v0, v1: v0 + dv };
            let n = 32;
            let pieces = face_pieces(face, r, n);
            let (u, v) = (u0 + su * du, v0 + sv * dv);
            let c = tracks::FaceCoord::from_dir(face.dir_from_uv(u, v)).unwrap();
            let (x, y) = c.to_pixel(n);
            prop_assert!(pieces.iter().any(|p| p.face == c.face && x >= p.x0 && x < p.x1 && y >= p.y0 && y < p.y1),
                "({u},{v}) → {:?} ({x},{y}) not in {:?}", c.face, pieces);
        }
    }
}
