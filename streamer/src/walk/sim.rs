//! One simulated run: virtual clock, event-driven downloads, per-frame metrics.

use std::sync::atomic::Ordering;

use bytes::Bytes;
use tracks::PerspectiveCamera;

use super::{
    look_at, FrameRecord, ManifestCost, RunReport, Scene, Strategy, VirtualLink, WalkConfig,
    WalkError,
};
use crate::client::{
    next_segment, plan, segment_at, BudgetParams, BundlePiece, Cache, ClientError, ClientStats,
    Connection, FailureBook, FetchKey, ItemInfo, ItemTable, LinkEstimate, LiveCount, MotionTracker,
    Part, PlanInput, PriorityMode, ProgressClock, TransferReport, Verdict,
};
use crate::db::split::ViewTable;
use crate::visibility::{blend_weights, frustum_half_angle, Surface, SurfaceCount};

mod tables;

/// Items and the parts of each one bundled request carries.
type Bundle = Vec<(usize, Vec<Part>)>;

/// A prefetch list and what it was computed for: (segment, yaw and pitch in 10° steps).
type PrefetchMemo = ((usize, i64, i64), Vec<(usize, f64)>);

struct InFlight {
    /// Carries only prefetched items.
    prefetch: bool,
    /// Viewpoint tables it carries (position in the track, decoded table).
    tables: Vec<(usize, ViewTable)>,
    /// A background table request (low priority: one at a time).
    background_table: bool,
    items: Vec<usize>,
    /// Checked pieces with the arc length of the item each belongs to.
    keys: Vec<(FetchKey, Bytes, f64)>,
    issued: f64,
    arrives: f64,
    bytes: u64,
}

struct Sim<'a> {
    scene: &'a Scene,
    cfg: &'a WalkConfig,
    strategy: Strategy,
    /// What the client knows: backgrounds from the top manifest, tiles as their viewpoints'
    /// tables arrive (item numbers are this table's).
    table: ItemTable,
    /// Per viewpoint: its table requested (in flight or arrived).
    table_requested: Vec<bool>,
    /// Bytes and requests spent on tables.
    table_bytes: u64,
    table_requests: u64,
    /// Bytes arrived so far, and of them tables.
    delivered_bytes: u64,
    delivered_table_bytes: u64,
    items: Vec<ItemInfo>,
    cache: Cache,
    /// [`Sim::have`] of the last call, with the cache's change count and the item count
    /// it was looked up at.
    have_memo: Option<((u64, usize), Vec<usize>)>,
    link: VirtualLink,
    estimate: LinkEstimate,
    motion: MotionTracker,
    in_flight: Vec<InFlight>,
    downloading: Vec<bool>,
    /// Naive: items not yet requested, in manifest order (by viewpoint, its tiles, then its
    /// background), rebuilt when tables add items.
    naive_order: Vec<usize>,
    naive_requested: Vec<bool>,
    pinned: Vec<FetchKey>,
    bytes: u64,
    /// Of `bytes`, the viewpoints' backgrounds.
    background_bytes: u64,
    requests: u64,
    /// Largest texture memory the plan held resident, and whether it ever exceeded `M`.
    max_resident: u64,
    over_budget: bool,
    /// Live counts of the latest frame (used again between frames).
    live: Vec<LiveCount>,
    /// The current segment's ACH list after frustum culling at the latest frame's camera
    /// (PTM §6.1: only tiles that can be in view share the budget).
    view_ach: Vec<(usize, f64)>,
    /// The same list within the frustum widened by `prefetch_turn_deg` (the combined mode's
    /// broadening: coarsest levels ready for a turn of the head).
    wide_ach: Vec<(usize, f64)>,
    /// The latest prefetch list and what it was computed for (segment, yaw and pitch in
    /// 10° steps): recomputed only when those change.
    prefetch_memo: Option<PrefetchMemo>,
    /// Per prefetched item, the level the predicted view needs it at (live-count prefetch
    /// asks for no finer level).
    prefetch_need: std::collections::HashMap<usize, u32>,
    /// The latest frame's camera (prefetch looks the same way from further on).
    cam: Option<PerspectiveCamera>,
    /// Budgets in force (the configured ones, or scaled to the database).
    budget: BudgetParams,
    s: f64,
    /// Object faults of parts and of viewpoint tables (virtual clock): retried later, then
    /// given up; the walk goes on without them.
    failures: FailureBook,
    table_failures: FailureBook,
    /// Time without progress on the virtual clock.
    progress: ProgressClock,
    /// Retries the real transfers took, and the longest outage one request met (wall clock).
    transfer: TransferReport,
    longest_outage_s: f64,
}

impl Sim<'_> {
    fn table(&self) -> &ItemTable {
        &self.table
    }

    /// What the last real fetch cost in retries: an outage (wall-clock time its requests
    /// spent failing) holds the virtual link for as long, from `t` on, so requests issued
    /// during it arrive after it, as they would on a real link.
    fn note_transfer(&mut self, conn: &mut Connection, t: f64) {
        let r = conn.take_report();
        if r.outage_s > 0.0 {
            self.link.outage(t, r.outage_s);
            self.longest_outage_s = self.longest_outage_s.max(r.outage_s);
        }
        self.transfer.add(&r);
    }

    /// Deliver everything that has arrived by `t`.
    fn deliver(&mut self, t: f64) {
        let waiting = !self.in_flight.is_empty();
        let (arrived, pending): (Vec<_>, Vec<_>) = std::mem::take(&mut self.in_flight)
            .into_iter()
            .partition(|f| f.arrives <= t + 1e-9);
        self.in_flight = pending;
        self.progress.observe(t, waiting, !arrived.is_empty());
        if self.in_flight.is_empty() {
            self.progress.observe(t, false, false);
        }
        for f in arrived {
            self.delivered_bytes += f.bytes;
            if !f.tables.is_empty() {
                self.delivered_table_bytes += f.bytes;
            }
            for (vi, vt) in f.tables {
                // Checked and decoded when fetched; the positions agree with the scene's.
                if let Ok(range) =
                    self.table
                        .add_viewpoint(vi, &vt.background, &vt.tiles, &vt.segments)
                {
                    for i in range {
                        self.items.push(self.table.items[i].info.clone());
                    }
                    self.downloading.resize(self.items.len(), false);
                }
            }
            for &i in &f.items {
                self.downloading[i] = false;
            }
            self.estimate.observe(f.bytes, f.arrives - f.issued);
            for (key, data, s_item) in f.keys {
                // Refused when the budget is full of data in use: dropped, asked again later.
                let _ = self.cache.insert(key, data, s_item);
            }
        }
    }

    /// Parts held per item (a prefix; naive: all or nothing), looked up again only when the
    /// cache or the items changed since the last call.
    fn have(&mut self) -> Vec<usize> {
        let stamp = (self.cache.changes(), self.table.items.len());
        if let Some((at, have)) = &self.have_memo {
            if *at == stamp {
                return have.clone();
            }
        }
        let naive = self.strategy == Strategy::Naive;
        let have: Vec<usize> = self
            .table()
            .items
            .iter()
            .map(|it| {
                if naive {
                    if it.parts.iter().all(|p| self.cache.contains(&p.key)) {
                        it.parts.len()
                    } else {
                        0
                    }
                } else {
                    it.parts
                        .iter()
                        .take_while(|p| self.cache.contains(&p.key))
                        .count()
                }
            })
            .collect();
        self.have_memo = Some((stamp, have.clone()));
        have
    }

    /// What to prefetch for the next segment `next`: what can be in view on arrival, seen
    /// from the middle of that segment (where both its viewpoints are blended), looking the
    /// way the camera looks now, within the frustum widened by the turn the walker may make
    /// meanwhile (`prefetch_turn_deg` left and right, half of it up and down). With live counts (visibility, combined) it
    /// is the visibility pass at that predicted camera, weighted by visible pixels; with ACH
    /// alone it is the segment's ACH list cut to the widened cone. Not the whole ACH list:
    /// tiles behind the walker cost bytes and are rarely shown.
    fn prefetch_list(&mut self, next: usize, mode: PriorityMode) -> Vec<(usize, f64)> {
        let Some(cam) = self.cam else {
            return Vec::new();
        };
        let memo_key = (
            next,
            (cam.yaw_deg / 10.0).round() as i64,
            (cam.pitch_deg / 10.0).round() as i64,
        );
        if let Some((k, list)) = &self.prefetch_memo {
            if *k == memo_key {
                return list.clone();
            }
        }
        let scene = self.scene;
        let table = &self.table;
        let lo = table.vp_s.get(next).copied().unwrap_or(0.0);
        let hi = table.vp_s.get(next + 1).copied().unwrap_or(lo);
        let s_mid = 0.5 * (lo + hi);
        let turn = self.cfg.prefetch_turn_deg.max(0.0);
        let list: Vec<(usize, f64)> = if matches!(mode, PriorityMode::Ach) {
            let half = (frustum_half_angle(&cam) + turn.to_radians()).min(std::f64::consts::PI);
            let position = scene.track.position_at(s_mid);
            table
                .segment_ach
                .get(next)
                .map_or(&[][..], |v| v.as_slice())
                .iter()
                .copied()
                .filter(|&(i, _)| {
                    let it = &table.items[i];
                    it.tile.is_none_or(|tile| {
                        scene
                            .index
                            .tile_in_cone(position, cam.forward(), half, it.viewpoint, tile)
                    })
                })
                .collect()
        } else {
            // Widened by `turn` left and right and by half of it up and down (a walker turns
            // the head sideways more than up or down).
            let tan_v = (cam.fov_deg.to_radians() * 0.5).tan() * cam.height.max(1) as f64
                / cam.width.max(1) as f64;
            let v_half = (tan_v.atan() + 0.5 * turn.to_radians()).min(1.3);
            let fov_deg = (cam.fov_deg + 2.0 * turn).min(150.0);
            let h_tan = (fov_deg.to_radians() * 0.5).tan();
            let ahead = PerspectiveCamera {
                position: scene.track.position_at(s_mid),
                fov_deg,
                height: ((cam.width as f64 * v_half.tan() / h_tan).round() as u32).max(1),
                ..cam
            };
            let weights = blend_weights(&table.vp_s, s_mid);
            let counts =
                scene
                    .index
                    .count(&ahead, &weights, self.cfg.samples_x, self.cfg.samples_y);
            let mut seen: Vec<(usize, f64)> = counts
                .iter()
                .filter_map(|c| Some((surface_item(table, c)?, c.pixels())))
                .filter(|&(_, px)| px > 0.0)
                .collect();
            // The level each tile is needed at in the predicted view: prefetch stops there.
            let mut need = std::collections::HashMap::new();
            for c in &counts {
                if let Some(i) = surface_item(table, c) {
                    let l = c.finest_needed();
                    need.entry(i)
                        .and_modify(|x: &mut u32| *x = (*x).min(l))
                        .or_insert(l);
                }
            }
            self.prefetch_need = need;
            // The tiles that cover most of the predicted view (`prefetch_coverage` of its
            // pixels), largest first: slivers at the edge are rarely worth their bytes ahead
            // of time, and are fetched anyway if they come into view.
            seen.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            let total: f64 = seen.iter().map(|x| x.1).sum();
            let mut acc = 0.0;
            let keep = seen
                .iter()
                .take_while(|x| {
                    let before = acc;
                    acc += x.1;
                    before < self.cfg.prefetch_coverage * total
                })
                .count();
            seen.truncate(keep);
            seen
        };
        self.prefetch_memo = Some((memo_key, list.clone()));
        list
    }

    /// Decide and issue downloads at time `t` (fetching the bytes for real). Each free
    /// request slot takes one bundle: the next requests in priority order, up to
    /// `bundle_entries` pieces and about one latency's worth of bytes — so a bundle costs one
    /// round trip plus a short transfer, and high priorities still arrive first.
    async fn issue(&mut self, conn: &mut Connection, t: f64) -> Result<(), WalkError> {
        let free = self
            .cfg
            .max_in_flight
            .max(1)
            .saturating_sub(self.in_flight.len());
        let mut free = free - self.issue_urgent_tables(conn, t, free).await?;
        // Naive streams the database in manifest order: the next viewpoint's table goes
        // beside the tiles (one at a time), so tiles never run out.
        if self.strategy == Strategy::Naive
            && free > 0
            && self.issue_background_table(conn, t).await?
        {
            free -= 1;
        }
        if free == 0 {
            return Ok(());
        }
        let n = self.items.len();
        // Wanted downloads in priority order: (item, parts).
        let mut wanted: Vec<(usize, Vec<Part>)> = Vec::new();
        // Entries from here on are prefetches (the plan ranks them after every current one).
        let mut first_prefetch = usize::MAX;
        // Whether something in view cannot be shown yet (then nothing is prefetched).
        let mut holes = false;
        let max_pieces = self.cfg.bundle_entries.max(1);
        match self.strategy {
            Strategy::Naive => {
                if self.naive_requested.len() != n {
                    self.naive_requested.resize(n, false);
                    let items = &self.table.items;
                    let mut order: Vec<usize> =
                        (0..n).filter(|&i| !self.naive_requested[i]).collect();
                    order.sort_by_key(|&i| (items[i].viewpoint, items[i].tile.is_none(), i));
                    order.reverse();
                    self.naive_order = order;
                }
                let mut k = self.naive_order.len();
                while k > 0 && wanted.len() < free * max_pieces {
                    k -= 1;
                    let i = self.naive_order[k];
                    let it = &self.table.items[i];
                    // A tile with a part that failed waits for its retry time.
                    if !it
                        .parts
                        .iter()
                        .all(|p| self.failures.may_request(&p.key, t))
                    {
                        continue;
                    }
                    // The whole tile: its mesh and every level range (contiguous in the
                    // viewpoint's pack, so they travel together).
                    wanted.push((i, it.parts.clone()));
                }
            }
            Strategy::Budget { mode, prefetch } => {
                let have = self.have();
                holes = self
                    .live
                    .iter()
                    .any(|c| have[c.item] < self.items[c.item].min_parts());
                let table = &self.table;
                let next = if prefetch {
                    next_segment(
                        &self.motion,
                        &table.vp_s,
                        self.s,
                        self.cfg.prefetch_horizon_s,
                    )
                } else {
                    None
                };
                let pre = match next {
                    None => Vec::new(),
                    Some(k) => self.prefetch_list(k, mode),
                };
                let table = &self.table;
                // Parts on their way (shared keys: another tile's request may carry them).
                let mut on_way: std::collections::HashSet<&FetchKey> = self
                    .in_flight
                    .iter()
                    .flat_map(|f| f.keys.iter().map(|k| &k.0))
                    .collect();
                let ach: &[(usize, f64)] = match mode {
                    // Combined: the segment's ACH within the widened frustum broadens
                    // (coarsest levels for a turn of the head); live counts pick what is in
                    // view.
                    PriorityMode::Combined { .. } => &self.wide_ach,
                    _ => &self.view_ach,
                };
                let (memory, dt_max) = self.budget.current(self.motion.still_s());
                let p = plan(&PlanInput {
                    items: &self.items,
                    have: &have,
                    downloading: &self.downloading,
                    ach,
                    live: &self.live,
                    prefetch: &pre,
                    mode,
                    memory_bytes: memory,
                    dt_max_s: dt_max,
                    link: &self.estimate,
                });
                self.max_resident = self.max_resident.max(p.resident_bytes);
                self.over_budget |= p.resident_bytes > memory;
                // Resident parts are in use: pin them until the next decision.
                for k in self.pinned.drain(..) {
                    self.cache.release(&k);
                }
                for &(i, _, resident) in &p.targets {
                    for part in &table.items[i].parts[..resident] {
                        if self.cache.acquire(&part.key) {
                            self.pinned.push(part.key.clone());
                        }
                    }
                }
                for r in &p.requests {
                    if r.priority < 1.0 && first_prefetch == usize::MAX {
                        first_prefetch = wanted.len();
                    }
                    let parts = &table.items[r.item].parts;
                    let mut end = (r.part + r.parts.max(1)).min(parts.len());
                    if r.priority < 1.0 {
                        if let Some(&l) = self.prefetch_need.get(&r.item) {
                            end = end.min(self.items[r.item].parts_for_level(l));
                        }
                    }
                    // Up to the first part that failed and waits (or was given up): the
                    // parts after it are of no use without it.
                    let failures = &self.failures;
                    let todo: Vec<Part> = parts[r.part..end.max(r.part)]
                        .iter()
                        .take_while(|p| failures.may_request(&p.key, t))
                        .filter(|p| on_way.insert(&p.key))
                        .cloned()
                        .collect();
                    if !todo.is_empty() {
                        wanted.push((r.item, todo));
                    }
                }
            }
        }
        // Bytes one bundle may carry: about one latency's worth of the estimated link (at
        // least 16 KiB), so its transfer costs no more than its round trip.
        let (bps, latency) = self.estimate.get();
        let byte_cap = ((bps / 8.0 * latency.max(0.05)) as u64).max(16 << 10);
        // Prefetch-only bundles hold at most a third of the slots, are small, and none go
        // while the view has holes, so what the current view needs never queues behind a
        // link full of prefetch.
        let prefetch_slots = if holes {
            0
        } else {
            (self.cfg.max_in_flight / 3).max(1)
        };
        let mut prefetch_busy = self.in_flight.iter().filter(|f| f.prefetch).count();
        let mut bundles: Vec<(bool, Bundle)> = Vec::new();
        let mut taken = 0usize;
        let mut wanted = wanted.into_iter().peekable();
        // Bytes on their way: the budget strategies keep about two latencies' worth on the
        // link (enough to fill it), so a tile that comes into view next waits behind little.
        let mut queued: u64 = self.in_flight.iter().map(|f| f.bytes).sum();
        let queue_cap = match self.strategy {
            Strategy::Naive => u64::MAX,
            Strategy::Budget { .. } => 2 * byte_cap,
        };
        while bundles.len() < free {
            let only_prefetch = taken >= first_prefetch;
            if only_prefetch && prefetch_busy >= prefetch_slots {
                break;
            }
            if queued >= queue_cap {
                break;
            }
            let mut b: Bundle = Vec::new();
            let (mut pieces, mut bytes) = (0usize, 0u64);
            while let Some((_, parts)) = wanted.peek() {
                let p_bytes: u64 = parts.iter().map(|p| p.bytes).sum();
                // Prefetch-only bundles are a quarter of the size: a tile that comes into
                // view waits behind at most a short one on the link.
                let cap = if only_prefetch {
                    byte_cap / 4
                } else {
                    byte_cap
                };
                let fits = pieces + parts.len() <= max_pieces && bytes + p_bytes <= cap;
                if !b.is_empty() && !fits {
                    break;
                }
                pieces += parts.len();
                bytes += p_bytes;
                taken += 1;
                b.extend(wanted.next());
            }
            if b.is_empty() {
                break;
            }
            prefetch_busy += usize::from(only_prefetch);
            queued += bytes;
            bundles.push((only_prefetch, b));
        }
        for (only_prefetch, b) in bundles {
            if self.strategy == Strategy::Naive {
                for (i, _) in &b {
                    self.naive_requested[*i] = true;
                }
                let done = &self.naive_requested;
                self.naive_order.retain(|&i| !done[i]);
            }
            let flat: Vec<&Part> = b.iter().flat_map(|(_, parts)| parts.iter()).collect();
            let pieces: Vec<BundlePiece> = flat
                .iter()
                .map(|p| BundlePiece {
                    key: &p.key,
                    len: p.bytes,
                    hash: &p.hash,
                })
                .collect();
            let data = conn.fetch_pieces(&pieces, None).await;
            self.note_transfer(conn, t);
            // A server that stopped answering ends the run (its measures so far are kept).
            if let Some(e) = first_unreachable(&data) {
                return Err(WalkError::Unreachable(e));
            }
            // One request per bundle; a static host answers one object (or range run) per
            // request (re-fetches after a checksum failure are not counted: they cost real
            // time, not virtual time, so a corrupting server changes no frame).
            let requests = if conn.bundles_supported() {
                1
            } else {
                request_runs(&flat)
            };
            self.requests += requests;
            let size: u64 = data
                .iter()
                .filter_map(|d| d.as_ref().ok())
                .map(|d| d.len() as u64)
                .sum();
            let mut data = data.into_iter();
            let mut items = Vec::with_capacity(b.len());
            let mut keys = Vec::with_capacity(flat.len());
            for (item, parts) in &b {
                self.downloading[*item] = true;
                items.push(*item);
                let s_item = self.table.items[*item].s;
                let background = self.table.items[*item].tile.is_none();
                let mut failed = false;
                for part in parts {
                    match data.next() {
                        Some(Ok(d)) => {
                            if background {
                                self.background_bytes += d.len() as u64;
                            }
                            self.failures.succeeded(&part.key);
                            keys.push((part.key.clone(), d, s_item));
                        }
                        Some(Err(e)) => {
                            failed = true;
                            match self.failures.fault(&part.key, t) {
                                Verdict::GivenUp => tracing::warn!(
                                    "walk: giving up {:?} of {}: {e}",
                                    part.key.range,
                                    part.key.object
                                ),
                                Verdict::RetryAt(_) => tracing::info!("walk: {e}"),
                            }
                        }
                        None => {}
                    }
                }
                // Naive asks for a failed tile again (whole) once its parts may be retried.
                if failed && self.strategy == Strategy::Naive {
                    let failures = &self.failures;
                    if !parts.iter().any(|p| failures.is_given_up(&p.key)) {
                        self.naive_requested[*item] = false;
                        self.naive_order.insert(0, *item);
                    }
                }
            }
            self.bytes += size;
            self.in_flight.push(InFlight {
                prefetch: only_prefetch,
                tables: Vec::new(),
                background_table: false,
                items,
                keys,
                issued: t,
                arrives: self.link.schedule_requests(t, size, requests),
                bytes: size,
            });
        }
        // The other viewpoints' tables, nearest first, one at a time and only while the view
        // has no holes and the tables around the walker are in: when the walk reaches them
        // they are there, and they never delay a frame.
        let around = blend_weights(&self.table.vp_s, self.s)
            .iter()
            .all(|w| self.table.has_viewpoint(w.0));
        if !holes && around {
            self.issue_background_table(conn, t).await?;
        }
        self.progress.observe(t, !self.in_flight.is_empty(), false);
        Ok(())
    }
}

/// The first error in `results` that is the server's (unreachable), not one object's.
pub(super) fn first_unreachable(results: &[Result<Bytes, ClientError>]) -> Option<ClientError> {
    results
        .iter()
        .filter_map(|r| r.as_ref().err())
        .find(|e| !e.is_object_fault() && !matches!(e, ClientError::Cancelled))
        .cloned()
}

/// Requests needed for `parts` one object at a time: consecutive ranges of one object
/// travel together.
fn request_runs(parts: &[&Part]) -> u64 {
    let mut n = 0;
    for (i, p) in parts.iter().enumerate() {
        let joins = i > 0
            && match (parts[i - 1].key.range, p.key.range) {
                (Some((o, l)), Some((o2, _))) => {
                    parts[i - 1].key.object == p.key.object && o + l == o2
                }
                _ => false,
            };
        if !joins {
            n += 1;
        }
    }
    n
}

/// Run one (strategy, bandwidth) walk.
pub(crate) async fn run_one(
    conn: &mut Connection,
    stats: &ClientStats,
    scene: &Scene,
    cfg: &WalkConfig,
    (strategy, bandwidth): (Strategy, Option<u64>),
    manifest: ManifestCost,
    on_frame: &mut dyn FnMut(u64),
) -> (RunReport, Option<WalkError>) {
    let wall = std::time::Instant::now();
    // The manifest comes first, alone on the link from t = 0; the walk (and every tile
    // request) starts when it has arrived, `t0` later.
    let t0 = VirtualLink::new(bandwidth, cfg.latency_s).schedule_requests(
        0.0,
        manifest.bytes,
        manifest.round_trips.max(1),
    );
    let mut table = scene.empty.clone();
    // Naive streams every tile whole, repeats included; the budget strategies fetch a
    // payload once however many tiles share it (`ItemTable::set_share_parts`).
    table.set_share_parts(strategy != Strategy::Naive);
    let items = table.infos();
    let n = items.len();
    let naive = strategy == Strategy::Naive;
    let mut sim = Sim {
        scene,
        cfg,
        strategy,
        table,
        table_requested: vec![false; scene.tables.len()],
        table_bytes: 0,
        background_bytes: 0,
        table_requests: 0,
        delivered_bytes: 0,
        delivered_table_bytes: 0,
        items,
        cache: Cache::new(if naive { u64::MAX } else { cfg.cache_bytes }),
        have_memo: None,
        link: VirtualLink::new(bandwidth, cfg.latency_s),
        estimate: LinkEstimate::new(bandwidth.map_or(1e9, |b| b as f64), cfg.latency_s),
        motion: MotionTracker::new(),
        in_flight: Vec::new(),
        downloading: vec![false; n],
        naive_order: Vec::new(),
        naive_requested: Vec::new(),
        pinned: Vec::new(),
        bytes: 0,
        requests: 0,
        max_resident: 0,
        over_budget: false,
        live: Vec::new(),
        view_ach: Vec::new(),
        wide_ach: Vec::new(),
        prefetch_memo: None,
        prefetch_need: std::collections::HashMap::new(),
        cam: None,
        budget: if cfg.scale_budget {
            cfg.budget
                .scaled_to(&scene.table.infos(), &scene.table.segment_ach)
        } else {
            cfg.budget
        },
        s: 0.0,
        failures: FailureBook::new(cfg.failures),
        table_failures: FailureBook::new(cfg.failures),
        progress: ProgressClock::default(),
        transfer: TransferReport::default(),
        longest_outage_s: 0.0,
    };
    let failures_before = stats.checksum_failures.load(Ordering::Relaxed);
    let mut error = None;
    let length = scene.track.length();
    let walk_s = if cfg.speed_mps > 0.0 {
        length / cfg.speed_mps
    } else {
        0.0
    };
    let end_t = walk_s + cfg.pause_s.max(0.0);
    let dt = cfg.frame_dt_s.max(1e-3);
    let mut frames = Vec::new();
    let mut max_cache = 0u64;
    let mut first_frame = None;
    let mut first_frame_bytes = None;
    let mut k = 0u64;
    loop {
        let t = k as f64 * dt;
        if t > end_t + 1e-9 {
            break;
        }
        let s = (t * cfg.speed_mps).min(length);
        sim.s = s;
        sim.motion.observe(t, s);
        sim.cache.set_position(s);
        sim.deliver(t);
        // What the frame needs: the CPU visibility pass at the scripted camera.
        let tan = scene.track.tangent_at(s);
        let heading = tan.x.atan2(-tan.z).to_degrees();
        let (yaw, pitch) = look_at(heading, t);
        let cam = PerspectiveCamera {
            position: scene.track.position_at(s),
            yaw_deg: yaw,
            pitch_deg: pitch,
            fov_deg: cfg.fov_deg,
            width: cfg.screen_width,
            height: cfg.screen_height,
        };
        sim.cam = Some(cam);
        let weights = blend_weights(&scene.table.vp_s, s);
        let counts = scene
            .index
            .count(&cam, &weights, cfg.samples_x, cfg.samples_y);
        sim.live = counts
            .iter()
            .filter_map(|c| {
                Some(LiveCount {
                    item: surface_item(&sim.table, c)?,
                    pixels: c.pixels(),
                    needed_level: c.finest_needed(),
                })
            })
            .collect();
        let have = sim.have();
        let seg = segment_at(&scene.table.vp_s, s).unwrap_or(0);
        let ach: &[(usize, f64)] = sim.table.segment_ach.get(seg).map_or(&[], |v| v.as_slice());
        let half = frustum_half_angle(&cam);
        let wide = (half + cfg.prefetch_turn_deg.max(0.0).to_radians()).min(std::f64::consts::PI);
        let in_cone = |i: usize, h: f64| {
            let it = &sim.table.items[i];
            it.tile.is_none_or(|tile| {
                scene
                    .index
                    .tile_in_cone(cam.position, cam.forward(), h, it.viewpoint, tile)
            })
        };
        sim.view_ach = ach
            .iter()
            .copied()
            .filter(|&(i, _)| in_cone(i, half))
            .collect();
        sim.wide_ach = ach
            .iter()
            .copied()
            .filter(|&(i, _)| in_cone(i, wide))
            .collect();
        // Backgrounds are not in the ACH lists; they fill everything no tile covers, so they
        // rank with the strongest tile (as `LiveSession` ranks them).
        let top = ach.iter().map(|a| a.1).fold(0.0f64, f64::max);
        let top = if top > 0.0 { top } else { 1.0 };
        let backgrounds: Vec<(usize, f64)> = weights
            .iter()
            .flat_map(|&(vi, _)| sim.table.background_items(vi))
            .map(|b| (b, top))
            .collect();
        sim.view_ach.extend(&backgrounds);
        sim.wide_ach.extend(&backgrounds);
        // The paper's quality is measured against the segment's ACH list as the database
        // has it, whether or not the strategy fetched the lists: the client's item of each
        // entry's tile (`None` while its table is missing).
        let truth: Vec<Option<usize>> = scene
            .table
            .segment_ach
            .get(seg)
            .map_or(&[][..], |v| v.as_slice())
            .iter()
            .map(|&(i, _)| {
                let it = &scene.table.items[i];
                sim.table.tile_item(it.viewpoint, it.tile?)
            })
            .collect();
        let (quality, needed, complete) =
            frame_metrics(&sim.table, &sim.items, &have, &truth, &counts);
        if complete && first_frame.is_none() {
            first_frame = Some(t0 + t);
            first_frame_bytes = Some((
                manifest.bytes + sim.delivered_bytes,
                sim.delivered_table_bytes,
            ));
        }
        if let Err(e) = sim.issue(conn, t).await {
            error = Some(e);
        }
        max_cache = max_cache.max(sim.cache.used());
        on_frame(k);
        frames.push(FrameRecord {
            t_s: t0 + t,
            s_m: s,
            quality,
            needed_fraction: needed,
            complete,
            bytes: sim.bytes,
            cache_bytes: sim.cache.used(),
        });
        if error.is_some() {
            break;
        }
        // Between frames: each arrival frees a slot and triggers the next decision at once.
        let t_next = (k + 1) as f64 * dt;
        while let Some(te) = sim
            .in_flight
            .iter()
            .map(|f| f.arrives)
            .filter(|&a| a < t_next - 1e-9)
            .min_by(f64::total_cmp)
        {
            sim.deliver(te);
            if let Err(e) = sim.issue(conn, te).await {
                error = Some(e);
                break;
            }
            max_cache = max_cache.max(sim.cache.used());
        }
        if error.is_some() {
            break;
        }
        k += 1;
    }
    let mean = |f: &dyn Fn(&FrameRecord) -> f64| {
        frames.iter().map(f).sum::<f64>() / frames.len().max(1) as f64
    };
    let report = RunReport {
        strategy: strategy.name(),
        bandwidth_bps: bandwidth,
        time_to_first_frame_s: first_frame,
        manifest_bytes: manifest.bytes,
        manifest_s: t0,
        table_bytes: sim.table_bytes,
        background_bytes: sim.background_bytes,
        first_frame_bytes: first_frame_bytes.map(|b| b.0),
        first_frame_table_bytes: first_frame_bytes.map(|b| b.1),
        table_requests: sim.table_requests,
        mean_needed_fraction: mean(&|f| f.needed_fraction),
        mean_quality: mean(&|f| f.quality),
        bytes: sim.bytes,
        bytes_per_m: if length > 0.0 {
            sim.bytes as f64 / length
        } else {
            0.0
        },
        requests: sim.requests,
        checksum_failures: stats.checksum_failures.load(Ordering::Relaxed) - failures_before,
        cache_budget_bytes: (!naive).then(|| sim.cache.budget()),
        max_cache_bytes: max_cache,
        max_resident_bytes: sim.max_resident,
        resident_within_budget: !sim.over_budget,
        memory_budget_bytes: sim.budget.memory_bytes,
        wall_s: wall.elapsed().as_secs_f64(),
        retries: sim.transfer.retries as u64,
        timeouts: sim.transfer.timeouts as u64,
        outage_s: sim.transfer.outage_s,
        longest_outage_s: sim.longest_outage_s,
        longest_wait_s: sim.progress.longest_s(),
        part_faults: sim.failures.faults(),
        parts_given_up: sim.failures.given_up(),
        table_faults: sim.table_failures.faults(),
        tables_given_up: sim.table_failures.given_up(),
        completed: error.is_none(),
        error: error.as_ref().map(|e| e.to_string()),
        frames,
    };
    (report, error)
}

fn surface_item(table: &ItemTable, c: &SurfaceCount) -> Option<usize> {
    match c.surface {
        Surface::Tile { viewpoint, tile } => table.tile_item(viewpoint, tile),
        Surface::Background { viewpoint, tile } => table.background_item(viewpoint, tile),
    }
}

/// `(quality, needed fraction, complete)` of one frame; `ach` is the segment's ACH list as
/// the client's items (`None`: not known to the client, nothing held).
fn frame_metrics(
    table: &ItemTable,
    items: &[ItemInfo],
    have: &[usize],
    ach: &[Option<usize>],
    counts: &[SurfaceCount],
) -> (f64, f64, bool) {
    let quality = if ach.is_empty() {
        0.0
    } else {
        ach.iter()
            .map(|&i| {
                let Some(i) = i else { return 0.0 };
                let info = &items[i];
                let groups = info.levels.len().max(1) as f64;
                have[i].saturating_sub(info.first_level_part) as f64 / groups
            })
            .sum::<f64>()
            / ach.len() as f64
    };
    let mut total = 0.0;
    let mut ok = 0.0;
    let mut complete = true;
    for c in counts {
        let px = c.pixels();
        if px <= 0.0 {
            continue;
        }
        let Some(item) = surface_item(table, c) else {
            // A background tile the database does not have is never needed; anything else,
            // and whatever a viewpoint whose table has not arrived shows, is missing.
            let absent = matches!(c.surface,
                Surface::Background { viewpoint, .. } if table.has_viewpoint(viewpoint));
            if !absent {
                total += px;
                complete = false;
            }
            continue;
        };
        total += px;
        let level = items[item].level_with(have[item]);
        if level.is_none() {
            complete = false;
        }
        ok += c.satisfied(level);
    }
    let needed = if total > 0.0 { ok / total } else { 1.0 };
    (quality, needed, complete)
}
