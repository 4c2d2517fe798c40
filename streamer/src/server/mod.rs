//! The HTTP tile server: serves a database directory (`manifest.json`, `objects/HH/HASH`).
//!
//! [`run`] takes a bound listener, the database, a [`ServerConfig`] and a shutdown future, in
//! the shape of a plain accept loop: a semaphore bounds the open connections, each
//! connection runs in its own task (one connection's error never stops the server), and the
//! shutdown future starts a graceful drain. Responses carry `ETag` = content hash and
//! `Cache-Control: immutable`, so any static server can stand in for this one; this one adds
//! per-connection bandwidth shaping and added latency for simulation. `/bundle?p=…`
//! (see [`parse_bundle_query`]) serves many objects or ranges in one response (one round trip for a batch of
//! small tiles); it is an optimisation only — a static host answers 404 and clients fall back
//! to one request per object.
//!
//! `GET /manifest.json` from a client whose `Accept-Encoding` allows gzip is answered with
//! `manifest.json.gz` (`Content-Encoding: gzip`, its own ETag, `Vary: Accept-Encoding`), as
//! nginx's `gzip_static on;` does with the same files; `/manifest.json.blake3` is served so a
//! client can check the decoded manifest.
//!
//! Paths are never taken from the request: an object request names a hash, the hash is
//! validated ([`tracks::manifest::object_rel_path`]) and must be one the manifest lists, and
//! only then is `DB/objects/HH/HASH` opened.

mod bundle;
mod range;
mod shape;

use std::collections::HashSet;
use std::convert::Infallible;
use std::future::Future;
use std::io::SeekFrom;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use bytes::Bytes;
use http_body_util::Full;
use hyper::body::Incoming;
use hyper::header::{self, HeaderValue};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncReadExt, AsyncSeekExt};
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;
use tracks::manifest::{object_rel_path, Manifest};

pub use bundle::{bundle_query, parse_bundle_query, BundleEntry, BundleError};
pub use range::{parse_range, RangeError};
pub use shape::{parse_duration, parse_rate, Shaped};

/// Server limits and simulation settings.
#[derive(Clone, Debug)]
pub struct ServerConfig {
    /// Open connections at most; further clients wait in the listen backlog.
    pub max_connections: usize,
    /// Time allowed to receive a request's headers.
    pub header_timeout: Duration,
    /// Largest request head (headers) accepted, bytes.
    pub max_header_bytes: usize,
    /// Largest response body (one range, one whole object or one bundle), bytes.
    pub max_range_bytes: u64,
    /// Entries one `/bundle` request may name at most.
    pub max_bundle_entries: usize,
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
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            max_connections: 256,
            header_timeout: Duration::from_secs(5),
            max_header_bytes: 16 * 1024,
            max_range_bytes: 64 << 20,
            max_bundle_entries: 256,
            bundles: true,
            throttle_bps: None,
            latency: Duration::ZERO,
            corrupt_every: None,
            drain_timeout: Duration::from_secs(5),
        }
    }
}

/// Errors that stop the server from starting or accepting.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServerError {
    #[error("reading {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a database manifest: {message}")]
    Manifest { path: PathBuf, message: String },
    #[error("accepting connections: {0}")]
    Accept(std::io::Error),
}

/// Counters, readable while the server runs.
#[derive(Debug, Default)]
pub struct ServerStats {
    pub connections: AtomicU64,
    pub requests: AtomicU64,
    pub client_errors: AtomicU64,
    pub bytes_sent: AtomicU64,
    pub corrupted: AtomicU64,
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
    objects: HashSet<String>,
}

impl ServedDb {
    /// Read and check `root/manifest.json` (through the database reader: version, and the
    /// checksum file when present); remember every object hash it lists.
    pub fn open(root: &Path) -> Result<ServedDb, ServerError> {
        let path = root.join("manifest.json");
        let err = |e: crate::db::DbError| ServerError::Manifest {
            path: path.clone(),
            message: e.to_string(),
        };
        let top = crate::db::read_top(root).map_err(err)?;
        let manifest: Manifest = crate::db::read_tables(root, &top).map_err(err)?;
        // The bytes served are the bytes checked (re-read: the reader does not return them).
        let raw = std::fs::read(&path).map_err(|source| ServerError::Io {
            path: path.clone(),
            source,
        })?;
        if crate::db::parse_top(&path, &raw).ok().as_ref() != Some(&top) {
            return Err(ServerError::Manifest {
                path,
                message: "changed while it was being opened".into(),
            });
        }
        let mut objects = manifest_objects(&manifest);
        for t in &top.tracks {
            objects.extend(t.viewpoints.iter().map(|v| v.table.hash.clone()));
            objects.extend(
                t.viewpoints
                    .iter()
                    .filter_map(|v| v.ach.as_ref().map(|a| a.hash.clone())),
            );
        }
        if let Some(bad) = objects.iter().find(|h| object_rel_path(h).is_none()) {
            return Err(ServerError::Manifest {
                path,
                message: format!("object hash `{bad}` is not 64 lowercase hex digits"),
            });
        }
        let read_optional = |name: &str| -> Result<Option<Vec<u8>>, ServerError> {
            let path = root.join(name);
            match std::fs::read(&path) {
                Ok(b) => Ok(Some(b)),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                Err(source) => Err(ServerError::Io { path, source }),
            }
        };
        let manifest_hash = read_optional(crate::db::MANIFEST_HASH_FILE)?.map(Bytes::from);
        // A gzip copy that does not decode to the manifest's bytes is not served (and said so):
        // clients then get the identity body, which is always right.
        let manifest_gz = read_optional(crate::db::MANIFEST_GZ_FILE)?.and_then(|gz| {
            match crate::db::gunzip_limited(&gz, raw.len() as u64) {
                Ok(plain) if plain == raw => {
                    let etag = format!("\"gz-{}\"", blake3::hash(&gz).to_hex());
                    Some((Bytes::from(gz), etag))
                }
                Ok(_) => {
                    tracing::warn!(
                        "{}: does not decompress to manifest.json; serving it uncompressed",
                        root.join(crate::db::MANIFEST_GZ_FILE).display()
                    );
                    None
                }
                Err(e) => {
                    tracing::warn!(
                        "{}: {e}; serving manifest.json uncompressed",
                        root.join(crate::db::MANIFEST_GZ_FILE).display()
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
            objects,
        })
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

/// Every object hash a manifest refers to.
pub fn manifest_objects(m: &Manifest) -> HashSet<String> {
    let mut out = HashSet::new();
    for t in &m.tracks {
        for vp in &t.viewpoints {
            for bg in &vp.background {
                out.insert(bg.ptm.object.hash.clone());
            }
            for tile in &vp.tiles {
                if let Some(p) = &tile.ptm {
                    out.insert(p.object.hash.clone());
                }
                if let Some(m) = &tile.mesh {
                    out.insert(m.hash.clone());
                }
            }
        }
    }
    out
}

struct Shared {
    db: ServedDb,
    config: ServerConfig,
    stats: Arc<ServerStats>,
}

/// Serve `db` on `listener` until `shutdown` completes, then drain open connections (up to
/// `config.drain_timeout`). Returns the counters.
pub async fn run(
    listener: TcpListener,
    db: ServedDb,
    config: ServerConfig,
    stats: Arc<ServerStats>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), ServerError> {
    let limit = Arc::new(Semaphore::new(config.max_connections.max(1)));
    let drain = config.drain_timeout;
    let shared = Arc::new(Shared { db, config, stats });
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut tasks = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        while tasks.try_join_next().is_some() {}
        let permit = tokio::select! {
            _ = &mut shutdown => break,
            p = limit.clone().acquire_owned() => match p {
                Ok(p) => p,
                Err(_) => break,
            },
        };
        let (stream, _peer) = tokio::select! {
            _ = &mut shutdown => break,
            r = listener.accept() => match r {
                Ok(c) => c,
                Err(e) if is_transient(&e) => {
                    tracing::warn!("accept: {e}");
                    tokio::time::sleep(Duration::from_millis(20)).await;
                    continue;
                }
                Err(e) => return Err(ServerError::Accept(e)),
            },
        };
        let shared = shared.clone();
        let mut stop = stop_rx.clone();
        tasks.spawn(async move {
            let _permit = permit;
            shared.stats.connections.fetch_add(1, Ordering::Relaxed);
            let _ = stream.set_nodelay(true);
            let io = TokioIo::new(Shaped::new(stream, shared.config.throttle_bps));
            let svc_shared = shared.clone();
            let service = hyper::service::service_fn(move |req| {
                let s = svc_shared.clone();
                async move { Ok::<_, Infallible>(handle(&s, req).await) }
            });
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(shared.config.header_timeout)
                .max_buf_size(shared.config.max_header_bytes.max(8192));
            let conn = builder.serve_connection(io, service);
            tokio::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r { tracing::debug!("connection: {e}"); }
                }
                _ = async { let _ = stop.wait_for(|s| *s).await; } => {
                    conn.as_mut().graceful_shutdown();
                    if let Err(e) = conn.as_mut().await { tracing::debug!("connection: {e}"); }
                }
            }
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let drained =
        tokio::time::timeout(drain, async { while tasks.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        tasks.abort_all();
    }
    Ok(())
}

fn is_transient(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        ConnectionAborted | ConnectionReset | Interrupted | WouldBlock
    ) || e.raw_os_error() == Some(24) // EMFILE: out of descriptors, retry later
}

type Resp = Response<Full<Bytes>>;

fn reply(status: StatusCode, reason: impl Into<String>) -> Resp {
    let mut r = Response::new(Full::new(Bytes::from(reason.into() + "\n")));
    *r.status_mut() = status;
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; charset=utf-8"),
    );
    r
}

async fn handle(s: &Shared, req: Request<Incoming>) -> Resp {
    s.stats.requests.fetch_add(1, Ordering::Relaxed);
    if !s.config.latency.is_zero() {
        tokio::time::sleep(s.config.latency).await;
    }
    let resp = route(s, &req).await;
    if resp.status().is_client_error() {
        s.stats.client_errors.fetch_add(1, Ordering::Relaxed);
    }
    use hyper::body::Body;
    let n = resp.body().size_hint().exact().unwrap_or(0);
    s.stats.bytes_sent.fetch_add(n, Ordering::Relaxed);
    resp
}

async fn route(s: &Shared, req: &Request<Incoming>) -> Resp {
    let head_only = req.method() == Method::HEAD;
    if req.method() != Method::GET && !head_only {
        return reply(
            StatusCode::METHOD_NOT_ALLOWED,
            "only GET and HEAD are served",
        );
    }
    let has_body = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .is_some_and(|v| v.as_bytes() != b"0")
        || req.headers().contains_key(header::TRANSFER_ENCODING);
    if has_body {
        return reply(
            StatusCode::PAYLOAD_TOO_LARGE,
            "request bodies are not accepted",
        );
    }
    let path = req.uri().path();
    if path.contains("..") || path.contains('\\') || path.contains("//") || path.contains('%') {
        return reply(
            StatusCode::BAD_REQUEST,
            "path must be /manifest.json, /manifest.json.blake3 or /objects/HH/HASH",
        );
    }
    let mut resp = if path == "/manifest.json" {
        manifest(s, req)
    } else if path == "/manifest.json.blake3" {
        match &s.db.manifest_hash {
            Some(b) => {
                let mut r = Response::new(Full::new(b.clone()));
                let h = r.headers_mut();
                h.insert(
                    header::CONTENT_TYPE,
                    HeaderValue::from_static("text/plain; charset=utf-8"),
                );
                h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
                r
            }
            None => reply(
                StatusCode::NOT_FOUND,
                "this database has no manifest.json.blake3",
            ),
        }
    } else if let Some(rest) = path.strip_prefix("/objects/") {
        match object(s, rest, req).await {
            Ok(r) => r,
            Err(r) => r,
        }
    } else if path == "/bundle" && s.config.bundles {
        match bundle(s, req).await {
            Ok(r) => r,
            Err(r) => r,
        }
    } else {
        reply(
            StatusCode::NOT_FOUND,
            "unknown path; served: /manifest.json, /manifest.json.blake3, /objects/HH/HASH, /bundle?p=…",
        )
    };
    if head_only {
        *resp.body_mut() = Full::new(Bytes::new());
    }
    resp
}

/// `/manifest.json`: the gzip copy when the client accepts it, else the identity bytes.
fn manifest(s: &Shared, req: &Request<Incoming>) -> Resp {
    let gzip_ok = req
        .headers()
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .any(|v| v.to_str().is_ok_and(accepts_gzip));
    let (body, etag, gz) = match &s.db.manifest_gz {
        Some((gz, etag)) if gzip_ok => (gz.clone(), etag.as_str(), true),
        _ => (
            s.db.manifest_bytes.clone(),
            s.db.manifest_etag.as_str(),
            false,
        ),
    };
    let mut r = Response::new(Full::new(body));
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
    if s.db.manifest_gz.is_some() {
        h.insert(header::VARY, HeaderValue::from_static("Accept-Encoding"));
    }
    if gz {
        h.insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    r
}

async fn object(s: &Shared, rest: &str, req: &Request<Incoming>) -> Result<Resp, Resp> {
    let bad = || {
        reply(
            StatusCode::BAD_REQUEST,
            "object id must be objects/HH/HASH with HASH 64 lowercase hex digits",
        )
    };
    let (hh, hash) = rest.split_once('/').ok_or_else(bad)?;
    let rel = object_rel_path(hash).ok_or_else(bad)?;
    if hh != &hash[..2] {
        return Err(bad());
    }
    if !s.db.objects.contains(hash) {
        return Err(reply(
            StatusCode::NOT_FOUND,
            format!("object {hash} is not in this database"),
        ));
    }
    let etag = format!("\"{hash}\"");
    if req
        .headers()
        .get(header::IF_NONE_MATCH)
        .is_some_and(|v| v.as_bytes() == etag.as_bytes() || v.as_bytes() == b"*")
    {
        let mut r = reply(StatusCode::NOT_MODIFIED, "");
        *r.body_mut() = Full::new(Bytes::new());
        add_object_headers(&mut r, &etag);
        return Ok(r);
    }
    let path = s.db.root.join(rel);
    let not_there = |e: std::io::Error| {
        tracing::warn!("{}: {e}", path.display());
        reply(
            StatusCode::NOT_FOUND,
            format!("object {hash} is listed but not readable"),
        )
    };
    let mut file = tokio::fs::File::open(&path).await.map_err(not_there)?;
    let size = file.metadata().await.map_err(not_there)?.len();
    let range = match req.headers().get(header::RANGE) {
        None => None,
        Some(v) => {
            let text = v
                .to_str()
                .map_err(|_| reply(StatusCode::BAD_REQUEST, "Range header is not ASCII"))?;
            match parse_range(text, size, s.config.max_range_bytes) {
                Ok(r) => Some(r),
                Err(e @ RangeError::Unsatisfiable { .. }) => {
                    let mut r = reply(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string());
                    if let Ok(v) = HeaderValue::from_str(&format!("bytes */{size}")) {
                        r.headers_mut().insert(header::CONTENT_RANGE, v);
                    }
                    return Err(r);
                }
                Err(e @ RangeError::TooLarge { .. }) => {
                    return Err(reply(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string()))
                }
                Err(e) => return Err(reply(StatusCode::BAD_REQUEST, e.to_string())),
            }
        }
    };
    let (offset, len) = range.unwrap_or((0, size));
    if len > s.config.max_range_bytes {
        return Err(reply(
            StatusCode::RANGE_NOT_SATISFIABLE,
            format!("object of {len} bytes is larger than the limit; ask for ranges"),
        ));
    }
    let mut data = vec![0u8; len as usize];
    file.seek(SeekFrom::Start(offset))
        .await
        .map_err(not_there)?;
    file.read_exact(&mut data).await.map_err(not_there)?;
    maybe_corrupt(s, &mut data);
    let mut r = Response::new(Full::new(Bytes::from(data)));
    add_object_headers(&mut r, &etag);
    if range.is_some() {
        *r.status_mut() = StatusCode::PARTIAL_CONTENT;
        let cr = format!("bytes {}-{}/{}", offset, offset + len - 1, size);
        if let Ok(v) = HeaderValue::from_str(&cr) {
            r.headers_mut().insert(header::CONTENT_RANGE, v);
        }
    }
    Ok(r)
}

/// `/bundle?p=…`: the named objects and ranges concatenated (see [`bundle`]'s module docs).
async fn bundle(s: &Shared, req: &Request<Incoming>) -> Result<Resp, Resp> {
    let query = req.uri().query().unwrap_or_default();
    let entries = parse_bundle_query(query, s.config.max_bundle_entries)
        .map_err(|e| reply(StatusCode::BAD_REQUEST, e.to_string()))?;
    let etag = format!("\"b3-{}\"", blake3::hash(query.as_bytes()).to_hex());
    if req
        .headers()
        .get(header::IF_NONE_MATCH)
        .is_some_and(|v| v.as_bytes() == etag.as_bytes() || v.as_bytes() == b"*")
    {
        let mut r = reply(StatusCode::NOT_MODIFIED, "");
        *r.body_mut() = Full::new(Bytes::new());
        add_object_headers(&mut r, &etag);
        return Ok(r);
    }
    let mut body = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        if !s.db.objects.contains(&e.object) {
            return Err(reply(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!(
                    "bundle entry {i}: object {} is not in this database",
                    e.object
                ),
            ));
        }
        let Some(rel) = object_rel_path(&e.object) else {
            return Err(reply(
                StatusCode::BAD_REQUEST,
                format!("bundle entry {i}: bad hash"),
            ));
        };
        let path = s.db.root.join(rel);
        let not_there = |err: std::io::Error| {
            tracing::warn!("{}: {err}", path.display());
            reply(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!(
                    "bundle entry {i}: object {} is listed but not readable",
                    e.object
                ),
            )
        };
        let mut file = tokio::fs::File::open(&path).await.map_err(not_there)?;
        let size = file.metadata().await.map_err(not_there)?.len();
        let (offset, len) = e.range.unwrap_or((0, size));
        if offset.checked_add(len).is_none_or(|end| end > size) {
            return Err(reply(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!(
                    "bundle entry {i}: range {offset}+{len} is outside the object of {size} bytes"
                ),
            ));
        }
        if body.len() as u64 + len > s.config.max_range_bytes {
            return Err(reply(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!(
                    "bundle is larger than the limit of {} bytes; ask for fewer entries",
                    s.config.max_range_bytes
                ),
            ));
        }
        let start = body.len();
        body.resize(start + len as usize, 0);
        file.seek(SeekFrom::Start(offset))
            .await
            .map_err(not_there)?;
        file.read_exact(&mut body[start..])
            .await
            .map_err(not_there)?;
    }
    maybe_corrupt(s, &mut body);
    let mut r = Response::new(Full::new(Bytes::from(body)));
    add_object_headers(&mut r, &etag);
    r.headers_mut().remove(header::ACCEPT_RANGES);
    Ok(r)
}

/// Fault injection (`ServerConfig::corrupt_every`): flip one byte of every n-th response body.
fn maybe_corrupt(s: &Shared, data: &mut [u8]) {
    if let Some(n) = s.config.corrupt_every.filter(|&n| n > 0) {
        let k = s.stats.requests.load(Ordering::Relaxed);
        if k.is_multiple_of(n) && !data.is_empty() {
            let i = (k as usize * 7919) % data.len();
            data[i] ^= 0x5a;
            s.stats.corrupted.fetch_add(1, Ordering::Relaxed);
        }
    }
}

fn add_object_headers(r: &mut Resp, etag: &str) {
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/octet-stream"),
    );
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("public, max-age=31536000, immutable"),
    );
    h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
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
