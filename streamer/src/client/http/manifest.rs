//! The manifest over HTTP: the top with its checksum file (gzip-encoded where the server
//! offers it, decoded within a limit), viewpoint tables and ACH objects, checked and
//! decoded.

use std::sync::atomic::Ordering;

use tracks::manifest::{object_rel_path, Manifest, ObjectRef};

use super::{Ask, ClientError, Connection, FetchKey};
use db::split::{assemble, decode_table, TopManifest, ViewTable};

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

impl Connection {
    /// Every piece of the index under `root` ([`db::index`]), level by level, each
    /// hash-checked, assembled into the top manifest: the top, the levels fetched (round
    /// trips) and the pieces.
    pub async fn fetch_index(
        &mut self,
        root: db::index::RootManifest,
    ) -> Result<(TopManifest, u64, u64), ClientError> {
        let mut walk = db::index::TreeWalk::new(root);
        let mut levels = 0;
        loop {
            let batch = walk.next_batch();
            if batch.is_empty() {
                break;
            }
            levels += 1;
            for (at, r) in batch {
                let key = FetchKey {
                    object: r.hash.as_str().into(),
                    range: None,
                };
                let bytes = self.fetch_checked(&key, &r.hash, None).await?;
                walk.give(&at, &r, &bytes).map_err(ClientError::Manifest)?;
            }
        }
        let pieces = walk.pieces() as u64;
        let top = walk.finish().map_err(ClientError::Manifest)?;
        Ok((top, levels, pieces))
    }

    /// The whole manifest: the top ([`Connection::fetch_manifest`]) and every viewpoint's
    /// table ([`Connection::fetch_table`]) and ACH object ([`Connection::fetch_ach`]),
    /// assembled (for tools that want everything at once; a viewer fetches tables as it
    /// needs them).
    pub async fn manifest(&mut self) -> Result<Manifest, ClientError> {
        let top = self.fetch_manifest().await?.top;
        let mut tables = Vec::with_capacity(top.viewpoints.len());
        for v in &top.viewpoints {
            let mut table = self.fetch_table(&v.table, v.index).await?;
            if let Some(ach) = &v.ach {
                table.segments = self.fetch_ach(ach, v.index).await?;
            }
            tables.push(table);
        }
        let refs: Vec<Option<&ViewTable>> = tables.iter().map(Some).collect();
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
    /// a gzip body is decompressed within [`RetryPolicy::max_body`](super::RetryPolicy::max_body) (more →
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
            let root = db::parse_root(std::path::Path::new("manifest.json"), &json)
                .map_err(|e| ClientError::Manifest(e.to_string()))?;
            let before = self.stats.bytes.load(Ordering::Relaxed);
            let (top, levels, pieces) = self.fetch_index(root).await?;
            transferred += self.stats.bytes.load(Ordering::Relaxed) - before;
            return Ok(ManifestFetch {
                top,
                transferred_bytes: transferred,
                requests: requests + pieces,
                round_trips: round_trips + levels,
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
