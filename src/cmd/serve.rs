//! `railview serve DB --addr 127.0.0.1:8080 [--throttle 56kbit] [--latency 50ms]`

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use streamer::server::{self, parse_duration, parse_rate, ServedDb, ServerConfig, ServerStats};

#[derive(clap::Args)]
pub struct Args {
    /// Database directory (manifest.json + objects/).
    pub db: PathBuf,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    /// Per-connection bandwidth, e.g. 56kbit, 2mbit (default unlimited).
    #[arg(long)]
    pub throttle: Option<String>,
    /// Added latency per response, e.g. 50ms.
    #[arg(long, default_value = "0ms")]
    pub latency: String,
    /// Open connections at most.
    #[arg(long, default_value_t = 256)]
    pub max_connections: usize,
    /// Fault injection: corrupt one byte of every Nth object response.
    #[arg(long)]
    pub corrupt_every: Option<u64>,
    /// Do not serve `/bundle` (behave like a static file host; clients fetch object by object).
    #[arg(long)]
    pub no_bundles: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let throttle_bps = match &args.throttle {
        Some(t) => parse_rate(t)
            .map_err(anyhow::Error::msg)
            .context("--throttle")?,
        None => None,
    };
    let config = ServerConfig {
        max_connections: args.max_connections,
        throttle_bps,
        latency: parse_duration(&args.latency)
            .map_err(anyhow::Error::msg)
            .context("--latency")?,
        corrupt_every: args.corrupt_every,
        bundles: !args.no_bundles,
        ..ServerConfig::default()
    };
    let db = ServedDb::open(&args.db)?;
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(&args.addr)
            .await
            .with_context(|| format!("binding {}", args.addr))?;
        let local = listener.local_addr()?;
        eprintln!(
            "serving {} on http://{local} (Ctrl-C or SIGTERM stops)",
            args.db.display()
        );
        let stats = Arc::new(ServerStats::default());
        // Ctrl-C or SIGTERM start a graceful drain.
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("installing the SIGTERM handler")?;
        let shutdown = async move {
            tokio::select! {
                r = tokio::signal::ctrl_c() => {
                    if let Err(e) = r {
                        tracing::warn!("waiting for Ctrl-C: {e}");
                        std::future::pending::<()>().await;
                    }
                }
                _ = term.recv() => {}
            }
        };
        server::run(listener, db, config, stats.clone(), shutdown).await?;
        use std::sync::atomic::Ordering::Relaxed;
        eprintln!(
            "stopped: {} connections, {} requests, {} client errors, {} bytes sent",
            stats.connections.load(Relaxed),
            stats.requests.load(Relaxed),
            stats.client_errors.load(Relaxed),
            stats.bytes_sent.load(Relaxed)
        );
        Ok(())
    })
}
