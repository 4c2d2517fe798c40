//! `railview render`: one reconstructed view from a walkthrough, headless.

use std::path::PathBuf;

use anyhow::Context;
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{open, parse_size, yaw_along};
use viewer::source::LoadOptions;
use viewer::DrawBudget;

/// Arguments of `railview render`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory, or `synth:street`.
    pub db: String,
    /// Arc length along the track, metres (0 to the track's length).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub at: f64,
    /// Yaw in degrees (0 looks along −z, 90 along +x); default: along the track.
    #[arg(long, allow_negative_numbers = true)]
    pub yaw: Option<f64>,
    /// Pitch in degrees, −90 to 90 (positive looks up).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub pitch: f64,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Output PNG (RGBA; alpha 0 marks holes); the name must end in `.png`.
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
    /// Also write the ground truth from the same camera here (any scene: built-in, scene
    /// file, POV-Ray import; see `railview eval --prerender`).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Ground truth rays per pixel along each axis (box filter over the pixel).
    #[arg(long, default_value_t = 3)]
    pub truth_supersample: u32,
    /// The prerender directory the database was built from, for its ground truth (default:
    /// DB.work/prerender when it made this database).
    #[arg(long)]
    pub prerender: Option<PathBuf>,
    /// Draw from the first N level groups of every tile's PTM only (coarsest first): what a
    /// streaming client shows before the finer levels arrive. Databases only; default: all.
    #[arg(long)]
    pub level_groups: Option<usize>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    check_png_name(&args.output, "--output")?;
    if let Some(t) = &args.truth {
        check_png_name(t, "--truth")?;
    }
    if let Some(g) = args.level_groups {
        anyhow::ensure!(
            g >= 1,
            "--level-groups {g}: at least 1 (the coarsest group)"
        );
        let is_db = std::path::Path::new(&args.db)
            .join(db::MANIFEST_FILE)
            .is_file();
        anyhow::ensure!(
            is_db,
            "--level-groups: {} is not a database (only databases hold PTM level groups)",
            args.db
        );
    }
    let opts = LoadOptions {
        level_groups: args.level_groups,
        ..Default::default()
    };
    let walk = open(&args.db, args.track.as_deref(), opts)
        .with_context(|| format!("opening {}", args.db))?;
    let len = walk.track.length();
    anyhow::ensure!(
        (0.0..=len).contains(&args.at),
        "--at {}: outside track `{}`, which runs from 0 to {:.3} m",
        args.at,
        walk.track.name,
        len
    );
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
    let mut plan = walk.plan(&camera, args.at, budget)?;
    // The frame as the window shows it between feedback frames (no tile ids: fused passes).
    plan.tile_ids = false;
    let mut renderer = Renderer::new(Gpu::new()?)?;
    let frame = renderer.render(&plan, &walk.views)?;
    save_png(&args.output, &frame)?;
    if let Some(path) = &args.truth {
        anyhow::ensure!(
            (1..=16).contains(&args.truth_supersample),
            "--truth-supersample must be in 1..=16"
        );
        let work = std::env::temp_dir().join(format!("railview-truth-{}", std::process::id()));
        let mut truth = viewer::eval::Truth::for_walkthrough(
            &args.db,
            &walk,
            args.prerender.as_deref(),
            args.truth_supersample,
            &work,
        )?;
        let rgb = truth.render(&camera);
        // Only POV-Ray writes there (wrapper, log): nothing worth keeping once it succeeded.
        std::fs::remove_dir_all(&work).ok();
        let rgb = rgb?;
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
        renderer.gpu.describe()
    );
    Ok(())
}

/// Only PNG is written: a name ending in anything else (`.jpg`, none) is an error, before
/// anything is rendered, rather than PNG bytes under a misleading name.
pub fn check_png_name(path: &std::path::Path, flag: &str) -> anyhow::Result<()> {
    let png = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    anyhow::ensure!(
        png,
        "{flag} {}: only PNG images are written; name the file `.png`",
        path.display()
    );
    Ok(())
}

/// Write a frame as PNG atomically (temporary file + rename).
pub fn save_png(path: &std::path::Path, frame: &viewer::gpu::Frame) -> anyhow::Result<()> {
    prerender::store::write_atomic(path, &frame.png()?)?;
    Ok(())
}
