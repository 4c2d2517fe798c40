//! `railview render`: one reconstructed view from a walkthrough, headless.

use std::path::PathBuf;

use anyhow::Context;
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{open, parse_size, yaw_along};
use viewer::source::LoadOptions;
use viewer::{plan_frame, DrawBudget};

/// Arguments of `railview render`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory, or `synth:street`.
    pub db: String,
    /// Arc length along the track, metres.
    #[arg(long, default_value_t = 0.0)]
    pub at: f64,
    /// Yaw in degrees (0 looks along −z, 90 along +x); default: along the track.
    #[arg(long)]
    pub yaw: Option<f64>,
    /// Pitch in degrees (positive looks up).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub pitch: f64,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Output PNG (RGBA; alpha 0 marks holes).
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Track name (default: the first).
    #[arg(long)]
    pub track: Option<String>,
    /// Draw at most this many slabs per view.
    #[arg(long)]
    pub max_slabs: Option<usize>,
    /// Draw only the nearer reference view.
    #[arg(long)]
    pub no_blend: bool,
    /// Also write the ground truth from the same camera here (built-in scenes, synth:street).
    #[arg(long)]
    pub truth: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    let walk = open(&args.db, args.track.as_deref(), LoadOptions::default())
        .with_context(|| format!("opening {}", args.db))?;
    let camera = tracks::PerspectiveCamera {
        position: walk.position_at(args.at),
        yaw_deg: args.yaw.unwrap_or_else(|| yaw_along(&walk, args.at)),
        pitch_deg: args.pitch,
        fov_deg: args.fov,
        width: w,
        height: h,
    };
    let budget = DrawBudget {
        max_slabs: args.max_slabs.unwrap_or(usize::MAX),
        blend: !args.no_blend,
        ..Default::default()
    };
    let mut plan = plan_frame(&walk.views, &camera, args.at, budget)?;
    // The frame as the window shows it between feedback frames (no tile ids: fused passes).
    plan.tile_ids = false;
    let mut renderer = Renderer::new(Gpu::new()?);
    let frame = renderer.render(&plan, &walk.views)?;
    save_png(&args.output, &frame)?;
    if let Some(path) = &args.truth {
        let truth = viewer::headless::Truth::for_scene(&walk.scene)
            .with_context(|| format!("no ground truth for scene `{}`", walk.scene))?;
        let rgb = truth.render(&camera);
        let gt = viewer::gpu::Frame {
            width: w,
            height: h,
            rgba: rgb.iter().flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        };
        save_png(path, &gt)?;
        let (got, _) = viewer::metrics::split_rgba(&frame.rgba);
        eprintln!(
            "PSNR against the ground truth: {:.2} dB",
            viewer::metrics::psnr(&got, &rgb)
        );
    }
    eprintln!(
        "{}: {}x{} at s = {} m, holes {:.4} %, adapter {}",
        args.output.display(),
        w,
        h,
        args.at,
        frame.hole_fraction() * 100.0,
        renderer.gpu.info.name
    );
    Ok(())
}

/// Write a frame as PNG atomically (temporary file + rename).
pub fn save_png(path: &std::path::Path, frame: &viewer::gpu::Frame) -> anyhow::Result<()> {
    let img = image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
        .context("frame buffer size")?;
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )?;
    prerender::store::write_atomic(path, &bytes)?;
    Ok(())
}
