//! The per-tile search of the shrunk variant: what a tile holds as groups of boxes, and the
//! refinement of (interval, group) pairs until each is shown hidden, a stored point is seen,
//! or nothing more can be learnt (see the proof in [`super`]).

use std::collections::HashMap;

use glam::DVec3;
use tracks::cubemap::{pixel_dir, subpixel_dir};
use tracks::{Face, TileGrid};

use super::{ShrunkParams, ShrunkStats, Solids};
use crate::input::{SlabLayer, TileInfo};

/// What every tile of one viewpoint is tested against.
pub(super) struct Ctx<'a> {
    pub(super) v: DVec3,
    pub(super) grid: &'a TileGrid,
    pub(super) layers: &'a [SlabLayer],
    /// Base intervals of the cell, world coordinates.
    pub(super) stretches: &'a [(DVec3, DVec3)],
    pub(super) params: &'a ShrunkParams,
    pub(super) solids: &'a dyn Solids,
    /// The content rule's depth tolerance `τ` at this face size.
    pub(super) tol: f64,
}

/// The tile under test: its face, its opaque pixels' stored depths (NaN where transparent)
/// over the tile's pixel rectangle, and the footprint rectangle of what it holds (the tile
/// grown by the search radius, clamped to the face).
struct TileData {
    face: Face,
    slab: usize,
    tile: (u32, u32, u32, u32),
    depth: Vec<f64>,
    rect: (u32, u32, u32, u32),
}

impl TileData {
    fn depth_at(&self, x: u32, y: u32) -> f64 {
        let (x0, y0, x1, _) = self.tile;
        self.depth[((y - y0) * (x1 - x0) + (x - x0)) as usize]
    }
}

/// A piece of what a tile holds at one footprint pixel: a distance band (the union of the
/// overlapping bands that reach the pixel) and a stored point of a pixel it came from.
#[derive(Clone, Copy, Debug)]
struct Piece {
    s0: f64,
    s1: f64,
    sample: DVec3,
}

/// A group of what a tile holds: the box that holds all of it (frame `f, e1, e2` relative
/// to `V`, ranges per axis), a stored point to look at, and how it splits.
#[derive(Clone, Copy, Debug)]
struct Group {
    frame: [DVec3; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    sample: DVec3,
    split: Split,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Split {
    /// Several footprint pixels: quarter the rectangle.
    Quarters,
    /// One footprint pixel holding several bands: one group per band.
    Pieces,
    /// One band: halve it (a long band seen from aside is wide across the line of sight;
    /// its far part may also lie inside the solid whose surface it is on).
    Band,
    /// Not split further.
    No,
}

/// What a group holds: every footprint pixel of a rectangle (bounded coarsely: its
/// footprint times the union of the bands that reach it), or part `j` of `2^level` of the
/// band of piece `k` of footprint pixel `(x, y)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Key {
    Rect(u32, u32, u32, u32),
    Piece {
        x: u32,
        y: u32,
        k: u16,
        level: u8,
        j: u32,
    },
}

/// How many times a piece's band may be halved.
const BAND_LEVELS: u8 = 4;

/// A work item: an interval of a stretch (parameters `t0..t1`) and a group.
#[derive(Clone, Copy, Debug)]
struct Pair {
    stretch: u32,
    t0: f64,
    t1: f64,
    key: Key,
}

enum Outcome {
    Hidden,
    Seen,
    Undecided,
}

/// The band `[r/(1 + τ), r/(1 − τ)]` of a stored distance.
fn band(r: f64, tol: f64) -> (f64, f64) {
    (r / (1.0 + tol), r / (1.0 - tol))
}

impl Ctx<'_> {
    /// Keep (`true`) or cull one tile of slab `k`, with what it took.
    pub(super) fn decide(&self, k: usize, tile: &TileInfo) -> (bool, ShrunkStats) {
        let mut stats = ShrunkStats {
            tiles: 1,
            ..ShrunkStats::default()
        };
        let id = tile.id;
        let layer = &self.layers[k];
        let n = self.grid.face_size;
        let rr = self.params.content.search_radius;
        let tracks::PixelRect { x0, y0, x1, y1, .. } = self.grid.pixel_rect(id);
        let mut depth = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
        let mut any = false;
        for y in y0..y1 {
            for x in x0..x1 {
                if *layer.alpha.get(id.face, x, y) < 128 {
                    depth.push(f64::NAN);
                    continue;
                }
                // Nothing of the earlier slabs in front: seen from V itself.
                if self.layers[..k]
                    .iter()
                    .all(|l| *l.alpha.get(id.face, x, y) < 128)
                {
                    stats.kept_direct = 1;
                    return (true, stats);
                }
                depth.push(*layer.depth.get(id.face, x, y) as f64);
                any = true;
            }
        }
        if !any {
            stats.culled = 1;
            return (false, stats);
        }
        let t = TileData {
            face: id.face,
            slab: k,
            tile: (x0, y0, x1, y1),
            depth,
            rect: (
                x0.saturating_sub(rr),
                y0.saturating_sub(rr),
                (x1 + rr).min(n),
                (y1 + rr).min(n),
            ),
        };
        match self.search(&t, &mut stats) {
            Outcome::Hidden => {
                stats.culled = 1;
                (false, stats)
            }
            Outcome::Seen => {
                stats.kept_seen = 1;
                (true, stats)
            }
            Outcome::Undecided => {
                stats.kept_undecided = 1;
                (true, stats)
            }
        }
    }

    /// The tile's pixels whose content can reach footprint rectangle `r`: those within the
    /// search radius of it.
    fn reaching(&self, t: &TileData, r: (u32, u32, u32, u32)) -> (u32, u32, u32, u32) {
        let rr = self.params.content.search_radius;
        let (tx0, ty0, tx1, ty1) = t.tile;
        (
            r.0.saturating_sub(rr).max(tx0),
            r.1.saturating_sub(rr).max(ty0),
            (r.2 + rr).min(tx1),
            (r.3 + rr).min(ty1),
        )
    }

    /// What the oracle could put in footprint pixel `(x, y)` and attribute to one of the
    /// tile's pixels: its own band at the pixel itself; at a neighbour, the part of the
    /// band in the slab's range that no layer at `(x, y)` holds itself (only then does
    /// the oracle search the neighbours). Overlapping bands merged, nearest first.
    fn pieces(&self, t: &TileData, x: u32, y: u32) -> Vec<Piece> {
        let n = self.grid.face_size;
        let layer = &self.layers[t.slab];
        let (qx0, qy0, qx1, qy1) = self.reaching(t, (x, y, x + 1, y + 1));
        let mut bands: Vec<Piece> = Vec::new();
        for qy in qy0..qy1 {
            for qx in qx0..qx1 {
                let r = t.depth_at(qx, qy);
                if r.is_nan() {
                    continue;
                }
                let sample = self.v + pixel_dir(t.face, qx, qy, n) * r;
                let (s0, s1) = band(r, self.tol);
                if (qx, qy) == (x, y) {
                    bands.push(Piece { s0, s1, sample });
                    continue;
                }
                let mut parts = [(0.0, 0.0); 8];
                parts[0] = (s0.max(layer.range.near), s1.min(layer.range.far));
                let mut count = usize::from(parts[0].1 > parts[0].0);
                for l in self.layers {
                    // A cut adds at most one part; with no room left, keep the parts whole.
                    if count < parts.len() && *l.alpha.get(t.face, x, y) >= 128 {
                        let cut = band(*l.depth.get(t.face, x, y) as f64, self.tol);
                        count = subtract(&mut parts, count, cut);
                    }
                }
                bands.extend(
                    parts[..count]
                        .iter()
                        .map(|&(s0, s1)| Piece { s0, s1, sample }),
                );
            }
        }
        bands.sort_by(|a, b| a.s0.total_cmp(&b.s0).then(a.s1.total_cmp(&b.s1)));
        let mut out: Vec<Piece> = Vec::with_capacity(bands.len());
        for b in bands {
            match out.last_mut() {
                Some(c) if b.s0 <= c.s1 => c.s1 = c.s1.max(b.s1),
                _ => out.push(b),
            }
        }
        out
    }

    /// The box of a group, in a frame along its mean direction.
    fn group(
        &self,
        t: &TileData,
        key: Key,
        pieces: &mut HashMap<(u32, u32), Vec<Piece>>,
    ) -> Option<Group> {
        let n = self.grid.face_size;
        let face = t.face;
        let (rect, s0, s1, sample, split) = match key {
            Key::Rect(x0, y0, x1, y1) if x1 - x0 > 1 || y1 - y0 > 1 => {
                // Every band that reaches the rectangle, and the stored point nearest its
                // centre.
                let (qx0, qy0, qx1, qy1) = self.reaching(t, (x0, y0, x1, y1));
                let (cx, cy) = (0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64);
                let (mut s0, mut s1) = (f64::INFINITY, f64::NEG_INFINITY);
                let mut nearest: Option<(f64, u32, u32, f64)> = None;
                for qy in qy0..qy1 {
                    for qx in qx0..qx1 {
                        let r = t.depth_at(qx, qy);
                        if r.is_nan() {
                            continue;
                        }
                        let (a, b) = band(r, self.tol);
                        (s0, s1) = (s0.min(a), s1.max(b));
                        let dd = (qx as f64 + 0.5 - cx).powi(2) + (qy as f64 + 0.5 - cy).powi(2);
                        if nearest.is_none_or(|p| dd < p.0) {
                            nearest = Some((dd, qx, qy, r));
                        }
                    }
                }
                let (_, qx, qy, r) = nearest?;
                let sample = self.v + pixel_dir(face, qx, qy, n) * r;
                ((x0, y0, x1, y1), s0, s1, sample, Split::Quarters)
            }
            Key::Rect(x, y, ..) => {
                let ps = pieces.entry((x, y)).or_insert_with(|| self.pieces(t, x, y));
                match ps.as_slice() {
                    [] => return None,
                    [p] => ((x, y, x + 1, y + 1), p.s0, p.s1, p.sample, Split::Band),
                    [first, .., last] => (
                        (x, y, x + 1, y + 1),
                        first.s0,
                        last.s1,
                        first.sample,
                        Split::Pieces,
                    ),
                }
            }
            Key::Piece { x, y, k, level, j } => {
                let ps = pieces.entry((x, y)).or_insert_with(|| self.pieces(t, x, y));
                let p = *ps.get(k as usize)?;
                let step = (p.s1 - p.s0) / (1u32 << level) as f64;
                let s0 = p.s0 + step * j as f64;
                let s1 = if j + 1 == 1 << level { p.s1 } else { s0 + step };
                let split = if level < BAND_LEVELS && s1 - s0 > 1e-3 * s1 {
                    Split::Band
                } else {
                    Split::No
                };
                ((x, y, x + 1, y + 1), s0, s1, p.sample, split)
            }
        };
        let (x0, y0, x1, y1) = rect;
        let f = subpixel_dir(face, 0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64, n);
        let e1 = (face.right() - f * face.right().dot(f)).normalize();
        let e2 = f.cross(e1);
        let (fx0, fy0, fx1, fy1) = (x0 as f64, y0 as f64, x1 as f64, y1 as f64);
        let corners = [
            subpixel_dir(face, fx0, fy0, n),
            subpixel_dir(face, fx1, fy0, n),
            subpixel_dir(face, fx1, fy1, n),
            subpixel_dir(face, fx0, fy1, n),
        ];
        // Every direction of the footprint is a normalised convex combination of the
        // corners, whose length before normalising is at least the cosine of the widest
        // angle between two corners (its dot product with any corner is).
        let wide = corners[0]
            .dot(corners[2])
            .min(corners[1].dot(corners[3]))
            .max(1e-3);
        // Along f: at least s0 · (smallest cosine, at a corner); at most s1.
        let min_cos = corners
            .iter()
            .map(|c| c.dot(f))
            .fold(f64::INFINITY, f64::min);
        let mut lo = [
            if min_cos >= 0.0 {
                s0 * min_cos
            } else {
                s1 * min_cos
            },
            0.0,
            0.0,
        ];
        let mut hi = [s1, 0.0, 0.0];
        // Across: corner values, grown for the footprint's bulge between corners.
        for (axis, e) in [(1, e1), (2, e2)] {
            let (mut m, mut mm) = (f64::INFINITY, f64::NEG_INFINITY);
            for c in &corners {
                let w = c.dot(e);
                m = m.min(w);
                mm = mm.max(w);
            }
            hi[axis] = if mm >= 0.0 { s1 * mm / wide } else { s0 * mm };
            lo[axis] = if m <= 0.0 { s1 * m / wide } else { s0 * m };
        }
        Some(Group {
            frame: [f, e1, e2],
            lo,
            hi,
            sample,
            split,
        })
    }

    /// The groups a group splits into.
    fn children(
        &self,
        key: Key,
        split: Split,
        pieces: &HashMap<(u32, u32), Vec<Piece>>,
    ) -> Vec<Key> {
        match (key, split) {
            (Key::Rect(x0, y0, x1, y1), Split::Quarters) => quarters((x0, y0, x1, y1))
                .into_iter()
                .map(|(a, b, c, d)| Key::Rect(a, b, c, d))
                .collect(),
            (Key::Rect(x, y, ..), Split::Pieces) => (0..pieces.get(&(x, y)).map_or(0, Vec::len))
                .map(|k| Key::Piece {
                    x,
                    y,
                    k: k as u16,
                    level: 0,
                    j: 0,
                })
                .collect(),
            (Key::Rect(x, y, ..), Split::Band) => (0..2)
                .map(|j| Key::Piece {
                    x,
                    y,
                    k: 0,
                    level: 1,
                    j,
                })
                .collect(),
            (Key::Piece { x, y, k, level, j }, Split::Band) => (0..2)
                .map(|h| Key::Piece {
                    x,
                    y,
                    k,
                    level: level + 1,
                    j: 2 * j + h,
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Refine (interval, group) pairs until all are hidden, a stored point is seen, or no
    /// more can be learnt.
    fn search(&self, t: &TileData, stats: &mut ShrunkStats) -> Outcome {
        let mut groups: HashMap<Key, Option<Group>> = HashMap::new();
        let mut pieces: HashMap<(u32, u32), Vec<Piece>> = HashMap::new();
        let (rx0, ry0, rx1, ry1) = t.rect;
        let root = Key::Rect(rx0, ry0, rx1, ry1);
        let mut stack: Vec<Pair> = (0..self.stretches.len() as u32)
            .rev()
            .map(|s| Pair {
                stretch: s,
                t0: 0.0,
                t1: 1.0,
                key: root,
            })
            .collect();
        let mut tests = 0u32;
        while let Some(pair) = stack.pop() {
            if tests >= self.params.max_tests_per_tile {
                return Outcome::Undecided;
            }
            let g = match groups.get(&pair.key) {
                Some(g) => *g,
                None => {
                    let g = self.group(t, pair.key, &mut pieces);
                    groups.insert(pair.key, g);
                    g
                }
            };
            let Some(g) = g else { continue };
            let (a, b) = self.stretches[pair.stretch as usize];
            let (xa, xb) = (a.lerp(b, pair.t0), a.lerp(b, pair.t1));
            let x = 0.5 * (xa + xb);
            let eps = 0.5 * xa.distance(xb);
            let aim = target(&g, self.v, x, eps);
            if let Some((pc, delta, _)) = aim {
                tests += 1;
                stats.block_tests += 1;
                let margin = 1e-6 + 1e-9 * (x.abs().max_element() + pc.distance(x));
                if self
                    .solids
                    .blocks(x, pc, eps + margin, delta + margin, (xa, xb))
                {
                    continue;
                }
            }
            // Not shown hidden: is the group's stored point simply seen?
            tests += 1;
            stats.see_tests += 1;
            if self.solids.sees(x, g.sample) {
                return Outcome::Seen;
            }
            // Refine the larger term of the shrink distance; a single piece whose own
            // extent dominates gains nothing from smaller intervals.
            let w_max = aim.map_or(f64::INFINITY, |a| a.2);
            let can_split = g.split != Split::No;
            let can_halve = 2.0 * eps > self.params.min_interval_m
                && (can_split || aim.is_none() || eps > 0.125 * w_max);
            if can_halve && (!can_split || aim.is_none() || eps >= w_max) {
                let tm = 0.5 * (pair.t0 + pair.t1);
                stack.push(Pair { t0: tm, ..pair });
                stack.push(Pair { t1: tm, ..pair });
            } else if can_split {
                for key in self.children(pair.key, g.split, &pieces).into_iter().rev() {
                    stack.push(Pair { key, ..pair });
                }
            } else {
                return Outcome::Undecided;
            }
        }
        Outcome::Hidden
    }
}

/// The point `P_c` to aim at from `x` (interval radius `eps`) for a group's box, the
/// shrink distance `δ` at it and the box's extent across the line of sight (`w_max`);
/// `None` when `x` is not in front of the box.
fn target(g: &Group, v: DVec3, x: DVec3, eps: f64) -> Option<(DVec3, f64, f64)> {
    let [f, e1, e2] = g.frame;
    let mid = [
        0.5 * (g.lo[0] + g.hi[0]),
        0.5 * (g.lo[1] + g.hi[1]),
        0.5 * (g.lo[2] + g.hi[2]),
    ];
    let half = [
        0.5 * (g.hi[0] - g.lo[0]),
        0.5 * (g.hi[1] - g.lo[1]),
        0.5 * (g.hi[2] - g.lo[2]),
    ];
    if half.iter().any(|h| !(h.is_finite() && *h >= 0.0)) {
        return None;
    }
    let c = v + f * mid[0] + e1 * mid[1] + e2 * mid[2];
    let to_c = c - x;
    let dist = to_c.length();
    if !(dist > 0.0 && dist.is_finite()) {
        return None;
    }
    let u = to_c / dist;
    let uf = [u.dot(f) * half[0], u.dot(e1) * half[1], u.dot(e2) * half[2]];
    let reach = uf[0].abs() + uf[1].abs() + uf[2].abs();
    let l = dist - reach;
    if l.is_nan() || l <= 0.0 {
        return None;
    }
    // Across the line of sight: the corner with the smallest |corner · u| is the widest.
    let h2 = half[0] * half[0] + half[1] * half[1] + half[2] * half[2];
    let min_along = [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
        .iter()
        .map(|(s1, s2)| (uf[0] + s1 * uf[1] + s2 * uf[2]).abs())
        .fold(f64::INFINITY, f64::min);
    let w_max = (h2 - min_along * min_along).max(0.0).sqrt();
    let span = 2.0 * reach;
    let delta = eps * span / (l + span) + w_max;
    Some((c - u * reach, delta, w_max))
}

/// Remove `cut` from the first `count` intervals of `parts` (closed intervals; ends kept,
/// so the parts cover a little more, never less); returns the new count. At most one
/// interval splits per cut, so eight places hold the cuts of seven layers.
fn subtract(parts: &mut [(f64, f64); 8], count: usize, cut: (f64, f64)) -> usize {
    let mut out = [(0.0, 0.0); 8];
    let mut m = 0;
    for &(a, b) in &parts[..count] {
        let mut push = |p: (f64, f64)| {
            if m < out.len() {
                out[m] = p;
                m += 1;
            }
        };
        if cut.1 < a || cut.0 > b {
            push((a, b));
            continue;
        }
        if cut.0 > a {
            push((a, cut.0));
        }
        if cut.1 < b {
            push((cut.1, b));
        }
    }
    *parts = out;
    m
}

/// The non-empty quarters (or halves, for a one-pixel-wide rectangle) of a rectangle.
fn quarters((x0, y0, x1, y1): (u32, u32, u32, u32)) -> Vec<(u32, u32, u32, u32)> {
    let (mx, my) = ((x0 + x1).div_ceil(2), (y0 + y1).div_ceil(2));
    let xs: &[(u32, u32)] = if x1 - x0 >= 2 {
        &[(x0, mx), (mx, x1)]
    } else {
        &[(x0, x1)]
    };
    let ys: &[(u32, u32)] = if y1 - y0 >= 2 {
        &[(y0, my), (my, y1)]
    } else {
        &[(y0, y1)]
    };
    ys.iter()
        .flat_map(|&(ya, yb)| xs.iter().map(move |&(xa, xb)| (xa, ya, xb, yb)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subtracting_bands() {
        let start = || {
            let mut p = [(0.0, 0.0); 8];
            p[0] = (1.0, 5.0);
            p[1] = (7.0, 9.0);
            p
        };
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (2.0, 3.0)), 3);
        assert_eq!(p[..3], [(1.0, 2.0), (3.0, 5.0), (7.0, 9.0)]);
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (0.0, 8.0)), 1);
        assert_eq!(p[0], (8.0, 9.0));
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (5.5, 6.5)), 2);
        assert_eq!(p[..2], [(1.0, 5.0), (7.0, 9.0)]);
        let mut p = start();
        assert_eq!(subtract(&mut p, 2, (0.0, 10.0)), 0);
    }

    #[test]
    fn quarters_cover_the_rectangle_once() {
        for r in [(0, 0, 8, 8), (3, 5, 4, 9), (2, 2, 7, 3), (0, 0, 1, 1)] {
            let q = quarters(r);
            let area: u32 = q.iter().map(|&(a, b, c, d)| (c - a) * (d - b)).sum();
            assert_eq!(area, (r.2 - r.0) * (r.3 - r.1), "{r:?} {q:?}");
        }
    }

    /// The lemma's target: every corner of the box lies at `P_c + α·u + w` with `α ≥ 0`
    /// and `|w| ≤ w_max`, and `P_c` is on the line from `x` through the box centre.
    #[test]
    fn target_covers_every_corner_of_the_box() {
        let f = DVec3::new(0.3, 0.2, 1.0).normalize();
        let e1 = DVec3::X.cross(f).normalize();
        let e2 = f.cross(e1);
        let g = Group {
            frame: [f, e1, e2],
            lo: [9.0, -0.4, -0.2],
            hi: [12.5, 0.3, 0.5],
            sample: DVec3::ZERO,
            split: Split::Quarters,
        };
        let v = DVec3::new(1.0, 2.0, 3.0);
        for x in [
            v,
            v + DVec3::new(2.0, 0.0, -1.0),
            v + DVec3::new(-3.0, 0.5, 2.0),
        ] {
            let (pc, delta, w_max) = target(&g, v, x, 0.25).unwrap();
            let u = (pc - x).normalize();
            assert!(delta >= w_max);
            for i in 0..8 {
                let a = if i & 1 == 0 { g.lo[0] } else { g.hi[0] };
                let b = if i & 2 == 0 { g.lo[1] } else { g.hi[1] };
                let c = if i & 4 == 0 { g.lo[2] } else { g.hi[2] };
                let corner = v + f * a + e1 * b + e2 * c;
                let rel = corner - pc;
                let along = rel.dot(u);
                let across = (rel - u * along).length();
                assert!(along >= -1e-9, "{x} corner {i}: α = {along}");
                assert!(across <= w_max + 1e-9, "{x} corner {i}: {across} > {w_max}");
            }
        }
    }
}
