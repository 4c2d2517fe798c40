//! `railview eval`: reconstructed views over the whole track against the anti-aliased ground
//! truth from the same camera (PSNR, SSIM, holes, frame time) for several renderer budgets,
//! and for a database also as a client shows it before the finer levels arrive
//! (`viewer::eval::stage`: this module only turns the options into its parameters).

use std::path::PathBuf;

use viewer::eval::stage::{self, ConfigSet, EvalEvent, EvalParams, ViewSize};
use viewer::eval::ViewSpec;
use viewer::headless::parse_size;

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

/// The evaluation's parameters from the command line. The stage's own checks come first,
/// then the options only a command line can get wrong, in the order their messages have
/// always come.
fn params(args: &Args) -> anyhow::Result<EvalParams> {
    let mut params = EvalParams {
        db: args.db.clone(),
        out: args.out.clone(),
        size: ViewSize::Matched,
        fov_deg: args.fov,
        views: ViewSpec {
            per_segment: args.per_segment,
            directions: args.directions,
            pitches_deg: vec![0.0],
            max_segments: args.segments,
        },
        truth_supersample: args.truth_supersample,
        truth_cache: args.truth_cache.clone(),
        prerender: args.prerender.clone(),
        configs: ConfigSet::All,
        worst: args.worst,
        timed_draws: args.timed_draws,
        track: args.track.clone(),
        bound: args.bound,
        also: args.also.clone(),
    };
    params.check()?;
    params.configs = match args.configs.as_str() {
        "all" => ConfigSet::All,
        "full" => ConfigSet::Full,
        other => anyhow::bail!("--configs `{other}`: expected `all` or `full`"),
    };
    params.views.pitches_deg = pitches(&args.pitch)?;
    if args.size != "matched" {
        let (width, height) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
        params.size = ViewSize::Pixels { width, height };
    }
    Ok(params)
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

pub fn run(args: Args) -> anyhow::Result<()> {
    run_stage(&params(&args)?)
}

/// Run the evaluation with its progress on the terminal and its report (`eval.md`) on
/// stderr.
pub fn run_stage(params: &EvalParams) -> anyhow::Result<()> {
    let mut bar = None;
    stage::run(params, |e| match e {
        EvalEvent::Planned { rows } => bar = Some(indicatif::ProgressBar::new(rows as u64)),
        EvalEvent::Row(_) => bar.iter().for_each(|b| b.inc(1)),
        EvalEvent::Evaluated => bar.iter().for_each(|b| b.finish_and_clear()),
        EvalEvent::Written { markdown } => eprint!("{markdown}"),
        _ => {}
    })?;
    Ok(())
}
