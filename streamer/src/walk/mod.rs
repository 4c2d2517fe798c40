//! The walk simulator: a scripted walk along a track, streamed over real HTTP, measured.
//!
//! [`run_walk`] walks track 0 of the database served at a URL at a given speed, looking
//! around like a person (a scripted yaw/pitch path, [`look_at`]), once per
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

pub mod load;
mod plot;
mod sim;
pub mod synth;

use std::path::Path;

use serde::Serialize;
use tracks::manifest::Manifest;

use crate::db::split::{assemble, TopManifest, ViewTable};
use tracks::{PerspectiveCamera, TrackSet};

use crate::client::{
    ClientError, ClientStats, Connection, FetchKey, ItemTable, RetryPolicy, SchedulerConfig,
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
    /// Keep every run's requests, in the order they went out ([`RunReport::request_log`]).
    pub record_requests: bool,
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
            record_requests: false,
        }
    }
}

/// A transfer link simulated in virtual time.
#[derive(Clone, Debug)]
pub struct VirtualLink {
    pub bandwidth_bps: Option<f64>,
    pub latency_s: f64,
    free_at: f64,
}

impl VirtualLink {
    pub fn new(bandwidth_bps: Option<u64>, latency_s: f64) -> VirtualLink {
        VirtualLink {
            bandwidth_bps: bandwidth_bps.map(|b| b as f64),
            latency_s,
            free_at: 0.0,
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

/// One frame of the scripted walk: its time (from the start of the walk), arc length and
/// camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkFrame {
    pub t_s: f64,
    pub s_m: f64,
    pub camera: PerspectiveCamera,
}

/// The frames of the scripted walk along `track`: every `frame_dt_s` from 0 to the end of
/// the track at `speed_mps` and `pause_s` beyond, the camera on the track looking around the
/// way of travel ([`look_at`]). The walk simulator runs these; a replay runs them through a
/// live session.
pub fn walk_frames(track: &tracks::Track, cfg: &WalkConfig) -> Vec<WalkFrame> {
    let length = track.length();
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
            let s = (t * cfg.speed_mps).min(length);
            let tan = track.tangent_at(s);
            let heading = tan.x.atan2(-tan.z).to_degrees();
            let (yaw, pitch) = look_at(heading, t);
            WalkFrame {
                t_s: t,
                s_m: s,
                camera: PerspectiveCamera {
                    position: track.position_at(s),
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

/// One frame of a run.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    pub t_s: f64,
    pub s_m: f64,
    pub quality: f64,
    pub needed_fraction: f64,
    pub complete: bool,
    pub bytes: u64,
    pub cache_bytes: u64,
}

/// One (strategy, bandwidth) run.
#[derive(Clone, Debug, Serialize)]
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
    #[serde(skip)]
    pub frames: Vec<FrameRecord>,
    /// With [`WalkConfig::record_requests`]: the keys of every request, in the order they
    /// went out.
    #[serde(skip)]
    pub request_log: Vec<Vec<FetchKey>>,
}

/// All runs.
#[derive(Clone, Debug, Serialize)]
pub struct WalkReport {
    pub scene: String,
    pub track: String,
    pub length_m: f64,
    pub speed_mps: f64,
    pub latency_s: f64,
    pub runs: Vec<RunReport>,
}

/// Errors of a walk.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WalkError {
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("database: {0}")]
    Database(String),
    #[error("writing {path}: {message}")]
    Output { path: String, message: String },
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
    /// Every item of the track (what each frame's needs are measured against).
    table: ItemTable,
    /// Where the walk's needs come from: the whole database.
    index: SceneIndex,
    track: tracks::Track,
}

fn load_scene(top: &TopManifest, manifest: Manifest, track: usize) -> Result<Scene, WalkError> {
    let table = ItemTable::new(&manifest, track)?;
    let index = SceneIndex::new(&manifest, track)
        .ok_or_else(|| WalkError::Database("face/tile sizes or track invalid".into()))?;
    let entry = &manifest.tracks[track];
    let set = TrackSet::parse(&entry.track_toml, "manifest track_toml")
        .map_err(|e| WalkError::Database(e.to_string()))?;
    let t = set
        .get(&entry.name)
        .or(set.tracks.first())
        .cloned()
        .ok_or_else(|| WalkError::Database("track_toml holds no track".into()))?;
    Ok(Scene {
        top: top.clone(),
        manifest,
        table,
        index,
        track: t,
    })
}

/// Walk every (strategy, bandwidth) over the server at `url`.
pub async fn run_walk(
    url: &ServerUrl,
    config: &WalkConfig,
    strategies: &[Strategy],
    bandwidths: &[Option<u64>],
    mut progress: impl FnMut(&RunReport),
) -> Result<WalkReport, WalkError> {
    let stats = std::sync::Arc::new(ClientStats::default());
    let mut conn = Connection::new(url.clone(), RetryPolicy::default(), stats);
    let fetched = conn.fetch_manifest().await?;
    let cost = ManifestCost {
        bytes: fetched.transferred_bytes,
        requests: fetched.requests,
        round_trips: fetched.round_trips,
    };
    // The whole database, for what each frame needs (the walker's eyes, not its client: the
    // runs fetch the tables again, on their links, as a viewer would).
    let mut tables = Vec::new();
    for t in &fetched.top.tracks {
        let mut row = Vec::new();
        for v in &t.viewpoints {
            let mut table = conn.fetch_table(&v.table, v.index).await?;
            if let Some(ach) = &v.ach {
                table.segments = conn.fetch_ach(ach, v.index).await?;
            }
            row.push(table);
        }
        tables.push(row);
    }
    let refs: Vec<Vec<Option<&ViewTable>>> = tables
        .iter()
        .map(|row| row.iter().map(Some).collect())
        .collect();
    let manifest = assemble(&fetched.top, &refs);
    let scene = load_scene(&fetched.top, manifest, config.track)?;
    let mut runs = Vec::new();
    for &bw in bandwidths {
        for &strategy in strategies {
            let source = Source::Http(url.clone());
            let r = sim::run_one(&source, &scene, config, strategy, bw, cost).await?;
            progress(&r);
            runs.push(r);
        }
    }
    Ok(WalkReport {
        scene: scene.manifest.scene.clone(),
        track: scene.track.name.clone(),
        length_m: scene.track.length(),
        speed_mps: config.speed_mps,
        latency_s: config.latency_s,
        runs,
    })
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
    let png = plot::plot_png(report).map_err(|e| err(&dir.join("walk.png"), &e))?;
    write("walk.png", &png)?;
    write("summary.md", summary_markdown(report).as_bytes())
}

/// The summary table (Markdown).
pub fn summary_markdown(r: &WalkReport) -> String {
    let mut s = format!(
        "# Walk: {} / {} ({:.1} m at {} m/s, latency {} ms)\n\n\
         | bandwidth | strategy | manifest bytes | manifest (s) | table bytes | first frame (s) | needed fraction | quality | bytes | bytes/m | requests | requests/m | checksum failures |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        r.scene,
        r.track,
        r.length_m,
        r.speed_mps,
        (r.latency_s * 1000.0).round()
    );
    for run in &r.runs {
        s += &format!(
            "| {} | {} | {} | {:.2} | {} | {} | {:.3} | {:.3} | {} | {:.0} | {} | {:.1} | {} |\n",
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
            run.checksum_failures
        );
    }
    s += "\nPlot colours (walk.png, one panel per bandwidth; solid = quality, dotted = needed fraction): ";
    let names: Vec<String> = plot::legend(r);
    s += &names.join(", ");
    s += "\n";
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
