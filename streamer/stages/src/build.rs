//! The whole pipeline into a database — prerender → slabs → cull → encode (PTM + meshes) →
//! ACH → manifest — with one report ([`BuildReport`], `WORK/build.json` and `build.md`).
//!
//! Culling uses the shrunk variant at α = 1 for built-in and TOML scenes (provably
//! conservative for every track point) and the conservative one otherwise
//! ([`CullChoice`]). A POV-Ray scene ([`BuildScene::PovRay`]) runs the same pipeline: POV-Ray
//! renders the base passes, the slabs stage chooses the boundaries from the low-resolution
//! depth and renders the layers with POV-Ray; culling, encoding and ACH work from the
//! rendered depth alone (no scene geometry needed).
//!
//! Stage outputs live in a work directory (default `DB.work/`): the prerender directory
//! (`prerender/`, which the slabs and cull stages also write into) and the encode stage's
//! records and staged objects (`encode/`). Every stage resumes from what is there, so a
//! killed build continues where it stopped; objects already stored are not rewritten. The
//! report goes to `WORK/build.json` and `WORK/build.md` (not into the database, whose every
//! file `verify` checks).

use std::path::{Path, PathBuf};
use std::time::Instant;

use occlusion::report::TileDecisions;
use occlusion::Variant;
use prerender::runlog::RunLog;
use prerender::store;
use serde::{Deserialize, Serialize};
use slabs::report::SlabsReport;
use slabs::tiles::MeshKind;
use tracks::TrackSet;

use crate::cost::Meter;
use crate::cull::{CullParams, Variants};
use crate::encode::{self, BuildReport, Culling, EncodeDirs, EncodeParams};
use crate::error::{parameter, Context, Result};
use crate::knobs::{CullChoice, Knobs};
use crate::prerender::{PovParams, PrerenderParams, Renderer};
use crate::progress::Reporter;
use crate::slabs::{SlabsParams, Tiling};

/// The scene of a build, and who renders it.
#[derive(Clone, Debug, PartialEq)]
pub enum BuildScene {
    /// A built-in scene name or a scene TOML file: the built-in tracer.
    Tracer(String),
    /// A POV-Ray 3.7 scene (`.pov`), with how POV-Ray renders it (`--supersample` above 1
    /// sets its `supersample`).
    PovRay { scene: PathBuf, pov: PovParams },
}

impl BuildScene {
    fn is_pov(&self) -> bool {
        matches!(self, BuildScene::PovRay { .. })
    }

    /// As the report names it.
    pub fn name(&self) -> String {
        match self {
            BuildScene::Tracer(s) => s.clone(),
            BuildScene::PovRay { scene, .. } => scene.display().to_string(),
        }
    }
}

/// Everything a build needs.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildParams {
    pub scene: BuildScene,
    /// A track of the scene, or a track TOML file (POV-Ray: the track file, whose first
    /// track is used unless `track_name` says otherwise).
    pub track: String,
    /// Which track of the track file.
    pub track_name: Option<String>,
    /// The database directory to write.
    pub out: PathBuf,
    /// The work directory (default: `OUT.work` beside the database).
    pub work: Option<PathBuf>,
    /// Face size of the low-resolution depth pass (default: the prerender stage's).
    pub lowres_face_size: Option<u32>,
    /// The knobs (its `every` is not used: the track is sampled as `samples`/`spacing_m` say).
    pub knobs: Knobs,
    /// Which mesh tiles carry and the grid step of the regular one (default: the slabs
    /// stage's).
    pub mesh: Option<MeshKind>,
    pub mesh_step: Option<u32>,
    /// How the tiles are coded; its `zstd_level` and `drop_levels` are the knobs'.
    pub encode: EncodeParams,
    /// Where the report goes when not into the work directory.
    pub report_dir: Option<PathBuf>,
    /// What chose these knobs and why, for the report (`build.json`'s `target`).
    pub evidence: Option<serde_json::Value>,
}

impl BuildParams {
    /// A build of `scene` along `track` into `out` with the command's defaults.
    pub fn new(scene: BuildScene, track: &str, out: &Path) -> BuildParams {
        BuildParams {
            scene,
            track: track.to_string(),
            track_name: None,
            out: out.to_path_buf(),
            work: None,
            lowres_face_size: None,
            knobs: Knobs {
                cull: CullChoice::Auto,
                ..Knobs::default()
            },
            mesh: None,
            mesh_step: None,
            encode: EncodeParams::default(),
            report_dir: None,
            evidence: None,
        }
    }

    /// The work directory: as given, or `OUT.work`.
    pub fn work_dir(&self) -> PathBuf {
        self.work.clone().unwrap_or_else(|| {
            let mut w = self.out.clone().into_os_string();
            w.push(".work");
            PathBuf::from(w)
        })
    }

    /// Colour rays per pixel along each axis of POV-Ray's panoramas (`--supersample N`, or
    /// `--aa` for 2); 1 for the tracer, whose knob is `supersample` itself.
    pub fn pov_supersample(&self) -> u32 {
        match &self.scene {
            BuildScene::PovRay { pov, .. } => self.knobs.supersample.max(pov.supersample).max(1),
            BuildScene::Tracer(_) => 1,
        }
    }

    /// The culling variant of the database (none keeps every non-empty tile); a variant
    /// that cannot run with these knobs is an error.
    pub fn cull_variant(&self) -> Result<Option<Variant>> {
        let k = &self.knobs;
        if let CullChoice::Variant(v) = k.cull {
            if !v.takes_alpha() && k.alpha != 1.0 {
                return Err(parameter!(
                    "--cull-variant {} runs at α = 1 only (found --alpha {})",
                    v.name(),
                    k.alpha
                ));
            }
        }
        if k.cull == CullChoice::Variant(Variant::Shrunk) && self.scene.is_pov() {
            return Err(parameter!(
                "--cull-variant shrunk needs the scene's solids: not with --pov (the rendered \
                 variant works from POV-Ray's depth renders)"
            ));
        }
        Ok(k.cull.resolve(self.scene.is_pov(), k.alpha))
    }

    /// Every number against its limit, before any stage runs.
    pub fn check(&self) -> Result<()> {
        use tracks::limits::{check_f64, MAX_VIEWPOINTS};
        let k = &self.knobs;
        crate::check_face_size("--face-size", k.face_size)?;
        if let Some(n) = self.lowres_face_size {
            crate::check_face_size("--lowres-face-size", n)?;
        }
        if let Some(n) = k.samples {
            crate::check_count("--samples", n, MAX_VIEWPOINTS)?;
        }
        if let Some(d) = k.spacing_m {
            if !(d.is_finite() && d > 0.0) {
                return Err(parameter!(
                    "--spacing {d}: must be a positive number of metres"
                ));
            }
        }
        if !(1..=16).contains(&k.supersample) {
            return Err(parameter!(
                "--supersample {}: must be from 1 to 16",
                k.supersample
            ));
        }
        let most = prerender::pov::MAX_SUPERSAMPLE;
        if self.scene.is_pov() && k.supersample > most {
            return Err(parameter!(
                "--supersample {} with --pov: POV-Ray imports render colour at most {most}×{most} rays a pixel",
                k.supersample
            ));
        }
        if !(k.tile_size.is_power_of_two() && (4..=1024).contains(&k.tile_size)) {
            return Err(parameter!(
                "--tile-size {}: a power of two from 4 to 1024",
                k.tile_size
            ));
        }
        if !(k.mesh_error_px.is_finite() && k.mesh_error_px > 0.0) {
            return Err(parameter!(
                "--mesh-error {}: must be a positive number of pixels",
                k.mesh_error_px
            ));
        }
        self.cull_variant()?;
        // α = 0 would keep nothing behind the first slab; the culling stage refuses it too.
        if !(k.alpha.is_finite() && k.alpha > 0.0 && k.alpha <= 1.0) {
            return Err(parameter!(
                "--alpha {}: must be a number in (0, 1]",
                k.alpha
            ));
        }
        if k.drop_levels > 8 {
            return Err(parameter!(
                "--drop-levels {}: must be at most 8",
                k.drop_levels
            ));
        }
        if !(-7..=22).contains(&k.zstd_level) {
            return Err(parameter!(
                "--zstd-level {}: must be from -7 to 22",
                k.zstd_level
            ));
        }
        crate::check_count("--ach-samples", self.encode.ach.samples, 1024)?;
        crate::check_face_size("--ach-camera-size", self.encode.ach.camera_size)?;
        if let BuildScene::PovRay { pov, .. } = &self.scene {
            if let Some(t) = pov.timeout_secs {
                check_f64("--timeout-secs", t, 0.001, 1e6)?;
            }
        }
        Ok(())
    }

    /// The track file the first stage renders: the track as given, or resampled to the
    /// knobs' `samples` or `spacing_m` (written to `WORK/track-resampled.toml`).
    pub fn track_file(&self, work: &Path) -> Result<String> {
        use tracks::Sampling;
        let sampling = match (self.knobs.samples, self.knobs.spacing_m) {
            (Some(n), _) => Sampling::Count(n),
            (None, Some(d)) => Sampling::Spacing(d),
            (None, None) => return Ok(self.track.clone()),
        };
        let scene = match &self.scene {
            BuildScene::Tracer(s) => Some(s.as_str()),
            BuildScene::PovRay { .. } => None,
        };
        let mut track = crate::scene::resolve_track(scene, &self.track, self.track_name.as_deref())
            .context("--samples/--spacing")?;
        track.sampling = sampling;
        let path = work.join("track-resampled.toml");
        let one = TrackSet {
            tracks: vec![track],
        };
        store::write_atomic(&path, one.to_toml().as_bytes())?;
        Ok(path.display().to_string())
    }

    /// The first stage: the tracer's prerender, or POV-Ray's base passes (the slabs stage
    /// renders the layers it chooses).
    pub fn prerender_params(&self, track: &str, pre_root: &Path) -> Result<PrerenderParams> {
        let (scene, renderer, track_name) = match &self.scene {
            BuildScene::Tracer(scene) => (
                scene.clone(),
                Renderer::Builtin {
                    supersample: self.knobs.supersample,
                    shadows: true,
                },
                None,
            ),
            BuildScene::PovRay { scene, pov } => {
                if !Path::new(&self.track).is_file() {
                    return Err(parameter!(
                        "--pov needs --track TRACK.toml (a track file); `{}` is not a file",
                        self.track
                    ));
                }
                let resampled = track != self.track;
                let pov = PovParams {
                    supersample: self.pov_supersample(),
                    ..pov.clone()
                };
                (
                    scene.display().to_string(),
                    Renderer::PovRay(pov),
                    self.track_name.clone().filter(|_| !resampled),
                )
            }
        };
        Ok(PrerenderParams {
            scene,
            track: track.to_string(),
            track_name,
            face_size: self.knobs.face_size,
            lowres_face_size: self.lowres_face_size,
            out: pre_root.to_path_buf(),
            slabs: None,
            shard: None,
            merge: false,
            renderer,
        })
    }

    /// The second stage: the knobs' slabs and tiling (each sample whose tiles were made with
    /// these parameters is kept as it is).
    pub fn slabs_params(&self, pre_root: &Path) -> SlabsParams {
        SlabsParams {
            slabs: self.knobs.slabs.clone(),
            tiling: Tiling {
                tile_size: self.knobs.tile_size,
                mesh: self.mesh.unwrap_or(MeshKind::Adaptive),
                mesh_step: self.mesh_step.unwrap_or(crate::slabs::DEFAULT_MESH_STEP),
                mesh_error_px: self.knobs.mesh_error_px,
                ..Tiling::default()
            },
            ..SlabsParams::new(pre_root)
        }
    }

    /// The encode stage's coding with the knobs' zstd level and levels left out.
    fn encode_params(&self) -> EncodeParams {
        EncodeParams {
            zstd_level: self.knobs.zstd_level,
            drop_levels: self.knobs.drop_levels,
            ..self.encode
        }
    }
}

/// Panoramas are reused only when rendered with the same anti-aliasing: the samples do not
/// record it, so `WORK/panoramas.json` does.
fn check_panoramas(work: &Path, params: &BuildParams) -> Result<()> {
    #[derive(Serialize, Deserialize, PartialEq)]
    struct Panoramas {
        supersample: u32,
        aa: bool,
    }
    let ss = match params.scene {
        BuildScene::PovRay { .. } => params.pov_supersample(),
        BuildScene::Tracer(_) => params.knobs.supersample,
    };
    let want = Panoramas {
        supersample: ss,
        aa: params.scene.is_pov() && ss > 1,
    };
    let path = work.join("panoramas.json");
    if let Ok(had) = store::read_json::<Panoramas>(&path) {
        if had != want && work.join("prerender").join("prerender.json").is_file() {
            return Err(parameter!(
                "{} holds panoramas rendered with {}×{} rays per pixel; give another --work (or remove it) to render them with {}×{}",
                work.display(),
                had.supersample,
                had.supersample,
                want.supersample,
                want.supersample
            ));
        }
    }
    store::write_json(&path, &want)?;
    Ok(())
}

fn stage(progress: &Reporter, n: usize, what: &str) {
    progress.message(&format!("[{n}/6] {what}"));
}

/// A stage's error, said to be that stage's (its command line).
fn in_stage(command: Vec<String>) -> impl FnOnce(crate::Error) -> crate::Error {
    move |e| e.context(format!("stage `{}`", command.join(" ")))
}

/// Run the whole pipeline; the report is written and returned.
pub fn run(params: &BuildParams, progress: &Reporter) -> Result<BuildReport> {
    params.check()?;
    let t_all = Instant::now();
    let cpu_all = Meter::start();
    let work = params.work_dir();
    store::ensure_writable_dir(&work)?;
    check_panoramas(&work, params)?;
    let track = params.track_file(&work)?;
    let pre_root = work.join("prerender");
    let mut report = BuildReport {
        scene: params.scene.name(),
        track: params.track.clone(),
        face_size: params.knobs.face_size,
        config: (&params.knobs).into(),
        ..BuildReport::default()
    };
    let log = RunLog::create(&work, "build", None)?;

    // 1–3: the other stages, each resuming on its own.
    let m = Meter::start();
    stage(progress, 1, "prerender");
    let pre = params.prerender_params(&track, &pre_root)?;
    crate::prerender::run(&pre, progress).map_err(in_stage(pre.command_line()))?;
    report.stage_done("prerender", m);
    let m = Meter::start();
    stage(progress, 2, "slabs");
    let slabs = params.slabs_params(&pre_root);
    crate::slabs::run(&slabs, progress).map_err(in_stage(slabs.command_line()))?;
    let tiling: SlabsReport = store::read_json(&pre_root.join("slabs.json"))
        .context("reading the slabs stage's report")?;
    report.stage_done("slabs", m);
    let m = Meter::start();
    stage(progress, 3, "cull");
    let culling = cull(params, &pre_root, &tiling, progress)?;
    report.culling = culling.summary.clone();
    report.stage_done("cull", m);

    // 4–6: encode every sample's tiles and background into the database, ACH, manifest.
    let dirs = EncodeDirs {
        out: params.out.clone(),
        work: work.clone(),
    };
    encode::run(
        &dirs,
        &params.encode_params(),
        &tiling,
        &culling,
        &mut report,
        progress,
    )?;
    report
        .seconds
        .push(("total".into(), t_all.elapsed().as_secs_f64()));
    report.cpu_seconds.push(("total".into(), cpu_all.stop().0));
    report.target = params.evidence.clone();
    let stage_seconds: Vec<(&str, serde_json::Value)> = report
        .seconds
        .iter()
        .map(|(name, secs)| (name.as_str(), (*secs).into()))
        .collect();
    log.end(&stage_seconds)?;
    let report_dir = params.report_dir.clone().unwrap_or(work);
    store::write_json(&report_dir.join("build.json"), &report)?;
    let md = report.markdown();
    store::write_atomic(&report_dir.join("build.md"), md.as_bytes())?;
    progress.output(&format!("{md}\n"));
    progress.message(&format!(
        "wrote {} (report: {})",
        params.out.join("manifest.json").display(),
        report_dir.join("build.md").display()
    ));
    Ok(report)
}

/// The cull stage's decisions for the knobs' variant and α: those already made on this tile
/// grid, or a run of the stage; where it cannot run, every non-empty tile is kept.
fn cull(
    params: &BuildParams,
    pre_root: &Path,
    tiling: &SlabsReport,
    progress: &Reporter,
) -> Result<Culling> {
    let variant = params.cull_variant()?;
    let alpha = params.knobs.alpha;
    // Decisions made on another tile grid (a rebuild with another tile size) are stale.
    let fits = |d: &TileDecisions| {
        d.grid.tile_size == tiling.tile_size && d.grid.face_size == tiling.face_size
    };
    let decisions = match variant {
        None => None,
        Some(v) => match cull_decisions(pre_root, alpha, v).filter(fits) {
            Some(d) => Some(d),
            None => {
                let cull = CullParams {
                    dir: pre_root.to_path_buf(),
                    alphas: vec![alpha],
                    variants: Variants::These(vec![v]),
                    oracle: None,
                    renders_per_segment: None,
                };
                match crate::cull::run(&cull, progress).map_err(in_stage(cull.command_line())) {
                    Ok(_) => cull_decisions(pre_root, alpha, v).filter(fits),
                    Err(e) => {
                        progress.message(&format!(
                            "      culling unavailable ({}): every non-empty tile is kept",
                            e.chain()
                        ));
                        None
                    }
                }
            }
        },
    };
    let summary = match (&decisions, variant) {
        (Some(_), Some(v)) => format!("{}, α = {}", v.name(), alpha),
        (_, None) => "none (--cull-variant none): every non-empty tile kept".into(),
        (None, Some(_)) => "none (cull stage unavailable): every non-empty tile kept".into(),
    };
    Ok(Culling {
        decisions,
        variant,
        alpha,
        summary,
    })
}

/// Kept/culled decisions of the run with this α and variant, by viewpoint and slab.
fn cull_decisions(pre_root: &Path, alpha: f64, variant: Variant) -> Option<TileDecisions> {
    let d: TileDecisions = store::read_json(&pre_root.join("cull_tiles.json")).ok()?;
    let run = d
        .runs
        .iter()
        .find(|r| (r.alpha - alpha).abs() < 1e-9 && r.variant == variant)?
        .clone();
    Some(TileDecisions {
        grid: d.grid,
        runs: vec![run],
    })
}
