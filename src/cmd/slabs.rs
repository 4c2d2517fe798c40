//! `railview slabs DIR`: choose slab boundaries, render missing slab layers (built-in
//! scenes with the built-in tracer, POV-Ray imports with POV-Ray, re-created from what
//! `import-pov` recorded in `prerender.json`), tile and mesh every layer, write tiles files
//! and the report.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use prerender::runlog::{LayersTiming, RunEvent, RunLog};
use prerender::store::{self, LayersMeta, PrerenderDir, PrerenderReport};
use slabs::boundaries::{self, ChooseParams, SlabChoice};
use slabs::io as sio;
use slabs::mesh::MeshParams;
use slabs::report::SlabsReport;
use slabs::tiles::{tile_sample, LayerInput, MeshKind, TileParams};
use tracks::{CubeMap, SlabRange};

/// The stage's defaults (`railview build` compares a work directory's tiles with them).
pub const DEFAULT_TILE_SIZE: u32 = 32;
pub const DEFAULT_MESH_STEP: u32 = 4;
pub const DEFAULT_MESH_ERROR: f64 = 0.5;
pub const DEFAULT_MESH: &str = "adaptive";

/// Arguments of `railview slabs`.
#[derive(clap::Args)]
pub struct Args {
    /// Prerender directory (written by `railview prerender` or `import-pov`).
    pub dir: PathBuf,
    /// Tile side in pixels (a power of two).
    #[arg(long, default_value_t = DEFAULT_TILE_SIZE)]
    pub tile_size: u32,
    /// Grid step of the regular mesh, pixels.
    #[arg(long, default_value_t = DEFAULT_MESH_STEP)]
    pub mesh_step: u32,
    /// Error bound of the adaptive mesh: parallax pixels at the track's largest baseline.
    #[arg(long, default_value_t = DEFAULT_MESH_ERROR)]
    pub mesh_error: f64,
    /// Which mesh tiles.bin stores: `adaptive` or `grid` (both are measured).
    #[arg(long, default_value = DEFAULT_MESH)]
    pub mesh: String,
    /// Parallax (pixels at the largest baseline) that makes neighbouring pixels a discontinuity.
    #[arg(long, default_value_t = 1.0)]
    pub discontinuity: f64,
    /// `auto`; `fewer` / `more` (the automatic choice with one boundary fewer or more;
    /// `auto-N`, `auto+N` for N); or slab ranges `0-1000,1000-10000,10000-inf` (metres).
    #[arg(long, default_value = "auto")]
    pub slabs: String,
    /// Choose the boundaries and render the missing layers, but do not tile them.
    #[arg(long)]
    pub layers_only: bool,
    /// Pixels of parallax above which a histogram valley becomes a boundary.
    #[arg(long, default_value_t = 1.0)]
    pub threshold_px: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let dir = PrerenderDir::new(&args.dir);
    let pre: PrerenderReport = dir
        .read_report()
        .context("reading the prerender report (run `railview prerender` first)")?;
    let log = Arc::new(RunLog::create(dir.root(), "slabs", None)?);
    let keep = match args.mesh.as_str() {
        "adaptive" => MeshKind::Adaptive,
        "grid" => MeshKind::Grid,
        other => bail!("--mesh `{other}`: expected `adaptive` or `grid`"),
    };
    if !args.tile_size.is_power_of_two() {
        bail!("--tile-size {}: must be a power of two", args.tile_size);
    }
    super::face_size("--tile-size", args.tile_size)?;
    super::count("--mesh-step", args.mesh_step as usize, 4096)?;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if args.mesh_step == 0 || !positive(args.mesh_error) || !positive(args.discontinuity) {
        bail!("--mesh-step, --mesh-error and --discontinuity must be positive");
    }
    let indices: Vec<usize> = pre.viewpoints.iter().map(|v| v.index).collect();
    if indices.is_empty() {
        bail!("{}: no viewpoints", dir.report_json().display());
    }
    let max_spacing = pre
        .viewpoints
        .windows(2)
        .map(|w| w[0].position.distance(w[1].position))
        .fold(0.0, f64::max);

    // Slab boundaries: from existing layers, the command line, or the low-res depth.
    let lowres: Vec<CubeMap<f32>> = indices
        .iter()
        .map(|&i| sio::read_lowres(&dir, i))
        .collect::<Result<_, _>>()
        .context("reading the low-resolution depth passes")?;
    let params = ChooseParams {
        threshold_px: args.threshold_px,
        ..ChooseParams::default()
    };
    let existing: Vec<Option<LayersMeta>> = indices.iter().map(|&i| dir.layers_meta(i)).collect();
    let rendered: Option<Vec<SlabRange>> =
        existing.iter().flatten().next().map(|m| m.slabs.clone());
    let auto = boundaries::choose(&lowres, max_spacing, pre.face_size, &params);
    let want: Option<Vec<SlabRange>> = match parse_spec(&args.slabs)? {
        Spec::Auto(0) => None,
        Spec::Auto(d) => Some(boundaries::adjust(&auto, d)),
        Spec::List(l) => Some(l),
    };
    let given = |slabs: Vec<SlabRange>, auto: SlabChoice| {
        let mut c = auto;
        c.criterion.manual = true;
        c.criterion.summary = format!(
            "{} slab(s) from --slabs {}; the automatic choice is {} ({})",
            slabs.len(),
            args.slabs,
            c.slabs.len(),
            c.criterion.summary
        );
        c.slabs = slabs;
        c
    };
    let choice: SlabChoice = match (&rendered, want) {
        (Some(slabs), want) => {
            if let Some(want) = want.filter(|w| !same_ranges(w, slabs)) {
                bail!(
                    "the samples already have slab layers {}; remove the slab_K directories and layers.json to render {}",
                    labels(slabs),
                    labels(&want)
                );
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
    };
    drop(lowres);
    eprintln!("{}", choice.criterion.summary);

    // Render the layers that are missing.
    let missing: Vec<usize> = indices
        .iter()
        .zip(&existing)
        .filter(|(_, m)| m.as_ref().map(|m| &m.slabs) != Some(&choice.slabs))
        .map(|(&i, _)| i)
        .collect();
    if !missing.is_empty() && !choice.slabs.is_empty() {
        render_layers(&dir, &pre, &choice.slabs, &missing, &log)?;
    }

    if args.layers_only {
        eprintln!(
            "layers {} rendered; tiles left to a later run",
            labels(&choice.slabs)
        );
        return Ok(());
    }

    let mesh = MeshParams {
        step: args.mesh_step,
        max_error_px: args.mesh_error,
        baseline_m: max_spacing,
        discontinuity_px: args.discontinuity,
    };
    let tp = TileParams {
        tile_size: args.tile_size,
        mesh,
        keep,
        measure_both: true,
    };
    let mut report = SlabsReport::new(&choice, pre.face_size, args.tile_size, mesh, keep);
    let bar = progress(indices.len() as u64, "tiling");
    let mut resumed = 0usize;
    for &i in &indices {
        // Resume: a sample whose tiles files match these parameters is not tiled again.
        if let Ok((file, _)) = sio::read_tiles(&dir, i) {
            // Tiles cut from panoramas of another face size (a work directory prerendered
            // again) are stale.
            let same = file.grid.tile_size == args.tile_size
                && file.grid.face_size == pre.face_size
                && file.mesh_params == mesh
                && file.mesh_kind == keep
                && file
                    .layers
                    .iter()
                    .map(|l| l.range)
                    .eq(choice.slabs.iter().copied())
                && !missing.contains(&i);
            if same {
                report.add_tiles_file(&file);
                resumed += 1;
                bar.inc(1);
                continue;
            }
        }
        let layers = (0..choice.slabs.len())
            .map(|k| sio::read_layer(&dir, i, k))
            .collect::<Result<Vec<_>, _>>()?;
        let inputs: Vec<LayerInput> = layers
            .iter()
            .map(|(depth, mask)| LayerInput { depth, mask })
            .collect();
        let tiles = tile_sample(i, &inputs, &tp).with_context(|| format!("sample {i}: tiling"))?;
        let (file, bin) = sio::encode_tiles(&tiles, &choice.slabs, mesh, keep);
        sio::write_tiles(&dir, i, &file, &bin)?;
        report.add_sample(&tiles);
        bar.inc(1);
    }
    bar.finish_and_clear();
    if resumed > 0 {
        eprintln!("{resumed} sample(s) already tiled with these parameters: kept");
    }
    report.seconds = t0.elapsed().as_secs_f64();
    log.end(&[
        ("samples", indices.len().into()),
        ("layers_rendered", missing.len().into()),
        ("tiled", (indices.len() - resumed).into()),
        ("tiles_kept_from_before", resumed.into()),
    ])?;

    let root = dir.root();
    store::write_json(&root.join("slabs.json"), &report)?;
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
        eprintln!(
            "slab {k} {}: tiles {} -> {}, adaptive mesh {} triangles (max {:.3} px), grid {} triangles (max {:.3} px)",
            SlabRange { near: s.near, far: s.far }.label(),
            s.tiles_before,
            s.tiles_after,
            s.adaptive_mesh.triangles,
            s.adaptive_mesh.max_error_px,
            s.grid_mesh.triangles,
            s.grid_mesh.max_error_px
        );
    }
    eprintln!("wrote {}", root.join("slabs.json").display());
    Ok(())
}

/// What `--slabs` asks for: the automatic choice moved by a number of boundaries, or a list.
enum Spec {
    Auto(i32),
    List(Vec<SlabRange>),
}

fn parse_spec(text: &str) -> anyhow::Result<Spec> {
    let bad = || {
        anyhow::anyhow!("--slabs `{text}`: expected auto, fewer, more, auto-N, auto+N or ranges like 0-10,10-inf")
    };
    Ok(match text {
        "auto" => Spec::Auto(0),
        "fewer" => Spec::Auto(-1),
        "more" => Spec::Auto(1),
        t if t.starts_with("auto") => {
            let d: i32 = t["auto".len()..].parse().map_err(|_| bad())?;
            if !(-16..=16).contains(&d) {
                return Err(bad());
            }
            Spec::Auto(d)
        }
        t => Spec::List(SlabRange::parse_list(t).map_err(|e| anyhow::anyhow!("--slabs: {e}"))?),
    })
}

/// Equal up to JSON round-off (ranges read back from `layers.json`).
fn same_ranges(a: &[SlabRange], b: &[SlabRange]) -> bool {
    let close = |x: f64, y: f64| x == y || (x - y).abs() <= 1e-9 * x.abs().max(y.abs());
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(p, q)| close(p.near, q.near) && close(p.far, q.far))
}

fn labels(s: &[SlabRange]) -> String {
    s.iter().map(|r| r.label()).collect::<Vec<_>>().join(",")
}

fn progress(n: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(n);
    if let Ok(style) = ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} {eta}") {
        bar.set_style(style);
    }
    bar.set_message(what.to_string());
    bar
}

/// Render slab layers of `missing` samples with the built-in ray tracer.
fn render_layers(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    slabs: &[SlabRange],
    missing: &[usize],
    log: &Arc<RunLog>,
) -> anyhow::Result<()> {
    if pre.renderer == "povray" {
        return render_layers_pov(dir, pre, slabs, missing, log);
    }
    if pre.renderer != "builtin" {
        bail!(
            "samples {:?} have no slab layers {} and renderer `{}` cannot be driven from `railview slabs` (only `builtin` and `povray` can): render them with that renderer's own command",
            missing,
            labels(slabs),
            pre.renderer
        );
    }
    let scene = match prerender::scenes::builtin(&pre.scene) {
        Some(b) => b.scene,
        None => {
            let text = super::read_text(std::path::Path::new(&pre.scene))
                .with_context(|| format!("reading scene `{}`", pre.scene))?;
            prerender::scene::Scene::parse_toml(&text, &pre.scene)?
        }
    };
    // As the panoramas were rendered (`prerender` records it; 1 ray, shadows if not).
    let opts = prerender::render::RenderOptions {
        face_size: pre.face_size,
        supersample: pre.extra["supersample"]
            .as_u64()
            .map_or(1, |s| s.clamp(1, 16) as u32),
        shadows: pre.extra["shadows"].as_bool().unwrap_or(true),
    };
    let bar = progress(missing.len() as u64, "rendering slab layers");
    for &i in missing {
        let vp = pre
            .viewpoints
            .iter()
            .find(|v| v.index == i)
            .with_context(|| format!("viewpoint {i} is not in prerender.json"))?;
        let t = Instant::now();
        let layers = prerender::render::render_slabs(&scene, vp.position, slabs, opts);
        for (k, l) in layers.iter().enumerate() {
            // Temporary files of a killed earlier run, before rewriting the layer.
            if let Some(d) = dir.slab_color_png(i, k).parent() {
                store::remove_temporaries(d)?;
            }
            store::write_atomic(&dir.slab_color_png(i, k), &store::encode_rgba_png(&l.color))?;
            store::write_depth_exr(&dir.slab_depth_exr(i, k), &l.depth)?;
        }
        store::write_json(
            &dir.layers_json(i),
            &LayersMeta {
                slabs: slabs.to_vec(),
            },
        )?;
        log.log(&RunEvent::Layers(LayersTiming {
            index: i,
            slabs: slabs.to_vec(),
            seconds: t.elapsed().as_secs_f64(),
        }))?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut pre = pre.clone();
    pre.slabs = slabs.to_vec();
    store::write_json(&dir.report_json(), &pre)?;
    Ok(())
}

/// The POV-Ray import that wrote `pre`, re-created from what `import-pov` recorded in
/// `prerender.json`, with its generated files in `DIR/pov-work`.
pub(crate) fn pov_import_from_report(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
) -> anyhow::Result<prerender::pov::PovImport> {
    prerender::pov::PovImport::from_report(dir, pre, &dir.root().join("pov-work")).with_context(
        || {
            format!(
                "re-creating the POV-Ray import of `{}` recorded in {}",
                pre.scene,
                dir.report_json().display()
            )
        },
    )
}

/// Render slab layers of `missing` samples of a POV-Ray import with POV-Ray.
fn render_layers_pov(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    slabs: &[SlabRange],
    missing: &[usize],
    log: &Arc<RunLog>,
) -> anyhow::Result<()> {
    let mut import = pov_import_from_report(dir, pre)?;
    import.set_run_log(log.clone());
    import.set_progress(|r| {
        eprintln!(
            "sample {:>4} {:<18} {:>8.2} s  (parse {:.2} s, trace {:.2} s)",
            r.sample, r.pass, r.stats.wall_seconds, r.stats.parse_seconds, r.stats.trace_seconds
        )
    });
    for &i in missing {
        let vp = pre
            .viewpoints
            .iter()
            .find(|v| v.index == i)
            .with_context(|| format!("viewpoint {i} is not in prerender.json"))?;
        if !import.base_done(dir, vp) {
            bail!(
                "sample {i}: its base pass is missing or was rendered with other face sizes; run `railview import-pov` on {} first",
                dir.root().display()
            );
        }
        eprintln!("sample {i}: POV-Ray slab layers {}", labels(slabs));
        import
            .render_slabs(vp, slabs, dir)
            .with_context(|| format!("sample {i}: rendering slab layers with POV-Ray"))?;
    }
    import.remove_mesh_includes()?;
    let total = import.total_stats();
    let mut pre = pre.clone();
    pre.slabs = slabs.to_vec();
    if let Some(extra) = pre.extra.as_object_mut() {
        extra.insert("slab_renders".into(), import.records().len().into());
        extra.insert("slab_povray_wall_seconds".into(), total.wall_seconds.into());
        extra.insert(
            "slab_render_log".into(),
            serde_json::to_value(import.records())?,
        );
    }
    store::write_json(&dir.report_json(), &pre)?;
    Ok(())
}
