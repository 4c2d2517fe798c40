//! `railview eval`: reconstructed views at and between reference samples against the ground
//! truth from the same camera (PSNR, SSIM, hole fraction, frame time) over configurations.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{
    default_configs, eval_positions, evaluate, open, parse_size, summarize, EvalRow, Truth,
};
use viewer::plot::{ranges, scatter, SERIES_COLORS};
use viewer::source::LoadOptions;

/// Arguments of `railview eval`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory of a built-in scene, or `synth:street`.
    pub db: String,
    /// Output directory: eval.json, eval.csv, eval.md, psnr_vs_frame_ms.png, psnr_vs_bytes.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Image size WxH.
    #[arg(long, default_value = "256x192")]
    pub size: String,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Segments evaluated from the start of the track (at least 1).
    #[arg(long, default_value_t = 3)]
    pub segments: usize,
    /// Positions evaluated inside each segment.
    #[arg(long, default_value_t = 1)]
    pub between: usize,
    /// Track name (default: the first).
    #[arg(long)]
    pub track: Option<String>,
    /// Other databases of the same scene and track (other build options: a lossy build,
    /// another depth bound, another tile size), evaluated beside it as configurations named
    /// after their directory and texture coding, so their points share the plots.
    #[arg(long)]
    pub also: Vec<String>,
}

#[derive(serde::Serialize)]
struct EvalJson<'a> {
    db: &'a str,
    scene: &'a str,
    width: u32,
    height: u32,
    fov_deg: f64,
    adapter: String,
    rows: &'a [EvalRow],
    summary: Vec<viewer::headless::EvalSummary>,
}

/// For a database directory, the level-group counts (1, 2) below the most any tile's PTM has:
/// the partial loads worth evaluating. Nothing for other sources.
fn coarse_level_groups(db: &str) -> anyhow::Result<Vec<usize>> {
    let dir = std::path::Path::new(db);
    if !dir.join(streamer::db::MANIFEST_FILE).is_file() {
        return Ok(Vec::new());
    }
    let db = streamer::db::Database::open(dir)?;
    let most = db
        .manifest()
        .tracks
        .iter()
        .flat_map(|t| &t.viewpoints)
        .flat_map(|v| v.tiles.iter().filter_map(|t| t.ptm.as_ref()))
        .map(|p| p.levels.len())
        .max()
        .unwrap_or(0);
    Ok((1..=2).filter(|&g| g < most).collect())
}

/// How a database codes its textures, read from its first PTM's header: `lossless` or
/// `lossy near=N`.
fn texture_coding(db: &str) -> anyhow::Result<String> {
    let db = streamer::db::Database::open(std::path::Path::new(db))?;
    let first = db
        .manifest()
        .tracks
        .iter()
        .flat_map(|t| &t.viewpoints)
        .flat_map(|v| v.tiles.iter().filter_map(|t| t.ptm.as_ref()))
        .next();
    let Some(p) = first else {
        return Ok("no textures".into());
    };
    let mut dec = streamer::ptm::Decoder::new(streamer::ptm::Limits::default());
    dec.push(&db.read_level(p, 0)?)?;
    Ok(match dec.header().map_or(0, |h| h.near) {
        0 => "lossless".into(),
        n => format!("lossy near={n}"),
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let size = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    super::count("--segments", args.segments, 100_000)?;
    super::count("--between", args.between.max(1), 10_000)?;
    let walk = open(&args.db, args.track.as_deref(), LoadOptions::default())
        .with_context(|| format!("opening {}", args.db))?;
    let truth = Truth::for_scene(&walk.scene).ok_or_else(|| {
        anyhow::anyhow!(
            "no ground truth for scene `{}` (needs a built-in scene or synth:street)",
            walk.scene
        )
    })?;
    prerender::store::ensure_writable_dir(&args.out)?;
    let mut renderer = Renderer::new(Gpu::new()?)?;
    // Renderer budgets on the walkthrough as given; for the synthetic street also other
    // databases: one slab, a coarser mesh, twice the sample spacing.
    let mut runs: Vec<(
        String,
        viewer::source::Walkthrough,
        Vec<viewer::headless::EvalConfig>,
    )> = Vec::new();
    if args.db == "synth:street" {
        use viewer::synth::Scene;
        let one = [tracks::SlabRange {
            near: 0.0,
            far: f64::INFINITY,
        }];
        let step4 = viewer::MeshParams {
            step: 4,
            ..Default::default()
        };
        let base = viewer::MeshParams::default();
        let slabs3 = Scene::street_slabs();
        let full = |name: &str| {
            vec![viewer::headless::EvalConfig {
                name: name.to_string(),
                budget: viewer::DrawBudget::default(),
            }]
        };
        runs.push((
            "db slabs=1".into(),
            viewer::headless::synth_street_spaced(64, &one, base, 1.5)?,
            full("db slabs=1"),
        ));
        runs.push((
            "db step=4".into(),
            viewer::headless::synth_street_spaced(64, &slabs3, step4, 1.5)?,
            full("db step=4"),
        ));
        runs.push((
            "db spacing=2.25".into(),
            viewer::headless::synth_street_spaced(64, &slabs3, base, 2.25)?,
            full("db spacing=2.25"),
        ));
    }
    // A database: also what a client shows before the finer texture levels arrive (the first
    // level groups of every PTM), whose bytes are what those groups cost.
    for groups in coarse_level_groups(&args.db)? {
        let name = format!("db level groups={groups}");
        let w = open(
            &args.db,
            args.track.as_deref(),
            LoadOptions {
                level_groups: Some(groups),
                ..Default::default()
            },
        )
        .with_context(|| format!("opening {} with {groups} level groups", args.db))?;
        let configs = vec![viewer::headless::EvalConfig {
            name: name.clone(),
            budget: viewer::DrawBudget::default(),
        }];
        runs.push((name, w, configs));
    }
    for other in &args.also {
        let name = format!("also {other} ({})", texture_coding(other)?);
        let w = open(other, args.track.as_deref(), LoadOptions::default())
            .with_context(|| format!("opening {other}"))?;
        anyhow::ensure!(
            w.scene == walk.scene,
            "--also {other}: scene `{}`, not `{}`",
            w.scene,
            walk.scene
        );
        let configs = vec![viewer::headless::EvalConfig {
            name: name.clone(),
            budget: viewer::DrawBudget::default(),
        }];
        runs.push((name, w, configs));
    }
    runs.insert(0, (args.db.clone(), walk, default_configs()));
    let total: usize = runs
        .iter()
        .map(|(_, w, c)| eval_positions(w, args.segments, args.between).len() * c.len())
        .sum();
    let bar = indicatif::ProgressBar::new(total as u64);
    let mut rows = Vec::new();
    for (_, w, configs) in &runs {
        let positions = eval_positions(w, args.segments, args.between);
        rows.extend(evaluate(
            &mut renderer,
            w,
            &truth,
            configs,
            &positions,
            size,
            args.fov,
            |_| bar.inc(1),
        )?);
    }
    bar.finish_and_clear();
    let walk = &runs[0].1;
    let summary = summarize(&rows);
    let json = EvalJson {
        db: &args.db,
        scene: &walk.scene,
        width: size.0,
        height: size.1,
        fov_deg: args.fov,
        adapter: format!(
            "{} ({:?})",
            renderer.gpu.info.name, renderer.gpu.info.backend
        ),
        rows: &rows,
        summary: summary.clone(),
    };
    prerender::store::write_json(&args.out.join("eval.json"), &json)?;

    let mut csv =
        String::from("config,position,at_reference,psnr_db,ssim,hole_fraction,frame_ms,db_bytes\n");
    for r in &rows {
        writeln!(
            csv,
            "{},{},{},{:.3},{:.4},{:.6},{:.3},{}",
            r.config,
            r.position,
            r.at_reference,
            r.psnr_db,
            r.ssim,
            r.hole_fraction,
            r.frame_ms,
            r.db_bytes
        )?;
    }
    prerender::store::write_atomic(&args.out.join("eval.csv"), csv.as_bytes())?;

    // Plots: one series per configuration.
    let series = |x: fn(&EvalRow) -> f64| -> Vec<Vec<(f64, f64)>> {
        summary
            .iter()
            .map(|s| {
                rows.iter()
                    .filter(|r| r.config == s.config)
                    .map(|r| (x(r), r.psnr_db))
                    .collect()
            })
            .collect()
    };
    let by_time = series(|r| r.frame_ms);
    let by_bytes = series(|r| r.db_bytes as f64);
    for (name, s) in [
        ("psnr_vs_frame_ms.png", &by_time),
        ("psnr_vs_bytes.png", &by_bytes),
    ] {
        let mut bytes = Vec::new();
        scatter(s).write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )?;
        prerender::store::write_atomic(&args.out.join(name), &bytes)?;
    }

    let mut md = format!(
        "# Viewer evaluation: {}\n\nScene `{}`, {}x{} px, FOV {}°, adapter {}. Ground truth: the \
         scene's ray tracer from the same camera. The resampling floor is the error at the \
         reference samples; interpolation error is measured between them.\n\n",
        args.db, walk.scene, size.0, size.1, args.fov, json.adapter
    );
    md.push_str("| config | floor PSNR dB | floor SSIM | between PSNR dB | between SSIM | between holes % | frame ms | DB bytes |\n|---|---|---|---|---|---|---|---|\n");
    for s in &summary {
        writeln!(
            md,
            "| {} | {:.2} | {:.4} | {:.2} | {:.4} | {:.3} | {:.2} | {} |",
            s.config,
            s.floor_psnr_db,
            s.floor_ssim,
            s.between_psnr_db,
            s.between_ssim,
            s.between_hole_fraction * 100.0,
            s.frame_ms,
            s.db_bytes
        )?;
    }
    let legend: Vec<String> = summary
        .iter()
        .enumerate()
        .map(|(i, s)| {
            format!(
                "{} = {}",
                SERIES_COLORS[i % SERIES_COLORS.len()].1,
                s.config
            )
        })
        .collect();
    let (x0, x1, y0, y1) = ranges(&by_time);
    writeln!(
        md,
        "\n![PSNR against frame time](psnr_vs_frame_ms.png)\n\nx: frame time {x0:.2}–{x1:.2} ms, y: PSNR {y0:.1}–{y1:.1} dB; {}.\n",
        legend.join(", ")
    )?;
    let (x0, x1, y0, y1) = ranges(&by_bytes);
    writeln!(
        md,
        "![PSNR against database bytes](psnr_vs_bytes.png)\n\nx: database bytes {x0:.0}–{x1:.0}, y: PSNR {y0:.1}–{y1:.1} dB; {}.",
        legend.join(", ")
    )?;
    prerender::store::write_atomic(&args.out.join("eval.md"), md.as_bytes())?;
    eprint!("{md}");
    Ok(())
}
