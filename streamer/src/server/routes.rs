//! What each request gets: `/manifest.json` (gzip when accepted), its checksum file,
//! `/objects/HH/HASH` (whole or one byte range), `/bundle?p=…` (many, concatenated).
//! Object and bundle bodies are streamed from the files ([`super::body`]).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::Ordering;

use hyper::body::Incoming;
use hyper::header::{self, HeaderValue};
use hyper::{Method, Request, Response, StatusCode, Version};
use tracks::manifest::object_rel_path;

use super::body::{read_small, FileStream, Segment, ServeBody, CHUNK_BYTES};
use super::{accepts_gzip, parse_bundle_query, parse_range, RangeError, Shared};

pub(crate) type Resp = Response<ServeBody>;

fn reply(status: StatusCode, reason: impl Into<String>) -> Resp {
    let mut r = Response::new(ServeBody::full(reason.into() + "\n"));
    *r.status_mut() = status;
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; charset=utf-8"),
    );
    r
}

pub(crate) async fn handle(s: &Shared, req: Request<Incoming>) -> Resp {
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
        return closing(reply(
            StatusCode::METHOD_NOT_ALLOWED,
            "only GET and HEAD are served",
        ));
    }
    let has_body = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .is_some_and(|v| v.as_bytes() != b"0")
        || req.headers().contains_key(header::TRANSFER_ENCODING);
    if has_body {
        // The body is never read: the connection closes after this answer.
        return closing(reply(
            StatusCode::PAYLOAD_TOO_LARGE,
            "request bodies are not accepted",
        ));
    }
    if req.version() == Version::HTTP_11 && !req.headers().contains_key(header::HOST) {
        return reply(
            StatusCode::BAD_REQUEST,
            "an HTTP/1.1 request needs a Host header",
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
                let mut r = Response::new(ServeBody::full(b.clone()));
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
        object(s, rest, req).await.unwrap_or_else(|r| r)
    } else if path == "/bundle" && s.config.bundles {
        bundle(s, req).await.unwrap_or_else(|r| r)
    } else {
        reply(
            StatusCode::NOT_FOUND,
            "unknown path; served: /manifest.json, /manifest.json.blake3, /objects/HH/HASH, /bundle?p=…",
        )
    };
    if head_only {
        // Same headers (Content-Length included), no body.
        let len = {
            use hyper::body::Body;
            resp.body().size_hint().exact().unwrap_or(0)
        };
        *resp.body_mut() = ServeBody::empty();
        if let Ok(v) = HeaderValue::from_str(&len.to_string()) {
            resp.headers_mut().insert(header::CONTENT_LENGTH, v);
        }
    }
    resp
}

/// `resp` with `Connection: close`.
fn closing(mut resp: Resp) -> Resp {
    resp.headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
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
    let mut r = Response::new(ServeBody::full(body));
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

/// Whether the client's `If-None-Match` names `etag` (or `*`): then `304`.
fn not_modified(req: &Request<Incoming>, etag: &str) -> Option<Resp> {
    let hit = req
        .headers()
        .get(header::IF_NONE_MATCH)
        .is_some_and(|v| v.as_bytes() == etag.as_bytes() || v.as_bytes() == b"*");
    hit.then(|| {
        let mut r = Response::new(ServeBody::empty());
        *r.status_mut() = StatusCode::NOT_MODIFIED;
        add_object_headers(&mut r, etag);
        r
    })
}

/// Fault injection (`ServerConfig::corrupt_every`): the request number whose body gets one
/// byte flipped, if this request is one.
fn flip_for(s: &Shared) -> Option<u64> {
    let n = s.config.corrupt_every.filter(|&n| n > 0)?;
    let k = s.stats.requests.load(Ordering::Relaxed);
    k.is_multiple_of(n).then_some(k)
}

/// The body for `segments` (`total` bytes): read now when small, else streamed; one byte
/// flipped when `flip` says so (counted).
async fn file_body(
    s: &Shared,
    segments: Vec<Segment>,
    total: u64,
    flip: Option<u64>,
) -> std::io::Result<ServeBody> {
    let corrupt_at = flip.filter(|_| total > 0).map(|k| (k * 7919) % total);
    if corrupt_at.is_some() {
        s.stats.corrupted.fetch_add(1, Ordering::Relaxed);
    }
    if total as usize <= CHUNK_BYTES {
        let data = tokio::task::spawn_blocking(move || read_small(segments, corrupt_at))
            .await
            .map_err(std::io::Error::other)??;
        Ok(ServeBody::full(data))
    } else {
        Ok(ServeBody::files(FileStream::new(segments, corrupt_at)))
    }
}

async fn file_size(path: PathBuf) -> std::io::Result<u64> {
    tokio::task::spawn_blocking(move || std::fs::metadata(&path).map(|m| m.len()))
        .await
        .map_err(std::io::Error::other)?
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
    if let Some(r) = not_modified(req, &etag) {
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
    let size = file_size(path.clone()).await.map_err(not_there)?;
    let limit = s.config.max_response_bytes;
    let range = match req.headers().get(header::RANGE) {
        None => None,
        Some(v) => {
            let text = v
                .to_str()
                .map_err(|_| reply(StatusCode::BAD_REQUEST, "Range header is not ASCII"))?;
            match parse_range(text, size, limit) {
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
    if len > limit {
        return Err(reply(
            StatusCode::RANGE_NOT_SATISFIABLE,
            format!(
                "object of {len} bytes is larger than the response limit of {limit} bytes; ask for ranges"
            ),
        ));
    }
    let seg = Segment {
        path: path.clone(),
        offset,
        len,
    };
    let body = file_body(s, vec![seg], len, flip_for(s))
        .await
        .map_err(not_there)?;
    let mut r = Response::new(body);
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

/// `/bundle?p=…`: the named objects and ranges concatenated (see [`super::bundle`]), at most
/// `max_bundle_entries` entries and `max_bundle_bytes` bytes, streamed from the files.
async fn bundle(s: &Shared, req: &Request<Incoming>) -> Result<Resp, Resp> {
    let query = req.uri().query().unwrap_or_default();
    let entries = parse_bundle_query(query, s.config.max_bundle_entries)
        .map_err(|e| reply(StatusCode::BAD_REQUEST, e.to_string()))?;
    let etag = format!("\"b3-{}\"", blake3::hash(query.as_bytes()).to_hex());
    if let Some(r) = not_modified(req, &etag) {
        return Ok(r);
    }
    // Each distinct object's size, looked up once (on the blocking pool, all together).
    let mut paths: HashMap<&str, PathBuf> = HashMap::new();
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
        let rel = object_rel_path(&e.object).ok_or_else(|| {
            reply(
                StatusCode::BAD_REQUEST,
                format!("bundle entry {i}: bad hash"),
            )
        })?;
        paths
            .entry(&e.object)
            .or_insert_with(|| s.db.root.join(rel));
    }
    let list: Vec<(String, PathBuf)> = paths
        .iter()
        .map(|(h, p)| (h.to_string(), p.clone()))
        .collect();
    let sizes: HashMap<String, Result<u64, String>> = tokio::task::spawn_blocking(move || {
        list.into_iter()
            .map(|(h, p)| {
                let size = std::fs::metadata(&p).map(|m| m.len()).map_err(|e| {
                    tracing::warn!("{}: {e}", p.display());
                    e.to_string()
                });
                (h, size)
            })
            .collect()
    })
    .await
    .map_err(|_| reply(StatusCode::INTERNAL_SERVER_ERROR, "bundle lookup failed"))?;
    let limit = s.config.max_bundle_bytes;
    let mut segments = Vec::with_capacity(entries.len());
    let mut total = 0u64;
    for (i, e) in entries.iter().enumerate() {
        let size = match sizes.get(&e.object) {
            Some(Ok(size)) => *size,
            _ => {
                return Err(reply(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    format!(
                        "bundle entry {i}: object {} is listed but not readable",
                        e.object
                    ),
                ))
            }
        };
        let (offset, len) = e.range.unwrap_or((0, size));
        if offset.checked_add(len).is_none_or(|end| end > size) {
            return Err(reply(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!(
                    "bundle entry {i}: range {offset}+{len} is outside the object of {size} bytes"
                ),
            ));
        }
        total = total.saturating_add(len);
        if total > limit {
            return Err(reply(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!("bundle is larger than the limit of {limit} bytes; ask for fewer entries"),
            ));
        }
        segments.push(Segment {
            path: paths[e.object.as_str()].clone(),
            offset,
            len,
        });
    }
    let body = file_body(s, segments, total, flip_for(s))
        .await
        .map_err(|e| {
            tracing::warn!("bundle: {e}");
            reply(
                StatusCode::UNPROCESSABLE_ENTITY,
                "a bundle entry's object is listed but not readable",
            )
        })?;
    let mut r = Response::new(body);
    add_object_headers(&mut r, &etag);
    r.headers_mut().remove(header::ACCEPT_RANGES);
    Ok(r)
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
