//! `railview tune`: error against cost over the build's knobs for one scene and track
//! (`tune::Sweep`).
//!
//! Builds the databases of a sweep (`tune::SweepSpec`: each knob varied on its own around a
//! base configuration), the stages of each in directories shared by the configurations that
//! agree on them (`tune::plan`), evaluates every database on the same views against the same
//! anti-aliased ground truth, streams a standard walk of each, and writes the Pareto tables
//! and figures (`tune::report`). With `--target-psnr` it also chooses the cheapest
//! configuration whose worst 5 % of views reach the target (and with `--combine` first tries
//! the knobs that reach it alone together). Everything is kept in OUT: a rerun reuses every
//! stage, evaluation and walk already made.

use std::path::PathBuf;

use anyhow::{bail, Context};
use db::ach::AchParams;
use prerender::pov::UpAxis;
use stages::build::BuildScene;
use stages::prerender::PovParams;
use tune::report as tr;
use tune::sweep::ViewParams;
use tune::{Cost, CullChoice, Knobs, Sweep, SweepParams, SweepSpec};

/// Arguments of `railview tune`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Built-in scene name or scene TOML file (the built-in tracer).
    #[arg(long, required_unless_present = "pov", conflicts_with = "pov")]
    pub scene: Option<String>,
    /// A POV-Ray 3.7 scene (POV-Ray renders the panoramas and the truth).
    #[arg(long)]
    pub pov: Option<PathBuf>,
    /// With --pov: the scene's up axis, `y` or `z`.
    #[arg(long, requires = "pov")]
    pub up: Option<UpAxis>,
    /// Track of the scene, or a track TOML file.
    #[arg(long, default_value = "main")]
    pub track: String,
    /// Directory of the sweep (stages, databases, evaluations, reports).
    #[arg(long)]
    pub out: PathBuf,

    /// Base configuration: face size, pixels.
    #[arg(long, default_value_t = 128)]
    pub face_size: u32,
    /// Base configuration: rays per panorama pixel along each axis.
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Base configuration: slabs (auto, fewer, more, ranges).
    #[arg(long, default_value = "auto")]
    pub slabs: String,
    /// Base configuration: tile size, pixels.
    #[arg(long, default_value_t = 32)]
    pub tile_size: u32,
    /// Base configuration: mesh error, parallax pixels.
    #[arg(long, default_value_t = 0.5)]
    pub mesh_error: f64,
    /// Base configuration: culling `VARIANT:ALPHA` (`auto`, `shrunk`, `rendered`,
    /// `conservative`, `paper`) or `none`.
    #[arg(long, default_value = "conservative:1")]
    pub cull: String,

    /// Swept: keep every N-th reference viewpoint, comma separated (`` for none).
    #[arg(long, default_value = "2")]
    pub every: String,
    /// Swept: face sizes (`3/4`: three quarters of the base's, a multiple of 8).
    #[arg(long, default_value = "3/4")]
    pub face_sizes: String,
    /// Swept: rays per panorama pixel along each axis.
    #[arg(long, default_value = "2")]
    pub supersamples: String,
    /// Swept: slab choices.
    #[arg(long, default_value = "fewer,more")]
    pub slab_counts: String,
    /// Swept: tile sizes.
    #[arg(long, default_value = "16,64")]
    pub tile_sizes: String,
    /// Swept: mesh errors.
    #[arg(long, default_value = "2")]
    pub mesh_errors: String,
    /// Swept: culling, `VARIANT:ALPHA` (`auto`, `shrunk`, `conservative`, `paper`) or `none`.
    #[arg(long, default_value = "paper:1,conservative:0.9,none")]
    pub culls: String,
    /// Swept: finest texture levels left out.
    #[arg(long, default_value = "1")]
    pub drop_levels: String,

    /// PSNR targets (dB) on the worst 5 % of views: choose the cheapest configuration for each.
    #[arg(long, value_delimiter = ',')]
    pub target_psnr: Vec<f64>,
    /// The cost to choose by: db-bytes, walk-bytes, prerender-cpu, build-cpu, frame-ms.
    #[arg(long, default_value = "db-bytes")]
    pub cost: String,
    /// For each target, also build and measure the knobs that reach it alone combined,
    /// cheapest saving first, keeping each that still reaches it.
    #[arg(long)]
    pub combine: bool,

    /// Evaluation: positions inside every segment of the base sampling.
    #[arg(long, default_value_t = 2)]
    pub per_segment: usize,
    /// Evaluation: directions per position.
    #[arg(long, default_value_t = 4)]
    pub directions: usize,
    /// Evaluation: horizontal field of view, degrees (views at matched resolution for the
    /// base face size, 4:3).
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Evaluation: ground-truth rays per pixel along each axis.
    #[arg(long, default_value_t = 3)]
    pub truth_supersample: u32,
    /// Standard walk: speed, m/s (unlimited bandwidth, ACH with prefetch).
    #[arg(long, default_value_t = 1.5)]
    pub walk_speed: f64,

    /// zstd level of the PTMs.
    #[arg(long, default_value_t = 19)]
    pub zstd_level: i32,
    /// ACH: viewpoints sampled per segment.
    #[arg(long, default_value_t = 8)]
    pub ach_samples: usize,
    /// ACH: pixels per side of each camera.
    #[arg(long, default_value_t = 64)]
    pub ach_camera_size: u32,
    /// Face size of the low-resolution depth pass (default: the prerender stage's).
    #[arg(long)]
    pub lowres_face_size: Option<u32>,
}

fn list<T: std::str::FromStr>(text: &str, flag: &str) -> anyhow::Result<Vec<T>> {
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<T>()
                .map_err(|_| anyhow::anyhow!("--{flag}: `{s}` is not a valid value"))
        })
        .collect()
}

/// A culling choice, `VARIANT:ALPHA` or `none` (`CullChoice::parse_with_alpha`).
fn cull(text: &str, flag: &str, pov: bool) -> anyhow::Result<(CullChoice, f64)> {
    CullChoice::parse_with_alpha(text, pov).map_err(|e| anyhow::anyhow!("--{flag} `{text}`: {e}"))
}

impl Args {
    /// The sweep these arguments ask for.
    pub fn spec(&self) -> anyhow::Result<SweepSpec> {
        let (culling, alpha) = cull(&self.cull, "cull", self.pov.is_some())?;
        let base = Knobs {
            every: 1,
            face_size: self.face_size,
            supersample: self.supersample,
            slabs: self.slabs.parse().map_err(anyhow::Error::msg)?,
            tile_size: self.tile_size,
            mesh_error_px: self.mesh_error,
            cull: culling,
            alpha,
            drop_levels: 0,
            zstd_level: self.zstd_level,
            ..Knobs::default()
        };
        let spec = SweepSpec {
            base,
            every: list(&self.every, "every")?,
            face_size: if self.face_sizes == "3/4" {
                vec![tune::knobs::three_quarters(self.face_size)]
            } else {
                list(&self.face_sizes, "face-sizes")?
            },
            supersample: list(&self.supersamples, "supersamples")?,
            slabs: list(&self.slab_counts, "slab-counts")?,
            tile_size: list(&self.tile_sizes, "tile-sizes")?,
            mesh_error_px: list(&self.mesh_errors, "mesh-errors")?,
            cull: self
                .culls
                .split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(|c| cull(c, "culls", self.pov.is_some()))
                .collect::<anyhow::Result<_>>()?,
            drop_levels: list(&self.drop_levels, "drop-levels")?,
        };
        spec.check(self.pov.is_some())?;
        Ok(spec)
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let spec = args.spec()?;
    let cost = Cost::parse(&args.cost).with_context(|| {
        format!(
            "--cost `{}`: expected one of db-bytes, walk-bytes, prerender-cpu, build-cpu, frame-ms",
            args.cost
        )
    })?;
    let scene = match (args.scene, args.pov) {
        (Some(s), _) => BuildScene::Tracer(s),
        (None, Some(p)) => BuildScene::PovRay {
            scene: p,
            pov: PovParams {
                up: args.up,
                ..PovParams::default()
            },
        },
        (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
    };
    let params = SweepParams {
        scene,
        track: args.track,
        out: args.out,
        spec,
        targets: args.target_psnr,
        cost,
        combine: args.combine,
        views: ViewParams {
            per_segment: args.per_segment,
            directions: args.directions,
            fov_deg: args.fov,
            truth_supersample: args.truth_supersample,
        },
        walk_speed: args.walk_speed,
        zstd_level: args.zstd_level,
        ach: AchParams {
            samples: args.ach_samples,
            camera_size: args.ach_camera_size,
        },
        lowres_face_size: args.lowres_face_size,
    };
    sweep(params)
}

/// Run a sweep and print its table and choices.
pub fn sweep(params: SweepParams) -> anyhow::Result<()> {
    let mut sweep = Sweep::new(params, &crate::progress::terminal())?;
    let report = sweep.run()?;
    print!("{}", tr::table(&report));
    for s in &report.selections {
        println!("\n{}", tr::selection_text(&report, s));
    }
    Ok(())
}
