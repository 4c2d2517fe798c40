//! Many byte ranges of one object in few round trips from any server that answers ranges:
//! one request with several ranges (`206 multipart/byteranges`, which nginx, Apache and most
//! CDNs send) where the server answers them, else one request per run of ranges, merged
//! across small gaps. Every piece is checked against its own hash; an answer that does not
//! parse or holds a damaged piece is fetched again, and never returned.

use std::sync::atomic::{AtomicBool, Ordering};

use bytes::Bytes;
use tracks::manifest::object_rel_path;

use super::{Ask, ClientError, Connection};
use crate::client::byteranges::{self, plan_ranges, range_header, Chunks, RangeLimits, Span};
use db::hash_matches;

/// Gap between two ranges of one request below which they are fetched as one: about what a
/// part of a multipart answer costs in headers (delimiter, Content-Type, Content-Range).
pub const MULTI_GAP_BYTES: u64 = 96;

/// Gap below which ranges are merged into one when every range is a request of its own:
/// fetching a few kilobytes more costs less than another round trip.
pub const SINGLE_GAP_BYTES: u64 = 16 << 10;

/// One piece of an object: `(offset, len, hash)`.
pub type RangePiece<'a> = (u64, u64, &'a str);

impl Connection {
    /// Whether this server answers several ranges in one request (`None`: not tried yet).
    pub fn multi_ranges(&self) -> Option<bool> {
        self.multi_ranges
    }

    /// The pieces of object `object` (of `size` bytes when known), each checked against its
    /// hash, in the order given: several ranges per request where the server answers them,
    /// else one request per run of ranges merged across gaps of up to [`SINGLE_GAP_BYTES`].
    /// A request whose answer does not parse or holds a piece that fails its check is made
    /// again (up to `checksum_attempts` times); a server that answers several ranges with
    /// one range, the whole object or a refusal is asked one range at a time from then on.
    pub async fn fetch_checked_ranges(
        &mut self,
        object: &str,
        size: Option<u64>,
        pieces: &[RangePiece<'_>],
        cancel: Option<&AtomicBool>,
    ) -> Result<Vec<Bytes>, ClientError> {
        let rel =
            object_rel_path(object).ok_or_else(|| ClientError::BadObject(object.to_string()))?;
        let path = format!("/{rel}");
        let limits = RangeLimits::default();
        let mut out: Vec<Option<Bytes>> = vec![None; pieces.len()];
        let attempts = self.policy.checksum_attempts.max(1);
        let mut failures = 0;
        while out.iter().any(Option::is_none) {
            let left: Vec<usize> = (0..pieces.len()).filter(|&i| out[i].is_none()).collect();
            let spans: Vec<Span> = left
                .iter()
                .map(|&i| Span {
                    start: pieces[i].0,
                    len: pieces[i].1,
                })
                .collect();
            let multi = self.multi_ranges != Some(false);
            let gap = if multi {
                MULTI_GAP_BYTES
            } else {
                SINGLE_GAP_BYTES
            };
            let requests = plan_ranges(&spans, gap, multi, &limits);
            let mut damaged = false;
            for ranges in requests {
                let chunks = match self
                    .get_ranges(&path, &ranges, size, &limits, cancel)
                    .await?
                {
                    Ok(c) => c,
                    Err(e) => {
                        tracing::warn!("{path}: {e}; fetching again");
                        self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                        damaged = true;
                        continue;
                    }
                };
                let mut covered = true;
                for &i in &left {
                    if out[i].is_some() {
                        continue;
                    }
                    let (off, len, hash) = pieces[i];
                    let span = Span { start: off, len };
                    if !ranges
                        .iter()
                        .any(|r| r.start <= off && off + len <= r.end())
                    {
                        continue;
                    }
                    match chunks.piece(span) {
                        Some(b) if hash_matches(&b, hash) => out[i] = Some(b),
                        Some(_) => {
                            tracing::warn!("{path}: range {off}+{len} fails its checksum");
                            self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                            damaged = true;
                        }
                        None => covered = false,
                    }
                }
                if !covered && ranges.len() == 1 {
                    // One range asked, another answered.
                    tracing::warn!("{path}: the answer does not hold the range asked for");
                    self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
                    damaged = true;
                }
                // Several ranges asked and not all answered, or the whole object sent: this
                // server answers one range at a time.
                if ranges.len() > 1 && (!covered || chunks.whole) {
                    if self.multi_ranges != Some(false) {
                        tracing::info!(
                            "{path}: several ranges not answered as asked; one range per request"
                        );
                    }
                    self.multi_ranges = Some(false);
                } else if ranges.len() > 1 {
                    self.multi_ranges = Some(true);
                }
            }
            if damaged {
                failures += 1;
                if failures >= attempts {
                    return Err(ClientError::Checksum { path, attempts });
                }
            }
        }
        Ok(out.into_iter().flatten().collect())
    }

    /// One request for `ranges` with the connection's timeouts, retries and back-off (the
    /// outer `Result`: the server could not be reached, or refused the object); the inner
    /// one is the answer's fault (it does not parse, or is a refusal of several ranges,
    /// which turns them off for this server).
    async fn get_ranges(
        &mut self,
        path: &str,
        ranges: &[Span],
        size: Option<u64>,
        limits: &RangeLimits,
        cancel: Option<&AtomicBool>,
    ) -> Result<Result<Chunks, byteranges::RangeError>, ClientError> {
        let header = range_header(ranges);
        let (body, _, head) = match self
            .get_retrying(path, Ask::Ranges(&header), cancel, false)
            .await
        {
            Ok(r) => r,
            // A refusal of several ranges: one at a time from now on.
            Err(ClientError::Status { status, .. })
                if ranges.len() > 1 && matches!(status, 400 | 416 | 501) =>
            {
                self.multi_ranges = Some(false);
                return Ok(Err(byteranges::RangeError::Status(status)));
            }
            Err(e) => return Err(e),
        };
        Ok(byteranges::parse_response(
            head.status,
            head.content_type.as_deref(),
            head.content_range.as_deref(),
            body,
            size,
            limits,
        ))
    }
}
