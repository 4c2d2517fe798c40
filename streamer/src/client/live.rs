//! A real-time streaming session for an interactive viewer.
//!
//! [`LiveSession`] composes the client parts on the wall clock: it connects to a server,
//! fetches the manifest and flattens one track into an [`ItemTable`]; a tokio runtime on its
//! own thread runs the [`Fetcher`] (prioritised, cancellable, checked downloads over
//! reconnecting connections). Each frame the caller hands the position along the track, the
//! camera and — when it has them — live visible-pixel counts from the GPU
//! ([`LiveSession::update`]). The session then
//!
//! 1. takes the finished downloads: their times (one sample per HTTP request, a bundle's
//!    parts sharing theirs) feed the running [`LinkEstimate`], their
//!    checked bytes go into the [`Cache`] (which never exceeds its byte budget; an insert that
//!    does not fit is dropped and asked for again later);
//! 2. runs [`plan`] in the selected [`PriorityMode`] (ACH of the current segment culled to the
//!    view frustum, live counts, or both) with the motion-predicted next segment as prefetch;
//!    live counts come from the CPU reference of the visibility pass ([`SceneIndex::count`])
//!    merged with the caller's (per item the larger count and the finer needed level);
//! 3. pins what the plan keeps resident and the coarsest levels of the current segment (its
//!    ACH tiles and the backgrounds of its two viewpoints), submits the plan's downloads (all
//!    at once, with their sizes, so the fetcher bundles them up to what one latency carries at
//!    the estimated bandwidth) and cancels queued or running ones the plan no longer wants;
//! 4. returns the parts that arrived since the last call ([`Arrival`]: checked bytes only).
//!
//! When the server goes away, the connections retry with back-off (within the timeouts of
//! [`super::RetryPolicy`]); failed downloads are counted, new requests pause briefly, and
//! what is cached stays available. A part or table whose object is damaged or missing is a
//! fault of that part alone ([`FailureBook`]): asked for again later, given up after
//! repeated faults, while everything else streams on. [`LiveStats`] shows the outage: time
//! without progress now and at its longest, retries, timeouts, faults.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use bytes::Bytes;
use tracks::manifest::Manifest;

use crate::db::split::{assemble, TopManifest, ViewTable};
use tracks::PerspectiveCamera;

use super::budget::{
    plan, BudgetParams, ItemInfo, LinkEstimate, LiveCount, PlanInput, PriorityMode,
};
use super::cache::Cache;
use super::failures::{FailureBook, FailurePolicy, ProgressClock, Verdict};
use super::fetcher::{FetchRequest, Fetcher, FetcherConfig};
use super::http::{ClientError, Connection, FetchKey, KeyMap, KeySet, ServerUrl};
use super::items::{ItemTable, Part};
use super::predict::{next_segment, segment_at, MotionTracker};
use crate::visibility::{blend_weights, SceneIndex, Surface};

mod tables;

/// Settings of a session.
#[derive(Clone, Debug)]
pub struct LiveConfig {
    /// Byte budget of the cache (downloaded bytes held).
    pub cache_bytes: u64,
    /// Memory/time budgets of the plan (PTM §6.2).
    pub budget: BudgetParams,
    pub mode: PriorityMode,
    /// Request the predicted next segment's tiles at lower priority.
    pub prefetch: bool,
    /// How far ahead (seconds) motion is predicted for prefetch.
    pub prefetch_horizon_s: f64,
    pub fetcher: FetcherConfig,
    /// Link guess used until downloads have been timed.
    pub prior_bps: f64,
    pub prior_latency_s: f64,
    /// Rays of the CPU visibility pass (live counts the caller does not supply).
    pub samples: (u32, u32),
    /// After a failed download, new requests wait this long.
    pub error_pause: Duration,
    /// Parts with the same checksum and length fetched and cached once under one key
    /// ([`ItemTable::set_share_parts`]).
    pub share_parts: bool,
    /// When a damaged or missing part is asked for again, and when it is given up.
    pub failures: FailurePolicy,
}

impl LiveConfig {
    /// Defaults for a cache of `cache_bytes`: the plan may keep half of it resident while
    /// moving and all of it when still (the paper's M and M_static).
    pub fn with_cache(cache_bytes: u64) -> LiveConfig {
        let cache_bytes = cache_bytes.max(1);
        LiveConfig {
            cache_bytes,
            budget: BudgetParams {
                memory_bytes: cache_bytes / 2,
                memory_static_bytes: cache_bytes,
                ..BudgetParams::default()
            },
            mode: PriorityMode::Combined { ach_weight: 0.5 },
            prefetch: true,
            prefetch_horizon_s: 2.0,
            fetcher: FetcherConfig::default(),
            prior_bps: 10e6,
            prior_latency_s: 0.02,
            samples: (32, 18),
            error_pause: Duration::from_millis(500),
            share_parts: true,
            failures: FailurePolicy::default(),
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

/// One part of an item that arrived (checked against the manifest's hash).
#[derive(Clone, Debug)]
pub struct Arrival {
    pub item: usize,
    /// Part index within the item (mesh first when it has one, then PTM groups coarse→fine).
    pub part: usize,
    pub data: Bytes,
}

/// Figures for a UI.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LiveStats {
    /// Seconds since the session started.
    pub t_s: f64,
    /// Bytes per second received over the last two seconds.
    pub bytes_per_s: f64,
    /// Parts in requests on the wire (a bundle carries many).
    pub in_flight: usize,
    /// Parts queued behind them.
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
    /// Bytes received in total.
    pub bytes: u64,
    /// HTTP requests completed (one bundle carries many parts).
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

/// The CPU visibility counts of one camera and pair of blend weights, per item.
struct CpuCounts {
    camera: PerspectiveCamera,
    weights: Vec<(usize, f64)>,
    counts: Vec<LiveCount>,
}

/// A streaming session (see the module docs).
pub struct LiveSession {
    // Dropped before the runtime: its workers are aborted on it.
    fetcher: Fetcher,
    _runtime: tokio::runtime::Runtime,
    manifest: Manifest,
    top: TopManifest,
    /// Tables that have arrived, per viewpoint of the session's track.
    tables: Vec<Option<ViewTable>>,
    /// Table keys requested and not yet arrived → viewpoint.
    table_keys: KeyMap<usize>,
    /// ACH lists that have arrived (from the viewpoints' ACH objects), per viewpoint.
    achs: Vec<Option<Vec<tracks::manifest::SegmentEntry>>>,
    /// ACH object keys requested and not yet arrived → viewpoint.
    ach_keys: KeyMap<usize>,
    /// Parts of items added by a table that were already held under their shared key:
    /// handed out with the next update's arrivals.
    pending: Vec<Arrival>,
    track: usize,
    table: ItemTable,
    infos: Vec<ItemInfo>,
    /// `infos` cut to the level cap (what [`plan`] sees).
    plan_infos: Vec<ItemInfo>,
    level_cap: Option<usize>,
    index: Option<SceneIndex>,
    config: LiveConfig,
    cache: Cache,
    link: LinkEstimate,
    motion: MotionTracker,
    /// Every (item, part) that uses a key (content-addressed keys may be shared).
    users: KeyMap<Vec<(usize, usize)>>,
    /// Keys submitted and not finished.
    requested: KeySet,
    /// Keys pinned in the cache (their bytes: `stats.pinned_bytes`).
    pinned: KeySet,
    /// What `pinned` was made from: per item the parts pinned (sorted by item), and whether
    /// the cache held every one of them. The same list again leaves the pins as they are.
    pin_spec: (Vec<(usize, usize)>, bool),
    /// The CPU visibility counts of the last update and what they were counted for (camera,
    /// viewpoints and weights); cleared when the index changes.
    cpu_counts: Option<CpuCounts>,
    /// Parts held per item (the prefix in the cache), kept by arrivals and evictions; equal
    /// to [`LiveSession::have`], which scans every part.
    held: Vec<usize>,
    start: Instant,
    paused_until: Option<Instant>,
    recent: VecDeque<(Instant, u64)>,
    /// Requests already fed to the link estimate (recent ids).
    timed: VecDeque<u64>,
    /// Object faults per key (seconds since `start`), and the time without progress.
    failures: FailureBook,
    progress: ProgressClock,
    stats: LiveStats,
}

impl LiveSession {
    /// Connect to `url` (`http://host:port[/prefix]`), read the manifest and pick `track` (by
    /// name; the first when `None`).
    pub fn connect(
        url: &str,
        track: Option<&str>,
        config: LiveConfig,
    ) -> Result<LiveSession, LiveError> {
        let url = ServerUrl::parse(url)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("railview-stream")
            .enable_all()
            .build()
            .map_err(LiveError::Runtime)?;
        let conn_stats = std::sync::Arc::new(super::http::ClientStats::default());
        let mut conn = Connection::new(
            url.clone(),
            config.fetcher.retry.clone(),
            conn_stats.clone(),
        );
        let t0 = Instant::now();
        let top = runtime.block_on(conn.fetch_manifest())?.top;
        let manifest = assemble(&top, &[]);
        let manifest_s = t0.elapsed().as_secs_f64();
        let manifest_bytes = conn_stats.bytes.load(Ordering::Relaxed);
        let names = || {
            manifest
                .tracks
                .iter()
                .map(|t| t.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let track = match track {
            Some(name) => manifest
                .tracks
                .iter()
                .position(|t| t.name == name)
                .ok_or_else(|| LiveError::NoTrack(name.to_string(), names()))?,
            None if manifest.tracks.is_empty() => {
                return Err(LiveError::NoTrack("(any)".into(), names()))
            }
            None => 0,
        };
        let mut table = ItemTable::empty(&manifest, track)?;
        table.set_share_parts(config.share_parts);
        let infos = table.infos();
        let index = SceneIndex::new(&manifest, track);
        let mut users: KeyMap<Vec<(usize, usize)>> = KeyMap::default();
        for (i, it) in table.items.iter().enumerate() {
            for (p, part) in it.parts.iter().enumerate() {
                users.entry(part.key.clone()).or_default().push((i, p));
            }
        }
        let n_vp = top.tracks[track].viewpoints.len();
        let n_items = table.items.len();
        let fetcher = {
            let _guard = runtime.enter();
            Fetcher::new(url, config.fetcher.clone())
        };
        let mut cache = Cache::new(config.cache_bytes);
        cache.record_evictions();
        let link = LinkEstimate::new(config.prior_bps, config.prior_latency_s);
        let stats = LiveStats {
            cache_budget: config.cache_bytes,
            manifest_bytes,
            manifest_s,
            ..Default::default()
        };
        Ok(LiveSession {
            fetcher,
            _runtime: runtime,
            manifest,
            top,
            tables: vec![None; n_vp],
            table_keys: KeyMap::default(),
            achs: vec![None; n_vp],
            ach_keys: KeyMap::default(),
            pending: Vec::new(),
            track,
            table,
            plan_infos: infos.clone(),
            infos,
            level_cap: None,
            index,
            cache,
            link,
            motion: MotionTracker::new(),
            users,
            requested: KeySet::default(),
            pinned: KeySet::default(),
            pin_spec: (Vec::new(), true),
            cpu_counts: None,
            held: vec![0; n_items],
            start: Instant::now(),
            paused_until: None,
            recent: VecDeque::new(),
            timed: VecDeque::new(),
            failures: FailureBook::new(config.failures),
            progress: ProgressClock::default(),
            config,
            stats,
        })
    }

    /// The manifest as far as the tables go: viewpoints whose table has not arrived have no
    /// tiles yet (their tiles cannot be requested); it grows as tables arrive.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The top manifest the session started from.
    pub fn top(&self) -> &TopManifest {
        &self.top
    }

    /// `(tables arrived, viewpoints)` of the session's track.
    pub fn tables_loaded(&self) -> (usize, usize) {
        (
            self.tables.iter().filter(|t| t.is_some()).count(),
            self.tables.len(),
        )
    }

    /// Whether viewpoint `vp`'s table has arrived (position in the track).
    pub fn has_table(&self, vp: usize) -> bool {
        self.tables.get(vp).is_some_and(|t| t.is_some())
    }

    /// Position of the session's track in the manifest.
    pub fn track(&self) -> usize {
        self.track
    }

    pub fn table(&self) -> &ItemTable {
        &self.table
    }

    pub fn cache(&self) -> &Cache {
        &self.cache
    }

    pub fn config(&self) -> &LiveConfig {
        &self.config
    }

    pub fn stats(&self) -> &LiveStats {
        &self.stats
    }

    pub fn set_mode(&mut self, mode: PriorityMode) {
        self.config.mode = mode;
    }

    pub fn set_prefetch(&mut self, on: bool) {
        self.config.prefetch = on;
    }

    /// Download at most the first `groups` PTM level groups of every item (`None`: all), e.g.
    /// a preview that holds only the coarsest levels; running downloads beyond the cap are
    /// cancelled at the next update.
    pub fn set_level_cap(&mut self, groups: Option<usize>) {
        self.level_cap = groups.map(|g| g.max(1));
        self.refresh_plan_infos();
    }

    fn refresh_plan_infos(&mut self) {
        self.plan_infos = self
            .infos
            .iter()
            .map(|info| match self.level_cap {
                Some(g) => {
                    let parts = (info.first_level_part + g).min(info.parts());
                    ItemInfo {
                        part_bytes: info.part_bytes[..parts].to_vec(),
                        part_mem: info.part_mem[..parts].to_vec(),
                        first_level_part: info.first_level_part,
                        levels: info.levels[..parts - info.first_level_part.min(parts)].to_vec(),
                    }
                }
                None => info.clone(),
            })
            .collect();
    }

    pub fn level_cap(&self) -> Option<usize> {
        self.level_cap
    }

    /// Cached bytes of one part, if held.
    pub fn part_bytes(&self, item: usize, part: usize) -> Option<&Bytes> {
        let key = &self.table.items.get(item)?.parts.get(part)?.key;
        self.cache.get(key)
    }

    /// Parts held per item, as the session keeps them from frame to frame.
    pub fn held(&self) -> &[usize] {
        &self.held
    }

    /// Parts held per item (the prefix present in the cache), by looking every part up.
    pub fn have(&self) -> Vec<usize> {
        self.table
            .items
            .iter()
            .map(|it| {
                it.parts
                    .iter()
                    .take_while(|p| self.cache.contains(&p.key))
                    .count()
            })
            .collect()
    }

    /// One frame: take finished downloads, plan, request, cancel; returns what arrived.
    /// `live` are visible-pixel counts measured by the caller (e.g. the GPU feedback pass);
    /// they are merged with the CPU estimate (larger count, finer level per item).
    pub fn update(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> Vec<Arrival> {
        let now = Instant::now();
        let t = now.duration_since(self.start).as_secs_f64();
        let s = if s.is_finite() { s } else { 0.0 };
        self.motion.observe(t, s);
        self.cache.set_position(s);
        let mut arrivals = self.take_finished(now);
        arrivals.append(&mut self.pending);

        let have = self.held.clone();
        let mut downloading = vec![false; self.table.items.len()];
        for k in &self.requested {
            for &(i, _) in self.users.get(k).map_or(&[][..], |v| v.as_slice()) {
                downloading[i] = true;
            }
        }
        let seg = segment_at(&self.table.vp_s, s).unwrap_or(0);
        let seg_ach: Vec<(usize, f64)> =
            self.table.segment_ach.get(seg).cloned().unwrap_or_default();
        let backgrounds = self.segment_backgrounds(s);
        let mode = self.config.mode;
        let mut ach: Vec<(usize, f64)> = match (mode, &self.index) {
            (PriorityMode::Combined { .. }, _) | (_, None) => seg_ach.clone(),
            (_, Some(index)) => seg_ach
                .iter()
                .copied()
                .filter(|&(i, _)| {
                    let it = &self.table.items[i];
                    it.tile
                        .is_none_or(|tile| index.tile_in_frustum(camera, it.viewpoint, tile))
                })
                .collect(),
        };
        // Backgrounds are not in the ACH lists; they fill everything no tile covers, so they
        // rank with the strongest tile.
        let top = ach.iter().map(|a| a.1).fold(0.0f64, f64::max);
        let top = if top > 0.0 { top } else { 1.0 };
        ach.extend(backgrounds.iter().map(|&b| (b, top)));
        let all_counts = self.live_counts(s, camera, live);
        self.stats.visible_fraction = visible_fraction(&all_counts, &have, &self.infos);
        let counts = if matches!(mode, PriorityMode::Ach) {
            Vec::new()
        } else {
            all_counts
        };
        let next = if self.config.prefetch {
            next_segment(
                &self.motion,
                &self.table.vp_s,
                s,
                self.config.prefetch_horizon_s,
            )
        } else {
            None
        };
        let prefetch: &[(usize, f64)] = next
            .and_then(|k| self.table.segment_ach.get(k))
            .map_or(&[], |v| v.as_slice());
        let (memory, dt_max) = self.config.budget.current(self.motion.still_s());
        let p = plan(&PlanInput {
            items: &self.plan_infos,
            have: &have,
            downloading: &downloading,
            ach: &ach,
            live: &counts,
            prefetch,
            mode,
            memory_bytes: memory,
            dt_max_s: dt_max,
            link: &self.link,
        });

        // Pins: what the plan keeps resident, and the current segment's coarsest levels. A key
        // is pinned once however many items use it, and only the keys that join or leave the
        // set touch the cache (the set holds tens of thousands of parts on big databases);
        // while the list of pinned parts stays the same (most frames), the set is not rebuilt.
        let mut pin: Vec<(usize, usize)> = p.targets.iter().map(|&(i, _, r)| (i, r)).collect();
        pin.extend(
            seg_ach
                .iter()
                .map(|a| a.0)
                .chain(backgrounds.iter().copied())
                .map(|i| (i, self.infos[i].min_parts())),
        );
        // Per item the most parts pinned; held parts only (the prefix the cache holds).
        let mut spec: Vec<(usize, usize)> = pin
            .into_iter()
            .map(|(i, n)| (i, n.min(have[i])))
            .filter(|&(_, n)| n > 0)
            .collect();
        spec.sort_unstable_by_key(|&(i, n)| (i, std::cmp::Reverse(n)));
        spec.dedup_by_key(|a| a.0);
        if spec != self.pin_spec.0 || !self.pin_spec.1 {
            let mut pins = KeySet::default();
            for &(i, n) in &spec {
                for part in &self.table.items[i].parts[..n] {
                    pins.insert(part.key.clone());
                }
            }
            for k in self.pinned.iter().filter(|k| !pins.contains(*k)) {
                self.stats.pinned_bytes -= self.cache.get(k).map_or(0, |b| b.len() as u64);
                self.cache.release(k);
            }
            let cache = &mut self.cache;
            let (mut added, mut complete) = (0, true);
            pins.retain(|k| {
                if self.pinned.contains(k) {
                    return true;
                }
                let held = cache.acquire(k);
                if held {
                    added += cache.get(k).map_or(0, |b| b.len() as u64);
                }
                complete &= held;
                held
            });
            self.stats.pinned_bytes += added;
            self.pinned = pins;
            self.pin_spec = (spec, complete);
        }

        // Requests the plan still wants: running/queued parts of items below their target,
        // plus the new ones.
        let mut keep = KeySet::default();
        for &(i, target, _) in &p.targets {
            for part in self.table.items[i].parts.iter().take(target).skip(have[i]) {
                if self.requested.contains(&part.key) {
                    keep.insert(part.key.clone());
                }
            }
        }
        let paused = self.paused_until.is_some_and(|u| now < u);
        let tables = self.request_tables(s, t);
        keep.extend(tables.iter().map(|(r, _)| r.key.clone()));
        if !paused {
            // Every missing table again: a queued one takes its new priority (a background
            // table becomes urgent as the walker nears it).
            for (r, _) in &tables {
                self.requested.insert(r.key.clone());
            }
            let mut submit: Vec<(FetchRequest, Option<u64>)> = tables;
            for r in &p.requests {
                let parts = &self.table.items[r.item].parts;
                let end = (r.part + r.parts.max(1)).min(parts.len());
                for (j, part) in parts[r.part..end].iter().enumerate() {
                    // A part that failed waits for its retry time (or was given up): the
                    // parts after it are of no use without it.
                    if !self.failures.may_request(&part.key, t) {
                        break;
                    }
                    keep.insert(part.key.clone());
                    if self.cache.contains(&part.key) || self.requested.contains(&part.key) {
                        continue;
                    }
                    // Bytes the cache would refuse (pinned data leaves no room) are not
                    // downloaded at all.
                    if self.stats.pinned_bytes.saturating_add(part.bytes) > self.cache.budget() {
                        continue;
                    }
                    self.requested.insert(part.key.clone());
                    submit.push((
                        FetchRequest {
                            key: part.key.clone(),
                            expected_hash: part.hash.clone(),
                            // Parts of one run in order.
                            priority: r.priority - j as f64 * 1e-6,
                        },
                        // Known sizes let whole objects (meshes) travel in bundles too.
                        Some(part.bytes),
                    ));
                }
            }
            // All at once, so the workers see the frame's requests together and bundle them.
            self.fetcher.set_bundle_max_bytes(self.bundle_bytes());
            self.fetcher.submit_all(submit);
        } else {
            // Nothing new while the server is failing; keep what is queued for the plan.
            for r in &p.requests {
                let parts = &self.table.items[r.item].parts;
                let end = (r.part + r.parts.max(1)).min(parts.len());
                for part in &parts[r.part..end] {
                    if self.requested.contains(&part.key) {
                        keep.insert(part.key.clone());
                    }
                }
            }
        }
        if self.requested.iter().any(|k| !keep.contains(k)) {
            self.fetcher.retain(|k| keep.contains(k));
            self.requested.retain(|k| keep.contains(k));
        }
        self.update_stats(now, t, s, &have, &seg_ach, &backgrounds);
        arrivals
    }

    /// Bytes one bundle may carry: what one latency carries at the estimated bandwidth (a
    /// bundle then costs about two latencies), at least the configured floor, at most 4 MiB.
    fn bundle_bytes(&self) -> u64 {
        let (bps, latency) = self.link.get();
        let bdp = bps / 8.0 * latency;
        let floor = self.config.fetcher.bundle_max_bytes.max(1);
        if bdp.is_finite() && bdp > 0.0 {
            (bdp as u64).clamp(floor, (4 << 20).max(floor))
        } else {
            floor
        }
    }

    /// The background tiles of the two viewpoints around `s`.
    fn segment_backgrounds(&self, s: f64) -> Vec<usize> {
        blend_weights(&self.table.vp_s, s)
            .iter()
            .flat_map(|&(vi, _)| self.table.background_items(vi))
            .collect()
    }

    /// CPU visibility counts at `camera` (counted again only when the camera or the blend
    /// weights changed), merged with the caller's counts per item.
    fn live_counts(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> Vec<LiveCount> {
        let mut by_item: HashMap<usize, LiveCount> = HashMap::new();
        if let Some(index) = &self.index {
            let weights = blend_weights(&self.table.vp_s, s);
            let same = self
                .cpu_counts
                .as_ref()
                .is_some_and(|c| c.camera == *camera && c.weights == weights);
            if !same {
                let (sx, sy) = self.config.samples;
                let counts = index
                    .count(camera, &weights, sx, sy)
                    .into_iter()
                    .filter_map(|c| {
                        let item = match c.surface {
                            Surface::Tile { viewpoint, tile } => {
                                self.table.tile_item(viewpoint, tile)
                            }
                            Surface::Background { viewpoint, tile } => {
                                self.table.background_item(viewpoint, tile)
                            }
                        }?;
                        Some(LiveCount {
                            item,
                            pixels: c.pixels(),
                            needed_level: c.finest_needed(),
                        })
                    })
                    .collect();
                self.cpu_counts = Some(CpuCounts {
                    camera: *camera,
                    weights,
                    counts,
                });
            }
            for c in self.cpu_counts.iter().flat_map(|c| &c.counts) {
                by_item.insert(c.item, *c);
            }
        }
        // The caller's counts (measured on the GPU) and the CPU estimate are merged by the
        // larger count and the finer need: a tile the caller drew from a coarse level may
        // show fewer pixels than it will (a coarse opacity mask), one the CPU march missed
        // may show more.
        for c in live.unwrap_or(&[]) {
            if c.item >= self.table.items.len() || !c.pixels.is_finite() {
                continue;
            }
            by_item
                .entry(c.item)
                .and_modify(|e| {
                    e.pixels = e.pixels.max(c.pixels);
                    e.needed_level = e.needed_level.min(c.needed_level);
                })
                .or_insert(*c);
        }
        let mut out: Vec<LiveCount> = by_item.into_values().filter(|c| c.pixels > 0.0).collect();
        out.sort_by_key(|c| c.item);
        out
    }

    /// Finished downloads: link estimate, cache, arrivals, failures.
    fn take_finished(&mut self, now: Instant) -> Vec<Arrival> {
        let mut out = Vec::new();
        let mut stored_keys = Vec::new();
        let mut tables_changed = false;
        let t = now.duration_since(self.start).as_secs_f64();
        let waiting = self.fetcher.pending() > 0 || !self.requested.is_empty();
        let mut arrived = false;
        while let Some(done) = self.fetcher.try_next() {
            self.requested.remove(&done.key);
            self.stats.retries += done.transfer.retries as u64;
            self.stats.timeouts += done.transfer.timeouts as u64;
            self.stats.outage_s += done.transfer.outage_s;
            match done.result {
                Ok(data) => {
                    arrived = true;
                    self.failures.succeeded(&done.key);
                    let len = data.len() as u64;
                    // One sample per HTTP request (a bundle's keys share theirs).
                    if !self.timed.contains(&done.request.id) {
                        self.link.observe(done.request.bytes, done.elapsed_s);
                        if self.timed.len() == 64 {
                            self.timed.pop_front();
                        }
                        self.timed.push_back(done.request.id);
                    }
                    self.stats.bytes += len;
                    self.stats.parts += 1;
                    self.stats.last_error = None;
                    self.recent.push_back((now, len));
                    if let Some(vi) = self.table_keys.remove(&done.key) {
                        tables_changed |= self.table_arrived(vi, &data);
                        continue;
                    }
                    if let Some(vi) = self.ach_keys.remove(&done.key) {
                        tables_changed |= self.ach_arrived(vi, &data);
                        continue;
                    }
                    let users = self.users.get(&done.key).cloned().unwrap_or_default();
                    let fresh = !self.cache.contains(&done.key);
                    let mut stored = !fresh;
                    for &(item, _) in &users {
                        let s_item = self.table.items[item].s;
                        stored |= self
                            .cache
                            .insert(done.key.clone(), data.clone(), s_item)
                            .is_ok();
                    }
                    if fresh && stored {
                        stored_keys.push(done.key.clone());
                        out.extend(users.iter().map(|&(item, part)| Arrival {
                            item,
                            part,
                            data: data.clone(),
                        }));
                    }
                }
                Err(ClientError::Cancelled) => {}
                Err(e) if e.is_object_fault() => {
                    // This object alone: asked for again later, given up after a few.
                    self.table_keys.remove(&done.key);
                    self.ach_keys.remove(&done.key);
                    if self.failures.fault(&done.key, t) == Verdict::GivenUp {
                        tracing::warn!("giving up {}: {e}", done.key.object);
                    }
                    self.stats.last_error = Some(e.to_string());
                }
                Err(e) => {
                    self.table_keys.remove(&done.key);
                    self.ach_keys.remove(&done.key);
                    self.stats.failed_requests += 1;
                    self.stats.last_error = Some(e.to_string());
                    self.paused_until = Some(now + self.config.error_pause);
                }
            }
        }
        self.progress.observe(t, waiting, arrived);
        self.stats.part_faults = self.failures.faults();
        self.stats.parts_given_up = self.failures.given_up();
        if tables_changed {
            self.tables_changed();
        }
        self.stats.cache_peak = self.stats.cache_peak.max(self.cache.used());
        self.update_held(&stored_keys);
        out
    }

    /// Keeps `held` true after parts were stored (`stored`) and others evicted to make room.
    /// Evictions first cut the items that used them, then stored parts extend the items they
    /// continue, each by what the cache holds now.
    fn update_held(&mut self, stored: &[FetchKey]) {
        for k in self.cache.take_evicted() {
            for &(item, part) in self.users.get(&k).map_or(&[][..], |v| v.as_slice()) {
                self.held[item] = self.held[item].min(part);
            }
        }
        for k in stored {
            for &(item, part) in self.users.get(k).map_or(&[][..], |v| v.as_slice()) {
                if self.held[item] == part {
                    self.held[item] = held_from(&self.table.items[item].parts, part, &self.cache);
                }
            }
        }
    }

    /// Extends item `i`'s held prefix by the parts the cache holds.
    pub(super) fn extend_held(&mut self, i: usize) {
        self.held[i] = held_from(&self.table.items[i].parts, self.held[i], &self.cache);
    }

    fn update_stats(
        &mut self,
        now: Instant,
        t: f64,
        s: f64,
        have: &[usize],
        seg_ach: &[(usize, f64)],
        backgrounds: &[usize],
    ) {
        let window = Duration::from_secs(2);
        while self
            .recent
            .front()
            .is_some_and(|(when, _)| now.duration_since(*when) > window)
        {
            self.recent.pop_front();
        }
        let span = t.min(window.as_secs_f64()).max(0.25);
        let pending = self.fetcher.pending();
        let running = self.fetcher.running();
        let fs = self.fetcher.stats();
        let quality = if seg_ach.is_empty() {
            0.0
        } else {
            seg_ach
                .iter()
                .map(|&(i, _)| {
                    let info = &self.infos[i];
                    let groups = info.levels.len().max(1) as f64;
                    have[i].saturating_sub(info.first_level_part) as f64 / groups
                })
                .sum::<f64>()
                / seg_ach.len() as f64
        };
        // A viewpoint of the segment whose table has not arrived counts as one item not
        // showable (its tiles are not even known yet).
        let tables_missing = blend_weights(&self.table.vp_s, s)
            .iter()
            .filter(|w| !self.table.has_viewpoint(w.0))
            .count();
        let showable: Vec<bool> = seg_ach
            .iter()
            .map(|a| a.0)
            .chain(backgrounds.iter().copied())
            .map(|i| have[i] >= self.infos[i].min_parts())
            .chain(std::iter::repeat_n(false, tables_missing))
            .collect();
        let coarse = if showable.is_empty() {
            1.0
        } else {
            showable.iter().filter(|&&b| b).count() as f64 / showable.len() as f64
        };
        // Waiting from here on when requests are outstanding after this update.
        self.progress.observe(
            t,
            self.fetcher.pending() > 0 || !self.requested.is_empty(),
            false,
        );
        self.stats = LiveStats {
            t_s: t,
            stalled_s: self.progress.current_s(t),
            longest_stall_s: self.progress.longest_s(),
            bytes_per_s: self.recent.iter().map(|r| r.1).sum::<u64>() as f64 / span,
            in_flight: running,
            queued: pending.saturating_sub(running),
            cache_used: self.cache.used(),
            cache_budget: self.cache.budget(),
            cache_peak: self.stats.cache_peak.max(self.cache.used()),
            quality,
            coarse_fraction: coarse,
            checksum_failures: fs.checksum_failures.load(Ordering::Relaxed),
            reconnects: fs.reconnects.load(Ordering::Relaxed),
            requests: fs.requests.load(Ordering::Relaxed),
            link: self.link.get(),
            ..std::mem::take(&mut self.stats)
        };
    }
}

/// End of the prefix of `parts` the cache holds, looking from part `from` on (the parts
/// before it are held).
fn held_from(parts: &[Part], from: usize, cache: &Cache) -> usize {
    from + parts[from.min(parts.len())..]
        .iter()
        .take_while(|p| cache.contains(&p.key))
        .count()
}

/// Fraction of the counted pixels whose item holds at least its coarsest level. With no
/// pixel counted, 0: the tables of the viewpoints around are not known yet, so nothing can
/// be shown (every pixel counts for some item once they are: backgrounds fill what no tile
/// covers).
fn visible_fraction(counts: &[LiveCount], have: &[usize], infos: &[ItemInfo]) -> f64 {
    let total: f64 = counts.iter().map(|c| c.pixels).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let shown: f64 = counts
        .iter()
        .filter(|c| have.get(c.item).copied().unwrap_or(0) >= infos[c.item].min_parts())
        .map(|c| c.pixels)
        .sum();
    shown / total
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info() -> ItemInfo {
        ItemInfo {
            part_bytes: vec![100, 200, 400],
            part_mem: vec![0, 300, 1200],
            first_level_part: 1,
            levels: vec![1, 0],
        }
    }

    #[test]
    fn nothing_counted_is_nothing_shown() {
        // Before the first tables arrive there are no counts: not "everything shown".
        assert_eq!(visible_fraction(&[], &[], &[info()]), 0.0);
        let zero = LiveCount {
            item: 0,
            pixels: 0.0,
            needed_level: 0,
        };
        assert_eq!(visible_fraction(&[zero], &[3], &[info()]), 0.0);
    }

    #[test]
    fn the_fraction_weighs_items_by_their_pixels_and_needs_the_coarsest_level() {
        let counts = [
            LiveCount {
                item: 0,
                pixels: 30.0,
                needed_level: 0,
            },
            LiveCount {
                item: 1,
                pixels: 10.0,
                needed_level: 0,
            },
        ];
        let infos = [info(), info()];
        // Mesh and coarsest level held (2 parts) against the mesh alone.
        assert_eq!(visible_fraction(&counts, &[2, 1], &infos), 0.75);
        assert_eq!(visible_fraction(&counts, &[3, 2], &infos), 1.0);
        assert_eq!(visible_fraction(&counts, &[0, 0], &infos), 0.0);
    }
}
