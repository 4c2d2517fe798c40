//! `railview eval` as a typed stage: [`EvalParams`] → [`run`] → the [`EvalReport`], with
//! `eval.json`, `eval.csv`, `eval.md`, the figures (SVG and PNG), `worst-N.png` and the
//! ground-truth pictures (`truth/`, reused by later runs) written into its directory.
//!
//! [`Instruments`] (the renderer, the ground truth and its cache, the views' size) evaluate
//! walkthroughs on views; the stage makes them once for every walkthrough it weighs (the
//! database, its coarse level groups, the `also` databases), and the sweep's bench once for
//! all its databases. [`Bound`] is the sampling bound evaluated beside.
//!
//! ```no_run
//! use viewer::eval::stage::{self, EvalParams};
//! let params = EvalParams {
//!     worst: 1,
//!     ..EvalParams::new("db", "eval".into())
//! };
//! let report = stage::run(&params, |_| {})?;
//! println!("{} rows", report.rows.len());
//! # Ok::<(), stage::StageError>(())
//! ```

use std::fmt::Display;
use std::path::{Path, PathBuf};

use super::bound::{BoundSource, ClassTally};
use super::pictures::{worst_pictures, PictureInput};
use super::report::{self, EvalReport};
use super::{
    default_configs, evaluate, mark_references, matched_size, resolution_ratio, summarize,
    views_at_samples, views_between, EvalConfig, EvalInput, EvalRow, EvalView, Truth, TruthCache,
    ViewSpec,
};
use crate::gpu::{Gpu, GpuError, Renderer};
use crate::headless::{open, HeadlessError};
use crate::plan::{DrawBudget, PlanError};
use crate::source::{LoadOptions, Walkthrough};

/// The size of the evaluated views.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewSize {
    /// Pixels as wide as the panorama's at the view centre, 4:3 ([`matched_size`]).
    Matched,
    Pixels {
        width: u32,
        height: u32,
    },
}

/// The renderer budgets evaluated on the walkthrough given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigSet {
    /// [`default_configs`]: full, one slab, one view, coarser textures, the second view at
    /// half resolution.
    All,
    /// The full budget only.
    Full,
}

/// Everything an evaluation needs.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalParams {
    /// What to evaluate: a database or prerender directory (any scene: built-in, scene
    /// file, POV-Ray import), or `synth:street` (what [`open`] takes).
    pub db: String,
    /// Output directory.
    pub out: PathBuf,
    pub size: ViewSize,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
    /// Where to look: positions per segment, directions, pitches, the first segments.
    pub views: ViewSpec,
    /// Ground-truth rays per pixel along each axis (box filter over the pixel).
    pub truth_supersample: u32,
    /// Where ground-truth pictures are kept between runs (`None`: `OUT/truth`).
    pub truth_cache: Option<PathBuf>,
    /// The prerender directory the database was built from (`None`: `DB.work/prerender`
    /// when it made this database).
    pub prerender: Option<PathBuf>,
    pub configs: ConfigSet,
    /// Worst views pictured beside their truth.
    pub worst: usize,
    /// Timed draws per view and configuration (after one untimed draw).
    pub timed_draws: usize,
    /// The track (`None`: every track of a network; the only track of one that is not).
    pub track: Option<String>,
    /// Evaluate the sampling bound beside, where the prerender directory is at hand.
    pub bound: bool,
    /// Other databases of the same scene and tracks, evaluated beside as configurations
    /// named after their directory and texture coding.
    pub also: Vec<String>,
}

impl EvalParams {
    /// An evaluation of `db` into `out` with `railview eval`'s defaults.
    pub fn new(db: impl Into<String>, out: PathBuf) -> EvalParams {
        EvalParams {
            db: db.into(),
            out,
            size: ViewSize::Matched,
            fov_deg: 90.0,
            views: ViewSpec::default(),
            truth_supersample: 3,
            truth_cache: None,
            prerender: None,
            configs: ConfigSet::All,
            worst: 3,
            timed_draws: 3,
            track: None,
            bound: true,
            also: Vec::new(),
        }
    }

    /// Refuse nonsense before anything is rendered or written; the messages name
    /// `railview eval`'s options.
    pub fn check(&self) -> Result<(), StageError> {
        let v = &self.views;
        if let Some(n) = v.max_segments {
            tracks::limits::check_u64("--segments", n as u64, 1, 100_000)?;
        }
        let fov = self.fov_deg;
        let checks = [
            (
                fov.is_finite() && fov > 0.0 && fov < 180.0,
                "--fov must be in (0, 180) degrees",
            ),
            (
                (1..=64).contains(&v.per_segment),
                "--per-segment must be in 1..=64",
            ),
            (
                (1..=64).contains(&v.directions),
                "--directions must be in 1..=64",
            ),
            (
                (1..=16).contains(&self.truth_supersample),
                "--truth-supersample must be in 1..=16",
            ),
            (
                (1..=100).contains(&self.timed_draws),
                "--timed-draws must be in 1..=100",
            ),
        ];
        if let Some((_, message)) = checks.iter().find(|(ok, _)| !ok) {
            return Err(StageError::Parameter(message.to_string()));
        }
        if let Some(p) = v.pitches_deg.iter().find(|p| !(-89.0..=89.0).contains(*p)) {
            return Err(StageError::Parameter(format!(
                "--pitch `{p}`: expected degrees in -89..=89"
            )));
        }
        if let ViewSize::Pixels { width, height } = self.size {
            if ![width, height].iter().all(|v| (1..=16384).contains(v)) {
                return Err(StageError::Parameter(format!(
                    "size `{width}x{height}`: expected sides in 1..=16384"
                )));
            }
        }
        Ok(())
    }
}

/// Errors of the headless stages (eval, flythrough). Printed with its sources (`{:#}` of an
/// `anyhow` error), it reads as the command line has always printed it: context first, then
/// each cause.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StageError {
    /// A parameter is out of range or contradicts the walkthrough; the message names the
    /// command line's option.
    #[error("{0}")]
    Parameter(String),
    #[error(transparent)]
    Limit(#[from] tracks::limits::OutOfRange),
    #[error(transparent)]
    View(#[from] HeadlessError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Db(#[from] db::DbError),
    #[error(transparent)]
    Store(#[from] prerender::store::StoreError),
    #[error(transparent)]
    Chart(#[from] charts::ChartError),
    #[error(transparent)]
    Image(#[from] image::ImageError),
    /// What the stage was doing when `source` happened.
    #[error("{context}")]
    Context {
        context: String,
        #[source]
        source: Box<StageError>,
    },
}

impl StageError {
    /// `self`, said to have happened while doing `context`.
    pub fn context(self, context: impl Display) -> StageError {
        StageError::Context {
            context: context.to_string(),
            source: Box::new(self),
        }
    }
}

/// What views are measured with, made once for any number of walkthroughs: the renderer,
/// the ground truth and its cache, the views' size and field of view, the timed draws.
pub struct Instruments {
    pub renderer: Renderer,
    pub truth: Truth,
    pub cache: TruthCache,
    pub size: (u32, u32),
    pub fov_deg: f64,
    /// Draws timed per view and configuration, after one untimed draw.
    pub timed_draws: usize,
}

/// The sampling bound of a walkthrough: the exact warp of its reference panoramas (from its
/// prerender directory), evaluated beside the configurations, and the first
/// configuration's error per pixel class against it.
pub struct Bound {
    pub source: BoundSource,
    pub tally: ClassTally,
}

impl Bound {
    /// The bound from prerender directory `dir` (its `prerender.json` must exist).
    pub fn open(dir: &Path) -> Result<Bound, HeadlessError> {
        Ok(Bound {
            source: BoundSource::open(dir)?,
            tally: ClassTally::default(),
        })
    }
}

impl Instruments {
    /// Every configuration at every view of `walk` (a view on another track of a network
    /// moves it there): one row per (view, configuration), and the bound's rows beside.
    /// `progress` is called after each row.
    pub fn evaluate(
        &mut self,
        walk: &mut Walkthrough,
        configs: &[EvalConfig],
        views: &[EvalView],
        bound: Option<&mut Bound>,
        progress: impl FnMut(&EvalRow),
    ) -> Result<Vec<EvalRow>, HeadlessError> {
        let input = EvalInput {
            walk,
            truth: &mut self.truth,
            cache: &self.cache,
            configs,
            views,
            size: self.size,
            fov_deg: self.fov_deg,
            timed_draws: self.timed_draws,
            bound: bound.map(|b| (&mut b.source, &mut b.tally)),
        };
        evaluate(&mut self.renderer, input, progress)
    }

    /// `worst-1.png` … `worst-N.png` and `worst-at-sample.png` of `config` into `out`;
    /// returns the `n` worst rows between samples, worst first.
    pub fn worst_pictures(
        &mut self,
        walk: &mut Walkthrough,
        config: &EvalConfig,
        rows: &[EvalRow],
        n: usize,
        out: &Path,
    ) -> Result<Vec<EvalRow>, HeadlessError> {
        let input = PictureInput {
            renderer: &mut self.renderer,
            walk,
            config: &config.name,
            budget: config.budget,
            size: self.size,
            fov_deg: self.fov_deg,
            cache: &self.cache,
            truth: &mut self.truth,
        };
        worst_pictures(input, rows, n, out)
    }
}

/// What an evaluation tells its caller as it goes.
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub enum EvalEvent<'a> {
    /// Before the first view: the rows to evaluate (views × configurations; the sampling
    /// bound's rows come on top).
    Planned { rows: usize },
    /// A row was evaluated.
    Row(&'a EvalRow),
    /// Every row is evaluated; the worst views' pictures and the files follow.
    Evaluated,
    /// The files are written; `markdown` is `eval.md`.
    Written { markdown: &'a str },
}

/// One walkthrough to evaluate with its renderer budgets.
struct Run {
    walk: Walkthrough,
    configs: Vec<EvalConfig>,
}

fn full(name: &str) -> Vec<EvalConfig> {
    vec![EvalConfig {
        name: name.to_string(),
        budget: DrawBudget::default(),
    }]
}

/// For a database directory, the level-group counts (1, 2) below the most any tile's PTM has:
/// the partial loads worth evaluating. Nothing for other sources.
fn coarse_level_groups(db: &str) -> Result<Vec<usize>, StageError> {
    if !Path::new(db).join(db::MANIFEST_FILE).is_file() {
        return Ok(Vec::new());
    }
    let most = db::Database::open(Path::new(db))?.most_level_groups();
    Ok((1..=2).filter(|&g| g < most).collect())
}

/// The walkthroughs: the one given, then for the synthetic street other databases (one
/// slab, a coarser mesh, wider spacing), for a database its first level groups, then the
/// `also` databases.
fn runs(params: &EvalParams, walk: Walkthrough) -> Result<Vec<Run>, StageError> {
    let mut runs = vec![Run {
        walk,
        configs: match params.configs {
            ConfigSet::Full => full("full"),
            ConfigSet::All => default_configs(),
        },
    }];
    let db = &params.db;
    if db == "synth:street" {
        for (name, walk) in crate::headless::synth_street_variants()? {
            runs.push(Run {
                walk,
                configs: full(name),
            });
        }
    }
    let track = params.track.as_deref();
    // A database: also what a client shows before the finer texture levels arrive (the first
    // level groups of every PTM), whose bytes are what those groups cost.
    for groups in coarse_level_groups(db)? {
        let name = format!("db level groups={groups}");
        let opts = LoadOptions {
            level_groups: Some(groups),
            every_track: track.is_none(),
            ..Default::default()
        };
        let walk = open(db, track, opts).map_err(|e| {
            StageError::from(e).context(format!("opening {db} with {groups} level groups"))
        })?;
        runs.push(Run {
            walk,
            configs: full(&name),
        });
    }
    let scene = runs[0].walk.scene.clone();
    for other in &params.also {
        let coding = db::Database::open(Path::new(other))?.texture_coding()?;
        let name = format!("also {other} ({coding})");
        let opts = LoadOptions {
            every_track: track.is_none(),
            ..LoadOptions::default()
        };
        let walk = open(other, track, opts)
            .map_err(|e| StageError::from(e).context(format!("opening {other}")))?;
        if walk.scene != scene {
            return Err(StageError::Parameter(format!(
                "--also {other}: scene `{}`, not `{scene}`",
                walk.scene
            )));
        }
        runs.push(Run {
            walk,
            configs: full(&name),
        });
    }
    Ok(runs)
}

/// The views of every track evaluated (the one named, or each of a network), at the first
/// walkthrough's samples and between them.
struct Views {
    tracks: Vec<usize>,
    at_samples: Vec<EvalView>,
    between: Vec<EvalView>,
}

impl Views {
    fn new(walk: &mut Walkthrough, params: &EvalParams) -> Views {
        let tracks: Vec<usize> = match &params.track {
            Some(_) => vec![walk.current],
            None => (0..walk.tracks.len()).collect(),
        };
        let start = walk.current;
        let mut at_samples = Vec::new();
        let mut between = Vec::new();
        for &t in &tracks {
            walk.set_track(t);
            let (_, arcs) = walk.order_and_arcs();
            at_samples.extend(views_at_samples(walk, &params.views));
            between.extend(views_between(walk, &arcs, &params.views));
        }
        walk.set_track(start);
        Views {
            tracks,
            at_samples,
            between,
        }
    }

    /// The views as evaluated on `walk`: those between samples marked where they lie at one
    /// of its own samples.
    fn on(&self, walk: &mut Walkthrough) -> Vec<EvalView> {
        let mut v = self.at_samples.clone();
        let mut b = self.between.clone();
        for &t in &self.tracks {
            walk.set_track(t);
            let mut mine: Vec<EvalView> = b.iter().filter(|x| x.track == t).copied().collect();
            mark_references(walk, &mut mine);
            for (x, m) in b.iter_mut().filter(|x| x.track == t).zip(mine) {
                *x = m;
            }
        }
        v.extend(b);
        v
    }
}

/// The views [`run`] evaluates `params.db` on (every track's, or the named track's, at its
/// samples then between them, as `params.views` places them), without rendering anything:
/// what other renderers are compared on (the browser viewer's fidelity test and its
/// measurement take these, or [`spread`](super::spread) of them).
pub fn chosen_views(params: &EvalParams) -> Result<Vec<EvalView>, StageError> {
    params.check()?;
    let db = &params.db;
    let opts = LoadOptions {
        every_track: params.track.is_none(),
        ..LoadOptions::default()
    };
    let mut walk = open(db, params.track.as_deref(), opts)
        .map_err(|e| StageError::from(e).context(format!("opening {db}")))?;
    Ok(Views::new(&mut walk, params).on(&mut walk))
}

/// Evaluate `params.db` (and the walkthroughs weighed beside it) against the ground truth
/// and write the outputs; `progress` hears how far it is.
pub fn run(
    params: &EvalParams,
    mut progress: impl FnMut(EvalEvent),
) -> Result<EvalReport, StageError> {
    params.check()?;
    let db = &params.db;
    // Without a track named, every track of a network is evaluated.
    let opts = LoadOptions {
        every_track: params.track.is_none(),
        ..LoadOptions::default()
    };
    let mut walk = open(db, params.track.as_deref(), opts)
        .map_err(|e| StageError::from(e).context(format!("opening {db}")))?;
    let face = walk.views.first().map_or(0, |v| v.face_size);
    if face == 0 {
        return Err(StageError::Parameter(format!("{db}: no reference views")));
    }
    let size = match params.size {
        ViewSize::Matched => matched_size(face, params.fov_deg, 0.75),
        ViewSize::Pixels { width, height } => (width, height),
    };
    let out = &params.out;
    prerender::store::ensure_writable_dir(out)?;
    let truth = Truth::for_walkthrough(
        db,
        &walk,
        params.prerender.as_deref(),
        params.truth_supersample,
        &out.join("pov-truth"),
    )?;
    let cache = TruthCache {
        dir: Some(
            params
                .truth_cache
                .clone()
                .unwrap_or_else(|| out.join("truth")),
        ),
    };
    let views = Views::new(&mut walk, params);
    let mut runs = runs(params, walk)?;
    let total: usize = runs
        .iter_mut()
        .map(|r| views.on(&mut r.walk).len() * r.configs.len())
        .sum();
    // The sampling bound, for the first walkthrough, from its prerender directory.
    let prerender_dir = super::prerender_dir(db, &runs[0].walk, params.prerender.as_deref());
    let mut bound = match prerender_dir {
        Some(dir) if params.bound => Some(Bound::open(&dir)?),
        _ => None,
    };
    let mut inst = Instruments {
        renderer: Renderer::new(Gpu::new()?)?,
        truth,
        cache,
        size,
        fov_deg: params.fov_deg,
        timed_draws: params.timed_draws,
    };
    progress(EvalEvent::Planned { rows: total });
    let mut rows: Vec<EvalRow> = Vec::new();
    for (ri, r) in runs.iter_mut().enumerate() {
        let on = views.on(&mut r.walk);
        let b = bound.as_mut().filter(|_| ri == 0);
        let row = |row: &EvalRow| progress(EvalEvent::Row(row));
        rows.extend(inst.evaluate(&mut r.walk, &r.configs, &on, b, row)?);
    }
    progress(EvalEvent::Evaluated);
    let first = &mut runs[0];
    let worst =
        inst.worst_pictures(&mut first.walk, &first.configs[0], &rows, params.worst, out)?;
    let rep = EvalReport {
        db: db.clone(),
        scene: first.walk.scene.clone(),
        truth: inst.truth.describe(),
        width: size.0,
        height: size.1,
        fov_deg: params.fov_deg,
        face_size: face,
        resolution_ratio: resolution_ratio(face, params.fov_deg, size.0),
        views: params.views.clone(),
        adapter: format!(
            "{} ({:?})",
            inst.renderer.gpu.info.name, inst.renderer.gpu.info.backend
        ),
        summary: summarize(&rows),
        worst,
        rows,
        classes: bound.map(|b| b.tally),
    };
    let markdown = write(&rep, out)?;
    progress(EvalEvent::Written {
        markdown: &markdown,
    });
    Ok(rep)
}

/// `eval.json`, `eval.csv`, the figures and `eval.md` (returned) into `out`.
fn write(rep: &EvalReport, out: &Path) -> Result<String, StageError> {
    use prerender::store::{write_atomic, write_json};
    write_json(&out.join("eval.json"), rep)?;
    write_atomic(&out.join("eval.csv"), report::csv(&rep.rows).as_bytes())?;
    let mut listed = Vec::new();
    for (stem, title, fig) in report::figures(rep) {
        write_atomic(
            &out.join(format!("{stem}.svg")),
            charts::svg(&fig)?.as_bytes(),
        )?;
        write_atomic(&out.join(format!("{stem}.png")), &charts::png(&fig)?)?;
        listed.push((format!("{stem}.svg"), title));
    }
    let md = report::markdown(rep, &listed);
    write_atomic(&out.join("eval.md"), md.as_bytes())?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_name_the_options_in_the_order_the_command_line_gives_them() {
        let ok = EvalParams::new("synth:street", PathBuf::from("out"));
        assert!(ok.check().is_ok());
        let mut p = ok.clone();
        p.views.max_segments = Some(0);
        p.fov_deg = 180.0;
        let e = p.check().unwrap_err().to_string();
        assert!(e.contains("--segments") && e.contains("1 to 100000"), "{e}");
        p.views.max_segments = None;
        assert_eq!(
            p.check().unwrap_err().to_string(),
            "--fov must be in (0, 180) degrees"
        );
        let mut p = ok.clone();
        p.views.pitches_deg = vec![0.0, 90.0];
        assert!(p.check().unwrap_err().to_string().contains("--pitch `90`"));
        let mut p = ok;
        p.size = ViewSize::Pixels {
            width: 0,
            height: 10,
        };
        assert!(p.check().is_err());
    }

    #[test]
    fn an_error_reads_as_its_context_then_its_causes() {
        let e = StageError::Parameter("no views".into()).context("opening db");
        assert_eq!(e.to_string(), "opening db");
        let cause = std::error::Error::source(&e).map(|s| s.to_string());
        assert_eq!(cause.as_deref(), Some("no views"));
    }
}
