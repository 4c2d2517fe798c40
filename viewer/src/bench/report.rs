//! What [`super::Bench::run`] reports: [`BenchResult`] (serialized as the command's JSON,
//! field for field) and its summary lines.

use super::measure::median;
use crate::gpu::Throughput;

/// One timed frame type: median wall-clock and CPU milliseconds per frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VariantTimes {
    pub name: String,
    pub wall_ms: f64,
    /// CPU time of all threads of this process (llvmpipe renders on its own threads), so a
    /// loaded machine inflates it much less than the wall clock; `None` without
    /// `/proc/self/task`.
    pub cpu_ms: Option<f64>,
    /// `wall_ms` and `cpu_ms` over the plain panorama's.
    pub wall_ratio: f64,
    pub cpu_ratio: Option<f64>,
    /// Throughput (`throughput_frames` submitted back to back, one wait): wall ms per
    /// frame, frames per second, and the median GPU time of one frame (timestamp queries;
    /// `None` where the adapter has none).
    pub throughput_ms: Option<f64>,
    pub throughput_fps: Option<f64>,
    pub gpu_ms: Option<f64>,
}

/// The benchmark's result: the frame, the meshes, the load, and per frame type its times.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BenchResult {
    pub adapter: String,
    pub width: u32,
    pub height: u32,
    pub views: usize,
    pub slabs: usize,
    pub triangles: usize,
    /// Triangles drawn at mesh levels 1, 2 (decimated).
    pub coarse_triangles: Vec<usize>,
    /// Triangles of the half-texel skirts (`viewer::refview::skirt`), drawn besides
    /// `triangles` at every mesh level.
    pub skirt_triangles: usize,
    /// Load average (1 min) before and after the run.
    pub load_before: Option<f64>,
    pub load_after: Option<f64>,
    /// The plain panorama first, then every frame type timed.
    pub variants: Vec<VariantTimes>,
    /// With [`super::BenchParams::uploads`]: one tile arriving in slab 0 of the first view.
    pub uploads: Option<Uploads>,
    /// With [`super::BenchParams::fragments`]: mesh fragments of the full frame's view
    /// passes.
    pub fragments: Vec<Fragments>,
}

/// Mesh fragments of one view pass of the full frame ([`crate::cpu::Fragments`]).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Fragments {
    pub view: usize,
    pub pixels: u64,
    pub rasterised: u64,
    pub shaded: u64,
    pub kept: u64,
    pub covered: u64,
}

/// Median milliseconds of one tile arrival, whole layer against the tile's region.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Uploads {
    pub face_size: u32,
    /// CPU: `Layer::from_rgba(dilate_masked(..))` of the whole layer.
    pub layer_rebuild_ms: f64,
    /// CPU: `Layer::update_region` of the tile.
    pub region_update_ms: f64,
    /// Next frame including the upload: the view re-uploaded whole (`invalidate_view`).
    pub frame_after_full_upload_ms: f64,
    /// Next frame after `update_layer_region` of the tile's texels.
    pub frame_after_region_upload_ms: f64,
}

/// Per row (`names`: the plain panorama, then the frame types) its medians and their ratios
/// to the plain panorama's, from the samples `wall` and `cpu` (ms per frame) and the
/// throughput `through`.
pub(super) fn variant_times<'a>(
    names: impl Iterator<Item = &'a str>,
    wall: &[Vec<f64>],
    cpu: &[Vec<f64>],
    through: &[Option<Throughput>],
) -> Vec<VariantTimes> {
    let med = |v: &[f64]| (!v.is_empty()).then(|| median(v));
    let (plain_wall, plain_cpu) = (median(&wall[0]), med(&cpu[0]));
    names
        .zip(wall.iter().zip(cpu))
        .zip(through)
        .map(|((name, (wv, cv)), t)| {
            let (wall_ms, cpu_ms) = (median(wv), med(cv));
            VariantTimes {
                name: name.to_string(),
                wall_ms,
                cpu_ms,
                wall_ratio: wall_ms / plain_wall,
                cpu_ratio: cpu_ms.zip(plain_cpu).map(|(a, b)| a / b),
                throughput_ms: t.map(|t| t.wall_ms),
                throughput_fps: t.map(|t| 1e3 / t.wall_ms),
                gpu_ms: t.and_then(|t| t.gpu_ms),
            }
        })
        .collect()
}

impl BenchResult {
    /// The human-readable lines of the result, each ending in a newline: fragments per
    /// frame pixel, a row per frame type, the tile arrival, the triangles.
    pub fn summary(&self) -> String {
        let mut lines = Vec::new();
        for f in &self.fragments {
            let px = f.pixels.max(1) as f64;
            lines.push(format!(
                "view {} mesh fragments per frame pixel: rasterised {:.2}, shaded (early depth) {:.2}, kept {:.2}; covered {:.2}",
                f.view,
                f.rasterised as f64 / px,
                f.shaded as f64 / px,
                f.kept as f64 / px,
                f.covered as f64 / px
            ));
        }
        let plain_gpu = self.variants.first().and_then(|v| v.gpu_ms);
        for v in &self.variants {
            lines.push(format!(
                "{:<40} {:>8.1} ms wall ({:>4.2}x)  {:>8.1} ms cpu ({:>4.2}x)  throughput {:>7.2} ms ({:>6.1} fps)  gpu {:>7.3} ms ({:>4.2}x)",
                v.name,
                v.wall_ms,
                v.wall_ratio,
                v.cpu_ms.unwrap_or(f64::NAN),
                v.cpu_ratio.unwrap_or(f64::NAN),
                v.throughput_ms.unwrap_or(f64::NAN),
                v.throughput_fps.unwrap_or(f64::NAN),
                v.gpu_ms.unwrap_or(f64::NAN),
                v.gpu_ms.zip(plain_gpu).map_or(f64::NAN, |(a, b)| a / b),
            ));
        }
        if let Some(u) = &self.uploads {
            lines.push(format!(
                "tile arrival at face {}: layer rebuild {:.1} ms, region update {:.3} ms; next frame with full upload {:.1} ms, with region upload {:.1} ms",
                u.face_size,
                u.layer_rebuild_ms,
                u.region_update_ms,
                u.frame_after_full_upload_ms,
                u.frame_after_region_upload_ms
            ));
        }
        lines.push(format!(
            "triangles {} (+ {} of skirts)",
            self.triangles, self.skirt_triangles
        ));
        lines.iter().map(|l| format!("{l}\n")).collect()
    }
}
