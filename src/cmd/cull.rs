//! `railview cull DIR`: track-dependent occlusion culling of the slab tiles that
//! `railview slabs DIR` wrote, for every α and variant, optionally judged by the exact oracle
//! (`stages::cull`, which says what it writes).

use std::path::PathBuf;

use anyhow::{bail, Context};
use occlusion::Variant;
use stages::cull::{CullParams, OracleParams, Variants};

/// Arguments of `railview cull`.
#[derive(clap::Args)]
pub struct Args {
    /// Prerender directory, after `railview slabs DIR`.
    pub dir: PathBuf,
    /// Opacity thresholds α, comma-separated (1 = fully opaque windows only).
    #[arg(long, default_value = "1.0,0.9,0.8")]
    pub alpha: String,
    /// Variants, comma-separated: `shrunk`, `rendered`, `conservative`, `paper`; `all` for
    /// the four (`shrunk` only where the scene's geometry is at hand), `both` for the last
    /// two.
    #[arg(long, default_value = "all")]
    pub variant: String,
    /// Also run the exact oracle: built-in or TOML scenes cast rays through the geometry;
    /// POV-Ray imports render depth with POV-Ray at every oracle position (a depth pass,
    /// two where the scene's fog shows, several runs at a time).
    #[arg(long)]
    pub oracle: bool,
    /// Oracle positions per track segment besides its two ends, at offset fractions of its
    /// length that the shrunk variant never samples (at least twice its base sampling).
    #[arg(long, default_value_t = 16)]
    pub oracle_per_segment: usize,
    /// Oracle rays per face side (default: the layers' face size).
    #[arg(long)]
    pub oracle_face_size: Option<u32>,
    /// The rendered variant: balls per track segment at the finest level (default 64),
    /// halved from 2 only where a tile needs smaller ones; depth is rendered (POV-Ray) or
    /// cast (built-in and TOML scenes) only for the balls some tile still needs.
    #[arg(long)]
    pub renders_per_segment: Option<usize>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let alphas = parse_alphas(&args.alpha)?;
    let variants = parse_variants(&args.variant)?;
    if let (false, Some(n)) = (args.oracle, args.oracle_face_size) {
        super::face_size("--oracle-face-size", n)?;
    }
    let params = CullParams {
        dir: args.dir,
        alphas,
        variants,
        oracle: args.oracle.then_some(OracleParams {
            per_segment: args.oracle_per_segment,
            face_size: args.oracle_face_size,
        }),
        renders_per_segment: args.renders_per_segment,
    };
    stages::cull::run(&params, &crate::progress::terminal())?;
    Ok(())
}

/// `--variant`: `all`, `both`, or variants named one by one (`all` and `both` leave out a
/// variant that cannot run here with a note; one named that cannot is an error).
fn parse_variants(s: &str) -> anyhow::Result<Variants> {
    match s.trim() {
        "all" => return Ok(Variants::All),
        "both" => return Ok(Variants::Both),
        _ => {}
    }
    let mut out = Vec::new();
    for part in s.split(',') {
        let v = Variant::parse(part).with_context(|| {
            format!(
                "--variant `{part}`: expected shrunk, rendered, conservative, paper, all or both"
            )
        })?;
        if !out.contains(&v) {
            out.push(v);
        }
    }
    Ok(Variants::These(out))
}

fn parse_alphas(s: &str) -> anyhow::Result<Vec<f64>> {
    s.split(',')
        .map(|a| {
            let v: f64 = a
                .trim()
                .parse()
                .with_context(|| format!("--alpha `{a}`: not a number"))?;
            if !(v > 0.0 && v <= 1.0) {
                bail!("--alpha {v}: must be in (0, 1]");
            }
            Ok(v)
        })
        .collect()
}
