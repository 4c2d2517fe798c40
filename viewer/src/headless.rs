//! Headless use of the renderer: open a walkthrough by name (`synth:street`, a database or a
//! prerender directory), place cameras along its track, render, and evaluate reconstructed
//! views against the ground truth from the same camera ([`evaluate`]).

use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::{PerspectiveCamera, SlabRange, TrackSet};

use crate::gpu::{GpuError, Renderer};
use crate::metrics::{psnr, split_rgba, ssim};
use crate::plan::{plan_frame, DrawBudget, FramePlan, PlanError};
use crate::refview::MeshParams;
use crate::source::{self, LoadOptions, SourceError, Walkthrough};
use crate::synth::{views_along, Scene};

/// Errors of the headless commands.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HeadlessError {
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error("no ground truth for scene `{0}`: evaluation needs a built-in scene (castle, nature) or synth:street")]
    NoTruth(String),
    #[error("{0}")]
    Parameter(String),
}

/// The exact renderer of the scene a walkthrough was made from.
pub enum Truth {
    Synth(Scene),
    Builtin(Box<prerender::scene::Scene>),
}

impl Truth {
    /// Ground truth for `camera` (sRGB RGB, rows from the top).
    pub fn render(&self, camera: &PerspectiveCamera) -> Vec<[u8; 3]> {
        match self {
            Truth::Synth(s) => s.perspective(camera),
            Truth::Builtin(s) => prerender::render::render_perspective(s, camera, 1).color,
        }
    }

    /// The truth for a walkthrough's scene name, if it is one we can render.
    pub fn for_scene(name: &str) -> Option<Truth> {
        if name == "synth:street" {
            return Some(Truth::Synth(Scene::street()));
        }
        let base = name.strip_prefix("builtin:").unwrap_or(name);
        prerender::scenes::builtin(base).map(|b| Truth::Builtin(Box::new(b.scene)))
    }
}

/// The synthetic street walkthrough: samples 1.5 m apart over 4.5 m along x at eye height.
pub fn synth_street(
    face_size: u32,
    slabs: &[SlabRange],
    params: MeshParams,
) -> Result<Walkthrough, HeadlessError> {
    synth_street_spaced(face_size, slabs, params, 1.5)
}

/// The synthetic street with samples `spacing_m` apart.
pub fn synth_street_spaced(
    face_size: u32,
    slabs: &[SlabRange],
    params: MeshParams,
    spacing_m: f64,
) -> Result<Walkthrough, HeadlessError> {
    let set = TrackSet::parse(
        &format!(
            "[[track]]\nname = \"main\"\npoints = [[0, 1.7, 0], [4.5, 1.7, 0]]\nspacing = {spacing_m}\n"
        ),
        "synth:street",
    )
    .map_err(|e| HeadlessError::Parameter(e.to_string()))?;
    let track = set.tracks[0].clone();
    let samples: Vec<(f64, DVec3)> = track
        .viewpoints()
        .iter()
        .map(|v| (v.s, v.position))
        .collect();
    let views = views_along(&Scene::street(), &samples, face_size, 16, slabs, params)
        .map_err(SourceError::from)?;
    let bytes = views
        .iter()
        .map(|v| {
            let tex: usize = v
                .layers
                .iter()
                .map(|l| l.levels[0].as_slice().len() * 4)
                .sum();
            let mesh: usize = v
                .tiles
                .iter()
                .map(|t| t.mesh.vertices.len() * 12 + t.mesh.indices.len() * 4)
                .sum();
            (tex + mesh) as u64
        })
        .sum();
    Ok(Walkthrough {
        scene: "synth:street".into(),
        track,
        views,
        slabs: slabs.to_vec(),
        bytes,
    })
}

/// Open `spec`: `synth:street` or a directory (database or prerender output).
pub fn open(
    spec: &str,
    track: Option<&str>,
    opts: LoadOptions,
) -> Result<Walkthrough, HeadlessError> {
    if spec == "synth:street" {
        return synth_street(64, &Scene::street_slabs(), opts.mesh);
    }
    Ok(source::open(Path::new(spec), track, opts)?)
}

/// Parse `WxH`.
pub fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size `{text}`: expected WxH, e.g. 1280x720"))?;
    let p = |s: &str| {
        s.trim()
            .parse::<u32>()
            .ok()
            .filter(|v| (1..=16384).contains(v))
            .ok_or_else(|| format!("size `{text}`: `{s}` is not a number in 1..=16384"))
    };
    Ok((p(w)?, p(h)?))
}

/// Yaw (degrees, camera convention) that looks along the track at `s`.
pub fn yaw_along(walk: &Walkthrough, s: f64) -> f64 {
    let t = walk.track.tangent_at(s);
    if t.x == 0.0 && t.z == 0.0 {
        0.0
    } else {
        t.x.atan2(-t.z).to_degrees()
    }
}

/// One evaluation row (the `rows` of `eval.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    pub config: String,
    /// Arc length, metres.
    pub position: f64,
    pub at_reference: bool,
    pub psnr_db: f64,
    pub ssim: f64,
    pub hole_fraction: f64,
    /// Mean GPU frame time (plan + draw + wait, no readback), milliseconds.
    pub frame_ms: f64,
    /// Database bytes of the configuration's walkthrough.
    pub db_bytes: u64,
}

/// A renderer configuration to evaluate.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalConfig {
    pub name: String,
    pub budget: DrawBudget,
}

/// The default renderer configurations: everything, first slab only, the nearer view only,
/// half-resolution textures, the second view at half resolution.
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

/// Where to evaluate: every reference sample of the first `max_segments` segments and
/// `between` evenly spaced positions inside each.
pub fn eval_positions(walk: &Walkthrough, max_segments: usize, between: usize) -> Vec<(f64, bool)> {
    let arcs: Vec<f64> = walk.views.iter().map(|v| v.s).collect();
    let mut out = Vec::new();
    for (i, w) in arcs.windows(2).enumerate().take(max_segments.max(1)) {
        if i == 0 {
            out.push((w[0], true));
        }
        for k in 1..=between {
            out.push((
                w[0] + (w[1] - w[0]) * k as f64 / (between + 1) as f64,
                false,
            ));
        }
        out.push((w[1], true));
    }
    if arcs.len() == 1 {
        out.push((arcs[0], true));
    }
    out
}

/// Evaluate `configs` on `walk` against `truth`: one row per configuration and position.
/// `progress` is called after each row.
#[expect(
    clippy::too_many_arguments,
    reason = "a flat list of evaluation settings"
)]
pub fn evaluate(
    renderer: &mut Renderer,
    walk: &Walkthrough,
    truth: &Truth,
    configs: &[EvalConfig],
    positions: &[(f64, bool)],
    size: (u32, u32),
    fov_deg: f64,
    mut progress: impl FnMut(&EvalRow),
) -> Result<Vec<EvalRow>, HeadlessError> {
    renderer.forget_views();
    let mut rows = Vec::new();
    for &(s, at_reference) in positions {
        let camera = PerspectiveCamera {
            position: walk.position_at(s),
            yaw_deg: yaw_along(walk, s),
            pitch_deg: 0.0,
            fov_deg,
            width: size.0,
            height: size.1,
        };
        let gt = truth.render(&camera);
        for cfg in configs {
            // Frames as the window shows them between feedback frames: no tile ids (the
            // fused passes of `gpu`).
            let plan_at = || -> Result<FramePlan, HeadlessError> {
                let mut plan = plan_frame(&walk.views, &camera, s, cfg.budget)?;
                plan.tile_ids = false;
                Ok(plan)
            };
            renderer.draw(&plan_at()?, &walk.views)?;
            let reps = 3;
            let t0 = Instant::now();
            for _ in 0..reps {
                renderer.draw(&plan_at()?, &walk.views)?;
            }
            let frame_ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
            let frame = renderer.read_output()?;
            let (rgb, hole_fraction) = split_rgba(&frame.rgba);
            let row = EvalRow {
                config: cfg.name.clone(),
                position: s,
                at_reference,
                psnr_db: psnr(&rgb, &gt).min(99.0),
                ssim: ssim(&rgb, &gt, size.0, size.1),
                hole_fraction,
                frame_ms,
                db_bytes: walk.bytes,
            };
            progress(&row);
            rows.push(row);
        }
    }
    Ok(rows)
}

/// Per configuration: mean PSNR/SSIM/holes at the reference samples (the resampling floor)
/// and between them (interpolation), mean frame time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalSummary {
    pub config: String,
    pub floor_psnr_db: f64,
    pub floor_ssim: f64,
    pub between_psnr_db: f64,
    pub between_ssim: f64,
    pub between_hole_fraction: f64,
    pub frame_ms: f64,
    pub db_bytes: u64,
}

pub fn summarize(rows: &[EvalRow]) -> Vec<EvalSummary> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.config.as_str()) {
            names.push(&r.config);
        }
    }
    let mean = |v: Vec<f64>| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    names
        .into_iter()
        .map(|name| {
            let of = |at: bool| {
                rows.iter()
                    .filter(move |r| r.config == name && r.at_reference == at)
            };
            EvalSummary {
                config: name.to_string(),
                floor_psnr_db: mean(of(true).map(|r| r.psnr_db).collect()),
                floor_ssim: mean(of(true).map(|r| r.ssim).collect()),
                between_psnr_db: mean(of(false).map(|r| r.psnr_db).collect()),
                between_ssim: mean(of(false).map(|r| r.ssim).collect()),
                between_hole_fraction: mean(of(false).map(|r| r.hole_fraction).collect()),
                frame_ms: mean(
                    rows.iter()
                        .filter(|r| r.config == name)
                        .map(|r| r.frame_ms)
                        .collect(),
                ),
                db_bytes: rows
                    .iter()
                    .find(|r| r.config == name)
                    .map_or(0, |r| r.db_bytes),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_reject_nonsense() {
        assert_eq!(parse_size("1280x720"), Ok((1280, 720)));
        assert_eq!(parse_size("1X1"), Ok((1, 1)));
        for bad in ["", "12", "0x5", "ax3", "5x-1", "99999x2"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn positions_cover_samples_and_midpoints() {
        let w = synth_street(8, &Scene::street_slabs(), MeshParams::default()).unwrap();
        let p = eval_positions(&w, 2, 1);
        assert_eq!(
            p,
            vec![
                (0.0, true),
                (0.75, false),
                (1.5, true),
                (2.25, false),
                (3.0, true)
            ]
        );
    }

    #[test]
    fn summary_separates_floor_and_interpolation() {
        let row = |at: bool, p: f64| EvalRow {
            config: "a".into(),
            position: 0.0,
            at_reference: at,
            psnr_db: p,
            ssim: 1.0,
            hole_fraction: 0.0,
            frame_ms: 2.0,
            db_bytes: 5,
        };
        let s = summarize(&[row(true, 30.0), row(false, 20.0), row(false, 22.0)]);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].floor_psnr_db, 30.0);
        assert_eq!(s[0].between_psnr_db, 21.0);
    }
}
