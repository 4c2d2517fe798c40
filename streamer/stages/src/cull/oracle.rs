//! What culling reads and what judges it: a viewpoint's tiles and layers, the track between
//! the viewpoints, the scene's geometry (and whether it is the one the layers show), and the
//! oracle's depth maps.

use glam::DVec3;
use occlusion::{raw_rgba_bytes, SlabLayer, TileInfo};
use prerender::pov::{DepthRequest, PovImport};
use prerender::scene::Scene;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use slabs::io::{self as sio, TilesFile};
use tracks::{CubeMap, TileGrid};

use crate::error::{input, parameter, Context, Result};
use crate::prerender::RenderedBy;

/// Everything loaded for one reference viewpoint.
pub(super) struct Loaded {
    pub index: usize,
    pub grid: TileGrid,
    pub layers: Vec<SlabLayer>,
}

/// The tiles and layers of one viewpoint, from `tiles.json` and the slab layer images.
pub(super) fn load_viewpoint(dir: &PrerenderDir, index: usize) -> Result<Loaded> {
    let jp = sio::tiles_json(dir, index);
    let file: TilesFile = store::read_json(&jp).with_context(|| {
        format!("reading tiles of viewpoint {index} (run `railview slabs` first)")
    })?;
    let grid = file.grid;
    let mut layers = Vec::with_capacity(file.layers.len());
    for rec in &file.layers {
        let (depth, mask) = sio::read_layer(dir, index, rec.slab)?;
        if depth.face_size() != grid.face_size {
            return Err(input!(
                "{}: slab {} layer is {}² but the tile grid is {}²",
                jp.display(),
                rec.slab,
                depth.face_size(),
                grid.face_size
            ));
        }
        let tiles = rec
            .tiles
            .iter()
            .map(|t| TileInfo {
                id: t.tile,
                depth_min: t.depth_min as f64,
                depth_max: t.depth_max as f64,
                bytes: raw_rgba_bytes(&grid, t.tile),
            })
            .collect();
        layers.push(SlabLayer {
            range: rec.range,
            alpha: mask.map(|&m| if m { 255 } else { 0 }),
            depth,
            tiles,
        });
    }
    Ok(Loaded {
        index,
        grid,
        layers,
    })
}

/// Where depth maps from free positions come from (the oracle's, and the rendered
/// variant's).
pub(super) enum OracleSource {
    /// Ray casting through the exact geometry of a built-in or TOML scene.
    Geometry(Box<Scene>),
    /// POV-Ray depth passes (a POV-Ray import), written to a scratch prerender directory
    /// that is removed afterwards.
    Pov {
        import: Box<PovImport>,
        scratch: PrerenderDir,
    },
}

impl OracleSource {
    pub fn load(
        dir: &PrerenderDir,
        pre: &PrerenderReport,
        face_size: Option<u32>,
    ) -> Result<OracleSource> {
        if RenderedBy::of(pre) == RenderedBy::PovRay {
            let scratch = PrerenderDir::new(dir.root().join("cull-oracle"));
            std::fs::remove_dir_all(scratch.root()).ok();
            // The import as it was recorded, at the oracle's face size.
            let mut at_size = pre.clone();
            at_size.face_size = face_size.unwrap_or(pre.face_size);
            at_size.lowres_face_size = pre.lowres_face_size.min(at_size.face_size);
            let import = crate::slabs::pov_import_from_report(&scratch, &at_size)
                .context("POV-Ray depth renders along the track")?;
            return Ok(OracleSource::Pov {
                import: Box::new(import),
                scratch,
            });
        }
        Ok(OracleSource::Geometry(Box::new(load_geometry(pre)?)))
    }

    pub fn name(&self) -> &'static str {
        match self {
            OracleSource::Geometry(_) => "geometry",
            OracleSource::Pov { .. } => "depth-renders (POV-Ray)",
        }
    }

    /// Radial depth seen from each of `positions`, `n` pixels a face side (`None` for one
    /// inside a solid, which sees nothing: a track through an object). `ends`: the
    /// reference viewpoints of the segment they lie on — a POV-Ray import takes the fog
    /// scales from their low-resolution depth (widened by the segment's length: no surface
    /// is nearer to a point of the segment than the nearest one to an end minus that) and
    /// renders the fog-only pass where the scene's fog shows at either end.
    pub fn depths(
        &mut self,
        dir: &PrerenderDir,
        positions: &[DVec3],
        n: u32,
        ends: &[&tracks::ReferenceViewpoint],
    ) -> Result<Vec<Option<CubeMap<f32>>>> {
        match self {
            OracleSource::Geometry(scene) => Ok(positions
                .iter()
                .map(|&x| Some(occlusion::oracle::depth_from_geometry(scene.as_ref(), x, n)))
                .collect()),
            OracleSource::Pov { import, .. } => {
                let (mut lo, mut hi, mut fog) = (f64::INFINITY, 0.0f64, false);
                // The ends' full depth: the witnesses that let positions share a run.
                let mut full = Vec::with_capacity(ends.len());
                for vp in ends {
                    let path = dir.depth_exr(vp.index);
                    let depth = store::read_depth_exr(&path)
                        .with_context(|| format!("reading {}", path.display()))?;
                    full.push((vp.position, depth));
                }
                let witnesses: Vec<(DVec3, &CubeMap<f32>)> =
                    full.iter().map(|(p, d)| (*p, d)).collect();
                for vp in ends {
                    let path = dir.lowres_depth_exr(vp.index);
                    let low = store::read_depth_exr(&path)
                        .with_context(|| format!("reading {}", path.display()))?;
                    for &d in low.as_slice().iter().filter(|d| d.is_finite() && **d > 0.0) {
                        lo = lo.min(d as f64);
                        hi = hi.max(d as f64);
                    }
                    fog |= import
                        .scene_fog(vp)
                        .with_context(|| format!("the scene's fog at viewpoint {}", vp.index))?;
                }
                let reach = ends
                    .iter()
                    .flat_map(|a| positions.iter().map(|p| p.distance(a.position)))
                    .fold(0.0, f64::max);
                let req = DepthRequest {
                    face_size: n,
                    nearest: (lo - reach).max(lo * 1e-3),
                    farthest: hi + reach,
                    fog,
                };
                Ok(import
                    .render_depths(positions, req, &witnesses)
                    .context("POV-Ray depth renders along the track")?)
            }
        }
    }
}

impl Drop for OracleSource {
    fn drop(&mut self) {
        if let OracleSource::Pov { scratch, .. } = self {
            std::fs::remove_dir_all(scratch.root()).ok();
        }
    }
}

/// Whether `scene` is the geometry the layers were rendered from: its first hit from the
/// viewpoint along each pixel centre of a grid of about 4 000 pixels is the depth of the
/// nearest layer opaque there, and lies in no slab's range where every layer is empty (a few
/// per cent may differ where an edge splits a pixel). The shrunk variant's guarantee is
/// about the solids it is given, so a scene file edited since `prerender` must not be used.
pub(super) fn same_geometry(scene: &Scene, position: DVec3, layers: &[SlabLayer]) -> Result<()> {
    let Some(l0) = layers.first() else {
        return Ok(());
    };
    let n = l0.depth.face_size();
    let stride = ((6 * n * n) as f64 / 4000.0).sqrt().ceil().max(1.0) as usize;
    let (mut checked, mut differ) = (0u32, 0u32);
    for face in tracks::Face::ALL {
        for y in (0..n).step_by(stride) {
            for x in (0..n).step_by(stride) {
                let stored = layers
                    .iter()
                    .find(|l| *l.alpha.get(face, x, y) >= 128)
                    .map(|l| *l.depth.get(face, x, y) as f64);
                let dir = tracks::cubemap::pixel_dir(face, x, y, n);
                let hit = scene.first_hit(position, dir, f64::INFINITY);
                checked += 1;
                let same = match (stored, hit) {
                    (Some(d), Some(h)) => (h - d).abs() <= 1e-3 * d + 1e-4,
                    (Some(_), None) => false,
                    (None, Some(h)) => !layers.iter().any(|l| h >= l.range.near && h < l.range.far),
                    (None, None) => true,
                };
                if !same {
                    differ += 1;
                }
            }
        }
    }
    if checked > 0 && differ as f64 > 0.05 * checked as f64 {
        return Err(input!(
            "its first hits differ from the stored depth at {differ} of {checked} pixels: \
             the scene changed since `railview prerender` (render again)"
        ));
    }
    Ok(())
}

/// Exact geometry of a built-in or TOML scene for the oracle.
pub(super) fn load_geometry(pre: &PrerenderReport) -> Result<Scene> {
    if RenderedBy::of(pre) != RenderedBy::Builtin {
        return Err(parameter!(
            "--oracle: scene `{}` was rendered by `{}`; the oracle needs exact geometry \
             (built-in or TOML scenes) or a POV-Ray import (depth rendered by POV-Ray)",
            pre.scene,
            pre.renderer
        ));
    }
    crate::scene::load_geometry(&pre.scene, "--oracle")
}
