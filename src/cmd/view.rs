//! `railview view`: the interactive viewer window.

use anyhow::Context;
use viewer::headless::open;
use viewer::source::LoadOptions;

/// Arguments of `railview view`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory, or `synth:street`.
    pub db: String,
    #[arg(long)]
    pub track: Option<String>,
    /// Close after this many frames (smoke tests, screenshots).
    #[arg(long)]
    pub frames: Option<u64>,
    /// With --frames: save a screenshot of the window (PNG) just before closing.
    #[arg(long)]
    pub screenshot: Option<std::path::PathBuf>,
    /// Start walking along the track at once (as the demo does).
    #[arg(long)]
    pub play: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        !(args.db.starts_with("http://") || args.db.starts_with("https://")),
        "{}: streaming from `railview serve` is not wired into the viewer yet; open the database directory",
        args.db
    );
    let walk = open(&args.db, args.track.as_deref(), LoadOptions::default())
        .with_context(|| format!("opening {}", args.db))?;
    viewer::app::run(walk, args.frames, args.screenshot, args.play)
        .map_err(|e| anyhow::anyhow!("viewer window: {e}"))
}
