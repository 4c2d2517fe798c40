//! `railview`: the command line. Parses arguments and calls the crates; each subcommand
//! lives in `src/cmd/<name>.rs` with an `Args` struct and a `run` function.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;
mod progress;

#[derive(Parser)]
#[command(
    name = "railview",
    version,
    about = "Image-based panoramic walkthroughs along tracks"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The whole system on the built-in castle scene in one command, then a report.
    Demo(cmd::demo::Args),
    /// Render cube-map colour, depth (and optionally slab layers) at the reference viewpoints of a track.
    Prerender(cmd::prerender::Args),
    /// Render a POV-Ray scene along a track into the same layout (colour, depth, slab layers).
    ImportPov(cmd::import_pov::Args),
    /// Choose slab boundaries, render missing slab layers, tile and mesh them, report.
    Slabs(cmd::slabs::Args),
    /// Cull slab tiles no viewpoint of the track can see (extended projections, α); --oracle measures.
    Cull(cmd::cull::Args),
    /// Serve a database over HTTP (ranges, ETags, optional shaping and added latency).
    Serve(cmd::serve::Args),
    /// Simulate walks streaming a database over loopback HTTP; report quality and bytes.
    Walk(cmd::walk::Args),
    /// Many concurrent clients against a database server: throughput and latency.
    Load(cmd::load::Args),
    /// Render one reconstructed view (headless): --at METRES --yaw --pitch --fov --size -o.
    Render(cmd::render::Args),
    /// Render frames along the whole track (headless).
    Flythrough(cmd::flythrough::Args),
    /// Reconstructed views against ground truth (PSNR, SSIM, holes, frame time).
    Eval(cmd::eval::Args),
    /// Frame time of two views × all slabs against a plain single-panorama draw.
    BenchViewer(cmd::bench_viewer::Args),
    /// The interactive viewer window (egui): move along the track, look around, budgets.
    View(cmd::view::Args),
    /// Check every file of a database (hashes, sizes, PTM level ranges); exit 0 only when intact.
    Verify(cmd::verify::Args),
    /// The whole pipeline into a database: prerender → slabs → cull → encode → ACH, one report.
    Build(cmd::build::Args),
    /// Error against cost over the build's knobs (a sweep of databases), Pareto fronts, and
    /// the cheapest configuration for a PSNR target.
    Tune(cmd::tune::Args),
}

/// Log filter without `RUST_LOG`: warnings, except the lines wgpu logs for each error it
/// reports on a device (a shader it cannot translate, "please report it") and eframe's line
/// for the error that closes the window: the command's error says it once, naming the
/// adapter, the backend and what failed. `RUST_LOG=warn` shows them as they happen.
const DEFAULT_LOG: &str = "warn,wgpu::backend::wgpu_core=off,eframe::native::run=off";

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(DEFAULT_LOG)),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match dispatch(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Run one subcommand.
fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Prerender(a) => cmd::prerender::run(a),
        Command::ImportPov(a) => cmd::import_pov::run(a),
        Command::Slabs(a) => cmd::slabs::run(a),
        Command::Cull(a) => cmd::cull::run(a),
        Command::Serve(a) => cmd::serve::run(a),
        Command::Walk(a) => cmd::walk::run(a),
        Command::Load(a) => cmd::load::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Flythrough(a) => cmd::flythrough::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::BenchViewer(a) => cmd::bench_viewer::run(a),
        Command::View(a) => cmd::view::run(a),
        Command::Verify(a) => cmd::verify::run(a),
        Command::Build(a) => cmd::build::run(a),
        Command::Tune(a) => cmd::tune::run(a),
    }
}
