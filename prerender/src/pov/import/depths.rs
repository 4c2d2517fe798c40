//! Depth cube maps from free positions along the track (for culling and its oracle): depth
//! passes only, several POV-Ray runs at a time.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use glam::DVec3;
use tracks::CubeMap;

use super::{remove, to_cube, PovImport};
use crate::pov::decode::{self, FogScales};
use crate::pov::frame::BlockLayout;
use crate::pov::runner::{RenderJob, RenderStats};
use crate::pov::sdl::PassKind;
use crate::pov::PovError;

/// Most POV-Ray runs at a time for depth renders.
pub const MAX_PARALLEL_RUNS: usize = 16;

/// Most pixels one depth render of several positions traces (its 16-bit image is 6 bytes a
/// pixel, decoded whole).
pub const MAX_BLOCK_PIXELS: u64 = 1 << 23;

/// Whether `p` is seen from the witness at `w` whose radial depth is `depth`: the nearest
/// 3×3 pixels in `p`'s direction all show surfaces past `p` (or `p` is `w`).
fn sees(w: DVec3, depth: &CubeMap<f32>, p: DVec3) -> bool {
    let v = p - w;
    let dist = v.length();
    if dist <= 1e-9 {
        return true;
    }
    let Some(fc) = tracks::cubemap::FaceCoord::from_dir(v) else {
        return false;
    };
    let n = depth.face_size();
    let (x, y) = fc.to_pixel(n);
    let reach = dist * (1.0 + 1e-6) + 1e-6;
    (-1i64..=1).all(|dy| {
        (-1i64..=1).all(|dx| {
            let xx = (x as i64 + dx).clamp(0, n as i64 - 1) as u32;
            let yy = (y as i64 + dy).clamp(0, n as i64 - 1) as u32;
            *depth.get(fc.face, xx, yy) as f64 > reach
        })
    })
}

/// How many positions one depth render holds at `face_size`: as many as
/// [`MAX_BLOCK_PIXELS`] allows, at least one.
pub fn positions_per_run(face_size: u32) -> usize {
    let per = face_size as u64 * BlockLayout::rows_per_position(face_size) as u64;
    (MAX_BLOCK_PIXELS / per.max(1)).max(1) as usize
}

/// What [`PovImport::render_depths`] renders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthRequest {
    /// Pixels a face side.
    pub face_size: u32,
    /// Nearest and farthest depth expected (the fog scales are chosen for them; farther
    /// surfaces still decode, up to about 20 times `farthest`).
    pub nearest: f64,
    pub farthest: f64,
    /// Whether the scene's own fog shows (a fog-only pass is rendered and subtracted).
    pub fog: bool,
}

impl PovImport {
    /// Radial depth cube maps (`+inf` where nothing is hit) seen from `positions` (railview
    /// frame): one depth pass each (two with fog), no colour, no low-resolution pass. `None`
    /// for a position inside or on a solid (most of its pixels are no valid depth code or
    /// at distance 0: a track passing through an object), which sees nothing.
    ///
    /// A POV-Ray run spends about a second starting and parsing the scene however little it
    /// traces, so the positions share runs: each run renders many positions at once
    /// ([`BlockLayout`], at most 2^23 pixels a run), with at least as many runs as cores.
    /// Results come back in the order of `positions`; one record a run, under the index of
    /// its first position.
    ///
    /// Which objects a ray starts inside (which turns fog, and so the depth code, on or off)
    /// POV-Ray 3.7 decides once per render thread, from the thread's first ray. So positions
    /// share a run only when each is *seen* from the same witness (a reference viewpoint,
    /// rendered fine, with its radial depth): the straight line from the witness to the
    /// position crosses no surface, so the position lies inside exactly the objects the
    /// witness does. The depth at the nearest 3×3 pixels of the witness's map must lie past
    /// the position; an occluder thinner than the map's pixels could slip through, as for
    /// every render. Every other position gets a run of its own.
    pub fn render_depths(
        &mut self,
        positions: &[DVec3],
        req: DepthRequest,
        witnesses: &[(DVec3, &CubeMap<f32>)],
    ) -> Result<Vec<Option<CubeMap<f32>>>, PovError> {
        if req.face_size == 0 || req.face_size > tracks::limits::MAX_FACE_SIZE {
            return Err(PovError::Parameter {
                name: "face-size",
                message: format!(
                    "depth renders need 1 to {} pixels a face side, found {}",
                    tracks::limits::MAX_FACE_SIZE,
                    req.face_size
                ),
            });
        }
        let k = if req.fog { 0.5 } else { 1.0 };
        let scales = FogScales::for_range(req.nearest, req.farthest, k);
        // Positions grouped by the first witness that sees them, each group in balanced runs:
        // as few as the image size allows, but at least one per core (a run parses the scene
        // on one thread while another traces). A position no witness sees runs alone.
        let mut groups: Vec<Vec<usize>> = vec![Vec::new(); witnesses.len()];
        let mut chunks: Vec<Vec<usize>> = Vec::new();
        for (i, &p) in positions.iter().enumerate() {
            match witnesses.iter().position(|(w, d)| sees(*w, d, p)) {
                Some(g) => groups[g].push(i),
                None => chunks.push(vec![i]),
            }
        }
        let per_run = positions_per_run(req.face_size);
        let cores = std::thread::available_parallelism().map_or(2, |c| c.get());
        for g in groups.iter().filter(|g| !g.is_empty()) {
            let n = g.len();
            let runs = n.div_ceil(per_run).max(n.min(cores));
            for r in 0..runs {
                chunks.push(g[r * n / runs..(r + 1) * n / runs].to_vec());
            }
        }
        // Every job first (the wrappers are written once), then the runs.
        let mut jobs: Vec<(usize, &'static str, RenderJob)> = Vec::new();
        for (c, chunk) in chunks.iter().enumerate() {
            self.depth_renders += 1;
            let stem = format!("d{:06}", self.depth_renders);
            let pov: Vec<DVec3> = chunk
                .iter()
                .map(|&i| self.opts.up.pov_from_railview(positions[i]))
                .collect();
            if req.fog {
                let fog_stem = format!("{stem}_depth-fog");
                let job =
                    self.block_job(&fog_stem, PassKind::FogOnly, req.face_size, &pov, None)?;
                jobs.push((c, "free-depth-fog", job));
            }
            let job = self.block_job(
                &format!("{stem}_depth"),
                PassKind::Depth,
                req.face_size,
                &pov,
                Some(&scales),
            )?;
            jobs.push((c, "free-depth", job));
        }
        let only: Vec<RenderJob> = jobs.iter().map(|(_, _, j)| j.clone()).collect();
        let stats = self.run_parallel(&only)?;
        let mut out: Vec<Option<CubeMap<f32>>> = vec![None; positions.len()];
        let mut fog_px: Option<Vec<Vec<[u16; 3]>>> = None;
        for ((c, pass, job), st) in jobs.iter().zip(stats) {
            let chunk = &chunks[*c];
            self.record(chunk[0], pass, req.face_size, job, st)?;
            let layout = BlockLayout::new(req.face_size, chunk.len() as u32);
            let px = decode::read_block_png16(&job.output, &layout)?;
            remove(&job.output)?;
            remove(&job.wrapper)?;
            if *pass == "free-depth-fog" {
                fog_px = Some(px);
                continue;
            }
            let fog = fog_px.take();
            for (k, (px, &i)) in px.iter().zip(chunk).enumerate() {
                let decoded =
                    decode::decode_fog(px, fog.as_ref().map(|f| f[k].as_slice()), &scales);
                let inside =
                    decoded.inconsistent * 20 > decoded.hits.max(1) || decoded.zero * 2 > px.len();
                if !inside {
                    out[i] = Some(to_cube(req.face_size, &decoded.t, |t| t)?);
                }
            }
        }
        Ok(out)
    }

    /// Run `jobs` with several POV-Ray processes at a time (up to twice the cores, at most
    /// [`MAX_PARALLEL_RUNS`]); their statistics in order. The first failure is returned
    /// once the runs under way have finished.
    pub(super) fn run_parallel(&self, jobs: &[RenderJob]) -> Result<Vec<RenderStats>, PovError> {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        let workers = (2 * cores).clamp(1, MAX_PARALLEL_RUNS).min(jobs.len());
        let next = AtomicUsize::new(0);
        let results: Mutex<Vec<Option<Result<RenderStats, PovError>>>> =
            Mutex::new((0..jobs.len()).map(|_| None).collect());
        let failed = std::sync::atomic::AtomicBool::new(false);
        let povray = &self.povray;
        std::thread::scope(|scope| {
            for _ in 0..workers {
                scope.spawn(|| loop {
                    if failed.load(Ordering::Relaxed) {
                        break;
                    }
                    let j = next.fetch_add(1, Ordering::Relaxed);
                    let Some(job) = jobs.get(j) else {
                        break;
                    };
                    let r = povray.run(job);
                    if r.is_err() {
                        failed.store(true, Ordering::Relaxed);
                    }
                    if let Ok(mut all) = results.lock() {
                        all[j] = Some(r);
                    }
                });
            }
        });
        let all = results.into_inner().unwrap_or_default();
        let mut out = Vec::with_capacity(jobs.len());
        for (r, job) in all.into_iter().zip(jobs) {
            match r {
                Some(r) => out.push(r?),
                None => {
                    return Err(PovError::Parameter {
                        name: "depth renders",
                        message: format!("{} was not run (an earlier run failed)", job.name),
                    })
                }
            }
        }
        Ok(out)
    }
}
