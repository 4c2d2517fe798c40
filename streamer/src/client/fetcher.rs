//! The asynchronous fetcher: a priority queue of downloads served by a fixed number of
//! workers (= the limit on requests in flight), each holding one connection.
//!
//! [`Fetcher`] takes [`FetchRequest`]s (key, hash, priority) and hands back one
//! [`FetchOutcome`] per key; [`FetcherConfig`] sets the workers and the bundle limits.
//!
//! Each worker takes the highest-priority queued request and, when the server serves
//! `/bundle`, further queued requests in priority order whose lengths are known (byte ranges,
//! or whole objects submitted with [`Fetcher::submit_sized`]) up to
//! [`FetcherConfig::bundle_max_entries`] entries and [`Fetcher::bundle_max_bytes`] bytes, and
//! fetches them in one round trip. Every key still gets its own outcome: checked bytes or an
//! error, never bytes that failed their checksum (a bundle with a bad piece is fetched again;
//! if that keeps failing, its keys are fetched one by one so only the bad piece fails). A
//! server without `/bundle` (a static host) is detected once and then served one request per
//! key, as are whole objects of unknown length.
//!
//! Submitting a key that is already queued updates its priority; [`Fetcher::retain`] cancels
//! every queued or running request the caller no longer wants (stale requests): queued keys
//! are dropped, running keys report [`ClientError::Cancelled`] instead of their bytes, and a
//! bundle whose keys are all cancelled is abandoned mid-transfer. Results come back on a
//! channel in completion order (the keys of one bundle in bundle order).

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use bytes::Bytes;
use tokio::sync::{mpsc, Notify};
use tokio::task::JoinHandle;

use super::http::{
    BundlePiece, ClientError, ClientStats, Connection, FetchKey, KeyMap, RetryPolicy, ServerUrl,
    TransferReport,
};

/// One download to make.
#[derive(Clone, Debug)]
pub struct FetchRequest {
    pub key: FetchKey,
    /// BLAKE3 the bytes must have (lowercase hex).
    pub expected_hash: String,
    /// Larger is sooner.
    pub priority: f64,
}

/// The HTTP request an outcome arrived with (one key, or a bundle of several).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RequestInfo {
    /// Distinct per request of this fetcher, from 1 (all keys of one bundle share it; 0 for
    /// keys that failed or were cancelled).
    pub id: u64,
    /// Keys the request carried.
    pub keys: usize,
    /// Bytes the request delivered in all (0 when it failed).
    pub bytes: u64,
}

/// A finished download.
#[derive(Debug)]
pub struct FetchOutcome {
    pub key: FetchKey,
    pub result: Result<Bytes, ClientError>,
    /// Seconds from the worker taking the request to the last byte (of the whole bundle when
    /// the key came in one).
    pub elapsed_s: f64,
    /// The request that carried the key: a link estimate should time `request.bytes` against
    /// `elapsed_s` once per request, not every key of a bundle.
    pub request: RequestInfo,
    /// What the worker's requests for this job cost in attempts, retries, timeouts and
    /// outage: carried by the first outcome of each job (the others hold zeros), so summing
    /// over outcomes counts each once.
    pub transfer: TransferReport,
}

struct Queued {
    req: FetchRequest,
    /// Exact length of the bytes, when known (ranges always; whole objects when given).
    len: Option<u64>,
    seq: u64,
}

/// Cancellation state of one request in flight.
struct JobCancel {
    /// Set when every key of the request is cancelled: abandon the transfer.
    all: AtomicBool,
    /// Keys not yet cancelled.
    left: AtomicUsize,
}

struct Running {
    cancelled: Arc<AtomicBool>,
    job: Arc<JobCancel>,
}

#[derive(Default)]
struct Queue {
    waiting: KeyMap<Queued>,
    running: KeyMap<Running>,
    seq: u64,
    closed: bool,
}

struct Shared {
    queue: Mutex<Queue>,
    wake: Notify,
    /// Bundle byte limit (see [`Fetcher::set_bundle_max_bytes`]).
    bundle_bytes: AtomicU64,
    bundle_entries: usize,
    /// Some connection found that the server has no `/bundle`.
    no_bundles: AtomicBool,
    next_request: AtomicU64,
}

/// One request taken by a worker.
struct Job {
    items: Vec<(FetchRequest, Option<u64>, Arc<AtomicBool>)>,
    cancel: Arc<JobCancel>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Queue> {
        // A worker never panics while holding the lock; recover the data if one did.
        self.queue.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The highest-priority request (then the oldest), followed — when bundles are on — by
    /// the next ones in the same order while they have known lengths and fit the limits.
    fn pop(&self) -> Option<Job> {
        let bundles = !self.no_bundles.load(Ordering::Relaxed) && self.bundle_entries > 1;
        let max_bytes = self.bundle_bytes.load(Ordering::Relaxed);
        let mut q = self.lock();
        let by_priority = |a: &&Queued, b: &&Queued| {
            b.req
                .priority
                .total_cmp(&a.req.priority)
                .then(a.seq.cmp(&b.seq))
        };
        let keys: Vec<FetchKey> = if bundles {
            let mut order: Vec<&Queued> = q.waiting.values().collect();
            // At most `bundle_entries` are taken: select those, then sort only them (the
            // queue can hold thousands of keys and every worker takes this lock).
            let k = self.bundle_entries;
            if k < order.len() {
                order.select_nth_unstable_by(k, by_priority);
                order.truncate(k);
            }
            order.sort_by(by_priority);
            let mut keys = Vec::new();
            let mut bytes = 0u64;
            for w in order {
                let Some(len) = w.len else {
                    // Unknown length: alone, and only as the first.
                    if keys.is_empty() {
                        keys.push(w.req.key.clone());
                    }
                    break;
                };
                if !keys.is_empty() && bytes.saturating_add(len) > max_bytes {
                    break;
                }
                keys.push(w.req.key.clone());
                bytes = bytes.saturating_add(len);
                if keys.len() >= self.bundle_entries {
                    break;
                }
            }
            keys
        } else {
            q.waiting
                .values()
                .min_by(by_priority)
                .map(|w| vec![w.req.key.clone()])
                .unwrap_or_default()
        };
        if keys.is_empty() {
            return None;
        }
        let cancel = Arc::new(JobCancel {
            all: AtomicBool::new(false),
            left: AtomicUsize::new(keys.len()),
        });
        let mut items = Vec::with_capacity(keys.len());
        for key in keys {
            let Some(w) = q.waiting.remove(&key) else {
                continue;
            };
            let flag = Arc::new(AtomicBool::new(false));
            q.running.insert(
                key,
                Running {
                    cancelled: flag.clone(),
                    job: cancel.clone(),
                },
            );
            items.push((w.req, w.len, flag));
        }
        Some(Job { items, cancel })
    }
}

/// Fetcher settings.
#[derive(Clone, Debug)]
pub struct FetcherConfig {
    /// Requests in flight at most (one connection each).
    pub max_in_flight: usize,
    pub retry: RetryPolicy,
    /// Keys one bundle carries at most; 1 turns bundles off (one request per key).
    pub bundle_max_entries: usize,
    /// Bytes one bundle carries at most (its first key always goes, whatever its size);
    /// [`Fetcher::set_bundle_max_bytes`] changes it while running, e.g. to what one latency
    /// carries at the estimated bandwidth.
    pub bundle_max_bytes: u64,
}

/// The smallest bundle byte limit worth using: a few dozen small PTM levels.
pub const MIN_BUNDLE_BYTES: u64 = 16 * 1024;

impl Default for FetcherConfig {
    fn default() -> Self {
        FetcherConfig {
            max_in_flight: 4,
            retry: RetryPolicy::default(),
            bundle_max_entries: 64,
            bundle_max_bytes: MIN_BUNDLE_BYTES,
        }
    }
}

/// Prioritised, cancellable downloads from one server.
pub struct Fetcher {
    shared: Arc<Shared>,
    results: mpsc::UnboundedReceiver<FetchOutcome>,
    workers: Vec<JoinHandle<()>>,
    stats: Arc<ClientStats>,
}

impl Fetcher {
    /// Start the workers on the current tokio runtime.
    pub fn new(url: ServerUrl, config: FetcherConfig) -> Fetcher {
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue::default()),
            wake: Notify::new(),
            bundle_bytes: AtomicU64::new(config.bundle_max_bytes.max(1)),
            bundle_entries: config.bundle_max_entries.max(1),
            no_bundles: AtomicBool::new(false),
            next_request: AtomicU64::new(1),
        });
        let stats = Arc::new(ClientStats::default());
        let (tx, rx) = mpsc::unbounded_channel();
        let workers = (0..config.max_in_flight.max(1))
            .map(|_| {
                let conn = Connection::new(url.clone(), config.retry.clone(), stats.clone());
                tokio::spawn(worker(shared.clone(), conn, tx.clone()))
            })
            .collect();
        Fetcher {
            shared,
            results: rx,
            workers,
            stats,
        }
    }

    /// Queue a request, or update the priority of the same key already queued. A key that
    /// is running is left alone. A whole object (no range) submitted this way travels alone
    /// (its length is unknown); see [`Fetcher::submit_sized`].
    pub fn submit(&self, req: FetchRequest) {
        self.submit_all([(req, None)]);
    }

    /// [`Fetcher::submit`] with the exact length of the bytes (e.g. the manifest's size of a
    /// whole object), so the request may travel in a bundle.
    pub fn submit_sized(&self, req: FetchRequest, len: u64) {
        self.submit_all([(req, Some(len))]);
    }

    /// Queue many requests at once (`(request, known length)`), so the workers see them
    /// together and bundle them.
    pub fn submit_all(&self, reqs: impl IntoIterator<Item = (FetchRequest, Option<u64>)>) {
        let mut added = false;
        {
            let mut q = self.shared.lock();
            for (req, len) in reqs {
                if q.running.contains_key(&req.key) {
                    continue;
                }
                // A range's length is the range's; a stated length must agree with it.
                let len = match req.key.range {
                    Some((_, l)) => Some(l),
                    None => len,
                };
                q.seq += 1;
                let seq = q.seq;
                match q.waiting.get_mut(&req.key) {
                    Some(w) => w.req.priority = req.priority,
                    None => {
                        q.waiting.insert(req.key.clone(), Queued { req, len, seq });
                    }
                }
                added = true;
            }
        }
        if added {
            self.shared.wake.notify_one();
        }
    }

    /// Change the bundle byte limit (at least 1; the first key of a bundle always goes).
    pub fn set_bundle_max_bytes(&self, bytes: u64) {
        self.shared
            .bundle_bytes
            .store(bytes.max(1), Ordering::Relaxed);
    }

    /// The bundle byte limit now.
    pub fn bundle_max_bytes(&self) -> u64 {
        self.shared.bundle_bytes.load(Ordering::Relaxed)
    }

    /// Whether requests still travel in bundles (false once the server turned out to have
    /// no `/bundle`, or when the config allows one key per bundle).
    pub fn bundles_enabled(&self) -> bool {
        self.shared.bundle_entries > 1 && !self.shared.no_bundles.load(Ordering::Relaxed)
    }

    /// Cancel every queued or running request whose key `keep` rejects.
    pub fn retain(&self, mut keep: impl FnMut(&FetchKey) -> bool) {
        let mut q = self.shared.lock();
        q.waiting.retain(|k, _| keep(k));
        for (k, r) in &q.running {
            if !keep(k) && !r.cancelled.swap(true, Ordering::Relaxed) {
                // The last key of a request cancelled: stop the transfer.
                if r.job.left.fetch_sub(1, Ordering::Relaxed) == 1 {
                    r.job.all.store(true, Ordering::Relaxed);
                }
            }
        }
    }

    /// Cancel one key.
    pub fn cancel(&self, key: &FetchKey) {
        self.retain(|k| k != key);
    }

    /// Queued plus running.
    pub fn pending(&self) -> usize {
        let q = self.shared.lock();
        q.waiting.len() + q.running.len()
    }

    /// Keys in requests on the wire (a bundle counts each of its keys).
    pub fn running(&self) -> usize {
        self.shared.lock().running.len()
    }

    /// Whether `key` is queued or running.
    pub fn is_pending(&self, key: &FetchKey) -> bool {
        let q = self.shared.lock();
        q.waiting.contains_key(key) || q.running.contains_key(key)
    }

    /// The next finished download.
    pub async fn next(&mut self) -> Option<FetchOutcome> {
        self.results.recv().await
    }

    /// A finished download if one is ready.
    pub fn try_next(&mut self) -> Option<FetchOutcome> {
        self.results.try_recv().ok()
    }

    pub fn stats(&self) -> &Arc<ClientStats> {
        &self.stats
    }
}

impl Drop for Fetcher {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        for w in &self.workers {
            w.abort();
        }
    }
}

type KeyResult = (Result<(Bytes, RequestInfo), ClientError>, f64);

/// Fetch one job: per key (in job order) its bytes with the request that carried them, and
/// the seconds from `start` to the end of that request.
async fn run_job(
    shared: &Shared,
    conn: &mut Connection,
    job: &Job,
    start: Instant,
) -> Vec<KeyResult> {
    let new_id = || shared.next_request.fetch_add(1, Ordering::Relaxed);
    let single = |data: Result<Bytes, ClientError>, id: u64, t0: Instant| {
        let r = data.map(|b| {
            let info = RequestInfo {
                id,
                keys: 1,
                bytes: b.len() as u64,
            };
            (b, info)
        });
        (r, t0.elapsed().as_secs_f64())
    };
    let cancel = Some(&job.cancel.all);
    if let [(req, _, _)] = job.items.as_slice() {
        let r = conn
            .fetch_checked(&req.key, &req.expected_hash, cancel)
            .await;
        return vec![single(r, new_id(), start)];
    }
    let pieces: Vec<BundlePiece> = job
        .items
        .iter()
        .map(|(req, len, _)| BundlePiece {
            key: &req.key,
            len: len.unwrap_or(0),
            hash: &req.expected_hash,
        })
        .collect();
    let id = new_id();
    match conn.fetch_checked_bundle(&pieces, cancel).await {
        Ok(parts) => {
            let info = RequestInfo {
                id,
                keys: parts.len(),
                bytes: parts.iter().map(|b| b.len() as u64).sum(),
            };
            let t = start.elapsed().as_secs_f64();
            parts.into_iter().map(|b| (Ok((b, info)), t)).collect()
        }
        // One object's fault (the server refused or mangled this bundle): key by key, so
        // only the bad ones fail; an unreachable server fails every key at once.
        Err(e) if e.is_object_fault() => {
            tracing::warn!(
                "bundle of {} keys failed ({e}); fetching them one by one",
                pieces.len()
            );
            let mut out = Vec::with_capacity(job.items.len());
            for (req, _, flag) in &job.items {
                let t0 = Instant::now();
                if flag.load(Ordering::Relaxed) {
                    out.push((Err(ClientError::Cancelled), 0.0));
                    continue;
                }
                let r = conn
                    .fetch_checked(&req.key, &req.expected_hash, Some(flag))
                    .await;
                out.push(single(r, new_id(), t0));
            }
            out
        }
        Err(e) => {
            let t = start.elapsed().as_secs_f64();
            job.items.iter().map(|_| (Err(e.clone()), t)).collect()
        }
    }
}

async fn worker(
    shared: Arc<Shared>,
    mut conn: Connection,
    tx: mpsc::UnboundedSender<FetchOutcome>,
) {
    loop {
        let job = loop {
            let notified = shared.wake.notified();
            if shared.lock().closed {
                return;
            }
            if let Some(job) = shared.pop() {
                break job;
            }
            notified.await;
        };
        // Another worker may take what this one left queued.
        if !shared.lock().waiting.is_empty() {
            shared.wake.notify_one();
        }
        let start = Instant::now();
        let results = run_job(&shared, &mut conn, &job, start).await;
        let mut transfer = Some(conn.take_report());
        if !conn.bundles_supported() {
            shared.no_bundles.store(true, Ordering::Relaxed);
        }
        {
            let mut q = shared.lock();
            for (req, _, _) in &job.items {
                q.running.remove(&req.key);
            }
        }
        // More work may be waiting that this worker did not see while busy.
        shared.wake.notify_one();
        for ((req, _, cancelled), (result, elapsed_s)) in job.items.into_iter().zip(results) {
            let (result, request) = match result {
                _ if cancelled.load(Ordering::Relaxed) => {
                    (Err(ClientError::Cancelled), RequestInfo::default())
                }
                Ok((b, info)) => (Ok(b), info),
                Err(e) => (Err(e), RequestInfo::default()),
            };
            let outcome = FetchOutcome {
                key: req.key,
                result,
                elapsed_s,
                request,
                transfer: transfer.take().unwrap_or_default(),
            };
            if tx.send(outcome).is_err() {
                return;
            }
        }
    }
}
