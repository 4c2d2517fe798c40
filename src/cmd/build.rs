//! `railview build --scene NAME --track NAME --face-size N --out DB`: the whole pipeline —
//! prerender → slabs → cull → encode (PTM + meshes) → ACH → manifest — with one report
//! (`stages::build`, which says where everything goes). `railview build --pov SCENE.pov
//! --track TRACK.toml [--up y|z] …` runs the same pipeline on a POV-Ray scene.
//! `--target-psnr` first sweeps the knobs around the settings given and builds the cheapest
//! configuration that reaches the target.

use std::path::PathBuf;

use anyhow::{bail, Context};
use codec::ptm;
use db::ach::AchParams;
use prerender::pov::UpAxis;
use stages::build::{BuildParams, BuildScene};
use stages::encode::EncodeParams;
use stages::prerender::PovParams;
use stages::{CullChoice, Knobs};
use tune::target::TargetParams;
use tune::Cost;

#[derive(clap::Args)]
pub struct Args {
    /// Built-in scene name or scene TOML path (rendered by the built-in tracer).
    #[arg(long, required_unless_present = "pov", conflicts_with = "pov")]
    pub scene: Option<String>,
    /// A POV-Ray 3.7 scene (`.pov`), imported with `railview import-pov` (needs `--track FILE`).
    #[arg(long)]
    pub pov: Option<PathBuf>,
    /// Track of the scene, or a track TOML file (with `--pov`: the track file, whose first
    /// track is used unless `--track-name` says otherwise).
    #[arg(long, default_value = "main")]
    pub track: String,
    /// With `--pov`: which track of the track file.
    #[arg(long, requires = "pov")]
    pub track_name: Option<String>,
    /// With `--pov`: the scene's up axis, `y` or `z`.
    #[arg(long, requires = "pov")]
    pub up: Option<UpAxis>,
    /// With `--pov`: anti-aliased colour (2×2 supersampling).
    #[arg(long, requires = "pov")]
    pub aa: bool,
    /// With `--pov`: the POV-Ray binary.
    #[arg(long, requires = "pov")]
    pub povray: Option<PathBuf>,
    /// With `--pov`: kill and fail a single POV-Ray render that runs longer than this.
    #[arg(long, requires = "pov")]
    pub timeout_secs: Option<f64>,
    /// Face size of the low-resolution depth pass (default: the prerender stage's).
    #[arg(long)]
    pub lowres_face_size: Option<u32>,
    /// Cube-map face size of the reference panoramas, pixels.
    #[arg(long, default_value_t = 128)]
    pub face_size: u32,
    /// Database directory to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Work directory for stage outputs (default: `OUT.work` beside the database). Point it
    /// at an existing prerender directory's parent layout to reuse its stages.
    #[arg(long)]
    pub work: Option<PathBuf>,
    /// Reference viewpoints: exactly N, evenly spread along the track (default: the track's
    /// own sampling).
    #[arg(long, conflicts_with = "spacing")]
    pub samples: Option<usize>,
    /// Reference viewpoints at most this many metres apart, evenly spread (default: the
    /// track's own sampling).
    #[arg(long)]
    pub spacing: Option<f64>,
    /// Colour rays per pixel along each axis of the panoramas, averaged in linear light
    /// (anti-aliasing). With --pov at most 4 (POV-Ray renders colour at that many times the
    /// face size); --aa is 2.
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Slab boundaries: `auto`, `fewer`, `more`, `auto-N`, `auto+N`, or ranges
    /// `0-10,10-inf` (see `railview slabs --slabs`).
    #[arg(long, default_value = "auto")]
    pub slabs: String,
    /// Tile side, pixels (a power of two).
    #[arg(long, default_value_t = 32)]
    pub tile_size: u32,
    /// Error bound of the tiles' depth meshes: parallax pixels at the track's longest segment.
    #[arg(long, default_value_t = 0.5)]
    pub mesh_error: f64,
    /// Occlusion culling α used for the database (a run with this α is used or made).
    #[arg(long, default_value_t = 1.0)]
    pub alpha: f64,
    /// How PTM level groups are coded: `arith` (context-modelled range coding, the smallest)
    /// or `zstd` (faster to decode, larger).
    #[arg(long, default_value = "arith")]
    pub ptm_method: String,
    /// Culling variant for the database: `shrunk` (conservative for every track point,
    /// against the scene's solids), `rendered` (from depth renders along the track),
    /// `conservative`, `paper`, `none` (keep every non-empty tile), or `auto`: at α = 1 shrunk
    /// for built-in and TOML scenes and rendered for POV-Ray imports, conservative at α < 1.
    #[arg(long, default_value = "auto")]
    pub cull_variant: String,
    /// Leave out the N finest texture levels: each tile's colour is kept at 1/2^N of its
    /// resolution (opacity masks and meshes stay whole).
    #[arg(long, default_value_t = 0)]
    pub drop_levels: u32,
    /// zstd level of the PTM groups with `--ptm-method zstd` (19 = smallest practical;
    /// lower encodes faster).
    #[arg(long, default_value_t = 19)]
    pub zstd_level: i32,
    /// Lossy textures: the largest error of a colour sample at every PTM level (0 =
    /// lossless, the default; at most 32; needs `--ptm-method arith`). Alpha stays exact.
    #[arg(long, default_value_t = 0)]
    pub lossy_near: u8,
    /// Bound on the meshes' depth quantisation, pixels of parallax at the track's largest
    /// baseline (0.001 to 10).
    #[arg(long, default_value_t = 0.05)]
    pub depth_error_px: f64,
    /// Which mesh tiles carry: `adaptive` (error-bounded) or `grid` (a vertex every
    /// `--mesh-step` pixels); default: the slabs stage's `adaptive`.
    #[arg(long)]
    pub mesh: Option<String>,
    /// Grid step of `--mesh grid`, pixels (default: the slabs stage's 4).
    #[arg(long)]
    pub mesh_step: Option<u32>,
    /// ACH: viewpoints sampled per track segment.
    #[arg(long, default_value_t = 8)]
    pub ach_samples: usize,
    /// ACH: pixels per side of each of the six cameras at a sampled viewpoint.
    #[arg(long, default_value_t = 64)]
    pub ach_camera_size: u32,
    /// Leave out what the scene does not need: sweep the build's knobs around the settings
    /// given (as `railview tune` does by default), and build the cheapest configuration (by
    /// --cost) whose worst 5 % of views reach this PSNR in dB. The sweep is kept in
    /// --tune-dir and reused; the choice and its evidence go into the build report.
    #[arg(long)]
    pub target_psnr: Option<f64>,
    /// With --target-psnr: the cost to minimise: db-bytes, walk-bytes, prerender-cpu,
    /// build-cpu or frame-ms.
    #[arg(long, default_value = "db-bytes")]
    pub cost: String,
    /// With --target-psnr: the sweep's directory (default: WORK/tune).
    #[arg(long)]
    pub tune_dir: Option<PathBuf>,
    /// With --target-psnr: evaluation views per segment and directions per position.
    #[arg(long, default_value_t = 2)]
    pub per_segment: usize,
    #[arg(long, default_value_t = 4)]
    pub directions: usize,
}

/// `--ptm-method`: `arith` or `zstd`.
fn ptm_method(text: &str) -> anyhow::Result<ptm::Method> {
    Ok(match text {
        "arith" => ptm::Method::Arith,
        "zstd" => ptm::Method::Zstd,
        other => bail!("--ptm-method `{other}`: expected `arith` or `zstd`"),
    })
}

/// The build these arguments ask for.
fn params(args: &Args) -> anyhow::Result<BuildParams> {
    let scene = match (&args.scene, &args.pov) {
        (Some(s), _) => BuildScene::Tracer(s.clone()),
        (None, Some(p)) => BuildScene::PovRay {
            scene: p.clone(),
            pov: PovParams {
                up: args.up,
                supersample: if args.aa { 2 } else { 1 },
                timeout_secs: args.timeout_secs,
                povray: args.povray.clone(),
                ..PovParams::default()
            },
        },
        (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
    };
    let cull: CullChoice = args
        .cull_variant
        .parse()
        .map_err(|e| anyhow::anyhow!("--cull-variant {e}"))?;
    Ok(BuildParams {
        scene,
        track: args.track.clone(),
        track_name: args.track_name.clone(),
        out: args.out.clone(),
        work: args.work.clone(),
        lowres_face_size: args.lowres_face_size,
        knobs: Knobs {
            every: 1,
            samples: args.samples,
            spacing_m: args.spacing,
            face_size: args.face_size,
            supersample: args.supersample,
            slabs: args.slabs.parse().map_err(anyhow::Error::msg)?,
            tile_size: args.tile_size,
            mesh_error_px: args.mesh_error,
            cull,
            alpha: args.alpha,
            drop_levels: args.drop_levels,
            zstd_level: args.zstd_level,
        },
        mesh: args
            .mesh
            .as_deref()
            .map(super::slabs::mesh_kind)
            .transpose()?,
        mesh_step: args.mesh_step,
        encode: EncodeParams {
            method: ptm_method(&args.ptm_method)?,
            zstd_level: args.zstd_level,
            lossy_near: args.lossy_near,
            depth_error_px: args.depth_error_px,
            drop_levels: args.drop_levels,
            ach: AchParams {
                samples: args.ach_samples,
                camera_size: args.ach_camera_size,
            },
        },
        report_dir: None,
        evidence: None,
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = params(&args)?;
    params.check()?;
    let progress = crate::progress::terminal();
    match args.target_psnr {
        None => {
            stages::build::run(&params, &progress)?;
        }
        Some(psnr_db) => {
            let cost = Cost::parse(&args.cost).with_context(|| {
                format!(
                    "--cost `{}`: expected one of db-bytes, walk-bytes, prerender-cpu, build-cpu, frame-ms",
                    args.cost
                )
            })?;
            let target = TargetParams {
                psnr_db,
                cost,
                tune_dir: args.tune_dir,
                per_segment: args.per_segment,
                directions: args.directions,
            };
            tune::target::build_for_target(&params, &target, &progress)?;
        }
    }
    // The browser viewer beside the manifest: the database folder is a website.
    viewer::web::write_site(&args.out)
        .with_context(|| format!("writing the browser viewer into {}", args.out.display()))?;
    Ok(())
}
