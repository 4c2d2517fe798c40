//! The per-sample tiles files that `cull` and `build` read, and reading slab layers.
//!
//! ```text
//! DIR/samples/NNNN/tiles.bin    meshes of every kept tile, back to back (little-endian):
//!                               magic "RVTMESH1", then per tile `vertex_count` × [f32; 3]
//!                               (x, y face pixels, radial metres) and `index_count` × u32
//! DIR/samples/NNNN/tiles.json   TilesFile: grid, mesh parameters, and per slab the kept
//!                               tiles with depth range, opaque pixels and the byte offset and
//!                               counts of their mesh in tiles.bin (written last: the marker)
//! ```
//!
//! Opacity masks are not repeated: they are the alpha of `slab_K/color.png`.

use prerender::store::{self, PrerenderDir, StoreError};
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, SlabRange, TileGrid, TileId};

use crate::mesh::{MeshParams, MeshStats, TileMesh};
use crate::tiles::{mask_from_layer, MeshKind, SampleTiles};
use crate::SlabsError;

/// Magic at the start of `tiles.bin`.
pub const MESH_MAGIC: &[u8; 8] = b"RVTMESH1";
/// Value of [`TilesFile::format`].
pub const TILES_FORMAT: &str = "railview-tiles-1";

/// One kept tile in `tiles.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileRecord {
    pub tile: TileId,
    pub depth_min: f32,
    pub depth_max: f32,
    pub opaque_pixels: u32,
    pub pixels: u32,
    /// Byte offset of this tile's vertices in `tiles.bin`.
    pub mesh_offset: u64,
    pub vertex_count: u32,
    pub index_count: u32,
    pub grid_stats: MeshStats,
    pub adaptive_stats: MeshStats,
}

/// One slab layer in `tiles.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerRecord {
    pub slab: usize,
    pub range: SlabRange,
    pub tiles_before: usize,
    pub tiles: Vec<TileRecord>,
}

/// `tiles.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TilesFile {
    pub format: String,
    pub viewpoint: usize,
    pub grid: TileGrid,
    pub mesh_params: MeshParams,
    /// Which mesh `tiles.bin` holds.
    pub mesh_kind: MeshKind,
    /// Length of `tiles.bin`.
    pub mesh_bytes: u64,
    pub layers: Vec<LayerRecord>,
    /// A digest of the slab layer files the tiles were cut from, set by the caller (the
    /// build's slabs stage: BLAKE3 of every `slab_K/color.png` and `depth.exr`): layers
    /// rendered again make the tiles stale.
    #[serde(default)]
    pub layers_digest: String,
}

/// Encode the meshes of `tiles` into `tiles.bin` bytes and the matching `tiles.json`.
pub fn encode_tiles(
    tiles: &SampleTiles,
    ranges: &[SlabRange],
    mesh_params: MeshParams,
    mesh_kind: MeshKind,
) -> (TilesFile, Vec<u8>) {
    let mut bin = MESH_MAGIC.to_vec();
    let mut layers = Vec::new();
    for l in &tiles.layers {
        let mut recs = Vec::with_capacity(l.tiles.len());
        for t in &l.tiles {
            let offset = bin.len() as u64;
            for v in &t.mesh.vertices {
                for c in v {
                    bin.extend_from_slice(&c.to_le_bytes());
                }
            }
            for i in &t.mesh.indices {
                bin.extend_from_slice(&i.to_le_bytes());
            }
            recs.push(TileRecord {
                tile: t.tile,
                depth_min: t.depth_min,
                depth_max: t.depth_max,
                opaque_pixels: t.opaque_pixels,
                pixels: t.pixels,
                mesh_offset: offset,
                vertex_count: t.mesh.vertices.len() as u32,
                index_count: t.mesh.indices.len() as u32,
                grid_stats: t.grid_stats,
                adaptive_stats: t.adaptive_stats,
            });
        }
        layers.push(LayerRecord {
            slab: l.slab,
            range: ranges.get(l.slab).copied().unwrap_or(SlabRange {
                near: 0.0,
                far: f64::INFINITY,
            }),
            tiles_before: l.tiles_before,
            tiles: recs,
        });
    }
    let file = TilesFile {
        format: TILES_FORMAT.into(),
        viewpoint: tiles.viewpoint,
        grid: tiles.grid,
        mesh_params,
        mesh_kind,
        mesh_bytes: bin.len() as u64,
        layers,
        layers_digest: String::new(),
    };
    (file, bin)
}

/// Decode the mesh of one tile record from `tiles.bin` bytes; `what` names the file.
pub fn decode_mesh(rec: &TileRecord, bin: &[u8], what: &str) -> Result<TileMesh, SlabsError> {
    let err = |m: String| SlabsError::Format {
        what: what.to_string(),
        message: format!(
            "tile {} ({}, {}): {m}",
            rec.tile.face.short_name(),
            rec.tile.tx,
            rec.tile.ty
        ),
    };
    if bin.len() < 8 || &bin[..8] != MESH_MAGIC {
        return Err(err("missing magic RVTMESH1".into()));
    }
    let nv = rec.vertex_count as usize;
    let ni = rec.index_count as usize;
    let start = usize::try_from(rec.mesh_offset).map_err(|_| err("offset too large".into()))?;
    let len = nv
        .checked_mul(12)
        .and_then(|a| a.checked_add(ni.checked_mul(4)?))
        .ok_or_else(|| err("counts overflow".into()))?;
    let end = start
        .checked_add(len)
        .filter(|&e| e <= bin.len() && start >= 8)
        .ok_or_else(|| {
            err(format!(
                "mesh bytes {start}..{} outside the file of {} bytes",
                start.saturating_add(len),
                bin.len()
            ))
        })?;
    if !ni.is_multiple_of(3) {
        return Err(err(format!("index count {ni} is not a multiple of 3")));
    }
    let b = &bin[start..end];
    let f = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let vertices: Vec<[f32; 3]> = (0..nv)
        .map(|v| [f(12 * v), f(12 * v + 4), f(12 * v + 8)])
        .collect();
    let base = 12 * nv;
    let indices: Vec<u32> = (0..ni)
        .map(|i| {
            let o = base + 4 * i;
            u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
        })
        .collect();
    if let Some(bad) = indices.iter().find(|&&i| i as usize >= nv) {
        return Err(err(format!("index {bad} >= vertex count {nv}")));
    }
    if let Some(v) = vertices.iter().find(|v| !v.iter().all(|c| c.is_finite())) {
        return Err(err(format!("vertex {v:?} is not finite")));
    }
    Ok(TileMesh { vertices, indices })
}

/// Paths of the tiles files of one sample.
pub fn tiles_json(dir: &PrerenderDir, index: usize) -> std::path::PathBuf {
    dir.sample_dir(index).join("tiles.json")
}

pub fn tiles_bin(dir: &PrerenderDir, index: usize) -> std::path::PathBuf {
    dir.sample_dir(index).join("tiles.bin")
}

/// Write `tiles.bin` then `tiles.json` (the completion marker), each atomically.
pub fn write_tiles(
    dir: &PrerenderDir,
    index: usize,
    file: &TilesFile,
    bin: &[u8],
) -> Result<(), StoreError> {
    store::write_atomic(&tiles_bin(dir, index), bin)?;
    store::write_json(&tiles_json(dir, index), file)
}

/// Read `tiles.json` and every mesh from `tiles.bin` of one sample (meshes in record order,
/// layer by layer).
pub fn read_tiles(
    dir: &PrerenderDir,
    index: usize,
) -> Result<(TilesFile, Vec<Vec<TileMesh>>), SlabsError> {
    let jp = tiles_json(dir, index);
    let file: TilesFile = store::read_json(&jp).map_err(|e| SlabsError::Format {
        what: jp.display().to_string(),
        message: e.to_string(),
    })?;
    if file.format != TILES_FORMAT {
        return Err(SlabsError::Format {
            what: jp.display().to_string(),
            message: format!("format `{}`, expected `{TILES_FORMAT}`", file.format),
        });
    }
    let bp = tiles_bin(dir, index);
    let bin = std::fs::read(&bp).map_err(|e| SlabsError::Format {
        what: bp.display().to_string(),
        message: e.to_string(),
    })?;
    let what = bp.display().to_string();
    let meshes = file
        .layers
        .iter()
        .map(|l| {
            l.tiles
                .iter()
                .map(|t| decode_mesh(t, &bin, &what))
                .collect()
        })
        .collect::<Result<Vec<Vec<TileMesh>>, _>>()?;
    Ok((file, meshes))
}

/// Read slab layer `slab` of sample `index`: depth and the opacity mask from colour alpha.
/// NaN or negative depth is an error naming the file and pixel.
pub fn read_layer(
    dir: &PrerenderDir,
    index: usize,
    slab: usize,
) -> Result<(CubeMap<f32>, CubeMap<bool>), StoreError> {
    let dp = dir.slab_depth_exr(index, slab);
    let depth = store::read_depth_exr(&dp)?;
    let cp = dir.slab_color_png(index, slab);
    let color = store::read_rgba_png(&cp)?;
    if color.face_size() != depth.face_size() {
        return Err(StoreError::Format {
            path: cp,
            message: format!(
                "face size {} differs from {} of {}",
                color.face_size(),
                depth.face_size(),
                dp.display()
            ),
        });
    }
    let mask = mask_from_layer(&color, &depth);
    Ok((depth, mask))
}

/// Read the low-resolution depth of sample `index`.
pub fn read_lowres(dir: &PrerenderDir, index: usize) -> Result<CubeMap<f32>, StoreError> {
    store::read_depth_exr(&dir.lowres_depth_exr(index))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tiles::{tile_sample, LayerInput, TileParams};
    use proptest::prelude::*;
    use tracks::Face;

    fn tmpdir(name: &str) -> PrerenderDir {
        let d = std::env::temp_dir().join(format!("railview-slabs-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&d).ok();
        std::fs::create_dir_all(&d).unwrap();
        PrerenderDir::new(d)
    }

    fn params() -> TileParams {
        TileParams {
            tile_size: 4,
            mesh: MeshParams::default(),
            keep: MeshKind::Adaptive,
            measure_both: true,
        }
    }

    #[test]
    fn tiles_files_round_trip() {
        let depth = CubeMap::from_fn(8, |f, x, y| {
            if f == Face::NegZ || x + y < 3 {
                f32::INFINITY
            } else {
                2.0 + x as f32 * 0.1 + (y * y) as f32 * 0.05
            }
        });
        let mask = depth.map(|d| d.is_finite());
        let st = tile_sample(
            7,
            &[LayerInput {
                depth: &depth,
                mask: &mask,
            }],
            &params(),
        )
        .unwrap();
        let ranges = [SlabRange::new(0.0, f64::INFINITY).unwrap()];
        let (file, bin) = encode_tiles(&st, &ranges, MeshParams::default(), MeshKind::Adaptive);
        let dir = tmpdir("roundtrip");
        write_tiles(&dir, 7, &file, &bin).unwrap();
        let (back, meshes) = read_tiles(&dir, 7).unwrap();
        // Floats in JSON may differ in the last bit; compare what locates the meshes exactly.
        let key = |f: &TilesFile| -> Vec<_> {
            f.layers[0]
                .tiles
                .iter()
                .map(|t| {
                    (
                        t.tile,
                        t.mesh_offset,
                        t.vertex_count,
                        t.index_count,
                        t.depth_min,
                        t.depth_max,
                    )
                })
                .collect()
        };
        assert_eq!(key(&back), key(&file));
        assert_eq!((back.grid, back.mesh_bytes), (file.grid, file.mesh_bytes));
        let want: Vec<&TileMesh> = st.layers[0].tiles.iter().map(|t| &t.mesh).collect();
        assert_eq!(meshes[0].iter().collect::<Vec<_>>(), want);
        // Face −z is all sky: its 4 tiles are removed; the sky corners leave other tiles partly opaque.
        assert_eq!(file.layers[0].tiles_before, 24);
        assert_eq!(file.layers[0].tiles.len(), 20);
    }

    #[test]
    fn corrupt_mesh_bytes_name_the_tile() {
        let rec = TileRecord {
            tile: TileId {
                face: Face::PosY,
                tx: 1,
                ty: 2,
            },
            depth_min: 1.0,
            depth_max: 1.0,
            opaque_pixels: 1,
            pixels: 1,
            mesh_offset: 8,
            vertex_count: 3,
            index_count: 3,
            grid_stats: MeshStats::default(),
            adaptive_stats: MeshStats::default(),
        };
        let mut bin = MESH_MAGIC.to_vec();
        bin.extend([0u8; 36]);
        for i in [0u32, 1, 9] {
            bin.extend(i.to_le_bytes());
        }
        let e = decode_mesh(&rec, &bin, "t.bin").unwrap_err().to_string();
        assert!(
            e.contains("t.bin") && e.contains("py (1, 2)") && e.contains("index 9"),
            "{e}"
        );
        let e = decode_mesh(&rec, &bin[..40], "t.bin")
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside the file"), "{e}");
    }

    #[test]
    fn nan_or_negative_depth_in_an_imported_layer_names_file_and_pixel() {
        let dir = tmpdir("nan");
        for (bad, name) in [(f32::NAN, "NaN"), (-3.0, "-3")] {
            let mut depth = CubeMap::filled(4, 5.0f32);
            *depth.get_mut(Face::PosZ, 1, 2) = bad;
            store::write_depth_exr(&dir.slab_depth_exr(0, 1), &depth).unwrap();
            let color = CubeMap::filled(4, [9u8, 9, 9, 255]);
            store::write_atomic(&dir.slab_color_png(0, 1), &store::encode_rgba_png(&color))
                .unwrap();
            let e = read_layer(&dir, 0, 1).unwrap_err().to_string();
            assert!(
                e.contains("slab_1")
                    && e.contains("depth.exr")
                    && e.contains("(1, 2)")
                    && e.contains("pz")
                    && e.contains(name),
                "{e}"
            );
        }
    }

    proptest! {
        #[test]
        fn mesh_bytes_round_trip(
            verts in prop::collection::vec(prop::array::uniform3(-1e6f32..1e6), 1..20),
            tris in prop::collection::vec(prop::array::uniform3(0u32..1000), 0..20),
        ) {
            let nv = verts.len() as u32;
            let indices: Vec<u32> = tris.iter().flat_map(|t| t.map(|i| i % nv)).collect();
            let mesh = TileMesh { vertices: verts, indices };
            let st = SampleTiles {
                viewpoint: 0,
                grid: TileGrid::new(4, 4).unwrap(),
                layers: vec![crate::tiles::LayerTiles {
                    slab: 0,
                    tiles_before: 6,
                    tiles: vec![crate::tiles::SlabTile {
                        viewpoint: 0,
                        slab: 0,
                        tile: TileId { face: Face::PosX, tx: 0, ty: 0 },
                        depth_min: 1.0,
                        depth_max: 2.0,
                        opaque_pixels: 3,
                        pixels: 16,
                        mask: vec![7, 0],
                        mesh: mesh.clone(),
                        grid_stats: MeshStats::default(),
                        adaptive_stats: MeshStats::default(),
                    }],
                }],
            };
            let (file, bin) = encode_tiles(&st, &[], MeshParams::default(), MeshKind::Grid);
            let back = decode_mesh(&file.layers[0].tiles[0], &bin, "x").unwrap();
            prop_assert_eq!(back, mesh);
        }
    }
}
