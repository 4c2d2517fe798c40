//! ACH — average coverage hints per track segment (Marvie & Bouatouch §5, adapted to tracks).
//!
//! The paper renders the potentially visible cells from sample points of a cell with six 90°
//! cameras (a "rendering box") and sets `ACH_j = N_j / N_total`, `N_j` the pixels cell `j`
//! covers over all cameras. Here a cell is a track segment between two reference viewpoints,
//! the objects are the kept slab tiles of those two viewpoints, and the visibility pass is a
//! CPU reprojection: every tile pixel is lifted to 3D with its radial depth and splatted into
//! the six cameras (a cube map of `camera_size`) at `samples` points evenly spread along the
//! segment, with a depth test. A viewer between the two viewpoints blends them with weights
//! `1 − t` and `t`, so each viewpoint's tiles are reprojected into their own depth buffer and
//! their pixel counts weighted the same way. Thus `Σ ACH_j = 1` over the segment's tiles.

use glam::DVec3;
use tracks::cubemap::{pixel_dir, FaceCoord};
use tracks::manifest::AchEntry;
use tracks::TileId;

/// A kept tile with its depth, as seen from its reference viewpoint.
#[derive(Clone, Debug)]
pub struct AchTile<'a> {
    /// Reference viewpoint index (must be the segment's `from` or `to`).
    pub viewpoint: usize,
    pub slab: u32,
    pub tile: TileId,
    /// Face size of the reference panorama.
    pub face_size: u32,
    /// First pixel of the tile on its face, and its width and height.
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    /// Radial depth per tile pixel (row-major); non-finite or ≤ 0 where the tile is empty.
    pub depth: &'a [f32],
}

/// One end of a segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentEnd {
    pub index: usize,
    pub position: DVec3,
}

/// Sampling of the visibility pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AchParams {
    /// Viewpoints along the segment (the paper uses eight per cell).
    pub samples: usize,
    /// Pixels per side of each of the six 90° cameras.
    pub camera_size: u32,
}

impl Default for AchParams {
    fn default() -> Self {
        AchParams {
            samples: 8,
            camera_size: 64,
        }
    }
}

/// ACH of every tile seen along the segment `from → to`, by descending value; tiles that cover
/// no pixel are left out. Tiles of other viewpoints are ignored.
pub fn segment_ach(
    from: SegmentEnd,
    to: SegmentEnd,
    tiles: &[AchTile],
    params: AchParams,
) -> Vec<AchEntry> {
    use rayon::prelude::*;
    let cs = params.camera_size.max(1);
    let samples = params.samples.max(1);
    // Each sample point's pixel counts on its own (in parallel), then summed in sample order
    // so the result does not depend on the threads.
    // Each tile pixel's point and footprint, once for all the samples.
    let points: Vec<Vec<SplatPoint>> = tiles
        .par_iter()
        .map(|tile| {
            let origin = if tile.viewpoint == from.index {
                from.position
            } else {
                to.position
            };
            points_of(tile, origin)
        })
        .collect();
    let per_sample: Vec<Vec<(f64, Vec<u64>)>> = (0..samples)
        .into_par_iter()
        .map(|s| {
            let t = (s as f64 + 0.5) / samples as f64;
            let eye = from.position.lerp(to.position, t);
            let mut zbuf = vec![(f32::INFINITY, u32::MAX); 6 * cs as usize * cs as usize];
            let mut out = Vec::with_capacity(2);
            for (end, w) in [(from, 1.0 - t), (to, t)] {
                if from.index == to.index && end.index == to.index && w == t {
                    continue; // a degenerate segment: count its one viewpoint once
                }
                zbuf.fill((f32::INFINITY, u32::MAX));
                for (i, tile) in tiles.iter().enumerate() {
                    if tile.viewpoint == end.index {
                        splat(&points[i], i as u32, eye, cs, &mut zbuf);
                    }
                }
                let mut counts = vec![0u64; tiles.len()];
                for &(_, i) in &zbuf {
                    if i != u32::MAX {
                        counts[i as usize] += 1;
                    }
                }
                let w = if from.index == to.index { 1.0 } else { w };
                out.push((w, counts));
            }
            out
        })
        .collect();
    let mut weighted = vec![0f64; tiles.len()];
    for (w, counts) in per_sample.iter().flatten() {
        for (acc, &c) in weighted.iter_mut().zip(counts) {
            *acc += w * c as f64;
        }
    }
    let total: f64 = weighted.iter().sum();
    let mut out: Vec<AchEntry> = tiles
        .iter()
        .zip(&weighted)
        .filter(|(_, &n)| n > 0.0)
        .map(|(t, &n)| AchEntry {
            viewpoint: t.viewpoint,
            slab: t.slab,
            tile: t.tile,
            ach: n / total,
        })
        .collect();
    out.sort_by(|a, b| {
        b.ach
            .total_cmp(&a.ach)
            .then((a.viewpoint, a.slab, a.tile).cmp(&(b.viewpoint, b.slab, b.tile)))
    });
    out
}

/// A tile pixel lifted to 3D: its point and its radial depth times the angle it spans seen from
/// its viewpoint.
#[derive(Clone, Copy, Debug)]
struct SplatPoint {
    p: DVec3,
    extent: f64,
}

/// The points of a tile's pixels with a usable depth, seen from `origin`.
fn points_of(tile: &AchTile, origin: DVec3) -> Vec<SplatPoint> {
    // Angular pixel sizes on a cube face: 2/N / √(1+u²+v²) across, 2/N / (1+u²+v²) along the
    // radius. Overestimating the source and underestimating the target keeps splats hole-free.
    let n_src = tile.face_size.max(1) as f64;
    let mut out = Vec::with_capacity((tile.width * tile.height) as usize);
    for ty in 0..tile.height {
        for tx in 0..tile.width {
            let Some(&r) = tile.depth.get((ty * tile.width + tx) as usize) else {
                return out;
            };
            if !(r.is_finite() && r > 0.0) {
                continue;
            }
            let dir = pixel_dir(tile.tile.face, tile.x0 + tx, tile.y0 + ty, tile.face_size);
            let (us, vs) = (
                2.0 * (tile.x0 + tx) as f64 / n_src + 1.0 / n_src - 1.0,
                1.0 - 2.0 * (tile.y0 + ty) as f64 / n_src - 1.0 / n_src,
            );
            let src_angle = 2.0 / n_src / (1.0 + us * us + vs * vs).sqrt();
            out.push(SplatPoint {
                p: origin + dir * r as f64,
                extent: r as f64 * src_angle,
            });
        }
    }
    out
}

/// Reprojects a tile's points into the six cameras at `eye` with a depth test; each is
/// splatted as a square as large as its footprint seen from `eye`.
fn splat(points: &[SplatPoint], id: u32, eye: DVec3, cs: u32, zbuf: &mut [(f32, u32)]) {
    for pt in points {
        let d = pt.p - eye;
        let dist = d.length();
        let Some(fc) = FaceCoord::from_dir(d) else {
            continue;
        };
        let (px, py) = fc.to_pixel_f(cs);
        let dst_angle = 2.0 / cs as f64 / (1.0 + fc.u * fc.u + fc.v * fc.v);
        let size = (pt.extent / dist.max(1e-9) / dst_angle).clamp(1.0, 16.0);
        let half = size * 0.5;
        let x_lo = (px - half).round().clamp(0.0, cs as f64 - 1.0) as u32;
        let x_hi = ((px + half).round() as u32).clamp(x_lo + 1, cs);
        let y_lo = (py - half).round().clamp(0.0, cs as f64 - 1.0) as u32;
        let y_hi = ((py + half).round() as u32).clamp(y_lo + 1, cs);
        let base = fc.face.index() * (cs * cs) as usize;
        let z = dist as f32;
        for y in y_lo..y_hi {
            for x in x_lo..x_hi {
                let cell = &mut zbuf[base + (y * cs + x) as usize];
                if z < cell.0 {
                    *cell = (z, id);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::Face;

    fn end(index: usize, x: f64) -> SegmentEnd {
        SegmentEnd {
            index,
            position: DVec3::new(x, 0.0, 0.0),
        }
    }

    fn tile<'a>(viewpoint: usize, slab: u32, face: Face, depth: &'a [f32], n: u32) -> AchTile<'a> {
        AchTile {
            viewpoint,
            slab,
            tile: TileId { face, tx: 0, ty: 0 },
            face_size: n,
            x0: 0,
            y0: 0,
            width: n,
            height: n,
            depth,
        }
    }

    #[test]
    fn a_surrounding_box_splits_coverage_by_face() {
        // Six whole-face tiles at depth ≈ 5 around both viewpoints (a box room): every
        // camera pixel is covered, ACH sums to one and each face gets about a sixth.
        let n = 32;
        let depth: Vec<Vec<f32>> = Face::ALL
            .iter()
            .map(|&f| {
                (0..n * n)
                    .map(|i| {
                        let d = pixel_dir(f, i % n, i / n, n);
                        (5.0 / d.abs().max_element()) as f32
                    })
                    .collect()
            })
            .collect();
        let tiles: Vec<AchTile> = Face::ALL
            .iter()
            .zip(&depth)
            .map(|(&f, d)| tile(0, 0, f, d, n))
            .collect();
        let ach = segment_ach(
            end(0, 0.0),
            end(1, 1.0),
            &tiles,
            AchParams {
                samples: 4,
                camera_size: 16,
            },
        );
        assert_eq!(ach.len(), 6);
        let sum: f64 = ach.iter().map(|a| a.ach).sum();
        assert!((sum - 1.0).abs() < 1e-12);
        for a in &ach {
            assert!((a.ach - 1.0 / 6.0).abs() < 0.03, "{a:?}");
        }
        assert!(ach.windows(2).all(|w| w[0].ach >= w[1].ach));
    }

    #[test]
    fn occluded_tiles_get_no_coverage_and_weights_follow_blending() {
        let n = 16;
        let near = vec![2.0f32; (n * n) as usize];
        let far = vec![9.0f32; (n * n) as usize];
        let empty = vec![f32::INFINITY; (n * n) as usize];
        // Viewpoint 0: a near wall on +z hides a far wall behind it; viewpoint 1 sees a far
        // wall on −z only. The hidden wall is the middle of the face: it stays hidden along
        // the short segment (a whole-face far wall would peek out at the edges).
        let mut hidden = tile(0, 1, Face::PosZ, &far[..64], n);
        (hidden.x0, hidden.y0, hidden.width, hidden.height) = (4, 4, 8, 8);
        let tiles = vec![
            tile(0, 0, Face::PosZ, &near, n),
            hidden,
            tile(1, 1, Face::NegZ, &far, n),
            tile(0, 0, Face::PosX, &empty, n),
            tile(7, 0, Face::PosX, &near, n), // another viewpoint: ignored
        ];
        let ach = segment_ach(end(0, 0.0), end(1, 0.1), &tiles, AchParams::default());
        let get = |v: usize, slab: u32| {
            ach.iter()
                .find(|a| a.viewpoint == v && a.slab == slab)
                .map(|a| a.ach)
        };
        assert_eq!(get(0, 1), None, "{ach:?}");
        assert_eq!(get(7, 0), None);
        let (a, b) = (get(0, 0).unwrap(), get(1, 1).unwrap());
        assert!((a + b - 1.0).abs() < 1e-12);
        // Each covers about one face from its own end; blending weights average to ½ each.
        assert!((a - 0.5).abs() < 0.1 && (b - 0.5).abs() < 0.1, "{a} {b}");
    }

    #[test]
    fn nothing_visible_gives_no_entries() {
        let empty = vec![f32::NAN; 4];
        let tiles = vec![tile(0, 0, Face::PosY, &empty, 2)];
        assert!(segment_ach(end(0, 0.0), end(1, 1.0), &tiles, AchParams::default()).is_empty());
        assert!(segment_ach(end(0, 0.0), end(0, 0.0), &[], AchParams::default()).is_empty());
    }
}
