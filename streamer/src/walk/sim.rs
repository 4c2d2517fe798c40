//! One simulated run: virtual clock, event-driven downloads, per-frame metrics.

use std::sync::atomic::Ordering;

use bytes::Bytes;
use tracks::PerspectiveCamera;

use super::{look_at, FrameRecord, RunReport, Scene, Strategy, VirtualLink, WalkConfig, WalkError};
use crate::client::{
    next_segment, plan, segment_at, Cache, ClientStats, Connection, FetchKey, ItemInfo, ItemTable,
    LinkEstimate, LiveCount, MotionTracker, Part, PlanInput, PriorityMode,
};
use crate::visibility::{blend_weights, Surface, SurfaceCount};

struct InFlight {
    item: usize,
    keys: Vec<(FetchKey, Bytes)>,
    issued: f64,
    arrives: f64,
    bytes: u64,
}

struct Sim<'a> {
    scene: &'a Scene,
    cfg: &'a WalkConfig,
    strategy: Strategy,
    items: Vec<ItemInfo>,
    cache: Cache,
    link: VirtualLink,
    estimate: LinkEstimate,
    motion: MotionTracker,
    in_flight: Vec<InFlight>,
    downloading: Vec<bool>,
    naive_next: usize,
    pinned: Vec<FetchKey>,
    bytes: u64,
    requests: u64,
    /// Largest texture memory the plan held resident, and whether it ever exceeded `M`.
    max_resident: u64,
    over_budget: bool,
    /// Live counts of the latest frame (used again between frames).
    live: Vec<LiveCount>,
    /// The current segment's ACH list after frustum culling at the latest frame's camera
    /// (PTM §6.1: only tiles that can be in view share the budget).
    view_ach: Vec<(usize, f64)>,
    s: f64,
}

impl Sim<'_> {
    fn table(&self) -> &ItemTable {
        &self.scene.table
    }

    /// Deliver everything that has arrived by `t`.
    fn deliver(&mut self, t: f64) {
        let (arrived, pending): (Vec<_>, Vec<_>) = std::mem::take(&mut self.in_flight)
            .into_iter()
            .partition(|f| f.arrives <= t + 1e-9);
        self.in_flight = pending;
        for f in arrived {
            self.downloading[f.item] = false;
            self.estimate.observe(f.bytes, f.arrives - f.issued);
            let s_item = self.scene.table.items[f.item].s;
            for (key, data) in f.keys {
                // Refused when the budget is full of data in use: dropped, asked again later.
                let _ = self.cache.insert(key, data, s_item);
            }
        }
    }

    /// Parts held per item (a prefix; naive: all or nothing).
    fn have(&self) -> Vec<usize> {
        let naive = self.strategy == Strategy::Naive;
        self.table()
            .items
            .iter()
            .map(|it| {
                if naive {
                    let mesh_ok =
                        it.info.first_level_part == 0 || self.cache.contains(&it.parts[0].key);
                    if mesh_ok && self.cache.contains(&it.whole.key) {
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
            .collect()
    }

    /// Decide and issue downloads at time `t` (fetching the bytes for real).
    async fn issue(&mut self, conn: &mut Connection, t: f64) -> Result<(), WalkError> {
        let free = self
            .cfg
            .max_in_flight
            .max(1)
            .saturating_sub(self.in_flight.len());
        if free == 0 {
            return Ok(());
        }
        let n = self.items.len();
        let mut issue: Vec<(usize, Vec<Part>)> = Vec::new();
        match self.strategy {
            Strategy::Naive => {
                while issue.len() < free && self.naive_next < n {
                    let it = &self.scene.table.items[self.naive_next];
                    let mut v = Vec::new();
                    if it.info.first_level_part == 1 {
                        v.push(it.parts[0].clone());
                    }
                    v.push(it.whole.clone());
                    issue.push((self.naive_next, v));
                    self.naive_next += 1;
                }
            }
            Strategy::Budget { mode, prefetch } => {
                let have = self.have();
                let table = &self.scene.table;
                let seg = segment_at(&table.vp_s, self.s).unwrap_or(0);
                let ach: &[(usize, f64)] = match mode {
                    // Combined: the whole segment's ACH broadens (coarsest levels for a turn
                    // of the head); live counts pick what is in view.
                    PriorityMode::Combined { .. } => {
                        table.segment_ach.get(seg).map_or(&[], |v| v.as_slice())
                    }
                    _ => &self.view_ach,
                };
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
                let pre: &[(usize, f64)] = next
                    .and_then(|k| table.segment_ach.get(k))
                    .map_or(&[], |v| v.as_slice());
                let (memory, dt_max) = self.cfg.budget.current(self.motion.still_s());
                let p = plan(&PlanInput {
                    items: &self.items,
                    have: &have,
                    downloading: &self.downloading,
                    ach,
                    live: &self.live,
                    prefetch: pre,
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
                for r in p.requests.iter().take(free) {
                    let parts = &table.items[r.item].parts;
                    let end = (r.part + r.parts.max(1)).min(parts.len());
                    issue.push((r.item, parts[r.part..end].to_vec()));
                }
            }
        }
        for (item, parts) in issue {
            let mut keys = Vec::new();
            let mut size = 0;
            if let Some(run) = as_run(&parts) {
                // Consecutive level groups of one object: one ranged request.
                let data = conn
                    .fetch_checked_run(&parts[0].key.object, &run, None)
                    .await?;
                for (part, d) in parts.iter().zip(data) {
                    size += d.len() as u64;
                    keys.push((part.key.clone(), d));
                }
                self.requests += 1;
            } else {
                for part in &parts {
                    let data = conn.fetch_checked(&part.key, &part.hash, None).await?;
                    size += data.len() as u64;
                    keys.push((part.key.clone(), data));
                }
                self.requests += parts.len() as u64;
            }
            self.bytes += size;
            self.downloading[item] = true;
            self.in_flight.push(InFlight {
                item,
                keys,
                issued: t,
                arrives: self.link.schedule(t, size),
                bytes: size,
            });
        }
        Ok(())
    }
}

/// `(offset, len, hash)` of each part when there are several and they are consecutive byte
/// ranges of one object (so one request can carry them all).
fn as_run(parts: &[Part]) -> Option<Vec<(u64, u64, &str)>> {
    if parts.len() < 2 {
        return None;
    }
    let mut out = Vec::with_capacity(parts.len());
    for p in parts {
        let (off, len) = p.key.range?;
        if p.key.object != parts[0].key.object {
            return None;
        }
        if let Some(&(o, l, _)) = out.last() {
            if o + l != off {
                return None;
            }
        }
        out.push((off, len, p.hash.as_str()));
    }
    Some(out)
}

/// Run one (strategy, bandwidth) walk.
pub(crate) async fn run_one(
    conn: &mut Connection,
    stats: &ClientStats,
    scene: &Scene,
    cfg: &WalkConfig,
    strategy: Strategy,
    bandwidth: Option<u64>,
) -> Result<RunReport, WalkError> {
    let items = scene.table.infos();
    let n = items.len();
    let naive = strategy == Strategy::Naive;
    let mut sim = Sim {
        scene,
        cfg,
        strategy,
        items,
        cache: Cache::new(if naive { u64::MAX } else { cfg.cache_bytes }),
        link: VirtualLink::new(bandwidth, cfg.latency_s),
        estimate: LinkEstimate::new(bandwidth.map_or(1e9, |b| b as f64), cfg.latency_s),
        motion: MotionTracker::new(),
        in_flight: Vec::new(),
        downloading: vec![false; n],
        naive_next: 0,
        pinned: Vec::new(),
        bytes: 0,
        requests: 0,
        max_resident: 0,
        over_budget: false,
        live: Vec::new(),
        view_ach: Vec::new(),
        s: 0.0,
    };
    let failures_before = stats.checksum_failures.load(Ordering::Relaxed);
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
        let weights = blend_weights(&scene.table.vp_s, s);
        let counts = scene
            .index
            .count(&cam, &weights, cfg.samples_x, cfg.samples_y);
        sim.live = counts
            .iter()
            .filter_map(|c| {
                Some(LiveCount {
                    item: surface_item(&scene.table, c)?,
                    pixels: c.pixels(),
                    needed_level: c.finest_needed(),
                })
            })
            .collect();
        let have = sim.have();
        let seg = segment_at(&scene.table.vp_s, s).unwrap_or(0);
        let ach: &[(usize, f64)] = scene
            .table
            .segment_ach
            .get(seg)
            .map_or(&[], |v| v.as_slice());
        sim.view_ach = ach
            .iter()
            .copied()
            .filter(|&(i, _)| {
                let it = &scene.table.items[i];
                it.tile
                    .is_none_or(|tile| scene.index.tile_in_frustum(&cam, it.viewpoint, tile))
            })
            .collect();
        let (quality, needed, complete) =
            frame_metrics(&scene.table, &sim.items, &have, ach, &counts);
        if complete && first_frame.is_none() {
            first_frame = Some(t);
        }
        sim.issue(conn, t).await?;
        max_cache = max_cache.max(sim.cache.used());
        frames.push(FrameRecord {
            t_s: t,
            s_m: s,
            quality,
            needed_fraction: needed,
            complete,
            bytes: sim.bytes,
            cache_bytes: sim.cache.used(),
        });
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
            sim.issue(conn, te).await?;
            max_cache = max_cache.max(sim.cache.used());
        }
        k += 1;
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
    items: &[ItemInfo],
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
        let Some(item) = surface_item(table, c) else {
            // A background the database does not have is never needed.
            if !matches!(c.surface, Surface::Background { .. }) {
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
