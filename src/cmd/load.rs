//! `railview load DB|URL --clients 100 --seconds 10`: many concurrent clients on loopback,
//! throughput and latency percentiles (a directory is served in-process).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use streamer::client::ServerUrl;
use streamer::server::{self, parse_duration, parse_rate, ServedDb, ServerConfig, ServerStats};
use streamer::walk::load;

#[derive(clap::Args)]
pub struct Args {
    /// Database directory or server URL.
    pub db: String,
    /// Concurrent clients.
    #[arg(long, default_value_t = 100)]
    pub clients: usize,
    /// How long the clients run, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Per-connection throttle of the in-process server (default unlimited).
    #[arg(long)]
    pub throttle: Option<String>,
    /// Added latency of the in-process server.
    #[arg(long, default_value = "0ms")]
    pub latency: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= 3600.0,
        "--seconds {}: must be a number of seconds in (0, 3600]",
        args.seconds
    );
    tracks::limits::check_u64("--clients", args.clients as u64, 1, 10_000)?;
    if let Some((scheme, _)) = args.db.split_once("://") {
        anyhow::ensure!(
            scheme.eq_ignore_ascii_case("http"),
            "`{}`: only http:// URLs are supported",
            args.db
        );
    }
    let config = ServerConfig {
        throttle_bps: match &args.throttle {
            Some(t) => parse_rate(t)
                .map_err(anyhow::Error::msg)
                .context("--throttle")?,
            None => None,
        },
        latency: parse_duration(&args.latency)
            .map_err(anyhow::Error::msg)
            .context("--latency")?,
        max_connections: args.clients.max(1) + 16,
        ..ServerConfig::default()
    };
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    rt.block_on(async {
        let (url, server) = if args.db.contains("://") {
            (ServerUrl::parse(&args.db)?, None)
        } else {
            let db = ServedDb::open(Path::new(&args.db))?;
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let url = ServerUrl::parse(&format!("http://{}", listener.local_addr()?))?;
            let (tx, rx) = tokio::sync::oneshot::channel::<()>();
            let stats = Arc::new(ServerStats::default());
            let task = tokio::spawn(server::run(listener, db, config, stats, async {
                let _ = rx.await;
            }));
            (url, Some((tx, task)))
        };
        let report =
            load::run_load(&url, args.clients, Duration::from_secs_f64(args.seconds)).await?;
        if let Some((tx, task)) = server {
            let _ = tx.send(());
            task.await.context("server task")??;
        }
        println!("{}", serde_json::to_string_pretty(&report)?);
        anyhow::ensure!(report.errors == 0, "{} requests failed", report.errors);
        Ok(())
    })
}
