//! The renderer on every backend and class of device it may get, each against the same
//! frames:
//!
//! - `vulkan`: lavapipe (Mesa's Vulkan driver on the CPU), every capability;
//! - `gl`: llvmpipe through EGL (wgpu's GL backend: no depth copies, no view formats);
//! - `gl-webgl2`: the same adapter asked for WebGL2-class limits (no storage buffers, no
//!   compute: what an OpenGL ES 3.0 driver offers, and what eframe asks of a GL adapter);
//! - `vulkan-fallbacks`: lavapipe with every optional path switched off ([`Caps`]).
//!
//! Every configuration must draw every frame (fused at a sample, just off it and between
//! samples, one view, the half-resolution second view, the composite with overlays and the
//! heat map, the plain panorama) within [`TOLERANCE`] of the golden images in
//! `tests/golden/` and of the `vulkan` configuration, and count the same visible pixels per
//! tile. The goldens are lavapipe's frames of the built-in synthetic street; after a
//! deliberate change of the picture, `RAILVIEW_UPDATE_GOLDEN=1` rewrites them from the
//! `vulkan` configuration (and the test then still compares every configuration with them).
//!
//! Why each was last rewritten (2026-12-02), against the goldens before: pixels no view
//! covers are filled from the farther side (`fs_fill`) and the street's background holds
//! the complete sky (alpha 255 where a reference sees it, 254 behind its surfaces).
//! `street_one_view`: its 172 holes (disocclusions of one view) are filled, 214 pixels
//! changed; `street_between`, `street_near_sample`, `street_half_res`, `street_sample`:
//! 42, 18, 38 and 2 pixels, cracks along silhouettes and sky edges now filled instead of
//! left black or taking partly covered sky texels; `street_overlays` (the hole overlay,
//! which the fill leaves alone): 30 pixels, sky edges now shown as holes. Stretched
//! triangles counting farther (`refview::stretch`) move a few silhouette pixels besides.
//!
//! A backend that is missing fails the test with the message of what to install (CI
//! installs Mesa's Vulkan driver; GL comes with Mesa's EGL); `RAILVIEW_SKIP_GPU_TESTS=1`
//! marks GPU tests as ignored.

use std::path::PathBuf;

use glam::DVec3;
use tracks::PerspectiveCamera;
use viewer::feedback::ViewCounts;
use viewer::gpu::{Caps, DeviceLimits, Frame, Gpu, GpuError, GpuRequest, Renderer};
use viewer::plan::Overlays;
use viewer::synth::{views_along, Scene};
use viewer::{plan_frame, DrawBudget, FramePlan, LayerMeshing, RefView};

/// How far a frame may be from the golden image and from the `vulkan` configuration: no
/// channel of any pixel more than `max` (of 255) apart, and the mean channel difference at
/// most `mean`. Measured (Mesa 22.3, 2026-12-01): every configuration within 1 of lavapipe,
/// mean below 0.001 (GL rounds the depth that wgpu's GL backend maps from [0, 1] to
/// [−1, 1] and back, which moves a blend weight by a hair). A real fault (a missing sky, a
/// view not drawn, a wrong blend) is off by tens to hundreds on many pixels.
struct Tolerance {
    max: u8,
    mean: f64,
}

const TOLERANCE: Tolerance = Tolerance { max: 4, mean: 0.05 };

const EYE: f64 = 1.7;

/// The configurations, `vulkan` (the reference) first.
fn configurations() -> Vec<(&'static str, Renderer)> {
    let request = |backends, limits| GpuRequest {
        backends: Some(backends),
        limits,
    };
    let gpu =
        |name: &str, r: GpuRequest| Gpu::request(&r).unwrap_or_else(|e| panic!("{name}: {e}"));
    let vulkan = gpu(
        "vulkan",
        request(wgpu::Backends::VULKAN, DeviceLimits::Best),
    );
    assert_eq!(vulkan.caps, Caps::ALL, "lavapipe has every capability");
    let gl = gpu("gl", request(wgpu::Backends::GL, DeviceLimits::Best));
    let webgl2 = gpu(
        "gl-webgl2",
        request(wgpu::Backends::GL, DeviceLimits::WebGl2),
    );
    assert!(!webgl2.caps.compute, "{:?}", webgl2.caps);
    let mut fallbacks = gpu(
        "vulkan",
        request(wgpu::Backends::VULKAN, DeviceLimits::Best),
    );
    fallbacks.caps = Caps {
        compute: false,
        depth_copy: false,
        view_formats: false,
        float_targets: true,
    };
    for (name, g) in [("gl", &gl), ("gl-webgl2", &webgl2)] {
        eprintln!("{name}: {}, without {}", g.describe(), g.caps.missing());
    }
    [
        ("vulkan", vulkan),
        ("gl", gl),
        ("gl-webgl2", webgl2),
        ("vulkan-fallbacks", fallbacks),
    ]
    .into_iter()
    .map(|(name, g)| {
        let r = Renderer::new(g).unwrap_or_else(|e| panic!("{name}: {e}"));
        (name, r)
    })
    .collect()
}

fn views() -> Vec<RefView> {
    let samples = [
        (0.0, DVec3::new(0.0, EYE, 0.0)),
        (1.5, DVec3::new(1.5, EYE, 0.0)),
    ];
    views_along(
        &Scene::street(),
        &samples,
        48,
        8,
        &Scene::street_slabs(),
        LayerMeshing::default(),
    )
    .unwrap()
}

fn plan(views: &[RefView], s: f64, budget: DrawBudget) -> FramePlan {
    let camera = PerspectiveCamera {
        position: DVec3::new(s, EYE, 0.0),
        yaw_deg: 10.0,
        pitch_deg: -5.0,
        fov_deg: 90.0,
        width: 96,
        height: 64,
    };
    plan_frame(views, &camera, s, budget).unwrap()
}

/// The frames every configuration draws, by name.
fn frames(views: &[RefView]) -> Vec<(&'static str, FramePlan)> {
    let half = DrawBudget {
        half_res_second: true,
        ..Default::default()
    };
    let one = DrawBudget {
        blend: false,
        ..Default::default()
    };
    let mut overlays = plan(views, 0.75, DrawBudget::default());
    overlays.overlays = Overlays {
        heat: true,
        slab_colors: true,
        holes: true,
        ..Default::default()
    };
    vec![
        // A sample: the second view (weight 0) fills the first view's holes only.
        ("street_sample", plan(views, 0.0, DrawBudget::default())),
        // Second weight below 0.003: the second view only where it is nearer.
        (
            "street_near_sample",
            plan(views, 0.02, DrawBudget::default()),
        ),
        ("street_between", plan(views, 0.75, DrawBudget::default())),
        ("street_one_view", plan(views, 0.75, one)),
        ("street_half_res", plan(views, 0.75, half)),
        // View targets, tile ids and the composite pass, the heat map counted on the GPU
        // (compute) or on the CPU (tile ids read back).
        ("street_overlays", overlays),
    ]
}

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(format!("{name}.png"))
}

/// Largest and mean channel difference (RGBA).
fn diff(a: &Frame, b: &Frame) -> (u8, f64) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mut max = 0u8;
    let mut sum = 0u64;
    for (x, y) in a.rgba.iter().zip(&b.rgba) {
        let d = x.abs_diff(*y);
        max = max.max(d);
        sum += u64::from(d);
    }
    (max, sum as f64 / a.rgba.len().max(1) as f64)
}

fn check(what: &str, a: &Frame, b: &Frame) {
    let (max, mean) = diff(a, b);
    eprintln!("{what}: max |diff| {max}, mean {mean:.4}");
    assert!(
        max <= TOLERANCE.max && mean <= TOLERANCE.mean,
        "{what}: max |diff| {max} (tolerance {}), mean {mean:.4} (tolerance {})",
        TOLERANCE.max,
        TOLERANCE.mean
    );
}

fn golden(name: &str, reference: &Frame) -> Frame {
    let path = golden_path(name);
    if std::env::var("RAILVIEW_UPDATE_GOLDEN").is_ok_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::RgbaImage::from_raw(reference.width, reference.height, reference.rgba.clone())
            .unwrap()
            .save(&path)
            .unwrap();
        eprintln!("wrote {}", path.display());
    }
    let img = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "golden image {}: {e} (RAILVIEW_UPDATE_GOLDEN=1 writes it from lavapipe)",
                path.display()
            )
        })
        .to_rgba8();
    Frame {
        width: img.width(),
        height: img.height(),
        rgba: img.into_raw(),
    }
}

/// Visible pixels per tile of the frame at `s` (tile ids at a quarter of the size).
fn counts(r: &mut Renderer, views: &[RefView], s: f64) -> Vec<ViewCounts> {
    let mut p = plan(views, s, DrawBudget::default());
    p.tile_ids = true;
    r.draw(&p, views).unwrap();
    r.feedback(&p, views).unwrap()
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn every_backend_draws_the_golden_frames() {
    let views = views();
    let frames = frames(&views);
    let mut configs = configurations();
    let mut reference: Vec<Frame> = Vec::new();
    for (i, (name, r)) in configs.iter_mut().enumerate() {
        for (k, (frame, p)) in frames.iter().enumerate() {
            let f = r
                .render(p, &views)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            if i == 0 {
                let g = golden(frame, &f);
                check(&format!("{name} {frame} against the golden image"), &f, &g);
                reference.push(f);
            } else {
                check(&format!("{name} {frame} against vulkan"), &f, &reference[k]);
                check(
                    &format!("{name} {frame} against the golden image"),
                    &f,
                    &golden(frame, &reference[k]),
                );
            }
        }
        // The plain panorama (one cube map).
        let p = plan(&views, 0.0, DrawBudget::default());
        r.draw_panorama(&p, &views).unwrap();
        let pano = r.read_output().unwrap();
        if i == 0 {
            reference.push(pano);
        } else {
            check(
                &format!("{name} panorama against vulkan"),
                &pano,
                reference.last().unwrap(),
            );
        }
    }
    // Visible pixels per tile: the same counts from compute passes and from ids read back.
    let (first, rest) = configs.split_at_mut(1);
    let expected = counts(&mut first[0].1, &views, 0.75);
    assert!(expected.iter().any(|c| c.pixels.iter().any(|&p| p > 0)));
    for (name, r) in rest {
        let got = counts(r, &views, 0.75);
        assert_eq!(got.len(), expected.len(), "{name}");
        for (g, e) in got.iter().zip(&expected) {
            let off: u64 = g
                .pixels
                .iter()
                .zip(&e.pixels)
                .map(|(a, b)| u64::from(a.abs_diff(*b)))
                .sum();
            let total: u64 = e.pixels.iter().map(|&p| u64::from(p)).sum();
            eprintln!("{name}: view {} counts off by {off} of {total}", e.view);
            assert!(off * 100 <= total, "{name}: counts off by {off} of {total}");
        }
    }
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn without_float_targets_overlay_frames_are_drawn_whole_without_overlays() {
    let views = views();
    let mut gpu = Gpu::new().expect("a GPU adapter");
    gpu.caps.float_targets = false;
    let mut r = Renderer::new(gpu).unwrap();
    let plain = plan(&views, 0.75, DrawBudget::default());
    let mut overlaid = plain.clone();
    overlaid.overlays.slab_colors = true;
    let mut half = plain.clone();
    half.half_res_second = true;
    let expected = r.render(&plain, &views).unwrap();
    assert_eq!(r.render(&overlaid, &views).unwrap(), expected);
    assert_eq!(r.render(&half, &views).unwrap(), expected);
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn a_wgpu_error_becomes_a_message_naming_the_adapter_not_a_panic() {
    let gpu = Gpu::new().expect("a GPU adapter");
    // Invalid: mapped at creation needs a size that is a multiple of 4.
    let _ = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("deliberately invalid"),
        size: 3,
        usage: wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: true,
    });
    let e = gpu.check("making a test buffer").unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, GpuError::Wgpu { .. }), "{e:?}");
    assert!(
        text.starts_with("making a test buffer failed on "),
        "{text}"
    );
    assert!(text.contains(&gpu.describe()), "{text}");
    assert!(text.contains("deliberately invalid"), "{text}");
    assert!(!text.contains('\n'), "one paragraph: {text}");
    // Reported once.
    assert!(gpu.check("nothing").is_ok());
    // The renderer refuses a device that already failed rather than blaming its pipelines.
    let _ = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("deliberately invalid"),
        size: 3,
        usage: wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: true,
    });
    let e = Renderer::new(gpu).err().expect("an error");
    assert!(e.to_string().contains("before the renderer"), "{e}");
}
