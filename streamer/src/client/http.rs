//! One HTTP/1 connection to a database server, with reconnect and back-off, and checked
//! downloads: every body is hashed (BLAKE3) and compared with the hash the manifest gives
//! before anyone sees it. The manifest itself is asked for gzip-compressed
//! ([`Connection::fetch_manifest`]), decompressed within a size limit and checked against
//! `manifest.json.blake3`.
//!
//! Nothing waits forever ([`RetryPolicy`]): connecting, the response head and every gap
//! between body bytes have their own timeout, and one request's retries (connection
//! failures, timeouts, 5xx) stop after `give_up_after`. Failures fall in two kinds
//! ([`ClientError::is_object_fault`]): the server is unreachable (retried here, then
//! [`ClientError::GaveUp`]), or one object is damaged or missing (checksum mismatch, 404,
//! a range outside the file: not retried here; a scheduler counts it per part, tries again
//! later and gives up, [`super::failures`]). What the retries cost is kept per connection
//! ([`Connection::take_report`]: attempts, retries, timeouts, time the server was
//! unreachable) for the caller's report.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::{Bytes, BytesMut};
use http_body_util::{BodyExt, Empty};
use hyper::client::conn::http1::SendRequest;
use hyper::{header, Request, StatusCode};
use hyper_util::rt::TokioIo;
use tokio::net::TcpStream;
use tracks::manifest::{object_rel_path, Manifest, ObjectRef};

use db::hash_matches;
use db::split::{assemble, decode_table, TopManifest, ViewTable};

mod ranges;
pub use ranges::{RangePiece, MULTI_GAP_BYTES, SINGLE_GAP_BYTES};

/// What one GET asks for: the whole object, one byte range `(offset, len)`, or a `Range:`
/// header of several ranges.
#[derive(Clone, Copy, Debug)]
enum Ask<'a> {
    Whole,
    One((u64, u64)),
    Ranges(&'a str),
}

/// The head of an answer: its status and the headers a range answer is read by.
#[derive(Clone, Debug, Default)]
struct Head {
    status: u16,
    content_type: Option<String>,
    content_range: Option<String>,
}

/// Where a database is served: `http://HOST:PORT[/PREFIX]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerUrl {
    /// `host:port` to connect to.
    pub authority: String,
    /// Path prefix without a trailing slash (may be empty).
    pub prefix: String,
}

impl ServerUrl {
    /// Parse `http://host:port/prefix` (only plain `http`; port defaults to 80).
    pub fn parse(text: &str) -> Result<ServerUrl, ClientError> {
        let bad = |why: &str| ClientError::Url(format!("`{text}`: {why}"));
        let rest = text
            .strip_prefix("http://")
            .ok_or_else(|| bad("only http:// URLs are supported"))?;
        let (auth, path) = match rest.find('/') {
            Some(i) => (&rest[..i], &rest[i..]),
            None => (rest, ""),
        };
        if auth.is_empty() || auth.contains('@') {
            return Err(bad("missing or unsupported host"));
        }
        let authority = if auth
            .rsplit_once(':')
            .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
        {
            auth.to_string()
        } else if auth.contains(':') && !auth.starts_with('[') {
            return Err(bad("port is not a number"));
        } else {
            format!("{auth}:80")
        };
        Ok(ServerUrl {
            authority,
            prefix: path.trim_end_matches('/').to_string(),
        })
    }

    fn host(&self) -> &str {
        &self.authority
    }
}

/// What a client asks for: a whole object or one byte range of it, and the hash its bytes
/// must have.
///
/// Clients look keys up tens of thousands of times a frame (what is held, pinned, wanted), so
/// a key is cheap to clone (the object id is shared) and to hash (its first 16 hex digits
/// and the range; equal keys agree on them), and the maps keyed by it ([`KeyMap`],
/// [`KeySet`]) use a fast non-cryptographic hasher.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct FetchKey {
    /// Object hash (64 lowercase hex digits).
    pub object: Arc<str>,
    /// `(offset, len)`; `None` = the whole object.
    pub range: Option<(u64, u64)>,
}

impl std::hash::Hash for FetchKey {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        let id = self.object.as_bytes();
        state.write(&id[..id.len().min(16)]);
        self.range.hash(state);
    }
}

/// A map keyed by [`FetchKey`] (fast hashing; the keys come from the manifests the user
/// chose to open).
pub type KeyMap<V> = std::collections::HashMap<FetchKey, V, foldhash::fast::RandomState>;
/// A set of [`FetchKey`]s (see [`KeyMap`]).
pub type KeySet = std::collections::HashSet<FetchKey, foldhash::fast::RandomState>;

/// Client failures.
#[derive(Debug, Clone, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    #[error("bad server URL {0}")]
    Url(String),
    #[error("object id `{0}` is not a valid hash")]
    BadObject(String),
    #[error("connecting to {addr}: {message}")]
    Connect { addr: String, message: String },
    #[error("{path}: HTTP {status}: {reason}")]
    Status {
        path: String,
        status: u16,
        reason: String,
    },
    #[error("{path}: {message}")]
    Transfer { path: String, message: String },
    #[error("{path}: checksum mismatch {attempts} times in a row")]
    Checksum { path: String, attempts: u32 },
    #[error("{path}: response of {len} bytes, expected {expected}")]
    Length {
        path: String,
        len: u64,
        expected: u64,
    },
    #[error("manifest: {0}")]
    Manifest(String),
    /// A compressed body that would decompress to more than the limit (never held whole).
    #[error("{path}: decompresses to more than {limit} bytes")]
    DecodedTooLarge { path: String, limit: u64 },
    /// No response head within the response timeout, or no body byte within the stall
    /// timeout.
    #[error("{path}: {what} within {:.1} s", after.as_secs_f64())]
    Timeout {
        path: String,
        what: &'static str,
        after: Duration,
    },
    #[error("request cancelled")]
    Cancelled,
    #[error("gave up after {attempts} attempts in {seconds:.1} s: {last}")]
    GaveUp {
        attempts: u32,
        seconds: f64,
        last: Box<ClientError>,
    },
}

impl ClientError {
    /// Whether trying again (after reconnecting) may help: the connection failed, timed out
    /// or the server answered 5xx.
    pub fn is_retryable(&self) -> bool {
        match self {
            ClientError::Connect { .. }
            | ClientError::Transfer { .. }
            | ClientError::Timeout { .. } => true,
            ClientError::Status { status, .. } => *status >= 500,
            _ => false,
        }
    }

    /// Whether the failure is the object's, not the server's: its bytes fail their checksum
    /// or length, or the server refuses it with a 4xx (missing, range outside the file).
    /// Other objects may still arrive; this one is counted and tried again later.
    pub fn is_object_fault(&self) -> bool {
        match self {
            ClientError::Checksum { .. }
            | ClientError::Length { .. }
            | ClientError::BadObject(_)
            | ClientError::DecodedTooLarge { .. } => true,
            ClientError::Status { status, .. } => (400..500).contains(status),
            _ => false,
        }
    }

    /// Whether the server could not be reached within the retry policy (nothing else will
    /// arrive from it now).
    pub fn is_unreachable(&self) -> bool {
        matches!(self, ClientError::GaveUp { .. }) || self.is_retryable()
    }
}

/// Retry, back-off and timeout settings.
#[derive(Clone, Debug)]
pub struct RetryPolicy {
    /// Attempts per request (connection failures, timeouts and 5xx), at least 1.
    pub attempts: u32,
    pub backoff_start: Duration,
    pub backoff_max: Duration,
    /// Retries of one request stop once this much time has passed since it started.
    pub give_up_after: Duration,
    /// Time to open a connection.
    pub connect_timeout: Duration,
    /// Time from sending a request to its response head.
    pub response_timeout: Duration,
    /// Longest gap between two pieces of a response body (a stalled transfer).
    pub stall_timeout: Duration,
    /// Re-downloads after a checksum mismatch before giving up.
    pub checksum_attempts: u32,
    /// Longest body accepted, bytes.
    pub max_body: u64,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        RetryPolicy {
            attempts: 12,
            backoff_start: Duration::from_millis(25),
            backoff_max: Duration::from_secs(1),
            give_up_after: Duration::from_secs(30),
            connect_timeout: Duration::from_secs(5),
            response_timeout: Duration::from_secs(10),
            stall_timeout: Duration::from_secs(10),
            checksum_attempts: 4,
            max_body: 256 << 20,
        }
    }
}

/// Counters shared by all connections of a client.
#[derive(Debug, Default)]
pub struct ClientStats {
    pub requests: AtomicU64,
    pub bytes: AtomicU64,
    pub checksum_failures: AtomicU64,
    pub reconnects: AtomicU64,
    /// Attempts retried after a connection failure, timeout or 5xx.
    pub retries: AtomicU64,
    /// Of those, timeouts (no response head, or a stalled body).
    pub timeouts: AtomicU64,
    /// Requests given up after the retry policy ran out.
    pub gave_up: AtomicU64,
    /// Milliseconds requests spent failing before they succeeded or gave up.
    pub outage_ms: AtomicU64,
}

/// What the requests of a connection cost in retries since the last
/// [`Connection::take_report`] (one fetch, for the caller that takes it after each).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TransferReport {
    /// HTTP attempts made.
    pub attempts: u32,
    /// Attempts that failed (connection, timeout, 5xx) and were tried again.
    pub retries: u32,
    /// Of the failed attempts, timeouts.
    pub timeouts: u32,
    /// Wall-clock seconds from each request's first failed attempt to its success or
    /// give-up, summed: how long the server was unreachable for these requests (0 when
    /// nothing failed, so a healthy transfer adds nothing).
    pub outage_s: f64,
}

impl TransferReport {
    /// Both reports together.
    pub fn add(&mut self, o: &TransferReport) {
        self.attempts += o.attempts;
        self.retries += o.retries;
        self.timeouts += o.timeouts;
        self.outage_s += o.outage_s;
    }
}

/// One piece of a bundle: what to fetch, its exact length and the hash it must have.
#[derive(Clone, Copy, Debug)]
pub struct BundlePiece<'a> {
    pub key: &'a FetchKey,
    pub len: u64,
    pub hash: &'a str,
}

/// A downloaded, checked top manifest and what it cost.
#[derive(Clone, Debug)]
pub struct ManifestFetch {
    pub top: TopManifest,
    /// Body bytes received for it (the checksum file and every attempt included).
    pub transferred_bytes: u64,
    /// Requests it took (the checksum file included).
    pub requests: u64,
    /// Round trips they took: the checksum file travels beside the first manifest request,
    /// so 1 unless the manifest had to be fetched again.
    pub round_trips: u64,
    /// Length of the decoded `manifest.json`.
    pub json_bytes: u64,
    /// Whether the accepted body came gzip-encoded.
    pub gzip: bool,
    /// Whether it was checked against `manifest.json.blake3` (`false`: the server has none).
    pub checked: bool,
}

/// One keep-alive connection, reopened on demand.
pub struct Connection {
    url: ServerUrl,
    sender: Option<SendRequest<Empty<Bytes>>>,
    policy: RetryPolicy,
    stats: Arc<ClientStats>,
    /// The server answered `/bundle` with 404/405/501 (a static host): fetch piece by piece.
    no_bundles: bool,
    /// Whether the server answers several ranges in one request (`None`: not tried yet).
    multi_ranges: Option<bool>,
    /// Retries and outage since the last [`Connection::take_report`].
    report: TransferReport,
}

impl Connection {
    pub fn new(url: ServerUrl, policy: RetryPolicy, stats: Arc<ClientStats>) -> Connection {
        Connection {
            url,
            sender: None,
            policy,
            stats,
            no_bundles: false,
            multi_ranges: None,
            report: TransferReport::default(),
        }
    }

    /// The retry policy (timeouts included).
    pub fn policy(&self) -> &RetryPolicy {
        &self.policy
    }

    /// What the requests since the last call cost in attempts, retries, timeouts and
    /// outage, and start counting again.
    pub fn take_report(&mut self) -> TransferReport {
        std::mem::take(&mut self.report)
    }

    /// The counters this connection adds to.
    pub fn stats(&self) -> &Arc<ClientStats> {
        &self.stats
    }

    /// Whether this server serves `/bundle` (as far as this connection has seen).
    pub fn bundles_supported(&self) -> bool {
        !self.no_bundles
    }

    async fn connect(&mut self) -> Result<&mut SendRequest<Empty<Bytes>>, ClientError> {
        if self
            .sender
            .as_ref()
            .is_some_and(|s| s.is_closed() || !s.is_ready())
        {
            self.sender = None;
        }
        if self.sender.is_none() {
            let addr = self.url.authority.clone();
            let err = |e: &dyn std::fmt::Display| ClientError::Connect {
                addr: addr.clone(),
                message: e.to_string(),
            };
            let limit = self.policy.connect_timeout;
            let timed_out = || ClientError::Connect {
                addr: addr.clone(),
                message: format!("no connection within {:.1} s", limit.as_secs_f64()),
            };
            let stream = tokio::time::timeout(limit, TcpStream::connect(&addr))
                .await
                .map_err(|_| timed_out())?
                .map_err(|e| err(&e))?;
            let _ = stream.set_nodelay(true);
            let (sender, conn) = tokio::time::timeout(
                limit,
                hyper::client::conn::http1::handshake(TokioIo::new(stream)),
            )
            .await
            .map_err(|_| timed_out())?
            .map_err(|e| err(&e))?;
            tokio::spawn(async move {
                if let Err(e) = conn.await {
                    tracing::debug!("client connection: {e}");
                }
            });
            self.stats.reconnects.fetch_add(1, Ordering::Relaxed);
            self.sender = Some(sender);
        }
        self.sender.as_mut().ok_or(ClientError::Cancelled)
    }

    /// One GET, no retry: the body, whether it is gzip-encoded, and the head. `cancel` is
    /// checked between body chunks; a cancelled transfer drops the connection (the rest of
    /// the body would otherwise block it).
    async fn get_once(
        &mut self,
        path: &str,
        ask: Ask<'_>,
        cancel: Option<&AtomicBool>,
        accept_gzip: bool,
    ) -> Result<(Bytes, bool, Head), ClientError> {
        let max_body = self.policy.max_body;
        let host = self.url.host().to_string();
        // Errors name the whole URL: which server, which object.
        let url = format!("http://{host}{path}");
        let path = url.as_str();
        let request_path = &url[7 + host.len()..];
        let tr = |m: &dyn std::fmt::Display| ClientError::Transfer {
            path: path.to_string(),
            message: m.to_string(),
        };
        let mut builder = Request::get(request_path).header(header::HOST, host.clone());
        match ask {
            Ask::Whole => {}
            Ask::One((_, 0)) => return Ok((Bytes::new(), false, Head::default())),
            Ask::One((off, len)) => {
                builder = builder.header(header::RANGE, format!("bytes={}-{}", off, off + len - 1))
            }
            Ask::Ranges(text) => builder = builder.header(header::RANGE, text),
        }
        if accept_gzip {
            builder = builder.header(header::ACCEPT_ENCODING, "gzip");
        }
        let req = builder.body(Empty::new()).map_err(|e| tr(&e))?;
        let response_timeout = self.policy.response_timeout;
        let stall_timeout = self.policy.stall_timeout;
        let timeout = |what: &'static str, after: Duration| ClientError::Timeout {
            path: path.to_string(),
            what,
            after,
        };
        let sender = self.connect().await?;
        let sent = tokio::time::timeout(response_timeout, async {
            sender.ready().await?;
            sender.send_request(req).await
        })
        .await;
        let resp = match sent {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => {
                self.sender = None;
                return Err(tr(&e));
            }
            Err(_) => {
                self.sender = None;
                return Err(timeout("no response", response_timeout));
            }
        };
        let stalled = || timeout("transfer stalled: no bytes", stall_timeout);
        let status = resp.status();
        let encoding = resp.headers().get(header::CONTENT_ENCODING).map(|v| {
            String::from_utf8_lossy(v.as_bytes())
                .trim()
                .to_ascii_lowercase()
        });
        let gzip = match encoding.as_deref() {
            None | Some("identity") => false,
            Some("gzip" | "x-gzip") if accept_gzip => true,
            Some(other) if status.is_success() => {
                self.sender = None;
                return Err(ClientError::Transfer {
                    path: path.to_string(),
                    message: format!("unrequested Content-Encoding `{other}`"),
                });
            }
            Some(_) => false,
        };
        let ok = match ask {
            Ask::Whole => status == StatusCode::OK,
            Ask::One(_) => status == StatusCode::PARTIAL_CONTENT,
            // Several ranges may come back as one, as several, or as the whole object.
            Ask::Ranges(_) => matches!(status, StatusCode::OK | StatusCode::PARTIAL_CONTENT),
        };
        let text = |name: header::HeaderName| {
            resp.headers().get(name).map(|v| {
                String::from_utf8_lossy(v.as_bytes())
                    .chars()
                    .take(256)
                    .collect()
            })
        };
        let head = Head {
            status: status.as_u16(),
            content_type: text(header::CONTENT_TYPE),
            content_range: text(header::CONTENT_RANGE),
        };
        let mut body = resp.into_body();
        if !ok {
            let mut reason = Vec::new();
            while let Ok(Some(f)) = tokio::time::timeout(stall_timeout, body.frame()).await {
                match f {
                    Ok(f) => {
                        if let Some(d) = f.data_ref() {
                            reason
                                .extend_from_slice(&d[..d.len().min(512 - reason.len().min(512))]);
                        }
                    }
                    Err(_) => {
                        self.sender = None;
                        break;
                    }
                }
            }
            {
                use hyper::body::Body as _;
                if !body.is_end_stream() {
                    self.sender = None;
                }
            }
            return Err(ClientError::Status {
                path: path.to_string(),
                status: status.as_u16(),
                reason: String::from_utf8_lossy(&reason).trim().to_string(),
            });
        }
        let mut out = BytesMut::new();
        loop {
            let frame = match tokio::time::timeout(stall_timeout, body.frame()).await {
                Ok(Some(f)) => f,
                Ok(None) => break,
                Err(_) => {
                    self.sender = None;
                    return Err(stalled());
                }
            };
            if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                self.sender = None;
                return Err(ClientError::Cancelled);
            }
            let frame = match frame {
                Ok(f) => f,
                Err(e) => {
                    self.sender = None;
                    return Err(tr(&e));
                }
            };
            if let Some(d) = frame.data_ref() {
                if out.len() as u64 + d.len() as u64 > max_body {
                    self.sender = None;
                    return Err(tr(&format!("body longer than {max_body} bytes")));
                }
                out.extend_from_slice(d);
            }
        }
        self.stats.requests.fetch_add(1, Ordering::Relaxed);
        self.stats
            .bytes
            .fetch_add(out.len() as u64, Ordering::Relaxed);
        Ok((out.freeze(), gzip, head))
    }

    /// GET with reconnect and exponential back-off on connection errors and 5xx.
    pub async fn get(
        &mut self,
        path: &str,
        range: Option<(u64, u64)>,
        cancel: Option<&AtomicBool>,
    ) -> Result<Bytes, ClientError> {
        let ask = range.map_or(Ask::Whole, Ask::One);
        Ok(self.get_retrying(path, ask, cancel, false).await?.0)
    }

    /// [`Connection::get`], optionally accepting a gzip body: `(body as sent, gzip-encoded)`.
    async fn get_retrying(
        &mut self,
        path: &str,
        ask: Ask<'_>,
        cancel: Option<&AtomicBool>,
        accept_gzip: bool,
    ) -> Result<(Bytes, bool, Head), ClientError> {
        let full = format!("{}{}", self.url.prefix, path);
        let mut delay = self.policy.backoff_start;
        let attempts = self.policy.attempts.max(1);
        let started = Instant::now();
        // When the first attempt failed: the server unreachable from then on.
        let mut failing_since: Option<Instant> = None;
        let mut attempt = 0;
        let result = loop {
            attempt += 1;
            self.report.attempts += 1;
            match self.get_once(&full, ask, cancel, accept_gzip).await {
                Ok(b) => break Ok(b),
                Err(e) if e.is_retryable() => {
                    failing_since.get_or_insert_with(Instant::now);
                    if matches!(e, ClientError::Timeout { .. }) {
                        self.report.timeouts += 1;
                        self.stats.timeouts.fetch_add(1, Ordering::Relaxed);
                    }
                    self.sender = None;
                    let out_of_time = started.elapsed() + delay > self.policy.give_up_after;
                    if attempt >= attempts || out_of_time {
                        self.stats.gave_up.fetch_add(1, Ordering::Relaxed);
                        break Err(ClientError::GaveUp {
                            attempts: attempt,
                            seconds: started.elapsed().as_secs_f64(),
                            last: Box::new(e),
                        });
                    }
                    tracing::debug!("{full}: {e}; retrying in {delay:?}");
                    self.report.retries += 1;
                    self.stats.retries.fetch_add(1, Ordering::Relaxed);
                    tokio::time::sleep(delay).await;
                    delay = (delay * 2).min(self.policy.backoff_max);
                    if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                        break Err(ClientError::Cancelled);
                    }
                }
                Err(e) => break Err(e),
            }
        };
        if let Some(since) = failing_since {
            let lost = since.elapsed();
            self.report.outage_s += lost.as_secs_f64();
            self.stats
                .outage_ms
                .fetch_add(lost.as_millis() as u64, Ordering::Relaxed);
        }
        result
    }

    /// Download `key` and check it against `expected_hash`; a mismatch is re-downloaded
    /// (up to `checksum_attempts` times) and never returned.
    pub async fn fetch_checked(
        &mut self,
        key: &FetchKey,
        expected_hash: &str,
        cancel: Option<&AtomicBool>,
    ) -> Result<Bytes, ClientError> {
        let rel = object_rel_path(&key.object)
            .ok_or_else(|| ClientError::BadObject(key.object.to_string()))?;
        let path = format!("/{rel}");
        let attempts = self.policy.checksum_attempts.max(1);
        for _ in 0..attempts {
            let data = self.get(&path, key.range, cancel).await?;
            if let Some((_, len)) = key.range {
                if data.len() as u64 != len {
                    self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
            }
            if hash_matches(&data, expected_hash) {
                return Ok(data);
            }
            self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
            tracing::warn!("{path}: checksum mismatch, fetching again");
        }
        Err(ClientError::Checksum { path, attempts })
    }

    /// Download consecutive byte ranges of one object in a single request and check each
    /// range against its own hash: `parts` are `(offset, len, hash)`, each starting where the
    /// previous one ends. A mismatch anywhere re-downloads the whole run (up to
    /// `checksum_attempts` times); nothing that failed its check is returned. One request
    /// instead of one per PTM level saves a round trip per level.
    pub async fn fetch_checked_run(
        &mut self,
        object: &str,
        parts: &[(u64, u64, &str)],
        cancel: Option<&AtomicBool>,
    ) -> Result<Vec<Bytes>, ClientError> {
        let rel =
            object_rel_path(object).ok_or_else(|| ClientError::BadObject(object.to_string()))?;
        let path = format!("/{rel}");
        let Some(&(start, _, _)) = parts.first() else {
            return Ok(Vec::new());
        };
        let mut end = start;
        for &(off, len, _) in parts {
            if off != end {
                return Err(ClientError::Transfer {
                    path,
                    message: format!("ranges not consecutive at offset {off} (expected {end})"),
                });
            }
            end = off.checked_add(len).ok_or_else(|| ClientError::Transfer {
                path: path.clone(),
                message: format!("range {off}+{len} overflows"),
            })?;
        }
        let attempts = self.policy.checksum_attempts.max(1);
        'attempt: for _ in 0..attempts {
            let data = self.get(&path, Some((start, end - start)), cancel).await?;
            if data.len() as u64 != end - start {
                self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            let mut out = Vec::with_capacity(parts.len());
            for &(off, len, hash) in parts {
                let piece = data.slice((off - start) as usize..(off - start + len) as usize);
                if !hash_matches(&piece, hash) {
                    self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("{path}: checksum mismatch at offset {off}, fetching again");
                    continue 'attempt;
                }
                out.push(piece);
            }
            return Ok(out);
        }
        Err(ClientError::Checksum { path, attempts })
    }

    /// Download many pieces (whole objects or ranges, of any objects) in one `/bundle`
    /// request and check each against its own hash; consecutive ranges of one object travel
    /// as one entry. A mismatch anywhere (or a body of the wrong length) re-downloads the
    /// bundle, up to `checksum_attempts` times; nothing that failed its check is returned.
    /// A server without `/bundle` (a static host: 404, 405 or 501) is remembered, and the
    /// pieces are then fetched one object at a time, an object's ranges together
    /// ([`Connection::fetch_checked_ranges`]: several per request where the server answers
    /// them as `multipart/byteranges`).
    pub async fn fetch_checked_bundle(
        &mut self,
        pieces: &[BundlePiece<'_>],
        cancel: Option<&AtomicBool>,
    ) -> Result<Vec<Bytes>, ClientError> {
        if pieces.is_empty() {
            return Ok(Vec::new());
        }
        for p in pieces {
            if object_rel_path(&p.key.object).is_none() {
                return Err(ClientError::BadObject(p.key.object.to_string()));
            }
            if p.key.range.is_some_and(|(_, len)| len != p.len) {
                return Err(ClientError::Transfer {
                    path: "/bundle".into(),
                    message: format!("{}: range length differs from {}", p.key.object, p.len),
                });
            }
        }
        if !self.no_bundles {
            match self.bundle_once_checked(pieces, cancel).await {
                Err(ClientError::Status { status, .. }) if matches!(status, 404 | 405 | 501) => {
                    tracing::info!("server has no /bundle ({status}); fetching object by object");
                    self.no_bundles = true;
                }
                other => return other,
            }
        }
        // One object at a time: whole objects alone, an object's ranges together (several
        // ranges per request where the server answers them, else runs merged across small
        // gaps: [`Connection::fetch_checked_ranges`]).
        let mut out: Vec<Option<Bytes>> = vec![None; pieces.len()];
        let mut objects: Vec<&str> = Vec::new();
        for p in pieces {
            if !objects.contains(&&*p.key.object) {
                objects.push(&p.key.object);
            }
        }
        for object in objects {
            let mut ranged = Vec::new();
            for (i, p) in pieces.iter().enumerate() {
                if &*p.key.object != object {
                    continue;
                }
                match p.key.range {
                    None => out[i] = Some(self.fetch_checked(p.key, p.hash, cancel).await?),
                    Some((off, len)) => ranged.push((i, (off, len, p.hash))),
                }
            }
            if ranged.is_empty() {
                continue;
            }
            let run: Vec<RangePiece> = ranged.iter().map(|r| r.1).collect();
            let got = self
                .fetch_checked_ranges(object, None, &run, cancel)
                .await?;
            for ((i, _), b) in ranged.into_iter().zip(got) {
                out[i] = Some(b);
            }
        }
        Ok(out.into_iter().flatten().collect())
    }

    /// Each piece's own result, in order. One `/bundle` (or, on a static host, one request
    /// per object or range run) when everything checks out; when that fails for one
    /// object's fault (a checksum that keeps failing, a missing object, a range outside its
    /// file), the pieces are fetched one by one so that only the damaged ones fail. Once the
    /// server is unreachable, the pieces not yet fetched fail with the same error without
    /// being tried each.
    pub async fn fetch_pieces(
        &mut self,
        pieces: &[BundlePiece<'_>],
        cancel: Option<&AtomicBool>,
    ) -> Vec<Result<Bytes, ClientError>> {
        match self.fetch_checked_bundle(pieces, cancel).await {
            Ok(v) => v.into_iter().map(Ok).collect(),
            Err(e) if e.is_object_fault() && pieces.len() > 1 => {
                tracing::warn!(
                    "{} pieces in one request failed ({e}); fetching them one by one",
                    pieces.len()
                );
                let mut out = Vec::with_capacity(pieces.len());
                let mut fatal: Option<ClientError> = None;
                for p in pieces {
                    if let Some(e) = &fatal {
                        out.push(Err(e.clone()));
                        continue;
                    }
                    let r = self.fetch_checked(p.key, p.hash, cancel).await;
                    if let Err(e) = &r {
                        if !e.is_object_fault() {
                            fatal = Some(e.clone());
                        }
                    }
                    out.push(r);
                }
                out
            }
            Err(e) => pieces.iter().map(|_| Err(e.clone())).collect(),
        }
    }

    async fn bundle_once_checked(
        &mut self,
        pieces: &[BundlePiece<'_>],
        cancel: Option<&AtomicBool>,
    ) -> Result<Vec<Bytes>, ClientError> {
        // Entries: consecutive ranges of one object merged.
        let mut entries: Vec<crate::server::BundleEntry> = Vec::new();
        for (k, p) in pieces.iter().enumerate() {
            if k > 0 && consecutive(&pieces[k - 1], p) {
                if let Some(Some((_, len))) = entries.last_mut().map(|e| e.range.as_mut()) {
                    *len += p.len;
                    continue;
                }
            }
            entries.push(crate::server::BundleEntry {
                object: p.key.object.to_string(),
                range: p.key.range,
            });
        }
        let path = format!("/bundle?{}", crate::server::bundle_query(&entries));
        let total: u64 = pieces.iter().map(|p| p.len).sum();
        let attempts = self.policy.checksum_attempts.max(1);
        'attempt: for _ in 0..attempts {
            let data = self.get(&path, None, cancel).await?;
            if data.len() as u64 != total {
                self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    "/bundle: {} bytes, expected {total}; fetching again",
                    data.len()
                );
                continue;
            }
            let mut out = Vec::with_capacity(pieces.len());
            let mut at = 0usize;
            for p in pieces {
                let piece = data.slice(at..at + p.len as usize);
                at += p.len as usize;
                if !hash_matches(&piece, p.hash) {
                    self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        "/bundle: checksum mismatch in {}, fetching again",
                        p.key.object
                    );
                    continue 'attempt;
                }
                out.push(piece);
            }
            return Ok(out);
        }
        Err(ClientError::Checksum {
            path: "/bundle".into(),
            attempts,
        })
    }

    /// The whole manifest: the top ([`Connection::fetch_manifest`]) and every viewpoint's
    /// table ([`Connection::fetch_table`]) and ACH object ([`Connection::fetch_ach`]),
    /// assembled (for tools that want everything at once; a viewer fetches tables as it
    /// needs them).
    pub async fn manifest(&mut self) -> Result<Manifest, ClientError> {
        let top = self.fetch_manifest().await?.top;
        let mut tables = Vec::with_capacity(top.tracks.len());
        for t in &top.tracks {
            let mut row = Vec::with_capacity(t.viewpoints.len());
            for v in &t.viewpoints {
                let mut table = self.fetch_table(&v.table, v.index).await?;
                if let Some(ach) = &v.ach {
                    table.segments = self.fetch_ach(ach, v.index).await?;
                }
                row.push(table);
            }
            tables.push(row);
        }
        let refs: Vec<Vec<Option<&ViewTable>>> = tables
            .iter()
            .map(|row| row.iter().map(Some).collect())
            .collect();
        Ok(assemble(&top, &refs))
    }

    /// Download viewpoint `viewpoint`'s table object, check it against its hash (re-fetched
    /// on mismatch, never used when wrong) and decode it.
    pub async fn fetch_table(
        &mut self,
        table: &ObjectRef,
        viewpoint: usize,
    ) -> Result<ViewTable, ClientError> {
        let key = FetchKey {
            object: table.hash.as_str().into(),
            range: None,
        };
        let bytes = self.fetch_checked(&key, &table.hash, None).await?;
        decode_table(&bytes, viewpoint)
            .map_err(|e| ClientError::Manifest(format!("viewpoint {viewpoint}: {e}")))
    }

    /// Fetches a viewpoint's ACH object (hash-checked) and decodes its lists.
    pub async fn fetch_ach(
        &mut self,
        ach: &ObjectRef,
        viewpoint: usize,
    ) -> Result<Vec<tracks::manifest::SegmentEntry>, ClientError> {
        let key = FetchKey {
            object: ach.hash.as_str().into(),
            range: None,
        };
        let bytes = self.fetch_checked(&key, &ach.hash, None).await?;
        db::split::decode_ach(&bytes, viewpoint)
            .map_err(|e| ClientError::Manifest(format!("viewpoint {viewpoint}: {e}")))
    }

    /// Download `manifest.json.blake3` and, at the same time on a second connection,
    /// `manifest.json` with `Accept-Encoding: gzip`;
    /// a gzip body is decompressed within [`RetryPolicy::max_body`] (more →
    /// [`ClientError::DecodedTooLarge`]), and the decoded bytes must hash to the checksum
    /// file before they are parsed. A body that fails (bad gzip, wrong hash) is fetched again
    /// (up to `checksum_attempts` times), uncompressed once gzip has failed; nothing that
    /// failed is returned. A server without the checksum file (404) gives an unchecked
    /// manifest (`checked: false`), as [`db::read_manifest`] accepts a database
    /// without one.
    pub async fn fetch_manifest(&mut self) -> Result<ManifestFetch, ClientError> {
        const PATH: &str = "/manifest.json";
        let mut transferred = 0u64;
        let mut requests = 0u64;
        // The checksum file on a second connection while the manifest comes on this one: one
        // round trip for both.
        let mut side = Connection::new(self.url.clone(), self.policy.clone(), self.stats.clone());
        let (hash_res, first) = tokio::join!(
            side.get("/manifest.json.blake3", None, None),
            self.get_retrying(PATH, Ask::Whole, None, true)
        );
        let mut first = Some(first?);
        let mut round_trips = 1u64;
        let expected = match hash_res {
            Ok(text) => {
                transferred += text.len() as u64;
                requests += 1;
                let line = std::str::from_utf8(&text).unwrap_or("").trim();
                if object_rel_path(line).is_none() {
                    return Err(ClientError::Manifest(
                        "manifest.json.blake3 is not a BLAKE3 hex line".into(),
                    ));
                }
                Some(line.to_string())
            }
            Err(ClientError::Status { status: 404, .. }) => {
                requests += 1;
                tracing::warn!("server has no manifest.json.blake3: the manifest is unchecked");
                None
            }
            Err(e) => return Err(e),
        };
        let limit = self.policy.max_body;
        let attempts = self.policy.checksum_attempts.max(1);
        let mut gzip_failed = false;
        for _ in 0..attempts {
            let (body, gzip) = match first.take() {
                Some((b, gzip, _)) => (b, gzip),
                None => {
                    round_trips += 1;
                    let (b, gzip, _) = self
                        .get_retrying(PATH, Ask::Whole, None, !gzip_failed)
                        .await?;
                    (b, gzip)
                }
            };
            transferred += body.len() as u64;
            requests += 1;
            let json = if gzip {
                match db::gunzip_limited(&body, limit) {
                    Ok(j) => j,
                    Err(db::GunzipError::TooLarge { limit }) => {
                        return Err(ClientError::DecodedTooLarge {
                            path: PATH.into(),
                            limit,
                        })
                    }
                    Err(e) => {
                        self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                        tracing::warn!("{PATH}: {e}; fetching it uncompressed");
                        gzip_failed = true;
                        continue;
                    }
                }
            } else {
                body.to_vec()
            };
            if let Some(want) = &expected {
                let got = blake3::hash(&json).to_hex();
                if got.as_str() != want {
                    self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        "{PATH}: hashes to {got}, manifest.json.blake3 says {want}; fetching again"
                    );
                    gzip_failed |= gzip;
                    continue;
                }
            }
            let top = db::parse_top(std::path::Path::new("manifest.json"), &json)
                .map_err(|e| ClientError::Manifest(e.to_string()))?;
            return Ok(ManifestFetch {
                top,
                transferred_bytes: transferred,
                requests,
                round_trips,
                json_bytes: json.len() as u64,
                gzip,
                checked: expected.is_some(),
            });
        }
        Err(ClientError::Checksum {
            path: PATH.into(),
            attempts,
        })
    }
}

/// Whether `b` is the byte range right after `a` in the same object.
fn consecutive(a: &BundlePiece, b: &BundlePiece) -> bool {
    match (a.key.range, b.key.range) {
        (Some((ao, al)), Some((bo, _))) => a.key.object == b.key.object && ao + al == bo,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_parse() {
        let u = ServerUrl::parse("http://127.0.0.1:8080/db/").unwrap();
        assert_eq!(u.authority, "127.0.0.1:8080");
        assert_eq!(u.prefix, "/db");
        let u = ServerUrl::parse("http://example.org").unwrap();
        assert_eq!(u.authority, "example.org:80");
        assert_eq!(u.prefix, "");
        for bad in [
            "https://x",
            "ftp://x",
            "http://",
            "http://a:b/",
            "http://u@h/",
        ] {
            assert!(ServerUrl::parse(bad).is_err(), "{bad}");
        }
    }
}
