//! `railview bench-viewer`: frame time of the full reconstruction (two reference views, all
//! slabs, blending) against a plain single-panorama draw (one cube map, no slabs, no
//! blending), same size, same run, interleaved frame by frame.

use std::time::Instant;

use anyhow::Context;
use viewer::gpu::{Gpu, Renderer};
use viewer::headless::{open, parse_size, synth_street, yaw_along};
use viewer::source::LoadOptions;
use viewer::{plan_frame, DrawBudget, MeshParams, RefView};

/// Arguments of `railview bench-viewer`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory; default: the synthetic street at `--face` pixels.
    pub db: Option<String>,
    #[arg(long, default_value = "1920x1080")]
    pub size: String,
    /// Face size of the synthetic street.
    #[arg(long, default_value_t = 512)]
    pub face: u32,
    /// Mesh grid step (pixels) of the synthetic street.
    #[arg(long, default_value_t = 4)]
    pub mesh_step: u32,
    /// Timed frames per variant.
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Write the results as JSON here.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
}

#[derive(serde::Serialize)]
struct BenchResult {
    adapter: String,
    width: u32,
    height: u32,
    views: usize,
    slabs: usize,
    triangles: usize,
    full_ms: f64,
    /// One reference view, all slabs.
    one_view_ms: f64,
    /// Two views, first slab only.
    one_slab_ms: f64,
    plain_ms: f64,
    ratio: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    anyhow::ensure!(args.frames >= 1, "--frames must be at least 1");
    let mesh = MeshParams {
        step: args.mesh_step,
        ..Default::default()
    };
    let walk = match &args.db {
        Some(db) => open(
            db,
            None,
            LoadOptions {
                mesh,
                ..Default::default()
            },
        )
        .with_context(|| format!("opening {db}"))?,
        None => synth_street(args.face, &viewer::synth::Scene::street_slabs(), mesh)?,
    };
    anyhow::ensure!(
        walk.views.len() >= 2,
        "the benchmark needs two reference views"
    );
    let s = 0.5 * (walk.views[0].s + walk.views[1].s);
    let camera = tracks::PerspectiveCamera {
        position: walk.position_at(s),
        yaw_deg: yaw_along(&walk, s),
        pitch_deg: 0.0,
        fov_deg: 90.0,
        width: w,
        height: h,
    };
    let plan = plan_frame(&walk.views, &camera, s, DrawBudget::default())?;
    let pano = [RefView::panorama(
        usize::MAX,
        walk.views[0].s,
        walk.views[0].position,
        &walk.views[0].flatten(),
    )];
    let pano_plan = plan_frame(&pano, &camera, s, DrawBudget::default())?;
    let mut r = Renderer::new(Gpu::new()?);
    let one_view = DrawBudget {
        blend: false,
        ..Default::default()
    };
    let one_slab = DrawBudget {
        max_slabs: 1,
        ..Default::default()
    };
    let variants = [DrawBudget::default(), one_view, one_slab];
    for _ in 0..3 {
        r.draw(&plan, &walk.views)?;
        r.draw_panorama(&pano_plan, &pano)?;
    }
    let (mut full, mut plain) = (Vec::new(), Vec::new());
    let mut others: Vec<Vec<f64>> = vec![Vec::new(); variants.len() - 1];
    for _ in 0..args.frames {
        for (k, budget) in variants.iter().enumerate() {
            let t = Instant::now();
            let plan = plan_frame(&walk.views, &camera, s, *budget)?;
            r.draw(&plan, &walk.views)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            if k == 0 {
                full.push(ms);
            } else {
                others[k - 1].push(ms);
            }
        }
        let t = Instant::now();
        let p = plan_frame(&pano, &camera, s, DrawBudget::default())?;
        r.draw_panorama(&p, &pano)?;
        plain.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let one_view_ms = median(others[0].clone());
    let one_slab_ms = median(others[1].clone());
    let (full_ms, plain_ms) = (median(full), median(plain));
    let res = BenchResult {
        adapter: format!("{} ({:?})", r.gpu.info.name, r.gpu.info.backend),
        width: w,
        height: h,
        views: plan.passes.len(),
        slabs: walk.views[0].slab_count(),
        triangles: plan
            .passes
            .iter()
            .map(|p| walk.views[p.view].triangle_count())
            .sum(),
        full_ms,
        one_view_ms,
        one_slab_ms,
        plain_ms,
        ratio: full_ms / plain_ms,
    };
    println!("{}", serde_json::to_string_pretty(&res)?);
    if let Some(path) = &args.json {
        prerender::store::write_json(path, &res)?;
    }
    Ok(())
}
