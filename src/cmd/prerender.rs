//! `railview prerender`: render the reference viewpoints of a track with the built-in ray
//! tracer into a prerender directory (`stages::prerender`). `--shard K/N` renders one
//! shard's samples and leaves the report to the merge; `--merge` renders nothing, checks that
//! every sample is complete (naming those that are not) and writes the report.

use std::path::PathBuf;

use prerender::job::Shard;
use stages::prerender::{PrerenderParams, Renderer};
use tracks::SlabRange;

/// Arguments of `railview prerender`.
#[derive(clap::Args)]
pub struct Args {
    /// Built-in scene name (`castle`, `nature`) or a scene TOML file.
    #[arg(long)]
    pub scene: String,
    /// A track of the scene (built-in or `[[track]]` in the scene file), or a track TOML file.
    #[arg(long, default_value = "main")]
    pub track: String,
    /// Pixels along a cube face.
    #[arg(long, default_value_t = 512)]
    pub face_size: u32,
    /// Output directory (created; resumable).
    #[arg(long)]
    pub out: PathBuf,
    /// Face size of the fast depth-only pass.
    #[arg(long, default_value_t = 64)]
    pub lowres_face_size: u32,
    /// Colour rays per pixel along each axis.
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Skip shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Also render slab layers for these depth ranges, e.g. `0-10,10-40,40-inf`.
    #[arg(long)]
    pub slabs: Option<String>,
    /// Render only viewpoints with index % N == K (`K/N`). Shards share one output directory;
    /// none of them writes `prerender.json` (the merge does).
    #[arg(long, conflicts_with = "merge")]
    pub shard: Option<String>,
    /// After the shards: render nothing, fail naming every sample (and its shard) that is not
    /// complete, else write `prerender.json` covering all shards.
    #[arg(long)]
    pub merge: bool,
}

/// `--slabs` of the prerender commands.
pub fn slab_list(text: Option<&str>) -> anyhow::Result<Option<Vec<SlabRange>>> {
    text.map(|s| SlabRange::parse_list(s).map_err(|e| anyhow::anyhow!("--slabs: {e}")))
        .transpose()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::face_size("--face-size", args.face_size)?;
    super::face_size("--lowres-face-size", args.lowres_face_size)?;
    if args.supersample == 0 || args.supersample > 16 {
        anyhow::bail!("--supersample must be between 1 and 16");
    }
    let shard = args
        .shard
        .as_deref()
        .map(Shard::parse)
        .transpose()
        .map_err(anyhow::Error::msg)?;
    let params = PrerenderParams {
        scene: args.scene,
        track: args.track,
        track_name: None,
        face_size: args.face_size,
        lowres_face_size: Some(args.lowres_face_size),
        out: args.out,
        slabs: slab_list(args.slabs.as_deref())?,
        shard,
        merge: args.merge,
        renderer: Renderer::Builtin {
            supersample: args.supersample,
            shadows: !args.no_shadows,
        },
    };
    stages::prerender::run(&params, &crate::progress::terminal())?;
    Ok(())
}
