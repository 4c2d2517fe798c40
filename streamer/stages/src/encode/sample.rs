//! One reference viewpoint encoded: its kept tiles' PTMs and meshes and its sky's tiles,
//! staged as objects, and the record of what produced them (`encode/NNNN.json`).

use rayon::prelude::*;
use std::path::Path;

use codec::mesh::{encode_mesh, MeshCoding};
use codec::ptm::{self, EncodeOptions, Image};
use db::DbWriter;
use occlusion::report::TileDecisions;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use serde::{Deserialize, Serialize};
use slabs::io as sio;
use tracks::manifest::{BackgroundTile, ObjectRef, TileEntry, ViewpointEntry};
use tracks::{CubeMap, TileGrid, TileId};

use crate::error::{Context, Result};

/// What `encode/NNNN.json` holds: a finished viewpoint and what produced it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodedSample {
    /// Everything that decided the objects; a record with another key is encoded again.
    pub key: String,
    pub entry: ViewpointEntry,
    /// Per slab: raw RGBA8 bytes of the non-empty and of the kept tiles, and the non-empty
    /// tiles.
    pub rgba_nonempty: Vec<u64>,
    pub rgba_kept: Vec<u64>,
    pub tiles_nonempty: Vec<usize>,
}

/// How tiles are coded.
pub(super) struct Coding<'a> {
    pub opts: &'a EncodeOptions,
    pub mesh: &'a MeshCoding,
    pub drop_levels: u32,
    /// The track's complete sky at the panoramas' face size (`prerender::sky`), if any.
    pub sky: Option<&'a CubeMap<[u8; 3]>>,
}

fn is_culled(d: Option<&TileDecisions>, viewpoint: usize, slab: usize, index: u32) -> bool {
    let Some(d) = d else { return false };
    d.runs[0]
        .viewpoints
        .iter()
        .find(|v| v.index == viewpoint)
        .and_then(|v| v.slabs.iter().find(|s| s.slab == slab))
        .is_some_and(|s| s.culled.contains(&index))
}

/// Whether a sample's objects are all stored: the background tiles' and the tiles' own PTM
/// and mesh objects in the stage (from which the packs are made).
pub(super) fn all_present(stage: &Path, v: &ViewpointEntry) -> bool {
    let ok = |root: &Path, o: &ObjectRef| {
        o.rel_path()
            .and_then(|r| std::fs::metadata(root.join(r)).ok())
            .is_some_and(|m| m.len() == o.size)
    };
    v.background.iter().all(|b| ok(stage, &b.ptm.object))
        && v.tiles.iter().all(|t| {
            t.ptm.as_ref().is_none_or(|p| ok(stage, &p.object))
                && t.mesh.as_ref().is_none_or(|m| ok(stage, m))
        })
}

/// The pixels of tile `t`, row by row.
pub(super) fn crop<T: Copy>(map: &CubeMap<T>, grid: &TileGrid, t: TileId) -> Vec<T> {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t);
    let mut out = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
    for y in y0..y1 {
        for x in x0..x1 {
            out.push(*map.get(t.face, x, y));
        }
    }
    out
}

/// FNV-1a, 64 bits: a short stable digest (not a security hash).
pub(super) fn fnv64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Encode one viewpoint's kept tiles and sky into staged objects.
/// A kept tile's PTM and, unless it has none, its mesh's bytes.
type Coded = (ptm::Encoded, Option<Vec<u8>>);

pub(super) fn encode_sample(
    dir: &PrerenderDir,
    vp: &tracks::ReferenceViewpoint,
    pre: &PrerenderReport,
    decisions: Option<&TileDecisions>,
    coding: &Coding,
    writer: &mut DbWriter,
    key: &str,
) -> Result<EncodedSample> {
    let i = vp.index;
    let (file, meshes) = sio::read_tiles(dir, i)?;
    let grid = file.grid;
    let mut tiles = Vec::new();
    let (mut rgba_nonempty, mut rgba_kept, mut tiles_nonempty) = (vec![], vec![], vec![]);
    for (layer, layer_meshes) in file.layers.iter().zip(&meshes) {
        let k = layer.slab;
        let color = store::read_rgba_png(&dir.slab_color_png(i, k))?;
        let (mut ne, mut kept_bytes) = (0u64, 0u64);
        // The kept tiles' PTMs and meshes coded in parallel, then stored in tile order.
        let coded: Vec<Option<Result<Coded>>> = layer
            .tiles
            .par_iter()
            .zip(layer_meshes.par_iter())
            .map(|(rec, mesh)| {
                if is_culled(decisions, i, k, grid.tile_index(rec.tile) as u32) {
                    return None;
                }
                let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(rec.tile);
                let code = || -> Result<Coded> {
                    let mut px: Vec<u8> = crop(&color, &grid, rec.tile)
                        .into_iter()
                        .flatten()
                        .collect();
                    slabs::tiles::coarsen_colour(&mut px, x1 - x0, y1 - y0, coding.drop_levels);
                    // Colour 0 under the mask (format 5): coarse levels are colour × coverage.
                    db::clear_masked(&mut px);
                    let img = Image::new(x1 - x0, y1 - y0, 4, px)?;
                    let enc = ptm::encode(&img, coding.opts)?;
                    let mesh_bytes = if mesh.indices.is_empty() {
                        None
                    } else {
                        Some(encode_mesh(mesh, coding.mesh).with_context(|| {
                            format!("sample {i} slab {k} tile {:?}: mesh", rec.tile)
                        })?)
                    };
                    Ok((enc, mesh_bytes))
                };
                Some(code())
            })
            .collect();
        for (rec, coded) in layer.tiles.iter().zip(coded) {
            let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(rec.tile);
            let bytes = ((x1 - x0) * (y1 - y0) * 4) as u64;
            ne += bytes;
            let culled = coded.is_none();
            let (ptm, mesh_ref) = match coded {
                None => (None, None),
                Some(c) => {
                    kept_bytes += bytes;
                    let (enc, mesh_bytes) = c?;
                    let ptm = writer.put_ptm_staged(&enc, 4)?;
                    let mesh_ref = match mesh_bytes {
                        Some(m) => Some(writer.put_staged(&m)?),
                        None => None,
                    };
                    (Some(ptm), mesh_ref)
                }
            };
            tiles.push(TileEntry {
                tile: rec.tile,
                slab: k as u32,
                depth_min: rec.depth_min as f64,
                depth_max: rec.depth_max as f64,
                opaque_pixels: rec.opaque_pixels,
                kept: !culled,
                ptm,
                mesh: mesh_ref,
                mesh_range: None,
            });
        }
        rgba_nonempty.push(ne);
        rgba_kept.push(kept_bytes);
        tiles_nonempty.push(layer.tiles.len());
    }
    let background = background(dir, i, pre.face_size, &grid, coding, writer)?;
    Ok(EncodedSample {
        key: key.to_string(),
        entry: ViewpointEntry {
            index: i,
            s: vp.s,
            position: vp.position,
            background,
            tiles,
        },
        rgba_nonempty,
        rgba_kept,
        tiles_nonempty,
    })
}

/// Background: the panorama's own colour where its depth is infinite (so a view at the
/// sample shows exactly the panorama; alpha [`db::SKY_SEEN_ALPHA`]), elsewhere the track's
/// complete sky (the sky behind this viewpoint's occluders: `prerender::sky`; alpha
/// [`db::SKY_BEHIND_ALPHA`]), cut into the tiles of the same grid.
/// Without a complete sky (no panorama of the track sees any), only the panorama's own sky,
/// and tiles without any are left out. Tiles wholly behind occluders hold the complete sky
/// alone, the same bytes at every viewpoint, stored once.
fn background(
    dir: &PrerenderDir,
    i: usize,
    n: u32,
    grid: &TileGrid,
    coding: &Coding,
    writer: &mut DbWriter,
) -> Result<Vec<BackgroundTile>> {
    let color = store::read_rgb_png(&dir.color_png(i))?;
    let depth = store::read_depth_exr(&dir.depth_exr(i))?;
    let behind = |k: usize| match coding.sky {
        Some(s) => {
            let c = s.as_slice()[k];
            [c[0], c[1], c[2], db::SKY_BEHIND_ALPHA]
        }
        None => [0, 0, 0, 0],
    };
    let sky = CubeMap::from_vec(
        n,
        color
            .as_slice()
            .iter()
            .zip(depth.as_slice())
            .enumerate()
            .map(|(k, (c, d))| {
                if d.is_finite() {
                    behind(k)
                } else {
                    [c[0], c[1], c[2], db::SKY_SEEN_ALPHA]
                }
            })
            .collect(),
    )
    .with_context(|| format!("sample {i}: background size"))?;
    let mut background = Vec::new();
    for face in tracks::Face::ALL {
        for ty in 0..grid.tiles_per_side() {
            for tx in 0..grid.tiles_per_side() {
                let tile = TileId { face, tx, ty };
                let px = crop(&sky, grid, tile);
                if px.iter().all(|p| p[3] == 0) {
                    continue;
                }
                let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
                let mut px: Vec<u8> = px.into_iter().flatten().collect();
                slabs::tiles::coarsen_colour(&mut px, x1 - x0, y1 - y0, coding.drop_levels);
                let img = Image::new(x1 - x0, y1 - y0, 4, px)?;
                let enc = ptm::encode(&img, coding.opts)?;
                background.push(BackgroundTile {
                    tile,
                    ptm: writer.put_ptm_staged(&enc, 4)?,
                });
            }
        }
    }
    Ok(background)
}
