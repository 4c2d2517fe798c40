//! The connectivity of a compact mesh: its triangles grown edge by edge.
//!
//! Vertices are known first (their lattice positions, raster order); a triangle is a set of
//! three vertex indices (its winding is not kept: the renderer draws both sides). A triangle
//! is never degenerate (its corners are not on one line) and no two triangles lie on the same
//! side of an edge, as in any planar triangulation.
//!
//! The coder grows the mesh from a seed triangle: a queue of edges, each with the side of it
//! not yet resolved. For each, one adaptive bit says whether a triangle lies there (its
//! context: the edge's direction and whether any vertex lies on that side near the edge)
//! and, if so, which vertex is its third: the *Delaunay vertex* of that side — the one seen
//! from the edge at the largest angle, whose circle through the edge's ends holds no other
//! vertex — in the usual case, coded as its place among the vertices tied with it (lattice
//! points are often co-circular: the corners of a rectangle), 0 almost always; any other
//! vertex is coded as the place one past the ties and its index. The adaptive meshes are
//! subsets of Delaunay triangulations, so they rarely need an index. The Delaunay vertex is
//! found by scanning a box around the edge, grown until it holds the circle of the best
//! vertex found (no better one can lie outside it). The triangle's two other edges join the queue. When the
//! queue runs dry before every triangle is out, the smallest remaining triangle (as sorted
//! index triples) seeds the next component, coded as three index gaps. Both sides stop as
//! soon as the last triangle is out.

use std::cmp::Ordering;
use std::collections::VecDeque;

use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};

use super::MeshError;
use crate::entropy::{Bit, Decoder, Encoder, Unsigned};

/// A vertex's lattice position.
pub(super) type Pt = (i64, i64);

/// The side of an edge `(u, v)`, `u < v`, a triangle or a vertex lies on (`true`: left of
/// `u → v`).
type Side = (u32, u32, bool);

// Lattice coordinates are below 2¹⁵ (the box limit), so products of two differences stay
// below 2³¹ and the Delaunay comparison's products of two of those below 2⁶³.
fn cross(o: Pt, a: Pt, b: Pt) -> i64 {
    (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
}

fn dot(o: Pt, a: Pt, b: Pt) -> i64 {
    (a.0 - o.0) * (b.0 - o.0) + (a.1 - o.1) * (b.1 - o.1)
}

/// Which side of `u → v` the point `p` lies on; `None` on the line.
fn side_of(pts: &[Pt], u: u32, v: u32, p: u32) -> Option<bool> {
    let c = cross(pts[u as usize], pts[v as usize], pts[p as usize]);
    (c != 0).then_some(c > 0)
}

/// Adaptive models of the connectivity.
struct Models {
    seed: [Unsigned; 3],
    exists: [Bit; 6],
    rank: Unsigned,
    far: Unsigned,
}

impl Models {
    fn new() -> Models {
        Models {
            seed: [Unsigned::new(), Unsigned::new(), Unsigned::new()],
            exists: [Bit::new(); 6],
            rank: Unsigned::new(),
            far: Unsigned::new(),
        }
    }
}

/// Context of an edge's "a triangle lies there" bit: axis-aligned, diagonal or other, and
/// whether any vertex lies in its search box.
fn edge_class(pts: &[Pt], u: u32, v: u32, empty: bool) -> usize {
    let (a, b) = (pts[u as usize], pts[v as usize]);
    let (dx, dy) = ((b.0 - a.0).abs(), (b.1 - a.1).abs());
    let shape = if dx == 0 || dy == 0 {
        0
    } else if dx == dy {
        1
    } else {
        2
    };
    shape + 3 * usize::from(empty)
}

/// The triangle's three edges, each as the side its third vertex lies on. `t` is sorted.
fn sides(pts: &[Pt], t: [u32; 3]) -> Option<[Side; 3]> {
    let [a, b, c] = t;
    Some([
        (a, b, side_of(pts, a, b, c)?),
        (b, c, side_of(pts, b, c, a)?),
        (a, c, side_of(pts, a, c, b)?),
    ])
}

/// The state both sides keep while the mesh grows.
struct Growth<'a> {
    pts: &'a [Pt],
    /// `rows[y]`: index of the first vertex of lattice row `y` or below (vertices are in
    /// raster order); one more entry than rows.
    rows: Vec<u32>,
    /// Lattice columns: every x is below this.
    width: i64,
    /// Sides already resolved: holding a triangle out, or known to hold none.
    done: HashSet<Side>,
    queue: VecDeque<Side>,
    out: Vec<[u32; 3]>,
    m: Models,
    /// Vertices on the current side inside the box scanned (reused).
    cands: Vec<u32>,
}

/// An inclusive lattice box `(x0, y0, x1, y1)`.
type Box = (i64, i64, i64, i64);

impl<'a> Growth<'a> {
    fn new(pts: &'a [Pt], triangles: usize) -> Growth<'a> {
        let height = pts.last().map_or(0, |p| p.1 as usize + 1);
        let mut rows = vec![0u32; height + 1];
        for p in pts {
            rows[p.1 as usize + 1] += 1;
        }
        for y in 0..height {
            rows[y + 1] += rows[y];
        }
        Growth {
            pts,
            rows,
            width: pts.iter().map(|p| p.0 + 1).max().unwrap_or(0),
            done: HashSet::with_capacity(3 * triangles),
            queue: VecDeque::new(),
            out: Vec::with_capacity(triangles),
            m: Models::new(),
            cands: Vec::new(),
        }
    }

    /// Adds a sorted triangle: its sides become resolved, the other sides of its edges join
    /// the queue. Fails when it is degenerate or a side is taken (overlapping triangles).
    fn add(&mut self, t: [u32; 3]) -> Result<(), MeshError> {
        let s = sides(self.pts, t).ok_or_else(|| {
            MeshError::Format(format!(
                "triangle {t:?} is degenerate (its corners are on a line)"
            ))
        })?;
        if s.iter().any(|x| self.done.contains(x)) {
            return Err(MeshError::Format(format!(
                "triangle {t:?} overlaps another on one of its edges"
            )));
        }
        for x in s {
            self.done.insert(x);
            self.queue.push_back((x.0, x.1, !x.2));
        }
        self.out.push(t);
        Ok(())
    }

    /// The whole lattice as a box.
    fn lattice(&self) -> Box {
        (0, 0, self.width - 1, self.rows.len() as i64 - 2)
    }

    /// The vertices on side `s` inside `bx`, into `self.cands`; vertices are in raster
    /// order, so the box's rows are one run of indices.
    fn scan(&mut self, s: Side, bx: Box) {
        let (u, v, left) = s;
        let pts = self.pts;
        self.cands.clear();
        let (x0, y0, x1, y1) = bx;
        let last_row = self.rows.len() as i64 - 2;
        let (ya, yb) = (y0.max(0), y1.min(last_row));
        if ya > yb {
            return;
        }
        // Each row's vertices are sorted by x: only those inside the box's columns are tested.
        for y in ya..=yb {
            let (first, end) = (self.rows[y as usize], self.rows[y as usize + 1]);
            let row = &pts[first as usize..end as usize];
            let lo = first + row.partition_point(|q| q.0 < x0) as u32;
            let hi = first + row.partition_point(|q| q.0 <= x1) as u32;
            self.cands.extend(
                (lo..hi).filter(|&p| p != u && p != v && side_of(pts, u, v, p) == Some(left)),
            );
        }
    }

    /// The first search box of an edge: its bounding box grown by its longer extent.
    fn first_box(&self, s: Side) -> Box {
        let (a, b) = (self.pts[s.0 as usize], self.pts[s.1 as usize]);
        let reach = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) / 2).max(1);
        (
            a.0.min(b.0) - reach,
            a.1.min(b.1) - reach,
            a.0.max(b.0) + reach,
            a.1.max(b.1) + reach,
        )
    }

    /// The next unresolved side and whether its first search box holds no vertex on it;
    /// `None` when the queue is dry. The caller resolves the side (a triangle added there,
    /// or marked empty).
    fn next_side(&mut self) -> Option<(Side, bool)> {
        while let Some(s) = self.queue.pop_front() {
            if self.done.contains(&s) {
                continue;
            }
            self.scan(s, self.first_box(s));
            return Some((s, self.cands.is_empty()));
        }
        None
    }

    /// The Delaunay vertices of side `s` (the vertices tied at the largest angle, by index),
    /// into `self.cands`; empty when no vertex lies on that side. Expects `self.cands` to
    /// hold the scan of the first box.
    fn delaunay_ties(&mut self, s: Side) {
        let lattice = self.lattice();
        let mut bx = self.first_box(s);
        let pts = self.pts;
        let (a, b) = (pts[s.0 as usize], pts[s.1 as usize]);
        // The angle at p as its cotangent dot / |cross|, compared by cross-multiplying.
        let key = |p: u32| {
            let q = pts[p as usize];
            (dot(q, a, b), cross(q, a, b).abs())
        };
        let before = |k: (i64, i64), l: (i64, i64)| k.0 * l.1 < l.0 * k.1;
        loop {
            let mut best: Option<(u32, (i64, i64))> = None;
            for &p in &self.cands {
                let k = key(p);
                if best.is_none_or(|(_, bk)| before(k, bk)) {
                    best = Some((p, k));
                }
            }
            let Some((best, bk)) = best else {
                if contains(bx, lattice) {
                    return;
                }
                bx = grow(bx, lattice);
                self.scan(s, bx);
                continue;
            };
            let reach = clamp(cap_box(a, b, pts[best as usize]), lattice);
            if contains(bx, reach) {
                // Ties: the same angle (scanned in index order, so already sorted).
                self.cands.retain(|&p| {
                    let k = key(p);
                    k.0 * bk.1 == bk.0 * k.1
                });
                return;
            }
            bx = union(bx, reach);
            self.scan(s, bx);
        }
    }
}

fn contains(outer: Box, inner: Box) -> bool {
    outer.0 <= inner.0 && outer.1 <= inner.1 && outer.2 >= inner.2 && outer.3 >= inner.3
}

fn clamp(b: Box, to: Box) -> Box {
    (b.0.max(to.0), b.1.max(to.1), b.2.min(to.2), b.3.min(to.3))
}

fn union(a: Box, b: Box) -> Box {
    (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3))
}

/// `b` twice as wide and high about its centre (at least one more cell each way).
fn grow(b: Box, lattice: Box) -> Box {
    let (dx, dy) = ((b.2 - b.0) / 2 + 1, (b.3 - b.1) / 2 + 1);
    clamp((b.0 - dx, b.1 - dy, b.2 + dx, b.3 + dy), lattice)
}

/// A lattice box holding the part of the circle through `a`, `b`, `c` (not on one line) on
/// `c`'s side of the chord `a b` — where every vertex better than `c` lies — with a cell of
/// margin for rounding: the chord's ends and the circle's extreme points on that side.
fn cap_box(a: Pt, b: Pt, c: Pt) -> Box {
    let (bx, by) = ((b.0 - a.0) as f64, (b.1 - a.1) as f64);
    let (cx, cy) = ((c.0 - a.0) as f64, (c.1 - a.1) as f64);
    let d = 2.0 * (bx * cy - by * cx);
    let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    let r = (ux * ux + uy * uy).sqrt();
    let side = (bx * cy - by * cx).signum();
    let (mut lo_x, mut lo_y) = (a.0.min(b.0) as f64, a.1.min(b.1) as f64);
    let (mut hi_x, mut hi_y) = (a.0.max(b.0) as f64, a.1.max(b.1) as f64);
    for (px, py) in [(ux + r, uy), (ux - r, uy), (ux, uy + r), (ux, uy - r)] {
        // On c's side of the chord, or near the chord (rounding): keep it.
        if (bx * py - by * px) * side > -(b2.sqrt() + 1.0) {
            let (x, y) = (a.0 as f64 + px, a.1 as f64 + py);
            lo_x = lo_x.min(x);
            lo_y = lo_y.min(y);
            hi_x = hi_x.max(x);
            hi_y = hi_y.max(y);
        }
    }
    (
        lo_x.floor() as i64 - 1,
        lo_y.floor() as i64 - 1,
        hi_x.ceil() as i64 + 1,
        hi_y.ceil() as i64 + 1,
    )
}

fn sorted(mut t: [u32; 3]) -> [u32; 3] {
    t.sort_unstable();
    t
}

/// Codes the triangles (index triples into `pts`) and returns them in the order a decoder
/// produces them, each sorted.
pub(super) fn encode(
    e: &mut Encoder,
    pts: &[Pt],
    triangles: &[[u32; 3]],
) -> Result<Vec<[u32; 3]>, MeshError> {
    let mut tris: Vec<[u32; 3]> = triangles.iter().map(|&t| sorted(t)).collect();
    tris.sort_unstable();
    // Which triangle lies on each side of each edge.
    let mut owner: HashMap<Side, usize> = HashMap::with_capacity(3 * tris.len());
    for (i, &t) in tris.iter().enumerate() {
        if t[0] == t[1] || t[1] == t[2] {
            return Err(MeshError::Format(format!(
                "triangle {t:?} repeats a vertex"
            )));
        }
        let s = sides(pts, t).ok_or_else(|| {
            MeshError::Format(format!(
                "triangle {t:?} is degenerate (its corners are on a line)"
            ))
        })?;
        for x in s {
            if owner.insert(x, i).is_some() {
                return Err(MeshError::Format(format!(
                    "triangle {t:?} overlaps another on one of its edges"
                )));
            }
        }
    }
    let mut visited = vec![false; tris.len()];
    let mut g = Growth::new(pts, tris.len());
    let (mut next_seed, mut prev_a) = (0usize, 0u32);
    'grow: while g.out.len() < tris.len() {
        while visited[next_seed] {
            next_seed += 1;
        }
        let t = tris[next_seed];
        g.m.seed[0].encode(e, t[0] - prev_a);
        g.m.seed[1].encode(e, t[1] - t[0] - 1);
        g.m.seed[2].encode(e, t[2] - t[1] - 1);
        prev_a = t[0];
        visited[next_seed] = true;
        g.add(t)?;
        while g.out.len() < tris.len() {
            let Some((s, empty)) = g.next_side() else {
                continue 'grow;
            };
            let class = edge_class(pts, s.0, s.1, empty);
            let here = owner.get(&s).copied();
            e.bit(&mut g.m.exists[class], here.is_some());
            let Some(i) = here else {
                g.done.insert(s);
                continue;
            };
            let t = tris[i];
            let w = t
                .into_iter()
                .find(|&p| p != s.0 && p != s.1)
                .unwrap_or(t[2]);
            g.delaunay_ties(s);
            match g.cands.iter().position(|&p| p == w) {
                Some(k) => g.m.rank.encode(e, k as u32),
                None => {
                    g.m.rank.encode(e, g.cands.len() as u32);
                    g.m.far.encode(e, w);
                }
            }
            visited[i] = true;
            g.add(t)?;
        }
    }
    Ok(g.out)
}

/// Decodes `count` triangles over `pts` (the encoder's order, each sorted).
pub(super) fn decode(
    d: &mut Decoder,
    pts: &[Pt],
    count: usize,
) -> Result<Vec<[u32; 3]>, MeshError> {
    let n = pts.len() as u64;
    let mut g = Growth::new(pts, count);
    let mut prev_a = 0u64;
    'grow: while g.out.len() < count {
        let a = prev_a + g.m.seed[0].decode(d) as u64;
        let b = a + 1 + g.m.seed[1].decode(d) as u64;
        let c = b + 1 + g.m.seed[2].decode(d) as u64;
        if c >= n {
            return Err(MeshError::Format(format!(
                "seed triangle ({a}, {b}, {c}) names a vertex beyond the {n} vertices"
            )));
        }
        prev_a = a;
        g.add([a as u32, b as u32, c as u32])?;
        while g.out.len() < count {
            let Some((s, empty)) = g.next_side() else {
                continue 'grow;
            };
            let class = edge_class(pts, s.0, s.1, empty);
            if !d.bit(&mut g.m.exists[class]) {
                g.done.insert(s);
                continue;
            }
            g.delaunay_ties(s);
            let (u, v) = (s.0, s.1);
            let k = g.m.rank.decode(d) as usize;
            let w = match k.cmp(&g.cands.len()) {
                Ordering::Less => g.cands[k],
                Ordering::Equal => {
                    let w = g.m.far.decode(d);
                    if w as u64 >= n || side_of(pts, u, v, w) != Some(s.2) {
                        return Err(MeshError::Format(format!(
                            "third vertex {w} of edge ({u}, {v}) is not on its side"
                        )));
                    }
                    w
                }
                Ordering::Greater => {
                    return Err(MeshError::Format(format!(
                        "third vertex {k} of {} tied ones",
                        g.cands.len()
                    )))
                }
            };
            g.add(sorted([u, v, w]))?;
        }
    }
    Ok(g.out)
}
