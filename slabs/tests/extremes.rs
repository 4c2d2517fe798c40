//! Extreme inputs, one named test each (NaN/negative depth in an imported layer is
//! `io::tests::nan_or_negative_depth_in_an_imported_layer_names_file_and_pixel`).

use slabs::boundaries::{choose, ChooseParams};
use slabs::mesh::MeshParams;
use slabs::tiles::{mask_from_depth, tile_sample, LayerInput, MeshKind, SampleTiles, TileParams};
use tracks::cubemap::pixel_dir;
use tracks::{CubeMap, Face};

fn params(tile: u32, baseline_m: f64) -> TileParams {
    TileParams {
        tile_size: tile,
        mesh: MeshParams {
            step: 4,
            max_error_px: 0.5,
            baseline_m,
            discontinuity_px: 1.0,
        },
        keep: MeshKind::Adaptive,
        measure_both: true,
    }
}

fn tile_one(depth: &CubeMap<f32>, p: &TileParams) -> SampleTiles {
    let mask = mask_from_depth(depth);
    tile_sample(0, &[LayerInput { depth, mask: &mask }], p).expect("valid parameters")
}

fn all_errors_within(t: &SampleTiles, bound: f64) {
    for l in &t.layers {
        for tile in &l.tiles {
            let s = tile.adaptive_stats;
            assert!(
                s.max_error_px.is_finite() && s.max_error_px <= bound + 1e-3,
                "{tile:?}"
            );
            assert!(tile.mesh.vertices.iter().flatten().all(|c| c.is_finite()));
        }
    }
}

#[test]
fn every_pixel_sky() {
    let sky = CubeMap::filled(16, f32::INFINITY);
    let c = choose(
        &[sky.clone(), sky.clone()],
        2.0,
        256,
        &ChooseParams::default(),
    );
    assert!(c.slabs.is_empty());
    assert!((c.criterion.sky_fraction - 1.0).abs() < 1e-12);
    assert!(c.criterion.summary.contains("sky"));
    let t = tile_one(&sky, &params(8, 2.0));
    assert_eq!(t.layers[0].tiles_before, 24);
    assert!(t.layers[0].tiles.is_empty());
}

#[test]
fn one_constant_depth() {
    let m = CubeMap::filled(16, 7.5f32);
    let c = choose(std::slice::from_ref(&m), 2.0, 256, &ChooseParams::default());
    assert_eq!(c.slabs.len(), 1);
    assert_eq!((c.slabs[0].near, c.slabs[0].far), (0.0, f64::INFINITY));
    let t = tile_one(&m, &params(8, 2.0));
    assert_eq!(t.layers[0].tiles.len(), 24);
    for tile in &t.layers[0].tiles {
        assert_eq!((tile.depth_min, tile.depth_max), (7.5, 7.5));
        assert_eq!(tile.adaptive_stats.uncovered_pixels, 0);
    }
    all_errors_within(&t, 0.5);
}

#[test]
fn one_pixel_objects() {
    // Single opaque pixels in the sky, and single near pixels in front of a far wall.
    let m = CubeMap::from_fn(16, |f, x, y| match (f, x, y) {
        (Face::PosX, 3, 3) | (Face::NegZ, 15, 0) => 2.0,
        (Face::PosY, 5, 9) => 1.0,
        (Face::PosY, _, _) => 30.0,
        _ => f32::INFINITY,
    });
    let c = choose(std::slice::from_ref(&m), 1.0, 256, &ChooseParams::default());
    assert!(!c.slabs.is_empty() && c.slabs.len() <= 2, "{:?}", c.slabs);
    let t = tile_one(&m, &params(8, 1.0));
    let l = &t.layers[0];
    let lone: Vec<_> = l.tiles.iter().filter(|t| t.opaque_pixels == 1).collect();
    assert_eq!(lone.len(), 2);
    for tile in lone {
        assert_eq!((tile.depth_min, tile.depth_max), (2.0, 2.0));
        // A lone pixel is spanned by triangles reaching into the filled band around it
        // (the opacity mask cuts them back to the pixel), exact at the pixel; one on a
        // corner of the tile's lattice (NegZ (15, 0)), a vertex from the start, too: the
        // mesh is refined towards it through its band.
        assert_eq!(tile.adaptive_stats.uncovered_pixels, 0, "{:?}", tile.tile);
        assert_eq!(tile.adaptive_stats.covered_pixels, 1, "{:?}", tile.tile);
        assert!(tile.adaptive_stats.max_error_px < 1e-3);
        let tracks::PixelRect { x0, y0, x1, .. } = t.grid.pixel_rect(tile.tile);
        let w = x1 - x0;
        let (dx, dy) = if tile.tile.face == Face::PosX {
            (3 - x0, 3 - y0)
        } else {
            (15 - x0, 0)
        };
        assert!(tile.is_opaque(dx, dy, w));
    }
    // The near pixel on the far wall: a discontinuity all round, so no triangle of the
    // wall may use it; it gets a quad of its own, corner to corner at its depth, and the
    // wall's vertices all stay on the wall.
    let wall = l
        .tiles
        .iter()
        .find(|t| t.tile.face == Face::PosY && t.tile.tx == 0 && t.tile.ty == 1)
        .unwrap();
    assert_eq!(wall.depth_min, 1.0);
    let near: Vec<&[f32; 3]> = wall.mesh.vertices.iter().filter(|v| v[2] != 30.0).collect();
    assert_eq!(near.len(), 4, "{:?}", wall.mesh.vertices);
    assert!(near
        .iter()
        .all(|v| v[2] == 1.0 && v[0].fract() == 0.0 && v[1].fract() == 0.0));
    let (xs, ys) = (
        near.iter().map(|v| v[0]).fold(f32::MAX, f32::min),
        near.iter().map(|v| v[1]).fold(f32::MAX, f32::min),
    );
    assert!(near.iter().all(|v| v[0] - xs <= 1.0 && v[1] - ys <= 1.0));
    all_errors_within(&t, 0.5);
}

#[test]
fn depth_ratio_1e6() {
    // 1 cm on one face, 10 km elsewhere, with relief on both.
    let m = CubeMap::from_fn(16, |f, x, y| {
        let d = pixel_dir(f, x, y, 16);
        let relief = 1.0 + 0.1 * (3.0 * d.x).sin() * d.y.cos();
        if f == Face::NegY && x < 8 {
            (0.01 * relief) as f32
        } else {
            (1e4 * relief) as f32
        }
    });
    let c = choose(std::slice::from_ref(&m), 1.0, 256, &ChooseParams::default());
    assert_eq!(c.histogram.depth_min_m.map(|d| d < 0.02), Some(true));
    assert_eq!(c.histogram.depth_max_m.map(|d| d > 9e3), Some(true));
    // The two clusters slide by ~50 rad at B/2 = 0.5 m: far above a pixel; they are
    // separated by a boundary.
    assert_eq!(c.slabs.len(), 2, "{:#?}", c.criterion);
    assert!(c.slabs[0].far > 0.02 && c.slabs[0].far < 9e3);
    let t = tile_one(&m, &params(8, 1.0));
    all_errors_within(&t, 0.5);
}

#[test]
fn single_reference_viewpoint() {
    // No baseline: nothing can be disoccluded, so one slab, and meshes measure error at 1 m.
    let m = CubeMap::from_fn(16, |_, x, _| if x < 5 { 2.0 } else { 40.0 });
    let c = choose(std::slice::from_ref(&m), 0.0, 256, &ChooseParams::default());
    assert_eq!(c.slabs.len(), 1);
    assert_eq!(c.criterion.half_baseline_m, 0.0);
    assert!(c
        .criterion
        .candidates
        .iter()
        .all(|x| !x.accepted && x.parallax_rad == 0.0));
    let t = tile_one(&m, &params(8, 0.0));
    all_errors_within(&t, 0.5);
}

#[test]
fn odd_and_tiny_face_sizes() {
    for n in [1u32, 2, 3, 10] {
        let m = CubeMap::from_fn(n, |f, x, y| 3.0 + f.index() as f32 + 0.1 * (x + y) as f32);
        let t = tile_one(&m, &params(4, 1.0));
        let pixels: u32 = t.layers[0].tiles.iter().map(|t| t.pixels).sum();
        assert_eq!(pixels, 6 * n * n);
        all_errors_within(&t, 0.5);
        let c = choose(&[m], 1.0, n, &ChooseParams::default());
        assert!(!c.slabs.is_empty());
    }
    assert!(
        tile_sample(0, &[], &params(3, 1.0)).is_err(),
        "tile size must be a power of two"
    );
}
