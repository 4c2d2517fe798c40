//! `railview slabs DIR`: choose slab boundaries, render missing slab layers (built-in
//! scenes with the built-in tracer, POV-Ray imports with POV-Ray, re-created from what
//! `import-pov` recorded in `prerender.json`), tile and mesh every layer, write tiles files
//! and the report (`stages::slabs`).

use std::path::PathBuf;

use anyhow::bail;
use slabs::tiles::MeshKind;
use stages::slabs::{
    SlabsParams, Tiling, DEFAULT_MESH_ERROR, DEFAULT_MESH_STEP, DEFAULT_TILE_SIZE,
};
use stages::SlabSpec;

/// The stage's default mesh (`railview build` compares a work directory's tiles with it).
pub const DEFAULT_MESH: &str = "adaptive";

/// Arguments of `railview slabs`.
#[derive(clap::Args)]
pub struct Args {
    /// Prerender directory (written by `railview prerender` or `import-pov`).
    pub dir: PathBuf,
    /// Tile side in pixels (a power of two).
    #[arg(long, default_value_t = DEFAULT_TILE_SIZE)]
    pub tile_size: u32,
    /// Grid step of the regular mesh, pixels.
    #[arg(long, default_value_t = DEFAULT_MESH_STEP)]
    pub mesh_step: u32,
    /// Error bound of the adaptive mesh: parallax pixels at the track's largest baseline.
    #[arg(long, default_value_t = DEFAULT_MESH_ERROR)]
    pub mesh_error: f64,
    /// Which mesh tiles.bin stores: `adaptive` or `grid` (both are measured).
    #[arg(long, default_value = DEFAULT_MESH)]
    pub mesh: String,
    /// Parallax (pixels at the largest baseline) that makes neighbouring pixels a discontinuity.
    #[arg(long, default_value_t = 1.0)]
    pub discontinuity: f64,
    /// `auto`; `fewer` / `more` (the automatic choice with one boundary fewer or more;
    /// `auto-N`, `auto+N` for N); or slab ranges `0-1000,1000-10000,10000-inf` (metres).
    #[arg(long, default_value = "auto")]
    pub slabs: String,
    /// Choose the boundaries and render the missing layers, but do not tile them.
    #[arg(long)]
    pub layers_only: bool,
    /// Pixels of parallax above which a histogram valley becomes a boundary.
    #[arg(long, default_value_t = 1.0)]
    pub threshold_px: f64,
}

/// `--mesh`: `adaptive` or `grid`.
pub fn mesh_kind(text: &str) -> anyhow::Result<MeshKind> {
    Ok(match text {
        "adaptive" => MeshKind::Adaptive,
        "grid" => MeshKind::Grid,
        other => bail!("--mesh `{other}`: expected `adaptive` or `grid`"),
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mesh = mesh_kind(&args.mesh)?;
    let slabs: SlabSpec = args.slabs.parse().map_err(anyhow::Error::msg)?;
    let params = SlabsParams {
        dir: args.dir,
        slabs,
        threshold_px: args.threshold_px,
        tiling: Tiling {
            tile_size: args.tile_size,
            mesh,
            mesh_step: args.mesh_step,
            mesh_error_px: args.mesh_error,
            discontinuity_px: args.discontinuity,
        },
        layers_only: args.layers_only,
    };
    stages::slabs::run(&params, &crate::progress::terminal())?;
    Ok(())
}
