//! `railview view SOURCE`: the interactive viewer window, streamed while shown from a server
//! URL or a database directory (the same client over local files, within the same memory
//! budget); a prerender directory or `synth:street` is decoded up front.

use anyhow::Context;
use streamer::client::LiveConfig;
use viewer::app::{Source, Strategy, WindowOptions};
use viewer::headless::open;
use viewer::source::LoadOptions;
use viewer::stream::StreamedWalkthrough;

/// Arguments of `railview view`.
#[derive(clap::Args, Clone)]
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
    /// Memory budget of a streamed database (URL or directory), MiB: a quarter for the
    /// downloaded bytes, the rest for the decoded views (laid out coarser when four of them
    /// do not fit at full resolution).
    #[arg(long, default_value_t = 512.0, allow_negative_numbers = true)]
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
        args.memory_mib.is_finite() && args.memory_mib >= 1.0 && args.memory_mib <= 1048576.0,
        "--memory-mib {}: must be between 1 and 1048576 (1 TiB)",
        args.memory_mib
    );
    tracks::limits::check_u64("--requests", args.requests as u64, 1, 64)?;
    anyhow::ensure!(
        args.target_fps.is_finite() && (1.0..=1000.0).contains(&args.target_fps),
        "--target-fps {}: must be between 1 and 1000",
        args.target_fps
    );
    let streamed = args.db.starts_with("http://")
        || args.db.starts_with("https://")
        || streamer::client::Source::is_database_dir(&args.db);
    let source = if streamed {
        let budget = (args.memory_mib * 1048576.0) as u64;
        let mut config = LiveConfig::with_cache(budget / 4);
        config.schedule.strategy = streamer::client::Strategy::Budget {
            mode: strategy.mode(),
            prefetch: !args.no_prefetch,
        };
        config.schedule.max_in_flight = args.requests;
        let mut stream = StreamedWalkthrough::connect(&args.db, args.track.as_deref(), config)
            .with_context(|| format!("opening {}", args.db))?;
        let level = stream.set_memory_budget(budget - budget / 4);
        if level > 0 {
            eprintln!(
                "railview view: views laid out at PTM level {level} (faces of {} px) to hold \
                 them in --memory-mib {}",
                stream.walk.views.first().map_or(0, |v| v.face_size),
                args.memory_mib
            );
        }
        Source::Stream(Box::new(stream))
    } else {
        let opts = LoadOptions {
            every_track: true,
            ..LoadOptions::default()
        };
        let walk = open(&args.db, args.track.as_deref(), opts)
            .with_context(|| format!("opening {}", args.db))?;
        Source::Local(Box::new(walk))
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
