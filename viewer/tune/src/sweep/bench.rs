//! The sweep's measuring instruments: the GPU renderer, the ground truth and the views every
//! database is evaluated on, made once (`viewer::eval::stage::Instruments`, what `railview
//! eval` measures with); and the evaluation of one database (`eval.json`).

use std::path::Path;

use serde::{Deserialize, Serialize};
use stages::progress::{BarKind, Reporter};
use viewer::eval::stage::{Bound, Instruments};
use viewer::eval::{self, EvalConfig, TruthCache, ViewSpec};

use crate::error::{Error, Result};
use crate::record::ErrorSummary;

/// How the views are chosen and judged.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewParams {
    /// Positions inside every segment of the base sampling.
    pub per_segment: usize,
    /// Directions per position.
    pub directions: usize,
    /// Horizontal field of view, degrees (views at matched resolution for the base face
    /// size, 4:3).
    pub fov_deg: f64,
    /// Ground-truth rays per pixel along each axis.
    pub truth_supersample: u32,
}

impl Default for ViewParams {
    fn default() -> Self {
        ViewParams {
            per_segment: 2,
            directions: 4,
            fov_deg: 90.0,
            truth_supersample: 3,
        }
    }
}

/// `eval.json` of a configuration: the summary and what it was measured with.
#[derive(Serialize, Deserialize)]
pub(super) struct EvalRecord {
    key: String,
    pub error: ErrorSummary,
    pub frame_ms: f64,
    pub resolution_ratio: f64,
    /// The sampling bound's mean PSNR between samples (the exact warp of this database's
    /// reference panoramas, holes black and filled), where its prerender directory was at
    /// hand.
    #[serde(default)]
    pub bound_black_db: Option<f64>,
    #[serde(default)]
    pub bound_filled_db: Option<f64>,
}

/// The instruments, made once.
pub(super) struct Bench {
    /// The renderer, the truth and its cache, the views' size.
    pub inst: Instruments,
    spec: ViewSpec,
    base_face: u32,
    /// Reference-sample arc lengths of the base sampling: the views lie between them.
    arcs: Vec<f64>,
    views_key: String,
}

impl Bench {
    /// The instruments for views like those of `db` (its prerender directory `pre_dir`),
    /// at the base face size, on `gpu`.
    pub fn new(
        gpu: viewer::gpu::Gpu,
        views: &ViewParams,
        base_face: u32,
        arcs: Vec<f64>,
        db: &Path,
        pre_dir: &Path,
        root: &Path,
    ) -> Result<Bench> {
        let walk = viewer::headless::open(&db.display().to_string(), None, Default::default())?;
        let size = eval::matched_size(base_face, views.fov_deg, 0.75);
        let truth = eval::Truth::for_walkthrough(
            &db.display().to_string(),
            &walk,
            Some(pre_dir),
            views.truth_supersample,
            &root.join("pov-truth"),
        )?;
        let spec = ViewSpec {
            per_segment: views.per_segment,
            directions: views.directions,
            pitches_deg: vec![0.0],
            max_segments: None,
        };
        let views_key = format!(
            "views {:?} | {}x{} fov {} | truth {} | base arcs {}",
            spec,
            size.0,
            size.1,
            views.fov_deg,
            truth.describe(),
            arcs.len()
        );
        Ok(Bench {
            inst: Instruments {
                renderer: viewer::gpu::Renderer::new(gpu)?,
                truth,
                cache: TruthCache {
                    dir: Some(root.join("truth")),
                },
                size,
                fov_deg: views.fov_deg,
                timed_draws: 2,
            },
            spec,
            base_face,
            arcs,
            views_key,
        })
    }

    /// Evaluate the database in `dir` on the sweep's views (or read the evaluation made
    /// before).
    /// The sampling bound comes from the configuration's own panoramas (`pre_dir`).
    pub fn evaluate(
        &mut self,
        dir: &Path,
        pre_dir: &Path,
        progress: &Reporter,
    ) -> Result<EvalRecord> {
        let db = dir.join("db");
        let path = dir.join("eval.json");
        if let Ok(r) = prerender::store::read_json::<EvalRecord>(&path) {
            if r.key == self.views_key {
                return Ok(r);
            }
        }
        let mut walk = viewer::headless::open(&db.display().to_string(), None, Default::default())?;
        let mut views = eval::views_at_samples(&walk, &self.spec);
        let mut between = eval::views_between(&walk, &self.arcs, &self.spec);
        eval::mark_references(&walk, &mut between);
        views.extend(between);
        let configs = [EvalConfig {
            name: "full".into(),
            budget: viewer::DrawBudget::default(),
        }];
        let bar = progress.bar(views.len() as u64, "evaluating", BarKind::Steps);
        // Without the configuration's prerender directory, no bound.
        let mut bound = Bound::open(pre_dir).ok();
        let rows = self
            .inst
            .evaluate(&mut walk, &configs, &views, bound.as_mut(), |_| bar.inc(1))?;
        bar.finish();
        let all = eval::summarize(&rows);
        let bound_mean = |name: &str| {
            all.iter()
                .find(|c| c.config == name)
                .map(|c| c.between.psnr_mean_db)
        };
        let s = all
            .first()
            .ok_or_else(|| Error::Outcome("no views evaluated".into()))?;
        let face = walk.views.first().map_or(self.base_face, |v| v.face_size);
        let r = EvalRecord {
            key: self.views_key.clone(),
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
            resolution_ratio: eval::resolution_ratio(face, self.inst.fov_deg, self.inst.size.0),
            bound_black_db: bound_mean(eval::bound::EXACT_BLACK),
            bound_filled_db: bound_mean(eval::bound::EXACT_FILLED),
        };
        prerender::store::write_json(&path, &r)?;
        Ok(r)
    }
}
