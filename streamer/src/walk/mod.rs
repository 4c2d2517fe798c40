//! The walk simulator: a scripted walk along a track, streamed over real HTTP, measured.
//!
//! [`run_walk`] walks track 0 of the database served at a URL at a given speed, looking
//! around like a person (a scripted yaw/pitch path, [`look_at`]), once per
//! ([`Strategy`], bandwidth). Time is virtual: every download really goes over HTTP (and is
//! checked), but its arrival time comes from a [`VirtualLink`] (latency + bytes / bandwidth,
//! one transfer at a time on the link, up to `max_in_flight` requests outstanding), so runs
//! at 56 kbit/s take seconds, not minutes, and repeat exactly. Per frame it records the PTM
//! paper's *progressive downloading quality* (downloaded levels / levels, averaged over the
//! current segment's ACH tiles) and the fraction of needed pixels present at their needed
//! level ([`crate::visibility`]). [`write_outputs`] writes `walk.json`, a CSV, a PNG plot
//! and a Markdown summary.

pub mod load;
mod plot;
pub mod synth;

use std::path::Path;

use serde::Serialize;
use tracks::manifest::Manifest;
use tracks::{PerspectiveCamera, TrackSet};

use crate::client::{
    next_segment, plan, segment_at, BudgetParams, Cache, ClientError, ClientStats, Connection,
    FetchKey, ItemTable, LinkEstimate, LiveCount, MotionTracker, PlanInput, PriorityMode,
    RetryPolicy, ServerUrl,
};
use crate::visibility::{blend_weights, SceneIndex, Surface, SurfaceCount};

/// How a run chooses what to download.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Strategy {
    /// Whole full-resolution tiles in manifest order.
    Naive,
    /// Budget rules with a priority source, optionally prefetching the next segment.
    Budget { mode: PriorityMode, prefetch: bool },
}

impl Strategy {
    /// `naive`, `ach`, `visibility`, `ach+visibility`, each of the last three `+prefetch`.
    pub fn parse(text: &str) -> Result<Strategy, String> {
        let t = text.trim().to_ascii_lowercase();
        if t == "naive" {
            return Ok(Strategy::Naive);
        }
        let mut ach = false;
        let mut vis = false;
        let mut prefetch = false;
        for part in t.split('+') {
            match part {
                "ach" => ach = true,
                "visibility" | "vis" => vis = true,
                "prefetch" => prefetch = true,
                _ => {
                    return Err(format!(
                        "strategy `{text}`: use naive, ach, visibility, ach+visibility, with optional +prefetch"
                    ))
                }
            }
        }
        let mode = match (ach, vis) {
            (true, false) => PriorityMode::Ach,
            (false, true) => PriorityMode::Visibility,
            (true, true) => PriorityMode::Combined { ach_weight: 0.5 },
            (false, false) => return Err(format!("strategy `{text}`: no priority source")),
        };
        Ok(Strategy::Budget { mode, prefetch })
    }

    pub fn name(&self) -> String {
        match self {
            Strategy::Naive => "naive".into(),
            Strategy::Budget { mode, prefetch } => {
                let m = match mode {
                    PriorityMode::Ach => "ach",
                    PriorityMode::Visibility => "visibility",
                    PriorityMode::Combined { .. } => "ach+visibility",
                };
                if *prefetch {
                    format!("{m}+prefetch")
                } else {
                    m.into()
                }
            }
        }
    }
}

/// Walk settings.
#[derive(Clone, Debug)]
pub struct WalkConfig {
    pub speed_mps: f64,
    pub latency_s: f64,
    pub frame_dt_s: f64,
    /// Standing still at the end of the track (the static budgets apply).
    pub pause_s: f64,
    pub budget: BudgetParams,
    pub cache_bytes: u64,
    pub max_in_flight: usize,
    pub screen_width: u32,
    pub screen_height: u32,
    pub fov_deg: f64,
    /// Visibility samples per frame.
    pub samples_x: u32,
    pub samples_y: u32,
    pub prefetch_horizon_s: f64,
    pub track: usize,
}

impl Default for WalkConfig {
    fn default() -> Self {
        WalkConfig {
            speed_mps: 1.5,
            latency_s: 0.05,
            frame_dt_s: 0.05,
            pause_s: 3.0,
            budget: BudgetParams::default(),
            cache_bytes: 64 << 20,
            max_in_flight: 4,
            screen_width: 1280,
            screen_height: 720,
            fov_deg: 90.0,
            samples_x: 64,
            samples_y: 36,
            prefetch_horizon_s: 3.0,
            track: 0,
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
    /// First time every visible pixel had at least its tile's coarsest level (`null` = never).
    pub time_to_first_frame_s: Option<f64>,
    pub mean_needed_fraction: f64,
    pub mean_quality: f64,
    pub bytes: u64,
    pub bytes_per_m: f64,
    pub requests: u64,
    pub checksum_failures: u64,
    pub cache_budget_bytes: u64,
    pub max_cache_bytes: u64,
    #[serde(skip)]
    pub frames: Vec<FrameRecord>,
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

struct Scene {
    manifest: Manifest,
    table: ItemTable,
    index: SceneIndex,
    track: tracks::Track,
}

fn load_scene(manifest: Manifest, track: usize) -> Result<Scene, WalkError> {
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
    let mut conn = Connection::new(url.clone(), RetryPolicy::default(), stats.clone());
    let manifest = conn.manifest().await?;
    let scene = load_scene(manifest, config.track)?;
    let mut runs = Vec::new();
    for &bw in bandwidths {
        for &strategy in strategies {
            let r = run_one(&mut conn, &stats, &scene, config, strategy, bw).await?;
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

struct InFlight {
    item: usize,
    keys: Vec<(FetchKey, bytes::Bytes)>,
    issued: f64,
    arrives: f64,
    bytes: u64,
}

async fn run_one(
    conn: &mut Connection,
    stats: &ClientStats,
    scene: &Scene,
    cfg: &WalkConfig,
    strategy: Strategy,
    bandwidth: Option<u64>,
) -> Result<RunReport, WalkError> {
    use std::sync::atomic::Ordering;
    let table = &scene.table;
    let items = table.infos();
    let n = items.len();
    let naive = strategy == Strategy::Naive;
    let mut cache = Cache::new(if naive { u64::MAX } else { cfg.cache_bytes });
    let mut link = VirtualLink::new(bandwidth, cfg.latency_s);
    let mut estimate = LinkEstimate::new(bandwidth.map_or(1e9, |b| b as f64), cfg.latency_s);
    let mut motion = MotionTracker::new();
    let mut in_flight: Vec<InFlight> = Vec::new();
    let mut downloading = vec![false; n];
    let mut naive_next = 0usize;
    let mut pinned: Vec<FetchKey> = Vec::new();
    let failures_before = stats.checksum_failures.load(Ordering::Relaxed);
    let length = scene.track.length();
    let walk_s = if cfg.speed_mps > 0.0 { length / cfg.speed_mps } else { 0.0 };
    let end_t = walk_s + cfg.pause_s.max(0.0);
    let dt = cfg.frame_dt_s.max(1e-3);
    let mut frames = Vec::new();
    let mut bytes = 0u64;
    let mut requests = 0u64;
    let mut max_cache = 0u64;
    let mut first_frame = None;
    let mut t = 0.0;
    while t <= end_t + 1e-9 {
        let s = (t * cfg.speed_mps).min(length);
        motion.observe(t, s);
        cache.set_position(s);
        // Deliver what has arrived by now.
        let (arrived, pending): (Vec<_>, Vec<_>) =
            in_flight.into_iter().partition(|f| f.arrives <= t + 1e-9);
        in_flight = pending;
        for f in arrived {
            downloading[f.item] = false;
            estimate.observe(f.bytes, f.arrives - f.issued);
            let s_item = table.items[f.item].s;
            for (key, data) in f.keys {
                // Refused when the budget is full of data in use: dropped, asked again later.
                let _ = cache.insert(key, data, s_item);
            }
        }
        // What the frame needs.
        let pos = scene.track.position_at(s);
        let tan = scene.track.tangent_at(s);
        let heading = tan.x.atan2(-tan.z).to_degrees();
        let (yaw, pitch) = look_at(heading, t);
        let cam = PerspectiveCamera {
            position: pos,
            yaw_deg: yaw,
            pitch_deg: pitch,
            fov_deg: cfg.fov_deg,
            width: cfg.screen_width,
            height: cfg.screen_height,
        };
        let weights = blend_weights(&table.vp_s, s);
        let counts = scene.index.count(&cam, &weights, cfg.samples_x, cfg.samples_y);
        let have: Vec<usize> = (0..n)
            .map(|i| {
                if naive {
                    let it = &table.items[i];
                    let mesh_ok = it.info.first_level_part == 0 || cache.contains(&it.parts[0].key);
                    if mesh_ok && cache.contains(&it.whole.key) {
                        it.parts.len()
                    } else {
                        0
                    }
                } else {
                    table.items[i]
                        .parts
                        .iter()
                        .take_while(|p| cache.contains(&p.key))
                        .count()
                }
            })
            .collect();
        let seg = segment_at(&table.vp_s, s).unwrap_or(0);
        let ach: &[(usize, f64)] = table.segment_ach.get(seg).map_or(&[], |v| v.as_slice());
        let (quality, needed, complete) = frame_metrics(table, &items, &have, ach, &counts);
        if complete && first_frame.is_none() {
            first_frame = Some(t);
        }
        // Decide and issue downloads.
        let free = cfg.max_in_flight.max(1).saturating_sub(in_flight.len());
        let mut issue: Vec<(usize, Vec<usize>)> = Vec::new();
        if naive {
            while issue.len() < free && naive_next < n {
                issue.push((naive_next, vec![usize::MAX]));
                naive_next += 1;
            }
        } else {
            let live: Vec<LiveCount> = counts
                .iter()
                .filter_map(|c| {
                    let item = surface_item(table, c)?;
                    Some(LiveCount {
                        item,
                        pixels: c.pixels(),
                        needed_level: c.finest_needed(),
                    })
                })
                .collect();
            let Strategy::Budget { mode, prefetch } = strategy else {
                unreachable!("naive handled above")
            };
            let next = if prefetch {
                next_segment(&motion, &table.vp_s, s, cfg.prefetch_horizon_s)
            } else {
                None
            };
            let pre: &[(usize, f64)] = next
                .and_then(|k| table.segment_ach.get(k))
                .map_or(&[], |v| v.as_slice());
            let (memory, dt_max) = cfg.budget.current(motion.still_s());
            let p = plan(&PlanInput {
                items: &items,
                have: &have,
                downloading: &downloading,
                ach,
                live: &live,
                prefetch: pre,
                mode,
                memory_bytes: memory,
                dt_max_s: dt_max,
                link: &estimate,
            });
            // Resident parts are in use: pin them for this frame.
            for k in pinned.drain(..) {
                cache.release(&k);
            }
            for &(i, _, resident) in &p.targets {
                for part in &table.items[i].parts[..resident] {
                    if cache.acquire(&part.key) {
                        pinned.push(part.key.clone());
                    }
                }
            }
            for r in p.requests.iter().take(free) {
                issue.push((r.item, vec![r.part]));
            }
        }
        for (item, parts) in issue {
            let it = &table.items[item];
            let wanted: Vec<&crate::client::Part> = if parts == [usize::MAX] {
                let mut v = Vec::new();
                if it.info.first_level_part == 1 {
                    v.push(&it.parts[0]);
                }
                v.push(&it.whole);
                v
            } else {
                parts.iter().map(|&p| &it.parts[p]).collect()
            };
            let mut keys = Vec::new();
            let mut size = 0;
            for part in &wanted {
                let data = conn.fetch_checked(&part.key, &part.hash, None).await?;
                size += data.len() as u64;
                keys.push((part.key.clone(), data));
            }
            requests += wanted.len() as u64;
            bytes += size;
            downloading[item] = true;
            in_flight.push(InFlight {
                item,
                keys,
                issued: t,
                arrives: link.schedule(t, size),
                bytes: size,
            });
        }
        max_cache = max_cache.max(cache.used());
        frames.push(FrameRecord {
            t_s: t,
            s_m: s,
            quality,
            needed_fraction: needed,
            complete,
            bytes,
            cache_bytes: cache.used(),
        });
        t += dt;
    }
    let mean = |f: &dyn Fn(&FrameRecord) -> f64| {
        frames.iter().map(f).sum::<f64>() / frames.len().max(1) as f64
    };
    Ok(RunReport {
        strategy: strategy.name(),
        bandwidth_bps: bandwidth,
        time_to_first_frame_s: first_frame,
        mean_needed_fraction: mean(&|f| f.needed_fraction),
        mean_quality: mean(&|f| f.quality),
        bytes,
        bytes_per_m: if length > 0.0 { bytes as f64 / length } else { 0.0 },
        requests,
        checksum_failures: stats.checksum_failures.load(Ordering::Relaxed) - failures_before,
        cache_budget_bytes: cache.budget(),
        max_cache_bytes: max_cache,
        frames,
    })
}

fn surface_item(table: &ItemTable, c: &SurfaceCount) -> Option<usize> {
    match c.surface {
        Surface::Tile { viewpoint, tile } => table.tile_item(viewpoint, tile),
        Surface::Background { viewpoint } => table.background_item(viewpoint),
    }
}

/// `(quality, needed fraction, complete)` of one frame.
fn frame_metrics(
    table: &ItemTable,
    items: &[crate::client::ItemInfo],
    have: &[usize],
    ach: &[(usize, f64)],
    counts: &[SurfaceCount],
) -> (f64, f64, bool) {
    let quality = if ach.is_empty() {
        0.0
    } else {
        ach.iter()
            .map(|&(i, _)| {
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
        total += px;
        // A background the database does not have is never needed.
        let Some(item) = surface_item(table, c) else {
            if matches!(c.surface, Surface::Background { .. }) {
                total -= px;
            } else {
                complete = false;
            }
            continue;
        };
        let level = items[item].level_with(have[item]);
        if level.is_none() {
            complete = false;
        }
        ok += c.satisfied(level);
    }
    let needed = if total > 0.0 { ok / total } else { 1.0 };
    (quality, needed, complete)
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
        let tmp = dir.join(format!("{name}.tmp"));
        std::fs::write(&tmp, data).map_err(|e| err(&tmp, &e))?;
        std::fs::rename(&tmp, &path).map_err(|e| err(&path, &e))
    };
    let json = serde_json::to_vec_pretty(report).map_err(|e| err(dir, &e))?;
    write("walk.json", &json)?;
    let mut csv = String::from("strategy,bandwidth_bps,t_s,s_m,quality,needed_fraction,complete,bytes,cache_bytes\n");
    for r in &report.runs {
        let bw = r.bandwidth_bps.map_or("unlimited".to_string(), |b| b.to_string());
        for f in &r.frames {
            csv += &format!(
                "{},{},{:.3},{:.3},{:.4},{:.4},{},{},{}\n",
                r.strategy, bw, f.t_s, f.s_m, f.quality, f.needed_fraction, f.complete as u8, f.bytes, f.cache_bytes
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
         | bandwidth | strategy | first frame (s) | needed fraction | quality | bytes | bytes/m | checksum failures |\n\
         |---|---|---|---|---|---|---|---|\n",
        r.scene,
        r.track,
        r.length_m,
        r.speed_mps,
        (r.latency_s * 1000.0).round()
    );
    for run in &r.runs {
        s += &format!(
            "| {} | {} | {} | {:.3} | {:.3} | {} | {:.0} | {} |\n",
            run.bandwidth_bps.map_or("unlimited".into(), format_bps),
            run.strategy,
            run.time_to_first_frame_s.map_or("never".into(), |t| format!("{t:.2}")),
            run.mean_needed_fraction,
            run.mean_quality,
            run.bytes,
            run.bytes_per_m,
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
    if b >= 1_000_000 && b % 1_000_000 == 0 {
        format!("{} Mbit/s", b / 1_000_000)
    } else if b >= 1000 && b % 1000 == 0 {
        format!("{} kbit/s", b / 1000)
    } else {
        format!("{b} bit/s")
    }
}
