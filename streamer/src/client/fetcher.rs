//! The asynchronous fetcher: a priority queue of downloads served by a fixed number of
//! workers (= the limit on requests in flight), each holding one connection.
//!
//! Submitting a key that is already queued updates its priority; [`Fetcher::retain`] cancels
//! every queued or running request the caller no longer wants (stale requests). Results come
//! back on a channel in completion order; each carries checked bytes or an error, never bytes
//! that failed their checksum.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use bytes::Bytes;
use tokio::sync::{mpsc, Notify};
use tokio::task::JoinHandle;

use super::http::{ClientError, ClientStats, Connection, FetchKey, RetryPolicy, ServerUrl};

/// One download to make.
#[derive(Clone, Debug)]
pub struct FetchRequest {
    pub key: FetchKey,
    /// BLAKE3 the bytes must have (lowercase hex).
    pub expected_hash: String,
    /// Larger is sooner.
    pub priority: f64,
}

/// A finished download.
#[derive(Debug)]
pub struct FetchOutcome {
    pub key: FetchKey,
    pub result: Result<Bytes, ClientError>,
    /// Seconds from the worker taking the request to the last byte.
    pub elapsed_s: f64,
}

struct Queued {
    req: FetchRequest,
    seq: u64,
}

#[derive(Default)]
struct Queue {
    waiting: HashMap<FetchKey, Queued>,
    running: HashMap<FetchKey, Arc<AtomicBool>>,
    seq: u64,
    closed: bool,
}

struct Shared {
    queue: Mutex<Queue>,
    wake: Notify,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Queue> {
        // A worker never panics while holding the lock; recover the data if one did.
        self.queue.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Highest priority first, then oldest.
    fn pop(&self) -> Option<(FetchRequest, Arc<AtomicBool>)> {
        let mut q = self.lock();
        let key = q
            .waiting
            .iter()
            .max_by(|a, b| {
                a.1.req
                    .priority
                    .total_cmp(&b.1.req.priority)
                    .then(b.1.seq.cmp(&a.1.seq))
            })
            .map(|(k, _)| k.clone())?;
        let item = q.waiting.remove(&key)?;
        let flag = Arc::new(AtomicBool::new(false));
        q.running.insert(key, flag.clone());
        Some((item.req, flag))
    }
}

/// Fetcher settings.
#[derive(Clone, Debug)]
pub struct FetcherConfig {
    /// Requests in flight at most (one connection each).
    pub max_in_flight: usize,
    pub retry: RetryPolicy,
}

impl Default for FetcherConfig {
    fn default() -> Self {
        FetcherConfig {
            max_in_flight: 4,
            retry: RetryPolicy::default(),
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
    /// is running is left alone.
    pub fn submit(&self, req: FetchRequest) {
        {
            let mut q = self.shared.lock();
            if q.running.contains_key(&req.key) {
                return;
            }
            q.seq += 1;
            let seq = q.seq;
            match q.waiting.get_mut(&req.key) {
                Some(w) => w.req.priority = req.priority,
                None => {
                    q.waiting.insert(req.key.clone(), Queued { req, seq });
                }
            }
        }
        self.shared.wake.notify_one();
    }

    /// Cancel every queued or running request whose key `keep` rejects.
    pub fn retain(&self, mut keep: impl FnMut(&FetchKey) -> bool) {
        let mut q = self.shared.lock();
        q.waiting.retain(|k, _| keep(k));
        for (k, flag) in &q.running {
            if !keep(k) {
                flag.store(true, Ordering::Relaxed);
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
        let (req, cancel) = job;
        let start = Instant::now();
        let result = conn
            .fetch_checked(&req.key, &req.expected_hash, Some(&cancel))
            .await;
        let result = if cancel.load(Ordering::Relaxed) {
            Err(ClientError::Cancelled)
        } else {
            result
        };
        shared.lock().running.remove(&req.key);
        // More work may be waiting that this worker did not see while busy.
        shared.wake.notify_one();
        let outcome = FetchOutcome {
            key: req.key,
            result,
            elapsed_s: start.elapsed().as_secs_f64(),
        };
        if tx.send(outcome).is_err() {
            return;
        }
    }
}
