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
use super::range::{close_delimiter, part_head};
use super::{accepts_gzip, parse_bundle_query, parse_range, parse_ranges, RangeError, Shared};

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

/// A refusal built inside a planning closure (boxed: a response is large).
fn refuse(status: StatusCode, reason: impl Into<String>) -> Box<Resp> {
    Box::new(reply(status, reason))
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
    } else if let Some((k, f)) = site_file(s, path) {
        let gz = s.site_gz.get(k).cloned().flatten();
        let send_gz = gz.is_some() && accepts_gzip_header(req);
        let body = match gz {
            Some(gz) if send_gz => gz,
            _ => bytes::Bytes::from_static(f.body.as_bytes()),
        };
        let mut r = Response::new(ServeBody::full(body));
        let h = r.headers_mut();
        h.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(f.content_type()),
        );
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
        if s.site_gz.get(k).is_some_and(Option::is_some) {
            h.insert(header::VARY, HeaderValue::from_static("Accept-Encoding"));
        }
        if send_gz {
            h.insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
        }
        r
    } else {
        reply(
            StatusCode::NOT_FOUND,
            "unknown path; served: /manifest.json, /manifest.json.blake3, /objects/HH/HASH, /bundle?p=…",
        )
    };
    let h = resp.headers_mut();
    for (name, value) in super::SECURITY_HEADERS {
        h.insert(name, HeaderValue::from_static(value));
    }
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

/// The site file at `path` (`/` is `index.html`), with its place in the site's list.
fn site_file(s: &Shared, path: &str) -> Option<(usize, super::SiteFile)> {
    let name = match path {
        "/" => "index.html",
        p => p.strip_prefix('/')?,
    };
    s.config
        .site
        .iter()
        .enumerate()
        .find(|(_, f)| f.name == name)
        .map(|(k, f)| (k, *f))
}

/// Whether the request's `Accept-Encoding` allows gzip.
fn accepts_gzip_header(req: &Request<Incoming>) -> bool {
    req.headers()
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .any(|v| v.to_str().is_ok_and(accepts_gzip))
}

/// `resp` with `Connection: close`.
fn closing(mut resp: Resp) -> Resp {
    resp.headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    resp
}

/// `/manifest.json`: the gzip copy when the client accepts it, else the identity bytes.
fn manifest(s: &Shared, req: &Request<Incoming>) -> Resp {
    let gzip_ok = accepts_gzip_header(req);
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

/// Fault injection (`ServerConfig::corrupt_every`): this object response's number, if its
/// body gets one byte flipped. Object responses are counted on their own, each taking its
/// number once, so that every Nth one is corrupted whatever else (the manifest, the
/// viewer's files) is asked for and however requests interleave.
fn flip_for(s: &Shared) -> Option<u64> {
    let n = s.config.corrupt_every.filter(|&n| n > 0)?;
    let k = s.stats.object_responses.fetch_add(1, Ordering::Relaxed) + 1;
    k.is_multiple_of(n).then_some(k)
}

/// The body of a request that reads files: the files' sizes, the segments `plan` makes of
/// them (or its refusal), and the bytes right away when they fit in one chunk (read here,
/// [`super::body`] says why), else a stream; one byte flipped when `flip` says so (counted).
/// `unreadable` is the answer when a file cannot be read.
fn file_body<T>(
    s: &Shared,
    paths: Vec<PathBuf>,
    flip: Option<u64>,
    unreadable: (StatusCode, String),
    plan: impl FnOnce(Vec<std::io::Result<u64>>) -> Result<(Vec<Segment>, T), Box<Resp>>,
) -> Result<(ServeBody, T), Box<Resp>> {
    let sizes = paths
        .iter()
        .map(|p| std::fs::metadata(p).map(|m| m.len()))
        .collect();
    let (segments, extra) = plan(sizes)?;
    let total: u64 = segments.iter().map(|s| s.len).sum();
    let corrupt_at = flip.filter(|_| total > 0).map(|k| (k * 7919) % total);
    if corrupt_at.is_some() {
        s.stats.corrupted.fetch_add(1, Ordering::Relaxed);
    }
    let body = if total as usize <= CHUNK_BYTES {
        let data = read_small(segments, corrupt_at).map_err(|e| {
            tracing::warn!("reading a response: {e}");
            refuse(unreadable.0, unreadable.1)
        })?;
        ServeBody::full(data)
    } else {
        ServeBody::files(FileStream::new(segments, corrupt_at))
    };
    Ok((body, extra))
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
    if !s.db.has_object(hash) {
        return Err(reply(
            StatusCode::NOT_FOUND,
            format!("object {hash} is not in this database"),
        ));
    }
    let etag = format!("\"{hash}\"");
    if let Some(r) = not_modified(req, &etag) {
        return Ok(r);
    }
    let range_text = match req.headers().get(header::RANGE) {
        None => None,
        Some(v) => Some(
            v.to_str()
                .map_err(|_| reply(StatusCode::BAD_REQUEST, "Range header is not ASCII"))?
                .to_string(),
        ),
    };
    let path = s.db.root.join(rel);
    let limit = s.config.max_response_bytes;
    let not_readable = format!("object {hash} is listed but not readable");
    let unreadable = (StatusCode::NOT_FOUND, not_readable.clone());
    let (body, (size, offset, len, ranged, boundary)) = file_body(
        s,
        vec![path.clone()],
        flip_for(s),
        unreadable,
        move |sizes| {
            let size = match sizes.into_iter().next() {
                Some(Ok(size)) => size,
                Some(Err(e)) => {
                    tracing::warn!("{}: {e}", path.display());
                    return Err(refuse(StatusCode::NOT_FOUND, not_readable));
                }
                None => return Err(refuse(StatusCode::NOT_FOUND, not_readable)),
            };
            // Several ranges: one multipart answer streamed from the file, their total
            // within the response limit.
            if let Some(text) = range_text.as_deref().filter(|t| t.contains(',')) {
                let ranges = parse_ranges(text, size, limit, MAX_RANGES)
                    .map_err(|e| range_refusal(e, size))?;
                if let [(offset, len)] = ranges[..] {
                    let seg = Segment::file(path, offset, len);
                    return Ok((vec![seg], (size, offset, len, true, None)));
                }
                // A boundary that names the object and the ranges: the same answer, byte
                // for byte, to the same request (caches may compare them).
                let boundary =
                    blake3::hash(format!("{hash}{text}").as_bytes()).to_hex()[..24].to_string();
                let mut segments = Vec::with_capacity(2 * ranges.len() + 1);
                for &(off, len) in &ranges {
                    segments.push(Segment::text(part_head(&boundary, off, len, size)));
                    segments.push(Segment::file(path.clone(), off, len));
                }
                segments.push(Segment::text(close_delimiter(&boundary)));
                return Ok((segments, (size, 0, 0, true, Some(boundary))));
            }
            let range = match range_text {
                None => None,
                Some(text) => match parse_range(&text, size, limit) {
                    Ok(r) => Some(r),
                    Err(e @ RangeError::Unsatisfiable { .. }) => {
                        let mut r = reply(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string());
                        if let Ok(v) = HeaderValue::from_str(&format!("bytes */{size}")) {
                            r.headers_mut().insert(header::CONTENT_RANGE, v);
                        }
                        return Err(Box::new(r));
                    }
                    Err(e @ RangeError::TooLarge { .. }) => {
                        return Err(refuse(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string()))
                    }
                    Err(e) => return Err(refuse(StatusCode::BAD_REQUEST, e.to_string())),
                },
            };
            let (offset, len) = range.unwrap_or((0, size));
            if len > limit {
                return Err(refuse(
                    StatusCode::RANGE_NOT_SATISFIABLE,
                    format!(
                        "object of {len} bytes is larger than the response limit of {limit} \
                         bytes; ask for ranges"
                    ),
                ));
            }
            let seg = Segment::file(path, offset, len);
            Ok((vec![seg], (size, offset, len, range.is_some(), None)))
        },
    )
    .map_err(|r| *r)?;
    let mut r = Response::new(body);
    add_object_headers(&mut r, &etag);
    if let Some(b) = boundary {
        *r.status_mut() = StatusCode::PARTIAL_CONTENT;
        if let Ok(v) = HeaderValue::from_str(&format!("multipart/byteranges; boundary={b}")) {
            r.headers_mut().insert(header::CONTENT_TYPE, v);
        }
    } else if ranged {
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
    // Each distinct object's size is looked up once.
    let mut paths: Vec<PathBuf> = Vec::new();
    let mut slot: HashMap<&str, usize> = HashMap::new();
    let mut which = Vec::with_capacity(entries.len());
    for (i, e) in entries.iter().enumerate() {
        if !s.db.has_object(&e.object) {
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
        let k = *slot.entry(&e.object).or_insert_with(|| {
            paths.push(s.db.root.join(rel));
            paths.len() - 1
        });
        which.push(k);
    }
    let limit = s.config.max_bundle_bytes;
    let files = paths.clone();
    let unreadable = (
        StatusCode::UNPROCESSABLE_ENTITY,
        "a bundle entry's object is listed but not readable".to_string(),
    );
    let (body, ()) = file_body(s, paths, flip_for(s), unreadable, move |sizes| {
        let mut segments = Vec::with_capacity(entries.len());
        let mut total = 0u64;
        for (i, (e, k)) in entries.iter().zip(which).enumerate() {
            let size = match &sizes[k] {
                Ok(size) => *size,
                Err(err) => {
                    tracing::warn!("{}: {err}", files[k].display());
                    return Err(refuse(
                        StatusCode::UNPROCESSABLE_ENTITY,
                        format!(
                            "bundle entry {i}: object {} is listed but not readable",
                            e.object
                        ),
                    ));
                }
            };
            let (offset, len) = e.range.unwrap_or((0, size));
            if offset.checked_add(len).is_none_or(|end| end > size) {
                return Err(refuse(
                    StatusCode::RANGE_NOT_SATISFIABLE,
                    format!(
                        "bundle entry {i}: range {offset}+{len} is outside the object of {size} bytes"
                    ),
                ));
            }
            total = total.saturating_add(len);
            if total > limit {
                return Err(refuse(
                    StatusCode::RANGE_NOT_SATISFIABLE,
                    format!(
                        "bundle is larger than the limit of {limit} bytes; ask for fewer entries"
                    ),
                ));
            }
            segments.push(Segment::file(files[k].clone(), offset, len));
        }
        Ok((segments, ()))
    })
    .map_err(|r| *r)?;
    let mut r = Response::new(body);
    add_object_headers(&mut r, &etag);
    r.headers_mut().remove(header::ACCEPT_RANGES);
    Ok(r)
}

/// Ranges one request may name at most (nginx's `max_ranges` is unlimited by default; a
/// client of ours sends at most 64).
pub const MAX_RANGES: usize = 256;

/// The answer to ranges that cannot be served: 416 (with `Content-Range: bytes */SIZE` when
/// none lies in the object), or 400 for a malformed header.
fn range_refusal(e: RangeError, size: u64) -> Box<Resp> {
    match e {
        RangeError::Unsatisfiable { .. } => {
            let mut r = reply(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string());
            if let Ok(v) = HeaderValue::from_str(&format!("bytes */{size}")) {
                r.headers_mut().insert(header::CONTENT_RANGE, v);
            }
            Box::new(r)
        }
        RangeError::TooLarge { .. } | RangeError::TooMany(_) => {
            refuse(StatusCode::RANGE_NOT_SATISFIABLE, e.to_string())
        }
        e => refuse(StatusCode::BAD_REQUEST, e.to_string()),
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
