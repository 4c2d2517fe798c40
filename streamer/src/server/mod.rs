//! The HTTP tile server: serves a database directory (`manifest.json`, `objects/HH/HASH`).
//!
//! [`run`] takes a bound listener, the database, a [`ServerConfig`] and a shutdown future, in
//! the shape of a plain accept loop: each connection runs in its own task (one connection's
//! error never stops the server), and the shutdown future starts a graceful drain. Responses
//! carry `ETag` = content hash and `Cache-Control: immutable`, so any static server can stand
//! in for this one; this one adds per-connection bandwidth shaping and added latency for
//! simulation. `/bundle?p=…` (see [`parse_bundle_query`]) serves many objects or ranges in
//! one response (one round trip for a batch of small tiles); it is an optimisation only — a
//! static host answers 404 and clients fall back to one request per object.
//!
//! `GET /manifest.json` from a client whose `Accept-Encoding` allows gzip is answered with
//! `manifest.json.gz` (`Content-Encoding: gzip`, its own ETag, `Vary: Accept-Encoding`), as
//! nginx's `gzip_static on;` does with the same files; `/manifest.json.blake3` is served so a
//! client can check the decoded manifest.
//!
//! Every answer carries [`SECURITY_HEADERS`]: the browser viewer's page and modules run under
//! the strict [`CONTENT_SECURITY_POLICY`], and nothing is sniffed into another type or leaks
//! a referrer. A static host in front of a database sends the same (README, nginx block).
//!
//! Paths are never taken from the request: an object request names a hash, the hash is
//! validated ([`tracks::manifest::object_rel_path`]), and only then is `DB/objects/HH/HASH`
//! opened: any object file of the database is served, as a static host serves the directory.
//! When it opens a database the server checks every piece of the index and every table a
//! chunk at a time and keeps only the root, so its memory is bounded by its connections, not
//! by the number of objects.
//!
//! Hostile and broken peers are bounded ([`ServerConfig`] has every limit):
//! - time: a request head must arrive within `header_timeout` of its first byte (a slow
//!   sender cannot extend it), an idle connection is closed after `idle_timeout`, a peer that
//!   stops reading after `write_timeout`, one that reads at less than `min_send_rate` once
//!   its writes block is closed too; request bodies are never read (`413`, then the
//!   connection closes);
//! - memory: object and bundle bodies stream from the files, so a response holds at most
//!   [`CHUNK_BYTES`] of file data whatever it asks for; a bundle names at most
//!   `max_bundle_entries` entries and `max_bundle_bytes` bytes;
//! - admission: the server never stops accepting. At `max_connections` (or a peer's
//!   `max_connections_per_peer`) a new connection takes the place of the one doing least for
//!   anyone — an idle one that never completed a request, then one whose peer stopped
//!   reading, then an idle keep-alive one (module `admit`); with none of those, the newcomer
//!   gets `503`. Idle or slow connections cannot starve live ones.

mod admit;
mod body;
mod bundle;
mod guard;
mod loopback;
mod range;
mod routes;
mod shape;

use std::convert::Infallible;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use bytes::Bytes;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinSet;
use tracks::manifest::object_rel_path;

use admit::{Admission, Clock, CloseReason, Registry, TimeLimits};
use guard::Guarded;

pub use body::{ServeBody, CHUNK_BYTES};
pub use bundle::{bundle_query, parse_bundle_query, BundleEntry, BundleError};
pub use loopback::Loopback;
pub use range::{multipart_body, parse_range, parse_ranges, RangeError};
pub use routes::MAX_RANGES;
pub use shape::{parse_duration, parse_rate, Shaped};

/// The policy the browser viewer runs under: its own scripts, workers, styles, images and
/// requests (same origin), nothing inline, no `<base>`, no form, never framed.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
    worker-src 'self'; connect-src 'self'; style-src 'self'; img-src 'self'; base-uri 'none'; \
    form-action 'none'; frame-ancestors 'none'";

/// Headers sent with every response, name and value: [`CONTENT_SECURITY_POLICY`], no type
/// sniffing (a module is run only if served as JavaScript) and no referrer.
pub const SECURITY_HEADERS: [(&str, &str); 3] = [
    ("Content-Security-Policy", CONTENT_SECURITY_POLICY),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
];

/// Server limits and simulation settings.
#[derive(Clone, Debug)]
pub struct ServerConfig {
    /// Open connections at most; at the limit a new connection takes the place of an idle or
    /// stalled one, or gets `503`.
    pub max_connections: usize,
    /// Open connections from one IP address at most (the same rule within that address).
    pub max_connections_per_peer: usize,
    /// A request head must be complete this long after its first byte.
    pub header_timeout: Duration,
    /// A connection waiting for a request (no byte of one yet) is closed after this long.
    pub idle_timeout: Duration,
    /// A connection whose peer does not read (writes blocked, no progress) is closed after
    /// this long.
    pub write_timeout: Duration,
    /// Bytes per second a response must average once its writes block (measured over at
    /// least `write_timeout`); 0 turns the check off. With `throttle_bps` below twice this,
    /// half the throttle applies instead.
    pub min_send_rate: u64,
    /// Largest request head (headers) accepted, bytes.
    pub max_header_bytes: usize,
    /// Largest response for one object or byte range, bytes.
    pub max_response_bytes: u64,
    /// Entries one `/bundle` request may name at most.
    pub max_bundle_entries: usize,
    /// Bytes one `/bundle` response may carry at most.
    pub max_bundle_bytes: u64,
    /// Serve `/bundle` (off: behave like a static file host, 404).
    pub bundles: bool,
    /// Per-connection write rate, bits per second (`None` = unlimited).
    pub throttle_bps: Option<u64>,
    /// Added before each response.
    pub latency: Duration,
    /// Fault injection for tests and demos: flip one byte in every Nth object response.
    pub corrupt_every: Option<u64>,
    /// How long a graceful shutdown waits for open connections.
    pub drain_timeout: Duration,
    /// Static files served beside the database (the browser viewer: `/` is `index.html`).
    pub site: &'static [SiteFile],
}

/// A static file served at `/NAME` (and `index.html` at `/` too), e.g. the browser viewer's.
#[derive(Clone, Copy, Debug)]
pub struct SiteFile {
    pub name: &'static str,
    pub body: &'static str,
}

impl SiteFile {
    /// The `Content-Type` of the file, from its extension.
    pub fn content_type(&self) -> &'static str {
        match self.name.rsplit('.').next() {
            Some("html") => "text/html; charset=utf-8",
            Some("js" | "mjs") => "text/javascript; charset=utf-8",
            Some("css") => "text/css; charset=utf-8",
            Some("json") => "application/json",
            Some("svg") => "image/svg+xml",
            _ => "application/octet-stream",
        }
    }
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            max_connections: 512,
            max_connections_per_peer: 128,
            header_timeout: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(30),
            write_timeout: Duration::from_secs(10),
            min_send_rate: 1024,
            max_header_bytes: 16 * 1024,
            max_response_bytes: 64 << 20,
            max_bundle_entries: 256,
            max_bundle_bytes: 16 << 20,
            bundles: true,
            throttle_bps: None,
            latency: Duration::ZERO,
            corrupt_every: None,
            drain_timeout: Duration::from_secs(5),
            site: &[],
        }
    }
}

impl ServerConfig {
    /// The minimum send rate in force: `min_send_rate`, or half the throttle when that is
    /// lower (the server's own shaping must not trip its own check).
    pub fn effective_min_send_rate(&self) -> u64 {
        match self.throttle_bps {
            Some(bps) => self.min_send_rate.min(bps / 16),
            None => self.min_send_rate,
        }
    }
}

/// Errors that stop the server from starting or accepting.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServerError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    /// The database does not open (the message names the damaged file).
    #[error("cannot serve {root}: {error}{}", verify_hint(error, root))]
    Database { root: PathBuf, error: db::DbError },
    #[error("{path}: {message}")]
    Manifest { path: PathBuf, message: String },
    #[error("accepting connections: {0}")]
    Accept(std::io::Error),
    /// A loopback server could not bind its port.
    #[error("binding a port on 127.0.0.1: {0}")]
    Bind(std::io::Error),
    /// A loopback server's task ended abnormally.
    #[error("server task: {0}")]
    Task(String),
}

/// For a database whose files are damaged: where to find every problem.
fn verify_hint(e: &db::DbError, root: &Path) -> String {
    match e {
        db::DbError::Format { .. } => format!(
            " (`railview verify {}` lists every problem)",
            root.display()
        ),
        _ => String::new(),
    }
}

/// Counters, readable while the server runs.
#[derive(Debug, Default)]
pub struct ServerStats {
    pub connections: AtomicU64,
    pub requests: AtomicU64,
    pub client_errors: AtomicU64,
    pub bytes_sent: AtomicU64,
    /// Responses that read object files (what `corrupt_every` counts), and those corrupted.
    pub object_responses: AtomicU64,
    pub corrupted: AtomicU64,
    /// Connections open now, and the most at once.
    pub open: AtomicU64,
    pub peak_open: AtomicU64,
    /// New connections answered `503` (no room, nothing to evict).
    pub refused: AtomicU64,
    /// Connections closed to make room for a new one.
    pub evicted: AtomicU64,
    /// Connections closed idle, with an incomplete head, with blocked writes, too slow.
    pub idle_timeouts: AtomicU64,
    pub header_timeouts: AtomicU64,
    pub write_timeouts: AtomicU64,
    pub too_slow: AtomicU64,
}

impl ServerStats {
    fn count_close(&self, reason: CloseReason) {
        let c = match reason {
            CloseReason::IdleTimeout => &self.idle_timeouts,
            CloseReason::HeaderTimeout => &self.header_timeouts,
            CloseReason::WriteTimeout => &self.write_timeouts,
            CloseReason::TooSlow => &self.too_slow,
            CloseReason::Evicted => &self.evicted,
        };
        c.fetch_add(1, Ordering::Relaxed);
    }

    /// One line for a log: connections, requests, closes by reason.
    pub fn summary(&self) -> String {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        format!(
            "{} connections (at most {} open), {} requests, {} client errors, {} bytes sent; \
             closed: {} idle, {} slow heads, {} stalled readers, {} too slow, {} evicted; {} refused",
            g(&self.connections),
            g(&self.peak_open),
            g(&self.requests),
            g(&self.client_errors),
            g(&self.bytes_sent),
            g(&self.idle_timeouts),
            g(&self.header_timeouts),
            g(&self.write_timeouts),
            g(&self.too_slow),
            g(&self.evicted),
            g(&self.refused),
        )
    }
}

/// A loaded database as the server sees it: the manifest bytes and the set of object hashes.
#[derive(Debug)]
pub struct ServedDb {
    root: PathBuf,
    manifest_bytes: Bytes,
    manifest_etag: String,
    /// `manifest.json.gz` and its ETag, when present and decompressing to `manifest_bytes`.
    manifest_gz: Option<(Bytes, String)>,
    /// `manifest.json.blake3`, when present.
    manifest_hash: Option<Bytes>,
}

impl ServedDb {
    /// Read and check `root/manifest.json`, the root of the index (through the database
    /// reader: version, limits, and the checksum file when present).
    pub fn open(root: &Path) -> Result<ServedDb, ServerError> {
        let err = |error: db::DbError| ServerError::Database {
            root: root.to_path_buf(),
            error,
        };
        // The bytes served are the bytes checked. Only the root is kept: objects are looked
        // up on disk as they are asked for, so what the server holds does not grow with the
        // database.
        // Every piece, table and ACH object is checked once, a chunk at a time.
        let (root_manifest, raw) = db::read_root(root).map_err(err)?;
        db::check_index(root, &root_manifest).map_err(err)?;
        let read_optional = |name: &str| -> Result<Option<Vec<u8>>, ServerError> {
            let path = root.join(name);
            if std::fs::metadata(&path).is_ok_and(|m| m.len() > tracks::limits::MAX_MANIFEST_BYTES)
            {
                return Err(ServerError::Manifest {
                    path,
                    message: format!("larger than {} bytes", tracks::limits::MAX_MANIFEST_BYTES),
                });
            }
            match std::fs::read(&path) {
                Ok(b) => Ok(Some(b)),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                Err(error) => Err(ServerError::Io { path, error }),
            }
        };
        let manifest_hash = read_optional(db::MANIFEST_HASH_FILE)?.map(Bytes::from);
        // A gzip copy that does not decode to the manifest's bytes is not served (and said so):
        // clients then get the identity body, which is always right.
        let manifest_gz = read_optional(db::MANIFEST_GZ_FILE)?.and_then(|gz| {
            match db::gunzip_limited(&gz, raw.len() as u64) {
                Ok(plain) if plain == raw => {
                    let etag = format!("\"gz-{}\"", blake3::hash(&gz).to_hex());
                    Some((Bytes::from(gz), etag))
                }
                Ok(_) => {
                    tracing::warn!(
                        "{}: does not decompress to manifest.json; serving it uncompressed",
                        root.join(db::MANIFEST_GZ_FILE).display()
                    );
                    None
                }
                Err(e) => {
                    tracing::warn!(
                        "{}: {e}; serving manifest.json uncompressed",
                        root.join(db::MANIFEST_GZ_FILE).display()
                    );
                    None
                }
            }
        });
        Ok(ServedDb {
            root: root.to_path_buf(),
            manifest_etag: format!("\"{}\"", blake3::hash(&raw).to_hex()),
            manifest_bytes: Bytes::from(raw),
            manifest_gz,
            manifest_hash,
        })
    }

    /// Whether `hash` names an object file of the database (a valid hash whose file is in
    /// `objects/`): what is served, as a static host serves the directory.
    pub fn has_object(&self, hash: &str) -> bool {
        object_rel_path(hash).is_some_and(|rel| self.root.join(rel).is_file())
    }

    /// Whether a valid `manifest.json.gz` is served to clients that accept gzip.
    pub fn serves_gzip_manifest(&self) -> bool {
        self.manifest_gz.is_some()
    }
}

/// Whether an `Accept-Encoding` value allows gzip (`gzip` or `x-gzip` listed without
/// `q=0`; `*` with a non-zero q and no explicit `gzip;q=0` counts too).
pub fn accepts_gzip(value: &str) -> bool {
    let mut star = false;
    for item in value.split(',') {
        let mut parts = item.split(';');
        let name = parts.next().unwrap_or("").trim().to_ascii_lowercase();
        let q_zero = parts.any(|p| {
            let p = p.trim();
            let Some(q) = p.strip_prefix("q=").or_else(|| p.strip_prefix("Q=")) else {
                return false;
            };
            q.trim().parse::<f64>().is_ok_and(|q| q <= 0.0)
        });
        match name.as_str() {
            "gzip" | "x-gzip" => return !q_zero,
            "*" => star = !q_zero,
            _ => {}
        }
    }
    star
}

impl Shared {
    /// What every connection shares; each site file's gzip, when that is smaller, is made
    /// here once.
    fn new(db: ServedDb, config: ServerConfig, stats: Arc<ServerStats>) -> Shared {
        let site_gz = config
            .site
            .iter()
            .map(|f| {
                db::gzip(f.body.as_bytes())
                    .ok()
                    .filter(|gz| gz.len() < f.body.len())
                    .map(bytes::Bytes::from)
            })
            .collect();
        Shared {
            db,
            config,
            stats,
            site_gz,
        }
    }
}

pub(crate) struct Shared {
    pub(crate) db: ServedDb,
    pub(crate) config: ServerConfig,
    pub(crate) stats: Arc<ServerStats>,
    /// Per site file (in `config.site`'s order), its gzip when that is smaller: sent to
    /// clients that accept gzip (the viewer's modules are a third of their size so, which is
    /// most of a first view's time on a slow link).
    pub(crate) site_gz: Vec<Option<bytes::Bytes>>,
}

/// Serve `db` on `listener` until `shutdown` completes, then drain open connections (up to
/// `config.drain_timeout`). Counters go to `stats` as the server runs.
pub async fn run(
    listener: TcpListener,
    db: ServedDb,
    config: ServerConfig,
    stats: Arc<ServerStats>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), ServerError> {
    let drain = config.drain_timeout;
    let limits = TimeLimits::new(
        config.idle_timeout,
        config.header_timeout,
        config.write_timeout,
        config.effective_min_send_rate(),
    );
    let clock = Clock::new();
    let registry = Arc::new(Mutex::new(Registry::default()));
    let shared = Arc::new(Shared::new(db, config, stats));
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut tasks = JoinSet::new();
    // The sweeper: closes connections that ran out of time, several times per shortest limit.
    let sweeper = {
        let registry = registry.clone();
        let shared = shared.clone();
        let every = [limits.header_ms, limits.write_ms, limits.idle_ms]
            .into_iter()
            .min()
            .unwrap_or(1000)
            .div_ceil(8)
            .clamp(10, 250);
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(every));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                let expired = lock(&registry).sweep(clock.now_ms(), &limits);
                for (conn, reason) in expired {
                    shared.stats.count_close(reason);
                    conn.close(reason);
                }
            }
        })
    };
    tokio::pin!(shutdown);
    loop {
        while tasks.try_join_next().is_some() {}
        let (stream, peer) = tokio::select! {
            _ = &mut shutdown => break,
            r = listener.accept() => match r {
                Ok(c) => c,
                Err(e) if is_transient(&e) => {
                    tracing::warn!("accept: {e}");
                    tokio::time::sleep(Duration::from_millis(20)).await;
                    continue;
                }
                Err(e) => {
                    sweeper.abort();
                    return Err(ServerError::Accept(e));
                }
            },
        };
        let admission = lock(&registry).admit(
            peer.ip(),
            clock.now_ms(),
            shared.config.max_connections,
            shared.config.max_connections_per_peer,
        );
        let (id, state) = match admission {
            Admission::Refuse => {
                shared.stats.refused.fetch_add(1, Ordering::Relaxed);
                // Best effort, never waiting: the socket is closed right after.
                let _ = stream.try_write(
                    b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\n\
                      Connection: close\r\nContent-Length: 0\r\n\r\n",
                );
                continue;
            }
            Admission::Admit { id, state, evicted } => {
                if let Some(old) = evicted {
                    shared.stats.count_close(CloseReason::Evicted);
                    old.close(CloseReason::Evicted);
                }
                (id, state)
            }
        };
        let open = lock(&registry).len() as u64;
        shared.stats.open.store(open, Ordering::Relaxed);
        shared.stats.peak_open.fetch_max(open, Ordering::Relaxed);
        let shared = shared.clone();
        let registry = registry.clone();
        let mut stop = stop_rx.clone();
        tasks.spawn(async move {
            shared.stats.connections.fetch_add(1, Ordering::Relaxed);
            let _ = stream.set_nodelay(true);
            let guarded = Guarded::new(stream, state.clone(), clock);
            let io = TokioIo::new(Shaped::new(guarded, shared.config.throttle_bps));
            let svc_shared = shared.clone();
            let svc_state = state.clone();
            let service = hyper::service::service_fn(move |req| {
                let s = svc_shared.clone();
                let st = svc_state.clone();
                async move {
                    st.start_response();
                    let resp = routes::handle(&s, req).await;
                    Ok::<_, Infallible>(resp.map(|b| b.report_to(st, clock)))
                }
            });
            let mut builder = hyper::server::conn::http1::Builder::new();
            // hyper's own head timeout counts from when it starts waiting for a request:
            // a backstop behind the sweeper's idle and header limits.
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(shared.config.idle_timeout + shared.config.header_timeout)
                .max_buf_size(shared.config.max_header_bytes.max(8192));
            let conn = builder.serve_connection(io, service);
            tokio::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r { tracing::debug!("connection: {e}"); }
                }
                reason = state.closed() => {
                    tracing::debug!("connection from {}: closed ({reason:?})", state.peer);
                }
                _ = async { let _ = stop.wait_for(|s| *s).await; } => {
                    conn.as_mut().graceful_shutdown();
                    tokio::select! {
                        r = conn.as_mut() => {
                            if let Err(e) = r { tracing::debug!("connection: {e}"); }
                        }
                        _ = state.closed() => {}
                    }
                }
            }
            let open = {
                let mut r = lock(&registry);
                r.remove(id);
                r.len() as u64
            };
            shared.stats.open.store(open, Ordering::Relaxed);
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let drained =
        tokio::time::timeout(drain, async { while tasks.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        tasks.abort_all();
    }
    sweeper.abort();
    Ok(())
}

fn lock(r: &Mutex<Registry>) -> MutexGuard<'_, Registry> {
    // Nothing panics while holding it; recover the data if something did.
    r.lock().unwrap_or_else(|p| p.into_inner())
}

fn is_transient(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        ConnectionAborted | ConnectionReset | Interrupted | WouldBlock
    ) || e.raw_os_error() == Some(24) // EMFILE: out of descriptors, retry later
}

#[cfg(test)]
mod tests {
    use super::accepts_gzip;

    #[test]
    fn accept_encoding_gzip() {
        for yes in [
            "gzip",
            "gzip, deflate, br",
            "br;q=1.0, GZIP;q=0.5",
            "x-gzip",
            "*",
            "deflate, *;q=0.1",
        ] {
            assert!(accepts_gzip(yes), "{yes}");
        }
        for no in [
            "",
            "identity",
            "deflate, br",
            "gzip;q=0",
            "gzip; q=0.000",
            "*;q=0",
            "gzip;q=0, *",
            "gzipx",
        ] {
            assert!(!accepts_gzip(no), "{no}");
        }
    }
}
