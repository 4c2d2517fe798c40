//! `railview flythrough`: frames along the whole track, looking along it, headless
//! (`viewer::flythrough`: this module only turns the options into its parameters).

use std::path::PathBuf;

use viewer::flythrough::{self, FlythroughParams};
use viewer::headless::parse_size;

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

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = FlythroughParams {
        db: args.db,
        out: args.output,
        frames: args.frames,
        size: parse_size(&args.size).map_err(anyhow::Error::msg)?,
        fov_deg: args.fov,
        track: args.track,
    };
    run_stage(&params)
}

/// Draw the frames with a progress bar on the terminal; a line on stderr says how fast.
pub fn run_stage(params: &FlythroughParams) -> anyhow::Result<()> {
    let bar = indicatif::ProgressBar::new(params.frames as u64);
    let result = flythrough::run(params, |_| bar.inc(1));
    bar.finish_and_clear();
    let report = result?;
    eprintln!(
        "{} frames in {}, mean frame {:.2} ms, adapter {}",
        report.frames.len(),
        params.out.display(),
        report.mean_frame_ms(),
        report.adapter
    );
    Ok(())
}
