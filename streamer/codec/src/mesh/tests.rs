use super::*;
use proptest::prelude::*;

const FACE: u32 = 256;

fn coding(step: f64) -> MeshCoding {
    MeshCoding {
        face_size: FACE,
        depth_step: step,
    }
}

/// A regular mesh of `nx × ny` vertices every `spacing` pixels from pixel (100, 36); cells
/// with `keep(cx, cy)` false are left out, `diag(cx, cy)` picks each cell's diagonal.
fn grid_with(
    nx: u32,
    ny: u32,
    spacing: f32,
    depth: impl Fn(u32, u32) -> f32,
    keep: impl Fn(u32, u32) -> bool,
    diag: impl Fn(u32, u32) -> bool,
) -> TileMesh {
    let mut m = TileMesh::default();
    for y in 0..ny {
        for x in 0..nx {
            m.vertices.push([
                100.5 + x as f32 * spacing,
                36.5 + y as f32 * spacing,
                depth(x, y),
            ]);
        }
    }
    for y in 0..ny - 1 {
        for x in 0..nx - 1 {
            if !keep(x, y) {
                continue;
            }
            let i = y * nx + x;
            if diag(x, y) {
                m.indices
                    .extend_from_slice(&[i, i + 1, i + nx + 1, i, i + nx + 1, i + nx]);
            } else {
                m.indices
                    .extend_from_slice(&[i, i + 1, i + nx, i + 1, i + nx + 1, i + nx]);
            }
        }
    }
    m
}

fn grid(nx: u32, ny: u32, depth: impl Fn(u32, u32) -> f32) -> TileMesh {
    grid_with(nx, ny, 4.0, depth, |_, _| true, |_, _| false)
}

/// Positions of a vertex as exact keys.
fn key(v: [f32; 3]) -> (u32, u32) {
    (v[0].to_bits(), v[1].to_bits())
}

/// The mesh as sorted triangles of positions and depths by position; vertices no triangle
/// uses are kept too.
type Canon = (Vec<[(u32, u32); 3]>, Vec<((u32, u32), f32)>);

fn canonical(m: &TileMesh) -> Canon {
    let mut tris: Vec<[(u32, u32); 3]> = m
        .indices
        .chunks_exact(3)
        .map(|t| {
            let mut k = [0, 1, 2].map(|i| key(m.vertices[t[i] as usize]));
            k.sort_unstable();
            k
        })
        .collect();
    tris.sort_unstable();
    let mut verts: Vec<((u32, u32), f32)> = m.vertices.iter().map(|&v| (key(v), v[2])).collect();
    verts.sort_by(|a, b| (a.0, a.1).partial_cmp(&(b.0, b.1)).unwrap());
    (tris, verts)
}

/// `m` survives a round trip: the same triangles on the same positions, every depth within
/// the quantisation bound (in inverse planar depth, f32 rounding allowed).
fn assert_round_trip(m: &TileMesh, step: f64) -> Vec<u8> {
    let bytes = encode_mesh(m, &coding(step)).unwrap();
    let back = decode_mesh(&bytes).unwrap();
    let (ta, va) = canonical(m);
    let (tb, vb) = canonical(&back);
    assert_eq!(ta, tb, "triangles");
    assert_eq!(va.len(), vb.len());
    let step32 = step_code(step).1;
    assert!(step32 <= step && step32 > step * 0.996);
    for (a, b) in va.iter().zip(&vb) {
        assert_eq!(a.0, b.0);
        let (x, y) = (f32::from_bits(a.0 .0) as f64, f32::from_bits(a.0 .1) as f64);
        let norm = planar_norm(x, y, FACE);
        let (qa, qb) = (norm / a.1 as f64, norm / b.1 as f64);
        // Pixel quads (corners on whole pixels) quantise inverse radial depth: its bound
        // times the planar norm in inverse planar depth.
        let scale = if x.fract() == 0.0 && y.fract() == 0.0 {
            norm
        } else {
            1.0
        };
        let bound = scale
            * if qa / scale >= step32 / 2.0 {
                step32 / 2.0
            } else {
                step32
            };
        assert!(
            (qa - qb).abs() <= bound * 1.0001 + qa * 1e-6,
            "q {qa} → {qb}, step {step32}"
        );
    }
    bytes
}

#[test]
fn pixel_centres_are_exact_and_depth_error_is_within_half_a_step() {
    let m = grid(9, 9, |x, y| 2.0 + (x * 9 + y) as f32 * 10.0);
    assert_round_trip(&m, 1e-4);
    assert_round_trip(&m, 1e-2);
}

#[test]
fn planes_cost_almost_nothing_beyond_their_outline() {
    // A tilted plane: inverse planar depth affine in face pixels.
    let plane = |x: u32, y: u32| {
        let (fx, fy) = (100.5 + x as f64 * 4.0, 36.5 + y as f64 * 4.0);
        let q = 0.2 + 0.001 * fx + 0.0005 * fy;
        (planar_norm(fx, fy, FACE) / q) as f32
    };
    let m = grid(9, 9, plane);
    let bytes = assert_round_trip(&m, 1e-5);
    // 81 vertices, 128 triangles: 1286 bytes at 6 bytes a vertex and 6 a triangle (the
    // flat layout of format 1); here mostly the header, the lattice positions and the
    // first depth.
    assert!(bytes.len() < 110, "{} bytes", bytes.len());
}

#[test]
fn flat_empty_isolated_and_eighth_pixel_meshes() {
    let flat = grid(3, 2, |_, _| 5.0);
    assert_round_trip(&flat, 1e-3);
    let empty = TileMesh::default();
    let b = encode_mesh(&empty, &coding(1e-3)).unwrap();
    assert_eq!(decode_mesh(&b).unwrap(), empty);
    // A vertex no triangle uses, and vertices off the pixel centres.
    let mut odd = grid(3, 3, |x, _| 3.0 + x as f32);
    odd.vertices.push([90.5, 10.5, 7.0]);
    assert_round_trip(&odd, 1e-3);
    let mut eighth = grid(3, 3, |_, y| 3.0 + y as f32);
    for v in &mut eighth.vertices {
        v[0] += 0.125;
    }
    let bytes = encode_mesh(&eighth, &coding(1e-3)).unwrap();
    assert_eq!(bytes[1], 8);
    assert_round_trip(&eighth, 1e-3);
}

#[test]
fn a_tile_with_a_vertex_on_every_pixel_fits_the_limits() {
    // 33 × 33 vertices on unit spacing: a 32² tile meshed at every pixel.
    let m = grid_with(
        33,
        33,
        1.0,
        |x, y| 4.0 + ((x * y) % 7) as f32 * 0.01,
        |_, _| true,
        |x, y| (x + y) % 2 == 0,
    );
    assert_round_trip(&m, 1e-4);
}

#[test]
fn bad_meshes_are_refused() {
    let c = coding(1e-3);
    let mut m = grid(2, 2, |_, _| 1.0);
    m.indices.push(0);
    assert_eq!(encode_mesh(&m, &c), Err(MeshError::Ragged(7)));
    m.indices.extend_from_slice(&[0, 9]);
    assert!(matches!(
        encode_mesh(&m, &c),
        Err(MeshError::BadIndex { index: 9, .. })
    ));
    let mut m = grid(2, 2, |_, _| 1.0);
    m.vertices[1][2] = f32::INFINITY;
    assert!(matches!(
        encode_mesh(&m, &c),
        Err(MeshError::BadVertex { index: 1, .. })
    ));
    // What the lattice cannot hold is stored plain, exactly: two vertices at one position
    // (the quad of a pixel no triangle covers, at that pixel's depth), three corners on a
    // line, two triangles on the same side of an edge.
    let mut shared = grid(2, 2, |_, _| 1.0);
    shared
        .vertices
        .push([shared.vertices[0][0], shared.vertices[0][1], 2.5]);
    shared.indices.extend_from_slice(&[4, 1, 2]);
    let line = TileMesh {
        vertices: vec![[0.5, 0.5, 1.0], [1.5, 0.5, 1.0], [2.5, 0.5, 1.0]],
        indices: vec![0, 1, 2],
    };
    let mut twice = grid(2, 2, |_, _| 1.0);
    twice.indices.extend_from_slice(&[0, 1, 2]);
    for m in [&shared, &line, &twice] {
        let b = encode_mesh(m, &c).unwrap();
        assert_eq!(b[1], 0, "stored plain");
        assert_eq!(&decode_mesh(&b).unwrap(), m);
        // Every shorter prefix, and one byte more, is refused.
        for cut in 0..b.len() {
            assert!(decode_mesh(&b[..cut]).is_err(), "prefix of {cut} bytes");
        }
        let mut longer = b.clone();
        longer.push(0);
        assert!(decode_mesh(&longer).is_err());
    }
    // A plain mesh naming a vertex it does not have, or a negative depth, is refused.
    let mut b = encode_mesh(&line, &c).unwrap();
    let last = b.len() - 4;
    b[last..].copy_from_slice(&7u32.to_le_bytes());
    assert!(matches!(
        decode_mesh(&b),
        Err(MeshError::BadIndex { index: 7, .. })
    ));
    assert!(matches!(
        encode_mesh(&grid(2, 2, |_, _| 1.0), &coding(0.0)),
        Err(MeshError::Coding(_))
    ));
    // Decoding: short, foreign, old, damaged headers.
    let good = encode_mesh(&grid(3, 3, |x, _| 1.0 + x as f32), &c).unwrap();
    for cut in 0..8 {
        assert!(matches!(
            decode_mesh(&good[..cut]),
            Err(MeshError::Format(_))
        ));
    }
    // Format 2 began with the magic "RMSH" then its version; format 3 had the magic too:
    // refused, asking for a rebuild.
    for old in [b"RMSH\x02\x01".to_vec(), vec![2, 1], vec![3, 1]] {
        let mut old = old;
        old.extend_from_slice(&good[2..]);
        let e = decode_mesh(&old).unwrap_err().to_string();
        assert!(e.contains("rebuild"), "{e}");
    }
    let mut bad = good.clone();
    bad[1] = 3;
    assert!(matches!(decode_mesh(&bad), Err(MeshError::Format(_))));
}

#[test]
fn hostile_counts_are_refused_before_allocating() {
    let header = |w: u64, h: u64, v: u64, t: u64| {
        let mut b = b"\x04\x01".to_vec();
        for x in [256, 0, 0, w, h, v, t, 0] {
            put_varint(&mut b, x);
        }
        b.extend_from_slice(&step_code(1e-3).0);
        b
    };
    for (w, h, v, t) in [
        (1 << 30, 1 << 30, 1, 0),
        (1 << 12, 1 << 13, 10, 0),
        (4, 4, 17, 0),
        (4, 4, 4, 9),
        (4096, 4096, 1 << 20, 1 << 21),
    ] {
        let e = decode_mesh(&header(w, h, v, t)).unwrap_err();
        assert!(matches!(e, MeshError::Format(_)), "{e}");
    }
    // Counts within the limits but a stream that holds nothing: an error, not a panic.
    assert!(decode_mesh(&header(4, 4, 16, 18)).is_err());
    // Pixel quads: more than the box holds, more than the limit, a box too wide.
    let quads = |p: u64, w: u64, h: u64| {
        let mut b = b"\x04\x01".to_vec();
        for x in [256, 0, 0, 0, 0, 0, 0, p, 0, 0, w, h] {
            put_varint(&mut b, x);
        }
        b.extend_from_slice(&step_code(1e-3).0);
        b
    };
    for (p, w, h) in [
        (17, 4, 4),
        (MAX_CELLS, 1 << 12, 1 << 12),
        (1, 1 << 16, 1),
        (1, 0, 1),
    ] {
        let e = decode_mesh(&quads(p, w, h)).unwrap_err();
        assert!(matches!(e, MeshError::Format(_)), "{e}");
    }
    assert!(decode_mesh(&quads(16, 4, 4)).is_err());
}

/// Appends the quad `slabs` gives an uncovered pixel `(x, y)`.
fn push_quad(m: &mut TileMesh, x: u32, y: u32, r: f32) {
    let base = m.vertices.len() as u32;
    let (x, y) = (x as f32, y as f32);
    m.vertices.extend([
        [x, y, r],
        [x + 1.0, y, r],
        [x + 1.0, y + 1.0, r],
        [x, y + 1.0, r],
    ]);
    m.indices
        .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
}

#[test]
fn pixel_quads_beside_a_mesh_stay_on_the_lattice() {
    // A pole one pixel wide in front of a wall: a column of quads sharing corners (two
    // vertices at one position, at different depths from the wall's), one quad alone.
    let mut m = grid(6, 6, |x, y| 8.0 + 0.1 * x as f32 + 0.02 * y as f32);
    for y in 3..9 {
        push_quad(&mut m, 7, y, 2.0 + 0.01 * y as f32);
    }
    push_quad(&mut m, 8, 3, 2.5);
    push_quad(&mut m, 20, 1, 30.0);
    let bytes = assert_round_trip(&m, 1e-3);
    assert_eq!(bytes[1], 1, "on the lattice, not plain");
    let plain = 12 * (m.vertices.len() + m.indices.len() / 3);
    assert!(
        bytes.len() * 8 < plain,
        "{} B against {plain} B plain",
        bytes.len()
    );
    // Quads alone, and a quad at a negative position.
    let mut alone = TileMesh::default();
    push_quad(&mut alone, 0, 0, 4.0);
    push_quad(&mut alone, 1, 0, 4.0);
    assert_round_trip(&alone, 1e-3);
    let mut neg = grid(2, 2, |_, _| 3.0);
    neg.vertices.extend([
        [-1.0, -2.0, 5.0],
        [0.0, -2.0, 5.0],
        [0.0, -1.0, 5.0],
        [-1.0, -1.0, 5.0],
    ]);
    let b = neg.vertices.len() as u32 - 4;
    neg.indices.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
    assert_round_trip(&neg, 1e-3);
}

#[test]
fn a_quad_sharing_its_vertices_with_other_triangles_is_not_split_off() {
    // The four corners look like a quad but a third triangle, overlapping it, uses two of
    // them: not a planar mesh plus quads, so it is stored plain, exactly.
    let mut m = TileMesh::default();
    push_quad(&mut m, 4, 4, 3.0);
    m.vertices.push([4.25, 4.75, 3.0]);
    m.indices.extend([0, 2, 4]);
    let bytes = encode_mesh(&m, &coding(1e-3)).unwrap();
    assert_eq!(bytes[1], 0);
    assert_eq!(decode_mesh(&bytes).unwrap(), m);
}

fn random_mesh() -> impl Strategy<Value = (TileMesh, f64)> {
    (
        2u32..12,
        2u32..12,
        1u32..5,
        proptest::collection::vec(any::<bool>(), 121),
        proptest::collection::vec(any::<bool>(), 121),
        proptest::collection::vec(0.5f32..400.0, 144),
        prop_oneof![Just(1e-5), Just(1e-3), Just(0.1)],
        any::<bool>(),
        proptest::collection::vec((0u32..40, 0u32..40, 0.5f32..400.0), 0..4),
    )
        .prop_map(
            |(nx, ny, spacing, keep, diag, depth, step, smooth, quads)| {
                let mut m = grid_with(
                    nx,
                    ny,
                    spacing as f32,
                    |x, y| {
                        if smooth {
                            3.0 + 0.1 * x as f32 + 0.05 * y as f32
                        } else {
                            depth[(y * 12 + x) as usize]
                        }
                    },
                    |x, y| keep[(y * 11 + x) as usize],
                    |x, y| diag[(y * 11 + x) as usize],
                );
                for (x, y, r) in quads {
                    push_quad(&mut m, x, y, r);
                }
                (m, step)
            },
        )
}

proptest! {
    #[test]
    fn random_meshes_round_trip((m, step) in random_mesh()) {
        assert_round_trip(&m, step);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200), head in any::<bool>()) {
        let mut b = bytes;
        if head && b.len() >= 2 {
            b[..2].copy_from_slice(b"\x04\x01");
        }
        if let Ok(m) = decode_mesh(&b) {
            prop_assert!(m.indices.iter().all(|&i| (i as usize) < m.vertices.len()));
        }
    }

    #[test]
    fn damaged_meshes_never_panic((m, step) in random_mesh(), flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..4), cut in any::<usize>()) {
        let mut b = encode_mesh(&m, &coding(step)).unwrap();
        for (at, x) in flips {
            let i = at % b.len();
            b[i] ^= x.max(1);
        }
        b.truncate(cut % (b.len() + 1));
        if let Ok(m) = decode_mesh(&b) {
            prop_assert!(m.indices.iter().all(|&i| (i as usize) < m.vertices.len()));
            prop_assert!(m.vertices.iter().all(|v| v.iter().all(|c| c.is_finite())));
        }
    }
}

/// The long fuzz run of the mesh decoder:
/// `MESH_FUZZ_CASES=1000000 cargo test --release -p codec --lib mesh_long_fuzz -- --ignored`.
#[test]
#[ignore = "long fuzz run; set MESH_FUZZ_CASES"]
fn mesh_long_fuzz() {
    use proptest::test_runner::{Config, TestRunner};
    let cases = std::env::var("MESH_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000);
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    });
    let strategy = (
        random_mesh(),
        proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
        any::<usize>(),
    );
    runner
        .run(&strategy, |((m, step), flips, cut)| {
            let mut b = encode_mesh(&m, &coding(step)).unwrap();
            if flips.is_empty() {
                let back = decode_mesh(&b).unwrap();
                prop_assert_eq!(canonical(&back).0, canonical(&m).0);
                return Ok(());
            }
            for (at, x) in flips {
                let i = at % b.len();
                b[i] ^= x.max(1);
            }
            b.truncate(cut % (b.len() + 1));
            if let Ok(m) = decode_mesh(&b) {
                prop_assert!(m.indices.iter().all(|&i| (i as usize) < m.vertices.len()));
            }
            Ok(())
        })
        .unwrap();
}
