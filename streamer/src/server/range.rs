//! `Range:` header parsing (sans-IO): one `bytes=` range against a known object size.

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
}
