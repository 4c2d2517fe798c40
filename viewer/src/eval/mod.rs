//! Error against cost: reconstructed views compared with the ground truth from the same
//! camera, over the whole track.
//!
//! - [`Truth`]: the renderer of the walkthrough's scene ([`prerender::truth::GroundTruth`]
//!   for built-in scenes, scene files and POV-Ray imports; the analytic street for
//!   `synth:street`), anti-aliased by supersampling, with an optional on-disk
//!   [`TruthCache`] so that many databases of one scene are judged on the same pictures
//!   rendered once.
//! - [`ViewSpec`] / [`views_between`] / [`views_at_samples`]: where to look: every segment,
//!   several positions inside each, several directions relative to the track.
//! - [`matched_size`]: the view size whose pixels are as wide as the panorama's at the view
//!   centre; [`resolution_ratio`] says how far another size is from it.
//! - [`evaluate`] renders every view for every [`EvalConfig`] and measures PSNR, SSIM, holes
//!   and frame time ([`EvalRow`]); [`ErrorStats`] summarises them (mean, worst 5 %, worst),
//!   [`worst_views`] says where the worst views are, [`triptych`] shows one beside its truth.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tracks::PerspectiveCamera;

use crate::gpu::Renderer;
use crate::headless::{yaw_along, HeadlessError};
use crate::metrics::{psnr, split_rgba, ssim};
use crate::plan::{DrawBudget, FramePlan};
use crate::source::Walkthrough;
use crate::synth::Scene as SynthScene;

pub mod bound;
pub mod pictures;
pub mod report;
pub mod stage;

/// The exact renderer of a walkthrough's scene.
pub enum Truth {
    /// The analytic street of `synth:street`, `supersample²` rays per pixel.
    Synth {
        scene: SynthScene,
        supersample: u32,
    },
    Scene(prerender::truth::GroundTruth),
}

impl Truth {
    /// The view of `camera`, sRGB, rows from the top.
    pub fn render(&mut self, camera: &PerspectiveCamera) -> Result<Vec<[u8; 3]>, HeadlessError> {
        match self {
            Truth::Synth { scene, supersample } => {
                let ss = (*supersample).max(1);
                if ss == 1 {
                    return Ok(scene.perspective(camera));
                }
                let fine = PerspectiveCamera {
                    width: camera.width * ss,
                    height: camera.height * ss,
                    ..*camera
                };
                let flat: Vec<u8> = scene.perspective(&fine).into_iter().flatten().collect();
                Ok(prerender::pov::decode::box_filter(
                    &flat,
                    camera.width,
                    camera.height,
                    ss,
                ))
            }
            Truth::Scene(t) => t
                .render(camera)
                .map_err(|e| HeadlessError::Parameter(format!("ground truth: {e}"))),
        }
    }

    /// One line for reports.
    pub fn describe(&self) -> String {
        match self {
            Truth::Synth { supersample, .. } => format!(
                "the analytic street, {s}×{s} rays per pixel averaged in linear light",
                s = supersample
            ),
            Truth::Scene(t) => t.describe(),
        }
    }

    /// The truth of a walkthrough opened from `spec`: `synth:street`; a prerender directory
    /// (its own `prerender.json`); a database, whose scene is rendered from `prerender` when
    /// given, else from the build's work directory beside it (`DB.work/prerender`) when that
    /// made it, else by name (built-in scenes, scene files that exist here). POV-Ray files
    /// the truth renders go to `work_dir`.
    pub fn for_walkthrough(
        spec: &str,
        walk: &Walkthrough,
        prerender: Option<&Path>,
        supersample: u32,
        work_dir: &Path,
    ) -> Result<Truth, HeadlessError> {
        use prerender::store::PrerenderDir;
        use prerender::truth::GroundTruth;
        if spec == "synth:street" {
            return Ok(Truth::Synth {
                scene: SynthScene::street(),
                supersample: supersample.max(1),
            });
        }
        let err = |e: prerender::truth::TruthError| {
            HeadlessError::Parameter(format!("no ground truth for scene `{}`: {e}", walk.scene))
        };
        let from_dir = |dir: &Path| {
            GroundTruth::for_prerender(&PrerenderDir::new(dir), supersample, work_dir)
                .map(Truth::Scene)
                .map_err(err)
        };
        if let Some(dir) = prerender_dir(spec, walk, prerender) {
            return from_dir(&dir);
        }
        if walk.scene.ends_with(".pov") {
            let mut beside = Path::new(spec).as_os_str().to_owned();
            beside.push(".work");
            let beside = PathBuf::from(beside).join("prerender");
            return Err(HeadlessError::Parameter(format!(
                "no ground truth for `{}`: it is a POV-Ray import, whose truth POV-Ray renders \
                 with the import's settings from its prerender directory; none was found at {} \
                 — give it with --prerender DIR",
                walk.scene,
                beside.display()
            )));
        }
        GroundTruth::for_scene(&walk.scene, supersample)
            .map(Truth::Scene)
            .map_err(err)
    }
}

/// The prerender directory of a walkthrough opened from `spec`: `prerender` when given; `spec`
/// itself when it is one; the build's work directory beside a database
/// (`DB.work/prerender`) when it made this scene; else none.
pub fn prerender_dir(spec: &str, walk: &Walkthrough, prerender: Option<&Path>) -> Option<PathBuf> {
    use prerender::store::PrerenderDir;
    if let Some(dir) = prerender {
        return Some(dir.to_path_buf());
    }
    let path = Path::new(spec);
    if PrerenderDir::new(path).report_json().is_file() {
        return Some(path.to_path_buf());
    }
    let mut beside = path.as_os_str().to_owned();
    beside.push(".work");
    let beside = PathBuf::from(beside).join("prerender");
    PrerenderDir::new(&beside)
        .read_report()
        .is_ok_and(|r| r.scene == walk.scene)
        .then_some(beside)
}

/// Truth pictures on disk, one PNG per camera (and scene and supersampling), so repeated
/// evaluations of one scene render each view once.
#[derive(Clone, Debug, Default)]
pub struct TruthCache {
    pub dir: Option<PathBuf>,
}

/// FNV-1a, 64 bits: a stable name for a cache key (not a security hash).
fn fnv64(text: &str) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

impl TruthCache {
    fn path(&self, scene: &str, camera: &PerspectiveCamera, truth: &Truth) -> Option<PathBuf> {
        let dir = self.dir.as_ref()?;
        let p = camera.position;
        let key = format!(
            "{scene}|{}|{:.9},{:.9},{:.9}|{:.9}|{:.9}|{:.9}|{}x{}",
            truth.describe(),
            p.x,
            p.y,
            p.z,
            camera.yaw_deg,
            camera.pitch_deg,
            camera.fov_deg,
            camera.width,
            camera.height
        );
        Some(dir.join(format!("{:016x}.png", fnv64(&key))))
    }

    /// The truth of `camera`, from the cache or rendered (and then stored).
    pub fn get(
        &self,
        scene: &str,
        camera: &PerspectiveCamera,
        truth: &mut Truth,
    ) -> Result<Vec<[u8; 3]>, HeadlessError> {
        let path = self.path(scene, camera, truth);
        if let Some(p) = &path {
            if let Ok(img) = image::open(p) {
                let img = img.to_rgb8();
                if img.dimensions() == (camera.width, camera.height) {
                    return Ok(img.pixels().map(|p| p.0).collect());
                }
            }
        }
        let rgb = truth.render(camera)?;
        if let Some(p) = &path {
            let flat: Vec<u8> = rgb.iter().flatten().copied().collect();
            let img = image::RgbImage::from_raw(camera.width, camera.height, flat)
                .ok_or_else(|| HeadlessError::Parameter("truth size".into()))?;
            let mut bytes = std::io::Cursor::new(Vec::new());
            img.write_to(&mut bytes, image::ImageFormat::Png)
                .map_err(|e| HeadlessError::Parameter(format!("{}: {e}", p.display())))?;
            prerender::store::write_atomic(p, bytes.get_ref())
                .map_err(|e| HeadlessError::Parameter(e.to_string()))?;
        }
        Ok(rgb)
    }
}

/// Where to look along a track.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewSpec {
    /// Positions inside each segment, evenly spaced, both ends excluded.
    pub per_segment: usize,
    /// Directions per position: yaws evenly spaced around the direction of travel.
    pub directions: usize,
    /// Pitches (degrees) of every direction.
    pub pitches_deg: Vec<f64>,
    /// Only the first segments (all when `None`).
    pub max_segments: Option<usize>,
}

impl Default for ViewSpec {
    fn default() -> Self {
        ViewSpec {
            per_segment: 3,
            directions: 4,
            pitches_deg: vec![0.0],
            max_segments: None,
        }
    }
}

/// One camera pose of an evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalView {
    /// The track (position in the source's tracks; 0 for a single track).
    #[serde(default)]
    pub track: usize,
    /// Arc length, metres.
    pub s: f64,
    /// The segment it lies in (between samples `segment` and `segment + 1`).
    pub segment: usize,
    pub yaw_deg: f64,
    /// The yaw measured from the direction of travel at `s`.
    pub yaw_from_track_deg: f64,
    pub pitch_deg: f64,
    /// At a reference sample of the evaluated walkthrough (the resampling floor).
    pub at_reference: bool,
}

/// `(yaw, yaw from the track, pitch)` of every direction at `s`.
fn directions(walk: &Walkthrough, s: f64, spec: &ViewSpec) -> Vec<(f64, f64, f64)> {
    let along = yaw_along(walk, s);
    let d = spec.directions.max(1);
    let pitches: &[f64] = if spec.pitches_deg.is_empty() {
        &[0.0]
    } else {
        &spec.pitches_deg
    };
    (0..d)
        .flat_map(|k| {
            let rel = 360.0 * k as f64 / d as f64;
            let yaw = (along + rel).rem_euclid(360.0);
            pitches.iter().map(move |&p| (yaw, rel, p))
        })
        .collect()
}

/// How far into a segment from a junction its extra views are, metres (at most a quarter of
/// the segment).
pub const JUNCTION_VIEW_M: f64 = 0.25;

/// The views between the samples at arc lengths `arcs` (a walkthrough's reference samples):
/// `spec.per_segment` positions inside every segment, each in `spec.directions` directions;
/// in a segment that starts or ends at a junction of the current track also one position
/// [`JUNCTION_VIEW_M`] from that end, where the blend leaves one track for another.
pub fn views_between(walk: &Walkthrough, arcs: &[f64], spec: &ViewSpec) -> Vec<EvalView> {
    let mut out = Vec::new();
    let segments = arcs.len().saturating_sub(1);
    let order = walk.order();
    let shared = |k: usize| {
        order.get(k).is_some_and(|&v| {
            walk.stops
                .iter()
                .enumerate()
                .filter(|(t, _)| *t != walk.current)
                .any(|(_, st)| st.iter().any(|x| x.0 == v))
        })
    };
    for i in 0..spec.max_segments.unwrap_or(segments).min(segments) {
        let (a, b) = (arcs[i], arcs[i + 1]);
        let mut at: Vec<f64> = (1..=spec.per_segment)
            .map(|k| a + (b - a) * k as f64 / (spec.per_segment + 1) as f64)
            .collect();
        let edge = JUNCTION_VIEW_M.min(0.25 * (b - a));
        if shared(i) {
            at.push(a + edge);
        }
        if shared(i + 1) {
            at.push(b - edge);
        }
        for s in at {
            for (yaw, rel, pitch) in directions(walk, s, spec) {
                out.push(EvalView {
                    track: walk.current,
                    s,
                    segment: i,
                    yaw_deg: yaw,
                    yaw_from_track_deg: rel,
                    pitch_deg: pitch,
                    at_reference: false,
                });
            }
        }
    }
    out
}

/// The views at the walkthrough's own reference samples (of the first `max_segments`
/// segments), in the same directions: the resampling floor.
pub fn views_at_samples(walk: &Walkthrough, spec: &ViewSpec) -> Vec<EvalView> {
    let (_, arcs) = walk.order_and_arcs();
    let n = arcs.len();
    let last = spec.max_segments.map_or(n, |m| (m + 1).min(n));
    let track = walk.current;
    arcs[..last]
        .iter()
        .enumerate()
        .flat_map(|(i, &s)| {
            directions(walk, s, spec)
                .into_iter()
                .map(move |(yaw, rel, pitch)| EvalView {
                    track,
                    s,
                    segment: i.min(n.saturating_sub(2)),
                    yaw_deg: yaw,
                    yaw_from_track_deg: rel,
                    pitch_deg: pitch,
                    at_reference: true,
                })
        })
        .collect()
}

/// `n` of `views` spread along the track: half of them (rounded up) from the views at
/// samples and the rest from those between (all of them when there are no more than `n`).
/// Within each half the positions share its views evenly (each position `⌊k/P⌋` or `⌈k/P⌉`
/// of them, those with one spread along the track when there are fewer views than
/// positions), and the directions rotate from one pick to the next. A view set of
/// [`stage::chosen_views`] thinned to what a slower comparison can afford, still along the
/// whole track, in every direction, at and between samples.
pub fn spread(views: &[EvalView], n: usize) -> Vec<EvalView> {
    if views.len() <= n {
        return views.to_vec();
    }
    let (at, between): (Vec<EvalView>, Vec<EvalView>) = views.iter().partition(|v| v.at_reference);
    let want_between = (n / 2).min(between.len());
    let want_at = (n - want_between).min(at.len());
    let want_between = (n - want_at).min(between.len());
    let mut out = spread_positions(&at, want_at);
    out.extend(spread_positions(&between, want_between));
    out
}

/// `k` of `part` (views in order, those of one position together), as [`spread`] shares
/// them out.
fn spread_positions(part: &[EvalView], k: usize) -> Vec<EvalView> {
    let mut groups: Vec<&[EvalView]> = Vec::new();
    let mut from = 0;
    for i in 1..=part.len() {
        let same = |a: &EvalView, b: &EvalView| a.track == b.track && a.s == b.s;
        if i == part.len() || !same(&part[i], &part[from]) {
            groups.push(&part[from..i]);
            from = i;
        }
    }
    let g = groups.len();
    let mut out = Vec::with_capacity(k);
    for (p, group) in groups.iter().enumerate() {
        let count = ((p + 1) * k / g - p * k / g).min(group.len());
        let offset = out.len();
        out.extend((0..count).map(|j| group[(offset + j) % group.len()]));
    }
    out
}

/// Mark the views that lie at one of `walk`'s samples (within a millimetre).
pub fn mark_references(walk: &Walkthrough, views: &mut [EvalView]) {
    let (_, arcs) = walk.order_and_arcs();
    for v in views {
        v.at_reference = arcs.iter().any(|r| (r - v.s).abs() < 1e-3);
    }
}

/// The view size `width × height` (aspect `height/width`) whose pixel at the view centre
/// spans the same angle as a pixel at the centre of a cube face of `face_size`.
pub fn matched_size(face_size: u32, fov_deg: f64, aspect: f64) -> (u32, u32) {
    let w = (face_size as f64 * (fov_deg.to_radians() * 0.5).tan())
        .round()
        .clamp(1.0, 16384.0);
    (w as u32, (w * aspect).round().clamp(1.0, 16384.0) as u32)
}

/// Angle of a view pixel at its centre over that of a panorama pixel at a face centre
/// (1 = matched; 2 = the view's pixels are twice as wide as the panorama's).
pub fn resolution_ratio(face_size: u32, fov_deg: f64, width: u32) -> f64 {
    face_size as f64 * (fov_deg.to_radians() * 0.5).tan() / width.max(1) as f64
}

/// A renderer configuration to evaluate.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalConfig {
    pub name: String,
    pub budget: DrawBudget,
}

/// The renderer configurations: everything, first slab only, the nearer view only, textures
/// one level coarser, the second view at half resolution.
pub fn default_configs() -> Vec<EvalConfig> {
    let c = |name: &str, budget| EvalConfig {
        name: name.into(),
        budget,
    };
    vec![
        c("full", DrawBudget::default()),
        c(
            "draw 1 slab",
            DrawBudget {
                max_slabs: 1,
                ..Default::default()
            },
        ),
        c(
            "draw 1 view",
            DrawBudget {
                blend: false,
                ..Default::default()
            },
        ),
        c(
            "textures +1 level",
            DrawBudget {
                lod_bias: 1.0,
                ..Default::default()
            },
        ),
        c(
            "second view half res",
            DrawBudget {
                half_res_second: true,
                ..Default::default()
            },
        ),
    ]
}

/// One view of one configuration (the `rows` of `eval.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    pub config: String,
    #[serde(flatten)]
    pub view: EvalView,
    /// Camera position, metres.
    pub position: [f64; 3],
    #[serde(deserialize_with = "nan_from_null")]
    pub psnr_db: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub ssim: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub hole_fraction: f64,
    /// Pixels no reference covered, filled from the farther side (`fs_fill`).
    #[serde(default)]
    pub filled_fraction: f64,
    /// Mean GPU frame time (plan + draw + wait, no readback), milliseconds; NaN (`null`)
    /// for the sampling bound's rows.
    #[serde(deserialize_with = "nan_from_null")]
    pub frame_ms: f64,
    /// Database bytes of the configuration's walkthrough.
    pub db_bytes: u64,
}

/// The camera of `view` on `walk`.
pub fn camera(
    walk: &Walkthrough,
    view: &EvalView,
    size: (u32, u32),
    fov_deg: f64,
) -> PerspectiveCamera {
    PerspectiveCamera {
        position: walk.position_at(view.s),
        yaw_deg: view.yaw_deg,
        pitch_deg: view.pitch_deg,
        fov_deg,
        width: size.0,
        height: size.1,
    }
}

/// Draw `view` with `budget` as the window shows it between feedback frames (no tile ids);
/// returns the RGBA frame.
pub fn draw(
    renderer: &mut Renderer,
    walk: &Walkthrough,
    camera: &PerspectiveCamera,
    s: f64,
    budget: DrawBudget,
) -> Result<Vec<u8>, HeadlessError> {
    let mut plan: FramePlan = walk.plan(camera, s, budget)?;
    plan.tile_ids = false;
    renderer.draw(&plan, &walk.views)?;
    Ok(renderer.read_output()?.rgba)
}

/// Everything one evaluation needs besides the renderer.
pub struct EvalInput<'a> {
    /// The views' walkthrough; a view on another track of a network moves it there.
    pub walk: &'a mut Walkthrough,
    pub truth: &'a mut Truth,
    pub cache: &'a TruthCache,
    pub configs: &'a [EvalConfig],
    pub views: &'a [EvalView],
    pub size: (u32, u32),
    pub fov_deg: f64,
    /// Draws timed per view and configuration, after one untimed draw.
    pub timed_draws: usize,
    /// The sampling bound: the exact warp of the reference panoramas, evaluated beside the
    /// configurations at every view between samples (rows [`bound::EXACT_BLACK`],
    /// [`bound::EXACT_FILLED`], [`bound::ORACLE`]), and the first configuration's error
    /// per pixel class against it.
    pub bound: Option<(&'a mut bound::BoundSource, &'a mut bound::ClassTally)>,
}

/// Evaluate every configuration at every view: one row per (view, configuration).
/// `progress` is called after each row.
pub fn evaluate(
    renderer: &mut Renderer,
    input: EvalInput<'_>,
    mut progress: impl FnMut(&EvalRow),
) -> Result<Vec<EvalRow>, HeadlessError> {
    renderer.forget_views();
    let walk = input.walk;
    let mut rows = Vec::new();
    let mut bound_input = input.bound;
    for view in input.views {
        if view.track != walk.current {
            walk.set_track(view.track);
        }
        let walk = &*walk;
        let cam = camera(walk, view, input.size, input.fov_deg);
        let gt = input.cache.get(&walk.scene, &cam, input.truth)?;
        let warp = match bound_input.as_mut() {
            Some((source, _)) => source.warp(walk, view, &cam, &gt)?,
            None => None,
        };
        for (ci, cfg) in input.configs.iter().enumerate() {
            let rgba = draw(renderer, walk, &cam, view.s, cfg.budget)?;
            let reps = input.timed_draws.max(1);
            let t0 = Instant::now();
            for _ in 0..reps {
                let mut plan = walk.plan(&cam, view.s, cfg.budget)?;
                plan.tile_ids = false;
                renderer.draw(&plan, &walk.views)?;
            }
            let frame_ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
            let (rgb, hole_fraction) = split_rgba(&rgba);
            if let (0, Some(w), Some((_, tally))) = (ci, &warp, bound_input.as_mut()) {
                tally.add(&rgb, w, &gt);
            }
            let row = EvalRow {
                config: cfg.name.clone(),
                view: *view,
                position: cam.position.to_array(),
                psnr_db: psnr(&rgb, &gt).min(99.0),
                ssim: ssim(&rgb, &gt, input.size.0, input.size.1),
                hole_fraction,
                filled_fraction: crate::metrics::filled_fraction(&rgba),
                frame_ms,
                db_bytes: walk.bytes,
            };
            progress(&row);
            rows.push(row);
        }
        if let Some(w) = &warp {
            for (name, rgb, holes) in [
                (bound::EXACT_BLACK, &w.black, w.hole_fraction),
                (bound::EXACT_FILLED, &w.filled, 0.0),
                (bound::ORACLE, &w.oracle, 0.0),
            ] {
                let row = EvalRow {
                    config: name.into(),
                    view: *view,
                    position: cam.position.to_array(),
                    psnr_db: psnr(rgb, &gt).min(99.0),
                    ssim: ssim(rgb, &gt, input.size.0, input.size.1),
                    hole_fraction: holes,
                    filled_fraction: if name == bound::EXACT_FILLED {
                        w.hole_fraction
                    } else {
                        0.0
                    },
                    frame_ms: f64::NAN,
                    db_bytes: 0,
                };
                progress(&row);
                rows.push(row);
            }
        }
    }
    Ok(rows)
}

/// Nearest-rank lower percentile: the value that a fraction `1 − q` of `values` meet or
/// exceed (q = 0.05: the worst 5 %). The minimum for fewer than `1/q` values; NaN if empty.
pub fn lower_percentile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let k = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[k - 1]
}

/// Upper counterpart of [`lower_percentile`] (holes: the worst 5 % are the largest).
pub fn upper_percentile(values: &[f64], q: f64) -> f64 {
    let neg: Vec<f64> = values.iter().map(|x| -x).collect();
    -lower_percentile(&neg, q)
}

/// A number of `eval.json` read back: JSON writes a value that is not finite (the mean over
/// no views, say) as `null`, which reads back as NaN.
fn nan_from_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Error over a set of views: means, the worst 5 % (the value 95 % of views meet or beat)
/// and the worst single view.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    pub views: usize,
    #[serde(deserialize_with = "nan_from_null")]
    pub psnr_mean_db: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub psnr_worst5_db: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub psnr_min_db: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub ssim_mean: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub ssim_worst5: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub holes_mean: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub holes_worst5: f64,
    #[serde(deserialize_with = "nan_from_null")]
    pub holes_max: f64,
}

impl ErrorStats {
    pub fn of<'a>(rows: impl IntoIterator<Item = &'a EvalRow>) -> ErrorStats {
        let rows: Vec<&EvalRow> = rows.into_iter().collect();
        let col = |f: fn(&EvalRow) -> f64| rows.iter().map(|r| f(r)).collect::<Vec<f64>>();
        let mean = |v: &[f64]| {
            if v.is_empty() {
                f64::NAN
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            }
        };
        let (p, s, h) = (
            col(|r| r.psnr_db),
            col(|r| r.ssim),
            col(|r| r.hole_fraction),
        );
        ErrorStats {
            views: rows.len(),
            psnr_mean_db: mean(&p),
            psnr_worst5_db: lower_percentile(&p, 0.05),
            psnr_min_db: p.iter().copied().fold(f64::NAN, f64::min),
            ssim_mean: mean(&s),
            ssim_worst5: lower_percentile(&s, 0.05),
            holes_mean: mean(&h),
            holes_worst5: upper_percentile(&h, 0.05),
            holes_max: h.iter().copied().fold(f64::NAN, f64::max),
        }
    }
}

/// Per configuration: the error at the reference samples (the resampling floor) and between
/// them, the mean frame time and the bytes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConfigSummary {
    pub config: String,
    pub at_samples: ErrorStats,
    pub between: ErrorStats,
    #[serde(deserialize_with = "nan_from_null")]
    pub frame_ms: f64,
    pub db_bytes: u64,
}

/// Summaries in the order configurations first appear in `rows`.
pub fn summarize(rows: &[EvalRow]) -> Vec<ConfigSummary> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.config.as_str()) {
            names.push(&r.config);
        }
    }
    names
        .into_iter()
        .map(|name| {
            let of = |at: bool| {
                rows.iter()
                    .filter(move |r| r.config == name && r.view.at_reference == at)
            };
            let times: Vec<f64> = rows
                .iter()
                .filter(|r| r.config == name)
                .map(|r| r.frame_ms)
                .collect();
            ConfigSummary {
                config: name.to_string(),
                at_samples: ErrorStats::of(of(true)),
                between: ErrorStats::of(of(false)),
                frame_ms: times.iter().sum::<f64>() / times.len().max(1) as f64,
                db_bytes: rows
                    .iter()
                    .find(|r| r.config == name)
                    .map_or(0, |r| r.db_bytes),
            }
        })
        .collect()
}

/// The `n` rows of `config` between samples with the lowest PSNR, worst first.
pub fn worst_views<'a>(rows: &'a [EvalRow], config: &str, n: usize) -> Vec<&'a EvalRow> {
    let mut v: Vec<&EvalRow> = rows
        .iter()
        .filter(|r| r.config == config && !r.view.at_reference)
        .collect();
    v.sort_by(|a, b| {
        a.psnr_db
            .total_cmp(&b.psnr_db)
            .then(a.view.s.total_cmp(&b.view.s))
    });
    v.truncate(n);
    v
}

/// The reconstruction, its truth and their difference (per channel |a − b| × 4, so an error
/// of 64 levels is white) side by side with 4-pixel gaps.
pub fn triptych(recon: &[[u8; 3]], truth: &[[u8; 3]], width: u32, height: u32) -> image::RgbImage {
    let gap = 4;
    let mut img = image::RgbImage::from_pixel(3 * width + 2 * gap, height, image::Rgb([255; 3]));
    for y in 0..height {
        for x in 0..width {
            let i = (y * width + x) as usize;
            let (a, b) = (
                recon.get(i).copied().unwrap_or([0; 3]),
                truth.get(i).copied().unwrap_or([0; 3]),
            );
            let d: [u8; 3] = std::array::from_fn(|c| {
                ((a[c] as i32 - b[c] as i32).unsigned_abs() * 4).min(255) as u8
            });
            img.put_pixel(x, y, image::Rgb(a));
            img.put_pixel(width + gap + x, y, image::Rgb(b));
            img.put_pixel(2 * (width + gap) + x, y, image::Rgb(d));
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_over_no_views_read_back_from_json_as_nan() {
        let stats = ErrorStats::of(std::iter::empty());
        let json = serde_json::to_string(&stats).unwrap();
        assert!(json.contains("\"psnr_mean_db\":null"), "{json}");
        let back: ErrorStats = serde_json::from_str(&json).unwrap();
        assert_eq!(back.views, 0);
        assert!(back.psnr_mean_db.is_nan() && back.holes_max.is_nan());
    }
    use crate::headless::synth_street;
    use crate::refview::LayerMeshing;

    #[test]
    fn percentiles_take_the_worst_tail() {
        let v: Vec<f64> = (1..=100).map(|i| i as f64).collect();
        assert_eq!(lower_percentile(&v, 0.05), 5.0);
        assert_eq!(upper_percentile(&v, 0.05), 96.0);
        assert_eq!(lower_percentile(&[3.0, 1.0, 2.0], 0.05), 1.0);
        assert!(lower_percentile(&[], 0.05).is_nan());
    }

    #[test]
    fn views_cover_every_segment_in_every_direction() {
        let w = synth_street(8, &SynthScene::street_slabs(), LayerMeshing::default()).unwrap();
        let arcs: Vec<f64> = w.views.iter().map(|v| v.s).collect();
        let spec = ViewSpec {
            per_segment: 2,
            directions: 4,
            pitches_deg: vec![0.0, 20.0],
            max_segments: None,
        };
        let v = views_between(&w, &arcs, &spec);
        assert_eq!(v.len(), (arcs.len() - 1) * 2 * 4 * 2);
        for seg in 0..arcs.len() - 1 {
            assert!(v.iter().any(|x| x.segment == seg));
        }
        // Strictly inside the segments; yaws a quarter turn apart.
        assert!(v
            .iter()
            .all(|x| x.s > arcs[x.segment] && x.s < arcs[x.segment + 1]));
        let yaws: Vec<f64> = v.iter().take(8).step_by(2).map(|x| x.yaw_deg).collect();
        for k in 1..4 {
            let d = (yaws[k] - yaws[0]).rem_euclid(360.0);
            assert!((d - 90.0 * k as f64).abs() < 1e-9, "{yaws:?}");
        }
        let at = views_at_samples(&w, &spec);
        assert_eq!(at.len(), arcs.len() * 8);
        assert!(at.iter().all(|x| x.at_reference));
    }

    #[test]
    fn a_spread_keeps_every_part_of_the_track_and_every_direction() {
        let w = synth_street(8, &SynthScene::street_slabs(), LayerMeshing::default()).unwrap();
        let arcs: Vec<f64> = w.views.iter().map(|v| v.s).collect();
        let spec = ViewSpec::default();
        let mut all = views_at_samples(&w, &spec);
        all.extend(views_between(&w, &arcs, &spec));
        for n in [1, 5, 12, 24, 40] {
            let got = spread(&all, n);
            assert_eq!(got.len(), n);
            let at = got.iter().filter(|v| v.at_reference).count();
            let at_all = all.iter().filter(|v| v.at_reference).count();
            assert_eq!(at, n.div_ceil(2).min(at_all), "n {n}");
            for (i, a) in got.iter().enumerate() {
                assert!(all.contains(a));
                assert!(got[..i].iter().all(|b| b != a), "n {n}: {a:?} twice");
            }
        }
        // 24 of them: both ends of the track, and every direction both at and between samples.
        let got = spread(&all, 24);
        let at: Vec<&EvalView> = got.iter().filter(|v| v.at_reference).collect();
        assert!(at.iter().any(|v| v.s == arcs[arcs.len() - 1]));
        for part in [true, false] {
            for rel in [0.0, 90.0, 180.0, 270.0] {
                assert!(got
                    .iter()
                    .any(|v| v.at_reference == part && v.yaw_from_track_deg == rel));
            }
        }
        assert_eq!(spread(&all[..3], 24), all[..3].to_vec());
    }

    #[test]
    fn matched_size_and_ratio() {
        assert_eq!(matched_size(192, 90.0, 0.75), (192, 144));
        assert!((resolution_ratio(192, 90.0, 192) - 1.0).abs() < 1e-12);
        assert!((resolution_ratio(192, 90.0, 96) - 2.0).abs() < 1e-12);
        let (w, _) = matched_size(256, 60.0, 0.75);
        assert!((resolution_ratio(256, 60.0, w) - 1.0).abs() < 0.01);
    }

    #[test]
    fn stats_and_worst_views() {
        let row = |s: f64, p: f64, at: bool| EvalRow {
            config: "full".into(),
            view: EvalView {
                track: 0,
                s,
                segment: 0,
                yaw_deg: 0.0,
                yaw_from_track_deg: 0.0,
                pitch_deg: 0.0,
                at_reference: at,
            },
            position: [s, 0.0, 0.0],
            psnr_db: p,
            ssim: 1.0,
            hole_fraction: 0.0,
            filled_fraction: 0.0,
            frame_ms: 2.0,
            db_bytes: 5,
        };
        let rows = vec![
            row(0.0, 60.0, true),
            row(0.5, 30.0, false),
            row(0.7, 20.0, false),
            row(0.9, 40.0, false),
        ];
        let s = summarize(&rows);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].at_samples.psnr_mean_db, 60.0);
        assert_eq!(s[0].between.psnr_mean_db, 30.0);
        assert_eq!(s[0].between.psnr_worst5_db, 20.0);
        let w = worst_views(&rows, "full", 2);
        assert_eq!(w.iter().map(|r| r.view.s).collect::<Vec<_>>(), [0.7, 0.5]);
    }

    #[test]
    fn triptych_shows_the_difference() {
        let a = vec![[100u8, 100, 100]; 4];
        let b = vec![[90u8, 100, 110]; 4];
        let img = triptych(&a, &b, 2, 2);
        assert_eq!(img.dimensions(), (14, 2));
        assert_eq!(img.get_pixel(12, 1).0, [40, 0, 40]);
    }
}
