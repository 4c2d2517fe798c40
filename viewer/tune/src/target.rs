//! A database for a PSNR target: a sweep of the knobs around a build's settings, and the
//! build of the cheapest configuration whose worst 5 % of views reach the target, from the
//! sweep's own stages (nothing is rendered or encoded again), with the choice and its
//! evidence in the build's report.

use std::path::PathBuf;

use stages::build::{BuildParams, BuildScene};
use stages::encode::BuildReport;
use stages::prerender::PovParams;
use stages::progress::Reporter;
use stages::{CullChoice, Knobs};

use crate::error::{Error, Result};
use crate::knobs::SweepSpec;
use crate::record::Cost;
use crate::sweep::{Sweep, SweepParams, ViewParams};

/// What a target asks for besides the build.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetParams {
    /// PSNR (dB) the worst 5 % of views must reach.
    pub psnr_db: f64,
    /// The cost to minimise.
    pub cost: Cost,
    /// The sweep's directory (default: `WORK/tune`).
    pub tune_dir: Option<PathBuf>,
    /// Evaluation views per segment and directions per position.
    pub per_segment: usize,
    pub directions: usize,
}

/// Sweep the knobs around `build`'s (`railview tune`'s lists), choose the cheapest
/// configuration reaching the target on the worst 5 % of views, and build it into
/// `build.out`, reporting beside the database's work directory.
pub fn build_for_target(
    build: &BuildParams,
    target: &TargetParams,
    progress: &Reporter,
) -> Result<BuildReport> {
    let t = target.psnr_db;
    if !(t.is_finite() && t > 0.0) {
        return Err(Error::Parameter(
            "--target-psnr must be a positive number of dB".into(),
        ));
    }
    let work = build.work_dir();
    prerender::store::ensure_writable_dir(&work)?;
    let tune_dir = target.tune_dir.clone().unwrap_or_else(|| work.join("tune"));
    let track = build.track_file(&work)?;
    let pov = matches!(build.scene, BuildScene::PovRay { .. });
    let k = &build.knobs;
    let (cull, alpha) = match build.cull_variant()? {
        None => (CullChoice::Off, 1.0),
        Some(v) => (CullChoice::Variant(v), k.alpha),
    };
    if pov && k.supersample > 2 {
        return Err(Error::Parameter("--supersample with --pov: 1 or 2".into()));
    }
    let base = Knobs {
        every: 1,
        samples: None,
        spacing_m: None,
        cull,
        alpha,
        drop_levels: 0,
        ..k.clone()
    };
    let scene = match &build.scene {
        BuildScene::Tracer(s) => BuildScene::Tracer(s.clone()),
        // The sweep renders with POV-Ray's defaults, in the scene's frame.
        BuildScene::PovRay { scene, pov } => BuildScene::PovRay {
            scene: scene.clone(),
            pov: PovParams {
                up: pov.up,
                ..PovParams::default()
            },
        },
    };
    let params = SweepParams {
        scene,
        track,
        out: tune_dir.clone(),
        spec: SweepSpec::around(base),
        targets: vec![t],
        cost: target.cost,
        combine: true,
        views: ViewParams {
            per_segment: target.per_segment,
            directions: target.directions,
            ..ViewParams::default()
        },
        walk_speed: 1.5,
        zstd_level: k.zstd_level,
        ach: build.encode.ach,
        lowres_face_size: build.lowres_face_size,
    };
    let mut sweep = Sweep::new(params, progress)?;
    let report = sweep.run()?;
    let selection = report
        .selections
        .first()
        .ok_or_else(|| Error::Outcome("the sweep made no choice".into()))?;
    let text = crate::report::selection_text(&report, selection);
    let Some(i) = selection.chosen else {
        return Err(Error::Outcome(format!(
            "{text} (the sweep is in {})",
            tune_dir.display()
        )));
    };
    let chosen = &report.records[i];
    progress.message(&text);
    let node = tune_dir.join(&chosen.dir);
    let c = &chosen.knobs;
    let evidence = serde_json::json!({
        "target_psnr_db": t,
        "judged_on": "PSNR of the worst 5 % of views between samples",
        "cost": selection.cost,
        "chosen": chosen,
        "left_out": c.differences(&report.base),
        "summary": text,
        "sweep": tune_dir.display().to_string(),
        "table": crate::report::table(&report),
        "configurations": report.records.len(),
    });
    let chosen_build = BuildParams {
        track: node
            .join("prerender")
            .join("track.toml")
            .display()
            .to_string(),
        track_name: None,
        knobs: Knobs {
            every: 1,
            samples: None,
            spacing_m: None,
            zstd_level: k.zstd_level,
            ..c.clone()
        },
        work: Some(node),
        report_dir: Some(work),
        evidence: Some(evidence),
        ..build.clone()
    };
    Ok(stages::build::run(&chosen_build, progress)?)
}
