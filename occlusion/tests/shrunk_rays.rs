//! The shrunk variant against brute-force ray casting on random scenes of boxes and
//! cylinders (thin ones, touching ones) and random tracks: no point of a culled tile — its
//! stored points, and its surfaces between pixel centres within the depth tolerance — is
//! reached from any of many positions along the cell. And its results do not depend on the
//! number of threads or on the order viewpoints are culled in.

mod common;

use glam::DVec3;
use occlusion::synth::render_layers;
use occlusion::{cull_viewpoint_shrunk, Cell, CullParams, SceneSolids, Variant, ViewpointCull};
use prerender::scene::{Scene, Shape};
use proptest::prelude::*;
use tracks::cubemap::subpixel_dir;
use tracks::{SlabRange, TileGrid};

const FACE: u32 = 32;

fn scene(shapes: Vec<Shape>) -> Scene {
    common::grey_scene(shapes, "random")
}

/// A box (`kind` 0) or an upright cylinder (1) centred at `c` with sizes `s`.
fn solid(kind: u8, c: (f64, f64, f64), s: (f64, f64, f64)) -> Shape {
    let c = DVec3::new(c.0, c.1, c.2);
    let h = DVec3::new(s.0, s.1, s.2) * 0.5;
    if kind == 0 {
        Shape::Box {
            min: c - h,
            max: c + h,
        }
    } else {
        Shape::Cone {
            base: c - DVec3::Y * h.y,
            top: c + DVec3::Y * h.y,
            radius_base: h.x,
            radius_top: h.x,
        }
    }
}

/// The first culled point reached from the cell of viewpoint 1, with how many were checked.
fn reached(s: &Scene, track: &[DVec3], ranges: &str) -> (u64, Option<String>) {
    let grid = TileGrid::new(FACE, 8).unwrap();
    let ranges = SlabRange::parse_list(ranges).unwrap();
    let v = track[1];
    let layers = render_layers(s, v, &grid, &ranges).unwrap();
    let cell = Cell::straight(track, 1);
    let params = CullParams::new(1.0, Variant::Shrunk).unwrap();
    let solids = SceneSolids::new(s);
    let (cull, _) = cull_viewpoint_shrunk(&cell, &grid, &layers, &params.shrunk, &solids).unwrap();
    let per_stretch = 96;
    let mut xs = vec![v];
    for path in &cell.paths {
        let mut a = v;
        for &b in path {
            xs.extend((0..=per_stretch).map(|j| a.lerp(b, j as f64 / per_stretch as f64)));
            a = b;
        }
    }
    let tol = 0.01 + 2.0 * std::f64::consts::FRAC_PI_2 / FACE as f64;
    let mut checked = 0;
    for d in &cull.slabs {
        let layer = &layers[d.slab];
        for t in &d.culled {
            let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t.id);
            for y in y0..y1 {
                for x in x0..x1 {
                    if *layer.alpha.get(t.id.face, x, y) < 128 {
                        continue;
                    }
                    let r = *layer.depth.get(t.id.face, x, y) as f64;
                    for (sx, sy) in [(0.5, 0.5), (0.1, 0.1), (0.9, 0.1), (0.1, 0.9), (0.9, 0.9)] {
                        let dir = subpixel_dir(t.id.face, x as f64 + sx, y as f64 + sy, FACE);
                        let q = if (sx, sy) == (0.5, 0.5) {
                            v + dir * r
                        } else {
                            let near = layer.range.near;
                            match s.first_hit(v + dir * near, dir, f64::INFINITY) {
                                Some(h) if (near + h - r).abs() <= tol * (near + h) => {
                                    v + dir * (near + h)
                                }
                                _ => continue,
                            }
                        };
                        checked += 1;
                        for &o in &xs {
                            let to = q - o;
                            let dist = to.length();
                            let hit = s.first_hit(o, to / dist, f64::INFINITY);
                            if hit.is_none_or(|h| h >= dist * (1.0 - 1e-5) - 1e-6) {
                                let e = format!(
                                    "slab {} {:?} pixel ({x}, {y}) point {q} seen from {o}",
                                    d.slab, t.id
                                );
                                return (checked, Some(e));
                            }
                        }
                    }
                }
            }
        }
    }
    (checked, None)
}

type Solid = (u8, (f64, f64, f64), (f64, f64, f64));

/// A wall at `z` (`thick` m), 12 m wide and 5 m high, cut by openings `(x, width)`, in
/// pieces that touch where no opening separates them.
fn wall(z: f64, thick: f64, openings: &[(f64, f64)]) -> Vec<Shape> {
    let mut cuts: Vec<(f64, f64)> = openings.iter().map(|&(x, w)| (x, x + w)).collect();
    cuts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = Vec::new();
    let mut x = -6.0;
    // Pieces 2 m long at most: touching boxes that only hide together.
    let mut piece = |a: f64, b: f64| {
        let mut a = a;
        while a < b {
            let e = (a + 2.0).min(b);
            out.push(Shape::Box {
                min: DVec3::new(a, -2.0, z),
                max: DVec3::new(e, 3.0, z + thick),
            });
            a = e;
        }
    };
    for (a, b) in cuts {
        if a > x {
            piece(x, a);
        }
        x = x.max(b);
    }
    if x < 6.0 {
        piece(x, 6.0);
    }
    out
}

fn solids(
    near: &[Solid],
    far: &[Solid],
    posts: &[(f64, f64)],
    wall_at: (f64, f64),
    openings: &[(f64, f64)],
) -> Vec<Shape> {
    let mut shapes: Vec<Shape> = near
        .iter()
        .chain(far)
        .map(|&(k, c, s)| solid(k, c, s))
        .collect();
    shapes.extend(wall(wall_at.0, wall_at.1, openings));
    // Posts thinner than a pixel (1–2 cm, a pixel spans 0.05 rad at face 32).
    for &(x, r) in posts {
        shapes.push(solid(1, (x, 0.0, 2.0), (r, 6.0, r)));
    }
    // The far wall facing the track.
    shapes.push(solid(0, (0.0, 0.0, 12.0), (40.0, 20.0, 1.0)));
    shapes
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    /// A wall in pieces (some touching, 0.4–2 m thick) with up to two openings from a
    /// centimetre (narrower than a pixel) to 1.5 m, boxes and cylinders before and behind
    /// it, thin posts, a far wall; random track directions, lengths (3 cm to 2 m) and turns
    /// of up to ±45°.
    #[test]
    fn culled_points_are_hidden_from_every_cell_point(
        near in prop::collection::vec((0u8..2, (-2.0f64..2.0, -1.0f64..1.0, 1.5f64..2.5), (0.2f64..1.5, 0.5f64..4.0, 0.2f64..1.0)), 0..3),
        far in prop::collection::vec((0u8..2, (-4.0f64..4.0, -2.0f64..2.0, 7.0f64..9.0), (0.3f64..2.0, 0.3f64..2.0, 0.3f64..1.0)), 0..4),
        posts in prop::collection::vec((-1.5f64..1.5, 0.01f64..0.02), 0..3),
        wall_at in (3.0f64..4.5, 0.4f64..2.0),
        openings in prop::collection::vec((-4.0f64..4.0, 0.01f64..1.5), 0..3),
        dir in (-1.0f64..1.0, -0.3f64..0.3, -1.0f64..1.0),
        step in 0.03f64..2.0,
        turn in -1.0f64..1.0,
    ) {
        let s = scene(solids(&near, &far, &posts, wall_at, &openings));
        let d = DVec3::new(dir.0, dir.1, dir.2).normalize_or(DVec3::X);
        let side = d.cross(DVec3::Y).normalize_or(DVec3::Z);
        let v = DVec3::ZERO;
        let track = [v - d * step, v, v + (d + side * turn).normalize_or(d) * step];
        let (_, e) = reached(&s, &track, "0-6,6-10,10-inf");
        if let Some(e) = e {
            prop_assert!(false, "culled but seen: {e}");
        }
    }
}

/// The brute-force check can fail: with the variant's solids swapped for a scene without
/// the wall that hides the far boxes, culled points are reached.
#[test]
fn brute_force_finds_what_a_wrong_scene_culls() {
    let wall = solid(0, (0.0, 0.0, 4.0), (8.0, 8.0, 1.0));
    let far = solid(0, (0.0, 0.0, 8.0), (2.0, 2.0, 1.0));
    let back = solid(0, (0.0, 0.0, 12.0), (40.0, 20.0, 1.0));
    let full = scene(vec![wall.clone(), far.clone(), back.clone()]);
    let track = [
        DVec3::new(-0.5, 0.0, 0.0),
        DVec3::ZERO,
        DVec3::new(0.5, 0.0, 0.0),
    ];
    let (n, e) = reached(&full, &track, "0-6,6-10,10-inf");
    assert!(n > 0 && e.is_none(), "{n} points, {e:?}");
    // Cull with the wall, then look with the wall gone: what was culled is seen.
    let grid = TileGrid::new(FACE, 8).unwrap();
    let ranges = SlabRange::parse_list("0-6,6-10,10-inf").unwrap();
    let layers = render_layers(&full, track[1], &grid, &ranges).unwrap();
    let params = CullParams::new(1.0, Variant::Shrunk).unwrap();
    let (cull, _) = cull_viewpoint_shrunk(
        &Cell::straight(&track, 1),
        &grid,
        &layers,
        &params.shrunk,
        &SceneSolids::new(&full),
    )
    .unwrap();
    let open = scene(vec![far, back]);
    let t = cull.slabs[2]
        .culled
        .first()
        .expect("something culled behind the wall");
    let tracks::PixelRect { x0, y0, .. } = grid.pixel_rect(t.id);
    let r = *layers[2].depth.get(t.id.face, x0, y0) as f64;
    let q = track[1] + tracks::cubemap::pixel_dir(t.id.face, x0, y0, FACE) * r;
    let to = q - track[1];
    assert!(open
        .first_hit(track[1], to.normalize(), to.length() * (1.0 - 1e-5))
        .is_none());
}

/// Same decisions, byte for byte, with one thread or four, and with the viewpoints culled
/// in either order.
#[test]
fn decisions_do_not_depend_on_threads_or_order() {
    let s = scene(vec![
        solid(0, (0.0, 0.0, 4.0), (3.0, 5.0, 1.0)),
        solid(1, (2.5, 0.0, 3.0), (0.4, 6.0, 0.4)),
        solid(0, (-1.0, 0.0, 8.0), (2.0, 3.0, 1.0)),
        solid(0, (0.0, 0.0, 12.0), (40.0, 20.0, 1.0)),
    ]);
    let track: Vec<DVec3> = (0..4)
        .map(|i| DVec3::new(-1.5 + i as f64, 0.0, 0.0))
        .collect();
    let grid = TileGrid::new(FACE, 4).unwrap();
    let ranges = SlabRange::parse_list("0-6,6-10,10-inf").unwrap();
    let layers: Vec<_> = track
        .iter()
        .map(|p| render_layers(&s, *p, &grid, &ranges).unwrap())
        .collect();
    let params = CullParams::new(1.0, Variant::Shrunk).unwrap();
    let solids = SceneSolids::new(&s);
    let run = |threads: usize, reverse: bool| -> Vec<u8> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut order: Vec<usize> = (0..track.len()).collect();
        if reverse {
            order.reverse();
        }
        let mut out: Vec<(usize, ViewpointCull)> = pool.install(|| {
            order
                .iter()
                .map(|&i| {
                    let cell = Cell::straight(&track, i);
                    let c =
                        cull_viewpoint_shrunk(&cell, &grid, &layers[i], &params.shrunk, &solids)
                            .unwrap();
                    (i, c.0)
                })
                .collect()
        });
        out.sort_by_key(|(i, _)| *i);
        serde_json::to_vec(&out).unwrap()
    };
    let one = run(1, false);
    assert_eq!(one, run(4, false));
    assert_eq!(one, run(4, true));
    assert_eq!(one, run(2, true));
    let culled: usize = serde_json::from_slice::<Vec<(usize, ViewpointCull)>>(&one)
        .unwrap()
        .iter()
        .map(|(_, c)| c.slabs.iter().map(|s| s.culled.len()).sum::<usize>())
        .sum();
    assert!(culled > 0);
}
