//! What culling takes: per reference viewpoint its slab layers and tiles, and its cell.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, SlabRange, TileGrid, TileId};

use crate::OcclusionError;

/// One non-empty tile of a slab layer.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileInfo {
    pub id: TileId,
    /// Nearest and farthest radial depth of the tile's opaque pixels, metres.
    pub depth_min: f64,
    pub depth_max: f64,
    /// Stored size of the tile (what "Size MB" in the reports adds up).
    pub bytes: u64,
}

/// A slab layer at one reference viewpoint.
#[derive(Clone, Debug)]
pub struct SlabLayer {
    pub range: SlabRange,
    /// Alpha of the layer (`slab_K/color.png`): opaque where ≥ 128.
    pub alpha: CubeMap<u8>,
    /// Radial depth (`slab_K/depth.exr`), `+inf` where the slab holds nothing.
    pub depth: CubeMap<f32>,
    /// Its non-empty tiles (empty tiles already removed).
    pub tiles: Vec<TileInfo>,
}

/// Bytes of a tile when stored as raw RGBA8 (the paper's tables: 32² × 4 = 4 KiB a tile).
pub fn raw_rgba_bytes(grid: &TileGrid, id: TileId) -> u64 {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(id);
    (x1 - x0) as u64 * (y1 - y0) as u64 * 4
}

impl SlabLayer {
    /// Build a layer from its alpha and depth maps, finding the non-empty tiles and their
    /// depth ranges; tiles are sized by `bytes_of`. Errors name the pixel whose depth is not
    /// usable (opaque but not a finite non-negative number).
    pub fn from_maps(
        range: SlabRange,
        alpha: CubeMap<u8>,
        depth: CubeMap<f32>,
        grid: &TileGrid,
        bytes_of: impl Fn(&TileGrid, TileId) -> u64,
    ) -> Result<SlabLayer, OcclusionError> {
        if alpha.face_size() != grid.face_size || depth.face_size() != grid.face_size {
            return Err(OcclusionError::Input {
                what: format!("slab {}", range.label()),
                message: format!(
                    "alpha is {}², depth {}², tile grid {}²",
                    alpha.face_size(),
                    depth.face_size(),
                    grid.face_size
                ),
            });
        }
        let mut tiles = Vec::new();
        for id in grid.tiles() {
            let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(id);
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for y in y0..y1 {
                for x in x0..x1 {
                    if *alpha.get(id.face, x, y) >= 128 {
                        let d = *depth.get(id.face, x, y) as f64;
                        if !(d.is_finite() && d >= 0.0) {
                            return Err(OcclusionError::Input {
                                what: format!("slab {}", range.label()),
                                message: format!(
                                    "pixel ({x}, {y}) of face {} is opaque but has depth {d}",
                                    id.face.short_name()
                                ),
                            });
                        }
                        lo = lo.min(d);
                        hi = hi.max(d);
                    }
                }
            }
            if lo <= hi {
                tiles.push(TileInfo {
                    id,
                    depth_min: lo,
                    depth_max: hi,
                    bytes: bytes_of(grid, id),
                });
            }
        }
        Ok(SlabLayer {
            range,
            alpha,
            depth,
            tiles,
        })
    }
}

/// The cell of a reference viewpoint: every place the viewer may be while this viewpoint's
/// layers are in use — the track from the previous to the next reference viewpoint.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    pub viewpoint: DVec3,
    /// Polylines from the viewpoint along the track towards each neighbour, ending at it
    /// (first vertex after the viewpoint). Empty for a single-sample track.
    pub paths: Vec<Vec<DVec3>>,
}

impl Cell {
    /// The cell of viewpoint `i` of a track whose reference viewpoints are `positions`,
    /// joined by straight segments.
    pub fn straight(positions: &[DVec3], i: usize) -> Cell {
        let mut paths = Vec::new();
        if i > 0 {
            paths.push(vec![positions[i - 1]]);
        }
        if i + 1 < positions.len() {
            paths.push(vec![positions[i + 1]]);
        }
        Cell {
            viewpoint: positions[i],
            paths,
        }
    }

    /// The cell of viewpoint `i` along a polyline `curve` whose vertices carry arc lengths
    /// `arc`, given the viewpoints' arc lengths `sample_arcs`: the curve's vertices between
    /// the neighbours (a smoothed track is followed, not cut short).
    pub fn along_curve(curve: &[DVec3], arc: &[f64], sample_arcs: &[f64], i: usize) -> Cell {
        let pos = |s: f64| tracks::segment::point_at(curve, arc, s);
        let s = sample_arcs[i];
        let mut paths = Vec::new();
        if i > 0 {
            let s0 = sample_arcs[i - 1];
            let mut p: Vec<DVec3> = curve
                .iter()
                .zip(arc)
                .filter(|(_, &a)| a > s0 && a < s)
                .map(|(c, _)| *c)
                .rev()
                .collect();
            p.push(pos(s0));
            paths.push(p);
        }
        if i + 1 < sample_arcs.len() {
            let s1 = sample_arcs[i + 1];
            let mut p: Vec<DVec3> = curve
                .iter()
                .zip(arc)
                .filter(|(_, &a)| a > s && a < s1)
                .map(|(c, _)| *c)
                .collect();
            p.push(pos(s1));
            paths.push(p);
        }
        Cell {
            viewpoint: pos(s),
            paths,
        }
    }

    /// Offsets `X − V` of every path vertex (the cell's straight pieces have their extremes
    /// there), the viewpoint itself included.
    pub fn offsets(&self) -> Vec<DVec3> {
        let mut out = vec![DVec3::ZERO];
        for p in &self.paths {
            out.extend(p.iter().map(|x| *x - self.viewpoint));
        }
        out
    }

    /// The cell's motion as straight pieces `(from, to)` of offsets `X − V`: every straight
    /// stretch of each path (starting at the viewpoint) cut into `steps` equal pieces. A
    /// single-sample track's cell is the one degenerate piece `(0, 0)`.
    pub fn motion_pieces(&self, steps: u32) -> Vec<(DVec3, DVec3)> {
        let steps = steps.max(1);
        let mut out = Vec::new();
        for path in &self.paths {
            let mut a = DVec3::ZERO;
            for x in path {
                let b = *x - self.viewpoint;
                for j in 0..steps {
                    let (s0, s1) = (j as f64 / steps as f64, (j + 1) as f64 / steps as f64);
                    let end = if j + 1 == steps { b } else { a.lerp(b, s1) };
                    out.push((a.lerp(b, s0), end));
                }
                a = b;
            }
        }
        if out.is_empty() {
            out.push((DVec3::ZERO, DVec3::ZERO));
        }
        out
    }

    /// Largest distance from the viewpoint to any point of the cell.
    pub fn radius(&self) -> f64 {
        self.offsets()
            .iter()
            .map(|b| b.length())
            .fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::Face;

    #[test]
    fn tiles_and_depth_ranges_from_maps() {
        let g = TileGrid::new(8, 4).unwrap();
        let alpha = CubeMap::from_fn(8, |f, x, y| {
            if f == Face::PosY && x < 2 && y >= 4 {
                255
            } else {
                0
            }
        });
        let depth = CubeMap::from_fn(8, |_, x, y| {
            if x < 2 {
                3.0 + x as f32 + y as f32
            } else {
                f32::INFINITY
            }
        });
        let l = SlabLayer::from_maps(
            SlabRange::new(2.0, 20.0).unwrap(),
            alpha,
            depth,
            &g,
            raw_rgba_bytes,
        )
        .unwrap();
        assert_eq!(l.tiles.len(), 1);
        let t = l.tiles[0];
        assert_eq!(
            t.id,
            TileId {
                face: Face::PosY,
                tx: 0,
                ty: 1
            }
        );
        assert_eq!((t.depth_min, t.depth_max, t.bytes), (7.0, 11.0, 64));
    }

    #[test]
    fn opaque_pixel_without_depth_is_named() {
        let g = TileGrid::new(4, 4).unwrap();
        let mut alpha = CubeMap::filled(4, 0u8);
        *alpha.get_mut(Face::NegZ, 1, 2) = 255;
        let depth = CubeMap::filled(4, f32::INFINITY);
        let e = SlabLayer::from_maps(
            SlabRange::new(0.0, 1.0).unwrap(),
            alpha,
            depth,
            &g,
            raw_rgba_bytes,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("(1, 2)") && e.contains("nz"), "{e}");
    }

    #[test]
    fn cells_of_a_track() {
        let p = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 0.0, 1.0)];
        let c0 = Cell::straight(&p, 0);
        assert_eq!(c0.offsets(), vec![DVec3::ZERO, DVec3::X]);
        let c1 = Cell::straight(&p, 1);
        assert_eq!(c1.paths.len(), 2);
        assert!((c1.radius() - 1.0).abs() < 1e-15);
        assert_eq!(Cell::straight(&p[..1], 0).paths.len(), 0);
        // Motion pieces: every stretch from the viewpoint cut in equal parts, ends exact.
        let m = c1.motion_pieces(2);
        assert_eq!(m.len(), 4);
        assert_eq!(m[0], (DVec3::ZERO, DVec3::new(-0.5, 0.0, 0.0)));
        assert_eq!(m[1].1, -DVec3::X);
        assert_eq!(m[3], (DVec3::new(0.0, 0.0, 0.5), DVec3::Z));
        assert_eq!(
            Cell::straight(&p[..1], 0).motion_pieces(4),
            vec![(DVec3::ZERO, DVec3::ZERO)]
        );
        // Along a bent curve the cell follows the bend.
        let curve = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 0.0, 1.0)];
        let arc = tracks::segment::arc_lengths(&curve);
        let c = Cell::along_curve(&curve, &arc, &[0.0, 2.0], 0);
        assert_eq!(c.paths[0], vec![DVec3::X, DVec3::new(1.0, 0.0, 1.0)]);
    }
}
