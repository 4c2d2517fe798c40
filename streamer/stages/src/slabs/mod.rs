//! The slabs stage: slab boundaries chosen (from layers already rendered, the
//! [`SlabSpec`], or the low-resolution depth), missing slab layers rendered (built-in scenes
//! with the built-in tracer, POV-Ray imports with POV-Ray, re-created from what the import
//! recorded in `prerender.json`), every layer tiled and meshed, tiles files and the report
//! (`slabs.json`, `slabs.md`, the depth histogram) written.

mod layers;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use prerender::runlog::RunLog;
use prerender::store::{self, LayersMeta, PrerenderDir, PrerenderReport};
use slabs::boundaries::{self, ChooseParams, SlabChoice};
use slabs::io as sio;
use slabs::mesh::MeshParams;
use slabs::report::SlabsReport;
use slabs::tiles::{tile_sample, LayerInput, MeshKind, TileParams};
use tracks::SlabRange;

pub(crate) use layers::pov_import_from_report;

use crate::error::{input, parameter, Context, Result};
use crate::knobs::SlabSpec;
use crate::prerender::labels;
use crate::progress::{BarKind, Reporter};

/// The stage's default tile side, pixels.
pub const DEFAULT_TILE_SIZE: u32 = 32;
/// The stage's default grid step of the regular mesh, pixels.
pub const DEFAULT_MESH_STEP: u32 = 4;
/// The stage's default error bound of the adaptive mesh, parallax pixels.
pub const DEFAULT_MESH_ERROR: f64 = 0.5;

/// How every slab layer is cut into tiles and meshed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tiling {
    /// Tile side in pixels (a power of two).
    pub tile_size: u32,
    /// Which mesh the tiles file stores (both are measured).
    pub mesh: MeshKind,
    /// Grid step of the regular mesh, pixels.
    pub mesh_step: u32,
    /// Error bound of the adaptive mesh: parallax pixels at the track's largest baseline.
    pub mesh_error_px: f64,
    /// Parallax (pixels at the largest baseline) that makes neighbouring pixels a
    /// discontinuity.
    pub discontinuity_px: f64,
}

impl Default for Tiling {
    fn default() -> Self {
        Tiling {
            tile_size: DEFAULT_TILE_SIZE,
            mesh: MeshKind::Adaptive,
            mesh_step: DEFAULT_MESH_STEP,
            mesh_error_px: DEFAULT_MESH_ERROR,
            discontinuity_px: 1.0,
        }
    }
}

/// What the slabs stage does to a prerender directory.
#[derive(Clone, Debug, PartialEq)]
pub struct SlabsParams {
    /// The prerender directory.
    pub dir: PathBuf,
    pub slabs: SlabSpec,
    /// Pixels of parallax above which a histogram valley becomes a boundary.
    pub threshold_px: f64,
    pub tiling: Tiling,
    /// Choose the boundaries and render the missing layers, but do not tile them.
    pub layers_only: bool,
}

impl SlabsParams {
    /// The stage's defaults on `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> SlabsParams {
        SlabsParams {
            dir: dir.into(),
            slabs: SlabSpec::default(),
            threshold_px: 1.0,
            tiling: Tiling::default(),
            layers_only: false,
        }
    }

    /// The command line a person would type to run this stage (after `railview`), for
    /// reports and messages; never parsed.
    pub fn command_line(&self) -> Vec<String> {
        let t = &self.tiling;
        let mut v = vec![
            "slabs".into(),
            self.dir.display().to_string(),
            "--slabs".into(),
            self.slabs.to_string(),
        ];
        if self.layers_only {
            v.push("--layers-only".into());
        } else {
            let mesh = match t.mesh {
                MeshKind::Adaptive => "adaptive",
                MeshKind::Grid => "grid",
            };
            v.extend([
                "--tile-size".into(),
                t.tile_size.to_string(),
                "--mesh".into(),
                mesh.into(),
                "--mesh-step".into(),
                t.mesh_step.to_string(),
                "--mesh-error".into(),
                t.mesh_error_px.to_string(),
            ]);
        }
        if t.discontinuity_px != 1.0 {
            v.extend(["--discontinuity".into(), t.discontinuity_px.to_string()]);
        }
        if self.threshold_px != 1.0 {
            v.extend(["--threshold-px".into(), self.threshold_px.to_string()]);
        }
        v
    }
}

/// What the slabs stage did.
#[derive(Clone, Debug)]
pub struct Slabbed {
    /// The slab boundaries the layers have.
    pub slabs: Vec<SlabRange>,
    /// Samples whose layers were rendered now.
    pub layers_rendered: usize,
    /// The report (`slabs.json`); none with [`SlabsParams::layers_only`].
    pub report: Option<SlabsReport>,
}

fn check_tiling(t: &Tiling) -> Result<()> {
    if !t.tile_size.is_power_of_two() {
        return Err(parameter!(
            "--tile-size {}: must be a power of two",
            t.tile_size
        ));
    }
    crate::check_face_size("--tile-size", t.tile_size)?;
    crate::check_count("--mesh-step", t.mesh_step as usize, 4096)?;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if t.mesh_step == 0 || !positive(t.mesh_error_px) || !positive(t.discontinuity_px) {
        return Err(parameter!(
            "--mesh-step, --mesh-error and --discontinuity must be positive"
        ));
    }
    Ok(())
}

/// Run the slabs stage.
pub fn run(params: &SlabsParams, progress: &Reporter) -> Result<Slabbed> {
    let t0 = Instant::now();
    let dir = PrerenderDir::new(&params.dir);
    let pre: PrerenderReport = dir
        .read_report()
        .context("reading the prerender report (run `railview prerender` first)")?;
    let log = Arc::new(RunLog::create(dir.root(), "slabs", None)?);
    check_tiling(&params.tiling)?;
    let indices: Vec<usize> = pre.viewpoints.iter().map(|v| v.index).collect();
    if indices.is_empty() {
        return Err(input!("{}: no viewpoints", dir.report_json().display()));
    }
    // The longest segment of the network (of the track: consecutive viewpoints).
    let net = crate::network::network_of(&dir, &pre)?;
    let max_spacing = net
        .segments
        .iter()
        .map(|sg| net.viewpoints[sg.from].distance(net.viewpoints[sg.to]))
        .fold(0.0, f64::max);
    let existing: Vec<Option<LayersMeta>> = indices.iter().map(|&i| dir.layers_meta(i)).collect();
    let choice = choose(params, &dir, &pre, &indices, &existing, max_spacing)?;
    progress.message(&choice.criterion.summary);

    // Render the layers that are missing.
    let missing: Vec<usize> = indices
        .iter()
        .zip(&existing)
        .filter(|(_, m)| m.as_ref().map(|m| &m.slabs) != Some(&choice.slabs))
        .map(|(&i, _)| i)
        .collect();
    if !missing.is_empty() && !choice.slabs.is_empty() {
        layers::render(&dir, &pre, &choice.slabs, &missing, &log, progress)?;
    }
    let mut done = Slabbed {
        slabs: choice.slabs.clone(),
        layers_rendered: missing.len(),
        report: None,
    };
    if params.layers_only {
        progress.message(&format!(
            "layers {} rendered; tiles left to a later run",
            labels(&choice.slabs)
        ));
        return Ok(done);
    }
    let t = &params.tiling;
    let mesh = MeshParams {
        step: t.mesh_step,
        max_error_px: t.mesh_error_px,
        baseline_m: max_spacing,
        discontinuity_px: t.discontinuity_px,
    };
    let tp = TileParams {
        tile_size: t.tile_size,
        mesh,
        keep: t.mesh,
        measure_both: true,
    };
    let mut report = SlabsReport::new(&choice, pre.face_size, t.tile_size, mesh, t.mesh);
    let resumed = tile_all(&dir, &pre, &choice, &tp, &missing, &mut report, progress)?;
    if resumed > 0 {
        progress.message(&format!(
            "{resumed} sample(s) already tiled with these parameters: kept"
        ));
    }
    report.seconds = t0.elapsed().as_secs_f64();
    log.end(&[
        ("samples", indices.len().into()),
        ("layers_rendered", missing.len().into()),
        ("tiled", (indices.len() - resumed).into()),
        ("tiles_kept_from_before", resumed.into()),
    ])?;
    write_report(&dir, &choice, &report, progress)?;
    done.report = Some(report);
    Ok(done)
}

/// The slab boundaries: from layers already rendered, the spec, or the low-res depth.
fn choose(
    params: &SlabsParams,
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    indices: &[usize],
    existing: &[Option<LayersMeta>],
    max_spacing: f64,
) -> Result<SlabChoice> {
    let choose_params = ChooseParams {
        threshold_px: params.threshold_px,
        ..ChooseParams::default()
    };
    let rendered: Option<Vec<SlabRange>> =
        existing.iter().flatten().next().map(|m| m.slabs.clone());
    // One low-resolution depth map in memory at a time (read twice): all of town-10's
    // 10 256 took 1 GB.
    let auto = boundaries::choose_streamed(
        indices.len(),
        |k| sio::read_lowres(dir, indices[k]),
        max_spacing,
        pre.face_size,
        &choose_params,
    )
    .context("reading the low-resolution depth passes")?;
    let want: Option<Vec<SlabRange>> = match &params.slabs {
        SlabSpec::Auto(0) => None,
        SlabSpec::Auto(d) => Some(boundaries::adjust(&auto, *d)),
        SlabSpec::Ranges(l) => Some(l.clone()),
    };
    let given = |slabs: Vec<SlabRange>, auto: SlabChoice| {
        let mut c = auto;
        c.criterion.manual = true;
        c.criterion.summary = format!(
            "{} slab(s) from --slabs {}; the automatic choice is {} ({})",
            slabs.len(),
            params.slabs,
            c.slabs.len(),
            c.criterion.summary
        );
        c.slabs = slabs;
        c
    };
    Ok(match (&rendered, want) {
        (Some(slabs), want) => {
            if let Some(want) = want.filter(|w| !same_ranges(w, slabs)) {
                return Err(parameter!(
                    "the samples already have slab layers {}; remove the slab_K directories and layers.json to render {}",
                    labels(slabs),
                    labels(&want)
                ));
            }
            // Layers rendered from the automatic choice keep its numbers in the report.
            if same_ranges(&auto.slabs, slabs) {
                SlabChoice {
                    slabs: slabs.clone(),
                    ..auto
                }
            } else {
                given(slabs.clone(), auto)
            }
        }
        (None, None) => auto,
        (None, Some(want)) => given(want, auto),
    })
}

/// Tile every sample (those whose tiles files match the parameters are kept); returns how
/// many were kept.
fn tile_all(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    choice: &SlabChoice,
    tp: &TileParams,
    missing: &[usize],
    report: &mut SlabsReport,
    progress: &Reporter,
) -> Result<usize> {
    let bar = progress.bar(pre.viewpoints.len() as u64, "tiling", BarKind::Steps);
    let mut resumed = 0usize;
    for i in pre.viewpoints.iter().map(|v| v.index) {
        let digest = layers_digest(dir, i, choice.slabs.len())?;
        // Resume: a sample whose tiles files match these parameters and layers is not tiled
        // again.
        if let Ok((file, _)) = sio::read_tiles(dir, i) {
            // Tiles cut from panoramas of another face size (a work directory prerendered
            // again) are stale.
            let same = file.grid.tile_size == tp.tile_size
                && file.grid.face_size == pre.face_size
                && file.mesh_params == tp.mesh
                && file.mesh_kind == tp.keep
                && file
                    .layers
                    .iter()
                    .map(|l| l.range)
                    .eq(choice.slabs.iter().copied())
                && file.layers_digest == digest
                && !missing.contains(&i);
            if same {
                report.add_tiles_file(&file);
                resumed += 1;
                bar.inc(1);
                continue;
            }
        }
        let layers = (0..choice.slabs.len())
            .map(|k| sio::read_layer(dir, i, k))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        let inputs: Vec<LayerInput> = layers
            .iter()
            .map(|(depth, mask)| LayerInput { depth, mask })
            .collect();
        let tiles = tile_sample(i, &inputs, tp).with_context(|| format!("sample {i}: tiling"))?;
        let (mut file, bin) = sio::encode_tiles(&tiles, &choice.slabs, tp.mesh, tp.keep);
        file.layers_digest = digest;
        sio::write_tiles(dir, i, &file, &bin)?;
        report.add_sample(&tiles);
        bar.inc(1);
    }
    bar.finish();
    Ok(resumed)
}

/// BLAKE3 of sample `i`'s slab layer files (colour and depth of each of `slabs`): tiles cut
/// from other layers (a sample's layers rendered again) are stale. A missing file counts as
/// empty; tiling then reports it.
fn layers_digest(dir: &PrerenderDir, i: usize, slabs: usize) -> Result<String> {
    let mut h = blake3::Hasher::new();
    for k in 0..slabs {
        for path in [dir.slab_color_png(i, k), dir.slab_depth_exr(i, k)] {
            match std::fs::read(&path) {
                Ok(bytes) => {
                    h.update(&(bytes.len() as u64).to_le_bytes());
                    h.update(&bytes);
                }
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    h.update(&u64::MAX.to_le_bytes());
                }
                Err(e) => {
                    return Err(e).with_context(|| format!("reading {}", path.display()));
                }
            }
        }
    }
    Ok(h.finalize().to_hex().to_string())
}

/// `slabs.json`, `slabs.md` and the histogram figure.
fn write_report(
    dir: &PrerenderDir,
    choice: &SlabChoice,
    report: &SlabsReport,
    progress: &Reporter,
) -> Result<()> {
    let root = dir.root();
    store::write_json(&root.join("slabs.json"), report)?;
    store::write_atomic(&root.join("slabs.md"), report.markdown().as_bytes())?;
    let rejected: Vec<f64> = choice
        .criterion
        .candidates
        .iter()
        .filter(|c| !c.accepted)
        .map(|c| c.depth_m)
        .collect();
    let fig = slabs::plot::histogram_figure(&choice.histogram, &choice.slabs, &rejected);
    store::write_atomic(&root.join("histogram.svg"), charts::svg(&fig)?.as_bytes())?;
    store::write_atomic(&root.join("histogram.png"), &charts::png(&fig)?)?;
    for (k, s) in report.slabs.iter().enumerate() {
        progress.message(&format!(
            "slab {k} {}: tiles {} -> {}, adaptive mesh {} triangles (max {:.3} px), grid {} triangles (max {:.3} px)",
            SlabRange { near: s.near, far: s.far }.label(),
            s.tiles_before,
            s.tiles_after,
            s.adaptive_mesh.triangles,
            s.adaptive_mesh.max_error_px,
            s.grid_mesh.triangles,
            s.grid_mesh.max_error_px
        ));
    }
    progress.message(&format!("wrote {}", root.join("slabs.json").display()));
    Ok(())
}

/// Equal up to JSON round-off (ranges read back from `layers.json`).
fn same_ranges(a: &[SlabRange], b: &[SlabRange]) -> bool {
    let close = |x: f64, y: f64| x == y || (x - y).abs() <= 1e-9 * x.abs().max(y.abs());
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(p, q)| close(p.near, q.near) && close(p.far, q.far))
}
