//! `railview flythrough`: frames along the whole track, looking along it, headless.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{open, parse_size, yaw_along};
use viewer::source::LoadOptions;
use viewer::DrawBudget;

/// Arguments of `railview flythrough`.
#[derive(clap::Args, Clone)]
pub struct Args {
    /// Database or prerender directory, or `synth:street`.
    pub db: String,
    /// Output directory for `frame_NNNN.png` and `flythrough.json`.
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Number of frames from the start to the end of the track.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Image size WxH.
    #[arg(long, default_value = "640x360")]
    pub size: String,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Track name (default: the first).
    #[arg(long)]
    pub track: Option<String>,
}

#[derive(serde::Serialize)]
struct FrameInfo {
    frame: usize,
    position: f64,
    frame_ms: f64,
    hole_fraction: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    super::count("--frames", args.frames, 100_000)?;
    let walk = open(&args.db, args.track.as_deref(), LoadOptions::default())
        .with_context(|| format!("opening {}", args.db))?;
    prerender::store::ensure_writable_dir(&args.output)?;
    let mut renderer = Renderer::new(Gpu::new()?)?;
    let len = walk.track.length();
    let bar = indicatif::ProgressBar::new(args.frames as u64);
    let mut infos = Vec::new();
    for i in 0..args.frames {
        let s = if args.frames == 1 {
            0.0
        } else {
            len * i as f64 / (args.frames - 1) as f64
        };
        let camera = tracks::PerspectiveCamera {
            position: walk.position_at(s),
            yaw_deg: yaw_along(&walk, s),
            pitch_deg: 0.0,
            fov_deg: args.fov,
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
        super::render::save_png(&args.output.join(format!("frame_{i:04}.png")), &frame)?;
        infos.push(FrameInfo {
            frame: i,
            position: s,
            frame_ms,
            hole_fraction: frame.hole_fraction(),
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    prerender::store::write_json(&args.output.join("flythrough.json"), &infos)?;
    let mean = infos.iter().map(|f| f.frame_ms).sum::<f64>() / infos.len() as f64;
    eprintln!(
        "{} frames in {}, mean frame {mean:.2} ms, adapter {}",
        infos.len(),
        args.output.display(),
        renderer.gpu.describe()
    );
    Ok(())
}
