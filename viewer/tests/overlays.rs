//! Debug overlays and mesh density on the default adapter (lavapipe without a GPU): each
//! overlay changes exactly the pixels it should, and decimated meshes keep the image. Set
//! `RAILVIEW_SKIP_GPU_TESTS=1` to mark them as ignored.

use glam::DVec3;
use tracks::{PerspectiveCamera, SlabRange};
use viewer::gpu::{Frame, Gpu, Renderer};
use viewer::plan::Overlays;
use viewer::synth::{views_along, Scene};
use viewer::{plan_frame, DrawBudget, FramePlan, LayerMeshing, RefView};

fn renderer() -> Renderer {
    let gpu = Gpu::new().expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    Renderer::new(gpu).expect("the renderer on this adapter")
}

const EYE: f64 = 1.7;

fn views(slabs: &[SlabRange]) -> Vec<RefView> {
    let samples = [
        (0.0, DVec3::new(0.0, EYE, 0.0)),
        (1.5, DVec3::new(1.5, EYE, 0.0)),
    ];
    views_along(
        &Scene::street(),
        &samples,
        48,
        8,
        slabs,
        LayerMeshing::default(),
    )
    .unwrap()
}

fn camera(s: f64) -> PerspectiveCamera {
    PerspectiveCamera {
        position: DVec3::new(s, EYE, 0.0),
        yaw_deg: 10.0,
        pitch_deg: -5.0,
        fov_deg: 90.0,
        width: 96,
        height: 64,
    }
}

/// One view (the dominant one everywhere), so every tinted pixel is that view's tile.
fn one_view_plan(views: &[RefView], s: f64, max_slabs: usize) -> FramePlan {
    let budget = DrawBudget {
        blend: false,
        max_slabs,
        ..Default::default()
    };
    let mut p = plan_frame(views, &camera(s), s, budget).unwrap();
    // Full-resolution tile ids: compared pixel by pixel with what the overlays tint.
    p.id_scale = 1;
    p
}

/// Indices of the pixels that differ between two frames.
/// Pixels that differ, leaving out those both frames filled from the farther side (the fused
/// and composite paths judge the farther side by depth and by distance).
fn changed(a: &Frame, b: &Frame) -> Vec<usize> {
    a.rgba
        .chunks(4)
        .zip(b.rgba.chunks(4))
        .enumerate()
        .filter(|(i, (p, q))| p != q && !(a.is_filled(*i) && b.is_filled(*i)))
        .map(|(i, _)| i)
        .collect()
}

/// Render `plan` with `overlays` and the tile ids of its first pass.
fn draw(
    r: &mut Renderer,
    plan: &FramePlan,
    views: &[RefView],
    overlays: Overlays,
) -> (Frame, Vec<u32>) {
    let mut p = plan.clone();
    p.overlays = overlays;
    let frame = r.render(&p, views).unwrap();
    (frame, r.read_tile_ids(0).unwrap())
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn highlight_tints_exactly_the_pixels_of_highlighted_tiles() {
    let mut r = renderer();
    let mut views = views(&Scene::street_slabs());
    let plan = one_view_plan(&views, 0.6, usize::MAX);
    let on = Overlays {
        highlight: true,
        ..Default::default()
    };
    // Frames without overlays take the fused path; with no tile highlighted the overlay's
    // composite path draws the same image up to 8-bit rounding.
    let (fused, ids) = draw(&mut r, &plan, &views, Overlays::default());
    let (base, ids_on) = draw(&mut r, &plan, &views, on);
    assert_eq!(ids, ids_on);
    let max = fused
        .rgba
        .iter()
        .zip(&base.rgba)
        .enumerate()
        .filter(|(k, _)| !(fused.is_filled(k / 4) && base.is_filled(k / 4)))
        .map(|(_, (a, b))| a.abs_diff(*b))
        .max();
    assert!(max <= Some(1), "{max:?}");
    for v in views.iter_mut() {
        for (i, t) in v.tiles.iter_mut().enumerate() {
            t.highlight = if i % 3 == 0 { 1.0 } else { 0.0 };
        }
    }
    let vi = plan.passes[0].view;
    let (lit, ids2) = draw(&mut r, &plan, &views, on);
    assert_eq!(ids, ids2);
    let expected: Vec<usize> = ids
        .iter()
        .enumerate()
        .filter(|(_, &t)| t > 0 && views[vi].tiles[t as usize - 1].highlight > 0.0)
        .map(|(i, _)| i)
        .collect();
    assert!(
        expected.len() > 100,
        "{} highlighted pixels",
        expected.len()
    );
    assert_eq!(changed(&base, &lit), expected);
    // Without the overlay the highlight values change nothing.
    let (plain, _) = draw(&mut r, &plan, &views, Overlays::default());
    assert!(changed(&fused, &plain).is_empty());
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn slab_colours_and_heat_map_tint_every_tile_pixel_and_nothing_else() {
    let mut r = renderer();
    let views = views(&Scene::street_slabs());
    let plan = one_view_plan(&views, 0.6, usize::MAX);
    let (base, ids) = draw(&mut r, &plan, &views, Overlays::default());
    let tiles: Vec<usize> = (0..ids.len()).filter(|&i| ids[i] > 0).collect();
    assert!(tiles.len() > 1000 && tiles.len() < ids.len());
    let slabs = Overlays {
        slab_colors: true,
        ..Default::default()
    };
    let heat = Overlays {
        heat: true,
        ..Default::default()
    };
    let (by_slab, _) = draw(&mut r, &plan, &views, slabs);
    assert_eq!(changed(&base, &by_slab), tiles);
    let (hot, _) = draw(&mut r, &plan, &views, heat);
    assert_eq!(changed(&base, &hot), tiles);
    // Two pixels of one slab in the same base colour get the same slab tint; pixels of
    // different slabs with the same base colour do not.
    let vi = plan.passes[0].view;
    let slab_of = |i: usize| views[vi].tiles[ids[i] as usize - 1].slab;
    let px = |f: &Frame, i: usize| [f.rgba[4 * i], f.rgba[4 * i + 1], f.rgba[4 * i + 2]];
    // Equal 8-bit colours may differ a little before rounding, so "same" allows 2 levels.
    let dist = |p: [u8; 3], q: [u8; 3]| (0..3).map(|k| p[k].abs_diff(q[k])).max().unwrap_or(0);
    let mut checked = 0;
    for w in tiles.windows(2) {
        let (a, b) = (w[0], w[1]);
        if px(&base, a) == px(&base, b) {
            let d = dist(px(&by_slab, a), px(&by_slab, b));
            if slab_of(a) == slab_of(b) {
                assert!(d <= 2, "pixels {a} {b}: {d}");
            } else {
                assert!(d > 40, "pixels {a} {b}: {d}");
            }
            checked += 1;
        }
    }
    assert!(checked > 100);
    // The heat map shows this frame's counts: a tile with more visible pixels is tinted
    // hotter (more red, less blue) than one with fewer, on the same base colour.
    let counts = r.feedback(&plan, &views).unwrap();
    let count = |i: usize| counts[0].pixels[ids[i] as usize - 1];
    let hotter = tiles
        .windows(2)
        .filter(|w| px(&base, w[0]) == px(&base, w[1]) && count(w[0]) > 2 * count(w[1]));
    let mut compared = 0;
    for w in hotter {
        let (a, b) = (px(&hot, w[0]), px(&hot, w[1]));
        assert!(a[0] + 2 >= b[0] && a[2] <= b[2] + 2, "{a:?} vs {b:?}");
        compared += 1;
    }
    eprintln!("{checked} slab pairs, {compared} heat pairs");
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn holes_overlay_paints_exactly_the_hole_pixels() {
    let mut r = renderer();
    let views = views(&Scene::street_slabs());
    // One slab, one view, between samples: disocclusions leave holes.
    let plan = one_view_plan(&views, 0.75, 1);
    // The base image on the composite path too: the highlight overlay with no tile
    // highlighted (the image without overlays is the fused path's, up to 8-bit rounding).
    let none_lit = Overlays {
        highlight: true,
        ..Default::default()
    };
    let (base, _) = draw(&mut r, &plan, &views, none_lit);
    // Without the hole overlay holes are filled from the farther side; with it they are
    // left unfilled and painted.
    assert_eq!(base.hole_fraction(), 0.0);
    let holes: Vec<usize> = (0..base.rgba.len() / 4)
        .filter(|&i| base.is_filled(i))
        .collect();
    assert!(!holes.is_empty());
    let on = Overlays {
        holes: true,
        ..Default::default()
    };
    let (shown, _) = draw(&mut r, &plan, &views, on);
    assert_eq!(changed(&base, &shown), holes);
    for &i in &holes {
        assert_eq!(&shown.rgba[4 * i..4 * i + 4], &[255, 0, 255, 255]);
    }
    assert_eq!(shown.hole_fraction(), 0.0);
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn frames_without_tile_ids_match_and_refuse_feedback() {
    let mut r = renderer();
    let views = views(&Scene::street_slabs());
    let mut plan = plan_frame(&views, &camera(0.6), 0.6, DrawBudget::default()).unwrap();
    let with = r.render(&plan, &views).unwrap();
    assert!(r.feedback(&plan, &views).is_ok());
    plan.tile_ids = false;
    // Feedback frames draw the picture as frames without ids do (the ids in a pass of
    // their own): the same image.
    let without = r.render(&plan, &views).unwrap();
    assert_eq!(with.hole_fraction(), without.hole_fraction());
    let diffs: Vec<u8> = with
        .rgba
        .iter()
        .zip(&without.rgba)
        .map(|(a, b)| a.abs_diff(*b))
        .collect();
    let max = diffs.iter().copied().max().unwrap_or(0);
    let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
    eprintln!("with vs without tile ids: max |diff| {max}, mean {mean:.4}");
    assert!(max == 0, "max {max}, mean {mean}");
    assert!(r.feedback(&plan, &views).is_err());
    assert!(r.read_tile_ids(0).is_err());
}

#[test]
#[cfg_attr(
    railview_skip_gpu,
    ignore = "GPU tests switched off by RAILVIEW_SKIP_GPU_TESTS=1"
)]
fn decimated_meshes_keep_the_image_and_open_few_holes() {
    let mut r = renderer();
    let views = views(&Scene::street_slabs());
    for s in [0.0, 0.75] {
        let mut frames = Vec::new();
        for level in 0..=viewer::refview::MESH_LEVELS {
            let budget = DrawBudget {
                mesh_level: level,
                ..Default::default()
            };
            let plan = plan_frame(&views, &camera(s), s, budget).unwrap();
            assert_eq!(plan.mesh_level, level);
            frames.push(r.render(&plan, &views).unwrap());
        }
        let base = &frames[0];
        for (level, f) in frames.iter().enumerate().skip(1) {
            let rgb = |f: &Frame| -> Vec<[u8; 3]> {
                f.rgba.chunks(4).map(|p| [p[0], p[1], p[2]]).collect()
            };
            let psnr = viewer::metrics::psnr(&rgb(f), &rgb(base));
            eprintln!(
                "s = {s}, mesh level {level}: {psnr:.1} dB against full meshes, holes {:.4} vs {:.4}",
                f.hole_fraction(),
                base.hole_fraction()
            );
            // Border vertices stay, so coverage keeps its outline: at a reference sample
            // (projective texturing, depth irrelevant) the image is practically unchanged;
            // between samples the thinned inner depth moves parallax by a fraction of a pixel.
            // (Measured: >= 90 dB at the sample, ~50 dB between.)
            assert!(psnr > if s == 0.0 { 60.0 } else { 40.0 }, "{psnr}");
            assert!(f.hole_fraction() <= base.hole_fraction() + 0.01);
        }
    }
}
