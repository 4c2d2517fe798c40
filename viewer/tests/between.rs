//! What a walker sees between samples, in the cases that break two-view renderers: the sky
//! through a gap neither reference sees through, a surface one reference sees edge-on, and
//! a view exactly at a sample. On the default adapter (lavapipe without a GPU) and on the
//! CPU reference; `RAILVIEW_SKIP_GPU_TESTS=1` marks them as ignored.

use glam::DVec3;
use tracks::{PerspectiveCamera, SlabRange};
use viewer::gpu::{Frame, Gpu, Renderer};
use viewer::synth::{views_along, Scene, Shape};
use viewer::{cpu, plan_frame, DrawBudget, LayerMeshing, RefView};

fn renderer() -> Renderer {
    let gpu = Gpu::new().expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    Renderer::new(gpu).expect("the renderer on this adapter")
}

const EYE: f64 = 1.7;
const SKY: [u8; 3] = [130, 180, 235];

fn cuboid(min: [f64; 3], max: [f64; 3], color: [u8; 3]) -> Shape {
    Shape::Cuboid {
        min: DVec3::from(min),
        max: DVec3::from(max),
        color,
    }
}

fn one_slab() -> Vec<SlabRange> {
    vec![SlabRange {
        near: 0.0,
        far: f64::INFINITY,
    }]
}

fn views(scene: &Scene, samples: &[(f64, DVec3)], slabs: &[SlabRange]) -> Vec<RefView> {
    views_along(scene, samples, 64, 16, slabs, LayerMeshing::default()).unwrap()
}

fn pixel(f: &Frame, x: u32, y: u32) -> [u8; 4] {
    let i = 4 * (y * f.width + x) as usize;
    [f.rgba[i], f.rgba[i + 1], f.rgba[i + 2], f.rgba[i + 3]]
}

fn close(a: [u8; 4], b: [u8; 3], tol: u8) -> bool {
    (0..3).all(|k| a[k].abs_diff(b[k]) <= tol)
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn a_view_through_a_one_pixel_gap_sees_the_sky_never_black() {
    // Two thick walls 10 m ahead with a gap about one view pixel wide between them (0.16 m
    // at 10 m, 96 pixels over 90°). The references, 0.6 m to either side, see walls where
    // the view between them looks through the gap: the gap is a hole of both, filled from
    // its farther side, the sky above the walls.
    let red = [200, 60, 50];
    let scene = Scene {
        shapes: vec![
            cuboid([-6.0, 0.0, -12.0], [-0.08, 3.0, -10.0], red),
            cuboid([0.08, 0.0, -12.0], [6.0, 3.0, -10.0], red),
        ],
        sky: SKY,
    };
    let samples = [
        (0.0, DVec3::new(-0.6, EYE, 0.0)),
        (1.2, DVec3::new(0.6, EYE, 0.0)),
    ];
    let v = views(&scene, &samples, &one_slab());
    let camera = PerspectiveCamera {
        position: DVec3::new(0.0, EYE, 0.0),
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        fov_deg: 90.0,
        width: 96,
        height: 64,
    };
    let plan = plan_frame(&v, &camera, 0.6, DrawBudget::default()).unwrap();
    let truth = scene.perspective(&camera);
    let gpu = renderer().render(&plan, &v).unwrap();
    let cpu = cpu::render(&plan, &v);
    for (name, f) in [("gpu", &gpu), ("cpu", &cpu)] {
        assert_eq!(f.hole_fraction(), 0.0, "{name}: no pixel left empty");
        // The gap's pixels: the truth shows sky there, below the walls' top.
        let gap: Vec<(u32, u32)> = (0..64u32)
            .flat_map(|y| (0..96u32).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let i = (y * 96 + x) as usize;
                truth[i] == SKY && {
                    let left = truth[i.saturating_sub(1)];
                    let right = truth[(i + 1).min(truth.len() - 1)];
                    left != SKY || right != SKY
                }
            })
            .filter(|&(_, y)| y > 28)
            .collect();
        assert!(!gap.is_empty(), "the gap is in view");
        for &(x, y) in &gap {
            let p = pixel(f, x, y);
            assert_ne!(&p[..3], &[0, 0, 0], "{name}: ({x}, {y}) is black");
            assert!(
                close(p, SKY, 8) || close(p, red, 60),
                "{name}: ({x}, {y}) = {p:?}, neither the sky nor the wall"
            );
        }
        let sky = gap.iter().filter(|&&(x, y)| close(pixel(f, x, y), SKY, 8));
        assert!(
            sky.count() * 2 >= gap.len(),
            "{name}: most of the gap shows the sky"
        );
    }
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn a_surface_one_reference_sees_edge_on_comes_from_the_other() {
    // A long wall along the track's direction, its face at x = 2. Reference A stands 2 cm
    // off that plane and sees the face edge-on (a sliver of its panorama, stretched over the
    // whole wall in a view between); reference B, 3 m away, sees it squarely. Halfway, the
    // wall must look as B alone draws it, not as a half-and-half blend with A's smear.
    let scene = Scene {
        shapes: vec![
            Shape::Ground {
                y: 0.0,
                radius: 100.0,
                color: [90, 140, 70],
            },
            cuboid([2.0, 0.0, -14.0], [2.4, 4.0, -2.0], [220, 180, 60]),
        ],
        sky: SKY,
    };
    let a = (0.0, DVec3::new(1.98, EYE, 0.0));
    let b = (3.0, DVec3::new(-1.02, EYE, 0.0));
    let both = views(&scene, &[a, b], &one_slab());
    let camera = PerspectiveCamera {
        position: DVec3::new(0.48, EYE, 0.0),
        yaw_deg: 30.0,
        pitch_deg: 0.0,
        fov_deg: 70.0,
        width: 96,
        height: 64,
    };
    let mut r = renderer();
    let plan = plan_frame(&both, &camera, 1.5, DrawBudget::default()).unwrap();
    assert_eq!(plan.passes.len(), 2);
    assert!(plan.passes.iter().all(|p| (p.weight - 0.5).abs() < 0.05));
    let blended = r.render(&plan, &both).unwrap();
    // Each reference alone, at the same camera.
    let mut alone = |sample: (f64, DVec3)| {
        let v = views(&scene, &[sample], &one_slab());
        r.forget_views();
        r.render(
            &plan_frame(&v, &camera, sample.0, DrawBudget::default()).unwrap(),
            &v,
        )
        .unwrap()
    };
    let (from_a, from_b) = (alone(a), alone(b));
    let truth = scene.perspective(&camera);
    let wall: Vec<usize> = (0..truth.len())
        .filter(|&i| truth[i][2] < 100 && truth[i][0] > 150)
        .collect();
    assert!(wall.len() > 500, "the wall fills much of the view");
    let error = |f: &Frame| {
        wall.iter()
            .map(|&i| {
                (0..3)
                    .map(|k| f.rgba[4 * i + k].abs_diff(truth[i][k]) as f64)
                    .sum::<f64>()
            })
            .sum::<f64>()
            / (3 * wall.len()) as f64
    };
    let (e, ea, eb) = (error(&blended), error(&from_a), error(&from_b));
    eprintln!("wall, mean |error|: blended {e:.2}, A alone {ea:.2}, B alone {eb:.2}");
    assert!(
        ea > 2.0 * eb,
        "A sees the wall edge-on: {ea:.2} against {eb:.2}"
    );
    assert!(
        e < eb + 0.25 * (ea - eb),
        "the blend takes A's edge-on samples: {e:.2} (A {ea:.2}, B {eb:.2})"
    );
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn a_view_exactly_at_a_sample_is_that_samples_own_view() {
    // The street: at sample 0 the two-view frame must be the sample's own view, exactly,
    // with neither the second view nor the fill changing a pixel it covers.
    let scene = Scene::street();
    let samples = [
        (0.0, DVec3::new(0.0, EYE, 0.0)),
        (1.5, DVec3::new(1.5, EYE, 0.0)),
    ];
    let both = views(&scene, &samples, &Scene::street_slabs());
    let own = views(&scene, &samples[..1], &Scene::street_slabs());
    let mut r = renderer();
    for yaw in [0.0, 45.0, 180.0, 270.0] {
        let camera = PerspectiveCamera {
            position: samples[0].1,
            yaw_deg: yaw,
            pitch_deg: -5.0,
            fov_deg: 90.0,
            width: 96,
            height: 64,
        };
        let plan = plan_frame(&both, &camera, 0.0, DrawBudget::default()).unwrap();
        r.forget_views();
        let two = r.render(&plan, &both).unwrap();
        r.forget_views();
        let one = r
            .render(
                &plan_frame(&own, &camera, 0.0, DrawBudget::default()).unwrap(),
                &own,
            )
            .unwrap();
        assert_eq!(two.hole_fraction(), 0.0, "yaw {yaw}");
        let mut se = 0.0;
        for (p, q) in two.rgba.chunks(4).zip(one.rgba.chunks(4)) {
            for k in 0..3 {
                se += (p[k] as f64 - q[k] as f64).powi(2);
            }
        }
        let mse = se / (3 * two.rgba.len() / 4) as f64;
        let psnr = if mse == 0.0 {
            f64::INFINITY
        } else {
            10.0 * (255.0f64 * 255.0 / mse).log10()
        };
        eprintln!("yaw {yaw}: at the sample {psnr:.1} dB against its own view");
        assert!(psnr >= 60.0, "yaw {yaw}: {psnr:.1} dB");
    }
}
