//! `railview tune`: error against cost over the build's knobs for one scene and track.
//!
//! Builds the databases of a sweep (`tune::SweepSpec`: each knob varied on its own around a
//! base configuration), the stages of each in directories shared by the configurations that
//! agree on them (`tune::plan`), evaluates every database on the same views against the same
//! anti-aliased ground truth, streams a standard walk of each, and writes the Pareto tables
//! and figures (`tune::report`). With `--target-psnr` it also chooses the cheapest
//! configuration whose worst 5 % of views reach the target (and with `--combine` first tries
//! the knobs that reach it alone together). Everything is kept in OUT: a rerun reuses every
//! stage, evaluation and walk already made.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};
use tune::pareto::{quality, select, Selection};
use tune::plan::{self, SceneSpec, Setup, Stage};
use tune::record::{Costs, ErrorSummary};
use tune::report::{self as tr, SweepReport};
use tune::{Cost, CullChoice, Knobs, Measured, SweepSpec};
use viewer::eval::{self, EvalConfig, EvalInput, Truth, TruthCache, ViewSpec};

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
    pub up: Option<String>,
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
    /// Base configuration: culling `VARIANT:ALPHA` (`auto`, `shrunk`, `conservative`,
    /// `paper`) or `none`.
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

impl Args {
    /// The command's defaults, with no scene and an empty output directory.
    pub fn defaults() -> Args {
        Args {
            scene: None,
            pov: None,
            up: None,
            track: "main".into(),
            out: PathBuf::new(),
            face_size: 128,
            supersample: 1,
            slabs: "auto".into(),
            tile_size: 32,
            mesh_error: 0.5,
            cull: "conservative:1".into(),
            every: "2".into(),
            face_sizes: "3/4".into(),
            supersamples: "2".into(),
            slab_counts: "fewer,more".into(),
            tile_sizes: "16,64".into(),
            mesh_errors: "2".into(),
            culls: "paper:1,conservative:0.9,none".into(),
            drop_levels: "1".into(),
            target_psnr: Vec::new(),
            cost: "db-bytes".into(),
            combine: false,
            per_segment: 2,
            directions: 4,
            fov: 90.0,
            truth_supersample: 3,
            walk_speed: 1.5,
            zstd_level: 19,
            ach_samples: 8,
            ach_camera_size: 64,
            lowres_face_size: None,
        }
    }
}

/// Run a subcommand in this process from its command line (after `railview`).
fn run_sub(argv: &[String]) -> anyhow::Result<()> {
    use clap::Parser;
    let mut full = vec!["railview".to_string()];
    full.extend_from_slice(argv);
    let cli = crate::Cli::try_parse_from(&full)
        .with_context(|| format!("`{}` is not available in this build", argv[0]))?;
    crate::dispatch(cli.command).with_context(|| format!("stage `{}`", argv.join(" ")))
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

/// A culling choice, `VARIANT:ALPHA` or `none`; `auto` is `railview build`'s default: the
/// shrunk variant at α = 1 for scenes whose solids the tracer has, the conservative one
/// otherwise.
fn cull(text: &str, flag: &str, pov: bool) -> anyhow::Result<(CullChoice, f64)> {
    if text == "none" {
        return Ok((CullChoice::Off, 1.0));
    }
    let (v, a) = text.split_once(':').unwrap_or((text, "1"));
    let alpha: f64 = a
        .parse()
        .ok()
        .filter(|x: &f64| *x > 0.0 && *x <= 1.0)
        .with_context(|| format!("--{flag} `{text}`: α must be in (0, 1]"))?;
    let variant = if v == "auto" {
        if pov || alpha != 1.0 {
            occlusion::Variant::Conservative
        } else {
            occlusion::Variant::Shrunk
        }
    } else {
        occlusion::Variant::parse(v).with_context(|| {
            format!("--{flag} `{text}`: expected auto, shrunk, conservative, paper or none")
        })?
    };
    anyhow::ensure!(
        variant != occlusion::Variant::Shrunk || (alpha == 1.0 && !pov),
        "--{flag} `{text}`: the shrunk variant runs at α = 1 on scenes with solids (not --pov)"
    );
    Ok((CullChoice::Variant(variant), alpha))
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
                vec![(self.face_size * 3 / 4).div_ceil(8).max(1) * 8]
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
        for k in spec.configs() {
            anyhow::ensure!(
                (1..=64).contains(&k.every),
                "--every {}: must be in 1..=64",
                k.every
            );
            anyhow::ensure!(
                (8..=4096).contains(&k.face_size),
                "face size {} out of 8..=4096",
                k.face_size
            );
            anyhow::ensure!(
                (1..=16).contains(&k.supersample) && (self.pov.is_none() || k.supersample <= 2),
                "supersampling {} out of range (POV-Ray imports: 1 or 2)",
                k.supersample
            );
            anyhow::ensure!(
                k.tile_size.is_power_of_two() && (4..=1024).contains(&k.tile_size),
                "tile size {}: a power of two from 4 to 1024",
                k.tile_size
            );
            anyhow::ensure!(
                k.mesh_error_px.is_finite() && k.mesh_error_px > 0.0,
                "mesh error {} must be positive",
                k.mesh_error_px
            );
            anyhow::ensure!(k.drop_levels <= 8, "at most 8 levels left out");
        }
        Ok(spec)
    }
}

/// `node.json`: a stage that completed, and what it cost when it ran.
#[derive(Serialize, Deserialize)]
struct NodeRecord {
    stage: Stage,
    key: String,
    argv: Vec<String>,
    cpu_s: f64,
    wall_s: f64,
}

/// `eval.json` of a configuration: the summary and what it was measured with.
#[derive(Serialize, Deserialize)]
struct EvalRecord {
    key: String,
    error: ErrorSummary,
    frame_ms: f64,
    resolution_ratio: f64,
}

/// The sweep's measuring instruments, made once.
struct Bench {
    renderer: viewer::gpu::Renderer,
    truth: Truth,
    cache: TruthCache,
    spec: ViewSpec,
    size: (u32, u32),
    fov: f64,
    base_face: u32,
    /// Reference-sample arc lengths of the base sampling: the views lie between them.
    arcs: Vec<f64>,
    views_key: String,
}

/// Runs a sweep; kept together so that `build --target-psnr` can run one too.
pub struct Sweep {
    args: Args,
    setup: Setup,
    track: tracks::Track,
    base_samples: usize,
    bench: Option<Bench>,
    /// The GPU, found before anything is built: a machine without one fails at once.
    gpu: Option<viewer::gpu::Gpu>,
    built: usize,
    reused: usize,
}

impl Sweep {
    pub fn new(args: Args) -> anyhow::Result<Sweep> {
        anyhow::ensure!(
            args.fov.is_finite() && args.fov > 0.0 && args.fov < 180.0,
            "--fov must be in (0, 180) degrees"
        );
        anyhow::ensure!(
            (1..=64).contains(&args.per_segment) && (1..=64).contains(&args.directions),
            "--per-segment and --directions must be in 1..=64"
        );
        anyhow::ensure!(
            args.walk_speed.is_finite() && args.walk_speed > 0.0,
            "--walk-speed must be positive"
        );
        args.spec()?;
        let scene = match (&args.scene, &args.pov) {
            (Some(s), _) => SceneSpec::Tracer { scene: s.clone() },
            (None, Some(p)) => SceneSpec::Pov {
                scene: std::fs::canonicalize(p)
                    .with_context(|| format!("POV-Ray scene {}", p.display()))?
                    .display()
                    .to_string(),
                up: args.up.clone(),
            },
            (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
        };
        let track = stages::scene::resolve_track(args.scene.as_deref(), &args.track, None)?;
        let base_samples = track.viewpoints().len();
        prerender::store::ensure_writable_dir(&args.out)?;
        let root =
            std::fs::canonicalize(&args.out).with_context(|| format!("{}", args.out.display()))?;
        let setup = Setup {
            scene,
            root,
            lowres_face_size: args.lowres_face_size,
            zstd_level: args.zstd_level,
            ach_samples: args.ach_samples,
            ach_camera_size: args.ach_camera_size,
        };
        Ok(Sweep {
            args,
            setup,
            track,
            base_samples,
            bench: None,
            gpu: None,
            built: 0,
            reused: 0,
        })
    }

    /// The track file of a sampling: `OUT/tracks/every-N.toml`.
    fn track_file(&self, k: &Knobs) -> anyhow::Result<(PathBuf, String)> {
        let mut t = self.track.clone();
        if k.every > 1 {
            t.sampling = tracks::Sampling::Count(k.samples(self.base_samples));
        }
        let text = tracks::TrackSet { tracks: vec![t] }.to_toml();
        let path = self
            .setup
            .root
            .join("tracks")
            .join(format!("every-{}.toml", k.every));
        if std::fs::read_to_string(&path).ok().as_deref() != Some(text.as_str()) {
            prerender::store::write_atomic(&path, text.as_bytes())?;
        }
        Ok((path, text))
    }

    /// Run (or find) every stage of `k`'s database; returns the database node's directory
    /// and the CPU seconds of its prerender and build stages.
    fn build(&mut self, k: &Knobs) -> anyhow::Result<(PathBuf, f64, f64)> {
        let (track_file, text) = self.track_file(k)?;
        let nodes = plan::nodes(&self.setup, k, &track_file, &text);
        let (mut pre, mut build) = (0.0, 0.0);
        for n in &nodes {
            let record = n.dir.join("node.json");
            let done: Option<NodeRecord> = prerender::store::read_json(&record)
                .ok()
                .filter(|r: &NodeRecord| r.key == n.key);
            let rec = match done {
                Some(r) => {
                    self.reused += 1;
                    r
                }
                None => {
                    // A stage killed midway starts again from its parent's files.
                    if n.dir.exists() {
                        std::fs::remove_dir_all(&n.dir)
                            .with_context(|| format!("clearing {}", n.dir.display()))?;
                    }
                    match &n.parent {
                        Some(p) => {
                            tune::link::link_tree(p, &n.dir).with_context(|| {
                                format!("starting {} from {}", n.dir.display(), p.display())
                            })?;
                        }
                        None => std::fs::create_dir_all(&n.dir)?,
                    }
                    eprintln!("tune: {:?} stage: railview {}", n.stage, n.argv.join(" "));
                    let meter = tune::cost::Meter::start();
                    run_sub(&n.argv)?;
                    let (cpu_s, wall_s) = meter.stop();
                    let r = NodeRecord {
                        stage: n.stage,
                        key: n.key.clone(),
                        argv: n.argv.clone(),
                        cpu_s,
                        wall_s,
                    };
                    prerender::store::write_json(&record, &r)?;
                    self.built += 1;
                    r
                }
            };
            if rec.stage.is_prerender() {
                pre += rec.cpu_s;
            } else {
                build += rec.cpu_s;
            }
        }
        let last = nodes.last().context("no stages")?.dir.clone();
        Ok((last, pre, build))
    }

    fn bench(&mut self, db: &Path, pre_dir: &Path) -> anyhow::Result<&mut Bench> {
        if self.bench.is_none() {
            let walk = viewer::headless::open(&db.display().to_string(), None, Default::default())?;
            let base_face = self.args.face_size;
            let size = eval::matched_size(base_face, self.args.fov, 0.75);
            let truth = Truth::for_walkthrough(
                &db.display().to_string(),
                &walk,
                Some(pre_dir),
                self.args.truth_supersample,
                &self.setup.root.join("pov-truth"),
            )?;
            let spec = ViewSpec {
                per_segment: self.args.per_segment,
                directions: self.args.directions,
                pitches_deg: vec![0.0],
                max_segments: None,
            };
            let arcs: Vec<f64> = self.track.viewpoints().iter().map(|v| v.s).collect();
            let views_key = format!(
                "views {:?} | {}x{} fov {} | truth {} | base arcs {}",
                spec,
                size.0,
                size.1,
                self.args.fov,
                truth.describe(),
                arcs.len()
            );
            self.bench = Some(Bench {
                renderer: viewer::gpu::Renderer::new(match self.gpu.take() {
                    Some(gpu) => gpu,
                    None => viewer::gpu::Gpu::new()?,
                })?,
                truth,
                cache: TruthCache {
                    dir: Some(self.setup.root.join("truth")),
                },
                spec,
                size,
                fov: self.args.fov,
                base_face,
                arcs,
                views_key,
            });
        }
        Ok(self.bench.as_mut().expect("made above"))
    }

    /// Evaluate a database on the sweep's views (or read the evaluation made before).
    fn evaluate(&mut self, dir: &Path, pre_dir: &Path) -> anyhow::Result<EvalRecord> {
        let db = dir.join("db");
        let path = dir.join("eval.json");
        let b = self.bench(&db, pre_dir)?;
        if let Ok(r) = prerender::store::read_json::<EvalRecord>(&path) {
            if r.key == b.views_key {
                return Ok(r);
            }
        }
        let walk = viewer::headless::open(&db.display().to_string(), None, Default::default())?;
        let mut views = eval::views_at_samples(&walk, &b.spec);
        let mut between = eval::views_between(&walk, &b.arcs, &b.spec);
        eval::mark_references(&walk, &mut between);
        views.extend(between);
        let configs = [EvalConfig {
            name: "full".into(),
            budget: viewer::DrawBudget::default(),
        }];
        let bar = indicatif::ProgressBar::new(views.len() as u64);
        bar.set_message("evaluating");
        let rows = eval::evaluate(
            &mut b.renderer,
            EvalInput {
                walk: &walk,
                truth: &mut b.truth,
                cache: &b.cache,
                configs: &configs,
                views: &views,
                size: b.size,
                fov_deg: b.fov,
                timed_draws: 2,
            },
            |_| bar.inc(1),
        )?;
        bar.finish_and_clear();
        let s = eval::summarize(&rows);
        let s = s.first().context("no views evaluated")?;
        let face = walk.views.first().map_or(b.base_face, |v| v.face_size);
        let r = EvalRecord {
            key: b.views_key.clone(),
            error: ErrorSummary {
                views: s.between.views,
                psnr_mean_db: s.between.psnr_mean_db,
                psnr_worst5_db: s.between.psnr_worst5_db,
                psnr_min_db: s.between.psnr_min_db,
                ssim_mean: s.between.ssim_mean,
                ssim_worst5: s.between.ssim_worst5,
                holes_mean: s.between.holes_mean,
                holes_worst5: s.between.holes_worst5,
                psnr_at_samples_db: s.at_samples.psnr_mean_db,
            },
            frame_ms: s.frame_ms,
            resolution_ratio: eval::resolution_ratio(face, b.fov, b.size.0),
        };
        prerender::store::write_json(&path, &r)?;
        Ok(r)
    }

    /// Bytes the standard walk streams (or the walk made before).
    fn walk_bytes(&mut self, dir: &Path) -> anyhow::Result<u64> {
        let out = dir.join("walk");
        let json = out.join("walk.json");
        if !json.is_file() {
            run_sub(&[
                "walk".into(),
                dir.join("db").display().to_string(),
                "--speed".into(),
                self.args.walk_speed.to_string(),
                "--bandwidth".into(),
                "unlimited".into(),
                "--strategy".into(),
                "ach+prefetch".into(),
                "--pause".into(),
                "1".into(),
                "--out".into(),
                out.display().to_string(),
            ])?;
        }
        let v: serde_json::Value = prerender::store::read_json(&json)?;
        v["runs"][0]["bytes"]
            .as_u64()
            .with_context(|| format!("{}: no bytes in its first run", json.display()))
    }

    /// Build, evaluate and walk one configuration.
    pub fn measure(&mut self, k: &Knobs, base: &Knobs) -> anyhow::Result<Measured> {
        let (dir, pre_cpu, build_cpu) = self.build(k)?;
        let pre_dir = dir.join("prerender");
        let ev = self.evaluate(&dir, &pre_dir)?;
        let walk_bytes = self.walk_bytes(&dir)?;
        let db = streamer::db::Database::open(&dir.join("db"))?;
        let m = db.manifest();
        let samples = m.tracks.first().map_or(0, |t| t.viewpoints.len());
        let length = m.tracks.first().map_or(0.0, |t| t.length);
        Ok(Measured {
            label: k.label(base),
            knobs: k.clone(),
            samples,
            spacing_m: length / samples.saturating_sub(1).max(1) as f64,
            slab_count: m.slabs.len(),
            resolution_ratio: ev.resolution_ratio,
            error: ev.error,
            costs: Costs {
                prerender_cpu_s: pre_cpu,
                build_cpu_s: build_cpu,
                db_bytes: dir_bytes(&dir.join("db")),
                walk_bytes,
                frame_ms: ev.frame_ms,
            },
            dir: dir
                .strip_prefix(&self.setup.root)
                .unwrap_or(&dir)
                .display()
                .to_string(),
        })
    }

    /// The sweep: every configuration, then for each target the combinations (`--combine`)
    /// and the choice; writes the reports into OUT.
    pub fn run(&mut self) -> anyhow::Result<SweepReport> {
        let spec = self.args.spec()?;
        let cost = Cost::parse(&self.args.cost).with_context(|| {
            format!(
                "--cost `{}`: expected one of db-bytes, walk-bytes, prerender-cpu, build-cpu, frame-ms",
                self.args.cost
            )
        })?;
        // Every configuration is evaluated on the GPU: without one, say so before building.
        if self.bench.is_none() && self.gpu.is_none() {
            self.gpu = Some(viewer::gpu::Gpu::new()?);
        }
        let base = spec.base.clone();
        let mut records = Vec::new();
        let configs = spec.configs();
        for (i, k) in configs.iter().enumerate() {
            eprintln!(
                "tune: configuration {} of {}: {}",
                i + 1,
                configs.len(),
                k.label(&base)
            );
            records.push(self.measure(k, &base)?);
        }
        let targets = self.args.target_psnr.clone();
        if self.args.combine {
            for &t in &targets {
                self.combine(&mut records, &base, t, cost)?;
            }
        }
        let selections: Vec<Selection> =
            targets.iter().map(|&t| select(&records, t, cost)).collect();
        let b = self.bench.as_ref();
        let views = format!(
            "{} views between the {} reference samples of the base sampling ({} position(s) per segment × {} direction(s)), {}×{} px at FOV {}° (matched to faces of {} px), against {}; error is PSNR between samples.",
            records.first().map_or(0, |m| m.error.views),
            self.base_samples,
            self.args.per_segment,
            self.args.directions,
            b.map_or(0, |b| b.size.0),
            b.map_or(0, |b| b.size.1),
            self.args.fov,
            self.args.face_size,
            b.map_or(String::new(), |b| b.truth.describe())
        );
        let report = SweepReport::new(
            self.setup.scene.name().to_string(),
            self.track.name.clone(),
            base,
            views,
            records,
            selections,
        );
        let out = &self.setup.root;
        prerender::store::write_json(&out.join("sweep.json"), &report)?;
        prerender::store::write_atomic(&out.join("sweep.csv"), tr::csv(&report).as_bytes())?;
        let mut listed = Vec::new();
        for (stem, title, fig) in tr::figures(&report) {
            prerender::store::write_atomic(
                &out.join(format!("{stem}.svg")),
                charts::svg(&fig)?.as_bytes(),
            )?;
            prerender::store::write_atomic(&out.join(format!("{stem}.png")), &charts::png(&fig)?)?;
            listed.push((format!("{stem}.svg"), title));
        }
        prerender::store::write_atomic(
            &out.join("sweep.md"),
            tr::markdown(&report, &listed).as_bytes(),
        )?;
        eprintln!(
            "tune: {} stage(s) run, {} reused; report in {}",
            self.built,
            self.reused,
            out.join("sweep.md").display()
        );
        prerender::store::write_json(
            &out.join("sweep-run.json"),
            &serde_json::json!({"stages_run": self.built, "stages_reused": self.reused}),
        )?;
        Ok(report)
    }

    /// Greedy combination for one target: the single-knob configurations that reach it and
    /// cost less than the base, cheapest first, each merged into the current choice and kept
    /// when the merged configuration still reaches the target and costs less.
    fn combine(
        &mut self,
        records: &mut Vec<Measured>,
        base: &Knobs,
        target: f64,
        cost: Cost,
    ) -> anyhow::Result<()> {
        let Some(b) = records.iter().find(|m| m.knobs == *base).cloned() else {
            return Ok(());
        };
        if quality(&b) < target {
            return Ok(());
        }
        let mut singles: Vec<Measured> = records
            .iter()
            .filter(|m| {
                m.knobs.differences(base).len() == 1
                    && quality(m) >= target
                    && cost.value(m) < cost.value(&b)
            })
            .cloned()
            .collect();
        singles.sort_by(|x, y| cost.value(x).total_cmp(&cost.value(y)));
        let mut current = b;
        for s in singles {
            let merged = current.knobs.merged(&s.knobs, base);
            if merged == current.knobs {
                continue;
            }
            let m = match records.iter().find(|r| r.knobs == merged) {
                Some(m) => m.clone(),
                None => {
                    eprintln!("tune: combining for {target} dB: {}", merged.label(base));
                    let m = self.measure(&merged, base)?;
                    records.push(m.clone());
                    m
                }
            };
            if quality(&m) >= target && cost.value(&m) < cost.value(&current) {
                current = m;
            }
        }
        Ok(())
    }
}

/// Bytes of the files under `dir`.
pub fn dir_bytes(dir: &Path) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.filter_map(Result::ok)
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                dir_bytes(&p)
            } else {
                e.metadata().map_or(0, |m| m.len())
            }
        })
        .sum()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut sweep = Sweep::new(args)?;
    let report = sweep.run()?;
    print!("{}", tr::table(&report));
    for s in &report.selections {
        println!("\n{}", tr::selection_text(&report, s));
    }
    Ok(())
}
