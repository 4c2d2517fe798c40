//! Depth cube maps from free positions along the track (for culling and its oracle): depth
//! passes only, several POV-Ray runs at a time.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use glam::DVec3;
use tracks::CubeMap;

use super::{remove, to_cube, PovImport, View};
use crate::pov::decode::{self, FogScales};
use crate::pov::frame::MeshLayout;
use crate::pov::runner::{RenderJob, RenderStats};
use crate::pov::sdl::PassKind;
use crate::pov::PovError;

/// Most POV-Ray runs at a time for depth renders.
pub const MAX_PARALLEL_RUNS: usize = 16;

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
    /// A short POV-Ray run spends most of its time starting and waiting rather than
    /// computing, so up to twice as many runs as there are cores go at a time (at most
    /// [`MAX_PARALLEL_RUNS`]); results and records come back in the order of `positions`.
    pub fn render_depths(
        &mut self,
        positions: &[DVec3],
        req: DepthRequest,
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
        // Every job first (the wrappers are written once), then the runs.
        let mut jobs: Vec<(usize, &'static str, RenderJob)> = Vec::new();
        for (i, &p) in positions.iter().enumerate() {
            self.depth_renders += 1;
            let stem = format!("d{:06}", self.depth_renders);
            let view = View {
                pov: self.opts.up.pov_from_railview(p),
                near: 0.0,
                range: 0.0,
            };
            if req.fog {
                let fog_stem = format!("{stem}_depth-fog");
                let job = self.job(&fog_stem, PassKind::FogOnly, req.face_size, view, None)?;
                jobs.push((i, "free-depth-fog", job));
            }
            let job = self.job(
                &format!("{stem}_depth"),
                PassKind::Depth,
                req.face_size,
                view,
                Some(&scales),
            )?;
            jobs.push((i, "free-depth", job));
        }
        let only: Vec<RenderJob> = jobs.iter().map(|(_, _, j)| j.clone()).collect();
        let stats = self.run_parallel(&only)?;
        let layout = MeshLayout::new(req.face_size);
        let mut out = Vec::with_capacity(positions.len());
        let mut fog_px: Option<Vec<[u16; 3]>> = None;
        for ((i, pass, job), st) in jobs.iter().zip(stats) {
            self.record(*i, pass, req.face_size, job, st)?;
            let px = decode::read_mesh_png16(&job.output, &layout)?;
            remove(&job.output)?;
            if *pass == "free-depth-fog" {
                fog_px = Some(px);
                continue;
            }
            let decoded = decode::decode_fog(&px, fog_px.take().as_deref(), &scales);
            let inside =
                decoded.inconsistent * 20 > decoded.hits.max(1) || decoded.zero * 2 > px.len();
            out.push(match inside {
                true => None,
                false => Some(to_cube(req.face_size, &decoded.t, |t| t)?),
            });
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
