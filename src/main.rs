//! `railview`: the command line. Parses arguments and calls the crates; each subcommand
//! lives in `src/cmd/<name>.rs` with an `Args` struct and a `run` function.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;

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
    /// Render cube-map colour, depth (and optionally slab layers) at the reference viewpoints of a track.
    Prerender(cmd::prerender::Args),
    /// Render a POV-Ray scene along a track into the same layout (colour, depth, slab layers).
    ImportPov(cmd::import_pov::Args),
    /// Check every file of a database (hashes, sizes, PTM level ranges); exit 0 only when intact.
    Verify(cmd::verify::Args),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Prerender(a) => cmd::prerender::run(a),
        Command::ImportPov(a) => cmd::import_pov::run(a),
        Command::Verify(a) => cmd::verify::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
