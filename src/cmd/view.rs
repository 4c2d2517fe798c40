//! `railview view SOURCE`: the interactive viewer window, on a directory (decoded up front) or
//! on `railview serve`'s URL (streamed while shown).

use anyhow::Context;
use streamer::client::LiveConfig;
use viewer::app::{Source, Strategy, WindowOptions};
use viewer::headless::open;
use viewer::source::LoadOptions;
use viewer::stream::StreamedWalkthrough;

/// Arguments of `railview view`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory, `synth:street`, or a server URL
    /// (`http://127.0.0.1:8080`, as `railview serve` prints).
    pub db: String,
    /// Track name (default: the first).
    #[arg(long)]
    pub track: Option<String>,
    /// Close after this many frames (smoke tests, screenshots, measurements): prints the
    /// frame-to-frame intervals (median, 95th percentile, longest), what the frame-time
    /// budget drew at the end and the view's size in pixels.
    #[arg(long)]
    pub frames: Option<u64>,
    /// With --frames: save a screenshot of the window (PNG) just before closing.
    #[arg(long)]
    pub screenshot: Option<std::path::PathBuf>,
    /// Start walking along the track at once (as the demo does).
    #[arg(long)]
    pub play: bool,
    /// Streaming: where download priorities come from — `ach` (the segment's average
    /// coverage hints), `visibility` (visible pixels per tile, from the GPU), or `both`.
    #[arg(long, default_value = "both")]
    pub strategy: String,
    /// Streaming: do not prefetch the next segment.
    #[arg(long)]
    pub no_prefetch: bool,
    /// Streaming: cache budget for downloaded bytes, MiB.
    #[arg(long, default_value_t = 64.0, allow_negative_numbers = true)]
    pub memory_mib: f64,
    /// Streaming: downloads in flight at most.
    #[arg(long, default_value_t = 6)]
    pub requests: usize,
    /// Frame rate the frame-time budget holds by drawing less (a slider in the window too):
    /// the second view at half resolution, the view at 3/4 and 1/2 of its size, coarser
    /// textures, coarser meshes, one view, fewer slabs, in that order.
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    pub target_fps: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let strategy = Strategy::parse(&args.strategy).with_context(|| {
        format!(
            "--strategy `{}`: expected ach, visibility or both",
            args.strategy
        )
    })?;
    anyhow::ensure!(
        args.memory_mib.is_finite() && args.memory_mib > 0.0 && args.memory_mib <= 1048576.0,
        "--memory-mib {}: must be a positive number of MiB, at most 1048576",
        args.memory_mib
    );
    tracks::limits::check_u64("--requests", args.requests as u64, 1, 64)?;
    anyhow::ensure!(
        args.target_fps.is_finite() && (1.0..=1000.0).contains(&args.target_fps),
        "--target-fps {}: must be between 1 and 1000",
        args.target_fps
    );
    let source = if args.db.starts_with("http://") || args.db.starts_with("https://") {
        let mut config = LiveConfig::with_cache((args.memory_mib * 1048576.0) as u64);
        config.mode = strategy.mode();
        config.prefetch = !args.no_prefetch;
        config.fetcher.max_in_flight = args.requests;
        let stream = StreamedWalkthrough::connect(&args.db, args.track.as_deref(), config)
            .with_context(|| format!("connecting to {}", args.db))?;
        Source::Stream(Box::new(stream))
    } else {
        let walk = open(&args.db, args.track.as_deref(), LoadOptions::default())
            .with_context(|| format!("opening {}", args.db))?;
        Source::Local(walk)
    };
    let opts = WindowOptions {
        quit_after: args.frames,
        screenshot: args.screenshot,
        play: args.play,
        started,
        target_fps: args.target_fps,
    };
    viewer::app::run(source, opts).map_err(anyhow::Error::from)
}
