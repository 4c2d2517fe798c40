//! `railview walk DB|URL --speed 1.5 --bandwidth 56kbit,2mbit,10mbit,unlimited
//!  --strategy naive,ach,visibility,ach+prefetch --out DIR`
//!
//! With a directory, a server is started in-process on 127.0.0.1 (an ephemeral port) and the
//! walk streams from it over loopback HTTP; with an `http://` URL it streams from there
//! (`streamer::walk::stage`: this module only turns the options into its parameters).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use streamer::client::{BudgetParams, RetryPolicy, SchedulerConfig, ServerUrl};
use streamer::server::{parse_duration, parse_rate};
use streamer::walk::stage::{self, WalkParams, WalkSource};
use streamer::walk::{self, synth, Strategy, WalkConfig, WalkEvent};
use tracks::limits::{check_f64, check_u64};

#[derive(clap::Args, Clone)]
pub struct Args {
    /// Database directory or server URL (http://HOST:PORT).
    pub db: String,
    /// Walking speed, m/s (0.01..=1000).
    #[arg(long, default_value_t = 1.5)]
    pub speed: f64,
    /// Bandwidths to simulate, comma separated (56kbit, 2mbit, unlimited, …).
    #[arg(long, default_value = "56kbit,2mbit,10mbit,unlimited")]
    pub bandwidth: String,
    /// Strategies: naive, ach, visibility, ach+visibility, each optionally +prefetch.
    #[arg(long, default_value = "naive,ach,visibility,ach+prefetch")]
    pub strategy: String,
    /// Output directory (walk.json, walk.csv, walk.png, summary.md).
    #[arg(long)]
    pub out: PathBuf,
    /// Simulated latency per request.
    #[arg(long, default_value = "50ms")]
    pub latency: String,
    /// Texture memory budget M while moving, MiB [default: the paper's 4 MiB, raised to the
    /// largest segment's tiles at full resolution].
    #[arg(long)]
    pub memory_mb: Option<f64>,
    /// Texture memory budget once static, MiB [default: 16 MiB, raised to twice that M].
    #[arg(long)]
    pub memory_static_mb: Option<f64>,
    /// Longest acceptable download of one level while moving, seconds (δt_max).
    #[arg(long, default_value_t = 0.5)]
    pub dt_max: f64,
    /// δt_max once static, seconds.
    #[arg(long, default_value_t = 20.0)]
    pub dt_static: f64,
    /// Seconds without moving before the static budgets apply.
    #[arg(long, default_value_t = 1.0)]
    pub t_static: f64,
    /// RAM cache budget, MiB.
    #[arg(long, default_value_t = 64.0)]
    pub cache_mb: f64,
    /// Requests in flight at most (1..=64).
    #[arg(long, default_value_t = 6)]
    pub in_flight: usize,
    /// Prefetch: widen the view by this turn of the head, degrees each side.
    #[arg(long, default_value_t = 10.0)]
    pub prefetch_turn: f64,
    /// Prefetch the next segment once the predicted motion reaches it within this many
    /// seconds.
    #[arg(long, default_value_t = 1.0)]
    pub prefetch_horizon: f64,
    /// Prefetch (with live counts) the tiles covering this fraction of the predicted view.
    #[arg(long, default_value_t = 0.9)]
    pub prefetch_coverage: f64,
    /// Seconds standing still at the end of the track (0..=3600).
    #[arg(long, default_value_t = 3.0)]
    pub pause: f64,
    /// Walk through these tracks of a network, comma separated: along the first from its end
    /// farther from the second into the second at their junction, and so on, to the far end
    /// of the last (turn stalls are reported apart). Default: the first track, whole.
    #[arg(long)]
    pub route: Option<String>,
    /// Stop this many metres along the walk (the route, or the track), so that walks on
    /// networks of any size cover the same length. Default: the whole route.
    #[arg(long)]
    pub length: Option<f64>,
    /// Write a synthetic corridor database into the DB directory first (tests and demos).
    #[arg(long)]
    pub synthetic: bool,
    /// Face size of the synthetic database (tiles are about face/4 pixels).
    #[arg(long, default_value_t = 64)]
    pub synthetic_face: u32,
    /// Track length of the synthetic database, metres.
    #[arg(long, default_value_t = 12.0)]
    pub synthetic_length: f64,
    /// Longest wait for a response head (and for a connection), e.g. 10s.
    #[arg(long, default_value = "10s")]
    pub response_timeout: String,
    /// Longest gap between two pieces of a response body (a stalled transfer).
    #[arg(long, default_value = "10s")]
    pub stall_timeout: String,
    /// A request that keeps failing (server unreachable) is given up after this long, and
    /// the walk stops there (what it measured is written).
    #[arg(long, default_value = "30s")]
    pub give_up_after: String,
}

fn mib(x: f64, name: &str) -> anyhow::Result<u64> {
    Ok((check_f64(&format!("--{name}"), x, 0.001, 1024.0 * 1024.0)? * 1048576.0) as u64)
}

/// A duration option that must be positive and at most an hour.
fn timeout(text: &str, name: &str) -> anyhow::Result<Duration> {
    let d = parse_duration(text)
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("--{name}"))?;
    anyhow::ensure!(!d.is_zero(), "--{name} {text}: must be longer than 0");
    Ok(d)
}

/// The walk's settings from the command line, every number checked against its limit.
fn config(args: &Args) -> anyhow::Result<WalkConfig> {
    let defaults = SchedulerConfig::default();
    let paper = defaults.budget;
    let seconds = |v: f64, name: &str, min: f64| check_f64(&format!("--{name}"), v, min, 3600.0);
    let retry = RetryPolicy {
        response_timeout: timeout(&args.response_timeout, "response-timeout")?,
        stall_timeout: timeout(&args.stall_timeout, "stall-timeout")?,
        connect_timeout: timeout(&args.response_timeout, "response-timeout")?,
        give_up_after: timeout(&args.give_up_after, "give-up-after")?,
        ..RetryPolicy::default()
    };
    Ok(WalkConfig {
        speed_mps: check_f64("--speed (m/s)", args.speed, 0.01, 1000.0)?,
        latency_s: parse_duration(&args.latency)
            .map_err(anyhow::Error::msg)
            .context("--latency")?
            .as_secs_f64(),
        pause_s: seconds(args.pause, "pause", 0.0)?,
        schedule: SchedulerConfig {
            budget: BudgetParams {
                memory_bytes: args
                    .memory_mb
                    .map_or(Ok(paper.memory_bytes), |m| mib(m, "memory-mb"))?,
                dt_max_s: seconds(args.dt_max, "dt-max", 0.001)?,
                memory_static_bytes: args
                    .memory_static_mb
                    .map_or(Ok(paper.memory_static_bytes), |m| {
                        mib(m, "memory-static-mb")
                    })?,
                dt_static_s: seconds(args.dt_static, "dt-static", 0.001)?,
                t_static_s: seconds(args.t_static, "t-static", 0.0)?,
            },
            // Given budgets are taken as they are; defaults grow with the database.
            scale_budget: args.memory_mb.is_none() && args.memory_static_mb.is_none(),
            cache_bytes: mib(args.cache_mb, "cache-mb")?,
            max_in_flight: check_u64("--in-flight", args.in_flight as u64, 1, 64)? as usize,
            prefetch_turn_deg: check_f64(
                "--prefetch-turn (degrees)",
                args.prefetch_turn,
                0.0,
                90.0,
            )?,
            prefetch_horizon_s: check_f64(
                "--prefetch-horizon (s)",
                args.prefetch_horizon,
                0.0,
                60.0,
            )?,
            prefetch_coverage: check_f64("--prefetch-coverage", args.prefetch_coverage, 0.0, 1.0)?,
            ..defaults
        },
        retry,
        route: match &args.route {
            Some(r) => {
                let names: Vec<String> = r.split(',').map(|x| x.trim().to_string()).collect();
                anyhow::ensure!(
                    names.iter().all(|n| !n.is_empty()),
                    "--route {r}: track names separated by commas"
                );
                check_u64("--route (tracks)", names.len() as u64, 1, 1024)?;
                Some(names)
            }
            None => None,
        },
        max_length_m: args
            .length
            .map(|m| check_f64("--length (m)", m, 0.1, tracks::limits::MAX_COORDINATE_M))
            .transpose()?,
        ..WalkConfig::default()
    })
}

/// The server a walk streams from: a URL, or a directory served in-process.
fn source(db: &str) -> anyhow::Result<WalkSource> {
    if let Some((scheme, _)) = db.split_once("://") {
        if scheme.eq_ignore_ascii_case("http") {
            return Ok(WalkSource::Url {
                url: ServerUrl::parse(db)?,
                text: db.to_string(),
            });
        }
        anyhow::bail!(
            "`{db}`: only http:// URLs are supported (for {scheme}://, put a TLS proxy in front \
             of `railview serve`, or walk the database directory)"
        );
    }
    Ok(WalkSource::Dir(PathBuf::from(db)))
}

/// The walk's parameters from the command line, every string parsed and every number
/// checked against its limit.
fn params(args: &Args) -> anyhow::Result<WalkParams> {
    let strategies = args
        .strategy
        .split(',')
        .map(Strategy::parse)
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)
        .context("--strategy")?;
    let bandwidths = args
        .bandwidth
        .split(',')
        .map(parse_rate)
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)
        .context("--bandwidth")?;
    let config = config(args)?;
    let source = source(&args.db)?;
    let synthetic = match source {
        WalkSource::Dir(_) if args.synthetic => Some(synthetic(args)?),
        _ => None,
    };
    Ok(WalkParams {
        source,
        out: args.out.clone(),
        config,
        strategies,
        bandwidths,
        synthetic,
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    run_stage(&params(&args)?)
}

/// Run the walk with its progress on the terminal and its summary on stdout.
pub fn run_stage(params: &WalkParams) -> anyhow::Result<()> {
    let frame_dt_s = params.config.frame_dt_s;
    let bar = indicatif::ProgressBar::hidden();
    let result = stage::run(params, |e| match e {
        WalkEvent::Planned {
            runs,
            frames_per_run,
        } => {
            eprintln!(
                "walk: {runs} runs of {frames_per_run} frames each ({:.0} s of simulated walk per run)",
                frames_per_run as f64 * frame_dt_s
            );
            bar.set_length(runs as u64 * frames_per_run);
            bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{msg} {bar:40} {pos}/{len} frames, eta {eta}",
            ) {
                bar.set_style(style);
            }
        }
        WalkEvent::Frame { .. } => bar.inc(1),
        WalkEvent::Finished(r) => bar.set_message(format!("{} done", r.strategy)),
    });
    bar.finish_and_clear();
    // The summary of what was measured, also when the walk stopped early.
    let report = match &result {
        Ok(report) => Some(report),
        Err(e) => e.report(),
    };
    if let Some(report) = report {
        print!("{}", walk::summary_markdown(report));
    }
    result?;
    Ok(())
}

/// The synthetic database's settings, checked.
fn synthetic(args: &Args) -> anyhow::Result<synth::SynthParams> {
    check_u64("--synthetic-face", args.synthetic_face as u64, 8, 4096)?;
    check_f64("--synthetic-length (m)", args.synthetic_length, 0.1, 1000.0)?;
    Ok(synth::SynthParams::for_face(
        args.synthetic_face,
        args.synthetic_length,
    ))
}
