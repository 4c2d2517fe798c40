//! The reason slabs exist, measured on the built-in `castle` with its automatic slabs: between
//! two reference samples a single reference view shows fewer hole pixels with the slabs than
//! with one slab holding everything. GPU test (see `tests/gpu.rs` for the adapter policy).

use glam::DVec3;
use prerender::render::{render_cube, render_depth_lowres, render_slabs, RenderOptions};
use tracks::{CubeMap, PerspectiveCamera, SlabRange};
use viewer::gpu::{Gpu, Renderer};
use viewer::refview::DenseLayer;
use viewer::{plan_frame, DrawBudget, LayerMeshing, RefView};

const FACE: u32 = 48;

fn views(
    scene: &prerender::scene::Scene,
    samples: &[(f64, DVec3)],
    slabs: &[SlabRange],
) -> Vec<RefView> {
    let opts = RenderOptions {
        face_size: FACE,
        supersample: 1,
        shadows: false,
    };
    samples
        .iter()
        .enumerate()
        .map(|(i, &(s, pos))| {
            let full = render_cube(scene, pos, opts);
            let background = CubeMap::from_fn(FACE, |f, x, y| {
                let c = full.color.get(f, x, y);
                let sky = !full.depth.get(f, x, y).is_finite();
                [c[0], c[1], c[2], if sky { 255 } else { 0 }]
            });
            let layers = render_slabs(scene, pos, slabs, opts);
            let dense: Vec<DenseLayer<'_>> = layers
                .iter()
                .map(|l| DenseLayer {
                    color: &l.color,
                    depth: &l.depth,
                })
                .collect();
            RefView::from_layers(i, s, pos, 8, LayerMeshing::default(), &background, &dense)
                .unwrap()
        })
        .collect()
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn castle_between_samples_automatic_slabs_leave_fewer_holes_than_one_slab() {
    let castle = prerender::scenes::builtin("castle").expect("built-in castle");
    let track = castle
        .tracks
        .get("main")
        .expect("castle track `main`")
        .clone();
    let vps = track.viewpoints();
    let samples: Vec<(f64, DVec3)> = vps.iter().take(2).map(|v| (v.s, v.position)).collect();
    assert_eq!(samples.len(), 2);
    let spacing = samples[1].0 - samples[0].0;
    let lowres: Vec<CubeMap<f32>> = samples
        .iter()
        .map(|&(_, p)| render_depth_lowres(&castle.scene, p, 32))
        .collect();
    let auto = slabs::choose(&lowres, spacing, FACE, &slabs::ChooseParams::default()).slabs;
    eprintln!("automatic slabs: {auto:?}");
    assert!(
        auto.len() >= 2,
        "castle should need more than one slab: {auto:?}"
    );
    let one = [SlabRange {
        near: 0.0,
        far: f64::INFINITY,
    }];
    let s = samples[0].0 + 0.5 * spacing;
    let t = track.tangent_at(s);
    let camera = PerspectiveCamera {
        position: track.position_at(s),
        yaw_deg: t.x.atan2(-t.z).to_degrees(),
        pitch_deg: 0.0,
        fov_deg: 100.0,
        width: 128,
        height: 96,
    };
    let mut r = Renderer::new(Gpu::new().expect("a GPU adapter (lavapipe)")).unwrap();
    let budget = DrawBudget {
        blend: false,
        ..Default::default()
    };
    let mut holes = Vec::new();
    for slabs in [&one[..], &auto[..]] {
        let v = views(&castle.scene, &samples, slabs);
        r.forget_views();
        let plan = plan_frame(&v, &camera, s, budget).unwrap();
        holes.push(r.render(&plan, &v).unwrap().uncovered_fraction());
    }
    eprintln!(
        "castle hole fraction at s = {s:.2}: one slab {}, automatic slabs {}",
        holes[0], holes[1]
    );
    assert!(
        holes[0] > 0.0,
        "the castle view must disocclude something with one slab"
    );
    assert!(holes[1] < holes[0], "{holes:?}");
}
