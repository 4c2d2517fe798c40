//! Compact tile meshes: lattice vertices, connectivity grown edge by edge, depth predicted
//! across triangles and quantised to a bound in pixels of parallax; one adaptive range-coded
//! stream ([`crate::entropy`]).
//!
//! A mesh is vertices `[x, y, r]` (continuous face-pixel coordinates, radial depth in metres;
//! the shape `slabs` produces, vertices on pixel centres) and triangles as vertex index
//! triples. A decoder returns the vertices of a lattice mesh in lattice raster order and
//! every triangle's indices sorted (the renderer draws both sides, so the winding is not
//! kept). Depth error: the decoded `1/r` is within `δ/2` of the encoded one (δ for depths
//! beyond `2/δ` metres, where Q would round to 0), so `δ = 2 e θ / B` bounds the parallax
//! error at baseline `B` to `e` pixels of `θ` radians ([`MeshCoding::for_parallax`]).
//! Positions are exact on pixel centres (u = 1), within 1/16 pixel otherwise.
//!
//! ## Layout (format 4)
//!
//! Varints are LEB128 (7 bits a byte, least significant group first, high bit = more
//! follows); zigzag maps `v` to `2v` (v ≥ 0) or `−2v − 1` (v < 0); floats and integers of
//! fixed width are little-endian.
//!
//! ```text
//! 0  1  version (4)
//! 1  1  lattice unit u: 1 (vertices on pixel centres), 8 (eighths of a pixel) or 0 (plain)
//! 2  …  varint face size N; zigzag varints X0, Y0; varints W, H (the lattice box); varint V
//!       (vertices); varint T (triangles); varint P (pixel quads), and when P > 0 zigzag
//!       varints PX0, PY0 and varints PW, PH (the pixel quads' box); the depth step δ
//!       (1/metres) as two bytes k, m: δ = (256 + m) · 2^(k − 136)
//! then one range-coded stream to the end of the bytes (zeros read past it):
//!   occupancy, triangles, depths, pixel quads (below)
//! ```
//!
//! A mesh is found through a table that says what it is, so it has no magic. The encoder
//! writes the largest δ the two bytes hold that is at most the one asked for, and quantises
//! with it, so the depth bound holds for the δ asked.
//!
//! Format 4 adds the pixel quads to format 2 and drops its magic and f32 δ; a decoder
//! refuses other formats with a request to rebuild the database.
//!
//! A decoder checks before allocating: `1 ≤ N ≤ 2²⁰`, `|X0|, |Y0| ≤ 2⁴⁰`, `W, H ≤ 2¹⁵`,
//! `W·H ≤ 2²⁴` ([`MAX_CELLS`], [`MAX_BOX_SIDE`]), `V ≤ W·H`, `T ≤ 2V`, `V·T ≤ 2²⁸`
//! ([`MAX_WORK`]), `10⁻⁹ ≤ δ ≤ 10⁹`, and with pixel quads `|PX0|, |PY0| ≤ 2⁴⁰`,
//! `1 ≤ PW, PH ≤ 2¹⁵` and `P ≤ min(PW·PH, 2²²)` ([`MAX_QUADS`]).
//!
//! **Occupancy.** The `W × H` lattice cells in raster order, one decision each with the
//! model `occ[ctx]` (16 bits), `ctx = L + 2·UL + 4·U + 8·UR` from the left, upper-left,
//! upper and upper-right cells (1 when inside the box and occupied), until `V` cells are set
//! (no decision after the `V`-th; none when `V = 0`). The set cells are the vertices, in this
//! order; cell `(X, Y)` (relative to the box) is the vertex at face position
//! `x = (X + X0)/u + ½`, `y = (Y + Y0)/u + ½` (computed in f64, stored as f32).
//!
//! **Triangles** (models: `seed[3]`, `rank`, `far` — [`Unsigned`](crate::entropy::Unsigned)s
//! — and `exists[6]`, bits; all fresh per mesh). Let `P(i)` be vertex `i`'s cell and
//! `cross(o, a, b) = (a.x − o.x)(b.y − o.y) − (a.y − o.y)(b.x − o.x)`. A *side* is
//! `(a, b, s)` with `a < b`: the points `p` with `cross(P(a), P(b), P(p))` positive
//! (`s` = left) or negative. A triangle `[a, b, c]` (sorted) has the sides `(a, b, side of
//! c)`, `(b, c, side of a)`, `(a, c, side of b)`; *adding* it marks these three resolved and
//! appends the three opposite sides, in that order, to a queue (FIFO). Until `T` triangles
//! are out:
//!
//! - Queue empty (at the start too): a *seed* `[a, b, c]` as three Unsigneds, `a − a'`
//!   with `seed[0]` (`a'`: the previous seed's `a`, 0 at first), `b − a − 1` with `seed[1]`,
//!   `c − b − 1` with `seed[2]`; it is added. (The encoder seeds with the smallest triangle
//!   not yet out, in the order of sorted triples.)
//! - Else pop a side; skip it when resolved. Its *first box*: the bounding box of `P(a)`,
//!   `P(b)` grown on every side by `max(⌊max(|dx|, |dy|)/2⌋, 1)`; `empty` = no vertex other
//!   than `a`, `b` strictly on the side within it. A decision with
//!   `exists[shape + 3·empty]`, shape 0 for an axis-aligned edge, 1 for a diagonal
//!   (`|dx| = |dy|`), 2 otherwise: 0 marks the side resolved; 1 is a triangle there. Its third
//!   vertex: the *ties* are the vertices strictly on the side seen from the edge at the
//!   largest angle (smallest `dot/|cross|` at the vertex, compared exactly in integers by
//!   cross-multiplying), in index order — empty when no vertex is on the side. An Unsigned
//!   with `rank`, `k`: `k` below the number of ties names the `k`-th; `k` equal to it is
//!   followed by the vertex's index as an Unsigned with `far` (it must lie on the side); the
//!   triangle (sorted) is added. A triangle whose corners are on one line, or that takes a
//!   resolved side, is damage.
//!
//! The triangles come out in this order, each sorted.
//!
//! **Depths.** Per vertex `k` in order the quantised inverse *planar* depth
//! `Q = round((√(1 + U² + V²) / r) / δ)` (f64, δ as written), clamped to
//! 1 ..= 2³¹ − 1, where
//! `U = 2x/N − 1`, `V = 1 − 2y/N` (so `Q` is affine in face pixels over a flat surface), is
//! coded as `Q − pred` with a [`Signed`] model of its own per
//! predictor (four), the prediction from earlier vertices (index below `k`), by the first
//! that applies:
//!
//! 1. *Plane*: over `k`'s triangles in output order, one with two earlier corners `a < b`;
//!    over the (up to two) triangles on edge `a b` in output order, another one whose third
//!    corner `c` is earlier; with `D(o, s, t) = cross(P(o), P(s), P(t))` and
//!    `den = D(a, b, c) ≠ 0`: `pred = Q_a + round((Q_b − Q_a)·D(a, k, c) + (Q_c − Q_a)·D(a, b, k),
//!    den)`, rounding half up (`⌊(2·num + den) / (2·den)⌋` with `den > 0`, signs moved to the
//!    numerator), clamped to 1 ..= 2³¹ − 1. The first such triangle and edge decide.
//! 2. *Edge*: the first of `k`'s triangles with two earlier corners `a < b`:
//!    `⌊(Q_a + Q_b + 1)/2⌋`.
//! 3. *Neighbour*: in the first of `k`'s triangles with an earlier corner, the first such
//!    (smaller index): its `Q`.
//! 4. *Previous*: `Q` of vertex `k − 1`, or 0 for the first.
//!
//! A decoded `Q` outside 1 ..= 2³¹ − 1 is damage; `r = √(1 + U² + V²) / (Q·δ)` (δ as
//! read, in f64), stored as f32.
//!
//! **Pixel quads** (after the depths; nothing when `P = 0`). `slabs` gives an opaque pixel
//! that no triangle covers (a pole or a frame one pixel thin between two discontinuities) a
//! quad of its own: four vertices on the pixel's corners at one radial depth, two triangles.
//! Neighbouring quads share corners at different depths, which no lattice holds, so the
//! encoder splits them off (module `quads`): four consecutive vertices `(x, y, r)`,
//! `(x + 1, y, r)`, `(x + 1, y + 1, r)`, `(x, y + 1, r)` with `x, y` whole, whose only
//! triangles are two over them (either diagonal). The rest must fit the lattice. Coded:
//!
//! - *Mask*: the `PW × PH` pixels of the box in raster order, one decision each with the
//!   model `quad[ctx]` (16 bits, fresh, the occupancy's context rule over the mask) until `P`
//!   are set. Set pixel `(X, Y)` is the quad of pixel `(X + PX0, Y + PY0)`.
//! - *Depths*, per quad in raster order: `Q = round(1 / (r·δ))` (inverse *radial* depth,
//!   clamped to 1 ..= 2³¹ − 1, so every corner keeps one depth) as `Q − pred` with a
//!   [`Signed`] model per predictor, the first that applies: the quad above (pixel
//!   `(x, y − 1)`), the quad to the left, the quad before in raster order, and for the first
//!   quad `round(1 / (r·δ))` of the last lattice vertex as decoded (0 without one).
//!   A decoded `Q` outside 1 ..= 2³¹ − 1 is damage; `r = 1 / (Q·δ)` (f64, stored as f32).
//!
//! A decoder appends each quad after the lattice vertices: its four corners in the order
//! above and the triangles `[0, 1, 2]`, `[0, 2, 3]` over them; the depth bound is the
//! lattice's, `|1/r − 1/r'| ≤ δ/2`.
//!
//! ## Plain layout (lattice unit 0)
//! A mesh the lattice cannot hold once its pixel quads are split off (two vertices at one
//! lattice position, or triangles that are not part of a planar triangulation; no mesh of
//! the built-in scenes or the measured POV-Ray imports) is stored plain and exact:
//!
//! ```text
//! 2  …  varint face size N (1 ..= 2²⁰); varint V (≤ 2²⁴); varint T (≤ 2²⁵);
//!       V × (x, y, r) f32; T × 3 u32 — exactly 12·(V + T) bytes to the end
//! ```
//!
//! Every vertex finite with `r > 0`, every index below `V`.

mod connect;
mod quads;

use crate::entropy::{Bit, Decoder, Encoder, Signed};

pub use quads::MAX_QUADS;
pub use tracks::TileMesh;

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
    #[error("mesh coding: {0}")]
    Coding(String),
    #[error("mesh file: {0}")]
    Format(String),
}

/// The format written and read.
pub const MESH_VERSION: u8 = 4;
/// Most lattice cells a mesh's box may hold (the occupancy is a bit per cell).
pub const MAX_CELLS: u64 = 1 << 24;
/// Most vertices × triangles of a mesh: growing the connectivity scans the vertices on one
/// side of each new edge. A 64² tile with a vertex on every pixel is 4225 × 8192 = 2²⁵.
pub const MAX_WORK: u64 = 1 << 28;
/// Largest face size a mesh may name.
pub const MAX_SIDE: u64 = 1 << 20;
/// Largest side of a mesh's lattice box (keeps the connectivity's integer geometry in 64
/// bits).
pub const MAX_BOX_SIDE: u64 = 1 << 15;

/// How a mesh's depths are quantised, and the face its positions are on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshCoding {
    /// Face size in pixels (the planar depth of a vertex depends on its place in the face).
    pub face_size: u32,
    /// Quantisation step δ of the inverse planar depth, 1/metres.
    pub depth_step: f64,
}

impl MeshCoding {
    /// The step that keeps depth errors within `error_px` pixels of parallax at `baseline_m`
    /// on faces of `face_size` pixels (`θ = (π/2)/N` per pixel; a baseline ≤ 0 counts as
    /// 1 m).
    pub fn for_parallax(face_size: u32, baseline_m: f64, error_px: f64) -> MeshCoding {
        let theta = std::f64::consts::FRAC_PI_2 / face_size.max(1) as f64;
        let b = if baseline_m > 0.0 { baseline_m } else { 1.0 };
        MeshCoding {
            face_size,
            depth_step: 2.0 * error_px * theta / b,
        }
    }
}

/// `|F + uR + vU|` at face position `(x, y)`: radial over planar depth.
fn planar_norm(x: f64, y: f64, face_size: u32) -> f64 {
    let (u, v) = tracks::cubemap::uv_from_pixel_f(x, y, face_size);
    (1.0 + u * u + v * v).sqrt()
}

/// The depth step written (its exponent and mantissa bytes, see the layout) and its value:
/// the largest that two bytes hold and is at most `step` (so the depth bound still holds).
fn step_code(step: f64) -> ([u8; 2], f64) {
    let mut e = step.log2().floor() as i32;
    while 2f64.powi(e) > step {
        e -= 1;
    }
    while 2f64.powi(e + 1) <= step {
        e += 1;
    }
    let k = (e + 128).clamp(0, 255);
    let m = ((step / 2f64.powi(k - 128) - 1.0) * 256.0)
        .floor()
        .clamp(0.0, 255.0) as u8;
    let code = [k as u8, m];
    (code, step_value(code))
}

/// `δ = (256 + m) · 2^(k − 136)` for the bytes `[k, m]`.
fn step_value([k, m]: [u8; 2]) -> f64 {
    (256 + m as i32) as f64 * 2f64.powi(k as i32 - 136)
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// The inverse of [`zigzag`].
fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

/// Context of a cell's occupancy bit.
fn occupancy_ctx(cells: &[bool], w: usize, i: usize) -> usize {
    let (x, y) = (i % w, i / w);
    let at = |ok: bool, k: usize| usize::from(ok && cells[k]);
    at(x > 0, i.wrapping_sub(1))
        | at(x > 0 && y > 0, i.wrapping_sub(w + 1)) << 1
        | at(y > 0, i.wrapping_sub(w)) << 2
        | at(y > 0 && x + 1 < w, i.wrapping_sub(w).wrapping_add(1)) << 3
}

/// The depth predictors, in order of preference (each has its own residual model).
#[derive(Clone, Copy)]
enum Predictor {
    Plane = 0,
    Edge = 1,
    Neighbour = 2,
    Previous = 3,
}

/// Rounded `num / den` (`den ≠ 0`).
fn div_round(num: i128, den: i128) -> i128 {
    let (n, d) = if den < 0 { (-num, -den) } else { (num, den) };
    (2 * n + d).div_euclid(2 * d)
}

/// The prediction of vertex `v`'s quantised depth from the earlier vertices' `q`.
fn predict(
    v: usize,
    pts: &[connect::Pt],
    q: &[i64],
    tris: &[[u32; 3]],
    adj: &Adjacency,
) -> (i64, Predictor) {
    let mut edge = None;
    let mut neighbour = None;
    let incident = &adj.incident[adj.first[v] as usize..adj.first[v + 1] as usize];
    for &ti in incident {
        let t = tris[ti as usize];
        let mut others = t.into_iter().filter(|&p| p as usize != v);
        let (a, b) = match (others.next(), others.next()) {
            (Some(a), Some(b)) => (a, b),
            _ => continue,
        };
        let both = (a as usize) < v && (b as usize) < v;
        if neighbour.is_none() {
            neighbour = [a, b].into_iter().map(|p| p as usize).find(|&p| p < v);
        }
        if !both {
            continue;
        }
        if edge.is_none() {
            edge = Some((a as usize, b as usize));
        }
        let Some(pair) = adj.across.get(&(a.min(b), a.max(b))) else {
            continue;
        };
        for &tj in pair {
            if tj == ti || tj == u32::MAX {
                continue;
            }
            let Some(c) = tris[tj as usize]
                .into_iter()
                .find(|&p| p != a && p != b)
                .map(|c| c as usize)
                .filter(|&c| c < v)
            else {
                continue;
            };
            let (pa, pb, pc, pv) = (pts[a as usize], pts[b as usize], pts[c], pts[v]);
            let d = |o: connect::Pt, s: connect::Pt, t: connect::Pt| {
                (s.0 - o.0) as i128 * (t.1 - o.1) as i128
                    - (s.1 - o.1) as i128 * (t.0 - o.0) as i128
            };
            let den = d(pa, pb, pc);
            if den == 0 {
                continue;
            }
            let (qa, qb, qc) = (q[a as usize] as i128, q[b as usize] as i128, q[c] as i128);
            let num = (qb - qa) * d(pa, pv, pc) + (qc - qa) * d(pa, pb, pv);
            let pred = qa + div_round(num, den);
            return (pred.clamp(1, i32::MAX as i128) as i64, Predictor::Plane);
        }
    }
    if let Some((a, b)) = edge {
        return ((q[a] + q[b] + 1) / 2, Predictor::Edge);
    }
    if let Some(a) = neighbour {
        return (q[a], Predictor::Neighbour);
    }
    (if v > 0 { q[v - 1] } else { 0 }, Predictor::Previous)
}

/// Per vertex the triangles using it, and per edge the (up to two) triangles on it.
struct Adjacency {
    /// `incident[first[v]..first[v + 1]]`: the triangles using vertex `v`, in order.
    first: Vec<u32>,
    incident: Vec<u32>,
    across: foldhash::HashMap<(u32, u32), [u32; 2]>,
}

fn adjacency(vertices: usize, tris: &[[u32; 3]]) -> Adjacency {
    use foldhash::HashMapExt;
    let mut first = vec![0u32; vertices + 1];
    for t in tris {
        for &p in t {
            first[p as usize + 1] += 1;
        }
    }
    for v in 0..vertices {
        first[v + 1] += first[v];
    }
    let mut fill = first.clone();
    let mut incident = vec![0u32; 3 * tris.len()];
    let mut across: foldhash::HashMap<(u32, u32), [u32; 2]> =
        foldhash::HashMap::with_capacity(3 * tris.len());
    for (ti, t) in tris.iter().enumerate() {
        for &p in t {
            incident[fill[p as usize] as usize] = ti as u32;
            fill[p as usize] += 1;
        }
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[0], t[2])] {
            let e = across.entry((a.min(b), a.max(b))).or_insert([u32::MAX; 2]);
            if e[0] == u32::MAX {
                e[0] = ti as u32;
            } else {
                e[1] = ti as u32;
            }
        }
    }
    Adjacency {
        first,
        incident,
        across,
    }
}

/// Encodes a mesh: vertices finite with depth > 0, indices in range. On the lattice when no
/// two vertices share a lattice position and the triangles are part of a planar
/// triangulation once the pixel quads are split off; plain (exact, larger) otherwise.
pub fn encode_mesh(mesh: &TileMesh, coding: &MeshCoding) -> Result<Vec<u8>, MeshError> {
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
    let step = coding.depth_step;
    if !(1e-9..=1e9).contains(&step) || coding.face_size == 0 || coding.face_size as u64 > MAX_SIDE
    {
        return Err(MeshError::Coding(format!(
            "depth step {step} (1e-9 to 1e9 per metre) on faces of {} pixels",
            coding.face_size
        )));
    }
    for (index, v) in mesh.vertices.iter().enumerate() {
        if !(v.iter().all(|c| c.is_finite()) && v[2] > 0.0) {
            return Err(MeshError::BadVertex {
                index,
                message: format!("{v:?} (needs finite x, y and depth > 0)"),
            });
        }
    }
    let (rest, pixel_quads) = quads::split(mesh);
    encode_lattice(&rest, &pixel_quads, coding).or_else(|_| encode_plain(mesh, coding))
}

/// The plain layout (lattice unit 0), exact: for meshes the lattice cannot hold.
fn encode_plain(mesh: &TileMesh, coding: &MeshCoding) -> Result<Vec<u8>, MeshError> {
    let (n, tris) = (mesh.vertices.len() as u64, mesh.indices.len() as u64 / 3);
    check_plain_counts(n, tris).map_err(MeshError::Coding)?;
    let mut out = Vec::with_capacity(32 + 12 * (n + tris) as usize);
    out.push(MESH_VERSION);
    out.push(0);
    put_varint(&mut out, coding.face_size as u64);
    put_varint(&mut out, n);
    put_varint(&mut out, tris);
    for v in &mesh.vertices {
        for c in v {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in &mesh.indices {
        out.extend_from_slice(&i.to_le_bytes());
    }
    Ok(out)
}

/// The plain layout's counts against the limits.
fn check_plain_counts(vertices: u64, triangles: u64) -> Result<(), String> {
    if vertices > MAX_CELLS || triangles > 2 * MAX_CELLS {
        return Err(format!(
            "{vertices} vertices and {triangles} triangles (at most {MAX_CELLS} and {})",
            2 * MAX_CELLS
        ));
    }
    Ok(())
}

/// Decodes the plain layout after its first 2 bytes.
fn decode_plain(b: &[u8]) -> Result<TileMesh, MeshError> {
    let fmt = |m: String| MeshError::Format(m);
    let mut hd = Header { b, at: 2 };
    let face_size = hd.varint("face size")?;
    let n = hd.varint("vertex count")?;
    let tris = hd.varint("triangle count")?;
    if face_size == 0 || face_size > MAX_SIDE {
        return Err(fmt(format!("face size {face_size}")));
    }
    check_plain_counts(n, tris).map_err(fmt)?;
    let body = &b[hd.at..];
    let want = 12 * (n + tris);
    if body.len() as u64 != want {
        return Err(fmt(format!(
            "{} bytes after the header of a plain mesh of {n} vertices and {tris} triangles \
             (needs {want})",
            body.len()
        )));
    }
    let word = |k: usize| {
        [
            body[4 * k],
            body[4 * k + 1],
            body[4 * k + 2],
            body[4 * k + 3],
        ]
    };
    let n = n as usize;
    let mut vertices = Vec::with_capacity(n);
    for k in 0..n {
        let v = [0, 1, 2].map(|c| f32::from_le_bytes(word(3 * k + c)));
        if !(v.iter().all(|c| c.is_finite()) && v[2] > 0.0) {
            return Err(fmt(format!(
                "vertex {k}: {v:?} (needs finite x, y and depth > 0)"
            )));
        }
        vertices.push(v);
    }
    let indices: Vec<u32> = (0..3 * tris as usize)
        .map(|k| u32::from_le_bytes(word(3 * n + k)))
        .collect();
    if let Some((at, &i)) = indices.iter().enumerate().find(|(_, &i)| i as usize >= n) {
        return Err(MeshError::BadIndex {
            at,
            index: i,
            count: n,
        });
    }
    Ok(TileMesh { vertices, indices })
}

/// The lattice layout: compact, for vertices on distinct lattice positions of a planar
/// triangulation (what `slabs` meshes are, apart from the quads of uncovered pixels).
fn encode_lattice(
    mesh: &TileMesh,
    pixel_quads: &[quads::PixelQuad],
    coding: &MeshCoding,
) -> Result<Vec<u8>, MeshError> {
    let n = mesh.vertices.len();
    let step = coding.depth_step;
    // The lattice: pixel centres when every vertex is on one, else eighths of a pixel.
    let on_centres = mesh
        .vertices
        .iter()
        .all(|v| (v[0] - 0.5).fract() == 0.0 && (v[1] - 0.5).fract() == 0.0);
    let unit: i64 = if on_centres { 1 } else { 8 };
    let lattice: Vec<connect::Pt> = mesh
        .vertices
        .iter()
        .map(|v| {
            let l = |c: f32| ((c as f64 - 0.5) * unit as f64).round() as i64;
            (l(v[0]), l(v[1]))
        })
        .collect();
    let (x0, y0) = lattice
        .iter()
        .fold((i64::MAX, i64::MAX), |(a, b), p| (a.min(p.0), b.min(p.1)));
    let (x1, y1) = lattice
        .iter()
        .fold((i64::MIN, i64::MIN), |(a, b), p| (a.max(p.0), b.max(p.1)));
    let (x0, y0, w, h) = if n == 0 {
        (0, 0, 0u64, 0u64)
    } else {
        (x0, y0, (x1 - x0 + 1) as u64, (y1 - y0 + 1) as u64)
    };
    let tris = mesh.indices.len() as u64 / 3;
    check_counts(w, h, n as u64, tris).map_err(MeshError::Coding)?;
    let quad_box = quads::QuadBox::around(pixel_quads).map_err(MeshError::Coding)?;
    // Vertices in raster order.
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by_key(|&i| (lattice[i].1, lattice[i].0));
    for pair in order.windows(2) {
        if lattice[pair[0]] == lattice[pair[1]] {
            return Err(MeshError::BadVertex {
                index: pair[1],
                message: format!(
                    "at the lattice position of vertex {} (one vertex per position)",
                    pair[0]
                ),
            });
        }
    }
    let mut new_index = vec![0u32; n];
    for (k, &i) in order.iter().enumerate() {
        new_index[i] = k as u32;
    }
    let pts: Vec<connect::Pt> = order
        .iter()
        .map(|&i| (lattice[i].0 - x0, lattice[i].1 - y0))
        .collect();

    let mut out = Vec::with_capacity(64 + 4 * n);
    out.push(MESH_VERSION);
    out.push(unit as u8);
    put_varint(&mut out, coding.face_size as u64);
    put_varint(&mut out, zigzag(x0));
    put_varint(&mut out, zigzag(y0));
    put_varint(&mut out, w);
    put_varint(&mut out, h);
    put_varint(&mut out, n as u64);
    put_varint(&mut out, tris);
    quad_box.put(&mut out);
    let (code, step) = step_code(step);
    out.extend_from_slice(&code);

    let mut e = Encoder::new();
    let mut occupied = vec![false; (w * h) as usize];
    for p in &pts {
        occupied[(p.1 as u64 * w + p.0 as u64) as usize] = true;
    }
    let mut ctx = [Bit::new(); 16];
    let mut seen = 0;
    for i in 0..occupied.len() {
        if seen == n {
            break;
        }
        let c = occupancy_ctx(&occupied, w as usize, i);
        e.bit(&mut ctx[c], occupied[i]);
        seen += usize::from(occupied[i]);
    }
    let triangles: Vec<[u32; 3]> = mesh
        .indices
        .chunks_exact(3)
        .map(|t| {
            [
                new_index[t[0] as usize],
                new_index[t[1] as usize],
                new_index[t[2] as usize],
            ]
        })
        .collect();
    let grown = connect::encode(&mut e, &pts, &triangles)?;
    let adj = adjacency(n, &grown);
    let mut q = vec![0i64; n];
    let mut models: [Signed; 4] = Default::default();
    for (k, &i) in order.iter().enumerate() {
        let (x, y) = position(pts[k], x0, y0, unit);
        let planar = planar_norm(x as f64, y as f64, coding.face_size) / mesh.vertices[i][2] as f64;
        q[k] = ((planar / step).round() as i64).clamp(1, i32::MAX as i64);
        let (pred, how) = predict(k, &pts, &q, &grown, &adj);
        models[how as usize].encode(&mut e, (q[k] - pred) as i32);
    }
    // The last vertex's depth as the decoder rebuilds it: the first quad's is predicted from it.
    let last_r = (n > 0).then(|| {
        let (x, y) = position(pts[n - 1], x0, y0, unit);
        (planar_norm(x as f64, y as f64, coding.face_size) / (q[n - 1] as f64 * step)) as f32
    });
    quads::encode(&mut e, &quad_box, pixel_quads, last_r, step);
    out.extend_from_slice(&e.finish());
    Ok(out)
}

/// Face position of lattice point `p` (relative to the box corner `(x0, y0)`).
fn position(p: connect::Pt, x0: i64, y0: i64, unit: i64) -> (f32, f32) {
    let c = |l: i64| (l as f64 / unit as f64 + 0.5) as f32;
    (c(p.0 + x0), c(p.1 + y0))
}

/// The header's counts against the limits.
fn check_counts(w: u64, h: u64, vertices: u64, triangles: u64) -> Result<(), String> {
    if w > MAX_BOX_SIDE || h > MAX_BOX_SIDE || w * h > MAX_CELLS {
        return Err(format!(
            "a lattice box of {w} × {h} cells (at most {MAX_CELLS} cells, {MAX_BOX_SIDE} a side)"
        ));
    }
    if vertices > w * h {
        return Err(format!("{vertices} vertices in {} lattice cells", w * h));
    }
    if triangles > 2 * vertices {
        return Err(format!(
            "{triangles} triangles over {vertices} vertices (a planar mesh has at most twice as many)"
        ));
    }
    if vertices * triangles > MAX_WORK {
        return Err(format!(
            "{vertices} vertices × {triangles} triangles exceed {MAX_WORK} (use smaller tiles)"
        ));
    }
    Ok(())
}

/// A cursor over the header.
pub(super) struct Header<'a> {
    b: &'a [u8],
    at: usize,
}

impl Header<'_> {
    pub(super) fn varint(&mut self, what: &str) -> Result<u64, MeshError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let byte = *self
                .b
                .get(self.at)
                .ok_or_else(|| MeshError::Format(format!("ends inside the header ({what})")))?;
            self.at += 1;
            v |= ((byte & 0x7f) as u64).checked_shl(shift).unwrap_or(0);
            if byte & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(MeshError::Format(format!("{what}: varint too long")))
    }
}

/// Decodes a mesh; every count is checked against the limits before allocating.
pub fn decode_mesh(b: &[u8]) -> Result<TileMesh, MeshError> {
    let fmt = |m: String| MeshError::Format(m);
    if b.len() < 2 {
        return Err(fmt(format!(
            "{} bytes, shorter than any mesh header",
            b.len()
        )));
    }
    if b[0] != MESH_VERSION {
        return Err(fmt(format!(
            "format {} (this build reads format {MESH_VERSION}; rebuild the database with `railview build`)",
            b[0]
        )));
    }
    let unit = match b[1] {
        0 => return decode_plain(b),
        u @ (1 | 8) => u as i64,
        u => return Err(fmt(format!("lattice unit {u} (0, 1 or 8)"))),
    };
    let mut hd = Header { b, at: 2 };
    let face_size = hd.varint("face size")?;
    let x0 = unzigzag(hd.varint("x0")?);
    let y0 = unzigzag(hd.varint("y0")?);
    let w = hd.varint("box width")?;
    let h = hd.varint("box height")?;
    let n = hd.varint("vertex count")?;
    let tris = hd.varint("triangle count")?;
    let quad_box = quads::QuadBox::read(&mut hd)?;
    if face_size == 0 || face_size > MAX_SIDE {
        return Err(fmt(format!("face size {face_size}")));
    }
    let lim = 1i64 << 40;
    if !(-lim..=lim).contains(&x0) || !(-lim..=lim).contains(&y0) {
        return Err(fmt(format!("box corner ({x0}, {y0}) out of range")));
    }
    check_counts(w, h, n, tris).map_err(fmt)?;
    let step_bytes = b
        .get(hd.at..hd.at + 2)
        .ok_or_else(|| fmt("ends inside the header (depth step)".into()))?;
    let step = step_value([step_bytes[0], step_bytes[1]]);
    if !(1e-9..=1e9).contains(&step) {
        return Err(fmt(format!("depth step {step}")));
    }
    let mut d = Decoder::new(&b[hd.at + 2..]);
    let n = n as usize;
    let cells = (w * h) as usize;
    let mut occupied = vec![false; cells];
    let mut pts = Vec::with_capacity(n);
    let mut ctx = [Bit::new(); 16];
    for i in 0..cells {
        if pts.len() == n {
            break;
        }
        let c = occupancy_ctx(&occupied, w as usize, i);
        if d.bit(&mut ctx[c]) {
            occupied[i] = true;
            pts.push(((i as u64 % w) as i64, (i as u64 / w) as i64));
        }
    }
    if pts.len() < n {
        return Err(fmt(format!(
            "occupancy holds {} of {n} vertices",
            pts.len()
        )));
    }
    let grown = connect::decode(&mut d, &pts, tris as usize)?;
    let adj = adjacency(n, &grown);
    let mut q = vec![0i64; n];
    let mut models: [Signed; 4] = Default::default();
    let mut vertices = Vec::with_capacity(n);
    for k in 0..n {
        let (pred, how) = predict(k, &pts, &q, &grown, &adj);
        let v = pred + models[how as usize].decode(&mut d) as i64;
        if !(1..=i32::MAX as i64).contains(&v) {
            return Err(fmt(format!("vertex {k}: quantised depth {v} out of range")));
        }
        q[k] = v;
        let (x, y) = position(pts[k], x0, y0, unit);
        let r = planar_norm(x as f64, y as f64, face_size as u32) / (v as f64 * step);
        vertices.push([x, y, r as f32]);
    }
    let mut mesh = TileMesh {
        vertices,
        indices: grown.into_iter().flatten().collect(),
    };
    let last_r = mesh.vertices.last().map(|v| v[2]);
    let pixel_quads = quads::decode(&mut d, &quad_box, last_r, step)?;
    quads::append(&mut mesh, &pixel_quads);
    Ok(mesh)
}

#[cfg(test)]
mod tests;
