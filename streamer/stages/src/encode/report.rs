//! The build's report (`build.json`, [`BuildReport`]) and its markdown (`build.md`).

use serde::{Deserialize, Serialize};

use crate::knobs::{CullChoice, Knobs, SlabSpec};

/// Bytes at each stage (raw RGBA8 unless stated), and the baseline they are weighed against.
/// A field missing from a report read back (an older build's) reads as 0.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Sizes {
    pub panoramas_rgba: u64,
    pub slab_layers_rgba: u64,
    pub nonempty_tiles_rgba: u64,
    pub kept_tiles_rgba: u64,
    /// The kept tiles' PTMs and meshes as encoded, each tile counted (before payloads
    /// repeated across tiles are stored once).
    pub kept_tiles_ptm: u64,
    pub meshes: u64,
    pub backgrounds_ptm: u64,
    /// Kept tiles, and those with a mesh.
    pub kept_tiles: u64,
    pub meshes_count: u64,
    /// Payloads found already stored (in an earlier pack, or earlier in the same one), and
    /// their bytes, not stored again.
    pub payloads_shared: u64,
    pub bytes_shared: u64,
    pub database_objects: u64,
    /// The baseline: every reference panorama as a PNG of its colour and a 16-bit PNG of
    /// its disparity-quantised depth (`db::baseline`).
    pub baseline_colour_png: u64,
    pub baseline_depth_png16: u64,
    pub baseline: u64,
    /// `database_objects / baseline`.
    pub db_over_baseline: f64,
}

/// One slab's tiles through culling and encoding.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SlabRow {
    pub slab: usize,
    pub tiles_nonempty: usize,
    pub tiles_kept: usize,
    pub rgba_nonempty: u64,
    pub rgba_kept: u64,
    pub ptm_kept: u64,
}

/// The knobs a database was built with, as `build.json`'s `config` writes them (a view of
/// [`Knobs`]: the track's resampling and the zstd level, not the sweep's `every`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BuildConfig {
    pub samples: Option<usize>,
    pub spacing_m: Option<f64>,
    pub face_size: u32,
    pub supersample: u32,
    pub slabs: SlabSpec,
    pub tile_size: u32,
    pub mesh_error_px: f64,
    pub cull_variant: CullChoice,
    pub alpha: f64,
    pub drop_levels: u32,
    pub zstd_level: i32,
}

impl From<&Knobs> for BuildConfig {
    fn from(k: &Knobs) -> BuildConfig {
        BuildConfig {
            samples: k.samples,
            spacing_m: k.spacing_m,
            face_size: k.face_size,
            supersample: k.supersample,
            slabs: k.slabs.clone(),
            tile_size: k.tile_size,
            mesh_error_px: k.mesh_error_px,
            cull_variant: k.cull,
            alpha: k.alpha,
            drop_levels: k.drop_levels,
            zstd_level: k.zstd_level,
        }
    }
}

/// `build.json`: what a build made, how large each stage's output is, and what it cost. A
/// field missing from a report read back (an older build's) reads as its default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BuildReport {
    pub scene: String,
    pub track: String,
    pub face_size: u32,
    pub tile_size: u32,
    pub samples: usize,
    /// The culling the database got, in words (`shrunk, α = 1`).
    pub culling: String,
    /// Where the background behind occluders came from (`prerender::sky::SkySource`, in
    /// lower case: `rendered`, `assembled`, `none`).
    #[serde(default)]
    pub sky: String,
    pub config: BuildConfig,
    pub sizes: Sizes,
    pub slabs: Vec<SlabRow>,
    /// Wall seconds per stage.
    pub seconds: Vec<(String, f64)>,
    /// CPU seconds per stage (this process's threads and the POV-Ray renders it waited
    /// for); a stage that found its outputs already there costs next to nothing.
    pub cpu_seconds: Vec<(String, f64)>,
    pub objects_written: u64,
    pub objects_reused: u64,
    /// Objects of an earlier build into the same directory that the new manifest does not
    /// reference, removed.
    #[serde(default)]
    pub objects_pruned: u64,
    /// With a PSNR target: the target, the choice, what it left out and saved, the sweep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<serde_json::Value>,
}

impl BuildReport {
    /// A stage's wall and CPU seconds, measured since `meter` started.
    pub fn stage_done(&mut self, name: &str, meter: crate::cost::Meter) {
        let (cpu, wall) = meter.stop();
        self.seconds.push((name.into(), wall));
        self.cpu_seconds.push((name.into(), cpu));
    }

    /// `build.md`.
    pub fn markdown(&self) -> String {
        let r = self;
        let s = &r.sizes;
        let mut m = format!(
            "# railview build: {} / {}\n\n{} reference viewpoints, faces {} px, tiles {} px. Culling: {}. Sky behind occluders: {}.\n\n\
             **Database {} = {:.2}× the baseline** ({}: every reference panorama as a PNG of its colour, {}, \
             and a 16-bit PNG of its disparity-quantised depth, {}).\n\n## Sizes per stage\n\n\
             | stage | bytes | of raw panoramas | ÷ baseline |\n|---|---|---|---|\n",
            r.scene,
            r.track,
            r.samples,
            r.face_size,
            r.tile_size,
            r.culling,
            r.sky,
            mib(s.database_objects),
            s.db_over_baseline,
            mib(s.baseline),
            mib(s.baseline_colour_png),
            mib(s.baseline_depth_png16),
        );
        m += &sizes_table(s);
        m += "\n## Culling table\n\n| slab | tiles non-empty | kept | RGBA8 non-empty | RGBA8 kept | PTM kept |\n|---|---|---|---|---|---|\n";
        for row in &r.slabs {
            m += &format!(
                "| {} | {} | {} | {} | {} | {} |\n",
                row.slab,
                row.tiles_nonempty,
                row.tiles_kept,
                mib(row.rgba_nonempty),
                mib(row.rgba_kept),
                mib(row.ptm_kept)
            );
        }
        m += "\n## Timings\n\n| stage | wall seconds | CPU seconds |\n|---|---|---|\n";
        for (name, secs) in &r.seconds {
            let cpu = r
                .cpu_seconds
                .iter()
                .find(|(n, _)| n == name)
                .map_or("–".to_string(), |(_, c)| format!("{c:.1}"));
            m += &format!("| {name} | {secs:.1} | {cpu} |\n");
        }
        let c = &r.config;
        m += &format!(
            "\nConfiguration: samples {}, spacing {}, faces {} px at {}×{} rays per pixel, slabs {}, tiles {} px, mesh error {} px, culling {} α {}, finest texture levels left out {}, zstd {}.\n",
            c.samples.map_or("as the track".into(), |n| n.to_string()),
            c.spacing_m.map_or("as the track".into(), |d| format!("{d} m")),
            c.face_size,
            c.supersample,
            c.supersample,
            c.slabs,
            c.tile_size,
            c.mesh_error_px,
            c.cull_variant,
            c.alpha,
            c.drop_levels,
            c.zstd_level
        );
        m += &format!(
            "\nObjects written {}, reused {} (a rebuild reuses everything already written), \
             {} of an earlier build no longer referenced removed.\n",
            r.objects_written, r.objects_reused, r.objects_pruned
        );
        if let Some(t) = &r.target {
            m += &format!(
                "\n## Chosen for a PSNR target\n\n{}\n\nThe sweep ({} configurations, in {}):\n\n{}",
                t["summary"].as_str().unwrap_or(""),
                t["configurations"],
                t["sweep"].as_str().unwrap_or(""),
                t["table"].as_str().unwrap_or("")
            );
        }
        m
    }
}

fn mib(b: u64) -> String {
    format!("{:.2} MiB", b as f64 / (1024.0 * 1024.0))
}

/// The sizes per stage, and per kept tile.
fn sizes_table(s: &Sizes) -> String {
    let mut m = String::new();
    let base = s.panoramas_rgba.max(1) as f64;
    let baseline = s.baseline.max(1) as f64;
    for (name, b) in [
        ("raw panoramas (RGBA8)", s.panoramas_rgba),
        ("slab layers (RGBA8)", s.slab_layers_rgba),
        ("empty tiles removed (RGBA8)", s.nonempty_tiles_rgba),
        ("culled (RGBA8)", s.kept_tiles_rgba),
        ("PTM compressed (kept tiles)", s.kept_tiles_ptm),
        ("meshes (compact binary)", s.meshes),
        ("backgrounds (PTM)", s.backgrounds_ptm),
        ("repeated payloads stored once (saved)", s.bytes_shared),
        ("database objects on disk", s.database_objects),
        ("baseline: PNG colour", s.baseline_colour_png),
        ("baseline: PNG16 disparity", s.baseline_depth_png16),
        ("baseline", s.baseline),
    ] {
        m += &format!(
            "| {name} | {} | {:.1} % | {:.2}× |\n",
            mib(b),
            100.0 * b as f64 / base,
            b as f64 / baseline
        );
    }
    let per = |b: u64, n: u64| b as f64 / n.max(1) as f64;
    m += &format!(
        "\nPer kept tile: texture {:.0} bytes, mesh {:.0} bytes ({} tiles, {} meshes); {} payloads \
         repeated across tiles stored once.\n",
        per(s.kept_tiles_ptm, s.kept_tiles),
        per(s.meshes, s.meshes_count),
        s.kept_tiles,
        s.meshes_count,
        s.payloads_shared
    );
    m
}
