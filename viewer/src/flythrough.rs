//! `railview flythrough` as a typed stage: frames along a whole track, looking along it,
//! drawn headless as the window shows them ([`FlythroughParams`] → [`run`] →
//! `frame_NNNN.png` and `flythrough.json`).
//!
//! ```no_run
//! use viewer::flythrough::{self, FlythroughParams};
//! let params = FlythroughParams::new("db", "frames".into());
//! let report = flythrough::run(&params, |_| {})?;
//! println!("mean frame {:.2} ms", report.mean_frame_ms());
//! # Ok::<(), viewer::eval::stage::StageError>(())
//! ```

use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::eval::stage::StageError;
use crate::gpu::{Gpu, Renderer};
use crate::headless::{open, yaw_along};
use crate::plan::DrawBudget;
use crate::source::LoadOptions;

/// Everything a flythrough needs.
#[derive(Clone, Debug, PartialEq)]
pub struct FlythroughParams {
    /// A database or prerender directory, or `synth:street` (what
    /// [`crate::headless::open`] takes).
    pub db: String,
    /// Output directory for `frame_NNNN.png` and `flythrough.json`.
    pub out: PathBuf,
    /// Frames from the start to the end of the track (1 to 100 000).
    pub frames: usize,
    /// Image size, pixels.
    pub size: (u32, u32),
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
    /// Track name (`None`: the first).
    pub track: Option<String>,
}

impl FlythroughParams {
    /// A flythrough of `db` into `out` with `railview flythrough`'s defaults: 60 frames of
    /// 640×360 at 90°, the first track.
    pub fn new(db: impl Into<String>, out: PathBuf) -> FlythroughParams {
        FlythroughParams {
            db: db.into(),
            out,
            frames: 60,
            size: (640, 360),
            fov_deg: 90.0,
            track: None,
        }
    }
}

/// One frame of `flythrough.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameInfo {
    pub frame: usize,
    /// Arc length along the track, metres.
    pub position: f64,
    /// Plan and draw, no readback, milliseconds.
    pub frame_ms: f64,
    pub hole_fraction: f64,
}

/// What a flythrough drew.
#[derive(Clone, Debug, PartialEq)]
pub struct FlythroughReport {
    pub frames: Vec<FrameInfo>,
    /// The adapter the frames were drawn on.
    pub adapter: String,
}

impl FlythroughReport {
    /// The mean frame time, milliseconds (NaN without frames).
    pub fn mean_frame_ms(&self) -> f64 {
        self.frames.iter().map(|f| f.frame_ms).sum::<f64>() / self.frames.len() as f64
    }
}

/// Draw the frames and write them with `flythrough.json`; `progress` is called after each
/// frame.
pub fn run(
    params: &FlythroughParams,
    mut progress: impl FnMut(&FrameInfo),
) -> Result<FlythroughReport, StageError> {
    let (w, h) = params.size;
    if ![w, h].iter().all(|v| (1..=16384).contains(v)) {
        return Err(StageError::Parameter(format!(
            "size `{w}x{h}`: expected sides in 1..=16384"
        )));
    }
    let frames = params.frames;
    tracks::limits::check_u64("--frames", frames as u64, 1, 100_000)?;
    let db = &params.db;
    let walk = open(db, params.track.as_deref(), LoadOptions::default())
        .map_err(|e| StageError::from(e).context(format!("opening {db}")))?;
    prerender::store::ensure_writable_dir(&params.out)?;
    let mut renderer = Renderer::new(Gpu::new()?)?;
    let len = walk.track.length();
    let mut infos = Vec::new();
    for i in 0..frames {
        let s = if frames == 1 {
            0.0
        } else {
            len * i as f64 / (frames - 1) as f64
        };
        let camera = tracks::PerspectiveCamera {
            position: walk.position_at(s),
            yaw_deg: yaw_along(&walk, s),
            pitch_deg: 0.0,
            fov_deg: params.fov_deg,
            width: w,
            height: h,
        };
        let t0 = Instant::now();
        let mut plan = walk.plan(&camera, s, DrawBudget::default())?;
        // As the window shows it between feedback frames (no tile ids: fused passes).
        plan.tile_ids = false;
        renderer.draw(&plan, &walk.views)?;
        let frame_ms = t0.elapsed().as_secs_f64() * 1e3;
        let frame = renderer.read_output()?;
        let png = params.out.join(format!("frame_{i:04}.png"));
        prerender::store::write_atomic(&png, &frame.png()?)?;
        let info = FrameInfo {
            frame: i,
            position: s,
            frame_ms,
            hole_fraction: frame.hole_fraction(),
        };
        progress(&info);
        infos.push(info);
    }
    prerender::store::write_json(&params.out.join("flythrough.json"), &infos)?;
    Ok(FlythroughReport {
        frames: infos,
        adapter: renderer.gpu.describe(),
    })
}
