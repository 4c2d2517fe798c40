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
use hyper::body::Incoming;
use hyper::client::conn::http1::SendRequest;
use hyper::{header, Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use tokio::net::TcpStream;

mod checked;
mod manifest;
mod ranges;
pub use manifest::ManifestFetch;
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

impl Head {
    /// The head of `resp` (header values cut to 256 characters).
    fn of(resp: &Response<Incoming>) -> Head {
        let text = |name: header::HeaderName| {
            resp.headers().get(name).map(|v| {
                String::from_utf8_lossy(v.as_bytes())
                    .chars()
                    .take(256)
                    .collect()
            })
        };
        Head {
            status: resp.status().as_u16(),
            content_type: text(header::CONTENT_TYPE),
            content_range: text(header::CONTENT_RANGE),
        }
    }
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
        let host = self.url.host().to_string();
        // Errors name the whole URL: which server, which object.
        let url = format!("http://{host}{path}");
        let path = url.as_str();
        let request_path = &url[7 + host.len()..];
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
        let req = builder
            .body(Empty::new())
            .map_err(|e| transfer_error(path, &e))?;
        let resp = self.send(req, path).await?;
        let status = resp.status();
        let gzip = self.content_gzip(&resp, accept_gzip, path)?;
        let ok = match ask {
            Ask::Whole => status == StatusCode::OK,
            Ask::One(_) => status == StatusCode::PARTIAL_CONTENT,
            // Several ranges may come back as one, as several, or as the whole object.
            Ask::Ranges(_) => matches!(status, StatusCode::OK | StatusCode::PARTIAL_CONTENT),
        };
        let head = Head::of(&resp);
        let body = resp.into_body();
        if !ok {
            return Err(self.refused(body, path, status).await);
        }
        let out = self.read_body(body, cancel, path).await?;
        self.stats.requests.fetch_add(1, Ordering::Relaxed);
        self.stats
            .bytes
            .fetch_add(out.len() as u64, Ordering::Relaxed);
        Ok((out, gzip, head))
    }

    /// Sends `req` on the connection (opened if needed) and waits for the response head,
    /// within the response timeout; drops the connection when that fails.
    async fn send(
        &mut self,
        req: Request<Empty<Bytes>>,
        path: &str,
    ) -> Result<Response<Incoming>, ClientError> {
        let response_timeout = self.policy.response_timeout;
        let sender = self.connect().await?;
        let sent = tokio::time::timeout(response_timeout, async {
            sender.ready().await?;
            sender.send_request(req).await
        })
        .await;
        match sent {
            Ok(Ok(r)) => Ok(r),
            Ok(Err(e)) => {
                self.sender = None;
                Err(transfer_error(path, &e))
            }
            Err(_) => {
                self.sender = None;
                Err(ClientError::Timeout {
                    path: path.to_string(),
                    what: "no response",
                    after: response_timeout,
                })
            }
        }
    }

    /// Whether the response's body is gzip-encoded (only where it was asked for); a
    /// successful response in an encoding nobody asked for is an error.
    fn content_gzip(
        &mut self,
        resp: &Response<Incoming>,
        accept_gzip: bool,
        path: &str,
    ) -> Result<bool, ClientError> {
        let encoding = resp.headers().get(header::CONTENT_ENCODING).map(|v| {
            String::from_utf8_lossy(v.as_bytes())
                .trim()
                .to_ascii_lowercase()
        });
        match encoding.as_deref() {
            None | Some("identity") => Ok(false),
            Some("gzip" | "x-gzip") if accept_gzip => Ok(true),
            Some(other) if resp.status().is_success() => {
                self.sender = None;
                Err(ClientError::Transfer {
                    path: path.to_string(),
                    message: format!("unrequested Content-Encoding `{other}`"),
                })
            }
            Some(_) => Ok(false),
        }
    }

    /// The error of a response with an unexpected `status`: its body's first 512 bytes as
    /// the reason; the connection is dropped unless the body was read to its end.
    async fn refused(&mut self, mut body: Incoming, path: &str, status: StatusCode) -> ClientError {
        let stall_timeout = self.policy.stall_timeout;
        let mut reason = Vec::new();
        while let Ok(Some(f)) = tokio::time::timeout(stall_timeout, body.frame()).await {
            match f {
                Ok(f) => {
                    if let Some(d) = f.data_ref() {
                        reason.extend_from_slice(&d[..d.len().min(512 - reason.len().min(512))]);
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
        ClientError::Status {
            path: path.to_string(),
            status: status.as_u16(),
            reason: String::from_utf8_lossy(&reason).trim().to_string(),
        }
    }

    /// The whole body, within the stall timeout between chunks and the body limit, checking
    /// `cancel` between chunks; the connection is dropped when it stops early.
    async fn read_body(
        &mut self,
        mut body: Incoming,
        cancel: Option<&AtomicBool>,
        path: &str,
    ) -> Result<Bytes, ClientError> {
        let max_body = self.policy.max_body;
        let stall_timeout = self.policy.stall_timeout;
        let mut out = BytesMut::new();
        loop {
            let frame = match tokio::time::timeout(stall_timeout, body.frame()).await {
                Ok(Some(f)) => f,
                Ok(None) => break,
                Err(_) => {
                    self.sender = None;
                    return Err(ClientError::Timeout {
                        path: path.to_string(),
                        what: "transfer stalled: no bytes",
                        after: stall_timeout,
                    });
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
                    return Err(transfer_error(path, &e));
                }
            };
            if let Some(d) = frame.data_ref() {
                if out.len() as u64 + d.len() as u64 > max_body {
                    self.sender = None;
                    return Err(transfer_error(
                        path,
                        &format!("body longer than {max_body} bytes"),
                    ));
                }
                out.extend_from_slice(d);
            }
        }
        Ok(out.freeze())
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
}

/// A transfer failure of `path`.
fn transfer_error(path: &str, m: &dyn std::fmt::Display) -> ClientError {
    ClientError::Transfer {
        path: path.to_string(),
        message: m.to_string(),
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
