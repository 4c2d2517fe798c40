//! Slab layers → tiles: opacity masks, empty-tile removal, per-tile depth range and mesh.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, SlabRange, TileGrid, TileId};

use crate::mesh::{mesh_tile, MeshParams, MeshStats, TileMesh};
use crate::SlabsError;

/// One slab layer of one viewpoint: radial depth (`+inf` where the slab holds nothing) and
/// the binary opacity mask.
#[derive(Clone, Copy, Debug)]
pub struct LayerInput<'a> {
    pub depth: &'a CubeMap<f32>,
    pub mask: &'a CubeMap<bool>,
}

/// The binary opacity mask of a slab layer: alpha ≥ 128 and a finite positive depth.
pub fn mask_from_layer(color: &CubeMap<[u8; 4]>, depth: &CubeMap<f32>) -> CubeMap<bool> {
    let data = color
        .as_slice()
        .iter()
        .zip(depth.as_slice())
        .map(|(c, &d)| c[3] >= 128 && d.is_finite() && d > 0.0)
        .collect();
    CubeMap::from_vec(color.face_size(), data).unwrap_or_else(|| CubeMap::filled(0, false))
}

/// The mask of a layer known only by its depth: every finite positive depth is opaque.
pub fn mask_from_depth(depth: &CubeMap<f32>) -> CubeMap<bool> {
    depth.map(|&d| d.is_finite() && d > 0.0)
}

/// Split one depth map into per-slab layers of what the viewpoint itself sees: depth where
/// it falls in the slab, `+inf` elsewhere. (Rendered layers also hold what nearer slabs
/// hide; this is the split of the visible surface only.)
pub fn split_depth(depth: &CubeMap<f32>, slabs: &[SlabRange]) -> Vec<CubeMap<f32>> {
    slabs
        .par_iter()
        .map(|s| {
            depth.map(|&d| {
                if s.contains(d as f64) {
                    d
                } else {
                    f32::INFINITY
                }
            })
        })
        .collect()
}

/// Which mesh a tile carries (by default the adaptive one, as `railview slabs` keeps).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshKind {
    Grid,
    #[default]
    Adaptive,
}

/// Parameters of [`tile_sample`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileParams {
    /// Tile side in pixels, a power of two.
    pub tile_size: u32,
    pub mesh: MeshParams,
    /// Which of the two meshes [`SlabTile::mesh`] holds.
    pub keep: MeshKind,
    /// Also build and measure the other mesh (for the report); otherwise its stats are zero.
    pub measure_both: bool,
}

/// A non-empty tile of one slab layer of one viewpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabTile {
    pub viewpoint: usize,
    pub slab: usize,
    pub tile: TileId,
    /// Nearest and farthest opaque depth in the tile, metres.
    pub depth_min: f32,
    pub depth_max: f32,
    /// Opaque pixels in the tile (≥ 1: empty tiles are not stored).
    pub opaque_pixels: u32,
    /// Pixels in the tile (smaller than `tile_size²` for edge tiles of odd face sizes).
    pub pixels: u32,
    /// Opacity bits of the tile's pixel rectangle, row-major, bit `i % 8` of byte `i / 8`.
    #[serde(skip)]
    pub mask: Vec<u8>,
    #[serde(skip)]
    pub mesh: TileMesh,
    pub grid_stats: MeshStats,
    pub adaptive_stats: MeshStats,
}

impl SlabTile {
    /// Whether pixel `(dx, dy)` of the tile rectangle (width `w`) is opaque.
    pub fn is_opaque(&self, dx: u32, dy: u32, w: u32) -> bool {
        let i = (dy * w + dx) as usize;
        self.mask.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 == 1)
    }
}

/// Tiles of one slab layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerTiles {
    pub slab: usize,
    /// Tiles of the grid (all faces) before empty-tile removal.
    pub tiles_before: usize,
    /// The non-empty tiles, in tile-index order.
    pub tiles: Vec<SlabTile>,
}

/// All slab layers of one viewpoint, tiled and meshed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleTiles {
    pub viewpoint: usize,
    pub grid: TileGrid,
    pub layers: Vec<LayerTiles>,
}

/// Tile one slab layer: empty tiles removed, depth range, mask bits and meshes per tile.
pub fn tile_layer(
    viewpoint: usize,
    slab: usize,
    layer: LayerInput,
    params: &TileParams,
) -> Result<LayerTiles, SlabsError> {
    let n = layer.depth.face_size();
    if layer.mask.face_size() != n {
        return Err(SlabsError::Parameter(format!(
            "slab {slab}: mask face size {} differs from depth face size {n}",
            layer.mask.face_size()
        )));
    }
    let grid = TileGrid::new(n, params.tile_size).ok_or_else(|| {
        SlabsError::Parameter(format!(
            "tile size {} must be a power of two and the face size {n} non-zero",
            params.tile_size
        ))
    })?;
    let ids: Vec<TileId> = grid.tiles().collect();
    let tiles: Vec<SlabTile> = ids
        .par_iter()
        .filter_map(|&t| tile_one(viewpoint, slab, layer, grid, t, params))
        .collect();
    Ok(LayerTiles {
        slab,
        tiles_before: grid.tile_count(),
        tiles,
    })
}

/// One tile of one slab layer: `None` when it holds no opaque pixel.
fn tile_one(
    viewpoint: usize,
    slab: usize,
    layer: LayerInput,
    grid: TileGrid,
    t: TileId,
    params: &TileParams,
) -> Option<SlabTile> {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t);
    let mut lo = f32::INFINITY;
    let mut hi = 0.0f32;
    let mut count = 0u32;
    let w = x1 - x0;
    let mut bits = vec![0u8; ((w * (y1 - y0)) as usize).div_ceil(8)];
    let n = grid.face_size as usize;
    let (fm, fd) = (layer.mask.face(t.face), layer.depth.face(t.face));
    let mut i = 0usize;
    for y in y0 as usize..y1 as usize {
        let row = y * n + x0 as usize..y * n + x1 as usize;
        for (&m, &d) in fm[row.clone()].iter().zip(&fd[row]) {
            if m {
                lo = lo.min(d);
                hi = hi.max(d);
                count += 1;
                bits[i / 8] |= 1 << (i % 8);
            }
            i += 1;
        }
    }
    if count == 0 {
        return None;
    }
    let mut m = mesh_tile(
        layer.depth,
        layer.mask,
        grid,
        t,
        &params.mesh,
        if params.measure_both {
            None
        } else {
            Some(params.keep)
        },
    );
    // Vertices stay within the depths of the tile's own opaque pixels, so within its slab:
    // an error-bounded or extrapolated vertex (the band past the outline) can then never put
    // a deeper slab's surface in front of a nearer slab's.
    for v in m
        .grid
        .vertices
        .iter_mut()
        .chain(m.adaptive.vertices.iter_mut())
    {
        v[2] = v[2].clamp(lo, hi);
    }
    Some(SlabTile {
        viewpoint,
        slab,
        tile: t,
        depth_min: lo,
        depth_max: hi,
        opaque_pixels: count,
        pixels: w * (y1 - y0),
        mask: bits,
        mesh: match params.keep {
            MeshKind::Grid => m.grid,
            MeshKind::Adaptive => m.adaptive,
        },
        grid_stats: m.grid_stats,
        adaptive_stats: m.adaptive_stats,
    })
}

/// Tile every slab layer of one viewpoint (`layers[k]` is slab `k`).
pub fn tile_sample(
    viewpoint: usize,
    layers: &[LayerInput],
    params: &TileParams,
) -> Result<SampleTiles, SlabsError> {
    let n = layers.first().map_or(1, |l| l.depth.face_size());
    if let Some((k, l)) = layers
        .iter()
        .enumerate()
        .find(|(_, l)| l.depth.face_size() != n)
    {
        return Err(SlabsError::Parameter(format!(
            "slab {k}: face size {} differs from slab 0's {n}",
            l.depth.face_size()
        )));
    }
    let grid = TileGrid::new(n, params.tile_size).ok_or_else(|| {
        SlabsError::Parameter(format!(
            "tile size {} must be a power of two",
            params.tile_size
        ))
    })?;
    for (k, l) in layers.iter().enumerate() {
        if l.mask.face_size() != n {
            return Err(SlabsError::Parameter(format!(
                "slab {k}: mask face size {} differs from depth face size {n}",
                l.mask.face_size()
            )));
        }
    }
    // One parallel loop over the tiles of all slabs, so that the cores stay busy across
    // slab boundaries; the collected order is slab-major, tile-index order within a slab.
    let jobs: Vec<(usize, TileId)> = (0..layers.len())
        .flat_map(|k| grid.tiles().map(move |t| (k, t)))
        .collect();
    let done: Vec<SlabTile> = jobs
        .par_iter()
        .filter_map(|&(k, t)| tile_one(viewpoint, k, layers[k], grid, t, params))
        .collect();
    let mut out: Vec<LayerTiles> = (0..layers.len())
        .map(|slab| LayerTiles {
            slab,
            tiles_before: grid.tile_count(),
            tiles: Vec::new(),
        })
        .collect();
    for tile in done {
        let slab = tile.slab;
        out[slab].tiles.push(tile);
    }
    let layers = out;
    Ok(SampleTiles {
        viewpoint,
        grid,
        layers,
    })
}

/// Leave out the `levels` finest texture levels of a tile's colour: every block of
/// `2^levels × 2^levels` texels takes the mean colour of its opaque texels (alpha > 0), so
/// the colour holds no more than a tile at `1/2^levels` of the resolution would; the alpha
/// (the slab's opacity mask) stays at full resolution. A PTM codes the repeated texels of
/// such blocks from their parent level almost for free. `rgba` is `width × height` RGBA8.
pub fn coarsen_colour(rgba: &mut [u8], width: u32, height: u32, levels: u32) {
    if levels == 0 {
        return;
    }
    let b = 1usize << levels.min(15);
    let (w, h) = (width as usize, height as usize);
    if rgba.len() < w * h * 4 {
        return;
    }
    for by in (0..h).step_by(b) {
        for bx in (0..w).step_by(b) {
            let (mut sum, mut n) = ([0u64; 3], 0u64);
            for y in by..(by + b).min(h) {
                for x in bx..(bx + b).min(w) {
                    let p = &rgba[(y * w + x) * 4..][..4];
                    if p[3] > 0 {
                        for (s, &v) in sum.iter_mut().zip(&p[..3]) {
                            *s += v as u64;
                        }
                        n += 1;
                    }
                }
            }
            if n == 0 {
                continue;
            }
            let mean = sum.map(|s| ((s + n / 2) / n) as u8);
            for y in by..(by + b).min(h) {
                for x in bx..(bx + b).min(w) {
                    let p = &mut rgba[(y * w + x) * 4..][..4];
                    if p[3] > 0 {
                        p[..3].copy_from_slice(&mean);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod coarsen_tests {
    use super::*;

    #[test]
    fn coarsened_colour_is_one_mean_per_block_under_the_same_mask() {
        // 4×2 RGBA: a 2×2 block with one empty texel, and one fully opaque.
        let mut px = vec![
            10, 0, 0, 255, 20, 0, 0, 255, 100, 0, 0, 255, 100, 0, 0, 255, //
            30, 0, 0, 255, 0, 0, 0, 0, 100, 0, 0, 255, 104, 0, 0, 255,
        ];
        let alpha: Vec<u8> = px.chunks(4).map(|p| p[3]).collect();
        coarsen_colour(&mut px, 4, 2, 1);
        let r: Vec<u8> = px.chunks(4).map(|p| p[0]).collect();
        assert_eq!(r, [20, 20, 101, 101, 20, 0, 101, 101]);
        assert_eq!(px.chunks(4).map(|p| p[3]).collect::<Vec<_>>(), alpha);
        let before = px.clone();
        coarsen_colour(&mut px, 4, 2, 0);
        assert_eq!(px, before);
    }
}
