//! [`PixelRect`]: a rectangle of pixels on one cube face, the one rectangle type of the
//! workspace (a tile's pixels, the texels a streamed tile changed, the pixels a culling
//! window covers).

use crate::cubemap::Face;

/// A pixel rectangle `[x0, x1) × [y0, y1)` on one face (ends exclusive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    pub face: Face,
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl PixelRect {
    /// Pixels covered (0 when empty).
    pub fn area(&self) -> u64 {
        u64::from(self.x1.saturating_sub(self.x0)) * u64::from(self.y1.saturating_sub(self.y0))
    }

    /// Whether it covers no pixel.
    pub fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }

    /// Grown by `d` pixels on every side, clipped to a face `n` pixels wide.
    pub fn grown(&self, d: u32, n: u32) -> PixelRect {
        PixelRect {
            face: self.face,
            x0: self.x0.saturating_sub(d),
            y0: self.y0.saturating_sub(d),
            x1: (self.x1 + d).min(n),
            y1: (self.y1 + d).min(n),
        }
    }

    /// The texels of the mip level `level` steps coarser that cover it.
    pub fn coarser(&self, level: u32) -> PixelRect {
        let s = 1u32 << level;
        PixelRect {
            face: self.face,
            x0: self.x0 / s,
            y0: self.y0 / s,
            x1: self.x1.div_ceil(s),
            y1: self.y1.div_ceil(s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{TileGrid, TileId};

    #[test]
    fn a_tile_rect_grows_within_the_face_and_covers_coarser_texels() {
        let grid = TileGrid::new(10, 4).unwrap();
        let tile = TileId {
            face: Face::NegY,
            tx: 2,
            ty: 1,
        };
        let r = grid.pixel_rect(tile);
        assert_eq!((r.face, r.x0, r.y0, r.x1, r.y1), (Face::NegY, 8, 4, 10, 8));
        assert_eq!(r.area(), 8);
        let g = r.grown(2, 10);
        assert_eq!((g.x0, g.y0, g.x1, g.y1), (6, 2, 10, 10));
        let c = r.coarser(1);
        assert_eq!((c.x0, c.y0, c.x1, c.y1), (4, 2, 5, 4));
        assert!(!r.is_empty());
        assert!(PixelRect { x1: 8, ..r }.is_empty());
        assert_eq!(PixelRect { x1: 8, ..r }.area(), 0);
    }
}
