//! `railview eval`: reconstructed views over the whole track against the anti-aliased ground
//! truth from the same camera (PSNR, SSIM, holes, frame time) for several renderer budgets,
//! and for a database also as a client shows it before the finer levels arrive.

use std::path::{Path, PathBuf};

use anyhow::Context;
use viewer::eval::report::{self, EvalReport};
use viewer::eval::{
    self, default_configs, evaluate, mark_references, matched_size, resolution_ratio,
    views_at_samples, views_between, EvalConfig, EvalInput, EvalRow, EvalView, Truth, TruthCache,
    ViewSpec,
};
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{open, parse_size};
use viewer::source::{LoadOptions, Walkthrough};

/// Arguments of `railview eval`.
#[derive(clap::Args, Clone)]
pub struct Args {
    /// Database or prerender directory (any scene: built-in, scene file, POV-Ray import), or
    /// `synth:street`.
    pub db: String,
    /// Output directory: eval.json, eval.csv, eval.md, figures (SVG and PNG), worst-N.png,
    /// truth/ (the ground-truth pictures, reused by later runs).
    #[arg(long)]
    pub out: PathBuf,
    /// View size WxH, or `matched`: pixels as wide as the panorama's at the view centre
    /// (4:3).
    #[arg(long, default_value = "matched")]
    pub size: String,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Positions evaluated inside every segment.
    #[arg(long, default_value_t = 3)]
    pub per_segment: usize,
    /// Directions per position, evenly spaced from the direction of travel.
    #[arg(long, default_value_t = 4)]
    pub directions: usize,
    /// Pitches of every direction, degrees, comma separated.
    #[arg(long, default_value = "0")]
    pub pitch: String,
    /// Evaluate only the first N segments (default: all).
    #[arg(long)]
    pub segments: Option<usize>,
    /// Ground truth rays per pixel along each axis (box filter over the pixel).
    #[arg(long, default_value_t = 3)]
    pub truth_supersample: u32,
    /// Where ground-truth pictures are kept between runs (default: OUT/truth).
    #[arg(long)]
    pub truth_cache: Option<PathBuf>,
    /// The prerender directory the database was built from (default: DB.work/prerender when
    /// it made this database; needed for POV-Ray imports built elsewhere).
    #[arg(long)]
    pub prerender: Option<PathBuf>,
    /// Renderer budgets: `all` (full, one slab, one view, coarser textures, second view at half
    /// resolution) or `full`.
    #[arg(long, default_value = "all")]
    pub configs: String,
    /// Worst views pictured beside their truth (worst-1.png, …).
    #[arg(long, default_value_t = 3)]
    pub worst: usize,
    /// Timed draws per view and configuration (after one untimed draw).
    #[arg(long, default_value_t = 3)]
    pub timed_draws: usize,
    /// Track name (default: every track of a network, views of each; the only track of one
    /// that is not).
    #[arg(long)]
    pub track: Option<String>,
    /// Evaluate the sampling bound beside (the exact warp of the reference panoramas, from
    /// the prerender directory when it is at hand): `--bound false` leaves it out.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub bound: bool,
    /// Other databases of the same scene and track (other build options: a lossy build,
    /// another depth bound, another tile size), evaluated beside it as configurations named
    /// after their directory and texture coding, so their points share the plots.
    #[arg(long)]
    pub also: Vec<String>,
}

/// Refuse nonsense before anything is rendered or written.
fn check(args: &Args) -> anyhow::Result<()> {
    if let Some(n) = args.segments {
        super::count("--segments", n, 100_000)?;
    }
    anyhow::ensure!(
        args.fov.is_finite() && args.fov > 0.0 && args.fov < 180.0,
        "--fov must be in (0, 180) degrees"
    );
    anyhow::ensure!(
        (1..=64).contains(&args.per_segment),
        "--per-segment must be in 1..=64"
    );
    anyhow::ensure!(
        (1..=64).contains(&args.directions),
        "--directions must be in 1..=64"
    );
    anyhow::ensure!(
        (1..=16).contains(&args.truth_supersample),
        "--truth-supersample must be in 1..=16"
    );
    anyhow::ensure!(
        (1..=100).contains(&args.timed_draws),
        "--timed-draws must be in 1..=100"
    );
    anyhow::ensure!(
        matches!(args.configs.as_str(), "all" | "full"),
        "--configs `{}`: expected `all` or `full`",
        args.configs
    );
    pitches(&args.pitch)?;
    if args.size != "matched" {
        parse_size(&args.size).map_err(anyhow::Error::msg)?;
    }
    Ok(())
}

fn pitches(text: &str) -> anyhow::Result<Vec<f64>> {
    text.split(',')
        .map(|p| {
            p.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| (-89.0..=89.0).contains(v))
                .ok_or_else(|| anyhow::anyhow!("--pitch `{p}`: expected degrees in -89..=89"))
        })
        .collect()
}

/// For a database directory, the level-group counts (1, 2) below the most any tile's PTM has:
/// the partial loads worth evaluating. Nothing for other sources.
fn coarse_level_groups(db: &str) -> anyhow::Result<Vec<usize>> {
    if !Path::new(db).join(db::MANIFEST_FILE).is_file() {
        return Ok(Vec::new());
    }
    let most = db::Database::open(Path::new(db))?.most_level_groups();
    Ok((1..=2).filter(|&g| g < most).collect())
}

/// One walkthrough to evaluate with its renderer budgets.
struct Run {
    walk: Walkthrough,
    configs: Vec<EvalConfig>,
}

fn full(name: &str) -> Vec<EvalConfig> {
    vec![EvalConfig {
        name: name.to_string(),
        budget: viewer::DrawBudget::default(),
    }]
}

/// The walkthroughs: the one given, then for the synthetic street other databases (one
/// slab, a coarser mesh, wider spacing), for a database its first level groups.
fn runs(args: &Args, walk: Walkthrough) -> anyhow::Result<Vec<Run>> {
    let mut runs = vec![Run {
        walk,
        configs: if args.configs == "full" {
            full("full")
        } else {
            default_configs()
        },
    }];
    if args.db == "synth:street" {
        for (name, walk) in viewer::headless::synth_street_variants()? {
            runs.push(Run {
                walk,
                configs: full(name),
            });
        }
    }
    // A database: also what a client shows before the finer texture levels arrive (the first
    // level groups of every PTM), whose bytes are what those groups cost.
    for groups in coarse_level_groups(&args.db)? {
        let name = format!("db level groups={groups}");
        let walk = open(
            &args.db,
            args.track.as_deref(),
            LoadOptions {
                level_groups: Some(groups),
                every_track: args.track.is_none(),
                ..Default::default()
            },
        )
        .with_context(|| format!("opening {} with {groups} level groups", args.db))?;
        runs.push(Run {
            walk,
            configs: full(&name),
        });
    }
    let scene = runs[0].walk.scene.clone();
    for other in &args.also {
        let coding = db::Database::open(Path::new(other))?.texture_coding()?;
        let name = format!("also {other} ({coding})");
        let opts = LoadOptions {
            every_track: args.track.is_none(),
            ..LoadOptions::default()
        };
        let walk =
            open(other, args.track.as_deref(), opts).with_context(|| format!("opening {other}"))?;
        anyhow::ensure!(
            walk.scene == scene,
            "--also {other}: scene `{}`, not `{}`",
            walk.scene,
            scene
        );
        runs.push(Run {
            walk,
            configs: full(&name),
        });
    }
    Ok(runs)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    check(&args)?;
    // Without a track named, every track of a network is evaluated.
    let opts = LoadOptions {
        every_track: args.track.is_none(),
        ..LoadOptions::default()
    };
    let mut walk = open(&args.db, args.track.as_deref(), opts)
        .with_context(|| format!("opening {}", args.db))?;
    let face = walk.views.first().map_or(0, |v| v.face_size);
    anyhow::ensure!(face > 0, "{}: no reference views", args.db);
    let size = if args.size == "matched" {
        matched_size(face, args.fov, 0.75)
    } else {
        parse_size(&args.size).map_err(anyhow::Error::msg)?
    };
    prerender::store::ensure_writable_dir(&args.out)?;
    let mut truth = Truth::for_walkthrough(
        &args.db,
        &walk,
        args.prerender.as_deref(),
        args.truth_supersample,
        &args.out.join("pov-truth"),
    )?;
    let cache = TruthCache {
        dir: Some(
            args.truth_cache
                .clone()
                .unwrap_or_else(|| args.out.join("truth")),
        ),
    };
    let spec = ViewSpec {
        per_segment: args.per_segment,
        directions: args.directions,
        pitches_deg: pitches(&args.pitch)?,
        max_segments: args.segments,
    };
    // The views of every track evaluated (the one named, or each of a network), at its
    // samples and between them.
    let tracks: Vec<usize> = match &args.track {
        Some(_) => vec![walk.current],
        None => (0..walk.tracks.len()).collect(),
    };
    let start = walk.current;
    let mut at_samples = Vec::new();
    let mut between = Vec::new();
    for &t in &tracks {
        walk.set_track(t);
        let (_, arcs) = walk.order_and_arcs();
        at_samples.extend(views_at_samples(&walk, &spec));
        between.extend(views_between(&walk, &arcs, &spec));
    }
    walk.set_track(start);
    let mut runs = runs(&args, walk)?;
    let views_of = |w: &mut Walkthrough| -> Vec<EvalView> {
        let mut v = at_samples.clone();
        let mut b = between.clone();
        for &t in &tracks {
            w.set_track(t);
            let mut mine: Vec<EvalView> = b.iter().filter(|x| x.track == t).copied().collect();
            mark_references(w, &mut mine);
            for (x, m) in b.iter_mut().filter(|x| x.track == t).zip(mine) {
                *x = m;
            }
        }
        v.extend(b);
        v
    };
    let total: usize = runs
        .iter_mut()
        .map(|r| views_of(&mut r.walk).len() * r.configs.len())
        .sum();
    // The sampling bound, for the first walkthrough, from its prerender directory.
    let mut bound = match eval::prerender_dir(&args.db, &runs[0].walk, args.prerender.as_deref()) {
        Some(dir) if args.bound => {
            Some((eval::bound::BoundSource::open(&dir)?, Default::default()))
        }
        _ => None,
    };
    let mut renderer = Renderer::new(Gpu::new()?)?;
    let bar = indicatif::ProgressBar::new(total as u64);
    let mut rows: Vec<EvalRow> = Vec::new();
    for (ri, r) in runs.iter_mut().enumerate() {
        let views = views_of(&mut r.walk);
        rows.extend(evaluate(
            &mut renderer,
            EvalInput {
                walk: &mut r.walk,
                truth: &mut truth,
                cache: &cache,
                configs: &r.configs,
                views: &views,
                size,
                fov_deg: args.fov,
                timed_draws: args.timed_draws,
                bound: bound
                    .as_mut()
                    .filter(|_| ri == 0)
                    .map(|(source, tally)| (source, tally)),
            },
            |_| bar.inc(1),
        )?);
    }
    bar.finish_and_clear();

    let summary = eval::summarize(&rows);
    let first = &mut runs[0];
    let worst = eval::pictures::worst_pictures(
        eval::pictures::PictureInput {
            renderer: &mut renderer,
            walk: &mut first.walk,
            config: &first.configs[0].name,
            budget: first.configs[0].budget,
            size,
            fov_deg: args.fov,
            cache: &cache,
            truth: &mut truth,
        },
        &rows,
        args.worst,
        &args.out,
    )?;
    let rep = EvalReport {
        db: args.db.clone(),
        scene: first.walk.scene.clone(),
        truth: truth.describe(),
        width: size.0,
        height: size.1,
        fov_deg: args.fov,
        face_size: face,
        resolution_ratio: resolution_ratio(face, args.fov, size.0),
        views: spec,
        adapter: format!(
            "{} ({:?})",
            renderer.gpu.info.name, renderer.gpu.info.backend
        ),
        summary,
        worst,
        rows,
        classes: bound.map(|(_, tally)| tally),
    };
    prerender::store::write_json(&args.out.join("eval.json"), &rep)?;
    prerender::store::write_atomic(
        &args.out.join("eval.csv"),
        report::csv(&rep.rows).as_bytes(),
    )?;
    let mut listed = Vec::new();
    for (stem, title, fig) in report::figures(&rep) {
        prerender::store::write_atomic(
            &args.out.join(format!("{stem}.svg")),
            charts::svg(&fig)?.as_bytes(),
        )?;
        prerender::store::write_atomic(&args.out.join(format!("{stem}.png")), &charts::png(&fig)?)?;
        listed.push((format!("{stem}.svg"), title));
    }
    let md = report::markdown(&rep, &listed);
    prerender::store::write_atomic(&args.out.join("eval.md"), md.as_bytes())?;
    eprint!("{md}");
    Ok(())
}
