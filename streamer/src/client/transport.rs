//! Where a database comes from: a server over HTTP ([`Connection`]) or a directory on this
//! machine, read the same way — by object and byte range, every piece checked against its
//! hash, nothing that failed its check ever returned. A directory is just another server: the
//! viewer runs the same client, with the same budgets, over either.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use bytes::Bytes;
use tracks::manifest::object_rel_path;

use super::http::{
    BundlePiece, ClientError, ClientStats, Connection, FetchKey, ManifestFetch, RetryPolicy,
    ServerUrl, TransferReport,
};
use super::schedule::Piece;
use db::hash_matches;

/// A database's address: `http://HOST:PORT[/PREFIX]` or a directory.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    Http(ServerUrl),
    Dir(PathBuf),
}

impl Source {
    /// An `http://` URL, or else a directory holding a database (`manifest.json`).
    pub fn parse(text: &str) -> Result<Source, ClientError> {
        if text.contains("://") {
            return ServerUrl::parse(text).map(Source::Http);
        }
        let dir = PathBuf::from(text);
        if !dir.join(db::MANIFEST_FILE).is_file() {
            return Err(ClientError::Url(format!(
                "`{text}`: neither an http:// URL nor a database directory (no {})",
                db::MANIFEST_FILE
            )));
        }
        Ok(Source::Dir(dir))
    }

    /// Whether `text` names a database directory (one with a `manifest.json`).
    pub fn is_database_dir(text: &str) -> bool {
        !text.contains("://") && Path::new(text).join(db::MANIFEST_FILE).is_file()
    }
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::Http(u) => write!(f, "http://{}{}", u.authority, u.prefix),
            Source::Dir(d) => write!(f, "{}", d.display()),
        }
    }
}

/// What one batch took: per piece (in order) its checked bytes or why it failed (an
/// object's fault fails that piece alone; a server that cannot be reached fails the pieces
/// not yet fetched), the requests and body bytes it cost (retries included) and what the
/// transfer cost in retries and outage.
#[derive(Clone, Debug)]
pub struct BatchData {
    pub data: Vec<Result<Bytes, ClientError>>,
    pub requests: u64,
    pub wire_bytes: u64,
    pub transfer: TransferReport,
}

impl BatchData {
    /// The first failure that is the server's (unreachable), not one object's.
    pub fn unreachable(&self) -> Option<&ClientError> {
        self.data
            .iter()
            .filter_map(|r| r.as_ref().err())
            .find(|e| !e.is_object_fault() && !matches!(e, ClientError::Cancelled))
    }
}

/// One way of reading a database: a keep-alive HTTP connection or a directory.
pub struct Transport {
    inner: Inner,
    stats: Arc<ClientStats>,
}

enum Inner {
    Http(Connection),
    Dir(LocalDir),
}

impl Transport {
    /// Counters of this transport alone (requests, bytes, checksum failures, reconnects).
    pub fn new(source: &Source, policy: RetryPolicy) -> Transport {
        let stats = Arc::new(ClientStats::default());
        let inner = match source {
            Source::Http(url) => Inner::Http(Connection::new(url.clone(), policy, stats.clone())),
            Source::Dir(dir) => Inner::Dir(LocalDir {
                root: dir.clone(),
                policy,
                stats: stats.clone(),
            }),
        };
        Transport { inner, stats }
    }

    pub fn stats(&self) -> &Arc<ClientStats> {
        &self.stats
    }

    /// Whether many objects travel in one request (`/bundle`, or a directory).
    pub fn bundles_supported(&self) -> bool {
        match &self.inner {
            Inner::Http(c) => c.bundles_supported(),
            Inner::Dir(_) => true,
        }
    }

    /// The top manifest, checked against `manifest.json.blake3` where there is one.
    pub async fn fetch_manifest(&mut self) -> Result<ManifestFetch, ClientError> {
        match &mut self.inner {
            Inner::Http(c) => c.fetch_manifest().await,
            Inner::Dir(d) => {
                let d = d.clone();
                blocking(move || d.manifest()).await
            }
        }
    }

    /// The pieces of one batch, each checked against its hash: together where they check
    /// out, else one by one so that only the damaged ones fail.
    pub async fn fetch_batch(
        &mut self,
        pieces: &[Piece],
        cancel: Option<&AtomicBool>,
    ) -> BatchData {
        let requests0 = self.stats.requests.load(Ordering::Relaxed);
        let bytes0 = self.stats.bytes.load(Ordering::Relaxed);
        let (data, transfer) = match &mut self.inner {
            Inner::Http(c) => {
                let b: Vec<BundlePiece> = pieces
                    .iter()
                    .map(|p| BundlePiece {
                        key: &p.key,
                        len: p.len,
                        hash: &p.hash,
                    })
                    .collect();
                let data = c.fetch_pieces(&b, cancel).await;
                (data, c.take_report())
            }
            Inner::Dir(d) => {
                let d = d.clone();
                let pieces = pieces.to_vec();
                let n = pieces.len();
                let data = blocking(move || {
                    Ok(pieces
                        .iter()
                        .map(|p| d.fetch_checked(&p.key, &p.hash))
                        .collect::<Vec<_>>())
                })
                .await
                .unwrap_or_else(|e| vec![Err(e); n]);
                (data, TransferReport::default())
            }
        };
        BatchData {
            data,
            requests: self.stats.requests.load(Ordering::Relaxed) - requests0,
            wire_bytes: self.stats.bytes.load(Ordering::Relaxed) - bytes0,
            transfer,
        }
    }
}

/// Runs file reads off the async threads.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, ClientError> + Send + 'static,
) -> Result<T, ClientError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| ClientError::Transfer {
            path: "(local read)".into(),
            message: e.to_string(),
        })?
}

/// A database directory read like a server.
#[derive(Clone)]
struct LocalDir {
    root: PathBuf,
    policy: RetryPolicy,
    stats: Arc<ClientStats>,
}

impl LocalDir {
    fn io(&self, path: &Path, e: impl std::fmt::Display) -> ClientError {
        ClientError::Transfer {
            path: path.display().to_string(),
            message: e.to_string(),
        }
    }

    /// Reads `key` (a whole object of at most `max_body` bytes, or a range of one).
    fn read(&self, key: &FetchKey) -> Result<Vec<u8>, ClientError> {
        use std::io::{Read, Seek, SeekFrom};
        let rel = object_rel_path(&key.object)
            .ok_or_else(|| ClientError::BadObject(key.object.to_string()))?;
        let path = self.root.join(rel);
        let mut f = std::fs::File::open(&path).map_err(|e| self.io(&path, e))?;
        let size = f.metadata().map_err(|e| self.io(&path, e))?.len();
        let (offset, len) = key.range.unwrap_or((0, size));
        if offset.checked_add(len).is_none_or(|end| end > size) {
            return Err(ClientError::Length {
                path: path.display().to_string(),
                len: size,
                expected: offset.saturating_add(len),
            });
        }
        if len > self.policy.max_body {
            return Err(self.io(
                &path,
                format!(
                    "{len} bytes, more than the limit of {}",
                    self.policy.max_body
                ),
            ));
        }
        let mut data = vec![0u8; len as usize];
        f.seek(SeekFrom::Start(offset))
            .and_then(|_| f.read_exact(&mut data))
            .map_err(|e| self.io(&path, e))?;
        self.stats.requests.fetch_add(1, Ordering::Relaxed);
        self.stats.bytes.fetch_add(len, Ordering::Relaxed);
        Ok(data)
    }

    /// [`LocalDir::read`] checked against `hash` (read again on a mismatch, up to
    /// `checksum_attempts` times; never returned when wrong).
    fn fetch_checked(&self, key: &FetchKey, hash: &str) -> Result<Bytes, ClientError> {
        let attempts = self.policy.checksum_attempts.max(1);
        for _ in 0..attempts {
            let data = self.read(key)?;
            if hash_matches(&data, hash) {
                return Ok(Bytes::from(data));
            }
            self.stats.checksum_failures.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(
                "{}: object {} does not match its hash",
                self.root.display(),
                key.object
            );
        }
        Err(ClientError::Checksum {
            path: format!("{}/objects/…/{}", self.root.display(), key.object),
            attempts,
        })
    }

    fn manifest(&self) -> Result<ManifestFetch, ClientError> {
        let path = self.root.join(db::MANIFEST_FILE);
        let json = std::fs::read(&path).map_err(|e| self.io(&path, e))?;
        if json.len() as u64 > self.policy.max_body {
            return Err(ClientError::DecodedTooLarge {
                path: path.display().to_string(),
                limit: self.policy.max_body,
            });
        }
        let hash_path = self.root.join(db::MANIFEST_HASH_FILE);
        let checked = match std::fs::read_to_string(&hash_path) {
            Ok(text) => {
                let got = blake3::hash(&json).to_hex();
                if text.trim() != got.as_str() {
                    return Err(ClientError::Manifest(format!(
                        "{}: hashes to {got}, {} says {}",
                        path.display(),
                        hash_path.display(),
                        text.trim()
                    )));
                }
                true
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
            Err(e) => return Err(self.io(&hash_path, e)),
        };
        let root =
            db::parse_root(&path, &json).map_err(|e| ClientError::Manifest(e.to_string()))?;
        // The pieces of the index, each counted as a request of its size.
        let mut piece_bytes = 0u64;
        let mut pieces = 0u64;
        let top = db::index::read_all(root, |r: &tracks::manifest::ObjectRef| {
            let b = db::read_piece(&self.root, r)?;
            piece_bytes += b.len() as u64;
            pieces += 1;
            Ok::<_, db::DbError>(b)
        })
        .map_err(|e| ClientError::Manifest(format!("{}: {e}", path.display())))?;
        self.stats.requests.fetch_add(1 + pieces, Ordering::Relaxed);
        self.stats
            .bytes
            .fetch_add(json.len() as u64 + piece_bytes, Ordering::Relaxed);
        Ok(ManifestFetch {
            top,
            transferred_bytes: json.len() as u64 + piece_bytes,
            requests: 1 + pieces,
            round_trips: 1,
            json_bytes: json.len() as u64,
            gzip: false,
            checked,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sources_are_urls_or_database_directories() {
        assert!(matches!(
            Source::parse("http://127.0.0.1:9/db"),
            Ok(Source::Http(_))
        ));
        assert!(Source::parse("https://example.org").is_err());
        let e = Source::parse("/nonexistent/railview-db")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no manifest.json"), "{e}");
    }
}
