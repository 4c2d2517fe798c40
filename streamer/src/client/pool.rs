//! The live executor of the scheduler's requests: a fixed number of workers (the limit on
//! requests in flight), each with its own [`Transport`], taking [`Batch`]es from a shared
//! [`Dispatcher`] as soon as a slot is free.
//!
//! [`Pool::set_queue`] replaces what has not gone out with the scheduler's latest wants;
//! [`Pool::cancel`] marks keys on the wire as unwanted (they come back as
//! [`ClientError::Cancelled`], and a request whose keys are all cancelled is abandoned
//! mid-transfer). Every key gets one [`Completion`]: checked bytes or an error, never bytes
//! that failed their check (a batch that keeps failing for a bad piece is fetched piece by
//! piece, so only that piece fails). Completions of a batch are handed over before its slot
//! is freed, so a pool that is [`Pool::idle`] has nothing left to hand over but what waits
//! in [`Pool::try_next`]. Times are read from the session's [`Clock`].

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use bytes::Bytes;
use tokio::sync::{mpsc, Notify};
use tokio::task::JoinHandle;

use super::clock::Clock;
use super::http::{ClientError, ClientStats, FetchKey, KeySet, RetryPolicy, TransferReport};
use super::schedule::{Batch, DispatchLimits, Dispatcher, Want};
use super::transport::{Source, Transport};

/// One finished key.
#[derive(Debug)]
pub struct Completion {
    pub key: FetchKey,
    pub result: Result<Bytes, ClientError>,
    /// The request (batch) that carried it (0: none went out).
    pub request: u64,
    /// Body bytes that request took on the wire (its retries included), and the HTTP
    /// requests it took.
    pub request_bytes: u64,
    pub http_requests: u64,
    /// Seconds from the request going out to its last byte.
    pub elapsed_s: f64,
    /// What the request cost in retries and outage (on one completion of the request, the
    /// others' default).
    pub transfer: TransferReport,
}

struct Job {
    /// Per piece: cancelled.
    flags: Vec<Arc<AtomicBool>>,
    /// Set once every piece is cancelled: abandon the transfer.
    all: Arc<AtomicBool>,
    left: Arc<AtomicUsize>,
}

#[derive(Default)]
struct State {
    dispatcher: Dispatcher,
    jobs: HashMap<u64, (Vec<FetchKey>, Job)>,
    /// Every batch that went out, in order (keys), when recording.
    log: Option<Vec<Vec<FetchKey>>>,
    closed: bool,
}

struct Shared {
    state: Mutex<State>,
    wake: Notify,
    clock: Arc<dyn Clock>,
    /// Some transport found that the server has no `/bundle`.
    no_bundles: AtomicBool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A worker never panics while holding the lock; recover the data if one did.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The workers and their shared queue (see the module docs).
pub struct Pool {
    shared: Arc<Shared>,
    results: mpsc::UnboundedReceiver<Completion>,
    workers: Vec<JoinHandle<()>>,
    stats: Vec<Arc<ClientStats>>,
}

impl Pool {
    /// `workers` workers on the current tokio runtime.
    pub fn new(source: &Source, retry: RetryPolicy, workers: usize, clock: Arc<dyn Clock>) -> Pool {
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            wake: Notify::new(),
            clock,
            no_bundles: AtomicBool::new(false),
        });
        let (tx, rx) = mpsc::unbounded_channel();
        let mut stats = Vec::new();
        let workers = (0..workers.max(1))
            .map(|_| {
                let t = Transport::new(source, retry.clone());
                stats.push(t.stats().clone());
                tokio::spawn(worker(shared.clone(), t, tx.clone()))
            })
            .collect();
        Pool {
            shared,
            results: rx,
            workers,
            stats,
        }
    }

    /// The scheduler's wants replace what has not gone out (see [`Dispatcher::replace`]).
    pub fn set_queue(&self, wants: Vec<Want>, limits: DispatchLimits) {
        self.shared.lock().dispatcher.replace(wants, limits);
        self.shared.wake.notify_waiters();
        self.shared.wake.notify_one();
    }

    /// Marks `keys` on the wire as unwanted.
    pub fn cancel(&self, keys: &[FetchKey]) {
        if keys.is_empty() {
            return;
        }
        let wanted_gone: KeySet = keys.iter().cloned().collect();
        let st = self.shared.lock();
        for (keys, job) in st.jobs.values() {
            for (k, flag) in keys.iter().zip(&job.flags) {
                if wanted_gone.contains(k)
                    && !flag.swap(true, Ordering::Relaxed)
                    && job.left.fetch_sub(1, Ordering::Relaxed) == 1
                {
                    job.all.store(true, Ordering::Relaxed);
                }
            }
        }
    }

    /// Keys of the requests on the wire.
    pub fn running_keys(&self) -> KeySet {
        self.shared.lock().dispatcher.running_keys()
    }

    /// `(requests on the wire, wants queued)`.
    pub fn load(&self) -> (usize, usize) {
        let st = self.shared.lock();
        (st.dispatcher.running(), st.dispatcher.queued())
    }

    /// Nothing on the wire and nothing that may go now (completions may still wait in
    /// [`Pool::try_next`]).
    pub fn idle(&self) -> bool {
        self.shared.lock().dispatcher.settled()
    }

    /// A finished key if one is ready.
    pub fn try_next(&mut self) -> Option<Completion> {
        self.results.try_recv().ok()
    }

    /// Whether many objects still travel in one request.
    pub fn bundles_supported(&self) -> bool {
        !self.shared.no_bundles.load(Ordering::Relaxed)
    }

    /// Record the keys of every batch that goes out from now on ([`Pool::take_log`]).
    pub fn record(&self) {
        self.shared.lock().log.get_or_insert_with(Vec::new);
    }

    /// The batches recorded so far, in the order they went out.
    pub fn take_log(&self) -> Vec<Vec<FetchKey>> {
        self.shared
            .lock()
            .log
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Counters summed over the workers' transports: `(requests, bytes, checksum failures,
    /// reconnects)`.
    pub fn totals(&self) -> (u64, u64, u64, u64) {
        let mut t = (0, 0, 0, 0);
        for s in &self.stats {
            t.0 += s.requests.load(Ordering::Relaxed);
            t.1 += s.bytes.load(Ordering::Relaxed);
            t.2 += s.checksum_failures.load(Ordering::Relaxed);
            t.3 += s.reconnects.load(Ordering::Relaxed);
        }
        t
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        for w in &self.workers {
            w.abort();
        }
    }
}

async fn worker(shared: Arc<Shared>, mut t: Transport, tx: mpsc::UnboundedSender<Completion>) {
    loop {
        let (batch, job) = loop {
            let notified = shared.wake.notified();
            {
                let mut st = shared.lock();
                if st.closed {
                    return;
                }
                if let Some(b) = st.dispatcher.pop() {
                    let n = b.pieces.len();
                    let job = Job {
                        flags: (0..n).map(|_| Arc::new(AtomicBool::new(false))).collect(),
                        all: Arc::new(AtomicBool::new(false)),
                        left: Arc::new(AtomicUsize::new(n)),
                    };
                    let keys: Vec<FetchKey> = b.pieces.iter().map(|p| p.key.clone()).collect();
                    if let Some(log) = &mut st.log {
                        log.push(keys.clone());
                    }
                    let flags = Job {
                        flags: job.flags.clone(),
                        all: job.all.clone(),
                        left: job.left.clone(),
                    };
                    st.jobs.insert(b.id, (keys, job));
                    break (b, flags);
                }
            }
            notified.await;
        };
        // Another worker may take what this one left queued.
        shared.wake.notify_one();
        let results = run(&shared, &mut t, &batch, &job).await;
        if !t.bundles_supported() {
            shared.no_bundles.store(true, Ordering::Relaxed);
        }
        {
            let mut st = shared.lock();
            for r in results {
                if tx.send(r).is_err() {
                    return;
                }
            }
            st.jobs.remove(&batch.id);
            st.dispatcher.finish(batch.id);
        }
        shared.wake.notify_one();
    }
}

/// Fetch one batch: one completion per piece, in order.
async fn run(shared: &Shared, t: &mut Transport, batch: &Batch, job: &Job) -> Vec<Completion> {
    let t0 = shared.clock.now_s();
    let outcome = t.fetch_batch(&batch.pieces, Some(&job.all)).await;
    let elapsed_s = (shared.clock.now_s() - t0).max(0.0);
    let cancelled = |i: usize| job.flags[i].load(Ordering::Relaxed);
    let done = |i: usize, result: Result<Bytes, ClientError>, bytes: u64, reqs: u64| {
        let result = if cancelled(i) {
            Err(ClientError::Cancelled)
        } else {
            result
        };
        Completion {
            key: batch.pieces[i].key.clone(),
            result,
            request: batch.id,
            request_bytes: bytes,
            http_requests: reqs,
            elapsed_s,
            transfer: TransferReport::default(),
        }
    };
    // What the transfer cost in retries travels with the batch's first piece.
    let mut transfer = Some(outcome.transfer);
    outcome
        .data
        .into_iter()
        .enumerate()
        .map(|(i, r)| {
            let mut c = done(i, r, outcome.wire_bytes, outcome.requests);
            c.transfer = transfer.take().unwrap_or_default();
            c
        })
        .collect()
}
