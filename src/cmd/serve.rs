//! `railview serve DB --addr 127.0.0.1:8080 [--throttle 56kbit] [--latency 50ms]`, with the
//! limits that keep hostile or broken clients from starving the others.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use streamer::server::{self, parse_duration, parse_rate, ServedDb, ServerConfig, ServerStats};

#[derive(clap::Args)]
#[command(after_help = "\
Limits against hostile or broken clients (defaults above):
  A request head (at most 16 KiB) must be complete --header-timeout after its first byte,
  however slowly it arrives; a connection that sends no request is closed after --idle-timeout; one whose client
  stops reading after --write-timeout; one whose client reads at less than --min-send-rate
  once the socket fills (checked over --write-timeout) is closed too. Request bodies are never
  read (413). Responses stream from the files in 32 KiB chunks, so a client that does not read
  holds one chunk, whatever it asked for. At --max-connections (or --max-connections-per-peer
  for one address) a new connection takes the place of an idle one that never completed a
  request, else of one whose client stopped reading for a second, else of an idle keep-alive
  one; with none of those it gets 503 Service Unavailable.")]
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
    /// Open connections at most (1..=65536).
    #[arg(long, default_value_t = 512)]
    pub max_connections: usize,
    /// Open connections from one IP address at most (1..=65536).
    #[arg(long, default_value_t = 128)]
    pub max_connections_per_peer: usize,
    /// Time for a request head after its first byte arrives (up to 1 h).
    #[arg(long, default_value = "5s")]
    pub header_timeout: String,
    /// Time a connection may wait without sending a request (up to 1 h).
    #[arg(long, default_value = "30s")]
    pub idle_timeout: String,
    /// Time a response may wait for a client that does not read (up to 1 h).
    #[arg(long, default_value = "10s")]
    pub write_timeout: String,
    /// Bytes per second a client must read at once the socket fills (0 = no check).
    #[arg(long, default_value_t = 1024)]
    pub min_send_rate: u64,
    /// Entries one /bundle request may name at most (1..=4096).
    #[arg(long, default_value_t = 256)]
    pub max_bundle_entries: usize,
    /// Bytes one /bundle response may carry at most, MiB (up to 1024).
    #[arg(long, default_value_t = 16.0)]
    pub max_bundle_mb: f64,
    /// Fault injection: corrupt one byte of every Nth object response.
    #[arg(long)]
    pub corrupt_every: Option<u64>,
    /// Do not serve `/bundle` (behave like a static file host; clients fetch object by object).
    #[arg(long)]
    pub no_bundles: bool,
}

/// Parse a duration option that must be positive.
fn timeout(text: &str, name: &str) -> anyhow::Result<std::time::Duration> {
    let d = parse_duration(text)
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("--{name}"))?;
    anyhow::ensure!(!d.is_zero(), "--{name} {text}: must be longer than 0");
    Ok(d)
}

/// The server's settings from the command line, every number checked against its limit.
pub fn config(args: &Args) -> anyhow::Result<ServerConfig> {
    use tracks::limits::{check_f64, check_u64};
    let throttle_bps = match &args.throttle {
        Some(t) => parse_rate(t)
            .map_err(anyhow::Error::msg)
            .context("--throttle")?,
        None => None,
    };
    let count = |v: usize, name: &str, max: u64| -> anyhow::Result<usize> {
        Ok(check_u64(&format!("--{name}"), v as u64, 1, max)? as usize)
    };
    Ok(ServerConfig {
        max_connections: count(args.max_connections, "max-connections", 65536)?,
        max_connections_per_peer: count(
            args.max_connections_per_peer,
            "max-connections-per-peer",
            65536,
        )?,
        header_timeout: timeout(&args.header_timeout, "header-timeout")?,
        idle_timeout: timeout(&args.idle_timeout, "idle-timeout")?,
        write_timeout: timeout(&args.write_timeout, "write-timeout")?,
        min_send_rate: check_u64("--min-send-rate", args.min_send_rate, 0, 1 << 30)?,
        max_bundle_entries: count(args.max_bundle_entries, "max-bundle-entries", 4096)?,
        max_bundle_bytes: (check_f64("--max-bundle-mb", args.max_bundle_mb, 0.001, 1024.0)?
            * 1048576.0) as u64,
        throttle_bps,
        latency: parse_duration(&args.latency)
            .map_err(anyhow::Error::msg)
            .context("--latency")?,
        corrupt_every: args.corrupt_every,
        bundles: !args.no_bundles,
        site: viewer::web::SITE,
        ..ServerConfig::default()
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = config(&args)?;
    let db = ServedDb::open(&args.db)?;
    // Few blocking threads: they only read the chunks of long bodies, and hundreds of
    // stalled readers would otherwise start hundreds of threads that fight for the cores.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .max_blocking_threads(16)
        .build()
        .context("starting the async runtime")?;
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
        eprintln!("stopped: {}", stats.summary());
        Ok(())
    })
}
