//! Pixel quads: the quads `slabs` gives opaque pixels that no triangle covers (a pole or a
//! frame one pixel thin between two depth discontinuities), split off a mesh so that the rest
//! fits the lattice, and coded as a pixel mask plus one depth each.
//!
//! A pixel quad of pixel `(x, y)` at radial depth `r` is four vertices at the pixel's corners,
//! `(x, y, r)`, `(x + 1, y, r)`, `(x + 1, y + 1, r)`, `(x, y + 1, r)` in this order, and the
//! triangles `[0, 1, 2]` and `[0, 2, 3]` over them; no other triangle uses its vertices.

use super::TileMesh;
use crate::entropy::{Bit, Decoder, Encoder, Signed};

/// A pixel quad: the pixel's top-left corner and its radial depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct PixelQuad {
    pub x: i64,
    pub y: i64,
    pub r: f32,
}

/// Splits the pixel quads off `mesh` (four consecutive vertices in the order above whose only
/// triangles are the quad's two, either diagonal): the rest of the mesh, re-indexed in the
/// order it had, and the quads in raster order of their pixels.
pub(super) fn split(mesh: &TileMesh) -> (TileMesh, Vec<PixelQuad>) {
    let n = mesh.vertices.len();
    let mut users: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (t, tri) in mesh.indices.chunks_exact(3).enumerate() {
        for &i in tri {
            let list = &mut users[i as usize];
            if list.last() != Some(&(t as u32)) {
                list.push(t as u32);
            }
        }
    }
    let tri = |t: u32| {
        let mut s = [0u32; 3];
        s.copy_from_slice(&mesh.indices[3 * t as usize..3 * t as usize + 3]);
        s.sort_unstable();
        s
    };
    let mut quad_vertex = vec![false; n];
    let mut quad_tri = vec![false; mesh.indices.len() / 3];
    let mut quads = Vec::new();
    let mut b = 0;
    while b + 4 <= n {
        let v = &mesh.vertices[b..b + 4];
        let (x, y, r) = (v[0][0], v[0][1], v[0][2]);
        let corners = x.fract() == 0.0
            && y.fract() == 0.0
            && x.abs() < 1e7
            && y.abs() < 1e7
            && v[1] == [x + 1.0, y, r]
            && v[2] == [x + 1.0, y + 1.0, r]
            && v[3] == [x, y + 1.0, r];
        let mut ts: Vec<u32> = (b..b + 4).flat_map(|i| users[i].iter().copied()).collect();
        ts.sort_unstable();
        ts.dedup();
        // Relative to the first corner (a triangle with a vertex below it wraps to a large
        // index and matches no pair).
        let rel = |t: u32| tri(t).map(|i| i.wrapping_sub(b as u32));
        let square = ts.len() == 2 && {
            let pair = [rel(ts[0]), rel(ts[1])];
            // Either diagonal: 0–2 ([0,1,2] + [0,2,3]) or 1–3 ([0,1,3] + [1,2,3]).
            pair == [[0, 1, 2], [0, 2, 3]] || pair == [[0, 1, 3], [1, 2, 3]]
        };
        if corners && square {
            quad_vertex[b..b + 4].fill(true);
            for &t in &ts {
                quad_tri[t as usize] = true;
            }
            quads.push(PixelQuad {
                x: x as i64,
                y: y as i64,
                r,
            });
            b += 4;
        } else {
            b += 1;
        }
    }
    if quads.is_empty() {
        return (mesh.clone(), quads);
    }
    let mut new_index = vec![u32::MAX; n];
    let mut vertices = Vec::with_capacity(n - 4 * quads.len());
    for (i, v) in mesh.vertices.iter().enumerate() {
        if !quad_vertex[i] {
            new_index[i] = vertices.len() as u32;
            vertices.push(*v);
        }
    }
    let indices = mesh
        .indices
        .chunks_exact(3)
        .enumerate()
        .filter(|(t, _)| !quad_tri[*t])
        .flat_map(|(_, tri)| tri.iter().map(|&i| new_index[i as usize]))
        .collect();
    quads.sort_by_key(|q| (q.y, q.x));
    (TileMesh { vertices, indices }, quads)
}

/// Appends the quads to `mesh` in the order [`split`] reads them.
pub(super) fn append(mesh: &mut TileMesh, quads: &[PixelQuad]) {
    for q in quads {
        let base = mesh.vertices.len() as u32;
        let (x, y) = (q.x as f32, q.y as f32);
        mesh.vertices.extend([
            [x, y, q.r],
            [x + 1.0, y, q.r],
            [x + 1.0, y + 1.0, q.r],
            [x, y + 1.0, q.r],
        ]);
        mesh.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }
}

/// The box of the quads' pixels in the header: varint `P` (quads), then, when `P > 0`,
/// zigzag varints `PX0`, `PY0` and varints `PW`, `PH`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct QuadBox {
    pub count: u64,
    pub x0: i64,
    pub y0: i64,
    pub w: u64,
    pub h: u64,
}

/// Most pixel quads of a mesh (each is four vertices: the decoded mesh stays within
/// [`MAX_CELLS`](super::MAX_CELLS) vertices).
pub const MAX_QUADS: u64 = super::MAX_CELLS / 4;

impl QuadBox {
    /// The box of `quads` (in raster order); two quads at one pixel are refused.
    pub fn around(quads: &[PixelQuad]) -> Result<QuadBox, String> {
        let Some(first) = quads.first() else {
            return Ok(QuadBox {
                count: 0,
                x0: 0,
                y0: 0,
                w: 0,
                h: 0,
            });
        };
        if let Some(w) = quads
            .windows(2)
            .find(|w| (w[0].x, w[0].y) == (w[1].x, w[1].y))
        {
            return Err(format!("two pixel quads at pixel ({}, {})", w[0].x, w[0].y));
        }
        let (mut x0, mut y0, mut x1, mut y1) = (first.x, first.y, first.x, first.y);
        for q in quads {
            (x0, y0, x1, y1) = (x0.min(q.x), y0.min(q.y), x1.max(q.x), y1.max(q.y));
        }
        let b = QuadBox {
            count: quads.len() as u64,
            x0,
            y0,
            w: (x1 - x0 + 1) as u64,
            h: (y1 - y0 + 1) as u64,
        };
        b.check()?;
        Ok(b)
    }

    fn check(&self) -> Result<(), String> {
        let lim = 1i64 << 40;
        if self.count == 0 {
            return Ok(());
        }
        if !(-lim..=lim).contains(&self.x0) || !(-lim..=lim).contains(&self.y0) {
            return Err(format!(
                "pixel quad box corner ({}, {}) out of range",
                self.x0, self.y0
            ));
        }
        let side = super::MAX_BOX_SIDE;
        if self.w == 0 || self.h == 0 || self.w > side || self.h > side {
            return Err(format!(
                "a pixel quad box of {} × {} pixels (1 to {side} a side)",
                self.w, self.h
            ));
        }
        if self.count > MAX_QUADS || self.count > self.w * self.h {
            return Err(format!(
                "{} pixel quads in a box of {} × {} pixels (at most {MAX_QUADS}, one a pixel)",
                self.count, self.w, self.h
            ));
        }
        Ok(())
    }

    pub fn put(&self, out: &mut Vec<u8>) {
        super::put_varint(out, self.count);
        if self.count > 0 {
            super::put_varint(out, super::zigzag(self.x0));
            super::put_varint(out, super::zigzag(self.y0));
            super::put_varint(out, self.w);
            super::put_varint(out, self.h);
        }
    }

    pub fn read(hd: &mut super::Header) -> Result<QuadBox, super::MeshError> {
        let count = hd.varint("pixel quad count")?;
        if count == 0 {
            return Ok(QuadBox {
                count,
                x0: 0,
                y0: 0,
                w: 0,
                h: 0,
            });
        }
        let b = QuadBox {
            count,
            x0: super::unzigzag(hd.varint("pixel quad x0")?),
            y0: super::unzigzag(hd.varint("pixel quad y0")?),
            w: hd.varint("pixel quad box width")?,
            h: hd.varint("pixel quad box height")?,
        };
        b.check().map_err(super::MeshError::Format)?;
        Ok(b)
    }
}

/// The quantised inverse radial depth of a quad.
fn quantise(r: f32, step: f64) -> i64 {
    ((1.0 / (r as f64 * step)).round() as i64).clamp(1, i32::MAX as i64)
}

/// Predictors of a quad's depth: the quad above, the quad to the left, the quad before in
/// raster order, the last lattice vertex's radial depth (first quad only).
const PREDICTORS: usize = 4;

/// Codes the quads' pixels (a mask over the box, contexts as the lattice occupancy's) and
/// their depths (`round(1/(r·δ))`, a residual against the first predictor that applies).
pub(super) fn encode(
    e: &mut Encoder,
    qb: &QuadBox,
    quads: &[PixelQuad],
    last_r: Option<f32>,
    step: f64,
) {
    if quads.is_empty() {
        return;
    }
    let (w, h) = (qb.w as usize, qb.h as usize);
    let mut mask = vec![false; w * h];
    let cell = |q: &PixelQuad| (q.y - qb.y0) as usize * w + (q.x - qb.x0) as usize;
    for q in quads {
        mask[cell(q)] = true;
    }
    let mut ctx = [Bit::new(); 16];
    let mut seen = 0;
    for i in 0..mask.len() {
        if seen == quads.len() {
            break;
        }
        e.bit(&mut ctx[super::occupancy_ctx(&mask, w, i)], mask[i]);
        seen += usize::from(mask[i]);
    }
    let mut q = vec![0i64; w * h];
    let mut models: [Signed; PREDICTORS] = Default::default();
    let mut prev = None;
    for quad in quads {
        let i = cell(quad);
        let v = quantise(quad.r, step);
        let (pred, how) = predict(&mask, &q, w, i, prev, last_r, step);
        models[how].encode(e, (v - pred) as i32);
        q[i] = v;
        prev = Some(v);
    }
}

fn predict(
    mask: &[bool],
    q: &[i64],
    w: usize,
    i: usize,
    prev: Option<i64>,
    last_r: Option<f32>,
    step: f64,
) -> (i64, usize) {
    if i >= w && mask[i - w] {
        (q[i - w], 0)
    } else if !i.is_multiple_of(w) && mask[i - 1] {
        (q[i - 1], 1)
    } else if let Some(p) = prev {
        (p, 2)
    } else {
        (last_r.map_or(0, |r| quantise(r, step)), 3)
    }
}

/// Decodes what [`encode`] wrote.
pub(super) fn decode(
    d: &mut Decoder,
    qb: &QuadBox,
    last_r: Option<f32>,
    step: f64,
) -> Result<Vec<PixelQuad>, super::MeshError> {
    if qb.count == 0 {
        return Ok(Vec::new());
    }
    let (w, h, count) = (qb.w as usize, qb.h as usize, qb.count as usize);
    let mut mask = vec![false; w * h];
    let mut cells = Vec::with_capacity(count);
    let mut ctx = [Bit::new(); 16];
    for i in 0..mask.len() {
        if cells.len() == count {
            break;
        }
        if d.bit(&mut ctx[super::occupancy_ctx(&mask, w, i)]) {
            mask[i] = true;
            cells.push(i);
        }
    }
    if cells.len() < count {
        return Err(super::MeshError::Format(format!(
            "pixel quad mask holds {} of {count} quads",
            cells.len()
        )));
    }
    let mut q = vec![0i64; w * h];
    let mut models: [Signed; PREDICTORS] = Default::default();
    let mut prev = None;
    let mut out = Vec::with_capacity(count);
    for (k, &i) in cells.iter().enumerate() {
        let (pred, how) = predict(&mask, &q, w, i, prev, last_r, step);
        let v = pred + models[how].decode(d) as i64;
        if !(1..=i32::MAX as i64).contains(&v) {
            return Err(super::MeshError::Format(format!(
                "pixel quad {k}: quantised depth {v} out of range"
            )));
        }
        q[i] = v;
        prev = Some(v);
        out.push(PixelQuad {
            x: qb.x0 + (i % w) as i64,
            y: qb.y0 + (i / w) as i64,
            r: (1.0 / (v as f64 * step)) as f32,
        });
    }
    Ok(out)
}
