//! `railview import-pov`: render a POV-Ray scene along a track into a prerender directory
//! (the same layout `railview prerender` writes, so `slabs`, `cull` and `build` work on it;
//! `stages::prerender` with `Renderer::PovRay`).

use std::path::PathBuf;

use prerender::job::Shard;
use prerender::pov::UpAxis;
use stages::prerender::{PovParams, PrerenderParams, Renderer};

/// Arguments of `railview import-pov`.
#[derive(clap::Args)]
pub struct Args {
    /// The POV-Ray 3.7 scene (`.pov`), used unchanged.
    pub scene: PathBuf,
    /// Track TOML in railview coordinates (y up; for a y-up scene POV-Ray <x,y,z> = [x,y,-z],
    /// for a z-up scene POV-Ray <x,y,z> = [-x,z,-y]).
    #[arg(long)]
    pub track: PathBuf,
    /// Which track of the file (default: the first).
    #[arg(long)]
    pub track_name: Option<String>,
    /// Cube-map face size in pixels.
    #[arg(long)]
    pub face_size: u32,
    /// Output prerender directory (created; resumable).
    #[arg(long)]
    pub out: PathBuf,
    /// The scene's up axis: `y` or `z`.
    #[arg(long, default_value = "y")]
    pub up: UpAxis,
    /// Anti-aliased colour (2×2 supersampling; 4× the colour render time).
    #[arg(long)]
    pub aa: bool,
    /// Colour rays per pixel along each axis, 1 to 4, box-filtered in linear light (N² times
    /// the colour render time; --aa is 2).
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Face size of the low-resolution depth pass.
    #[arg(long, default_value_t = 32)]
    pub lowres_face_size: u32,
    /// Slab layers to render, e.g. `0-300,300-700,700-inf` (scene units).
    #[arg(long)]
    pub slabs: Option<String>,
    /// Kill and fail a single POV-Ray render that runs longer than this.
    #[arg(long)]
    pub timeout_secs: Option<f64>,
    /// Render only samples with index % N == K (0 <= K < N). Shards share one output
    /// directory; none of them writes `prerender.json` (the merge does).
    #[arg(long, conflicts_with = "merge")]
    pub shard: Option<String>,
    /// After the shards: render nothing, fail naming every sample (and its shard) that is not
    /// complete, else write `prerender.json` covering all shards.
    #[arg(long)]
    pub merge: bool,
    /// The POV-Ray binary.
    #[arg(long, default_value = "povray")]
    pub povray: PathBuf,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// File_Gamma of the depth passes (default: the scene's assumed_gamma).
    #[arg(long)]
    pub gamma: Option<f64>,
    /// Also write an equirectangular colour preview of this width per sample
    /// (DIR/previews/NNNN.png, POV-Ray's spherical camera).
    #[arg(long)]
    pub preview_width: Option<u32>,
}

fn parse_shard(text: &str) -> anyhow::Result<(usize, usize)> {
    Shard::parse(text)
        .map(|s| s.pair())
        .map_err(|e| anyhow::anyhow!("--shard: {e}"))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::face_size("--face-size", args.face_size)?;
    super::face_size("--lowres-face-size", args.lowres_face_size)?;
    let slabs = super::prerender::slab_list(args.slabs.as_deref())?;
    let shard = args
        .shard
        .as_deref()
        .map(parse_shard)
        .transpose()?
        .map(|(index, count)| Shard { index, count });
    let params = PrerenderParams {
        scene: args.scene.display().to_string(),
        track: args.track.display().to_string(),
        track_name: args.track_name,
        face_size: args.face_size,
        lowres_face_size: Some(args.lowres_face_size),
        out: args.out,
        slabs,
        shard,
        merge: args.merge,
        renderer: Renderer::PovRay(PovParams {
            up: Some(args.up),
            supersample: if args.aa {
                args.supersample.max(2)
            } else {
                args.supersample
            },
            timeout_secs: args.timeout_secs,
            povray: Some(args.povray),
            threads: args.threads,
            gamma: args.gamma,
            preview_width: args.preview_width,
        }),
    };
    stages::prerender::run(&params, &crate::progress::terminal())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_syntax() {
        assert_eq!(parse_shard("1/3").unwrap(), (1, 3));
        assert!(parse_shard("3/3").is_err());
        assert!(parse_shard("0/0").is_err());
        assert!(parse_shard("a/2").is_err());
        assert!(parse_shard("2").is_err());
    }
}
