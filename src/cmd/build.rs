//! `railview build --scene NAME --track NAME --face-size N --out DB`: the whole pipeline —
//! prerender → slabs → cull → encode (PTM + meshes) → ACH → manifest — with one report.
//! Culling uses the shrunk variant at α = 1 for built-in and TOML scenes (provably
//! conservative for every track point) and the conservative one otherwise (`--cull-variant`).
//! `railview build --pov SCENE.pov --track TRACK.toml [--up y|z] …` runs the same pipeline on
//! a POV-Ray scene: `import-pov` renders the base passes, `slabs` chooses the boundaries from
//! the low-resolution depth and renders the layers with POV-Ray; culling, encoding and ACH
//! work from the rendered depth alone (no scene geometry needed).
//!
//! Stage outputs live in a work directory (`--work`, default `DB.work/`): the prerender
//! directory (`prerender/`, which `slabs` and `cull` also write into) and one encoded
//! viewpoint record per sample (`encode/NNNN.json`) with the tiles' own PTM and mesh objects
//! (`encode/objects/`; each viewpoint's pack in the database is made from them, so the
//! database holds only what its manifest refers to). Every stage resumes from what is there,
//! so a killed build continues where it stopped; objects already stored are not rewritten. The report goes to `WORK/build.json` and `WORK/build.md` (not into the database,
//! whose every file `verify` checks).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use occlusion::report::TileDecisions;
use occlusion::Variant;
use prerender::runlog::RunLog;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use serde::{Deserialize, Serialize};
use slabs::io as sio;
use streamer::db::ach::{segment_ach, AchParams, AchTile, SegmentEnd};
use streamer::db::mesh::{encode_mesh, MeshCoding, MeshData};
use streamer::db::DbWriter;
use streamer::ptm::{self, EncodeOptions, Image};
use tracks::manifest::{
    BackgroundTile, Manifest, SegmentEntry, TileEntry, TrackEntry, ViewpointEntry, MANIFEST_VERSION,
};
use tracks::{CubeMap, TileGrid, TrackSet};

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
    pub up: Option<String>,
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
    /// (anti-aliasing). Built-in and scene-file scenes; with --pov, 2 is --aa.
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
    /// against the scene's solids), `conservative`, `paper`, `none` (keep every non-empty
    /// tile), or `auto`: shrunk at α = 1 for built-in and TOML scenes, conservative otherwise
    /// (POV-Ray imports, α < 1).
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
    /// Where the report goes when not into the work directory (the choice of --target-psnr
    /// builds in the sweep's directory and reports beside the database).
    #[arg(skip)]
    pub report_dir: Option<PathBuf>,
    /// What --target-psnr chose and why, for the report.
    #[arg(skip)]
    pub evidence: Option<serde_json::Value>,
}

/// Bytes at each stage (raw RGBA8 unless stated), and the baseline they are weighed against.
#[derive(Clone, Debug, Default, Serialize)]
struct Sizes {
    panoramas_rgba: u64,
    slab_layers_rgba: u64,
    nonempty_tiles_rgba: u64,
    kept_tiles_rgba: u64,
    /// The kept tiles' PTMs and meshes as encoded, each tile counted (before payloads
    /// repeated across tiles are stored once).
    kept_tiles_ptm: u64,
    meshes: u64,
    backgrounds_ptm: u64,
    /// Kept tiles, and those with a mesh.
    kept_tiles: u64,
    meshes_count: u64,
    /// Payloads found already stored (in an earlier pack, or earlier in the same one), and
    /// their bytes, not stored again.
    payloads_shared: u64,
    bytes_shared: u64,
    database_objects: u64,
    /// The baseline: every reference panorama as a PNG of its colour and a 16-bit PNG of
    /// its disparity-quantised depth (`streamer::db::baseline`).
    baseline_colour_png: u64,
    baseline_depth_png16: u64,
    baseline: u64,
    /// `database_objects / baseline`.
    db_over_baseline: f64,
}

#[derive(Clone, Debug, Default, Serialize)]
struct SlabRow {
    slab: usize,
    tiles_nonempty: usize,
    tiles_kept: usize,
    rgba_nonempty: u64,
    rgba_kept: u64,
    ptm_kept: u64,
}

/// The knobs a database was built with (`build.json`'s `config`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BuildConfig {
    pub samples: Option<usize>,
    pub spacing_m: Option<f64>,
    pub face_size: u32,
    pub supersample: u32,
    pub slabs: String,
    pub tile_size: u32,
    pub mesh_error_px: f64,
    pub cull_variant: String,
    pub alpha: f64,
    pub drop_levels: u32,
    pub zstd_level: i32,
}

impl BuildConfig {
    fn of(a: &Args) -> BuildConfig {
        BuildConfig {
            samples: a.samples,
            spacing_m: a.spacing,
            face_size: a.face_size,
            supersample: a.supersample,
            slabs: a.slabs.clone(),
            tile_size: a.tile_size,
            mesh_error_px: a.mesh_error,
            cull_variant: a.cull_variant.clone(),
            alpha: a.alpha,
            drop_levels: a.drop_levels,
            zstd_level: a.zstd_level,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
struct BuildReport {
    scene: String,
    track: String,
    face_size: u32,
    tile_size: u32,
    samples: usize,
    culling: String,
    config: BuildConfig,
    sizes: Sizes,
    slabs: Vec<SlabRow>,
    /// Wall seconds per stage.
    seconds: Vec<(String, f64)>,
    /// CPU seconds per stage (this process's threads and the POV-Ray renders it waited
    /// for); a stage that found its outputs already there costs next to nothing.
    cpu_seconds: Vec<(String, f64)>,
    objects_written: u64,
    objects_reused: u64,
    /// With --target-psnr: the target, the choice, what it left out and saved, the sweep.
    #[serde(skip_serializing_if = "Option::is_none")]
    target: Option<serde_json::Value>,
}

impl BuildReport {
    fn stage_done(&mut self, name: &str, meter: tune::cost::Meter) {
        let (cpu, wall) = meter.stop();
        self.seconds.push((name.into(), wall));
        self.cpu_seconds.push((name.into(), cpu));
    }
}

/// What `encode/NNNN.json` holds: a finished viewpoint and what produced it.
#[derive(Serialize, Deserialize)]
struct EncodedSample {
    key: String,
    entry: ViewpointEntry,
    rgba_nonempty: Vec<u64>,
    rgba_kept: Vec<u64>,
    tiles_nonempty: Vec<usize>,
}

fn stage(n: usize, what: &str) {
    eprintln!("[{n}/6] {what}");
}

pub(crate) fn run_sub(argv: &[String]) -> anyhow::Result<()> {
    let mut full = vec!["railview".to_string()];
    full.extend_from_slice(argv);
    let cli = crate::Cli::try_parse_from(&full)
        .with_context(|| format!("`{}` is not available in this build", argv[0]))?;
    crate::dispatch(cli.command).with_context(|| format!("stage `{}`", argv.join(" ")))
}

fn bar(n: u64, what: &str) -> ProgressBar {
    let b = ProgressBar::new(n);
    if let Ok(style) = ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} {eta}") {
        b.set_style(style);
    }
    b.set_message(what.to_string());
    b
}

/// Every number of the command line against its limit, before any stage runs.
fn check_args(args: &Args) -> anyhow::Result<()> {
    use tracks::limits::{check_f64, MAX_VIEWPOINTS};
    super::face_size("--face-size", args.face_size)?;
    if let Some(n) = args.lowres_face_size {
        super::face_size("--lowres-face-size", n)?;
    }
    if let Some(n) = args.samples {
        super::count("--samples", n, MAX_VIEWPOINTS)?;
    }
    if let Some(d) = args.spacing {
        anyhow::ensure!(
            d.is_finite() && d > 0.0,
            "--spacing {d}: must be a positive number of metres"
        );
    }
    anyhow::ensure!(
        (1..=16).contains(&args.supersample),
        "--supersample {}: must be from 1 to 16",
        args.supersample
    );
    anyhow::ensure!(
        args.pov.is_none() || args.supersample <= 2,
        "--supersample {} with --pov: POV-Ray imports anti-alias 2×2 (--supersample 2 or --aa) or not at all",
        args.supersample
    );
    anyhow::ensure!(
        args.tile_size.is_power_of_two() && (4..=1024).contains(&args.tile_size),
        "--tile-size {}: a power of two from 4 to 1024",
        args.tile_size
    );
    anyhow::ensure!(
        args.mesh_error.is_finite() && args.mesh_error > 0.0,
        "--mesh-error {}: must be a positive number of pixels",
        args.mesh_error
    );
    cull_variant(args)?;
    // α = 0 would keep nothing behind the first slab; the culling stage refuses it too.
    anyhow::ensure!(
        args.alpha.is_finite() && args.alpha > 0.0 && args.alpha <= 1.0,
        "--alpha {}: must be a number in (0, 1]",
        args.alpha
    );
    anyhow::ensure!(
        args.drop_levels <= 8,
        "--drop-levels {}: must be at most 8",
        args.drop_levels
    );
    anyhow::ensure!(
        (-7..=22).contains(&args.zstd_level),
        "--zstd-level {}: must be from -7 to 22",
        args.zstd_level
    );
    super::count("--ach-samples", args.ach_samples, 1024)?;
    super::face_size("--ach-camera-size", args.ach_camera_size)?;
    if let Some(t) = args.timeout_secs {
        check_f64("--timeout-secs", t, 0.001, 1e6)?;
    }
    Ok(())
}

/// The track `track` names: a track file (its track `track_name`, `main` or its only one),
/// or a track of the scene (built-in or scene file).
pub(crate) fn resolve_track(
    scene: Option<&str>,
    track: &str,
    track_name: Option<&str>,
) -> anyhow::Result<tracks::Track> {
    let from_file = |path: &Path| -> anyhow::Result<TrackSet> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading track file {}", path.display()))?;
        Ok(TrackSet::parse(&text, &path.display().to_string())?)
    };
    let set = if Path::new(track).is_file() {
        from_file(Path::new(track))?
    } else if let Some(b) = scene.and_then(prerender::scenes::builtin) {
        b.tracks
    } else if let Some(scene) = scene.filter(|s| Path::new(s).is_file()) {
        let text = std::fs::read_to_string(scene)
            .with_context(|| format!("reading scene file {scene}"))?;
        prerender::parse::tracks_from_scene_toml(&text, scene)?
            .with_context(|| format!("{scene} has no [[track]]"))?
    } else {
        bail!("track `{track}` is neither a track file nor a track of the scene");
    };
    let name = track_name.unwrap_or(track);
    Ok(match set.get(name) {
        Some(t) => t.clone(),
        None if set.tracks.len() == 1 => set.tracks[0].clone(),
        None => set.get("main").cloned().with_context(|| {
            format!(
                "no track `{name}` or `main` among {}",
                set.names().join(", ")
            )
        })?,
    })
}

/// The track file the first stage renders: the track as given, or resampled to `--samples`
/// or `--spacing` (written to `WORK/track-resampled.toml`).
fn track_arg(args: &Args, work: &Path) -> anyhow::Result<String> {
    use tracks::Sampling;
    let sampling = match (args.samples, args.spacing) {
        (Some(n), _) => Sampling::Count(n),
        (None, Some(d)) => Sampling::Spacing(d),
        (None, None) => return Ok(args.track.clone()),
    };
    let mut track = resolve_track(
        args.scene.as_deref(),
        &args.track,
        args.track_name.as_deref(),
    )
    .context("--samples/--spacing")?;
    track.sampling = sampling;
    let path = work.join("track-resampled.toml");
    let one = TrackSet {
        tracks: vec![track],
    };
    store::write_atomic(&path, one.to_toml().as_bytes())?;
    Ok(path.display().to_string())
}

/// Panoramas are reused only when rendered with the same anti-aliasing: the samples do not
/// record it, so `WORK/panoramas.json` does.
fn check_panoramas(work: &Path, args: &Args) -> anyhow::Result<()> {
    #[derive(Serialize, Deserialize, PartialEq)]
    struct Panoramas {
        supersample: u32,
        aa: bool,
    }
    let want = Panoramas {
        supersample: args.supersample,
        aa: args.aa || (args.pov.is_some() && args.supersample == 2),
    };
    let path = work.join("panoramas.json");
    if let Ok(had) = store::read_json::<Panoramas>(&path) {
        if had != want && work.join("prerender").join("prerender.json").is_file() {
            bail!(
                "{} holds panoramas rendered with {}×{} rays per pixel; give another --work (or remove it) to render them with {}×{}",
                work.display(),
                had.supersample,
                had.supersample,
                want.supersample,
                want.supersample
            );
        }
    }
    store::write_json(&path, &want)?;
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    check_args(&args)?;
    if let Some(target) = args.target_psnr {
        return build_for_target(args, target);
    }
    let t_all = Instant::now();
    let cpu_all = tune::cost::Meter::start();
    let work = args.work.clone().unwrap_or_else(|| {
        let mut w = args.out.clone().into_os_string();
        w.push(".work");
        PathBuf::from(w)
    });
    store::ensure_writable_dir(&work)?;
    check_panoramas(&work, &args)?;
    let track = track_arg(&args, &work)?;
    let pre_root = work.join("prerender");
    let dir = PrerenderDir::new(&pre_root);
    let scene_name = match (&args.scene, &args.pov) {
        (Some(s), _) => s.clone(),
        (None, Some(p)) => p.display().to_string(),
        (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
    };
    let mut report = BuildReport {
        scene: scene_name,
        track: args.track.clone(),
        face_size: args.face_size,
        config: BuildConfig::of(&args),
        ..BuildReport::default()
    };
    let p = |x: &Path| x.display().to_string();
    let log = RunLog::create(&work, "build", None)?;

    // 1–3: the other stages, each resuming on its own.
    let m = tune::cost::Meter::start();
    stage(1, "prerender");
    run_sub(&prerender_argv(&args, &track, &pre_root)?)?;
    report.stage_done("prerender", m);
    let m = tune::cost::Meter::start();
    stage(2, "slabs");
    // Each sample whose tiles were made with these parameters is kept as it is.
    let mut argv = vec![
        "slabs".into(),
        p(&pre_root),
        "--slabs".into(),
        args.slabs.clone(),
    ];
    argv.extend(TilingWanted::from_args(&args)?.argv());
    run_sub(&argv)?;
    let tiling: slabs::report::SlabsReport = store::read_json(&pre_root.join("slabs.json"))
        .context("reading the slabs stage's report")?;
    report.stage_done("slabs", m);
    let m = tune::cost::Meter::start();
    stage(3, "cull");
    let variant = cull_variant(&args)?;
    // Decisions made on another tile grid (a rebuild with another --tile-size) are stale.
    let fits = |d: &TileDecisions| {
        d.grid.tile_size == tiling.tile_size && d.grid.face_size == tiling.face_size
    };
    let decisions = match variant {
        None => None,
        Some(v) => match cull_decisions(&pre_root, args.alpha, v).filter(fits) {
            Some(d) => Some(d),
            None => match run_sub(&[
                "cull".into(),
                p(&pre_root),
                "--alpha".into(),
                args.alpha.to_string(),
                "--variant".into(),
                v.name().into(),
            ]) {
                Ok(()) => cull_decisions(&pre_root, args.alpha, v).filter(fits),
                Err(e) => {
                    eprintln!("      culling unavailable ({e:#}): every non-empty tile is kept");
                    None
                }
            },
        },
    };
    report.culling = match (&decisions, variant) {
        (Some(_), Some(v)) => format!("{}, α = {}", v.name(), args.alpha),
        (_, None) => "none (--cull-variant none): every non-empty tile kept".into(),
        (None, Some(_)) => "none (cull stage unavailable): every non-empty tile kept".into(),
    };
    report.stage_done("cull", m);

    // 4: encode every sample's tiles and background into the database.
    let m = tune::cost::Meter::start();
    stage(4, "encode (PTM + meshes)");
    let mut pre: PrerenderReport = dir.read_report().context("reading the prerender report")?;
    report.track = pre.track.clone();
    if pre.slabs.is_empty() {
        // A resumed prerender rewrites its report without the slabs; the layers know them.
        if let Some(m) = pre
            .viewpoints
            .first()
            .and_then(|v| dir.layers_meta(v.index))
        {
            pre.slabs = m.slabs;
        }
    }
    if pre.slabs.is_empty() {
        bail!(
            "{}: no slab layers after the slabs stage",
            dir.report_json().display()
        );
    }
    // The tiles' own PTM and mesh objects, which the viewpoints' packs replace, stay in the
    // work directory: the database holds only what its manifest refers to.
    let staged_objects = work.join("encode");
    let method = match args.ptm_method.as_str() {
        "arith" => ptm::Method::Arith,
        "zstd" => ptm::Method::Zstd,
        other => bail!("--ptm-method `{other}`: expected `arith` or `zstd`"),
    };
    if args.lossy_near > ptm::MAX_NEAR || (args.lossy_near > 0 && method != ptm::Method::Arith) {
        bail!(
            "--lossy-near {}: at most {} and only with --ptm-method arith",
            args.lossy_near,
            ptm::MAX_NEAR
        );
    }
    if !(0.001..=10.0).contains(&args.depth_error_px) {
        bail!(
            "--depth-error-px {}: expected 0.001 to 10 pixels of parallax",
            args.depth_error_px
        );
    }
    let mut writer = DbWriter::create(&args.out)?.with_stage(&staged_objects)?;
    if !writer.leftovers_removed.is_empty() {
        eprintln!(
            "      removed {} temporary file(s) of an interrupted build",
            writer.leftovers_removed.len()
        );
    }
    let opts = EncodeOptions {
        method,
        zstd_level: args.zstd_level,
        near: args.lossy_near,
        ..EncodeOptions::default()
    };
    let mesh_coding = MeshCoding::for_parallax(
        tiling.face_size,
        tiling.mesh_params.baseline_m,
        args.depth_error_px,
    );
    // `db{TOP_VERSION}`: a format's rule on the PTMs' content (format 5 clears the colour
    // under the mask) re-encodes samples encoded under another; so does any other knob, and
    // tiles meshed with other parameters.
    let key = format!(
        "ptm-v{} db{} {:?} zstd{} near{} mesh-v{} depth{} tiles:{}/{}/{:?}/{:?} cull:{} drop:{}",
        ptm::FORMAT_VERSION,
        streamer::db::TOP_VERSION,
        method,
        args.zstd_level,
        args.lossy_near,
        streamer::db::mesh::MESH_VERSION,
        args.depth_error_px,
        tiling.face_size,
        tiling.tile_size,
        tiling.mesh_kind,
        tiling.mesh_params,
        report.culling,
        args.drop_levels
    );
    let enc_dir = work.join("encode");
    let mut viewpoints = Vec::new();
    let mut grid = None;
    let nslabs = pre.slabs.len();
    let mut rows: Vec<SlabRow> = (0..nslabs)
        .map(|slab| SlabRow {
            slab,
            ..SlabRow::default()
        })
        .collect();
    let b = bar(pre.viewpoints.len() as u64, "encoding");
    for vp in &pre.viewpoints {
        let path = enc_dir.join(format!("{:04}.json", vp.index));
        let tiles_bytes = std::fs::read(sio::tiles_json(&dir, vp.index))
            .with_context(|| format!("sample {}: reading its tiles file", vp.index))?;
        let key = format!("{key} tiles:{:016x}", fnv64(&tiles_bytes));
        let cached: Option<EncodedSample> = store::read_json(&path)
            .ok()
            .filter(|c: &EncodedSample| c.key == key && all_present(writer.stage_root(), &c.entry));
        let sample = match cached {
            Some(c) => c,
            None => {
                let s = encode_sample(
                    &dir,
                    vp,
                    &pre,
                    decisions.as_ref(),
                    (&opts, &mesh_coding),
                    args.drop_levels,
                    &mut writer,
                    &key,
                )?;
                store::write_json(&path, &s)?;
                // The manifest is always assembled from these records, so a resumed build
                // gives the same bytes (JSON float parsing is not always bit-exact).
                store::read_json(&path)?
            }
        };
        let (file, _) = sio::read_tiles(&dir, vp.index)?;
        grid = Some(file.grid);
        for (k, row) in rows.iter_mut().enumerate() {
            row.tiles_nonempty += sample.tiles_nonempty.get(k).copied().unwrap_or(0);
            row.rgba_nonempty += sample.rgba_nonempty.get(k).copied().unwrap_or(0);
            row.rgba_kept += sample.rgba_kept.get(k).copied().unwrap_or(0);
        }
        for tile in &sample.entry.tiles {
            let row = &mut rows[tile.slab as usize];
            if tile.kept {
                row.tiles_kept += 1;
                row.ptm_kept += tile.ptm.as_ref().map_or(0, |p| p.object.size);
                report.sizes.meshes += tile.mesh.as_ref().map_or(0, |m| m.size);
                report.sizes.kept_tiles += 1;
                report.sizes.meshes_count += u64::from(tile.mesh.is_some());
            }
        }
        report.sizes.backgrounds_ptm += sample
            .entry
            .background
            .iter()
            .map(|b| b.ptm.object.size)
            .sum::<u64>();
        viewpoints.push(sample.entry);
        b.inc(1);
    }
    b.finish_and_clear();
    let grid = grid.context("no viewpoints")?;
    report.tile_size = grid.tile_size;
    report.samples = viewpoints.len();
    let face_px = 6 * (pre.face_size as u64).pow(2) * 4;
    report.sizes.panoramas_rgba = face_px * viewpoints.len() as u64;
    report.sizes.slab_layers_rgba = face_px * (viewpoints.len() * nslabs) as u64;
    report.sizes.nonempty_tiles_rgba = rows.iter().map(|r| r.rgba_nonempty).sum();
    report.sizes.kept_tiles_rgba = rows.iter().map(|r| r.rgba_kept).sum();
    report.sizes.kept_tiles_ptm = rows.iter().map(|r| r.ptm_kept).sum();
    report.slabs = rows;
    report.stage_done("encode", m);

    // 5: ACH per segment.
    let m = tune::cost::Meter::start();
    stage(5, "ACH per segment");
    let params = AchParams {
        samples: args.ach_samples,
        camera_size: args.ach_camera_size,
    };
    let mut segments = Vec::new();
    let b = bar(viewpoints.len().saturating_sub(1) as u64, "ACH");
    let mut depth_cache: Vec<(usize, Vec<CubeMap<f32>>)> = Vec::new();
    for pair in viewpoints.windows(2) {
        let (a, z) = (&pair[0], &pair[1]);
        for v in [a, z] {
            if !depth_cache.iter().any(|(i, _)| *i == v.index) {
                let maps = (0..nslabs)
                    .map(|k| store::read_depth_exr(&dir.slab_depth_exr(v.index, k)))
                    .collect::<Result<Vec<_>, _>>()?;
                depth_cache.push((v.index, maps));
            }
        }
        depth_cache.retain(|(i, _)| *i == a.index || *i == z.index);
        let crops: Vec<(usize, &TileEntry, Vec<f32>)> = [a, z]
            .iter()
            .flat_map(|v| v.tiles.iter().filter(|t| t.kept).map(move |t| (v.index, t)))
            .map(|(vi, t)| {
                let maps = &depth_cache
                    .iter()
                    .find(|(i, _)| *i == vi)
                    .expect("cached")
                    .1;
                (vi, t, crop(&maps[t.slab as usize], &grid, t.tile))
            })
            .collect();
        let tiles: Vec<AchTile> = crops
            .iter()
            .map(|(vi, t, d)| {
                let (x0, y0, x1, y1) = grid.pixel_rect(t.tile);
                AchTile {
                    viewpoint: *vi,
                    slab: t.slab,
                    tile: t.tile,
                    face_size: grid.face_size,
                    x0,
                    y0,
                    width: x1 - x0,
                    height: y1 - y0,
                    depth: d,
                }
            })
            .collect();
        let end = |v: &ViewpointEntry| SegmentEnd {
            index: v.index,
            position: v.position,
        };
        segments.push(SegmentEntry {
            from: a.index,
            to: z.index,
            ach: segment_ach(end(a), end(z), &tiles, params),
        });
        b.inc(1);
    }
    b.finish_and_clear();
    report.stage_done("ach", m);

    // 6: the manifest, last.
    stage(6, "manifest");
    let track_toml = std::fs::read_to_string(dir.track_toml())
        .with_context(|| format!("reading {}", dir.track_toml().display()))?;
    let length = TrackSet::parse(&track_toml, &p(&dir.track_toml()))?
        .get(&pre.track)
        .map_or(0.0, |t| t.length());
    let manifest = Manifest {
        version: MANIFEST_VERSION,
        scene: pre.scene.clone(),
        face_size: pre.face_size,
        tile_size: grid.tile_size,
        slabs: pre.slabs.clone(),
        cull_alpha: decisions.as_ref().map(|_| args.alpha),
        cull_variant: decisions
            .as_ref()
            .and(variant)
            .map(|v| v.name().to_string()),
        tracks: vec![TrackEntry {
            name: pre.track.clone(),
            track_toml,
            length,
            viewpoints,
            segments,
        }],
    };
    writer.finish(&manifest)?;
    report.objects_written = writer.objects_written;
    report.objects_reused = writer.objects_reused;
    report.sizes.payloads_shared = writer.payloads_shared;
    report.sizes.bytes_shared = writer.bytes_shared;
    report.sizes.database_objects = walk_size(&args.out.join("objects"));

    // The baseline, from the same prerender directory.
    let t = Instant::now();
    let base = baseline(&dir, &pre, &work)?;
    let sizes = &mut report.sizes;
    sizes.baseline_colour_png = base.iter().map(|b| b.colour_png).sum();
    sizes.baseline_depth_png16 = base.iter().map(|b| b.depth_png16).sum();
    sizes.baseline = sizes.baseline_colour_png + sizes.baseline_depth_png16;
    sizes.db_over_baseline = sizes.database_objects as f64 / sizes.baseline.max(1) as f64;
    report
        .seconds
        .push(("baseline".into(), t.elapsed().as_secs_f64()));
    report
        .seconds
        .push(("total".into(), t_all.elapsed().as_secs_f64()));
    report.cpu_seconds.push(("total".into(), cpu_all.stop().0));
    report.target = args.evidence.clone();
    let stage_seconds: Vec<(&str, serde_json::Value)> = report
        .seconds
        .iter()
        .map(|(name, secs)| (name.as_str(), (*secs).into()))
        .collect();
    log.end(&stage_seconds)?;
    let report_dir = args.report_dir.clone().unwrap_or(work);
    store::write_json(&report_dir.join("build.json"), &report)?;
    let md = markdown(&report);
    store::write_atomic(&report_dir.join("build.md"), md.as_bytes())?;
    println!("{md}");
    eprintln!(
        "wrote {} (report: {})",
        args.out.join("manifest.json").display(),
        report_dir.join("build.md").display()
    );
    Ok(())
}

/// `--target-psnr`: sweep the knobs around the settings given (`railview tune`'s lists),
/// choose the cheapest configuration reaching the target on the worst 5 % of views, and
/// build it into `--out` from the sweep's own stages (nothing is rendered or encoded again),
/// with the choice and its evidence in the report.
fn build_for_target(args: Args, target: f64) -> anyhow::Result<()> {
    anyhow::ensure!(
        target.is_finite() && target > 0.0,
        "--target-psnr must be a positive number of dB"
    );
    let work = args.work.clone().unwrap_or_else(|| {
        let mut w = args.out.clone().into_os_string();
        w.push(".work");
        PathBuf::from(w)
    });
    store::ensure_writable_dir(&work)?;
    let tune_dir = args.tune_dir.clone().unwrap_or_else(|| work.join("tune"));
    let track = track_arg(&args, &work)?;
    let mut argv: Vec<String> = vec!["railview".into(), "tune".into()];
    match (&args.scene, &args.pov) {
        (Some(s), _) => argv.extend(["--scene".into(), s.clone()]),
        (None, Some(p)) => {
            argv.extend(["--pov".into(), p.display().to_string()]);
            if let Some(up) = &args.up {
                argv.extend(["--up".into(), up.clone()]);
            }
        }
        (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
    }
    let cull = match cull_variant(&args)? {
        None => "none".to_string(),
        Some(v) => format!("{}:{}", v.name(), args.alpha),
    };
    argv.extend([
        "--track".into(),
        track,
        "--out".into(),
        tune_dir.display().to_string(),
        "--face-size".into(),
        args.face_size.to_string(),
        "--supersample".into(),
        args.supersample.to_string(),
        "--slabs".into(),
        args.slabs.clone(),
        "--tile-size".into(),
        args.tile_size.to_string(),
        "--mesh-error".into(),
        args.mesh_error.to_string(),
        "--cull".into(),
        cull,
        "--target-psnr".into(),
        target.to_string(),
        "--cost".into(),
        args.cost.clone(),
        "--combine".into(),
        "--per-segment".into(),
        args.per_segment.to_string(),
        "--directions".into(),
        args.directions.to_string(),
        "--zstd-level".into(),
        args.zstd_level.to_string(),
        "--ach-samples".into(),
        args.ach_samples.to_string(),
        "--ach-camera-size".into(),
        args.ach_camera_size.to_string(),
    ]);
    if args.pov.is_some() && args.supersample > 2 {
        bail!("--supersample with --pov: 1 or 2");
    }
    if let Some(n) = args.lowres_face_size {
        argv.extend(["--lowres-face-size".into(), n.to_string()]);
    }
    let cli = crate::Cli::try_parse_from(&argv).context("the sweep's arguments")?;
    let crate::Command::Tune(tune_args) = cli.command else {
        bail!("the sweep's arguments did not parse as `railview tune`");
    };
    let mut sweep = super::tune::Sweep::new(tune_args)?;
    let report = sweep.run()?;
    let selection = report
        .selections
        .first()
        .context("the sweep made no choice")?;
    let text = tune::report::selection_text(&report, selection);
    let Some(i) = selection.chosen else {
        bail!("{text} (the sweep is in {})", tune_dir.display());
    };
    let chosen = &report.records[i];
    eprintln!("{text}");
    let node = tune_dir.join(&chosen.dir);
    let k = &chosen.knobs;
    let evidence = serde_json::json!({
        "target_psnr_db": target,
        "judged_on": "PSNR of the worst 5 % of views between samples",
        "cost": selection.cost,
        "chosen": chosen,
        "left_out": k.differences(&report.base),
        "summary": text,
        "sweep": tune_dir.display().to_string(),
        "table": tune::report::table(&report),
        "configurations": report.records.len(),
    });
    let chosen_args = Args {
        track: node
            .join("prerender")
            .join("track.toml")
            .display()
            .to_string(),
        track_name: None,
        samples: None,
        spacing: None,
        face_size: k.face_size,
        supersample: k.supersample,
        aa: args.aa || (args.pov.is_some() && k.supersample == 2),
        slabs: k.slabs.clone(),
        tile_size: k.tile_size,
        mesh_error: k.mesh_error_px,
        cull_variant: k.cull_variant.clone(),
        alpha: k.alpha,
        drop_levels: k.drop_levels,
        work: Some(node),
        target_psnr: None,
        report_dir: Some(work),
        evidence: Some(evidence),
        ..args
    };
    run(chosen_args)
}

/// The first stage's command line: `prerender` for built-in and TOML scenes, `import-pov`
/// (base pass only; the slabs stage renders the layers it chooses) for POV-Ray scenes.
fn prerender_argv(args: &Args, track: &str, pre_root: &Path) -> anyhow::Result<Vec<String>> {
    let p = |x: &Path| x.display().to_string();
    let mut argv: Vec<String> = match (&args.scene, &args.pov) {
        (Some(scene), _) => vec![
            "prerender".into(),
            "--scene".into(),
            scene.clone(),
            "--track".into(),
            track.to_string(),
            "--supersample".into(),
            args.supersample.to_string(),
        ],
        (None, Some(pov)) => {
            if !Path::new(&args.track).is_file() {
                bail!(
                    "--pov needs --track TRACK.toml (a track file); `{}` is not a file",
                    args.track
                );
            }
            let resampled = track != args.track;
            let mut v = vec![
                "import-pov".into(),
                p(pov),
                "--track".into(),
                track.to_string(),
            ];
            if let Some(name) = args.track_name.as_ref().filter(|_| !resampled) {
                v.extend(["--track-name".into(), name.clone()]);
            }
            if let Some(up) = &args.up {
                v.extend(["--up".into(), up.clone()]);
            }
            if args.aa || args.supersample == 2 {
                v.push("--aa".into());
            }
            if let Some(b) = &args.povray {
                v.extend(["--povray".into(), p(b)]);
            }
            if let Some(t) = args.timeout_secs {
                v.extend(["--timeout-secs".into(), t.to_string()]);
            }
            v
        }
        (None, None) => bail!("give --scene NAME or --pov SCENE.pov"),
    };
    argv.extend([
        "--face-size".into(),
        args.face_size.to_string(),
        "--out".into(),
        p(pre_root),
    ]);
    if let Some(n) = args.lowres_face_size {
        argv.extend(["--lowres-face-size".into(), n.to_string()]);
    }
    Ok(argv)
}

/// The tiling a build asks of the slabs stage: its options, or the stage's defaults.
struct TilingWanted {
    tile_size: u32,
    mesh: slabs::tiles::MeshKind,
    step: u32,
    error: f64,
}

impl TilingWanted {
    fn from_args(args: &Args) -> anyhow::Result<TilingWanted> {
        use super::slabs as s;
        let mesh = match args.mesh.as_deref().unwrap_or(s::DEFAULT_MESH) {
            "adaptive" => slabs::tiles::MeshKind::Adaptive,
            "grid" => slabs::tiles::MeshKind::Grid,
            other => bail!("--mesh `{other}`: expected `adaptive` or `grid`"),
        };
        Ok(TilingWanted {
            tile_size: args.tile_size,
            mesh,
            step: args.mesh_step.unwrap_or(stages::slabs::DEFAULT_MESH_STEP),
            error: args.mesh_error,
        })
    }

    fn argv(&self) -> Vec<String> {
        let mesh = match self.mesh {
            slabs::tiles::MeshKind::Adaptive => "adaptive",
            slabs::tiles::MeshKind::Grid => "grid",
        };
        vec![
            "--tile-size".into(),
            self.tile_size.to_string(),
            "--mesh".into(),
            mesh.into(),
            "--mesh-step".into(),
            self.step.to_string(),
            "--mesh-error".into(),
            self.error.to_string(),
        ]
    }
}

/// The culling variant of the database: `--cull-variant`, where `auto` is the shrunk
/// variant at α = 1 for scenes whose solids the tracer has, else the conservative one, and
/// `none` keeps every non-empty tile.
fn cull_variant(args: &Args) -> anyhow::Result<Option<Variant>> {
    match args.cull_variant.trim() {
        "none" => Ok(None),
        "auto" => Ok(Some(if args.pov.is_none() && args.alpha == 1.0 {
            Variant::Shrunk
        } else {
            Variant::Conservative
        })),
        s => {
            let v = Variant::parse(s).with_context(|| {
                format!("--cull-variant `{s}`: expected auto, shrunk, conservative, paper or none")
            })?;
            if v == Variant::Shrunk && args.alpha != 1.0 {
                bail!(
                    "--cull-variant shrunk runs at α = 1 only (found --alpha {})",
                    args.alpha
                );
            }
            if v == Variant::Shrunk && args.pov.is_some() {
                bail!("--cull-variant shrunk needs the scene's solids: not with --pov");
            }
            Ok(Some(v))
        }
    }
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

fn is_culled(d: Option<&TileDecisions>, viewpoint: usize, slab: usize, index: u32) -> bool {
    let Some(d) = d else { return false };
    d.runs[0]
        .viewpoints
        .iter()
        .find(|v| v.index == viewpoint)
        .and_then(|v| v.slabs.iter().find(|s| s.slab == slab))
        .is_some_and(|s| s.culled.contains(&index))
}

/// Whether a sample's objects are all stored: the background tiles' and the tiles' own PTM
/// and mesh objects in the stage (from which the packs are made).
fn all_present(stage: &Path, v: &ViewpointEntry) -> bool {
    let ok = |root: &Path, o: &tracks::manifest::ObjectRef| {
        o.rel_path()
            .and_then(|r| std::fs::metadata(root.join(r)).ok())
            .is_some_and(|m| m.len() == o.size)
    };
    v.background.iter().all(|b| ok(stage, &b.ptm.object))
        && v.tiles.iter().all(|t| {
            t.ptm.as_ref().is_none_or(|p| ok(stage, &p.object))
                && t.mesh.as_ref().is_none_or(|m| ok(stage, m))
        })
}

fn crop<T: Copy>(map: &CubeMap<T>, grid: &TileGrid, t: tracks::TileId) -> Vec<T> {
    let (x0, y0, x1, y1) = grid.pixel_rect(t);
    let mut out = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
    for y in y0..y1 {
        for x in x0..x1 {
            out.push(*map.get(t.face, x, y));
        }
    }
    out
}

/// FNV-1a, 64 bits: a short stable digest (not a security hash).
fn fnv64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

#[expect(
    clippy::too_many_arguments,
    reason = "one sample's inputs, each from a different stage"
)]
fn encode_sample(
    dir: &PrerenderDir,
    vp: &tracks::ReferenceViewpoint,
    pre: &PrerenderReport,
    decisions: Option<&TileDecisions>,
    (opts, mesh_coding): (&EncodeOptions, &MeshCoding),
    drop_levels: u32,
    writer: &mut DbWriter,
    key: &str,
) -> anyhow::Result<EncodedSample> {
    let i = vp.index;
    let (file, meshes) = sio::read_tiles(dir, i)?;
    let grid = file.grid;
    let mut tiles = Vec::new();
    let (mut rgba_nonempty, mut rgba_kept, mut tiles_nonempty) = (vec![], vec![], vec![]);
    for (layer, layer_meshes) in file.layers.iter().zip(&meshes) {
        let k = layer.slab;
        let color = store::read_rgba_png(&dir.slab_color_png(i, k))?;
        let (mut ne, mut kept_bytes) = (0u64, 0u64);
        for (rec, mesh) in layer.tiles.iter().zip(layer_meshes) {
            let (x0, y0, x1, y1) = grid.pixel_rect(rec.tile);
            let bytes = ((x1 - x0) * (y1 - y0) * 4) as u64;
            ne += bytes;
            let culled = is_culled(decisions, i, k, grid.tile_index(rec.tile) as u32);
            let (ptm, mesh_ref) = if culled {
                (None, None)
            } else {
                kept_bytes += bytes;
                let mut px: Vec<u8> = crop(&color, &grid, rec.tile)
                    .into_iter()
                    .flatten()
                    .collect();
                slabs::tiles::coarsen_colour(&mut px, x1 - x0, y1 - y0, drop_levels);
                // Colour 0 under the mask (format 5): coarse levels are colour × coverage.
                streamer::db::clear_masked(&mut px);
                let img = Image::new(x1 - x0, y1 - y0, 4, px)?;
                let enc = ptm::encode(&img, opts)?;
                let ptm = writer.put_ptm_staged(&enc, 4)?;
                let data = MeshData {
                    vertices: mesh.vertices.clone(),
                    indices: mesh.indices.clone(),
                };
                let mesh_ref = if data.indices.is_empty() {
                    None
                } else {
                    Some(
                        writer.put_staged(&encode_mesh(&data, mesh_coding).with_context(
                            || format!("sample {i} slab {k} tile {:?}: mesh", rec.tile),
                        )?)?,
                    )
                };
                (Some(ptm), mesh_ref)
            };
            tiles.push(TileEntry {
                tile: rec.tile,
                slab: k as u32,
                depth_min: rec.depth_min as f64,
                depth_max: rec.depth_max as f64,
                opaque_pixels: rec.opaque_pixels,
                kept: !culled,
                ptm,
                mesh: mesh_ref,
                mesh_range: None,
            });
        }
        rgba_nonempty.push(ne);
        rgba_kept.push(kept_bytes);
        tiles_nonempty.push(layer.tiles.len());
    }
    // Background: the sky where the panorama's depth is infinite (alpha 255), else clear,
    // cut into the tiles of the same grid; tiles without sky are left out.
    let color = store::read_rgb_png(&dir.color_png(i))?;
    let depth = store::read_depth_exr(&dir.depth_exr(i))?;
    let n = pre.face_size;
    let sky = CubeMap::from_vec(
        n,
        color
            .as_slice()
            .iter()
            .zip(depth.as_slice())
            .map(|(c, d)| {
                if d.is_finite() {
                    [0, 0, 0, 0]
                } else {
                    [c[0], c[1], c[2], 255]
                }
            })
            .collect(),
    )
    .with_context(|| format!("sample {i}: background size"))?;
    let mut background = Vec::new();
    for face in tracks::Face::ALL {
        for ty in 0..grid.tiles_per_side() {
            for tx in 0..grid.tiles_per_side() {
                let tile = tracks::TileId { face, tx, ty };
                let px = crop(&sky, &grid, tile);
                if px.iter().all(|p| p[3] == 0) {
                    continue;
                }
                let (x0, y0, x1, y1) = grid.pixel_rect(tile);
                let mut px: Vec<u8> = px.into_iter().flatten().collect();
                slabs::tiles::coarsen_colour(&mut px, x1 - x0, y1 - y0, drop_levels);
                let img = Image::new(x1 - x0, y1 - y0, 4, px)?;
                let enc = ptm::encode(&img, opts)?;
                background.push(BackgroundTile {
                    tile,
                    ptm: writer.put_ptm_staged(&enc, 4)?,
                });
            }
        }
    }
    Ok(EncodedSample {
        key: key.to_string(),
        entry: ViewpointEntry {
            index: i,
            s: vp.s,
            position: vp.position,
            background,
            tiles,
        },
        rgba_nonempty,
        rgba_kept,
        tiles_nonempty,
    })
}

/// What `WORK/baseline.json` keeps: the baseline per viewpoint and the BLAKE3 of the files it
/// was measured from.
#[derive(Serialize, Deserialize)]
struct BaselineCache {
    key: String,
    panoramas: Vec<streamer::db::baseline::PanoramaBaseline>,
}

/// The baseline of every reference panorama of the prerender directory: measured on every
/// core, kept in `WORK/baseline.json` while the colour and depth files stay the same.
fn baseline(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    work: &Path,
) -> anyhow::Result<Vec<streamer::db::baseline::PanoramaBaseline>> {
    let mut h = blake3::Hasher::new();
    for vp in &pre.viewpoints {
        for path in [dir.color_png(vp.index), dir.depth_exr(vp.index)] {
            let bytes =
                std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            h.update(&bytes);
        }
    }
    let key = format!("baseline-v1 {}", h.finalize().to_hex());
    let path = work.join("baseline.json");
    if let Ok(c) = store::read_json::<BaselineCache>(&path) {
        if c.key == key && c.panoramas.len() == pre.viewpoints.len() {
            return Ok(c.panoramas);
        }
    }
    let panoramas = streamer::db::baseline::measure(pre.viewpoints.len(), |k| {
        let i = pre.viewpoints[k].index;
        let colour = store::read_rgb_png(&dir.color_png(i))?;
        let depth = store::read_depth_exr(&dir.depth_exr(i))?;
        anyhow::Ok((colour, depth))
    })?;
    store::write_json(
        &path,
        &BaselineCache {
            key,
            panoramas: panoramas.clone(),
        },
    )?;
    Ok(panoramas)
}

fn walk_size(dir: &Path) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.filter_map(Result::ok)
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                walk_size(&p)
            } else {
                e.metadata().map_or(0, |m| m.len())
            }
        })
        .sum()
}

fn mib(b: u64) -> String {
    format!("{:.2} MiB", b as f64 / (1024.0 * 1024.0))
}

fn markdown(r: &BuildReport) -> String {
    let s = &r.sizes;
    let mut m = format!(
        "# railview build: {} / {}\n\n{} reference viewpoints, faces {} px, tiles {} px. Culling: {}.\n\n\
         **Database {} = {:.2}× the baseline** ({}: every reference panorama as a PNG of its colour, {}, \
         and a 16-bit PNG of its disparity-quantised depth, {}).\n\n## Sizes per stage\n\n\
         | stage | bytes | of raw panoramas | ÷ baseline |\n|---|---|---|---|\n",
        r.scene,
        r.track,
        r.samples,
        r.face_size,
        r.tile_size,
        r.culling,
        mib(s.database_objects),
        s.db_over_baseline,
        mib(s.baseline),
        mib(s.baseline_colour_png),
        mib(s.baseline_depth_png16),
    );
    let base = s.panoramas_rgba.max(1) as f64;
    let baseline = s.baseline.max(1) as f64;
    for (name, b) in [
        ("raw panoramas (RGBA8)", s.panoramas_rgba),
        ("slab layers (RGBA8)", s.slab_layers_rgba),
        ("empty tiles removed (RGBA8)", s.nonempty_tiles_rgba),
        ("culled (RGBA8)", s.kept_tiles_rgba),
        ("PTM compressed (kept tiles)", s.kept_tiles_ptm),
        ("meshes (compact binary)", s.meshes),
        ("backgrounds (PTM)", s.backgrounds_ptm),
        ("repeated payloads stored once (saved)", s.bytes_shared),
        ("database objects on disk", s.database_objects),
        ("baseline: PNG colour", s.baseline_colour_png),
        ("baseline: PNG16 disparity", s.baseline_depth_png16),
        ("baseline", s.baseline),
    ] {
        m += &format!(
            "| {name} | {} | {:.1} % | {:.2}× |\n",
            mib(b),
            100.0 * b as f64 / base,
            b as f64 / baseline
        );
    }
    let per = |b: u64, n: u64| b as f64 / n.max(1) as f64;
    m += &format!(
        "\nPer kept tile: texture {:.0} bytes, mesh {:.0} bytes ({} tiles, {} meshes); {} payloads \
         repeated across tiles stored once.\n",
        per(s.kept_tiles_ptm, s.kept_tiles),
        per(s.meshes, s.meshes_count),
        s.kept_tiles,
        s.meshes_count,
        s.payloads_shared
    );
    m += "\n## Culling table\n\n| slab | tiles non-empty | kept | RGBA8 non-empty | RGBA8 kept | PTM kept |\n|---|---|---|---|---|---|\n";
    for row in &r.slabs {
        m += &format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            row.slab,
            row.tiles_nonempty,
            row.tiles_kept,
            mib(row.rgba_nonempty),
            mib(row.rgba_kept),
            mib(row.ptm_kept)
        );
    }
    m += "\n## Timings\n\n| stage | wall seconds | CPU seconds |\n|---|---|---|\n";
    for (name, secs) in &r.seconds {
        let cpu = r
            .cpu_seconds
            .iter()
            .find(|(n, _)| n == name)
            .map_or("–".to_string(), |(_, c)| format!("{c:.1}"));
        m += &format!("| {name} | {secs:.1} | {cpu} |\n");
    }
    let c = &r.config;
    m += &format!(
        "\nConfiguration: samples {}, spacing {}, faces {} px at {}×{} rays per pixel, slabs {}, tiles {} px, mesh error {} px, culling {} α {}, finest texture levels left out {}, zstd {}.\n",
        c.samples.map_or("as the track".into(), |n| n.to_string()),
        c.spacing_m.map_or("as the track".into(), |d| format!("{d} m")),
        c.face_size,
        c.supersample,
        c.supersample,
        c.slabs,
        c.tile_size,
        c.mesh_error_px,
        c.cull_variant,
        c.alpha,
        c.drop_levels,
        c.zstd_level
    );
    m += &format!(
        "\nObjects written {}, reused {} (a rebuild reuses everything already written).\n",
        r.objects_written, r.objects_reused
    );
    if let Some(t) = &r.target {
        m += &format!(
            "\n## Chosen for a PSNR target\n\n{}\n\nThe sweep ({} configurations, in {}):\n\n{}",
            t["summary"].as_str().unwrap_or(""),
            t["configurations"],
            t["sweep"].as_str().unwrap_or(""),
            t["table"].as_str().unwrap_or("")
        );
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole pipeline at a tiny size; the result verifies, and a rebuild writes nothing.
    #[test]
    fn builds_verifies_and_resumes() {
        let out = std::env::temp_dir().join(format!("railview-build-{}", std::process::id()));
        let work = out.with_extension("work");
        std::fs::remove_dir_all(&out).ok();
        std::fs::remove_dir_all(&work).ok();
        let args = || Args {
            scene: Some("castle".into()),
            pov: None,
            track: "main".into(),
            track_name: None,
            up: None,
            aa: false,
            povray: None,
            timeout_secs: None,
            lowres_face_size: None,
            face_size: 32,
            out: out.clone(),
            work: Some(work.clone()),
            samples: None,
            spacing: None,
            supersample: 1,
            slabs: "auto".into(),
            tile_size: 32,
            mesh_error: 0.5,
            drop_levels: 0,
            target_psnr: None,
            cost: "db-bytes".into(),
            tune_dir: None,
            per_segment: 2,
            directions: 4,
            report_dir: None,
            evidence: None,
            alpha: 1.0,
            cull_variant: "auto".into(),
            ptm_method: "arith".into(),
            zstd_level: 3,
            lossy_near: 0,
            depth_error_px: 0.05,
            mesh: None,
            mesh_step: None,
            ach_samples: 2,
            ach_camera_size: 16,
        };
        run(args()).unwrap();
        let v = streamer::db::verify(&out).unwrap();
        assert!(v.is_intact());
        // The tiles' own objects stay in the work directory: nothing unreferenced.
        assert!(v.notes.is_empty(), "{:?}", v.notes);
        let db = streamer::db::Database::open(&out).unwrap();
        let m = db.manifest();
        // A built-in scene: the shrunk variant by default.
        assert_eq!(m.cull_variant.as_deref(), Some("shrunk"));
        let track = &m.tracks[0];
        assert!(track.viewpoints.len() > 1);
        assert_eq!(track.segments.len(), track.viewpoints.len() - 1);
        for seg in &track.segments {
            let sum: f64 = seg.ach.iter().map(|a| a.ach).sum();
            // Tables store ACH values as f32.
            assert!(seg.ach.is_empty() || (sum - 1.0).abs() < 1e-5, "{sum}");
        }
        let kept = track.viewpoints[0].tiles.iter().find(|t| t.kept).unwrap();
        let ptm_ref = kept.ptm.as_ref().unwrap();
        // The PTM's ranges in its viewpoint's pack, each checked, make up the PTM file.
        let bytes: Vec<u8> = (0..ptm_ref.levels.len())
            .flat_map(|g| db.read_level(ptm_ref, g).unwrap())
            .collect();
        let img = ptm::decode(&bytes, ptm::Limits::default()).unwrap();
        assert_eq!((img.width(), img.height()), (ptm_ref.width, ptm_ref.height));
        let first = std::fs::read(out.join("manifest.json")).unwrap();
        run(args()).unwrap();
        let again = std::fs::read(out.join("manifest.json")).unwrap();
        assert!(again == first, "a resumed build changed manifest.json");
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(work.join("build.json")).unwrap()).unwrap();
        assert_eq!(report["objects_written"], 0);
        // The baseline and the ratio, from the same prerender directory.
        let sizes = &report["sizes"];
        let base = sizes["baseline"].as_u64().unwrap();
        assert!(base > 0);
        assert_eq!(
            base,
            sizes["baseline_colour_png"].as_u64().unwrap()
                + sizes["baseline_depth_png16"].as_u64().unwrap()
        );
        let ratio = sizes["db_over_baseline"].as_f64().unwrap();
        let db = sizes["database_objects"].as_u64().unwrap();
        assert!((ratio - db as f64 / base as f64).abs() < 1e-9);
        assert!(std::fs::read_to_string(work.join("build.md"))
            .unwrap()
            .contains("× the baseline"));
        std::fs::remove_dir_all(&out).unwrap();
        std::fs::remove_dir_all(&work).unwrap();
    }
}
