//! Compact binary tile meshes with quantised depth.
//!
//! A mesh is vertices `[x, y, r]` (continuous face-pixel coordinates, radial depth in metres;
//! the shape `slabs` produces) and triangles as vertex index triples. Layout, little endian:
//!
//! ```text
//! 0   4  magic "RMSH"
//! 4   1  version (1)
//! 5   1  flags: bit 0 = indices are u32 (else u16); other bits zero
//! 6   2  zero
//! 8   4  vertex count V (u32)
//! 12  4  triangle count T (u32)
//! 16  4  x0 (f32): smallest x          20  4  y0 (f32): smallest y
//! 24  4  d_near = 1 / smallest r (f32) 28  4  d_far = 1 / largest r (f32)
//! 32  6V vertices: qx, qy, qd (u16 each)
//!          x = x0 + qx / 8, y = y0 + qy / 8        (1/8 pixel; pixel centres are exact)
//!          1/r = d_far + qd / 65535 · (d_near − d_far)   (depth quantised in disparity, so the
//!          error is uniform in parallax: at most (d_near − d_far) / 131070 in 1/r)
//! then   3T indices, u16 or u32
//! ```
//! 18 bytes per triangle-ish instead of 36 for `[f32; 3]` vertices with u32 indices. A mesh
//! may span at most 8191 pixels in x and y.

/// Mesh vertices and triangles (the decoded form).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshData {
    pub vertices: Vec<[f32; 3]>,
    pub indices: Vec<u32>,
}

/// Why a mesh could not be encoded or decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    #[error("mesh vertex {index}: {message}")]
    BadVertex { index: usize, message: String },
    #[error("mesh has {0} indices, not a multiple of 3")]
    Ragged(usize),
    #[error("mesh index {index} at position {at} ≥ vertex count {count}")]
    BadIndex { at: usize, index: u32, count: usize },
    #[error("mesh file: {0}")]
    Format(String),
}

const MAGIC: [u8; 4] = *b"RMSH";
const HEADER: usize = 32;
const XY_STEPS: f32 = 8.0;

/// Encodes a mesh.
pub fn encode_mesh(mesh: &MeshData) -> Result<Vec<u8>, MeshError> {
    if !mesh.indices.len().is_multiple_of(3) {
        return Err(MeshError::Ragged(mesh.indices.len()));
    }
    let n = mesh.vertices.len();
    for (at, &i) in mesh.indices.iter().enumerate() {
        if i as usize >= n {
            return Err(MeshError::BadIndex {
                at,
                index: i,
                count: n,
            });
        }
    }
    let (mut x0, mut y0, mut rmin, mut rmax) = (f32::MAX, f32::MAX, f32::MAX, 0f32);
    for (index, v) in mesh.vertices.iter().enumerate() {
        if !(v.iter().all(|c| c.is_finite()) && v[2] > 0.0) {
            return Err(MeshError::BadVertex {
                index,
                message: format!("{v:?} (needs finite x, y and depth > 0)"),
            });
        }
        x0 = x0.min(v[0]);
        y0 = y0.min(v[1]);
        rmin = rmin.min(v[2]);
        rmax = rmax.max(v[2]);
    }
    if n == 0 {
        (x0, y0, rmin, rmax) = (0.0, 0.0, 1.0, 1.0);
    }
    let (d_near, d_far) = (1.0 / rmin, 1.0 / rmax);
    let u32_indices = n > 65_536;
    let tris = mesh.indices.len() / 3;
    let mut out =
        Vec::with_capacity(HEADER + 6 * n + mesh.indices.len() * if u32_indices { 4 } else { 2 });
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&[1, u32_indices as u8, 0, 0]);
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&(tris as u32).to_le_bytes());
    for f in [x0, y0, d_near, d_far] {
        out.extend_from_slice(&f.to_le_bytes());
    }
    for (index, v) in mesh.vertices.iter().enumerate() {
        let q = |d: f32| -> Result<u16, MeshError> {
            let s = (d * XY_STEPS).round();
            if s > u16::MAX as f32 {
                return Err(MeshError::BadVertex {
                    index,
                    message: format!("{v:?} lies more than 8191 pixels from the mesh's corner"),
                });
            }
            Ok(s as u16)
        };
        let qd = if d_near > d_far {
            ((1.0 / v[2] - d_far) / (d_near - d_far) * 65_535.0)
                .round()
                .clamp(0.0, 65_535.0) as u16
        } else {
            0
        };
        out.extend_from_slice(&q(v[0] - x0)?.to_le_bytes());
        out.extend_from_slice(&q(v[1] - y0)?.to_le_bytes());
        out.extend_from_slice(&qd.to_le_bytes());
    }
    for &i in &mesh.indices {
        if u32_indices {
            out.extend_from_slice(&i.to_le_bytes());
        } else {
            out.extend_from_slice(&(i as u16).to_le_bytes());
        }
    }
    Ok(out)
}

/// Decodes a mesh; every count is checked against the buffer length before allocating.
pub fn decode_mesh(b: &[u8]) -> Result<MeshData, MeshError> {
    let fmt = |m: String| MeshError::Format(m);
    if b.len() < HEADER {
        return Err(fmt(format!(
            "{} bytes, shorter than the {HEADER}-byte header",
            b.len()
        )));
    }
    if b[0..4] != MAGIC {
        return Err(fmt("bad magic (not a railview mesh)".into()));
    }
    if b[4] != 1 {
        return Err(fmt(format!("unsupported version {}", b[4])));
    }
    if b[5] > 1 || b[6] != 0 || b[7] != 0 {
        return Err(fmt("unknown flags".into()));
    }
    let u32_indices = b[5] == 1;
    let rd = |at: usize| [b[at], b[at + 1], b[at + 2], b[at + 3]];
    let n = u32::from_le_bytes(rd(8)) as u64;
    let tris = u32::from_le_bytes(rd(12)) as u64;
    let [x0, y0, d_near, d_far] = [16, 20, 24, 28].map(|at| f32::from_le_bytes(rd(at)));
    let expected = HEADER as u64 + 6 * n + 3 * tris * if u32_indices { 4 } else { 2 };
    if b.len() as u64 != expected {
        return Err(fmt(format!(
            "{} bytes, but {n} vertices and {tris} triangles need {expected}",
            b.len()
        )));
    }
    if !(x0.is_finite() && y0.is_finite() && d_near.is_finite() && d_far > 0.0 && d_near >= d_far) {
        return Err(fmt(format!(
            "bad ranges x0 {x0} y0 {y0} disparity {d_far}..{d_near}"
        )));
    }
    let n = n as usize;
    let u16_at = |at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
    let vertices = (0..n)
        .map(|i| {
            let at = HEADER + 6 * i;
            let d = d_far + u16_at(at + 4) as f32 / 65_535.0 * (d_near - d_far);
            [
                x0 + u16_at(at) as f32 / XY_STEPS,
                y0 + u16_at(at + 2) as f32 / XY_STEPS,
                1.0 / d,
            ]
        })
        .collect();
    let start = HEADER + 6 * n;
    let mut indices = Vec::with_capacity(3 * tris as usize);
    for k in 0..3 * tris as usize {
        let i = if u32_indices {
            u32::from_le_bytes(rd(start + 4 * k))
        } else {
            u16_at(start + 2 * k) as u32
        };
        if i as usize >= n {
            return Err(MeshError::BadIndex {
                at: k,
                index: i,
                count: n,
            });
        }
        indices.push(i);
    }
    Ok(MeshData { vertices, indices })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn grid(nx: u32, ny: u32, depth: impl Fn(u32, u32) -> f32) -> MeshData {
        let mut m = MeshData::default();
        for y in 0..ny {
            for x in 0..nx {
                m.vertices
                    .push([100.5 + x as f32 * 4.0, 36.5 + y as f32 * 4.0, depth(x, y)]);
            }
        }
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let i = y * nx + x;
                m.indices
                    .extend_from_slice(&[i, i + 1, i + nx, i + 1, i + nx + 1, i + nx]);
            }
        }
        m
    }

    #[test]
    fn pixel_centres_are_exact_and_depth_error_is_bounded_in_disparity() {
        let m = grid(9, 9, |x, y| 2.0 + (x * 9 + y) as f32 * 10.0);
        let bytes = encode_mesh(&m).unwrap();
        assert_eq!(bytes.len(), 32 + 6 * 81 + 2 * m.indices.len());
        let back = decode_mesh(&bytes).unwrap();
        assert_eq!(back.indices, m.indices);
        let (dn, df) = (1.0 / 2.0f32, 1.0 / 802.0f32);
        for (a, b) in m.vertices.iter().zip(&back.vertices) {
            assert_eq!((a[0], a[1]), (b[0], b[1]));
            assert!(
                (1.0 / a[2] - 1.0 / b[2]).abs() <= (dn - df) / 131_070.0 * 1.01 + 1e-7,
                "{a:?} {b:?}"
            );
        }
    }

    #[test]
    fn flat_empty_and_large_meshes() {
        let flat = grid(3, 2, |_, _| 5.0);
        assert_eq!(decode_mesh(&encode_mesh(&flat).unwrap()).unwrap(), flat);
        let empty = MeshData::default();
        assert_eq!(decode_mesh(&encode_mesh(&empty).unwrap()).unwrap(), empty);
        let big = MeshData {
            vertices: (0..70_000)
                .map(|i| [(i % 256) as f32 + 0.5, (i / 256) as f32 + 0.5, 3.0])
                .collect(),
            indices: vec![0, 1, 69_999],
        };
        let bytes = encode_mesh(&big).unwrap();
        assert_eq!(bytes[5], 1);
        assert_eq!(decode_mesh(&bytes).unwrap(), big);
    }

    #[test]
    fn bad_meshes_are_refused() {
        let mut m = grid(2, 2, |_, _| 1.0);
        m.indices.push(0);
        assert_eq!(encode_mesh(&m), Err(MeshError::Ragged(7)));
        m.indices.extend_from_slice(&[0, 9]);
        assert!(matches!(
            encode_mesh(&m),
            Err(MeshError::BadIndex { index: 9, .. })
        ));
        let mut m = grid(2, 2, |_, _| 1.0);
        m.vertices[1][2] = f32::INFINITY;
        assert!(matches!(
            encode_mesh(&m),
            Err(MeshError::BadVertex { index: 1, .. })
        ));
        m.vertices[1] = [1e5, 0.0, 1.0];
        assert!(matches!(
            encode_mesh(&m),
            Err(MeshError::BadVertex { index: 1, .. })
        ));
        let good = encode_mesh(&grid(2, 2, |x, _| 1.0 + x as f32)).unwrap();
        let mut bad = good.clone();
        *bad.last_mut().unwrap() = 9; // index 2304+ > 4 vertices
        assert!(matches!(decode_mesh(&bad), Err(MeshError::BadIndex { .. })));
        let mut bad = good.clone();
        bad[8] = 0xff; // vertex count no longer matches the length
        assert!(matches!(decode_mesh(&bad), Err(MeshError::Format(_))));
        assert!(matches!(
            decode_mesh(&good[..31]),
            Err(MeshError::Format(_))
        ));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200), head in any::<bool>()) {
            let mut b = bytes;
            if head && b.len() >= 8 {
                b[..8].copy_from_slice(&[b'R', b'M', b'S', b'H', 1, 0, 0, 0]);
            }
            if let Ok(m) = decode_mesh(&b) {
                prop_assert!(m.indices.iter().all(|&i| (i as usize) < m.vertices.len()));
            }
        }
    }
}
