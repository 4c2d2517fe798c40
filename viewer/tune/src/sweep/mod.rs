//! A sweep: the databases of a [`SweepSpec`] built from shared stages ([`crate::plan`]),
//! each evaluated on the same views against the same anti-aliased ground truth and walked
//! once, then the Pareto tables and figures ([`crate::report`]) and, for each PSNR target,
//! the cheapest configuration (with `combine`, after trying together the knobs that reach
//! it alone). Everything is kept in the sweep's directory: a rerun reuses every stage,
//! evaluation and walk already made.

mod bench;

use std::path::{Path, PathBuf};

use db::ach::AchParams;
use serde::{Deserialize, Serialize};
use stages::build::BuildScene;
use stages::progress::Reporter;

pub use bench::ViewParams;

use self::bench::Bench;
use crate::error::{Context, Error, Result};
use crate::knobs::{Knobs, SweepSpec};
use crate::pareto::{quality, select, Selection};
use crate::plan::{self, Node, Setup, Stage, StageParams};
use crate::record::{Cost, Costs, Measured};
use crate::report::{self as tr, SweepReport};

/// Everything a sweep needs.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepParams {
    /// The scene (POV-Ray: POV-Ray renders the panoramas and the truth).
    pub scene: BuildScene,
    /// A track of the scene, or a track TOML file.
    pub track: String,
    /// The sweep's directory (stages, databases, evaluations, reports).
    pub out: PathBuf,
    /// The configurations, each in range (see [`SweepSpec::check`]).
    pub spec: SweepSpec,
    /// PSNR targets (dB) on the worst 5 % of views: the cheapest configuration for each.
    pub targets: Vec<f64>,
    /// The cost to choose by.
    pub cost: Cost,
    /// For each target, also build and measure the knobs that reach it alone combined,
    /// cheapest saving first, keeping each that still reaches it.
    pub combine: bool,
    pub views: ViewParams,
    /// Speed of the standard walk, m/s (unlimited bandwidth, ACH with prefetch).
    pub walk_speed: f64,
    /// zstd level of the PTMs, and ACH, for every configuration.
    pub zstd_level: i32,
    pub ach: AchParams,
    /// Face size of the low-resolution depth pass (default: the prerender stage's).
    pub lowres_face_size: Option<u32>,
}

/// `node.json`: a stage that completed, and what it cost when it ran.
#[derive(Serialize, Deserialize)]
struct NodeRecord {
    stage: Stage,
    key: String,
    /// The command line that runs the same stage.
    argv: Vec<String>,
    cpu_s: f64,
    wall_s: f64,
}

/// A sweep under way.
pub struct Sweep {
    params: SweepParams,
    setup: Setup,
    track: tracks::Track,
    base_samples: usize,
    bench: Option<Bench>,
    /// The GPU, found before anything is built: a machine without one fails at once.
    gpu: Option<viewer::gpu::Gpu>,
    built: usize,
    reused: usize,
    progress: Reporter,
}

impl Sweep {
    /// A sweep of `params`, its directory made; nothing is built yet.
    pub fn new(mut params: SweepParams, progress: &Reporter) -> Result<Sweep> {
        let v = &params.views;
        if !(v.fov_deg.is_finite() && v.fov_deg > 0.0 && v.fov_deg < 180.0) {
            return Err(Error::Parameter("--fov must be in (0, 180) degrees".into()));
        }
        if !((1..=64).contains(&v.per_segment) && (1..=64).contains(&v.directions)) {
            return Err(Error::Parameter(
                "--per-segment and --directions must be in 1..=64".into(),
            ));
        }
        if !(params.walk_speed.is_finite() && params.walk_speed > 0.0) {
            return Err(Error::Parameter("--walk-speed must be positive".into()));
        }
        let pov = matches!(params.scene, BuildScene::PovRay { .. });
        params.spec.check(pov)?;
        if let BuildScene::PovRay { scene, .. } = &mut params.scene {
            *scene = std::fs::canonicalize(&*scene)
                .with_context(|| format!("POV-Ray scene {}", scene.display()))?;
        }
        let tracer_scene = match &params.scene {
            BuildScene::Tracer(s) => Some(s.as_str()),
            BuildScene::PovRay { .. } => None,
        };
        let track = stages::scene::resolve_track(tracer_scene, &params.track, None)?;
        let base_samples = track.viewpoints().len();
        prerender::store::ensure_writable_dir(&params.out)?;
        let root = std::fs::canonicalize(&params.out)
            .with_context(|| format!("{}", params.out.display()))?;
        let setup = Setup {
            scene: params.scene.clone(),
            root,
            lowres_face_size: params.lowres_face_size,
            zstd_level: params.zstd_level,
            ach_samples: params.ach.samples,
            ach_camera_size: params.ach.camera_size,
        };
        Ok(Sweep {
            params,
            setup,
            track,
            base_samples,
            bench: None,
            gpu: None,
            built: 0,
            reused: 0,
            progress: progress.clone(),
        })
    }

    /// The track file of a sampling: `OUT/tracks/every-N.toml`.
    fn track_file(&self, k: &Knobs) -> Result<(PathBuf, String)> {
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

    /// Run one node's stage in its directory (started from its parent's files).
    fn run_node(&mut self, n: &Node) -> Result<NodeRecord> {
        // A stage killed midway starts again from its parent's files.
        if n.dir.exists() {
            std::fs::remove_dir_all(&n.dir)
                .with_context(|| format!("clearing {}", n.dir.display()))?;
        }
        match &n.parent {
            Some(p) => {
                crate::link::link_tree(p, &n.dir).with_context(|| {
                    format!("starting {} from {}", n.dir.display(), p.display())
                })?;
            }
            None => std::fs::create_dir_all(&n.dir)?,
        }
        let argv = n.command_line();
        let p = &self.progress;
        p.message(&format!(
            "tune: {:?} stage: railview {}",
            n.stage,
            argv.join(" ")
        ));
        let meter = stages::cost::Meter::start();
        let ran = match &n.params {
            StageParams::Prerender(s) => stages::prerender::run(s, p).map(drop),
            StageParams::Slabs(s) => stages::slabs::run(s, p).map(drop),
            StageParams::Cull(s) => stages::cull::run(s, p).map(drop),
            StageParams::Build(s) => stages::build::run(s, p).map(drop),
        };
        ran.with_context(|| format!("stage `{}`", argv.join(" ")))?;
        let (cpu_s, wall_s) = meter.stop();
        let r = NodeRecord {
            stage: n.stage,
            key: n.key.clone(),
            argv,
            cpu_s,
            wall_s,
        };
        prerender::store::write_json(&n.dir.join("node.json"), &r)?;
        self.built += 1;
        Ok(r)
    }

    /// Run (or find) every stage of `k`'s database; returns the database node's directory
    /// and the CPU seconds of its prerender and build stages.
    fn build(&mut self, k: &Knobs) -> Result<(PathBuf, f64, f64)> {
        let (track_file, text) = self.track_file(k)?;
        let nodes = plan::nodes(&self.setup, k, &track_file, &text);
        let (mut pre, mut build) = (0.0, 0.0);
        for n in &nodes {
            let done: Option<NodeRecord> = prerender::store::read_json(&n.dir.join("node.json"))
                .ok()
                .filter(|r: &NodeRecord| r.key == n.key);
            let rec = match done {
                Some(r) => {
                    self.reused += 1;
                    r
                }
                None => self.run_node(n)?,
            };
            if rec.stage.is_prerender() {
                pre += rec.cpu_s;
            } else {
                build += rec.cpu_s;
            }
        }
        let last = nodes
            .last()
            .ok_or_else(|| Error::Outcome("no stages".into()))?
            .dir
            .clone();
        Ok((last, pre, build))
    }

    /// Evaluate a database, the instruments made at the first.
    fn evaluate(&mut self, dir: &Path, pre_dir: &Path) -> Result<bench::EvalRecord> {
        if self.bench.is_none() {
            let gpu = match self.gpu.take() {
                Some(gpu) => gpu,
                None => viewer::gpu::Gpu::new()?,
            };
            let arcs: Vec<f64> = self.track.viewpoints().iter().map(|v| v.s).collect();
            self.bench = Some(Bench::new(
                gpu,
                &self.params.views,
                self.params.spec.base.face_size,
                arcs,
                &dir.join("db"),
                pre_dir,
                &self.setup.root,
            )?);
        }
        let bench = self.bench.as_mut().expect("made above");
        bench.evaluate(dir, pre_dir, &self.progress)
    }

    /// Bytes the standard walk streams (or the walk made before).
    fn walk_bytes(&mut self, dir: &Path) -> Result<u64> {
        let out = dir.join("walk");
        let json = out.join("walk.json");
        if !json.is_file() {
            let db = dir.join("db");
            let command = format!(
                "stage `walk {} --speed {} --bandwidth unlimited --strategy ach+prefetch --pause 1 --out {}`",
                db.display(),
                self.params.walk_speed,
                out.display()
            );
            crate::walk::standard_walk(&db, &out, self.params.walk_speed, &self.progress)
                .context(command)?;
        }
        let v: serde_json::Value = prerender::store::read_json(&json)?;
        v["runs"][0]["bytes"]
            .as_u64()
            .ok_or_else(|| Error::Outcome(format!("{}: no bytes in its first run", json.display())))
    }

    /// Build, evaluate and walk one configuration.
    pub fn measure(&mut self, k: &Knobs, base: &Knobs) -> Result<Measured> {
        let (dir, pre_cpu, build_cpu) = self.build(k)?;
        let pre_dir = dir.join("prerender");
        let ev = self.evaluate(&dir, &pre_dir)?;
        let walk_bytes = self.walk_bytes(&dir)?;
        let db = db::Database::open(&dir.join("db"))?;
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
                db_bytes: stages::encode::walk_size(&dir.join("db")),
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

    /// The sweep: every configuration, then for each target the combinations (`combine`)
    /// and the choice; writes the reports into the sweep's directory.
    pub fn run(&mut self) -> Result<SweepReport> {
        // Every configuration is evaluated on the GPU: without one, say so before building.
        if self.bench.is_none() && self.gpu.is_none() {
            self.gpu = Some(viewer::gpu::Gpu::new()?);
        }
        let base = self.params.spec.base.clone();
        let cost = self.params.cost;
        let mut records = Vec::new();
        let configs = self.params.spec.configs();
        for (i, k) in configs.iter().enumerate() {
            self.progress.message(&format!(
                "tune: configuration {} of {}: {}",
                i + 1,
                configs.len(),
                k.label(&base)
            ));
            records.push(self.measure(k, &base)?);
        }
        let targets = self.params.targets.clone();
        if self.params.combine {
            for &t in &targets {
                self.combine(&mut records, &base, t, cost)?;
            }
        }
        let selections: Vec<Selection> =
            targets.iter().map(|&t| select(&records, t, cost)).collect();
        let views = self.views_text(&records);
        let report = SweepReport::new(
            self.setup.scene.name(),
            self.track.name.clone(),
            base,
            views,
            records,
            selections,
        );
        self.write(&report)?;
        Ok(report)
    }

    /// How the views were chosen and judged, in one line.
    fn views_text(&self, records: &[Measured]) -> String {
        let b = self.bench.as_ref();
        let v = &self.params.views;
        format!(
            "{} views between the {} reference samples of the base sampling ({} position(s) per segment × {} direction(s)), {}×{} px at FOV {}° (matched to faces of {} px), against {}; error is PSNR between samples.",
            records.first().map_or(0, |m| m.error.views),
            self.base_samples,
            v.per_segment,
            v.directions,
            b.map_or(0, |b| b.inst.size.0),
            b.map_or(0, |b| b.inst.size.1),
            v.fov_deg,
            self.params.spec.base.face_size,
            b.map_or(String::new(), |b| b.inst.truth.describe())
        )
    }

    /// `sweep.json`, `sweep.csv`, the figures, `sweep.md` and `sweep-run.json`.
    fn write(&self, report: &SweepReport) -> Result<()> {
        let out = &self.setup.root;
        prerender::store::write_json(&out.join("sweep.json"), report)?;
        prerender::store::write_atomic(&out.join("sweep.csv"), tr::csv(report).as_bytes())?;
        let mut listed = Vec::new();
        for (stem, title, fig) in tr::figures(report) {
            prerender::store::write_atomic(
                &out.join(format!("{stem}.svg")),
                charts::svg(&fig)?.as_bytes(),
            )?;
            prerender::store::write_atomic(&out.join(format!("{stem}.png")), &charts::png(&fig)?)?;
            listed.push((format!("{stem}.svg"), title));
        }
        prerender::store::write_atomic(
            &out.join("sweep.md"),
            tr::markdown(report, &listed).as_bytes(),
        )?;
        self.progress.message(&format!(
            "tune: {} stage(s) run, {} reused; report in {}",
            self.built,
            self.reused,
            out.join("sweep.md").display()
        ));
        prerender::store::write_json(
            &out.join("sweep-run.json"),
            &serde_json::json!({"stages_run": self.built, "stages_reused": self.reused}),
        )?;
        Ok(())
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
    ) -> Result<()> {
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
                    self.progress.message(&format!(
                        "tune: combining for {target} dB: {}",
                        merged.label(base)
                    ));
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
