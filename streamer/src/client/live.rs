//! A real-time streaming session for an interactive viewer.
//!
//! [`LiveSession`] drives the client's one request policy, the sans-IO [`Scheduler`], on a
//! clock (the wall clock; a hand-set one in replay tests): it reads the top manifest from a
//! server or a database directory ([`Source`]), and a tokio runtime on its own thread runs the
//! [`Pool`] of workers that send the scheduler's requests. Each frame the caller hands the
//! position along the track, the camera and — when it has them — live visible-pixel counts
//! from the GPU ([`LiveSession::update`]). The session then
//!
//! 1. feeds the finished downloads to the scheduler, in request order (link estimate, tables,
//!    the cache — which never exceeds its byte budget);
//! 2. ticks the scheduler (plan, prefetch, pins) and hands its wants to the pool, which
//!    replaces what had not gone out, and cancels what it no longer wants on the wire;
//! 3. returns the parts that arrived since the last call ([`Arrival`]: checked bytes only).
//!
//! The walk simulator drives the same scheduler on a virtual clock and link, so its numbers
//! are this session's. When the server goes away, the connections retry with back-off
//! (within the timeouts of [`super::RetryPolicy`]); failed downloads are counted, new requests
//! pause briefly, and what is cached stays available. A part or table whose object is damaged
//! or missing is a fault of that part alone ([`super::FailureBook`], kept by the scheduler):
//! asked for again later, given up after repeated faults, while everything else streams on.
//! [`LiveStats`] shows the outage: time without progress now and at its longest, retries,
//! timeouts, faults.

use std::collections::VecDeque;
use std::sync::Arc;

use bytes::Bytes;
use tracks::manifest::Manifest;
use tracks::PerspectiveCamera;

use super::budget::{LiveCount, PriorityMode};
use super::cache::Cache;
use super::clock::{Clock, WallClock};
use super::failures::ProgressClock;
use super::http::{ClientError, FetchKey, RetryPolicy};
use super::items::ItemTable;
use super::pool::Pool;
use super::schedule::{Arrival, Scheduler, SchedulerConfig, Strategy};
use super::transport::{Source, Transport};
use db::split::TopManifest;

/// Settings of a session.
#[derive(Clone, Debug)]
pub struct LiveConfig {
    /// The request policy (the walk simulator's defaults).
    pub schedule: SchedulerConfig,
    /// Retries, back-off and body limits of each connection.
    pub retry: RetryPolicy,
}

impl LiveConfig {
    /// The scheduler's defaults with a cache of `cache_bytes`.
    pub fn with_cache(cache_bytes: u64) -> LiveConfig {
        LiveConfig {
            schedule: SchedulerConfig {
                cache_bytes: cache_bytes.max(1),
                ..SchedulerConfig::default()
            },
            retry: RetryPolicy::default(),
        }
    }
}

/// Why a session could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LiveError {
    #[error("starting the streaming runtime: {0}")]
    Runtime(std::io::Error),
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("track `{0}` not in the manifest (available: {1})")]
    NoTrack(String, String),
}

/// Figures for a UI.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LiveStats {
    /// Seconds since the session started.
    pub t_s: f64,
    /// Bytes per second received over the last two seconds.
    pub bytes_per_s: f64,
    /// Requests on the wire.
    pub in_flight: usize,
    /// Wants queued behind them.
    pub queued: usize,
    pub cache_used: u64,
    pub cache_budget: u64,
    /// Largest cache use seen.
    pub cache_peak: u64,
    /// Bytes pinned (resident parts and the current segment's coarsest levels).
    pub pinned_bytes: u64,
    /// Progressive downloading quality: mean over the current segment's ACH tiles of the
    /// fraction of level groups held (the walk simulator's measure).
    pub quality: f64,
    /// Fraction of the current segment's items showable (mesh and coarsest level held).
    pub coarse_fraction: f64,
    /// Fraction of the visible pixels (live counts) whose tile or background is showable;
    /// 1 = every visible tile at some level.
    pub visible_fraction: f64,
    /// Bytes received in total (the manifest's not included).
    pub bytes: u64,
    /// Requests completed (HTTP requests, or reads of a directory).
    pub requests: u64,
    /// Parts received (checked).
    pub parts: u64,
    /// Downloads that failed because the server could not be reached (given up after
    /// retries), not counting object faults.
    pub failed_requests: u64,
    pub checksum_failures: u64,
    pub reconnects: u64,
    /// Attempts retried after a connection failure, timeout or 5xx, and of them timeouts.
    pub retries: u64,
    pub timeouts: u64,
    /// Seconds requests spent failing before they succeeded or gave up (server
    /// unreachable), summed over requests.
    pub outage_s: f64,
    /// Seconds with requests outstanding and nothing arriving: now, and at the longest.
    pub stalled_s: f64,
    pub longest_stall_s: f64,
    /// Faults of parts or tables whose object is damaged or missing (each asked for again
    /// later), and those given up after repeated faults.
    pub part_faults: u64,
    pub parts_given_up: u64,
    /// Link estimate `(bits/s, latency s)`.
    pub link: (f64, f64),
    /// Latest download error, cleared by the next success.
    pub last_error: Option<String>,
    /// Size of `manifest.json` and the seconds it took to download and parse.
    pub manifest_bytes: u64,
    pub manifest_s: f64,
}

/// A streaming session (see the module docs).
pub struct LiveSession {
    // Dropped before the runtime: its workers are aborted on it.
    pool: Pool,
    _runtime: tokio::runtime::Runtime,
    scheduler: Scheduler,
    config: LiveConfig,
    clock: Arc<dyn Clock>,
    /// Arrivals over the last seconds `(t, bytes)`.
    recent: VecDeque<(f64, u64)>,
    /// Time without progress (requests outstanding, nothing arriving).
    progress: ProgressClock,
    stats: LiveStats,
}

impl LiveSession {
    /// Connect to `source` (`http://host:port[/prefix]`, or a database directory), read the
    /// manifest and pick `track` (by name; the first when `None`), on the wall clock.
    pub fn connect(
        source: &str,
        track: Option<&str>,
        config: LiveConfig,
    ) -> Result<LiveSession, LiveError> {
        Self::connect_with_clock(source, track, config, Arc::new(WallClock::new()))
    }

    /// [`LiveSession::connect`] on `clock`.
    pub fn connect_with_clock(
        source: &str,
        track: Option<&str>,
        config: LiveConfig,
        clock: Arc<dyn Clock>,
    ) -> Result<LiveSession, LiveError> {
        let source = Source::parse(source)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("railview-stream")
            .enable_all()
            .build()
            .map_err(LiveError::Runtime)?;
        let mut t = Transport::new(&source, config.retry.clone());
        let t0 = clock.now_s();
        let fetched = runtime.block_on(t.fetch_manifest())?;
        let manifest_s = clock.now_s() - t0;
        let top = fetched.top;
        let names = || {
            top.tracks
                .iter()
                .map(|t| t.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let track = match track {
            Some(name) => top
                .tracks
                .iter()
                .position(|t| t.name == name)
                .ok_or_else(|| LiveError::NoTrack(name.to_string(), names()))?,
            None if top.tracks.is_empty() => {
                return Err(LiveError::NoTrack("(any)".into(), names()))
            }
            None => 0,
        };
        let scheduler = Scheduler::new(top, track, config.schedule.clone())?;
        let pool = {
            let _guard = runtime.enter();
            Pool::new(
                &source,
                config.retry.clone(),
                config.schedule.max_in_flight,
                clock.clone(),
            )
        };
        let stats = LiveStats {
            cache_budget: scheduler.cache().budget(),
            manifest_bytes: fetched.transferred_bytes,
            manifest_s,
            ..Default::default()
        };
        Ok(LiveSession {
            pool,
            _runtime: runtime,
            scheduler,
            config,
            clock,
            recent: VecDeque::new(),
            progress: ProgressClock::default(),
            stats,
        })
    }

    /// The manifest as far as the tables go: viewpoints whose table has not arrived have no
    /// tiles yet (their tiles cannot be requested); it grows as tables arrive.
    pub fn manifest(&self) -> &Manifest {
        self.scheduler.manifest()
    }

    /// The top manifest the session started from.
    pub fn top(&self) -> &TopManifest {
        self.scheduler.top()
    }

    /// `(tables arrived, viewpoints)` of the session's track.
    pub fn tables_loaded(&self) -> (usize, usize) {
        self.scheduler.tables_loaded()
    }

    /// Whether viewpoint `vp`'s table has arrived (position in the track).
    pub fn has_table(&self, vp: usize) -> bool {
        self.scheduler.has_table(vp)
    }

    /// Position of the session's track in the manifest.
    pub fn track(&self) -> usize {
        self.scheduler.track()
    }

    pub fn table(&self) -> &ItemTable {
        self.scheduler.table()
    }

    pub fn cache(&self) -> &Cache {
        self.scheduler.cache()
    }

    /// The branch the user chose for the next junction (`None`: the one nearest the view).
    pub fn set_branch(&mut self, branch: Option<tracks::network::Branch>) {
        self.scheduler.set_branch(branch);
    }

    pub fn scheduler(&self) -> &Scheduler {
        &self.scheduler
    }

    pub fn config(&self) -> &LiveConfig {
        &self.config
    }

    pub fn stats(&self) -> &LiveStats {
        &self.stats
    }

    /// The priority mode (`None` for `naive`).
    pub fn mode(&self) -> Option<PriorityMode> {
        match self.config.schedule.strategy {
            Strategy::Budget { mode, .. } => Some(mode),
            Strategy::Naive => None,
        }
    }

    /// Whether the session prefetches the predicted next segment.
    pub fn prefetch(&self) -> bool {
        self.config.schedule.strategy.prefetches()
    }

    pub fn set_mode(&mut self, mode: PriorityMode) {
        let prefetch = self.prefetch();
        self.set_strategy(Strategy::Budget { mode, prefetch });
    }

    pub fn set_prefetch(&mut self, on: bool) {
        let mode = self
            .mode()
            .unwrap_or(PriorityMode::Combined { ach_weight: 0.5 });
        self.set_strategy(Strategy::Budget { mode, prefetch: on });
    }

    fn set_strategy(&mut self, strategy: Strategy) {
        self.config.schedule.strategy = strategy;
        self.scheduler.set_strategy(strategy);
    }

    /// Download at most the first `groups` PTM level groups of every item (`None`: all), e.g.
    /// a preview that holds only the coarsest levels; running downloads beyond the cap are
    /// cancelled at the next update.
    pub fn set_level_cap(&mut self, groups: Option<usize>) {
        self.scheduler.set_level_cap(groups);
    }

    pub fn level_cap(&self) -> Option<usize> {
        self.scheduler.level_cap()
    }

    /// Fetch no PTM level finer than `level` ([`Scheduler::set_finest_level`]).
    pub fn set_finest_level(&mut self, level: Option<u32>) {
        self.scheduler.set_finest_level(level);
    }

    /// Cached bytes of one part, if held.
    pub fn part_bytes(&self, item: usize, part: usize) -> Option<&Bytes> {
        self.scheduler.part_bytes(item, part)
    }

    /// Parts held per item, as the session keeps them from frame to frame.
    pub fn held(&self) -> &[usize] {
        self.scheduler.held()
    }

    /// Parts held per item (the prefix present in the cache), by looking every part up.
    pub fn have(&self) -> Vec<usize> {
        let cache = self.scheduler.cache();
        self.scheduler
            .table()
            .items
            .iter()
            .map(|it| {
                it.parts
                    .iter()
                    .take_while(|p| cache.contains(&p.key))
                    .count()
            })
            .collect()
    }

    /// Whether nothing is on the wire and nothing may go now (replays wait for this between
    /// frames).
    pub fn idle(&self) -> bool {
        self.pool.idle()
    }

    /// Record the keys of every request that goes out ([`LiveSession::take_request_log`]).
    pub fn record_requests(&self) {
        self.pool.record();
    }

    /// The requests that went out since recording started (or the last call), in order.
    pub fn take_request_log(&self) -> Vec<Vec<FetchKey>> {
        self.pool.take_log()
    }

    /// One frame: take finished downloads, tick the scheduler, request, cancel; returns what
    /// arrived. `live` are visible-pixel counts measured by the caller (e.g. the GPU feedback
    /// pass); they are merged with the scheduler's CPU estimate (larger count, finer level
    /// per item).
    pub fn update(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> Vec<Arrival> {
        let pos = crate::client::NetPos {
            track: self.scheduler.track(),
            s,
        };
        self.update_at(pos, camera, live)
    }

    /// [`LiveSession::update`] at a position on the network (a walker that turned at a
    /// junction is on another track).
    pub fn update_at(
        &mut self,
        pos: crate::client::NetPos,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> Vec<Arrival> {
        let now = self.clock.now_s();
        let mut done = Vec::new();
        while let Some(c) = self.pool.try_next() {
            done.push(c);
        }
        // In request order, as the simulator delivers them (a stable sort keeps each
        // request's pieces in order).
        done.sort_by_key(|c| c.request);
        let waiting = self.pool.load() != (0, 0) || !done.is_empty();
        let mut arrived = false;
        for c in done {
            self.stats.retries += c.transfer.retries as u64;
            self.stats.timeouts += c.transfer.timeouts as u64;
            self.stats.outage_s += c.transfer.outage_s;
            match &c.result {
                Ok(b) => {
                    arrived = true;
                    self.stats.parts += 1;
                    self.stats.last_error = None;
                    self.recent.push_back((now, b.len() as u64));
                }
                Err(ClientError::Cancelled) => {}
                // An object's fault: the scheduler asks for it again later, or gives it up.
                Err(e) if e.is_object_fault() => {
                    self.stats.last_error = Some(e.to_string());
                }
                Err(e) => {
                    self.stats.failed_requests += 1;
                    self.stats.last_error = Some(e.to_string());
                }
            }
            self.scheduler.arrive(now, c);
        }
        self.scheduler.set_bundles(self.pool.bundles_supported());
        let running = self.pool.running_keys();
        self.progress.observe(now, waiting, arrived);
        let actions = self.scheduler.tick_at(now, pos, camera, live, &running);
        self.pool.cancel(&actions.cancel);
        self.pool.set_queue(actions.wants, actions.limits);
        self.update_stats(now);
        self.scheduler.take_arrivals()
    }

    fn update_stats(&mut self, now: f64) {
        let window = 2.0;
        while self.recent.front().is_some_and(|(t, _)| now - t > window) {
            self.recent.pop_front();
        }
        let span = now.clamp(0.25, window);
        let (in_flight, queued) = self.pool.load();
        let (requests, bytes, checksum_failures, reconnects) = self.pool.totals();
        // Waiting from here on when requests are outstanding after this update.
        self.progress.observe(now, in_flight + queued > 0, false);
        let v = self.scheduler.stats();
        let cache = self.scheduler.cache();
        self.stats = LiveStats {
            t_s: now,
            stalled_s: self.progress.current_s(now),
            longest_stall_s: self.progress.longest_s(),
            part_faults: v.part_faults + v.table_faults,
            parts_given_up: v.parts_given_up + v.tables_given_up,
            bytes_per_s: self.recent.iter().map(|r| r.1).sum::<u64>() as f64 / span,
            in_flight,
            queued,
            cache_used: cache.used(),
            cache_budget: cache.budget(),
            cache_peak: self.stats.cache_peak.max(cache.used()),
            pinned_bytes: v.pinned_bytes,
            quality: v.quality,
            coarse_fraction: v.coarse_fraction,
            visible_fraction: v.visible_fraction,
            bytes,
            requests,
            checksum_failures,
            reconnects,
            link: self.scheduler.link().get(),
            ..std::mem::take(&mut self.stats)
        };
    }
}
