//! The request policy of the streaming client, without I/O: one [`Scheduler`] that the
//! viewer's [`super::LiveSession`] drives on the wall clock and the walk simulator on a
//! virtual clock and link, so a walk's numbers are the viewer's.
//!
//! Inputs: the top manifest (at [`Scheduler::new`]); per tick ([`Scheduler::tick`]) the time,
//! the position along the track, the camera, optional live visible-pixel counts (the GPU's;
//! the scheduler's own CPU estimate of the same pass, [`crate::visibility`], is merged with
//! them) and the keys on the wire; finished downloads as they are taken
//! ([`Scheduler::arrive`]: checked bytes or an error, with the request that carried them, which
//! feeds the link estimate). Outputs ([`Actions`]): the requests it wants, in priority order
//! ([`Want`]s, which replace what has not gone out yet, with the [`DispatchLimits`] under which
//! a [`Dispatcher`] sends them), the running downloads it no longer wants (cancels), and pins:
//! what the plan keeps resident and the current segment's coarsest levels are held in its
//! [`Cache`] against eviction. It keeps the checked bytes (the cache), the tables that
//! arrived, the item table they grow, and hands out what arrived per item and part
//! ([`Scheduler::take_arrivals`]).
//!
//! The policy: the two tables of the segment around the walker before any tile (with prefetch,
//! the predicted next segment's once nothing in view is missing; the viewpoint after the
//! segment once the walker would reach it before its table arrives), other tables one at a
//! time nearest first while the view has no holes; tiles by the PTM budget rules
//! ([`super::plan`]) in the strategy's priority mode — the segment's ACH cut to the view
//! frustum, live counts, or both — and, with prefetch, the tiles covering most of the view
//! predicted at the middle of the next segment, looking the same way, within the frustum
//! widened by a turn of the head ([`SchedulerConfig::prefetch_turn_deg`]). Requests carry about
//! one latency's worth of bytes at the estimated bandwidth, about two latencies' worth stay
//! on the link, prefetch takes at most a third of the request slots and none while the view
//! has holes. `naive` streams every tile whole in manifest order instead.
//!
//! A part or table whose object is damaged or missing is a fault of that object alone
//! ([`FailureBook`], on the driver's clock): it is asked for again after a wait and given
//! up after repeated faults, while everything else streams on. Only a server that cannot be
//! reached pauses new requests.

use std::collections::{HashMap, VecDeque};

use bytes::Bytes;
use tracks::manifest::{Manifest, SegmentEntry};
use tracks::PerspectiveCamera;

use super::budget::{BudgetParams, ItemInfo, LinkEstimate, LiveCount};
use super::cache::Cache;
use super::failures::{FailureBook, Verdict};
use super::http::{ClientError, FetchKey, KeyMap, KeySet};
use super::items::{ItemTable, Part};
use super::pool::Completion;
use super::predict::MotionTracker;
use crate::visibility::{SceneIndex, Surface, SurfaceCount};
use db::split::{assemble, TopManifest, ViewTable};

mod config;
mod dispatch;
mod network;
mod prefetch;
mod tables;
mod tick;
mod view;

pub use config::{SchedulerConfig, Strategy};
pub use dispatch::{Batch, DispatchLimits, Dispatcher, Piece, Want, WantClass};

/// One part of an item that arrived (checked against the manifest's hash).
#[derive(Clone, Debug)]
pub struct Arrival {
    pub item: usize,
    /// Part index within the item (mesh first when it has one, then PTM groups coarse→fine).
    pub part: usize,
    pub data: Bytes,
}

/// What a tick decided.
#[derive(Clone, Debug, Default)]
pub struct Actions {
    /// The requests wanted, in priority order (they replace what has not gone out yet).
    pub wants: Vec<Want>,
    pub limits: DispatchLimits,
    /// Keys on the wire that are no longer wanted.
    pub cancel: Vec<FetchKey>,
}

/// Figures of the latest tick, for a UI and the walk's report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewStats {
    /// Progressive downloading quality: mean over the current segment's ACH tiles of the
    /// fraction of level groups held.
    pub quality: f64,
    /// Fraction of the current segment's items showable (mesh and coarsest level held).
    pub coarse_fraction: f64,
    /// Fraction of the visible pixels (live counts) whose tile or background is showable.
    pub visible_fraction: f64,
    /// Bytes pinned (resident parts and the current segment's coarsest levels).
    pub pinned_bytes: u64,
    /// Largest texture memory the plan held resident, and whether it ever exceeded the
    /// budget in force.
    pub max_resident_bytes: u64,
    pub over_budget: bool,
    /// `M` in force (configured, or scaled to what is known).
    pub memory_budget_bytes: u64,
    /// Downloads that failed (cancellations not counted), and the latest error.
    pub failed: u64,
    pub last_error: Option<String>,
    /// Faults of parts whose object is damaged or missing (each asked for again later), and
    /// parts given up after repeated faults; the same for viewpoint tables and ACH objects.
    pub part_faults: u64,
    pub parts_given_up: u64,
    pub table_faults: u64,
    pub tables_given_up: u64,
}

/// The CPU visibility counts of one camera and pair of blend weights, per item.
struct CpuCounts {
    camera: PerspectiveCamera,
    weights: Vec<(usize, f64)>,
    counts: Vec<LiveCount>,
}

/// A merged prefetch list, what it was computed for (the segments with their likelihoods in
/// thousandths, yaw and pitch in 10° steps) and the level each item is needed at.
type PrefetchMemo = (
    (Vec<(usize, i64)>, i64, i64),
    Vec<(usize, f64)>,
    HashMap<usize, u32>,
);

/// Shortest distances along the network from the two ends of a segment: (segment, from its
/// `from` end, from its `to` end).
type DistMemo = (usize, Vec<f64>, Vec<f64>);

/// The request policy (see the module docs).
pub struct Scheduler {
    config: SchedulerConfig,
    top: TopManifest,
    /// The track the walker is on.
    track: usize,
    /// The graph of tracks (curves, viewpoints, junctions).
    net: tracks::network::Network,
    /// The branch the user chose for the next junction.
    chosen: Option<tracks::network::Branch>,
    dist_memo: Option<DistMemo>,
    /// The manifest as far as the tables go.
    manifest: Manifest,
    /// Tables that have arrived, per viewpoint (by id).
    tables: Vec<Option<ViewTable>>,
    /// ACH lists that have arrived, per viewpoint.
    achs: Vec<Option<Vec<SegmentEntry>>>,
    /// Table and ACH object keys → viewpoint.
    table_keys: KeyMap<usize>,
    ach_keys: KeyMap<usize>,
    table: ItemTable,
    infos: Vec<ItemInfo>,
    /// `infos` cut to the level cap (what [`plan`] sees).
    plan_infos: Vec<ItemInfo>,
    level_cap: Option<usize>,
    /// Finest PTM level fetched (`None`: level 0).
    finest_level: Option<u32>,
    index: Option<SceneIndex>,
    cache: Cache,
    link: LinkEstimate,
    /// Requests already fed to the link estimate (recent ids).
    timed: VecDeque<u64>,
    motion: MotionTracker,
    /// Every (item, part) that uses a key.
    users: KeyMap<Vec<(usize, usize)>>,
    /// Parts held per item (the prefix in the cache), kept by arrivals and evictions.
    held: Vec<usize>,
    pinned: KeySet,
    /// What `pinned` was made from, and whether the cache held all of it.
    pin_spec: (Vec<(usize, usize)>, bool),
    cpu_counts: Option<CpuCounts>,
    prefetch_memo: Option<PrefetchMemo>,
    /// Per prefetched item, the level the predicted view needs it at.
    prefetch_need: HashMap<usize, u32>,
    arrivals: Vec<Arrival>,
    /// Keys cancelled while on the wire: their bytes are dropped when they come.
    cancelled: KeySet,
    paused_until: Option<f64>,
    /// Budgets in force.
    budget: BudgetParams,
    /// Whether the server answers `/bundle` (as far as seen).
    bundles: bool,
    /// Viewpoints whose table or ACH lists arrived since the manifest and index were updated.
    changed: Vec<usize>,
    /// Where each viewpoint stops on the tracks (`db::split::stops_by_viewpoint`).
    stops: Vec<Vec<(usize, usize)>>,
    /// Live counts of the latest tick (CPU estimate merged with the caller's).
    live: Vec<LiveCount>,
    /// Object faults of parts, and of tables and ACH objects (driver's clock).
    failures: FailureBook,
    table_failures: FailureBook,
    /// Time of the latest tick or arrival.
    now: f64,
    stats: ViewStats,
}

impl Scheduler {
    /// A scheduler for `top`'s network, the walker starting on track `track` (no table yet:
    /// they come as requests).
    pub fn new(
        top: TopManifest,
        track: usize,
        config: SchedulerConfig,
    ) -> Result<Scheduler, ClientError> {
        let manifest = assemble(&top, &[]);
        if track >= top.tracks.len() {
            return Err(ClientError::Manifest(format!("no track {track}")));
        }
        let net = top
            .network()
            .map_err(|e| ClientError::Manifest(format!("the graph of tracks: {e}")))?;
        let naive = config.strategy == Strategy::Naive;
        let mut table = ItemTable::empty(&manifest)?;
        table.set_share_parts(config.share_parts && !naive);
        let infos = table.infos();
        let mut users: KeyMap<Vec<(usize, usize)>> = KeyMap::default();
        for (i, it) in table.items.iter().enumerate() {
            for (p, part) in it.parts.iter().enumerate() {
                users.entry(part.key.clone()).or_default().push((i, p));
            }
        }
        let n_vp = top.viewpoints.len();
        let mut table_keys = KeyMap::default();
        let mut ach_keys = KeyMap::default();
        for v in &top.viewpoints {
            table_keys.insert(whole(&v.table.hash), v.index);
            if let Some(a) = &v.ach {
                ach_keys.insert(whole(&a.hash), v.index);
            }
        }
        let mut cache = Cache::new(if naive { u64::MAX } else { config.cache_bytes });
        cache.record_evictions();
        let index = SceneIndex::new(&manifest);
        let stops = db::split::stops_by_viewpoint(&top);
        let held = vec![0; table.items.len()];
        let link = LinkEstimate::new(config.prior_bps, config.prior_latency_s);
        let config_failures = config.failures;
        Ok(Scheduler {
            budget: config.budget,
            config,
            top,
            track,
            net,
            chosen: None,
            dist_memo: None,
            manifest,
            stops,
            tables: vec![None; n_vp],
            achs: vec![None; n_vp],
            table_keys,
            ach_keys,
            plan_infos: infos.clone(),
            infos,
            table,
            level_cap: None,
            finest_level: None,
            index,
            cache,
            link,
            timed: VecDeque::new(),
            motion: MotionTracker::new(),
            users,
            held,
            pinned: KeySet::default(),
            pin_spec: (Vec::new(), true),
            cpu_counts: None,
            prefetch_memo: None,
            prefetch_need: HashMap::new(),
            arrivals: Vec::new(),
            cancelled: KeySet::default(),
            paused_until: None,
            bundles: true,
            changed: Vec::new(),
            live: Vec::new(),
            failures: FailureBook::new(config_failures),
            table_failures: FailureBook::new(config_failures),
            now: 0.0,
            stats: ViewStats::default(),
        })
    }

    pub fn config(&self) -> &SchedulerConfig {
        &self.config
    }

    pub fn top(&self) -> &TopManifest {
        &self.top
    }

    /// Position of the track the walker is on in the manifest.
    pub fn track(&self) -> usize {
        self.track
    }

    /// The manifest as far as the tables go (it grows as they arrive).
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    pub fn table(&self) -> &ItemTable {
        &self.table
    }

    pub fn cache(&self) -> &Cache {
        &self.cache
    }

    pub fn link(&self) -> &LinkEstimate {
        &self.link
    }

    pub fn stats(&self) -> &ViewStats {
        &self.stats
    }

    /// The live counts of the latest tick, per item.
    pub fn live_counts(&self) -> &[LiveCount] {
        &self.live
    }

    /// Parts held per item, as the scheduler keeps them from tick to tick.
    pub fn held(&self) -> &[usize] {
        &self.held
    }

    /// `(tables arrived, viewpoints)` of the network.
    pub fn tables_loaded(&self) -> (usize, usize) {
        (
            self.tables.iter().filter(|t| t.is_some()).count(),
            self.tables.len(),
        )
    }

    /// Whether viewpoint `vp`'s table has arrived (by id).
    pub fn has_table(&self, vp: usize) -> bool {
        self.tables.get(vp).is_some_and(|t| t.is_some())
    }

    pub fn set_strategy(&mut self, strategy: Strategy) {
        self.config.strategy = strategy;
        self.prefetch_memo = None;
    }

    /// Download at most the first `groups` PTM level groups of every item (`None`: all);
    /// downloads beyond the cap on the wire are cancelled at the next tick.
    pub fn set_level_cap(&mut self, groups: Option<usize>) {
        self.level_cap = groups.map(|g| g.max(1));
        self.refresh_plan_infos();
    }

    pub fn level_cap(&self) -> Option<usize> {
        self.level_cap
    }

    /// Fetch no PTM level finer than `level` (`None`: every level): a viewer that lays its
    /// views out at a reduced resolution to stay within its memory needs no finer one.
    pub fn set_finest_level(&mut self, level: Option<u32>) {
        self.finest_level = level.filter(|&l| l > 0);
        self.refresh_plan_infos();
    }

    pub fn finest_level(&self) -> u32 {
        self.finest_level.unwrap_or(0)
    }

    /// Cached bytes of one part, if held.
    pub fn part_bytes(&self, item: usize, part: usize) -> Option<&Bytes> {
        let key = &self.table.items.get(item)?.parts.get(part)?.key;
        self.cache.get(key)
    }

    /// Parts that arrived since the last call (every item that uses a part gets it).
    pub fn take_arrivals(&mut self) -> Vec<Arrival> {
        std::mem::take(&mut self.arrivals)
    }

    fn refresh_plan_infos(&mut self) {
        self.plan_infos = self
            .infos
            .iter()
            .map(|info| {
                let mut parts = info.parts();
                if let Some(g) = self.level_cap {
                    parts = parts.min(info.first_level_part + g);
                }
                if let Some(l) = self.finest_level {
                    parts = parts.min(info.parts_for_level(l));
                }
                if parts == info.parts() {
                    return info.clone();
                }
                ItemInfo {
                    part_bytes: info.part_bytes[..parts].to_vec(),
                    part_mem: info.part_mem[..parts].to_vec(),
                    first_level_part: info.first_level_part,
                    levels: info.levels[..parts - info.first_level_part.min(parts)].to_vec(),
                }
            })
            .collect();
    }

    /// A finished download: the link estimate (once per request), tables, the cache,
    /// arrivals. Feed the downloads of a tick in request order (`request`), as both
    /// drivers do.
    pub fn arrive(&mut self, now: f64, done: Completion) {
        self.now = self.now.max(now);
        match done.result {
            Ok(data) => {
                self.failures.succeeded(&done.key);
                self.table_failures.succeeded(&done.key);
                if done.request != 0 && !self.timed.contains(&done.request) {
                    self.link.observe(done.request_bytes, done.elapsed_s);
                    if self.timed.len() == 64 {
                        self.timed.pop_front();
                    }
                    self.timed.push_back(done.request);
                }
                if self.cancelled.remove(&done.key) {
                    return;
                }
                if let Some(&vi) = self.table_keys.get(&done.key) {
                    if self.tables[vi].is_none() && self.table_arrived(vi, &data) {
                        self.changed.push(vi);
                    }
                    return;
                }
                if let Some(&vi) = self.ach_keys.get(&done.key) {
                    if self.achs[vi].is_none() && self.ach_arrived(vi, &data) {
                        self.changed.push(vi);
                    }
                    return;
                }
                let users = self.users.get(&done.key).cloned().unwrap_or_default();
                let fresh = !self.cache.contains(&done.key);
                let mut stored = !fresh;
                for &(item, _) in &users {
                    let vp = self.table.items[item].viewpoint;
                    stored |= self
                        .cache
                        .insert(done.key.clone(), data.clone(), vp)
                        .is_ok();
                }
                if fresh && stored {
                    self.arrivals
                        .extend(users.iter().map(|&(item, part)| Arrival {
                            item,
                            part,
                            data: data.clone(),
                        }));
                }
                self.update_held(if fresh && stored {
                    Some(&done.key)
                } else {
                    None
                });
            }
            Err(ClientError::Cancelled) => {
                self.cancelled.remove(&done.key);
            }
            Err(e) if e.is_object_fault() => {
                // This object alone: asked for again later, given up after a few faults.
                self.cancelled.remove(&done.key);
                let table = self.table_keys.contains_key(&done.key)
                    || self.ach_keys.contains_key(&done.key);
                let book = if table {
                    &mut self.table_failures
                } else {
                    &mut self.failures
                };
                if book.fault(&done.key, now) == Verdict::GivenUp {
                    tracing::warn!("giving up {}: {e}", done.key.object);
                }
                self.stats.last_error = Some(e.to_string());
                self.fault_stats();
            }
            Err(e) => {
                self.cancelled.remove(&done.key);
                self.stats.failed += 1;
                self.stats.last_error = Some(e.to_string());
                self.paused_until = Some(now + self.config.error_pause_s.max(0.0));
            }
        }
    }

    /// The fault counters of [`ViewStats`] from the failure books.
    fn fault_stats(&mut self) {
        self.stats.part_faults = self.failures.faults();
        self.stats.parts_given_up = self.failures.given_up();
        self.stats.table_faults = self.table_failures.faults();
        self.stats.tables_given_up = self.table_failures.given_up();
    }

    /// Whether part `key` may be asked for now (none of its faults waits for its retry
    /// time, and it was not given up).
    fn part_ready(&self, key: &FetchKey) -> bool {
        self.failures.may_request(key, self.now)
    }

    /// Every (item, part) that uses `key`.
    pub fn users(&self, key: &FetchKey) -> &[(usize, usize)] {
        self.users.get(key).map_or(&[], |v| v.as_slice())
    }

    /// Whether the server answers `/bundle` (false once a request found it does not): one
    /// object per request then.
    pub fn set_bundles(&mut self, on: bool) {
        self.bundles = on;
    }

    /// Keeps `held` true after `stored` was stored and others were evicted to make room.
    fn update_held(&mut self, stored: Option<&FetchKey>) {
        for k in self.cache.take_evicted() {
            for &(item, part) in self.users.get(&k).map_or(&[][..], |v| v.as_slice()) {
                self.held[item] = self.held[item].min(part);
            }
        }
        if let Some(k) = stored {
            for &(item, part) in self.users.get(k).map_or(&[][..], |v| v.as_slice()) {
                if self.held[item] == part {
                    self.held[item] = held_from(&self.table.items[item].parts, part, &self.cache);
                }
            }
        }
    }
}

/// A whole object as a key.
fn whole(hash: &str) -> FetchKey {
    FetchKey {
        object: hash.into(),
        range: None,
    }
}

/// A whole object of `size` bytes as a piece.
fn whole_piece(hash: &str, size: u64) -> Piece {
    Piece {
        key: whole(hash),
        hash: hash.to_string(),
        len: size,
    }
}

/// The client's item shown by a surface of the visibility pass (`None`: not known yet).
pub fn surface_item(table: &ItemTable, c: &SurfaceCount) -> Option<usize> {
    match c.surface {
        Surface::Tile { viewpoint, tile } => table.tile_item(viewpoint, tile),
        Surface::Background { viewpoint, tile } => table.background_item(viewpoint, tile),
    }
}

/// End of the prefix of `parts` the cache holds, looking from part `from` on.
fn held_from(parts: &[Part], from: usize, cache: &Cache) -> usize {
    from + parts[from.min(parts.len())..]
        .iter()
        .take_while(|p| cache.contains(&p.key))
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strategies_parse_and_name() {
        for s in [
            "naive",
            "ach",
            "visibility+prefetch",
            "ach+visibility+prefetch",
        ] {
            assert_eq!(Strategy::parse(s).unwrap().name(), s);
        }
        assert!(Strategy::parse("fast").is_err());
        assert!(Strategy::parse("prefetch").is_err());
    }
}
