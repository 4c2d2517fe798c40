//! Bundle requests (sans-IO parsing): many objects or byte ranges in one response, so a client
//! pays one round trip for a batch of small tiles (mesh + PTM levels each) instead of one per
//! object.
//!
//! `GET /bundle?p=ENTRY,ENTRY,…` where each entry is `HASH` (the whole object) or
//! `HASH:OFFSET:LEN` (a byte range). The body is the entries' bytes concatenated in request
//! order; the client knows every length from the manifest and checks each piece against its
//! own hash. Every entry is content-addressed, so the response for one query never changes:
//! it carries `Cache-Control: immutable` and an `ETag` derived from the query. A static HTTP
//! host has no `/bundle` (404); clients then fetch the same pieces one object at a time, so
//! the database still streams from plain files.

/// One entry of a bundle: an object hash and an optional `(offset, len)` range.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BundleEntry {
    pub object: String,
    pub range: Option<(u64, u64)>,
}

/// Why a bundle query was refused (each maps to `400 Bad Request` with this text).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BundleError {
    #[error("bundle query must be `p=HASH[:OFFSET:LEN],…`")]
    Malformed,
    #[error("bundle entry {index} (`{text}`): {why}")]
    Entry {
        index: usize,
        text: String,
        why: &'static str,
    },
    #[error("bundle of {count} entries is larger than the limit of {limit}")]
    TooMany { count: usize, limit: usize },
}

/// Parse the query string of a bundle request (without the `?`).
pub fn parse_bundle_query(
    query: &str,
    max_entries: usize,
) -> Result<Vec<BundleEntry>, BundleError> {
    let list = query.strip_prefix("p=").ok_or(BundleError::Malformed)?;
    if list.is_empty() || list.contains('&') {
        return Err(BundleError::Malformed);
    }
    let count = list.split(',').count();
    if count > max_entries {
        return Err(BundleError::TooMany {
            count,
            limit: max_entries,
        });
    }
    list.split(',')
        .enumerate()
        .map(|(index, text)| {
            let err = |why| BundleError::Entry {
                index,
                text: text.chars().take(100).collect(),
                why,
            };
            let mut fields = text.split(':');
            let object = fields.next().unwrap_or_default();
            if tracks::manifest::object_rel_path(object).is_none() {
                return Err(err("not a 64-hex-digit object hash"));
            }
            let num = |s: Option<&str>| -> Result<u64, BundleError> {
                let s = s.ok_or_else(|| err("a range needs OFFSET:LEN"))?;
                if s.is_empty() || s.len() > 20 || !s.bytes().all(|c| c.is_ascii_digit()) {
                    return Err(err("offset and length must be decimal numbers"));
                }
                s.parse().map_err(|_| err("number too large"))
            };
            let range = match fields.next() {
                None => None,
                Some(off) => {
                    let off = num(Some(off))?;
                    let len = num(fields.next())?;
                    if len == 0 {
                        return Err(err("empty range"));
                    }
                    if fields.next().is_some() {
                        return Err(err("too many fields"));
                    }
                    Some((off, len))
                }
            };
            Ok(BundleEntry {
                object: object.to_string(),
                range,
            })
        })
        .collect()
}

/// The query for `entries` (what a client sends; [`parse_bundle_query`] reads it back).
pub fn bundle_query(entries: &[BundleEntry]) -> String {
    let mut q = String::from("p=");
    for (i, e) in entries.iter().enumerate() {
        if i > 0 {
            q.push(',');
        }
        q.push_str(&e.object);
        if let Some((off, len)) = e.range {
            q.push_str(&format!(":{off}:{len}"));
        }
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: &str = "0cb39874d4940f1a33d16b1e5b23d1557913e5116a94536e8356a591ab7c8b4a";

    #[test]
    fn queries_round_trip() {
        let entries = vec![
            BundleEntry {
                object: H.into(),
                range: None,
            },
            BundleEntry {
                object: H.into(),
                range: Some((53, 25)),
            },
        ];
        let q = bundle_query(&entries);
        assert_eq!(q, format!("p={H},{H}:53:25"));
        assert_eq!(parse_bundle_query(&q, 8).unwrap(), entries);
    }

    #[test]
    fn bad_queries_are_refused_with_the_entry_named() {
        for bad in [
            "",
            "p=",
            "q=abc",
            &format!("p={H}&x=1"),
            "p=../../etc/passwd",
            &format!("p={H}:1"),
            &format!("p={H}:1:0"),
            &format!("p={H}:1:2:3"),
            &format!("p={H}:-1:2"),
            &format!("p={H}:99999999999999999999999:2"),
            &format!("p={},{H}", H.to_uppercase()),
        ] {
            assert!(parse_bundle_query(bad, 8).is_err(), "{bad}");
        }
        let e = parse_bundle_query(&format!("p={H},{H}:x:1"), 8).unwrap_err();
        assert!(matches!(e, BundleError::Entry { index: 1, .. }), "{e}");
        let many = format!("p={}", [H; 9].join(","));
        assert_eq!(
            parse_bundle_query(&many, 8),
            Err(BundleError::TooMany { count: 9, limit: 8 })
        );
    }
}
