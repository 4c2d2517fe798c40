//! `Range:` header parsing (sans-IO): one `bytes=` range ([`parse_range`]) or several
//! ([`parse_ranges`], answered as `multipart/byteranges` by [`multipart_body`]) against a known
//! object size.

/// Why a range was refused; each maps to a 4xx status with this text as the reason.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RangeError {
    #[error("Range header is not `bytes=START-END`: {0}")]
    Malformed(String),
    #[error("multiple ranges are not served; ask for one level group per request")]
    Multiple,
    #[error("range {start}-{end} is outside the object of {size} bytes")]
    Unsatisfiable { start: u64, end: u64, size: u64 },
    #[error("range of {len} bytes is larger than the limit of {limit} bytes")]
    TooLarge { len: u64, limit: u64 },
    #[error("more than {0} ranges in one request")]
    TooMany(usize),
}

/// Parse a `Range` header value into `(offset, len)` within an object of `size` bytes.
/// Accepts `bytes=a-b` (inclusive end, clamped to the object), `bytes=a-` and `bytes=-n`.
pub fn parse_range(value: &str, size: u64, limit: u64) -> Result<(u64, u64), RangeError> {
    let malformed = || RangeError::Malformed(value.chars().take(64).collect());
    let spec = value.trim().strip_prefix("bytes=").ok_or_else(malformed)?;
    if spec.contains(',') {
        return Err(RangeError::Multiple);
    }
    let (a, b) = spec.split_once('-').ok_or_else(malformed)?;
    let num = |s: &str| -> Result<u64, RangeError> {
        if s.is_empty() || s.len() > 20 || !s.bytes().all(|c| c.is_ascii_digit()) {
            return Err(malformed());
        }
        s.parse::<u64>().map_err(|_| malformed())
    };
    let (start, end_incl) = match (a.trim(), b.trim()) {
        ("", n) => {
            let n = num(n)?;
            if n == 0 || size == 0 {
                return Err(RangeError::Unsatisfiable {
                    start: 0,
                    end: 0,
                    size,
                });
            }
            (size.saturating_sub(n), size - 1)
        }
        (s, "") => (num(s)?, size.saturating_sub(1)),
        (s, e) => {
            let (s, e) = (num(s)?, num(e)?);
            if e < s {
                return Err(malformed());
            }
            (s, e.min(size.saturating_sub(1)))
        }
    };
    if size == 0 || start >= size {
        return Err(RangeError::Unsatisfiable {
            start,
            end: end_incl,
            size,
        });
    }
    let len = end_incl - start + 1;
    if len > limit {
        return Err(RangeError::TooLarge { len, limit });
    }
    Ok((start, len))
}

/// Parse a `Range` header value of one or more ranges (`bytes=a-b,c-,-n`) into
/// `(offset, len)` pairs within an object of `size` bytes: at most `max_ranges` of them,
/// sorted, overlapping or adjacent ones merged (RFC 9110 lets a server coalesce them), their
/// total at most `limit` bytes. Ranges that lie wholly past the end are left out; none left
/// is [`RangeError::Unsatisfiable`].
pub fn parse_ranges(
    value: &str,
    size: u64,
    limit: u64,
    max_ranges: usize,
) -> Result<Vec<(u64, u64)>, RangeError> {
    let malformed = || RangeError::Malformed(value.chars().take(64).collect());
    let spec = value.trim().strip_prefix("bytes=").ok_or_else(malformed)?;
    let specs: Vec<&str> = spec.split(',').map(str::trim).collect();
    if specs.len() > max_ranges {
        return Err(RangeError::TooMany(max_ranges));
    }
    let mut out: Vec<(u64, u64)> = Vec::with_capacity(specs.len());
    let mut unsatisfiable = None;
    for one in specs {
        match parse_range(&format!("bytes={one}"), size, u64::MAX) {
            Ok(r) => out.push(r),
            Err(RangeError::Malformed(_)) => return Err(malformed()),
            Err(e @ RangeError::Unsatisfiable { .. }) => unsatisfiable = Some(e),
            Err(e) => return Err(e),
        }
    }
    if out.is_empty() {
        return Err(unsatisfiable.unwrap_or_else(malformed));
    }
    out.sort_unstable();
    let mut merged: Vec<(u64, u64)> = Vec::with_capacity(out.len());
    for (off, len) in out {
        match merged.last_mut() {
            Some((o, l)) if off <= *o + *l => *l = (*l).max(off + len - *o),
            _ => merged.push((off, len)),
        }
    }
    let total: u64 = merged.iter().map(|r| r.1).sum();
    if total > limit {
        return Err(RangeError::TooLarge { len: total, limit });
    }
    Ok(merged)
}

/// A `multipart/byteranges` body: for each range, its delimiter, `Content-Type` and
/// `Content-Range` lines and its bytes (`read(offset, len)`), then the close delimiter.
/// Returns the body; its Content-Type is `multipart/byteranges; boundary={boundary}`.
pub fn multipart_body(
    ranges: &[(u64, u64)],
    size: u64,
    boundary: &str,
    mut read: impl FnMut(u64, u64) -> Vec<u8>,
) -> Vec<u8> {
    let mut out = Vec::new();
    for &(off, len) in ranges {
        out.extend_from_slice(part_head(boundary, off, len, size).as_bytes());
        out.extend_from_slice(&read(off, len));
    }
    out.extend_from_slice(close_delimiter(boundary).as_bytes());
    out
}

/// What goes before the bytes of range `(off, len)` in a multipart answer: its delimiter
/// and headers.
pub fn part_head(boundary: &str, off: u64, len: u64, size: u64) -> String {
    format!(
        "\r\n--{boundary}\r\nContent-Type: application/octet-stream\r\nContent-Range: bytes {off}-{}/{size}\r\n\r\n",
        off + len.max(1) - 1
    )
}

/// The end of a multipart answer.
pub fn close_delimiter(boundary: &str) -> String {
    format!("\r\n--{boundary}--\r\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordinary_ranges() {
        assert_eq!(parse_range("bytes=0-9", 100, 1000), Ok((0, 10)));
        assert_eq!(parse_range("bytes=90-", 100, 1000), Ok((90, 10)));
        assert_eq!(parse_range("bytes=-5", 100, 1000), Ok((95, 5)));
        // An end past the object is clamped, as RFC 9110 asks.
        assert_eq!(parse_range("bytes=50-1000", 100, 1000), Ok((50, 50)));
    }

    #[test]
    fn hostile_ranges_are_refused() {
        for bad in [
            "bytes=",
            "bytes=a-b",
            "items=0-1",
            "bytes=5-1",
            "bytes=-",
            "bytes=99999999999999999999999-1",
            "bytes=+1-2",
        ] {
            assert!(
                matches!(parse_range(bad, 100, 1000), Err(RangeError::Malformed(_))),
                "{bad}"
            );
        }
        assert_eq!(
            parse_range("bytes=0-1,5-6", 100, 1000),
            Err(RangeError::Multiple)
        );
        assert!(matches!(
            parse_range("bytes=100-200", 100, 1000),
            Err(RangeError::Unsatisfiable { .. })
        ));
        assert!(matches!(
            parse_range("bytes=0-", 0, 1000),
            Err(RangeError::Unsatisfiable { .. })
        ));
        assert_eq!(
            parse_range("bytes=0-18446744073709551615", u64::MAX, 1 << 20),
            Err(RangeError::TooLarge {
                len: u64::MAX,
                limit: 1 << 20
            })
        );
    }

    #[test]
    fn several_ranges_are_sorted_merged_and_bounded() {
        assert_eq!(
            parse_ranges("bytes=50-59, 0-9,5-14,-5", 100, 1000, 8),
            Ok(vec![(0, 15), (50, 10), (95, 5)])
        );
        // Ranges wholly past the end are left out; all of them past it is unsatisfiable.
        assert_eq!(
            parse_ranges("bytes=0-1,200-300", 100, 1000, 8),
            Ok(vec![(0, 2)])
        );
        assert!(matches!(
            parse_ranges("bytes=200-300,400-", 100, 1000, 8),
            Err(RangeError::Unsatisfiable { .. })
        ));
        assert_eq!(
            parse_ranges("bytes=0-1,2-3,4-5", 100, 1000, 2),
            Err(RangeError::TooMany(2))
        );
        assert!(matches!(
            parse_ranges("bytes=0-59,60-99", 100, 50, 8),
            Err(RangeError::TooLarge { len: 100, .. })
        ));
        for bad in ["bytes=0-1,", "bytes=0-1,,2-3", "bytes=0-1,x", "0-1,2-3"] {
            assert!(
                matches!(
                    parse_ranges(bad, 100, 1000, 8),
                    Err(RangeError::Malformed(_))
                ),
                "{bad}"
            );
        }
    }

    #[test]
    fn a_multipart_body_reads_back_with_the_clients_parser() {
        let object: Vec<u8> = (0..200u8).collect();
        let ranges = [(0, 10), (100, 20)];
        let body = multipart_body(&ranges, 200, "b0und", |o, l| {
            object[o as usize..(o + l) as usize].to_vec()
        });
        let parts = crate::client::byteranges::parse_multipart(
            &bytes::Bytes::from(body),
            "b0und",
            Some(200),
            &Default::default(),
        )
        .unwrap();
        assert_eq!(parts.len(), 2);
        assert_eq!(parts[1].1, &object[100..120]);
    }
}
