//! Checked downloads: every body hashed and compared with the hash it must have before it
//! is returned, re-downloaded on a mismatch; many pieces in one `/bundle` request, or object
//! by object from a server without it.

use std::sync::atomic::{AtomicBool, Ordering};

use bytes::Bytes;
use tracks::manifest::object_rel_path;

use super::{BundlePiece, ClientError, Connection, FetchKey, RangePiece};
use db::hash_matches;

impl Connection {
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
}

/// Whether `b` is the byte range right after `a` in the same object.
fn consecutive(a: &BundlePiece, b: &BundlePiece) -> bool {
    match (a.key.range, b.key.range) {
        (Some((ao, al)), Some((bo, _))) => a.key.object == b.key.object && ao + al == bo,
        _ => false,
    }
}
