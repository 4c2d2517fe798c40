//! POV-Ray import against real POV-Ray 3.7 (`povray` must be installed; never mocked).
//!
//! The analytic scene `scenes/pov/analytic.pov` is re-described here as exact geometry; every
//! cube-map pixel's depth and slab layer are compared with the analytic first hit.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::DVec3;
use prerender::pov::{PovError, PovImport, PovOptions, UpAxis};
use prerender::store::{self, PrerenderDir};
use tracks::cubemap::{pixel_dir, subpixel_dir};
use tracks::{CubeMap, Face, ReferenceViewpoint, SlabRange};

const FACE: u32 = 16;
const LOWRES: u32 = 8;

fn repo_file(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("railview-pov-{name}-{}", std::process::id()));
    fs::remove_dir_all(&d).ok();
    fs::create_dir_all(&d).unwrap();
    d
}

fn options(out: &Path) -> PovOptions {
    let mut o = PovOptions::new(FACE, out.join("pov-work"));
    o.lowres_face_size = LOWRES;
    o.threads = 2;
    o
}

fn vp(index: usize, p: [f64; 3]) -> ReferenceViewpoint {
    ReferenceViewpoint {
        index,
        s: index as f64,
        position: DVec3::from_array(p),
    }
}

/// Exact geometry in POV-Ray coordinates.
struct Analytic {
    spheres: Vec<(DVec3, f64)>,
    boxes: Vec<(DVec3, DVec3)>,
    /// Planes `n·p = c`.
    planes: Vec<(DVec3, f64)>,
}

impl Analytic {
    /// `scenes/pov/analytic.pov`.
    fn scene() -> Analytic {
        Analytic {
            spheres: vec![
                (DVec3::new(0.0, 1.0, 6.0), 1.0),
                (DVec3::new(-4.0, 1.5, -3.0), 1.5),
                (DVec3::new(-2.0, 1.0, 2.0), 0.8),
            ],
            boxes: vec![(DVec3::new(3.0, 0.0, -2.0), DVec3::new(5.0, 2.5, 1.0))],
            planes: vec![(DVec3::Y, 0.0)],
        }
    }

    /// Every surface crossing along the ray, ascending, `t > 0`.
    fn crossings(&self, o: DVec3, d: DVec3) -> Vec<f64> {
        let mut t = Vec::new();
        for &(c, r) in &self.spheres {
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            if disc >= 0.0 {
                let s = disc.sqrt();
                t.extend([-b - s, -b + s]);
            }
        }
        for &(lo, hi) in &self.boxes {
            let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
            for k in 0..3 {
                let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
            if t0 <= t1 {
                t.extend([t0, t1]);
            }
        }
        for &(n, c) in &self.planes {
            let dn = n.dot(d);
            if dn != 0.0 {
                t.push((c - n.dot(o)) / dn);
            }
        }
        t.retain(|x| x.is_finite() && *x > 0.0);
        t.sort_by(f64::total_cmp);
        t
    }

    /// First crossing in `[near, far)`.
    fn first_in(&self, o: DVec3, d: DVec3, near: f64, far: f64) -> Option<f64> {
        self.crossings(o, d)
            .into_iter()
            .find(|&t| t >= near)
            .filter(|&t| t < far)
    }
}

/// Whether the analytic answer at pixel `(face, x, y)` is stable under tiny direction changes
/// (a mesh-camera ray is only float-accurate) and not within the depth decoding error (3e-4
/// relative) of a slab boundary.
fn stable(
    scene: &Analytic,
    up: UpAxis,
    o: DVec3,
    (face, x, y): (Face, u32, u32),
    near: f64,
    far: f64,
) -> bool {
    let centre = scene.first_in(
        o,
        up.pov_from_railview(pixel_dir(face, x, y, FACE)),
        near,
        far,
    );
    let crossings = scene.crossings(o, up.pov_from_railview(pixel_dir(face, x, y, FACE)));
    if crossings
        .iter()
        .any(|&t| (t - near).abs() < 3e-4 * t || (far.is_finite() && (t - far).abs() < 3e-4 * t))
    {
        return false;
    }
    let e = 1e-4;
    [(e, 0.0), (-e, 0.0), (0.0, e), (0.0, -e)]
        .iter()
        .all(|&(dx, dy)| {
            let d = subpixel_dir(face, x as f64 + 0.5 + dx, y as f64 + 0.5 + dy, FACE);
            let other = scene.first_in(o, up.pov_from_railview(d), near, far);
            match (centre, other) {
                (None, None) => true,
                (Some(a), Some(b)) => (a - b).abs() < 1e-4 * a,
                _ => false,
            }
        })
}

fn pixels(n: u32) -> impl Iterator<Item = (Face, u32, u32)> {
    Face::ALL
        .into_iter()
        .flat_map(move |f| (0..n).flat_map(move |y| (0..n).map(move |x| (f, x, y))))
}

/// Radial depth of every pixel against the analytic scene: relative error ≤ 1e-4 on every hit,
/// +inf on every miss. Returns the number of hits.
fn check_depth(scene: &Analytic, up: UpAxis, o: DVec3, depth: &CubeMap<f32>) -> usize {
    let mut hits = 0;
    for (face, x, y) in pixels(depth.face_size()) {
        let d = up.pov_from_railview(pixel_dir(face, x, y, depth.face_size()));
        let got = *depth.get(face, x, y) as f64;
        match scene.first_in(o, d, 0.0, f64::INFINITY) {
            Some(t) => {
                hits += 1;
                let rel = (got - t).abs() / t;
                assert!(
                    rel <= 1e-4,
                    "face {face:?} ({x}, {y}): depth {got} vs analytic {t} (rel {rel:.2e})"
                );
            }
            None => assert_eq!(
                got,
                f64::INFINITY,
                "face {face:?} ({x}, {y}) misses everything"
            ),
        }
    }
    hits
}

#[test]
fn analytic_scene_depth_and_slabs_match_ground_truth() {
    let out = tmp("analytic");
    let dir = PrerenderDir::new(&out);
    let mut import = PovImport::new(repo_file("scenes/pov/analytic.pov"), options(&out)).unwrap();
    let scene = Analytic::scene();
    let up = UpAxis::Y;

    // Two viewpoints: the second checks that positions map railview → POV-Ray correctly.
    for v in [vp(0, [0.0, 1.2, 0.0]), vp(1, [1.0, 0.8, 1.5])] {
        let meta = import.render_base(&v, &dir).unwrap();
        assert_eq!((meta.face_size, meta.lowres_face_size), (FACE, LOWRES));
        let o = up.pov_from_railview(v.position);
        let depth = store::read_depth_exr(&dir.depth_exr(v.index)).unwrap();
        let hits = check_depth(&scene, up, o, &depth);
        assert!(
            hits > 200 && hits < 6 * 256 - 100,
            "hits {hits}: both sky and surfaces"
        );
        let low = store::read_depth_exr(&dir.lowres_depth_exr(v.index)).unwrap();
        assert_eq!(low.face_size(), LOWRES);
        assert!(dir.sample_meta(v.index).is_some());
        assert!(import.base_done(&dir, &v), "resume sees the sample as done");
    }
    let mut bigger = options(&out);
    bigger.face_size = 2 * FACE;
    let other = PovImport::new(repo_file("scenes/pov/analytic.pov"), bigger).unwrap();
    assert!(
        !other.base_done(&dir, &vp(0, [0.0, 1.2, 0.0])),
        "face size changed"
    );
    assert!(
        !import.base_done(&dir, &vp(0, [0.0, 1.3, 0.0])),
        "position changed"
    );

    // Slab [0, inf) is the plain colour render.
    let v = vp(0, [0.0, 1.2, 0.0]);
    let whole = SlabRange::parse_list("0-inf").unwrap();
    import.render_slabs(&v, &whole, &dir).unwrap();
    let color = store::read_rgb_png(&dir.color_png(0)).unwrap();
    let slab = store::read_rgba_png(&dir.slab_color_png(0, 0)).unwrap();
    let diff: f64 = color
        .as_slice()
        .iter()
        .zip(slab.as_slice())
        .map(|(a, b)| {
            (0..3)
                .map(|c| (a[c] as f64 - b[c] as f64).abs())
                .sum::<f64>()
                / 3.0
        })
        .sum::<f64>()
        / color.as_slice().len() as f64;
    assert!(diff < 0.5, "mean |slab[0,inf) - colour| = {diff} levels");
    let slab_depth = store::read_depth_exr(&dir.slab_depth_exr(0, 0)).unwrap();
    let depth = store::read_depth_exr(&dir.depth_exr(0)).unwrap();
    for (a, b) in depth.as_slice().iter().zip(slab_depth.as_slice()) {
        assert!(a == b || ((a - b) / a).abs() < 1e-4, "{a} vs {b}");
    }

    // Slabs against the analytic "first hit in [near, far)".
    let slabs = SlabRange::parse_list("0-2.5,2.5-6,6-inf").unwrap();
    let layers = import.render_slabs(&v, &slabs, &dir).unwrap();
    assert_eq!(layers.slabs, slabs);
    let o = up.pov_from_railview(v.position);
    for (k, s) in slabs.iter().enumerate() {
        let rgba = store::read_rgba_png(&dir.slab_color_png(0, k)).unwrap();
        let z = store::read_depth_exr(&dir.slab_depth_exr(0, k)).unwrap();
        let (mut checked, mut filled) = (0, 0);
        for p @ (face, x, y) in pixels(FACE) {
            let got = *z.get(face, x, y) as f64;
            let alpha = rgba.get(face, x, y)[3];
            assert_eq!(alpha == 255, got.is_finite(), "alpha follows depth");
            assert!(alpha == 0 || alpha == 255);
            if !stable(&scene, up, o, p, s.near, s.far) {
                continue;
            }
            checked += 1;
            let d = up.pov_from_railview(pixel_dir(face, x, y, FACE));
            match scene.first_in(o, d, s.near, s.far) {
                Some(t) => {
                    filled += 1;
                    let rel = (got - t).abs() / t;
                    assert!(
                        rel <= 1e-4,
                        "slab {} {face:?} ({x}, {y}): {got} vs analytic {t}",
                        s.label()
                    );
                }
                None => assert_eq!(
                    got,
                    f64::INFINITY,
                    "slab {} {face:?} ({x}, {y}) should be empty",
                    s.label()
                ),
            }
        }
        assert!(
            checked > 6 * 256 * 95 / 100,
            "slab {k}: only {checked} pixels checked"
        );
        assert!(filled > 10, "slab {k}: {filled} filled pixels");
    }
    assert!(import.slabs_done(&dir, &v, &slabs));
    assert!(!import.slabs_done(&dir, &v, &whole));

    // Equirectangular preview through POV-Ray's spherical camera.
    let preview = out.join("preview.png");
    import.render_preview(&v, 32, &preview).unwrap();
    let img = image::open(&preview).unwrap();
    assert_eq!((img.width(), img.height()), (32, 16));
}

#[test]
fn z_up_scene_maps_axes() {
    let out = tmp("zup");
    let scene_path = out.join("zup.pov");
    fs::write(
        &scene_path,
        "#version 3.7;\nglobal_settings { assumed_gamma 1.0 }\n\
         light_source { <10, -20, 30> rgb 1 }\n\
         plane { z, 0 pigment { rgb 0.6 } }\n\
         sphere { <3, 1, 1>, 1 pigment { rgb <1, 0, 0> } }\n\
         sphere { <-1, -4, 2>, 1.5 pigment { rgb <0, 1, 0> } }\n",
    )
    .unwrap();
    let mut opts = options(&out);
    opts.up = UpAxis::Z;
    let mut import = PovImport::new(&scene_path, opts).unwrap();
    let dir = PrerenderDir::new(&out);
    // railview (x, y, z) = POV-Ray (−X, Z, −Y): camera at POV-Ray <0.5, 0.2, 1.0>.
    let v = vp(0, [-0.5, 1.0, -0.2]);
    import.render_base(&v, &dir).unwrap();
    let scene = Analytic {
        spheres: vec![
            (DVec3::new(3.0, 1.0, 1.0), 1.0),
            (DVec3::new(-1.0, -4.0, 2.0), 1.5),
        ],
        boxes: vec![],
        planes: vec![(DVec3::Z, 0.0)],
    };
    let o = UpAxis::Z.pov_from_railview(v.position);
    assert_eq!(o, DVec3::new(0.5, 0.2, 1.0));
    let depth = store::read_depth_exr(&dir.depth_exr(0)).unwrap();
    let hits = check_depth(&scene, UpAxis::Z, o, &depth);
    // The ground fills the lower half: railview −y looks at POV-Ray −z.
    assert!(hits >= 3 * 256, "{hits}");
    assert!(depth.get(Face::NegY, 8, 8).is_finite());
    assert!(depth.get(Face::PosY, 8, 8).is_infinite());
}

#[test]
fn depth_from_many_positions_in_shared_runs_matches_ground_truth() {
    let out = tmp("free-depths");
    let dir = PrerenderDir::new(&out);
    let mut import = PovImport::new(repo_file("scenes/pov/analytic.pov"), options(&out)).unwrap();
    let scene = Analytic::scene();
    let up = UpAxis::Y;
    // The witness: a reference viewpoint and its depth.
    let w = vp(0, [0.0, 1.2, 0.0]);
    import.render_base(&w, &dir).unwrap();
    let w_depth = store::read_depth_exr(&dir.depth_exr(0)).unwrap();
    // Seven positions share a few runs; the fourth is inside the box <3,0,-2>..<5,2.5,1>
    // and sees nothing (rendered with the others, it would take their fog and show the
    // box's inside as if it were a room).
    let positions = [
        [0.0, 1.2, 0.0],
        [1.0, 0.8, 1.5],
        [-1.5, 2.0, -0.5],
        [4.0, 1.0, -0.5],
        [0.5, 0.3, 3.0],
        [-3.0, 1.0, 1.0],
        [2.0, 4.0, -4.0],
    ]
    .map(DVec3::from_array);
    for fog in [false, true] {
        let req = prerender::pov::DepthRequest {
            face_size: FACE,
            nearest: 0.3,
            farthest: 40.0,
            fog,
        };
        let before = import.records().len();
        let depths = import
            .render_depths(&positions, req, &[(w.position, &w_depth)])
            .unwrap();
        assert_eq!(depths.len(), positions.len());
        let runs = import.records().len() - before;
        let passes = if fog { 2 } else { 1 };
        assert!(
            runs <= passes * 4,
            "{runs} POV-Ray runs for {} positions",
            positions.len()
        );
        for (i, (p, d)) in positions.iter().zip(&depths).enumerate() {
            match d {
                None => assert_eq!(i, 3, "only the position inside the box sees nothing"),
                Some(d) => {
                    let o = up.pov_from_railview(*p);
                    let (mut checked, mut hits) = (0, 0);
                    for px @ (face, x, y) in pixels(FACE) {
                        if !stable(&scene, up, o, px, 0.0, f64::INFINITY) {
                            continue;
                        }
                        checked += 1;
                        let got = *d.get(face, x, y) as f64;
                        let dir = up.pov_from_railview(pixel_dir(face, x, y, FACE));
                        match scene.first_in(o, dir, 0.0, f64::INFINITY) {
                            Some(t) => {
                                hits += 1;
                                assert!(
                                    (got - t).abs() <= 1e-4 * t,
                                    "position {i} {face:?} ({x}, {y}): {got} vs analytic {t}"
                                );
                            }
                            None => assert_eq!(got, f64::INFINITY, "position {i} {face:?}"),
                        }
                    }
                    assert!(checked > 6 * 256 * 95 / 100, "position {i}: {checked}");
                    assert!(hits > 100, "position {i}: {hits} hits");
                }
            }
        }
        assert!(depths[3].is_none());
    }
    let left: Vec<_> = fs::read_dir(out.join("pov-work"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".png") || n.ends_with("_wrap.pov"))
        .collect();
    assert!(left.is_empty(), "renders and wrappers removed: {left:?}");
}

fn assert_no_sample(dir: &PrerenderDir) {
    assert!(
        dir.sample_meta(0).is_none(),
        "a failed sample must not look complete"
    );
}

#[test]
fn camera_inside_a_solid_names_the_viewpoint() {
    let out = tmp("inside");
    let dir = PrerenderDir::new(&out);
    let mut import = PovImport::new(repo_file("scenes/pov/analytic.pov"), options(&out)).unwrap();
    // Inside the box <3,0,-2>..<5,2.5,1>.
    let e = import
        .render_base(&vp(0, [4.0, 1.0, 0.5]), &dir)
        .unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, PovError::Viewpoint { index: 0, .. }), "{msg}");
    assert!(
        msg.contains("viewpoint 0") && msg.contains("inside"),
        "{msg}"
    );
    assert_no_sample(&dir);
}

#[test]
fn povray_errors_name_file_and_line() {
    let out = tmp("errors");
    let dir = PrerenderDir::new(&out);
    let parse = out.join("broken.pov");
    fs::write(
        &parse,
        "#version 3.7;\nsphere { <0, 0, 5>, 1 pigment { rgb 1 } }\nbox { 1 }\n",
    )
    .unwrap();
    let include = out.join("include.pov");
    fs::write(&include, "#version 3.7;\n\n#include \"no_such_file.inc\"\n").unwrap();
    for (scene, expect) in [(&parse, "broken.pov:3:"), (&include, "include.pov:3:")] {
        let mut import = PovImport::new(scene, options(&out)).unwrap();
        let e = import
            .render_base(&vp(0, [0.0, 1.0, 0.0]), &dir)
            .unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, PovError::Render { .. }), "{msg}");
        assert!(msg.contains(expect) && msg.contains("Parse Error"), "{msg}");
        assert_no_sample(&dir);
    }
    let e = import_err(out.join("missing.pov"), options(&out));
    assert!(
        matches!(e, PovError::Scene { .. }) && e.to_string().contains("missing.pov"),
        "{e}"
    );
}

fn import_err(scene: PathBuf, opts: PovOptions) -> PovError {
    match PovImport::new(scene, opts) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e,
    }
}

#[test]
fn missing_povray_and_unwritable_output_are_clear() {
    let out = tmp("setup");
    let mut opts = options(&out);
    opts.povray = PathBuf::from("/nonexistent/bin/povray");
    let e = import_err(repo_file("scenes/pov/analytic.pov"), opts);
    let msg = e.to_string();
    assert!(matches!(e, PovError::PovrayMissing { .. }), "{msg}");
    assert!(
        msg.contains("/nonexistent/bin/povray") && msg.contains("install POV-Ray"),
        "{msg}"
    );

    let opts = PovOptions::new(FACE, "/proc/railview-no-such-dir/pov-work");
    let e = import_err(repo_file("scenes/pov/analytic.pov"), opts);
    assert!(e.to_string().contains("/proc/railview-no-such-dir"), "{e}");
}

#[test]
fn timeout_kills_the_render_and_leaves_no_complete_sample() {
    let out = tmp("timeout");
    let dir = PrerenderDir::new(&out);
    // A stale marker from an earlier run must not survive a failed re-render.
    let stale = store::SampleMeta {
        index: 0,
        s: 0.0,
        position: DVec3::new(0.0, 1.2, 0.0),
        face_size: FACE,
        lowres_face_size: LOWRES,
        primary_rays: 1,
    };
    store::write_json(&dir.sample_json(0), &stale).unwrap();
    let mut opts = options(&out);
    opts.timeout = Some(Duration::from_millis(50));
    let mut import = PovImport::new(repo_file("scenes/pov/analytic.pov"), opts).unwrap();
    let e = import
        .render_base(&vp(0, [0.0, 1.2, 0.0]), &dir)
        .unwrap_err();
    assert!(matches!(e, PovError::Timeout { .. }), "{e}");
    assert!(!import.base_done(&dir, &vp(0, [0.0, 1.2, 0.0])));
    assert!(e.to_string().contains("sample 0"), "{e}");
    assert_no_sample(&dir);
}

#[test]
fn antialiased_colour_is_the_same_view() {
    let out = tmp("aa");
    let plain_dir = PrerenderDir::new(out.join("plain"));
    let aa_dir = PrerenderDir::new(out.join("aa"));
    let scene = repo_file("scenes/pov/analytic.pov");
    let v = vp(0, [0.0, 1.2, 0.0]);
    PovImport::new(&scene, options(&out))
        .unwrap()
        .render_base(&v, &plain_dir)
        .unwrap();
    let mut opts = options(&out);
    opts.supersample = 2;
    PovImport::new(&scene, opts)
        .unwrap()
        .render_base(&v, &aa_dir)
        .unwrap();
    let a = store::read_rgb_png(&plain_dir.color_png(0)).unwrap();
    let b = store::read_rgb_png(&aa_dir.color_png(0)).unwrap();
    assert_eq!(b.face_size(), FACE);
    // 2×2 supersampling only changes edges and texture detail, not what is where.
    let mean: f64 = a
        .as_slice()
        .iter()
        .zip(b.as_slice())
        .map(|(p, q)| {
            (0..3)
                .map(|c| (p[c] as f64 - q[c] as f64).abs())
                .sum::<f64>()
                / 3.0
        })
        .sum::<f64>()
        / a.as_slice().len() as f64;
    assert!(
        mean > 0.0 && mean < 12.0,
        "mean |aa - plain| = {mean} levels"
    );
}

/// The ground truth's perspective camera sees what the cube map sees: a camera at the
/// viewpoint looking along each horizontal cube face, 90° wide at the face's resolution,
/// traces the same pixel-centre rays as the mesh camera (rows and columns the same way round,
/// on both up axes).
#[test]
fn perspective_truth_matches_the_cube_faces() {
    for (up, name) in [(UpAxis::Y, "y"), (UpAxis::Z, "z")] {
        let out = tmp(&format!("truth-{name}"));
        let dir = PrerenderDir::new(&out);
        let scene = repo_file("scenes/pov/analytic.pov");
        let mut opts = options(&out);
        opts.up = up;
        let mut import = PovImport::new(&scene, opts).unwrap();
        // POV-Ray <0.5, 1.2, 0.5> (above the ground) in railview coordinates; the y-up scene
        // read as z-up is merely turned on its side.
        let at = match up {
            UpAxis::Y => [0.5, 1.2, -0.5],
            UpAxis::Z => [-0.5, 0.5, -1.2],
        };
        import.render_base(&vp(0, at), &dir).unwrap();
        let cube = store::read_rgb_png(&dir.color_png(0)).unwrap();
        // Yaw 0 looks along railview −z (face NegZ), 90 along +x, 180 along +z, 270 along −x.
        for (yaw, face) in [
            (0.0, Face::NegZ),
            (90.0, Face::PosX),
            (180.0, Face::PosZ),
            (270.0, Face::NegX),
        ] {
            let cam = tracks::PerspectiveCamera {
                position: DVec3::from_array(at),
                yaw_deg: yaw,
                pitch_deg: 0.0,
                fov_deg: 90.0,
                width: FACE,
                height: FACE,
            };
            let view = import.render_perspective(&cam, 1).unwrap();
            let mut worst = 0;
            for y in 0..FACE {
                for x in 0..FACE {
                    let p = view[(y * FACE + x) as usize];
                    let q = cube.get(face, x, y);
                    for c in 0..3 {
                        worst = worst.max((p[c] as i32 - q[c] as i32).abs());
                    }
                }
            }
            assert!(
                worst <= 3,
                "up {name}, yaw {yaw}: worst channel difference {worst}"
            );
        }
    }
}

/// Regression (the balcony's black specks in the sky): under a scene's own ground fog (the
/// balcony's, copied here) the depth pass is decoded with the fog-only pass subtracted at
/// half strength, and a slab ray that hits nothing before the slab's far end decoded 1e-4
/// short of it (4.4995 of 4.5 here, 7.4246 of 7.4254 on the balcony), so it counted as a hit
/// at the far plane: an opaque pixel coloured by a ray that saw nothing. Every layer
/// must be empty wherever the panorama sees sky, and where a layer holds what the panorama
/// sees, it holds the panorama's colour (its fog, its light, its anti-aliasing).
#[test]
fn fogged_sky_leaves_every_slab_empty_and_layers_keep_the_panoramas_colour() {
    let out = tmp("fogged");
    let scene = out.join("fogged.pov");
    fs::write(
        &scene,
        format!(
            "#include \"{}\"\nfog {{ fog_type 2 fog_alt 1.2 fog_offset 0 color rgbt <0.6, 0.68, 0.82, 0> distance 700 up y }}\n",
            repo_file("scenes/pov/analytic.pov").display()
        ),
    )
    .unwrap();
    let dir = PrerenderDir::new(&out);
    let mut import = PovImport::new(&scene, options(&out)).unwrap();
    let slabs = SlabRange::parse_list("0-4.5,4.5-inf").unwrap();
    for v in [vp(0, [0.0, 1.2, 0.0]), vp(1, [1.0, 0.8, 1.5])] {
        import.render_base(&v, &dir).unwrap();
        import.render_slabs(&v, &slabs, &dir).unwrap();
        let depth = store::read_depth_exr(&dir.depth_exr(v.index)).unwrap();
        let color = store::read_rgb_png(&dir.color_png(v.index)).unwrap();
        let sky = depth.as_slice().iter().filter(|d| d.is_infinite()).count();
        assert!(sky > 300, "sample {}: {sky} sky pixels", v.index);
        for k in 0..slabs.len() {
            let layer = store::read_rgba_png(&dir.slab_color_png(v.index, k)).unwrap();
            let layer_depth = store::read_depth_exr(&dir.slab_depth_exr(v.index, k)).unwrap();
            let mut seen = 0;
            for (i, (&d, px)) in depth.as_slice().iter().zip(layer.as_slice()).enumerate() {
                if d.is_infinite() {
                    assert_eq!(
                        px[3],
                        0,
                        "sample {} slab {k} pixel {i}: opaque ({:?}, depth {}) where the \
                         panorama sees sky",
                        v.index,
                        px,
                        layer_depth.as_slice()[i]
                    );
                } else if px[3] > 0 && (layer_depth.as_slice()[i] - d).abs() <= 1e-3 * d {
                    seen += 1;
                    assert_eq!(
                        px[..3],
                        color.as_slice()[i][..],
                        "sample {} slab {k} pixel {i}: the panorama's surface in another colour",
                        v.index
                    );
                }
            }
            assert!(
                seen > 50,
                "sample {} slab {k}: {seen} pixels the panorama sees",
                v.index
            );
        }
    }
    fs::remove_dir_all(&out).ok();
}
