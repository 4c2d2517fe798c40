//! One simulated run: the client's scheduler on a virtual clock and link, per-frame metrics.

use super::{
    walk_frames, FrameRecord, ManifestCost, RunReport, Scene, Strategy, TurnRecord, VirtualLink,
    WalkConfig, WalkError,
};
use crate::client::schedule::surface_item;
use crate::client::{
    Batch, ClientError, Completion, Dispatcher, FetchKey, ItemTable, NetPos, ProgressClock,
    Scheduler, SchedulerConfig, Source, TransferReport, Transport, WantClass,
};
use crate::visibility::{Surface, SurfaceCount};
use bytes::Bytes;
use tracks::PerspectiveCamera;

/// A request on the virtual link.
struct InFlight {
    batch: Batch,
    /// Checked bytes of each piece, or why it failed (an object's fault).
    data: Vec<Result<Bytes, ClientError>>,
    /// HTTP requests and body bytes it took.
    requests: u64,
    wire_bytes: u64,
    issued: f64,
    arrives: f64,
}

/// The executor of one run: the dispatcher's requests, fetched for real, timed on the link.
struct Exec {
    transport: Transport,
    dispatcher: Dispatcher,
    link: VirtualLink,
    in_flight: Vec<InFlight>,
    /// Arrived, not yet handed to the scheduler (it takes them at its next tick).
    arrived: Vec<InFlight>,
    bytes: u64,
    requests: u64,
    table_bytes: u64,
    table_requests: u64,
    background_bytes: u64,
    /// Bytes handed to the scheduler so far, and of them tables.
    delivered_bytes: u64,
    delivered_table_bytes: u64,
    log: Option<Vec<Vec<FetchKey>>>,
    /// Time without progress on the virtual clock.
    progress: ProgressClock,
    /// Retries the real transfers took, and the longest outage one request met (wall clock).
    transfer: TransferReport,
    longest_outage_s: f64,
}

impl Exec {
    /// Send every request the dispatcher gives at time `t`.
    async fn send(&mut self, t: f64, sched: &Scheduler) -> Result<(), WalkError> {
        while let Some(batch) = self.dispatcher.pop() {
            let d = self.transport.fetch_batch(&batch.pieces, None).await;
            // An outage (wall-clock time the requests spent failing) holds the virtual link
            // for as long, from `t` on, so requests issued during it arrive after it, as
            // they would on a real link.
            if d.transfer.outage_s > 0.0 {
                self.link.outage(t, d.transfer.outage_s);
                self.longest_outage_s = self.longest_outage_s.max(d.transfer.outage_s);
            }
            self.transfer.add(&d.transfer);
            // A server that stopped answering ends the run (its measures so far are kept).
            if let Some(e) = d.unreachable() {
                return Err(WalkError::Unreachable(e.clone()));
            }
            let requests = d.requests.max(1);
            self.requests += requests;
            self.bytes += d.wire_bytes;
            if matches!(batch.class, WantClass::Table | WantClass::BackgroundTable) {
                self.table_bytes += d.wire_bytes;
                self.table_requests += requests;
            }
            for (p, b) in batch.pieces.iter().zip(&d.data) {
                let Ok(b) = b else { continue };
                let background = sched
                    .users(&p.key)
                    .iter()
                    .any(|&(i, _)| sched.table().items[i].tile.is_none());
                if background {
                    self.background_bytes += b.len() as u64;
                }
            }
            if let Some(log) = &mut self.log {
                log.push(batch.pieces.iter().map(|p| p.key.clone()).collect());
            }
            let arrives = self.link.schedule_requests(t, d.wire_bytes, requests);
            self.in_flight.push(InFlight {
                batch,
                data: d.data,
                requests,
                wire_bytes: d.wire_bytes,
                issued: t,
                arrives,
            });
        }
        self.progress.observe(t, !self.in_flight.is_empty(), false);
        Ok(())
    }

    /// The requests that have arrived by `t`: their slots are free.
    fn arrive_until(&mut self, t: f64) {
        let (done, pending): (Vec<_>, Vec<_>) = std::mem::take(&mut self.in_flight)
            .into_iter()
            .partition(|f| f.arrives <= t + 1e-9);
        let waiting = !done.is_empty() || !pending.is_empty();
        self.in_flight = pending;
        self.progress.observe(t, waiting, !done.is_empty());
        if self.in_flight.is_empty() {
            self.progress.observe(t, false, false);
        }
        for f in done {
            self.dispatcher.finish(f.batch.id);
            self.arrived.push(f);
        }
    }

    /// Hand what arrived to the scheduler, in request order (as the live session does).
    fn feed(&mut self, t: f64, sched: &mut Scheduler) {
        let mut arrived = std::mem::take(&mut self.arrived);
        arrived.sort_by_key(|f| f.batch.id);
        for f in arrived {
            self.delivered_bytes += f.wire_bytes;
            if matches!(f.batch.class, WantClass::Table | WantClass::BackgroundTable) {
                self.delivered_table_bytes += f.wire_bytes;
            }
            for (p, data) in f.batch.pieces.into_iter().zip(f.data) {
                sched.arrive(
                    t,
                    Completion {
                        key: p.key,
                        result: data,
                        request: f.batch.id,
                        request_bytes: f.wire_bytes,
                        http_requests: f.requests,
                        elapsed_s: f.arrives - f.issued,
                        transfer: TransferReport::default(),
                    },
                );
            }
        }
        // The simulator shows nothing: what arrived is only measured.
        drop(sched.take_arrivals());
    }

    /// The earliest arrival before `t_next`.
    fn next_arrival(&self, t_next: f64) -> Option<f64> {
        self.in_flight
            .iter()
            .map(|f| f.arrives)
            .filter(|&a| a < t_next - 1e-9)
            .min_by(f64::total_cmp)
    }
}

impl Exec {
    fn new(source: &Source, cfg: &WalkConfig, bandwidth: Option<u64>) -> Exec {
        Exec {
            transport: Transport::new(source, cfg.retry.clone()),
            dispatcher: Dispatcher::new(),
            link: VirtualLink::new(bandwidth, cfg.latency_s),
            in_flight: Vec::new(),
            arrived: Vec::new(),
            bytes: 0,
            requests: 0,
            table_bytes: 0,
            table_requests: 0,
            background_bytes: 0,
            delivered_bytes: 0,
            delivered_table_bytes: 0,
            log: cfg.record_requests.then(Vec::new),
            progress: ProgressClock::default(),
            transfer: TransferReport::default(),
            longest_outage_s: 0.0,
        }
    }

    /// Checksum failures of the transport so far.
    fn checksum_failures(&self) -> u64 {
        self.transport
            .stats()
            .checksum_failures
            .load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// What the frames of a walk measured.
#[derive(Default)]
struct Walked {
    frames: Vec<FrameRecord>,
    /// Most bytes the cache held after a frame.
    max_cache: u64,
    /// Time of the first complete frame, and the bytes (all, tables) delivered by then.
    first_frame: Option<f64>,
    first_frame_bytes: Option<(u64, u64)>,
}

/// Run one (strategy, bandwidth) walk.
pub(crate) async fn run_one(
    source: &Source,
    scene: &Scene,
    cfg: &WalkConfig,
    (strategy, bandwidth): (Strategy, Option<u64>),
    manifest: ManifestCost,
    on_frame: &mut dyn FnMut(u64),
) -> (RunReport, Option<WalkError>) {
    let wall = std::time::Instant::now();
    // The manifest comes first, alone on the link from t = 0; the walk (and every request)
    // starts when it has arrived, `t0` later.
    let t0 = VirtualLink::new(bandwidth, cfg.latency_s).schedule_requests(
        0.0,
        manifest.bytes,
        manifest.round_trips.max(1),
    );
    let config = SchedulerConfig {
        strategy,
        ..cfg.schedule.clone()
    };
    let start = scene.route.legs.first().map_or(cfg.track, |l| l.0);
    let mut sched = match Scheduler::new(scene.top.clone(), start, config) {
        Ok(s) => s,
        Err(e) => {
            let report = RunReport {
                strategy: strategy.name(),
                bandwidth_bps: bandwidth,
                manifest_bytes: manifest.bytes,
                manifest_s: t0,
                error: Some(e.to_string()),
                ..RunReport::default()
            };
            return (report, Some(e.into()));
        }
    };
    let mut exec = Exec::new(source, cfg, bandwidth);
    let failures_before = exec.checksum_failures();
    let length = scene.route.length();
    let (walked, error) = walk(&mut exec, &mut sched, scene, cfg, t0, manifest, on_frame).await;
    let frames = walked.frames;
    let mean = |f: &dyn Fn(&FrameRecord) -> f64| {
        frames.iter().map(f).sum::<f64>() / frames.len().max(1) as f64
    };
    let naive = strategy == Strategy::Naive;
    let stats = sched.stats().clone();
    let turns = turn_records(scene, cfg, &frames);
    let window = |f: &FrameRecord| {
        scene
            .route
            .turn_distances()
            .iter()
            .any(|&d| f.d_m >= d && f.d_m < d + cfg.turn_window_m)
    };
    let part_mean = |at: bool| {
        let v: Vec<f64> = frames
            .iter()
            .filter(|f| window(f) == at)
            .map(|f| f.needed_fraction)
            .collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let stalled = |at: bool| {
        frames
            .iter()
            .filter(|f| window(f) == at && !f.complete)
            .count() as u64
    };
    let failures = exec.checksum_failures() - failures_before;
    let report = RunReport {
        strategy: strategy.name(),
        bandwidth_bps: bandwidth,
        time_to_first_frame_s: walked.first_frame,
        manifest_bytes: manifest.bytes,
        manifest_s: t0,
        table_bytes: exec.table_bytes,
        background_bytes: exec.background_bytes,
        first_frame_bytes: walked.first_frame_bytes.map(|b| b.0),
        first_frame_table_bytes: walked.first_frame_bytes.map(|b| b.1),
        table_requests: exec.table_requests,
        mean_needed_fraction: mean(&|f| f.needed_fraction),
        mean_quality: mean(&|f| f.quality),
        bytes: exec.bytes,
        bytes_per_m: if length > 0.0 {
            exec.bytes as f64 / length
        } else {
            0.0
        },
        requests: exec.requests,
        requests_per_m: if length > 0.0 {
            exec.requests as f64 / length
        } else {
            0.0
        },
        checksum_failures: failures,
        cache_budget_bytes: (!naive).then(|| sched.cache().budget()),
        max_cache_bytes: walked.max_cache,
        max_resident_bytes: stats.max_resident_bytes,
        resident_within_budget: !stats.over_budget,
        memory_budget_bytes: stats.memory_budget_bytes,
        wall_s: wall.elapsed().as_secs_f64(),
        retries: exec.transfer.retries as u64,
        timeouts: exec.transfer.timeouts as u64,
        outage_s: exec.transfer.outage_s,
        longest_outage_s: exec.longest_outage_s,
        longest_wait_s: exec.progress.longest_s(),
        part_faults: stats.part_faults,
        parts_given_up: stats.parts_given_up,
        table_faults: stats.table_faults,
        tables_given_up: stats.tables_given_up,
        stalled_frames_at_turns: stalled(true),
        stalled_frames_elsewhere: stalled(false),
        mean_needed_fraction_at_turns: part_mean(true),
        mean_needed_fraction_elsewhere: part_mean(false),
        turns,
        completed: error.is_none(),
        error: error.as_ref().map(|e| e.to_string()),
        frames,
        request_log: exec.log.unwrap_or_default(),
    };
    (report, error)
}

/// The frames of the walk, each measured, with the requests between them; stops at the
/// first error.
async fn walk(
    exec: &mut Exec,
    sched: &mut Scheduler,
    scene: &Scene,
    cfg: &WalkConfig,
    t0: f64,
    manifest: ManifestCost,
    on_frame: &mut dyn FnMut(u64),
) -> (Walked, Option<WalkError>) {
    let dt = cfg.frame_dt_s.max(1e-3);
    let mut walked = Walked::default();
    let turns = scene.route.turn_distances();
    for (k, frame) in walk_frames(&scene.net, &scene.route, cfg)
        .into_iter()
        .enumerate()
    {
        let (t, cam) = (frame.t_s, frame.camera);
        let pos = NetPos {
            track: frame.track,
            s: frame.s_m,
        };
        exec.arrive_until(t);
        exec.feed(t, sched);
        let (quality, needed, complete) = measure_frame(scene, cfg, sched, pos, &cam);
        if complete && walked.first_frame.is_none() {
            walked.first_frame = Some(t0 + t);
            walked.first_frame_bytes = Some((
                manifest.bytes + exec.delivered_bytes,
                exec.delivered_table_bytes,
            ));
        }
        sched.set_bundles(exec.transport.bundles_supported());
        let running = exec.dispatcher.running_keys();
        // The walker knows its way: the branch of the next turn is its choice.
        sched.set_branch(next_branch(scene, frame.d_m, &turns));
        let actions = sched.tick_at(t, pos, &cam, None, &running);
        exec.dispatcher.replace(actions.wants, actions.limits);
        let mut error = exec.send(t, sched).await.err();
        walked.max_cache = walked.max_cache.max(sched.cache().used());
        on_frame(k as u64);
        walked.frames.push(FrameRecord {
            t_s: t0 + t,
            s_m: pos.s,
            track: pos.track,
            d_m: frame.d_m,
            quality,
            needed_fraction: needed,
            complete,
            bytes: exec.bytes,
            cache_bytes: sched.cache().used(),
        });
        if error.is_some() {
            return (walked, error);
        }
        // Between frames: each arrival frees a slot, and the next request goes at once.
        let t_next = (k + 1) as f64 * dt;
        while let Some(te) = exec.next_arrival(t_next) {
            exec.arrive_until(te);
            sched.set_bundles(exec.transport.bundles_supported());
            if let Err(e) = exec.send(te, sched).await {
                error = Some(e);
                break;
            }
        }
        if error.is_some() {
            return (walked, error);
        }
    }
    (walked, None)
}

/// The branch the route takes at its next turn after `d` metres (none past the last).
fn next_branch(scene: &Scene, d: f64, turns: &[f64]) -> Option<tracks::network::Branch> {
    let k = turns.iter().position(|&t| t >= d)?;
    let (to_track, from, to) = scene.route.legs.get(k + 1).copied()?;
    let j = scene.net.junction_at(*scene.route.turns.get(k)?)?;
    j.branches
        .iter()
        .copied()
        .find(|b| b.track == to_track && b.forward == (to >= from))
}

/// Per turn of the route, how the frames in the window after it fared.
fn turn_records(scene: &Scene, cfg: &WalkConfig, frames: &[FrameRecord]) -> Vec<TurnRecord> {
    let names = |t: usize| scene.net.tracks[t].name.clone();
    scene
        .route
        .turn_distances()
        .iter()
        .enumerate()
        .map(|(k, &d)| {
            let win: Vec<&FrameRecord> = frames
                .iter()
                .filter(|f| f.d_m >= d && f.d_m < d + cfg.turn_window_m)
                .collect();
            let passed = win.first().map(|f| f.t_s);
            TurnRecord {
                viewpoint: scene.route.turns[k],
                d_m: d,
                from_track: names(scene.route.legs[k].0),
                to_track: names(scene.route.legs[k + 1].0),
                first_complete_after_s: win
                    .iter()
                    .find(|f| f.complete)
                    .zip(passed)
                    .map(|(f, p)| f.t_s - p),
                frames: win.len() as u64,
                stalled: win.iter().filter(|f| !f.complete).count() as u64,
            }
        })
        .collect()
}

/// `(quality, needed fraction, complete)` of the frame at `pos` seen by `cam`: the visibility
/// pass over the whole database at the scripted camera, against what the scheduler holds.
fn measure_frame(
    scene: &Scene,
    cfg: &WalkConfig,
    sched: &Scheduler,
    pos: NetPos,
    cam: &PerspectiveCamera,
) -> (f64, f64, bool) {
    let weights = scene.net.blend_weights(pos.track, pos.s);
    let counts = scene
        .index
        .count(cam, &weights, cfg.samples_x, cfg.samples_y);
    let seg = scene.net.segment_at(pos.track, pos.s).unwrap_or(0);
    // The paper's quality is measured against the segment's ACH list as the database has
    // it, whether or not the strategy fetched the lists: the client's item of each entry's
    // tile (`None` while its table is missing).
    let truth: Vec<Option<usize>> = scene
        .table
        .segment_ach
        .get(seg)
        .map_or(&[][..], |v| v.as_slice())
        .iter()
        .map(|&(i, _)| {
            let it = &scene.table.items[i];
            sched.table().tile_item(it.viewpoint, it.tile?)
        })
        .collect();
    frame_metrics(sched.table(), sched.held(), &truth, &counts)
}

/// `(quality, needed fraction, complete)` of one frame; `ach` is the segment's ACH list as
/// the client's items (`None`: not known to the client, nothing held).
fn frame_metrics(
    table: &ItemTable,
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
                let info = &table.items[i].info;
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
        let level = table.items[item].info.level_with(have[item]);
        if level.is_none() {
            complete = false;
        }
        ok += c.satisfied(level);
    }
    let needed = if total > 0.0 { ok / total } else { 1.0 };
    (quality, needed, complete)
}
