//! The walk simulator: a scripted walk along a track, streamed over real HTTP, measured.
//!
//! [`run_walk`] walks a track of the database served at a URL (or a route through several,
//! turning at their junctions: [`WalkConfig::route`]) at a given speed, looking around like a
//! person (a scripted yaw/pitch path, [`look_at`]), once per
//! ([`Strategy`], bandwidth). The client is the viewer's: the same [`crate::client::Scheduler`]
//! decides every request, and its requests go out by the same [`crate::client::Dispatcher`]
//! rule as the viewer's worker pool, so a walk measures what `railview view URL` does (the
//! GPU's visible-pixel counts are the one thing a walk cannot have; the scheduler's CPU
//! estimate of the same pass stands in). Time is virtual: every request really goes over
//! HTTP (and is checked), but its arrival time comes from a [`VirtualLink`] (latency per HTTP
//! request + body bytes / bandwidth, one transfer at a time on the link, up to the client's
//! requests in flight), so runs at 56 kbit/s take seconds, not minutes, and repeat exactly.
//! The scheduler ticks once per frame; between frames each arrival frees a slot, and the next
//! request the dispatcher gives goes out at once, as in the viewer. Per frame it records the
//! PTM paper's *progressive downloading quality* (downloaded levels / levels, averaged over
//! the current segment's ACH tiles) and the fraction of needed pixels present at their needed
//! level ([`crate::visibility`], over the whole database: the walker's eyes, not its client).
//! [`write_outputs`] writes `walk.json`, a CSV, a PNG plot and a Markdown summary.
//!
//! The manifest is charged too: the top manifest's transferred bytes (gzip when the server
//! offers it, plus the checksum file) occupy each run's link from t = 0, and the walk starts
//! when it has arrived (`manifest_s`). Viewpoint tables are fetched during the walk like any
//! response (`table_bytes` and `table_requests` per run; `bytes` includes them). Frame times
//! and `time_to_first_frame_s` count from t = 0, so they include the manifest and the tables;
//! the per-frame means are over the walk itself. `requests` counts HTTP requests (a request
//! the client sends as one batch may take several on a server without `/bundle` or
//! multi-range answers), `bytes` their body bytes.
//!
//! Failures are measured, not fatal. A part or table whose object is damaged or missing is
//! counted, asked for again later on the virtual clock and given up after repeated faults
//! (the scheduler's [`crate::client::FailureBook`], the same as the viewer's); the walk goes
//! on without it (`part_faults`, `parts_given_up`, `tables_given_up`). A server that stops
//! answering for a while costs the requests retries; the wall-clock time they spent failing
//! (`outage_s`) also holds the virtual link, so the outage shows in the frames and in
//! `longest_wait_s` (the longest virtual time with requests outstanding and nothing
//! arriving). A server gone for longer than the retry policy allows
//! ([`crate::client::RetryPolicy::give_up_after`]) ends the run and the walk: the report
//! keeps every finished run and what the failed one measured ([`WalkFailed`]), so
//! `walk.json` is always written.

pub mod load;
mod plot;
mod sim;
pub mod stage;
pub mod synth;

use std::path::Path;

use serde::{Deserialize, Serialize};
use tracks::manifest::Manifest;

use db::split::{assemble, TopManifest, ViewTable};
use tracks::network::Network;
use tracks::PerspectiveCamera;

use crate::client::{
    ClientError, ClientStats, Connection, FetchKey, ItemTable, RetryPolicy, Route, SchedulerConfig,
    ServerUrl, Source,
};
use crate::visibility::SceneIndex;

pub use crate::client::Strategy;

/// Walk settings: the walker (speed, camera, frames), the simulated link, and the client's
/// own settings ([`SchedulerConfig`], the viewer's defaults; its strategy is set per run).
#[derive(Clone, Debug)]
pub struct WalkConfig {
    pub speed_mps: f64,
    pub latency_s: f64,
    pub frame_dt_s: f64,
    /// Standing still at the end of the track (the static budgets apply).
    pub pause_s: f64,
    /// The client: budgets, cache, requests in flight, prefetch (the viewer's defaults).
    pub schedule: SchedulerConfig,
    pub screen_width: u32,
    pub screen_height: u32,
    pub fov_deg: f64,
    /// Samples per frame of the visibility pass that measures what the frame needs (the
    /// walker's eyes, over the whole database; the client counts with its own).
    pub samples_x: u32,
    pub samples_y: u32,
    pub track: usize,
    /// Walk through these tracks instead (names; from the first's far end into each next at
    /// their junction, to the far end of the last): [`crate::client::Route`].
    pub route: Option<Vec<String>>,
    /// Stop the walk this many metres along it (the route, or the track), when set: the same
    /// length of walk on networks of any size.
    pub max_length_m: Option<f64>,
    /// Frames within this many metres after a turn count as the turn's ([`RunReport::turns`]).
    pub turn_window_m: f64,
    /// Keep every run's requests, in the order they went out ([`RunReport::request_log`]).
    pub record_requests: bool,
    /// Timeouts and retries of the real transfers.
    pub retry: RetryPolicy,
}

/// Most frames one run may simulate (length / speed + pause, over the frame time): a limit
/// on how long a walk can run, checked before it starts.
pub const MAX_FRAMES_PER_RUN: u64 = 1_000_000;

impl WalkConfig {
    /// Frames one run simulates on a track of `length_m` metres, or an error naming the
    /// values when that is over [`MAX_FRAMES_PER_RUN`] or a value is not a usable number.
    pub fn frames_per_run(&self, length_m: f64) -> Result<u64, String> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.speed_mps) || !positive(self.frame_dt_s) {
            return Err(format!(
                "speed {} m/s and frame time {} s must be positive numbers",
                self.speed_mps, self.frame_dt_s
            ));
        }
        if !(self.pause_s.is_finite() && self.pause_s >= 0.0 && length_m.is_finite()) {
            return Err(format!(
                "pause {} s and track length {length_m} m must be finite",
                self.pause_s
            ));
        }
        let seconds = length_m / self.speed_mps + self.pause_s;
        let frames = (seconds / self.frame_dt_s).floor() + 1.0;
        if frames > MAX_FRAMES_PER_RUN as f64 {
            return Err(format!(
                "a walk of {length_m:.1} m at {} m/s with a {} s pause is {seconds:.3e} s of \
                 simulated time, {frames:.3e} frames of {} s; at most {MAX_FRAMES_PER_RUN} \
                 frames per run (walk faster)",
                self.speed_mps, self.pause_s, self.frame_dt_s
            ));
        }
        Ok(frames as u64)
    }
}

impl Default for WalkConfig {
    fn default() -> Self {
        WalkConfig {
            speed_mps: 1.5,
            latency_s: 0.05,
            frame_dt_s: 0.05,
            pause_s: 3.0,
            schedule: SchedulerConfig::default(),
            screen_width: 1280,
            screen_height: 720,
            fov_deg: 90.0,
            samples_x: 64,
            samples_y: 36,
            track: 0,
            route: None,
            max_length_m: None,
            turn_window_m: 4.0,
            record_requests: false,
            retry: RetryPolicy::default(),
        }
    }
}

/// A transfer link simulated in virtual time.
#[derive(Clone, Debug)]
pub struct VirtualLink {
    pub bandwidth_bps: Option<f64>,
    pub latency_s: f64,
    free_at: f64,
    /// Nothing gets through before this time (an outage).
    down_until: f64,
}

impl VirtualLink {
    pub fn new(bandwidth_bps: Option<u64>, latency_s: f64) -> VirtualLink {
        VirtualLink {
            bandwidth_bps: bandwidth_bps.map(|b| b as f64),
            latency_s,
            free_at: 0.0,
            down_until: 0.0,
        }
    }

    /// The server is unreachable from `t` for `seconds`: requests issued before the end of
    /// it start when it ends.
    pub fn outage(&mut self, t: f64, seconds: f64) {
        if seconds.is_finite() && seconds > 0.0 {
            self.down_until = self.down_until.max(t + seconds);
        }
    }

    /// Arrival time of `bytes` requested at `t` over `requests` sequential requests on one
    /// connection (a bundle is one; a static host answers its pieces one request each, each
    /// paying the latency again).
    pub fn schedule_requests(&mut self, t: f64, bytes: u64, requests: u64) -> f64 {
        self.schedule(t, bytes) + self.latency_s * requests.saturating_sub(1) as f64
    }

    /// Arrival time of `bytes` requested at `t`.
    pub fn schedule(&mut self, t: f64, bytes: u64) -> f64 {
        let t = t.max(self.down_until);
        match self.bandwidth_bps {
            None => t + self.latency_s,
            Some(bps) => {
                let start = (t + self.latency_s).max(self.free_at);
                self.free_at = start + bytes as f64 * 8.0 / bps;
                self.free_at
            }
        }
    }
}

/// The scripted look-around at time `t`: `(yaw, pitch)` degrees around the walking heading.
pub fn look_at(heading_yaw_deg: f64, t: f64) -> (f64, f64) {
    use std::f64::consts::TAU;
    let yaw = heading_yaw_deg + 55.0 * (TAU * t / 7.0).sin() + 20.0 * (TAU * t / 2.9).sin();
    let pitch = -5.0 + 12.0 * (TAU * t / 4.3).sin();
    (yaw, pitch)
}

/// One frame of the scripted walk: its time (from the start of the walk), where on the network
/// (`s_m` along `track`), how far along the walk, and the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkFrame {
    pub t_s: f64,
    pub s_m: f64,
    pub track: usize,
    /// Metres along the walk (the route).
    pub d_m: f64,
    pub camera: PerspectiveCamera,
}

/// The frames of the scripted walk along `route` of `net`: every `frame_dt_s` from 0 to its
/// end at `speed_mps` and `pause_s` beyond, the camera on the route looking around the way of
/// travel ([`look_at`]). The walk simulator runs these; a replay runs them through a live
/// session.
pub fn walk_frames(net: &Network, route: &Route, cfg: &WalkConfig) -> Vec<WalkFrame> {
    let length = route.length();
    let walk_s = if cfg.speed_mps > 0.0 {
        length / cfg.speed_mps
    } else {
        0.0
    };
    let end_t = walk_s + cfg.pause_s.max(0.0);
    let dt = cfg.frame_dt_s.max(1e-3);
    (0u64..)
        .map(|k| k as f64 * dt)
        .take_while(|&t| t <= end_t + 1e-9)
        .map(|t| {
            let d = (t * cfg.speed_mps).min(length);
            let (pos, forward) = route.at(d);
            let track = &net.tracks[pos.track];
            let tan = track.tangent_at(pos.s) * if forward { 1.0 } else { -1.0 };
            let heading = tan.x.atan2(-tan.z).to_degrees();
            let (yaw, pitch) = look_at(heading, t);
            WalkFrame {
                t_s: t,
                s_m: pos.s,
                track: pos.track,
                d_m: d,
                camera: PerspectiveCamera {
                    position: track.position_at(pos.s),
                    yaw_deg: yaw,
                    pitch_deg: pitch,
                    fov_deg: cfg.fov_deg,
                    width: cfg.screen_width,
                    height: cfg.screen_height,
                },
            }
        })
        .collect()
}

/// The walk a config asks for on `net`: its route, or the whole of its track.
pub fn route_of(net: &Network, cfg: &WalkConfig) -> Result<Route, WalkError> {
    let names: Vec<String> = match &cfg.route {
        Some(r) => r.clone(),
        None => vec![net
            .tracks
            .get(cfg.track)
            .ok_or_else(|| WalkError::Config(format!("no track {}", cfg.track)))?
            .name
            .clone()],
    };
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut route =
        Route::new(net, &refs).map_err(|e| WalkError::Config(format!("--route: {e}")))?;
    if let Some(max) = cfg.max_length_m {
        cut_route(&mut route, max);
    }
    Ok(route)
}

/// Cuts `route` to its first `max` metres: the leg that reaches `max` ends there, later legs
/// and their turns are dropped.
fn cut_route(route: &mut Route, max: f64) {
    let mut left = max.max(0.0);
    for k in 0..route.legs.len() {
        let (t, a, b) = route.legs[k];
        let len = (b - a).abs();
        if len >= left {
            route.legs[k] = (t, a, a + left * (b - a).signum());
            route.legs.truncate(k + 1);
            route.turns.truncate(k);
            return;
        }
        left -= len;
    }
}

/// One frame of a run.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    pub t_s: f64,
    pub s_m: f64,
    /// The track the walker is on, and metres along the walk.
    pub track: usize,
    pub d_m: f64,
    pub quality: f64,
    pub needed_fraction: f64,
    pub complete: bool,
    pub bytes: u64,
    pub cache_bytes: u64,
}

/// One (strategy, bandwidth) run. Read back (its frames and request log are not in
/// `walk.json`), a field the file lacks takes its default.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RunReport {
    pub strategy: String,
    pub bandwidth_bps: Option<u64>,
    /// First time every visible pixel had at least its tile's coarsest level (`null` = never),
    /// counted from the request for the manifest.
    pub time_to_first_frame_s: Option<f64>,
    /// Bytes transferred for the manifest (body bytes of its requests), charged at t = 0.
    pub manifest_bytes: u64,
    /// When the manifest had arrived on this run's link: the walk starts then.
    pub manifest_s: f64,
    /// Bytes of viewpoint tables transferred (also counted in `bytes`), and their requests.
    pub table_bytes: u64,
    pub table_requests: u64,
    /// Bytes of viewpoints' backgrounds transferred (also counted in `bytes`).
    pub background_bytes: u64,
    /// Bytes that had arrived (the manifest's included) at the first complete frame, and of
    /// them viewpoint tables.
    pub first_frame_bytes: Option<u64>,
    pub first_frame_table_bytes: Option<u64>,
    pub mean_needed_fraction: f64,
    pub mean_quality: f64,
    pub bytes: u64,
    pub bytes_per_m: f64,
    /// HTTP requests (retries included), and per metre of track.
    pub requests: u64,
    pub requests_per_m: f64,
    pub checksum_failures: u64,
    /// `null` = unlimited (naive keeps everything).
    pub cache_budget_bytes: Option<u64>,
    pub max_cache_bytes: u64,
    /// Largest texture memory held resident by the budget rules (decoded bytes).
    pub max_resident_bytes: u64,
    /// Whether the resident set always fit the memory budget in force (`M` or `M_static`).
    pub resident_within_budget: bool,
    /// `M` of the run at its end (configured, or scaled to what the client knew).
    pub memory_budget_bytes: u64,
    /// Wall-clock seconds the run took (real transfers and simulation).
    pub wall_s: f64,
    /// Transfer attempts retried after a connection failure, timeout or 5xx, and of them
    /// timeouts: the server was unreachable for a while.
    pub retries: u64,
    pub timeouts: u64,
    /// Wall-clock seconds requests spent failing before they succeeded, in all and the
    /// longest for one request; the virtual link is held for as long.
    pub outage_s: f64,
    pub longest_outage_s: f64,
    /// Longest virtual time with requests outstanding and nothing arriving.
    pub longest_wait_s: f64,
    /// Faults of parts (checksum that keeps failing, missing object) and parts given up
    /// after repeated faults; the same for viewpoint tables.
    pub part_faults: u64,
    pub parts_given_up: u64,
    pub table_faults: u64,
    pub tables_given_up: u64,
    /// Per turn of the route: where it is, and how the frames after it fared.
    pub turns: Vec<TurnRecord>,
    /// Frames without every visible pixel showable, within the turn window after a turn and
    /// elsewhere, and the needed fraction's mean over each.
    pub stalled_frames_at_turns: u64,
    pub stalled_frames_elsewhere: u64,
    pub mean_needed_fraction_at_turns: Option<f64>,
    pub mean_needed_fraction_elsewhere: Option<f64>,
    /// Whether the run reached its end; `error` says what stopped it.
    pub completed: bool,
    pub error: Option<String>,
    #[serde(skip)]
    pub frames: Vec<FrameRecord>,
    /// With [`WalkConfig::record_requests`]: the keys of every request, in the order they
    /// went out.
    #[serde(skip)]
    pub request_log: Vec<Vec<FetchKey>>,
}

/// A turn of a walk and how the frames after it fared.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct TurnRecord {
    /// The junction's viewpoint and the metres along the walk where it is.
    pub viewpoint: usize,
    pub d_m: f64,
    pub from_track: String,
    pub to_track: String,
    /// Seconds from passing the junction to the first complete frame (`null`: none in the
    /// turn window).
    pub first_complete_after_s: Option<f64>,
    /// Frames in the turn window, and of them not complete.
    pub frames: u64,
    pub stalled: u64,
}

impl TurnRecord {
    /// `from→to` and the seconds to the first complete frame after the junction, followed by
    /// `unit` (`never` where none came in the turn window).
    pub fn label(&self, unit: &str) -> String {
        format!(
            "{}→{} {}",
            self.from_track,
            self.to_track,
            self.first_complete_after_s
                .map_or("never".into(), |x| format!("{x:.2}{unit}"))
        )
    }
}

/// All runs (`walk.json`). Read back, a field the file lacks takes its default.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct WalkReport {
    pub scene: String,
    pub track: String,
    pub length_m: f64,
    pub speed_mps: f64,
    pub latency_s: f64,
    pub runs: Vec<RunReport>,
    /// Why the walk stopped before every run finished (`null`: it did not).
    pub error: Option<String>,
}

/// Errors of a walk.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WalkError {
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The server stopped answering within the retry policy during a run.
    #[error("the server stopped answering: {0}")]
    Unreachable(ClientError),
    #[error("database: {0}")]
    Database(String),
    /// The walk's settings would make a run that does not end in reasonable time.
    #[error("{0}")]
    Config(String),
    #[error("writing {path}: {message}")]
    Output { path: String, message: String },
}

/// A walk that stopped early: what it measured (finished runs, the failed one's frames so
/// far) and why it stopped.
#[derive(Debug)]
pub struct WalkFailed {
    pub report: WalkReport,
    pub error: WalkError,
}

/// What a walk tells its caller as it goes.
#[derive(Clone, Copy, Debug)]
pub enum WalkEvent<'a> {
    /// Before the first run: how many runs, and how many frames each.
    Planned { runs: usize, frames_per_run: u64 },
    /// A frame of run `run` (0-based) was simulated.
    Frame { run: usize, frame: u64 },
    /// A run ended.
    Finished(&'a RunReport),
}

/// What fetching the manifest cost: body bytes and requests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ManifestCost {
    pub bytes: u64,
    pub requests: u64,
    /// Round trips the requests took (the checksum file travels beside the manifest).
    pub round_trips: u64,
}

pub(crate) struct Scene {
    manifest: Manifest,
    /// The top manifest the clients start from.
    top: TopManifest,
    /// Every item of the database (what each frame's needs are measured against).
    table: ItemTable,
    /// Where the walk's needs come from: the whole database.
    index: SceneIndex,
    /// The graph of tracks and the walk along it.
    net: Network,
    route: Route,
}

fn load_scene(top: &TopManifest, manifest: Manifest, cfg: &WalkConfig) -> Result<Scene, WalkError> {
    let table = ItemTable::new(&manifest)?;
    let index = SceneIndex::new(&manifest)
        .ok_or_else(|| WalkError::Database("face/tile sizes invalid".into()))?;
    let net = top
        .network()
        .map_err(|e| WalkError::Database(format!("the graph of tracks: {e}")))?;
    let route = route_of(&net, cfg)?;
    Ok(Scene {
        top: top.clone(),
        manifest,
        table,
        index,
        net,
        route,
    })
}

/// Walk every (strategy, bandwidth) over the server at `url`. When the server cannot be
/// reached (at the start, or for longer than the retry policy allows during a run), the
/// walk stops: [`WalkFailed`] holds every finished run and what the failed one measured.
pub async fn run_walk(
    url: &ServerUrl,
    config: &WalkConfig,
    strategies: &[Strategy],
    bandwidths: &[Option<u64>],
    mut progress: impl FnMut(WalkEvent),
) -> Result<WalkReport, Box<WalkFailed>> {
    let mut report = WalkReport {
        speed_mps: config.speed_mps,
        latency_s: config.latency_s,
        ..WalkReport::default()
    };
    let fail = |mut report: WalkReport, error: WalkError| {
        report.error = Some(error.to_string());
        Box::new(WalkFailed { report, error })
    };
    let stats = std::sync::Arc::new(ClientStats::default());
    let mut conn = Connection::new(url.clone(), config.retry.clone(), stats.clone());
    let scene = match fetch_scene(&mut conn, config).await {
        Ok(s) => s,
        Err(e) => return Err(fail(report, e)),
    };
    let (scene, cost) = scene;
    report.scene = scene.manifest.scene.clone();
    report.track = scene
        .route
        .legs
        .iter()
        .map(|l| scene.net.tracks[l.0].name.as_str())
        .collect::<Vec<_>>()
        .join(",");
    report.length_m = scene.route.length();
    let frames_per_run = match config.frames_per_run(report.length_m) {
        Ok(n) => n,
        Err(e) => return Err(fail(report, WalkError::Config(e))),
    };
    progress(WalkEvent::Planned {
        runs: strategies.len() * bandwidths.len(),
        frames_per_run,
    });
    let source = Source::Http(url.clone());
    for &bw in bandwidths {
        for &strategy in strategies {
            let run = report.runs.len();
            let mut on_frame = |frame| progress(WalkEvent::Frame { run, frame });
            let (r, error) =
                sim::run_one(&source, &scene, config, (strategy, bw), cost, &mut on_frame).await;
            progress(WalkEvent::Finished(&r));
            report.runs.push(r);
            if let Some(e) = error {
                return Err(fail(report, e));
            }
        }
    }
    Ok(report)
}

/// The manifest and the tables along the route (the walker's eyes: what each frame
/// needs), and what fetching the manifest cost.
async fn fetch_scene(
    conn: &mut Connection,
    config: &WalkConfig,
) -> Result<(Scene, ManifestCost), WalkError> {
    let fetched = conn.fetch_manifest().await?;
    let cost = ManifestCost {
        bytes: fetched.transferred_bytes,
        requests: fetched.requests,
        round_trips: fetched.round_trips,
    };
    // The tables of the route's tracks, for what each frame needs (the walker's eyes, not
    // its client: the runs fetch the tables again, on their links, as a viewer would). A
    // frame needs the two viewpoints around it and its segment's ACH list, so the viewpoints
    // at the ends of the segments the route runs along are all the eyes need, however large
    // the network.
    // A table that is damaged or missing on the server is one the walker cannot see either
    // (its viewpoint shows nothing); the runs count it when they ask for it.
    let net = fetched
        .top
        .network()
        .map_err(|e| WalkError::Database(format!("the graph of tracks: {e}")))?;
    let route = route_of(&net, config)?;
    let mut seen = vec![false; fetched.top.viewpoints.len()];
    for &(t, a, b) in &route.legs {
        let stops = net.stops.get(t).map_or(&[][..], |v| v.as_slice());
        // The stops from the last at or before the leg's start to the first at or after its
        // end: every segment the leg runs along, both ends.
        let (lo, hi) = (a.min(b), a.max(b));
        let first = stops.partition_point(|st| st.s <= lo).saturating_sub(1);
        let last = stops
            .partition_point(|st| st.s < hi)
            .min(stops.len().saturating_sub(1));
        for st in stops.get(first..=last).into_iter().flatten() {
            if let Some(x) = seen.get_mut(st.viewpoint) {
                *x = true;
            }
        }
    }
    drop(net);
    let mut tables = Vec::new();
    for v in &fetched.top.viewpoints {
        if !seen[v.index] {
            tables.push(ViewTable {
                viewpoint: v.index,
                background: Vec::new(),
                tiles: Vec::new(),
                segments: Vec::new(),
            });
            continue;
        }
        let mut table = match conn.fetch_table(&v.table, v.index).await {
            Ok(t) => t,
            Err(e) if e.is_object_fault() || matches!(e, ClientError::Manifest(_)) => {
                tracing::warn!("walk: viewpoint {}'s table unreadable: {e}", v.index);
                ViewTable {
                    viewpoint: v.index,
                    background: Vec::new(),
                    tiles: Vec::new(),
                    segments: Vec::new(),
                }
            }
            Err(e) => return Err(e.into()),
        };
        if let Some(ach) = &v.ach {
            match conn.fetch_ach(ach, v.index).await {
                Ok(seg) => table.segments = seg,
                Err(e) if e.is_object_fault() || matches!(e, ClientError::Manifest(_)) => {
                    tracing::warn!("walk: viewpoint {}'s ACH lists unreadable: {e}", v.index)
                }
                Err(e) => return Err(e.into()),
            }
        }
        tables.push(table);
    }
    conn.take_report();
    let refs: Vec<Option<&ViewTable>> = tables.iter().map(Some).collect();
    let manifest = assemble(&fetched.top, &refs);
    let scene = load_scene(&fetched.top, manifest, config)?;
    Ok((scene, cost))
}

/// Write `walk.json`, `walk.csv`, `walk.png` and `summary.md` into `dir`.
pub fn write_outputs(report: &WalkReport, dir: &Path) -> Result<(), WalkError> {
    let err = |path: &Path, e: &dyn std::fmt::Display| WalkError::Output {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| err(dir, &e))?;
    let write = |name: &str, data: &[u8]| -> Result<(), WalkError> {
        let path = dir.join(name);
        railview_files::write(&path, data).map_err(|e| err(&path, &e))
    };
    let json = serde_json::to_vec_pretty(report).map_err(|e| err(dir, &e))?;
    write("walk.json", &json)?;
    let mut csv = String::from(
        "strategy,bandwidth_bps,t_s,s_m,quality,needed_fraction,complete,bytes,cache_bytes\n",
    );
    for r in &report.runs {
        let bw = r
            .bandwidth_bps
            .map_or("unlimited".to_string(), |b| b.to_string());
        for f in &r.frames {
            csv += &format!(
                "{},{},{:.3},{:.3},{:.4},{:.4},{},{},{}\n",
                r.strategy,
                bw,
                f.t_s,
                f.s_m,
                f.quality,
                f.needed_fraction,
                f.complete as u8,
                f.bytes,
                f.cache_bytes
            );
        }
    }
    write("walk.csv", csv.as_bytes())?;
    let fig = plot::figure(report);
    let svg = charts::svg(&fig).map_err(|e| err(&dir.join("walk.svg"), &e))?;
    write("walk.svg", svg.as_bytes())?;
    let png = charts::png(&fig).map_err(|e| err(&dir.join("walk.png"), &e))?;
    write("walk.png", &png)?;
    write("summary.md", summary_markdown(report).as_bytes())
}

/// The summary table (Markdown).
pub fn summary_markdown(r: &WalkReport) -> String {
    let mut s = format!(
        "# Walk: {} / {} ({:.1} m at {} m/s, latency {} ms)\n\n\
         | bandwidth | strategy | manifest bytes | manifest (s) | table bytes | first frame (s) | needed fraction | quality | bytes | bytes/m | requests | requests/m | checksum failures | part faults (given up) | retries | outage (s) | longest wait (s) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        r.scene,
        r.track,
        r.length_m,
        r.speed_mps,
        (r.latency_s * 1000.0).round()
    );
    for run in &r.runs {
        s += &format!(
            "| {} | {} | {} | {:.2} | {} | {} | {:.3} | {:.3} | {} | {:.0} | {} | {:.1} | {} | {} ({}) | {} | {:.1} | {:.2} |\n",
            run.bandwidth_bps.map_or("unlimited".into(), format_bps),
            run.strategy,
            run.manifest_bytes,
            run.manifest_s,
            run.table_bytes,
            run.time_to_first_frame_s
                .map_or("never".into(), |t| format!("{t:.2}")),
            run.mean_needed_fraction,
            run.mean_quality,
            run.bytes,
            run.bytes_per_m,
            run.requests,
            run.requests_per_m,
            run.checksum_failures,
            run.part_faults + run.table_faults,
            run.parts_given_up + run.tables_given_up,
            run.retries,
            run.outage_s,
            run.longest_wait_s,
        );
        if let Some(e) = &run.error {
            s += &format!(
                "\n**{} at {} stopped early:** {e}\n\n",
                run.strategy,
                run.bandwidth_bps.map_or("unlimited".into(), format_bps)
            );
        }
    }
    if r.runs.iter().any(|run| !run.turns.is_empty()) {
        s += "\n## Turns\n\nFrames in the window after each turn (stalled: not every visible pixel showable) \
              against the rest of the walk, and the time from passing each junction to the \
              first complete frame.\n\n\
              | bandwidth | strategy | stalled at turns | stalled elsewhere | needed at turns | needed elsewhere | first complete after each turn (s) |\n\
              |---|---|---|---|---|---|---|\n";
        let opt = |v: Option<f64>| v.map_or("–".to_string(), |x| format!("{x:.3}"));
        for run in &r.runs {
            let after: Vec<String> = run.turns.iter().map(|t| t.label("")).collect();
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} |\n",
                run.bandwidth_bps.map_or("unlimited".into(), format_bps),
                run.strategy,
                run.stalled_frames_at_turns,
                run.stalled_frames_elsewhere,
                opt(run.mean_needed_fraction_at_turns),
                opt(run.mean_needed_fraction_elsewhere),
                after.join(", ")
            );
        }
    }
    if let Some(e) = &r.error {
        s += &format!("\n**The walk stopped early:** {e}\n");
    }
    s += "\n![Quality over time, one panel per bandwidth](walk.svg)\n";
    s
}

/// `56 kbit/s`, `2 Mbit/s`.
pub fn format_bps(b: u64) -> String {
    if b >= 1_000_000 && b.is_multiple_of(1_000_000) {
        format!("{} Mbit/s", b / 1_000_000)
    } else if b >= 1000 && b.is_multiple_of(1000) {
        format!("{} kbit/s", b / 1000)
    } else {
        format!("{b} bit/s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_route_is_cut_at_its_length_within_the_leg_that_reaches_it() {
        let whole = Route {
            legs: vec![(0, 10.0, 0.0), (1, 5.0, 25.0), (2, 0.0, 8.0)],
            turns: vec![3, 7],
        };
        let mut r = whole.clone();
        cut_route(&mut r, 16.0);
        assert_eq!(r.legs, vec![(0, 10.0, 0.0), (1, 5.0, 11.0)]);
        assert_eq!(r.turns, vec![3]);
        let mut r = whole.clone();
        cut_route(&mut r, 4.0);
        assert_eq!((r.legs, r.turns), (vec![(0, 10.0, 6.0)], vec![]));
        let mut r = whole.clone();
        cut_route(&mut r, 1000.0);
        assert_eq!(r.legs, whole.legs);
        assert_eq!(r.turns, whole.turns);
    }
}
