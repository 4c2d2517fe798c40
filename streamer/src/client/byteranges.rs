//! Byte ranges without I/O: which `Range:` requests carry a set of pieces of one object
//! ([`plan_ranges`]), and what a server answered ([`parse_response`]): a `206` with one
//! `Content-Range`, a `206 multipart/byteranges` body (RFC 9110 §14.6), or a `200` with the
//! whole object. Parsing is strict and bounded — the boundary is taken from the
//! `Content-Type`, every part must carry a `Content-Range` inside the object and exactly the
//! bytes it names, at most [`RangeLimits::max_parts`] parts with headers of at most
//! [`RangeLimits::max_part_header_bytes`] — and never copies the body (parts are slices of
//! it). What a part holds is only trusted once the caller has checked each piece against
//! its hash ([`Chunks::piece`] finds the bytes; the hash check is the caller's).

use bytes::Bytes;

/// Bounds on what a range response may make the client do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RangeLimits {
    /// Ranges one request names at most (servers cap them too: nginx's `max_ranges`, header
    /// size limits).
    pub max_ranges: usize,
    /// Longest `Range:` header value sent, bytes (nginx refuses request headers over 8 KiB
    /// by default).
    pub max_header_len: usize,
    /// Parts one multipart body may hold.
    pub max_parts: usize,
    /// Header bytes of one part at most.
    pub max_part_header_bytes: usize,
}

impl Default for RangeLimits {
    fn default() -> Self {
        RangeLimits {
            max_ranges: 64,
            max_header_len: 2048,
            max_parts: 256,
            max_part_header_bytes: 1024,
        }
    }
}

/// A byte range `[start, start + len)` of an object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Span {
    pub start: u64,
    pub len: u64,
}

impl Span {
    pub fn end(&self) -> u64 {
        self.start.saturating_add(self.len)
    }

    fn contains(&self, other: &Span) -> bool {
        self.start <= other.start && other.end() <= self.end()
    }
}

/// The requests for `pieces` (ranges of one object, any order, may repeat or overlap): the
/// pieces sorted and merged wherever the gap between them is at most `gap` bytes (fetching
/// a small gap costs less than one more range or request), then cut into requests of at most
/// `limits.max_ranges` ranges and `limits.max_header_len` header bytes. With `multi` false
/// (a server that answers one range per request) every range is a request of its own.
pub fn plan_ranges(pieces: &[Span], gap: u64, multi: bool, limits: &RangeLimits) -> Vec<Vec<Span>> {
    let mut sorted: Vec<Span> = pieces.iter().copied().filter(|p| p.len > 0).collect();
    sorted.sort();
    let mut merged: Vec<Span> = Vec::new();
    for p in sorted {
        match merged.last_mut() {
            Some(last) if p.start <= last.end().saturating_add(gap) => {
                let end = last.end().max(p.end());
                last.len = end - last.start;
            }
            _ => merged.push(p),
        }
    }
    if !multi {
        return merged.into_iter().map(|r| vec![r]).collect();
    }
    let mut out: Vec<Vec<Span>> = Vec::new();
    let mut header = 0usize;
    for r in merged {
        let text = range_text(r).len() + 1;
        let fits = out.last().is_some_and(|last| {
            last.len() < limits.max_ranges.max(1) && header + text <= limits.max_header_len.max(32)
        });
        if fits {
            if let Some(last) = out.last_mut() {
                last.push(r);
            }
            header += text;
        } else {
            out.push(vec![r]);
            header = "bytes=".len() + text;
        }
    }
    out
}

fn range_text(r: Span) -> String {
    format!("{}-{}", r.start, r.end().saturating_sub(1))
}

/// The `Range:` header value for `ranges` (none empty).
pub fn range_header(ranges: &[Span]) -> String {
    let parts: Vec<String> = ranges.iter().map(|&r| range_text(r)).collect();
    format!("bytes={}", parts.join(","))
}

/// What a response holds: byte spans of the object with their bytes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Chunks {
    pub parts: Vec<(Span, Bytes)>,
    /// The whole object came (a `200`, or one range covering it).
    pub whole: bool,
}

impl Chunks {
    /// The bytes of `piece` from whichever part holds all of it.
    pub fn piece(&self, piece: Span) -> Option<Bytes> {
        self.parts
            .iter()
            .find(|(s, _)| s.contains(&piece))
            .map(|(s, b)| {
                let at = (piece.start - s.start) as usize;
                b.slice(at..at + piece.len as usize)
            })
    }
}

/// Why a range response could not be used (the request is made again, or the pieces are
/// fetched another way).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RangeError {
    #[error("status {0} to a range request")]
    Status(u16),
    #[error("Content-Range `{0}` is not `bytes START-END/SIZE` within the object")]
    ContentRange(String),
    #[error("Content-Type `{0}` of a multipart answer names no usable boundary")]
    Boundary(String),
    #[error("multipart body: {what} at byte {at}")]
    Multipart { what: &'static str, at: usize },
    #[error("multipart body has more than {0} parts")]
    TooManyParts(usize),
    #[error("body of {got} bytes, the range names {want}")]
    Length { got: u64, want: u64 },
}

/// Parse `bytes START-END/SIZE` (SIZE may be `*`): the span, checked against `size` (the
/// object's size as the manifest gives it, when known) or else against SIZE.
pub fn parse_content_range(value: &str, size: Option<u64>) -> Result<Span, RangeError> {
    let bad = || RangeError::ContentRange(value.chars().take(80).collect());
    let rest = value.trim().strip_prefix("bytes ").ok_or_else(bad)?;
    let (range, total) = rest.split_once('/').ok_or_else(bad)?;
    let (a, b) = range.split_once('-').ok_or_else(bad)?;
    let num = |s: &str| -> Result<u64, RangeError> {
        let s = s.trim();
        if s.is_empty() || s.len() > 20 || !s.bytes().all(|c| c.is_ascii_digit()) {
            return Err(bad());
        }
        s.parse().map_err(|_| bad())
    };
    let (start, end) = (num(a)?, num(b)?);
    let total = match total.trim() {
        "*" => None,
        t => Some(num(t)?),
    };
    if size.is_some() && total.is_some() && total != size {
        return Err(bad());
    }
    if end < start || size.or(total).is_some_and(|n| end >= n) {
        return Err(bad());
    }
    Ok(Span {
        start,
        len: end - start + 1,
    })
}

/// The boundary of a `multipart/byteranges` Content-Type (1–70 characters as RFC 2046
/// allows, quoted or not), or `None` when the type is another one.
pub fn multipart_boundary(content_type: &str) -> Option<Result<String, RangeError>> {
    let mut params = content_type.split(';');
    let kind = params.next()?.trim();
    if !kind.eq_ignore_ascii_case("multipart/byteranges") {
        return None;
    }
    let bad = || RangeError::Boundary(content_type.chars().take(120).collect());
    let b = params
        .filter_map(|p| p.split_once('='))
        .find(|(k, _)| k.trim().eq_ignore_ascii_case("boundary"))
        .map(|(_, v)| v.trim().trim_matches('"').to_string());
    let ok = |b: &str| {
        !b.is_empty()
            && b.len() <= 70
            && b.bytes()
                .all(|c| c.is_ascii_alphanumeric() || b"'()+_,-./:=? ".contains(&c))
            && !b.ends_with(' ')
    };
    Some(match b {
        Some(b) if ok(&b) => Ok(b),
        _ => Err(bad()),
    })
}

/// What a response to a range request of an object (of `size` bytes, when known) holds:
/// `status`, its `Content-Type` and `Content-Range` headers, and the body.
pub fn parse_response(
    status: u16,
    content_type: Option<&str>,
    content_range: Option<&str>,
    body: Bytes,
    size: Option<u64>,
    limits: &RangeLimits,
) -> Result<Chunks, RangeError> {
    match status {
        200 => {
            let len = body.len() as u64;
            if size.is_some_and(|s| s != len) {
                return Err(RangeError::Length {
                    got: len,
                    want: size.unwrap_or(len),
                });
            }
            Ok(Chunks {
                parts: vec![(Span { start: 0, len }, body)],
                whole: true,
            })
        }
        206 => {
            if let Some(boundary) = content_type.and_then(multipart_boundary) {
                let parts = parse_multipart(&body, &boundary?, size, limits)?;
                return Ok(Chunks {
                    parts,
                    whole: false,
                });
            }
            let span = parse_content_range(
                content_range.ok_or_else(|| RangeError::ContentRange(String::new()))?,
                size,
            )?;
            if body.len() as u64 != span.len {
                return Err(RangeError::Length {
                    got: body.len() as u64,
                    want: span.len,
                });
            }
            Ok(Chunks {
                whole: span.start == 0 && size == Some(span.len),
                parts: vec![(span, body)],
            })
        }
        s => Err(RangeError::Status(s)),
    }
}

/// The parts of a `multipart/byteranges` body: each `--BOUNDARY CRLF`, header lines up to an
/// empty line (one `Content-Range` required, other headers ignored), exactly the bytes the
/// range names, then `CRLF`; after the last part `--BOUNDARY--`. A preamble before the first
/// delimiter and an epilogue after the last are allowed, as RFC 2046 allows; nothing else.
pub fn parse_multipart(
    body: &Bytes,
    boundary: &str,
    size: Option<u64>,
    limits: &RangeLimits,
) -> Result<Vec<(Span, Bytes)>, RangeError> {
    let err = |what, at| RangeError::Multipart { what, at };
    let delim = format!("--{boundary}");
    let d = delim.as_bytes();
    // The first delimiter: at the very start, or after a CRLF (the preamble's end).
    let mut at = if body.starts_with(d) {
        0
    } else {
        find(body, &[b"\r\n", d].concat(), 0).ok_or(err("no delimiter", 0))? + 2
    };
    let mut parts = Vec::new();
    loop {
        at += d.len();
        if body[at..].starts_with(b"--") {
            // The close delimiter; anything after it is the epilogue.
            if parts.is_empty() {
                return Err(err("no part before the close delimiter", at));
            }
            return Ok(parts);
        }
        // Transport padding (spaces, tabs) may follow a delimiter.
        while matches!(body.get(at), Some(b' ' | b'\t')) {
            at += 1;
        }
        if !body[at..].starts_with(b"\r\n") {
            return Err(err("delimiter not followed by CRLF", at));
        }
        at += 2;
        if parts.len() == limits.max_parts {
            return Err(RangeError::TooManyParts(limits.max_parts));
        }
        // Part headers, bounded.
        let window = &body[at..body.len().min(at + limits.max_part_header_bytes + 4)];
        let head_len =
            find(window, b"\r\n\r\n", 0).ok_or(err("part headers too long or unterminated", at))?;
        let head = std::str::from_utf8(&body[at..at + head_len])
            .map_err(|_| err("part headers are not text", at))?;
        let mut span = None;
        for line in head.split("\r\n") {
            let Some((name, value)) = line.split_once(':') else {
                if line.is_empty() {
                    continue;
                }
                return Err(err("part header line without a colon", at));
            };
            if name.trim().eq_ignore_ascii_case("content-range") {
                if span.is_some() {
                    return Err(err("two Content-Range headers in one part", at));
                }
                span = Some(parse_content_range(value, size)?);
            }
        }
        let span = span.ok_or(err("part without Content-Range", at))?;
        at += head_len + 4;
        let end = usize::try_from(span.len)
            .ok()
            .and_then(|l| at.checked_add(l))
            .filter(|&e| e <= body.len())
            .ok_or(err("part shorter than its Content-Range", at))?;
        parts.push((span, body.slice(at..end)));
        at = end;
        if !body[at..].starts_with(b"\r\n") || !body[at + 2..].starts_with(d) {
            return Err(err("part not followed by CRLF and a delimiter", at));
        }
        at += 2;
    }
}

fn find(hay: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    if needle.is_empty() || hay.len() < needle.len() {
        return None;
    }
    (from..=hay.len() - needle.len()).find(|&i| &hay[i..i + needle.len()] == needle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn span(start: u64, len: u64) -> Span {
        Span { start, len }
    }

    /// A multipart body as nginx writes it.
    fn multipart(boundary: &str, object: &[u8], ranges: &[Span]) -> Bytes {
        let mut out = Vec::new();
        for r in ranges {
            out.extend_from_slice(
                format!(
                    "\r\n--{boundary}\r\nContent-Type: application/octet-stream\r\nContent-Range: bytes {}-{}/{}\r\n\r\n",
                    r.start,
                    r.end() - 1,
                    object.len()
                )
                .as_bytes(),
            );
            out.extend_from_slice(&object[r.start as usize..r.end() as usize]);
        }
        out.extend_from_slice(format!("\r\n--{boundary}--\r\n").as_bytes());
        Bytes::from(out)
    }

    #[test]
    fn ranges_merge_across_small_gaps_and_split_by_the_limits() {
        let pieces = [
            span(100, 10),
            span(0, 10),
            span(10, 5),
            span(40, 10),
            span(115, 5),
        ];
        let lim = RangeLimits::default();
        assert_eq!(
            plan_ranges(&pieces, 0, true, &lim),
            vec![vec![span(0, 15), span(40, 10), span(100, 10), span(115, 5)]]
        );
        assert_eq!(
            plan_ranges(&pieces, 30, true, &lim),
            vec![vec![span(0, 50), span(100, 20)]]
        );
        // One range per request for a server without multi-range answers.
        assert_eq!(
            plan_ranges(&pieces, 0, false, &lim),
            vec![
                vec![span(0, 15)],
                vec![span(40, 10)],
                vec![span(100, 10)],
                vec![span(115, 5)]
            ]
        );
        let many: Vec<Span> = (0..200).map(|i| span(i * 100, 10)).collect();
        let small = RangeLimits {
            max_ranges: 64,
            ..lim
        };
        let reqs = plan_ranges(&many, 0, true, &small);
        assert!(reqs
            .iter()
            .all(|r| r.len() <= 64 && range_header(r).len() <= 2048));
        assert_eq!(reqs.iter().map(Vec::len).sum::<usize>(), 200);
        assert_eq!(range_header(&[span(0, 10), span(20, 1)]), "bytes=0-9,20-20");
    }

    #[test]
    fn a_multipart_answer_gives_every_range_and_a_single_one_its_span() {
        let object: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        let asked = [span(0, 10), span(500, 20)];
        let body = multipart("00000000000000000001", &object, &asked);
        let ct = "multipart/byteranges; boundary=00000000000000000001";
        let c = parse_response(
            206,
            Some(ct),
            None,
            body,
            Some(1000),
            &RangeLimits::default(),
        )
        .unwrap();
        assert_eq!(c.parts.len(), 2);
        assert_eq!(c.piece(span(505, 5)).unwrap(), &object[505..510]);
        assert_eq!(c.piece(span(0, 10)).unwrap(), &object[..10]);
        assert_eq!(c.piece(span(15, 10)), None);
        // A server may coalesce ranges into one.
        let one = Bytes::copy_from_slice(&object[0..520]);
        let c = parse_response(
            206,
            None,
            Some("bytes 0-519/1000"),
            one,
            Some(1000),
            &RangeLimits::default(),
        )
        .unwrap();
        assert_eq!(c.piece(span(500, 20)).unwrap(), &object[500..520]);
        // Or ignore ranges and send the object.
        let all = Bytes::from(object.clone());
        let c = parse_response(200, None, None, all, Some(1000), &RangeLimits::default()).unwrap();
        assert!(c.whole);
        assert!(parse_response(
            200,
            None,
            None,
            Bytes::from_static(b"x"),
            Some(1000),
            &RangeLimits::default()
        )
        .is_err());
        // Quoted boundaries, preamble and epilogue.
        let mut b = b"preamble".to_vec();
        b.extend_from_slice(&multipart("a b", &object, &asked));
        b.extend_from_slice(b"epilogue");
        let c = parse_response(
            206,
            Some("multipart/byteranges; boundary=\"a b\""),
            None,
            Bytes::from(b),
            Some(1000),
            &RangeLimits::default(),
        )
        .unwrap();
        assert_eq!(c.parts.len(), 2);
    }

    #[test]
    fn damaged_or_hostile_multipart_answers_are_refused() {
        let object = vec![7u8; 1000];
        let ct = "multipart/byteranges; boundary=XYZ";
        let lim = RangeLimits::default();
        let good = multipart("XYZ", &object, &[span(0, 10), span(100, 10)]);
        let parse = |b: Bytes| parse_response(206, Some(ct), None, b, Some(1000), &lim);
        assert!(parse(good.clone()).is_ok());
        // Every prefix is refused (a truncated answer is never half used).
        for cut in 0..good.len() - 4 {
            assert!(parse(good.slice(..cut)).is_err(), "prefix {cut}");
        }
        // A part longer or shorter than its Content-Range.
        let s = String::from_utf8_lossy(&good).replace("0-9/1000", "0-10/1000");
        assert!(parse(Bytes::from(s.into_bytes())).is_err());
        // A range outside the object, a wrong object size, no Content-Range.
        for (from, to) in [
            ("100-109/1000", "990-1009/1000"),
            ("100-109/1000", "100-109/999"),
            ("Content-Range", "Content-Rang"),
        ] {
            let s = String::from_utf8_lossy(&good).replace(from, to);
            assert!(parse(Bytes::from(s.into_bytes())).is_err(), "{to}");
        }
        // Bad boundaries.
        for ct in [
            "multipart/byteranges",
            "multipart/byteranges; boundary=",
            "multipart/byteranges; boundary=a\u{7f}",
        ] {
            assert!(
                parse_response(206, Some(ct), None, good.clone(), Some(1000), &lim).is_err(),
                "{ct}"
            );
        }
        // Too many parts.
        let many: Vec<Span> = (0..10).map(|i| span(i * 10, 5)).collect();
        let few = RangeLimits {
            max_parts: 4,
            ..lim
        };
        assert_eq!(
            parse_response(
                206,
                Some(ct),
                None,
                multipart("XYZ", &object, &many),
                Some(1000),
                &few
            ),
            Err(RangeError::TooManyParts(4))
        );
        // Headers without end.
        let endless = Bytes::from(format!("--XYZ\r\n{}", "X-Pad: 1\r\n".repeat(500)).into_bytes());
        assert!(parse(endless).is_err());
        assert!(parse_response(416, Some(ct), None, good, Some(1000), &lim).is_err());
    }

    proptest! {
        #[test]
        fn any_bytes_parse_or_fail_without_panicking(body in proptest::collection::vec(any::<u8>(), 0..600), cut in 0usize..5) {
            let b = Bytes::from(body);
            let _ = parse_multipart(&b, "XYZ", Some(1000), &RangeLimits::default());
            let mut framed = b"--XYZ\r\nContent-Range: bytes 0-3/1000\r\n\r\n".to_vec();
            framed.extend_from_slice(&b[..b.len().min(cut)]);
            framed.extend_from_slice(&b);
            let _ = parse_multipart(&Bytes::from(framed), "XYZ", Some(1000), &RangeLimits::default());
        }

        #[test]
        fn planned_ranges_cover_every_piece(
            pieces in proptest::collection::vec((0u64..5000, 1u64..300), 1..80),
            gap in 0u64..200,
            multi in any::<bool>(),
        ) {
            let spans: Vec<Span> = pieces.iter().map(|&(s, l)| span(s, l)).collect();
            let reqs = plan_ranges(&spans, gap, multi, &RangeLimits::default());
            let all: Vec<Span> = reqs.iter().flatten().copied().collect();
            for p in &spans {
                prop_assert!(all.iter().any(|r| r.contains(p)));
            }
            for w in all.windows(2) {
                prop_assert!(w[0].end() < w[1].start, "ranges overlap or touch");
            }
            for r in &reqs {
                prop_assert!(multi || r.len() == 1);
                prop_assert!(r.len() <= 64 && range_header(r).len() <= 2048);
            }
        }
    }
}
