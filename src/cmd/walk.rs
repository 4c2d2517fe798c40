//! `railview walk DB|URL --speed 1.5 --bandwidth 56kbit,2mbit,10mbit,unlimited
//!  --strategy naive,ach,visibility,ach+prefetch --out DIR`
//!
//! With a directory, a server is started in-process on 127.0.0.1 (an ephemeral port) and the
//! walk streams from it over loopback HTTP; with an `http://` URL it streams from there.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use streamer::client::{BudgetParams, SchedulerConfig, ServerUrl};
use streamer::server::{self, parse_duration, parse_rate, ServedDb, ServerConfig, ServerStats};
use streamer::walk::{self, synth, Strategy, WalkConfig};

#[derive(clap::Args)]
pub struct Args {
    /// Database directory or server URL (http://HOST:PORT).
    pub db: String,
    /// Walking speed, m/s.
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
    /// Requests in flight at most.
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
    /// Seconds standing still at the end of the track.
    #[arg(long, default_value_t = 3.0)]
    pub pause: f64,
    /// Write a synthetic corridor database into the DB directory first (tests and demos).
    #[arg(long)]
    pub synthetic: bool,
    /// Face size of the synthetic database (tiles are about face/4 pixels).
    #[arg(long, default_value_t = 64)]
    pub synthetic_face: u32,
    /// Track length of the synthetic database, metres.
    #[arg(long, default_value_t = 12.0)]
    pub synthetic_length: f64,
}

fn mib(x: f64, name: &str) -> anyhow::Result<u64> {
    anyhow::ensure!(x.is_finite() && x > 0.0, "--{name} must be positive");
    Ok((x * 1048576.0) as u64)
}

pub fn run(args: Args) -> anyhow::Result<()> {
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
    anyhow::ensure!(
        args.speed.is_finite() && args.speed > 0.0,
        "--speed must be positive"
    );
    let defaults = SchedulerConfig::default();
    let paper = defaults.budget;
    let config = WalkConfig {
        speed_mps: args.speed,
        latency_s: parse_duration(&args.latency)
            .map_err(anyhow::Error::msg)
            .context("--latency")?
            .as_secs_f64(),
        pause_s: args.pause.max(0.0),
        schedule: SchedulerConfig {
            budget: BudgetParams {
                memory_bytes: args
                    .memory_mb
                    .map_or(Ok(paper.memory_bytes), |m| mib(m, "memory-mb"))?,
                dt_max_s: args.dt_max,
                memory_static_bytes: args
                    .memory_static_mb
                    .map_or(Ok(paper.memory_static_bytes), |m| {
                        mib(m, "memory-static-mb")
                    })?,
                dt_static_s: args.dt_static,
                t_static_s: args.t_static,
            },
            // Given budgets are taken as they are; defaults grow with the database.
            scale_budget: args.memory_mb.is_none() && args.memory_static_mb.is_none(),
            cache_bytes: mib(args.cache_mb, "cache-mb")?,
            max_in_flight: args.in_flight.max(1),
            prefetch_turn_deg: args.prefetch_turn.clamp(0.0, 90.0),
            prefetch_horizon_s: args.prefetch_horizon.clamp(0.0, 60.0),
            prefetch_coverage: args.prefetch_coverage.clamp(0.0, 1.0),
            ..defaults
        },
        ..WalkConfig::default()
    };
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    rt.block_on(async {
        let (url, server) = if args.db.starts_with("http://") {
            (ServerUrl::parse(&args.db)?, None)
        } else {
            let dir = Path::new(&args.db);
            if args.synthetic {
                anyhow::ensure!(
                    args.synthetic_face >= 8 && args.synthetic_face <= 4096,
                    "--synthetic-face must be in 8..=4096"
                );
                anyhow::ensure!(
                    args.synthetic_length > 0.0 && args.synthetic_length <= 1000.0,
                    "--synthetic-length must be in (0, 1000]"
                );
                let params = synth::SynthParams {
                    face_size: args.synthetic_face,
                    tile_size: 1 << (args.synthetic_face / 4).ilog2(),
                    levels: (args.synthetic_face / 4)
                        .ilog2()
                        .saturating_sub(1)
                        .clamp(1, 4),
                    length_m: args.synthetic_length,
                    ..synth::SynthParams::default()
                };
                synth::write_synthetic(dir, &params).with_context(|| {
                    format!("writing a synthetic database to {}", dir.display())
                })?;
            }
            let db = ServedDb::open(dir)?;
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let url = ServerUrl::parse(&format!("http://{}", listener.local_addr()?))?;
            let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
            let task = tokio::spawn(server::run(
                listener,
                db,
                ServerConfig::default(),
                Arc::new(ServerStats::default()),
                async {
                    let _ = stop_rx.await;
                },
            ));
            (url, Some((stop_tx, task)))
        };
        let total = strategies.len() * bandwidths.len();
        let bar = indicatif::ProgressBar::new(total as u64);
        let report = walk::run_walk(&url, &config, &strategies, &bandwidths, |r| {
            bar.inc(1);
            bar.set_message(r.strategy.clone());
        })
        .await?;
        bar.finish_and_clear();
        if let Some((stop, task)) = server {
            let _ = stop.send(());
            task.await.context("server task")??;
        }
        walk::write_outputs(&report, &args.out)?;
        print!("{}", walk::summary_markdown(&report));
        Ok(())
    })
}
