//! Analytic and equivalence tests of the renderers.

use glam::DVec3;
use tracks::cubemap::{pixel_dir, subpixel_dir, Face};
use tracks::{CubeMap, PerspectiveCamera, SlabRange};

use super::*;
use crate::scene::{Material, Object, Scene, SceneDesc, Shape, Sun, Texture};

const REL: f64 = 1e-5;

fn scene(shapes: Vec<Shape>) -> Scene {
    Scene::new(
        SceneDesc {
            materials: vec![Material {
                name: "m".into(),
                color: DVec3::new(0.6, 0.5, 0.4),
                texture: Texture::Checker {
                    color2: DVec3::new(0.1, 0.2, 0.3),
                    size: 0.37,
                },
            }],
            objects: shapes
                .into_iter()
                .map(|shape| Object { shape, material: 0 })
                .collect(),
            sun: Some(Sun {
                direction: DVec3::new(0.3, 0.8, 0.5),
                color: DVec3::ONE,
            }),
            ..Default::default()
        },
        "test",
    )
    .unwrap()
}

fn opts(n: u32) -> RenderOptions {
    RenderOptions {
        face_size: n,
        supersample: 1,
        shadows: true,
    }
}

fn assert_rel(got: f64, want: f64, what: &str) {
    let e = ((got - want) / want).abs();
    assert!(
        e < REL,
        "{what}: got {got}, want {want}, relative error {e:e}"
    );
}

/// Expected first hit of an infinite plane, written independently of the tracer.
fn plane_t(o: DVec3, d: DVec3, p: DVec3, n: DVec3) -> Option<f64> {
    let t = (p - o).dot(n) / d.dot(n);
    (t > 0.0 && t.is_finite()).then_some(t)
}

/// Expected first hit of a sphere from outside (naive quadratic, fine at test scales).
fn sphere_t(o: DVec3, d: DVec3, c: DVec3, r: f64) -> Option<f64> {
    let oc = o - c;
    let b = oc.dot(d);
    let disc = b * b - (oc.dot(oc) - r * r);
    (disc >= 0.0).then(|| -b - disc.sqrt()).filter(|t| *t > 0.0)
}

#[test]
fn plane_at_known_distance_every_pixel() {
    let (p, n) = (DVec3::new(0.0, -1.7, 0.0), DVec3::Y);
    let s = scene(vec![Shape::Plane {
        point: p,
        normal: n,
    }]);
    let r = render_cube(&s, DVec3::ZERO, opts(17));
    for face in Face::ALL {
        for y in 0..17 {
            for x in 0..17 {
                let d = pixel_dir(face, x, y, 17);
                let got = *r.depth.get(face, x, y);
                match plane_t(DVec3::ZERO, d, p, n) {
                    Some(t) => assert_rel(got as f64, t, "plane"),
                    None => assert_eq!(got, f32::INFINITY, "{face:?} {x} {y}"),
                }
            }
        }
    }
}

#[test]
fn sphere_at_known_distance() {
    let c = DVec3::new(0.4, 0.3, -10.0);
    let s = scene(vec![Shape::Sphere {
        center: c,
        radius: 3.0,
    }]);
    let r = render_cube(&s, DVec3::ZERO, opts(31));
    let mut hits = 0;
    for y in 0..31 {
        for x in 0..31 {
            let d = pixel_dir(Face::NegZ, x, y, 31);
            let got = *r.depth.get(Face::NegZ, x, y);
            match sphere_t(DVec3::ZERO, d, c, 3.0) {
                Some(t) => {
                    hits += 1;
                    assert_rel(got as f64, t, "sphere")
                }
                None => assert_eq!(got, f32::INFINITY),
            }
        }
    }
    assert!(hits > 50);
}

#[test]
fn from_inside_a_box_every_direction_hits() {
    let (lo, hi) = (DVec3::splat(-1.0), DVec3::new(2.0, 1.5, 1.0));
    let s = scene(vec![Shape::Box { min: lo, max: hi }]);
    let o = DVec3::new(0.3, 0.2, -0.1);
    let r = render_cube(&s, o, opts(15));
    for face in Face::ALL {
        for y in 0..15 {
            for x in 0..15 {
                let d = pixel_dir(face, x, y, 15);
                let want = (0..3)
                    .map(|k| {
                        let b = if d[k] > 0.0 { hi[k] } else { lo[k] };
                        (b - o[k]) / d[k]
                    })
                    .filter(|t| t.is_finite())
                    .fold(f64::INFINITY, f64::min);
                assert_rel(*r.depth.get(face, x, y) as f64, want, "box inside");
            }
        }
    }
}

#[test]
fn camera_a_tenth_of_a_millimetre_from_surfaces() {
    let s = scene(vec![
        Shape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        },
        Shape::Sphere {
            center: DVec3::new(5.0, 1.0, 0.0),
            radius: 1.0,
        },
    ]);
    let o = DVec3::new(0.0, 1e-4, 0.0);
    let r = render_cube(&s, o, opts(9));
    for y in 0..9 {
        for x in 0..9 {
            let d = pixel_dir(Face::NegY, x, y, 9);
            assert_rel(
                *r.depth.get(Face::NegY, x, y) as f64,
                1e-4 / -d.y,
                "plane 1e-4",
            );
        }
    }
    let o = DVec3::new(5.0 - 1.0 - 1e-4, 1.0, 0.0);
    assert_rel(
        s.first_hit(o, DVec3::X, f64::INFINITY).unwrap(),
        1e-4,
        "sphere 1e-4",
    );
    // Odd face size: the centre pixel looks exactly along the axis.
    let r = render_cube(&s, o, opts(9));
    assert_rel(
        *r.depth.get(Face::PosX, 4, 4) as f64,
        1e-4,
        "sphere centre pixel",
    );
}

fn test_shapes(scale: f64, offset: DVec3) -> Vec<Shape> {
    vec![
        Shape::Plane {
            point: offset + DVec3::new(0.0, -1.0, 0.0) * scale,
            normal: DVec3::Y,
        },
        Shape::Sphere {
            center: offset + DVec3::new(3.0, 0.5, -2.0) * scale,
            radius: 1.2 * scale,
        },
        Shape::Box {
            min: offset + DVec3::new(-4.0, -1.0, -1.0) * scale,
            max: offset + DVec3::new(-2.0, 2.0, 3.0) * scale,
        },
        Shape::Cone {
            base: offset + DVec3::new(0.0, -1.0, 4.0) * scale,
            top: offset + DVec3::new(0.0, 3.0, 4.0) * scale,
            radius_base: 1.0 * scale,
            radius_top: 0.3 * scale,
        },
        Shape::Triangle {
            a: offset + DVec3::new(-1.0, 0.0, -6.0) * scale,
            b: offset + DVec3::new(1.0, 0.0, -6.0) * scale,
            c: offset + DVec3::new(0.0, 2.0, -6.0) * scale,
        },
    ]
}

/// Same scene at 1e-3 m, 1e5 m, and far from the origin: depths scale exactly.
#[test]
fn scene_scales_and_far_offsets_keep_depth_exact() {
    let base = scene(test_shapes(1.0, DVec3::ZERO));
    let eye = DVec3::new(0.2, 0.3, 0.1);
    let want = render_cube(&base, eye, opts(21)).depth;
    for (scale, offset) in [
        (1e-3, DVec3::ZERO),
        (1e5, DVec3::ZERO),
        (1.0, DVec3::new(1e5, -3e4, 2e5)),
        (1e-3, DVec3::new(10.0, 0.0, -10.0)),
    ] {
        let s = scene(test_shapes(scale, offset));
        let got = render_cube(&s, offset + eye * scale, opts(21)).depth;
        for (i, (g, w)) in got.as_slice().iter().zip(want.as_slice()).enumerate() {
            if w.is_finite() {
                assert_rel(
                    *g as f64 / scale,
                    *w as f64,
                    &format!("scale {scale} offset {offset} texel {i}"),
                );
            } else {
                assert_eq!(*g, f32::INFINITY, "scale {scale} texel {i}");
            }
        }
    }
}

#[test]
fn depth_ratio_of_a_million_in_one_view() {
    // A 0.1 mm sphere 1 mm in front, a wall 1 km behind.
    let s = scene(vec![
        Shape::Sphere {
            center: DVec3::new(1e-3, 0.0, 0.0),
            radius: 1e-4,
        },
        Shape::Plane {
            point: DVec3::new(-1e3, 0.0, 0.0),
            normal: DVec3::X,
        },
    ]);
    let r = render_cube(&s, DVec3::ZERO, opts(9));
    let near = *r.depth.get(Face::PosX, 4, 4) as f64;
    let far = *r.depth.get(Face::NegX, 4, 4) as f64;
    assert_rel(near, 1e-3 - 1e-4, "near");
    assert_rel(far, 1e3, "far");
    assert!(far / near > 1e6);
}

#[test]
fn axis_parallel_and_grazing_rays() {
    let s = scene(vec![
        Shape::Box {
            min: DVec3::new(2.0, -1.0, -1.0),
            max: DVec3::new(3.0, 1.0, 1.0),
        },
        Shape::Plane {
            point: DVec3::new(0.0, -1.0, 0.0),
            normal: DVec3::Y,
        },
    ]);
    let o = DVec3::ZERO;
    assert_eq!(s.first_hit(o, DVec3::X, f64::INFINITY), Some(2.0));
    assert_eq!(s.first_hit(o, DVec3::NEG_Y, f64::INFINITY), Some(1.0));
    assert_eq!(s.first_hit(o, DVec3::Y, f64::INFINITY), None);
    assert_eq!(s.first_hit(o, DVec3::Z, f64::INFINITY), None);
    // Along the box's top face plane (y = 1): touches the face edge-on.
    let t = s.first_hit(DVec3::new(0.0, 1.0, 0.0), DVec3::X, f64::INFINITY);
    assert_eq!(t, Some(2.0));
    // Grazing the ground plane: elevation -1e-6 rad from 1 m up hits ~1e6 m away.
    for e in [1e-3, 1e-5, 1e-6] {
        let d = DVec3::new(0.0, -e, -1.0).normalize();
        let o = DVec3::new(10.0, 0.0, 0.0);
        let want = plane_t(o, d, DVec3::new(0.0, -1.0, 0.0), DVec3::Y).unwrap();
        assert_rel(
            s.first_hit(o, d, f64::INFINITY).unwrap(),
            want,
            "grazing plane",
        );
    }
    // Grazing a sphere: a ray passing 1e-6 inside the silhouette.
    let sp = scene(vec![Shape::Sphere {
        center: DVec3::ZERO,
        radius: 1.0,
    }]);
    let o = DVec3::new(-10.0, 1.0 - 1e-6, 0.0);
    let want = 10.0 - (1.0f64 - (1.0 - 1e-6f64).powi(2)).sqrt();
    assert_rel(
        sp.first_hit(o, DVec3::X, f64::INFINITY).unwrap(),
        want,
        "grazing sphere",
    );
    assert_eq!(
        sp.first_hit(DVec3::new(-10.0, 1.0 + 1e-9, 0.0), DVec3::X, f64::INFINITY),
        None
    );
}

#[test]
fn sky_is_infinite_after_the_exr_round_trip() {
    let s = scene(vec![Shape::Sphere {
        center: DVec3::new(0.0, 0.0, -5.0),
        radius: 1.0,
    }]);
    let r = render_cube(&s, DVec3::ZERO, opts(8));
    let dir = std::env::temp_dir().join(format!("railview-sky-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("depth.exr");
    crate::store::write_depth_exr(&p, &r.depth).unwrap();
    let back = crate::store::read_depth_exr(&p).unwrap();
    assert_eq!(back, r.depth);
    assert_eq!(*back.get(Face::PosZ, 3, 3), f32::INFINITY);
    assert!(back.get(Face::NegZ, 3, 3).is_finite());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn faces_meet_without_seams() {
    let b = crate::scenes::builtin("castle").unwrap();
    let o = b.tracks.get("main").unwrap().viewpoints()[5].position;
    let n = 16;
    // Every point on every face edge: the direction from either face is the same and so
    // is what the tracer returns.
    for face in Face::ALL {
        for k in 0..=4 * n {
            let t = k as f64 / 4.0;
            for (x, y) in [(0.0, t), (n as f64, t), (t, 0.0), (t, n as f64)] {
                let d = subpixel_dir(face, x, y, n);
                let other = Face::ALL
                    .into_iter()
                    .filter(|f| *f != face)
                    .find_map(|f| {
                        let (u, v) = f.uv_from_dir(d)?;
                        (u.abs() <= 1.0 + 1e-12 && v.abs() <= 1.0 + 1e-12).then_some((f, u, v))
                    })
                    .expect("edge direction lies on a second face");
                let (f2, u, v) = other;
                let d2 = f2
                    .dir_from_uv(u.clamp(-1.0, 1.0), v.clamp(-1.0, 1.0))
                    .normalize();
                assert!((d - d2).length() < 1e-12, "{face:?} {x} {y}");
                // The same direction reached from the second face gives the same texel value.
                let (c1, z1) = trace_ray(&b.scene, o, d, true);
                let (c2, z2) = trace_ray(&b.scene, o, d2, true);
                assert!(
                    z1 == z2 || ((z1 - z2) / z1).abs() < 1e-6,
                    "{face:?} ({x}, {y}) vs {f2:?}: depth {z1} vs {z2}"
                );
                let dc = (0..3).map(|k| c1[k].abs_diff(c2[k])).max().unwrap_or(0);
                assert!(dc <= 2, "{face:?} ({x}, {y}) vs {f2:?}: {c1:?} vs {c2:?}");
            }
        }
    }
    // Across every edge (away from the corners), depth changes per radian
    // towards the neighbour on the next face no faster than towards the steepest neighbour
    // inside the face: no seam.
    // Inside a sphere, off-centre: depth is smooth and finite in every direction.
    let s = scene(vec![Shape::Sphere {
        center: DVec3::new(1.5, -0.8, 0.6),
        radius: 3.0,
    }]);
    let r = render_cube(&s, DVec3::ZERO, opts(n));
    let mut edges = 0;
    for face in Face::ALL {
        for k in 2..n - 2 {
            for (edge, out) in [
                ((0, k), (-0.5, k as f64 + 0.5)),
                ((n - 1, k), (n as f64 + 0.5, k as f64 + 0.5)),
                ((k, 0), (k as f64 + 0.5, -0.5)),
                ((k, n - 1), (k as f64 + 0.5, n as f64 + 0.5)),
            ] {
                let c = tracks::FaceCoord::from_dir(subpixel_dir(face, out.0, out.1, n)).unwrap();
                assert_ne!(c.face, face);
                let (ax, ay) = c.to_pixel(n);
                let de = pixel_dir(face, edge.0, edge.1, n);
                let da = pixel_dir(c.face, ax, ay, n);
                let a = *r.depth.get(face, edge.0, edge.1) as f64;
                let across = *r.depth.get(c.face, ax, ay) as f64;
                // Steepest change per radian towards any neighbour inside the face.
                let mut steepest: f64 = 0.0;
                for (dx, dy) in [
                    (-1i64, -1i64),
                    (-1, 0),
                    (-1, 1),
                    (0, -1),
                    (0, 1),
                    (1, -1),
                    (1, 0),
                    (1, 1),
                ] {
                    let (x2, y2) = (edge.0 as i64 + dx, edge.1 as i64 + dy);
                    if x2 < 0 || y2 < 0 || x2 >= n as i64 || y2 >= n as i64 {
                        continue;
                    }
                    let (x2, y2) = (x2 as u32, y2 as u32);
                    let z = *r.depth.get(face, x2, y2) as f64;
                    if z.is_finite() {
                        steepest = steepest
                            .max((a - z).abs() / de.angle_between(pixel_dir(face, x2, y2, n)));
                    }
                }
                if !(a.is_finite() && across.is_finite() && steepest > 0.0) {
                    continue;
                }
                edges += 1;
                let step_across = (a - across).abs() / de.angle_between(da);
                assert!(
                    step_across <= 3.0 * steepest,
                    "{face:?} {edge:?}: {a} vs {across} across ({step_across}/rad, steepest inside {steepest}/rad)"
                );
            }
        }
    }
    assert!(edges > 100);
}

#[test]
fn slab_layers_composite_to_the_single_layer_render() {
    let b = crate::scenes::builtin("castle").unwrap();
    let vps = b.tracks.get("main").unwrap().viewpoints();
    let slabs = SlabRange::parse_list("0-4,4-12,12-30,30-inf").unwrap();
    for vp in [vps[0], vps[vps.len() / 2], *vps.last().unwrap()] {
        let o = opts(20);
        let single = render_cube(&b.scene, vp.position, o);
        let layers = render_slabs(&b.scene, vp.position, &slabs, o);
        assert_eq!(layers.len(), 4);
        let sky = render_sky(&b.scene, 20, 1);
        let (color, depth) = composite_layers(&layers, &sky);
        assert_eq!(color, single.color, "colour at {vp:?}");
        assert_eq!(depth, single.depth, "depth at {vp:?}");
        // Later slabs really show what nearer surfaces hide.
        for l in &layers {
            for (c, d) in l.color.as_slice().iter().zip(l.depth.as_slice()) {
                assert!(c[3] == 0 || c[3] == 255);
                assert_eq!(c[3] == 255, d.is_finite());
                if d.is_finite() {
                    assert!(
                        l.range.contains(*d as f64)
                            || (*d as f64 - l.range.near).abs() < 1e-5 * l.range.near.max(1.0)
                    );
                }
            }
        }
        let hidden = layers[2]
            .color
            .as_slice()
            .iter()
            .zip(single.depth.as_slice())
            .filter(|(c, d)| c[3] == 255 && (**d as f64) < 12.0)
            .count();
        assert!(hidden > 0, "no surface hidden behind nearer ones at {vp:?}");
    }
}

/// Anti-aliased layers composite to the anti-aliased panorama: the layer each pixel-centre ray
/// sees first holds the whole pixel's colour (silhouettes included), so a reconstruction at
/// the reference viewpoint shows the panorama exactly.
#[test]
fn antialiased_slab_layers_composite_to_the_antialiased_render() {
    let b = crate::scenes::builtin("castle").unwrap();
    let vp = b.tracks.get("main").unwrap().viewpoints()[2];
    let slabs = SlabRange::parse_list("0-6,6-15,15-inf").unwrap();
    let o = RenderOptions {
        face_size: 16,
        supersample: 2,
        shadows: true,
    };
    let single = render_cube(&b.scene, vp.position, o);
    let layers = render_slabs(&b.scene, vp.position, &slabs, o);
    // The background as a database keeps it: the panorama where its depth is infinite.
    let (color, _) = composite_layers(&layers, &single.color);
    assert_eq!(color, single.color);
}

#[test]
fn parallel_and_serial_runs_are_identical() {
    let b = crate::scenes::builtin("nature").unwrap();
    let p = b.tracks.get("main").unwrap().viewpoints()[3].position;
    let o = RenderOptions {
        face_size: 16,
        supersample: 2,
        shadows: true,
    };
    let par = render_cube(&b.scene, p, o);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let ser = pool.install(|| render_cube(&b.scene, p, o));
    assert_eq!(par, ser);
    assert_eq!(par.primary_rays, 6 * 256 * 5);
    let slabs = SlabRange::parse_list("0-10,10-inf").unwrap();
    assert_eq!(
        render_slabs(&b.scene, p, &slabs, o),
        pool.install(|| render_slabs(&b.scene, p, &slabs, o))
    );
}

#[test]
fn lowres_depth_matches_the_full_pass_and_supersampling_keeps_depth() {
    let b = crate::scenes::builtin("castle").unwrap();
    let p = b.tracks.get("main").unwrap().viewpoints()[10].position;
    let low = render_depth_lowres(&b.scene, p, 12);
    let full = render_cube(&b.scene, p, opts(12));
    assert_eq!(low, full.depth);
    let ss = render_cube(
        &b.scene,
        p,
        RenderOptions {
            supersample: 3,
            ..opts(12)
        },
    );
    assert_eq!(ss.depth, full.depth);
    // Supersampled colour stays close to the centre-ray colour on average.
    let diff: f64 = ss
        .color
        .as_slice()
        .iter()
        .zip(full.color.as_slice())
        .map(|(a, b)| {
            (0..3)
                .map(|k| (a[k] as f64 - b[k] as f64).abs())
                .sum::<f64>()
        })
        .sum::<f64>()
        / (3.0 * 6.0 * 144.0);
    assert!(diff < 30.0, "mean difference {diff}");
}

#[test]
fn perspective_matches_the_cube_map_along_the_same_ray() {
    let b = crate::scenes::builtin("castle").unwrap();
    let p = b.tracks.get("main").unwrap().viewpoints()[8].position;
    // 90° camera looking along -z with an odd size: centre pixel looks exactly along -z,
    // like the centre pixel of an odd-sized NegZ face.
    let cam = PerspectiveCamera {
        position: p,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        fov_deg: 90.0,
        width: 9,
        height: 7,
    };
    let r = render_perspective(&b.scene, &cam, 1);
    assert_eq!((r.color.len(), r.depth.len()), (63, 63));
    let cube = render_cube(&b.scene, p, opts(9));
    let centre = 3 * 9 + 4;
    assert_eq!(r.depth[centre], *cube.depth.get(Face::NegZ, 4, 4));
    assert_eq!(r.color[centre], *cube.color.get(Face::NegZ, 4, 4));
    let want = b.scene.first_hit(p, cam.pixel_dir(0, 0), f64::INFINITY);
    assert_eq!(r.depth[0], want.map_or(f32::INFINITY, |t| t as f32));
}

#[test]
fn shadows_darken_and_can_be_switched_off() {
    // A sphere above a plane, sun straight up: the point under the sphere is in shadow.
    let mut s = scene(vec![
        Shape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        },
        Shape::Sphere {
            center: DVec3::new(0.0, 3.0, 0.0),
            radius: 1.0,
        },
    ]);
    let mut desc = s.desc().clone();
    desc.sun = Some(Sun {
        direction: DVec3::Y,
        color: DVec3::ONE,
    });
    desc.materials[0].texture = Texture::Solid;
    s = Scene::new(desc, "t").unwrap();
    let o = DVec3::new(0.0, 1.0, 0.0);
    let shadowed = trace_ray(&s, o, DVec3::NEG_Y, true).0;
    let lit = trace_ray(&s, o, DVec3::NEG_Y, false).0;
    assert!(shadowed[0] < lit[0], "{shadowed:?} vs {lit:?}");
    let _unused: CubeMap<u8> = CubeMap::filled(1, 0);
}
