//! The rendered variant a segment at a time, with balls refined only where a tile needs them.
//!
//! A segment's balls form a binary tree: [`RenderedParams::coarse_per_segment`] pieces at the
//! top, each split in two down to [`RenderedParams::per_segment`] pieces. Every later-slab
//! tile of both ends starts with the top balls. For each ball a tile either
//! - is hidden from it ([`BallView::hides`] over the tile's pixels, a block at a time: the
//!   whole tile first, its quarters where that fails, down to single pixels) — done with that
//!   ball;
//! - shows a pixel to the ball's centre (its surface point is the first hit there, within the
//!   oracle's depth tolerance): the tile is seen from the segment and kept, and nothing more
//!   is rendered for it;
//! - or neither: the ball's two halves are tried instead, down to the finest level, where the
//!   tile is kept.
//!
//! A tile is hidden from the segment when every piece of it is covered by a ball it is hidden
//! from — the same guarantee as balls of the finest size everywhere, since a ball holds both
//! its halves. Renders are made only for the balls some tile still needs, a level at a time
//! (so a caller that renders with an outside program can run several at once), and tiles the
//! reference viewpoint itself sees are kept before any render. A segment of length zero (a
//! track of one viewpoint) is one ball of radius zero.

use glam::DVec3;
use rayon::prelude::*;
use tracks::cubemap::subpixel_dir;
use tracks::{CubeMap, Face, TileGrid};

use super::{cover, nearest_distance, BallDepth, BallView, RenderedParams, RenderedStats};
use crate::input::SlabLayer;
use crate::oracle::Visibility;
use crate::OcclusionError;

/// Memory the balls rendered and tested at a time may hold (each a depth and a solid map of
/// the face size, about 8 bytes a pixel with what their tests build).
const BALL_MEMORY_BYTES: usize = 256 << 20;

/// Balls rendered and tested at a time at `n` pixels a face side: as many as
/// [`BALL_MEMORY_BYTES`] holds, from 8 to 256. A renderer that starts a process for each call
/// (POV-Ray) then starts few.
fn balls_at_a_time(n: u32) -> usize {
    let per = 6 * (n as usize).pow(2) * 8;
    (BALL_MEMORY_BYTES / per.max(1)).clamp(8, 256)
}
/// Above the finest level, blocks of this many pixels a side are the smallest tested.
const MIN_BLOCK_ABOVE_FINEST: u32 = 8;

/// One end of a segment: a reference viewpoint and its slab layers (nearest first).
#[derive(Clone, Copy)]
pub struct SegmentEnd<'a> {
    pub viewpoint: DVec3,
    pub grid: &'a TileGrid,
    pub layers: &'a [SlabLayer],
}

/// Which later-slab tiles of each end are hidden from every point of a segment.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SegmentVerdict {
    /// Per end, per slab, per tile (as in `layers[k].tiles`): hidden from the whole segment.
    /// The nearest slab is never hidden.
    pub hidden: Vec<Vec<Vec<bool>>>,
    pub stats: RenderedStats,
}

/// A later-slab tile still being decided.
struct Candidate {
    end: usize,
    slab: usize,
    tile: usize,
    /// The level its tests start at.
    start: Option<u32>,
    /// Balls of the current level it must still be hidden from.
    balls: Vec<u32>,
    /// Balls of the next level.
    next: Vec<u32>,
    kept: bool,
    tests: u64,
}

/// Decide every later-slab tile of `ends` against the segment `path` (a polyline, both ends
/// included; one point for a track of one viewpoint). `render` gives the depth seen from ball
/// centres at the face size — whole renders, or rays cast where the tests look ([`BallDepth`];
/// `None` for a centre inside a solid, which proves nothing).
pub fn hidden_from_segment<'g, E>(
    path: &[DVec3],
    ends: &[SegmentEnd],
    params: &RenderedParams,
    mut render: impl FnMut(&[DVec3]) -> Result<Vec<Option<BallDepth<'g>>>, E>,
) -> Result<Result<SegmentVerdict, OcclusionError>, E> {
    let Some(first) = ends.first() else {
        return Ok(Ok(SegmentVerdict::default()));
    };
    let (grid, tol) = match checked_ends(first.grid, ends, params) {
        Ok(checked) => checked,
        Err(e) => return Ok(Err(e)),
    };
    let mut verdict = SegmentVerdict {
        hidden: ends
            .iter()
            .map(|e| {
                e.layers
                    .iter()
                    .map(|l| vec![false; l.tiles.len()])
                    .collect()
            })
            .collect(),
        stats: RenderedStats::default(),
    };
    let (coarse, levels) = params.levels();
    let zero_length = path.len() < 2 || path.windows(2).all(|w| w[0] == w[1]);
    let levels = if zero_length { 0 } else { levels };
    let top = if zero_length { 1 } else { coarse };
    let length: f64 = path.windows(2).map(|w| w[0].distance(w[1])).sum();
    // The radius of the balls of each level.
    let radius = |level: u32| 0.5 * length / (top << level) as f64;
    let theta =
        params.max_parallax_px.max(0.0) * std::f64::consts::FRAC_PI_2 / grid.face_size as f64;
    let mut cands: Vec<Candidate> = Vec::new();
    for (ei, e) in ends.iter().enumerate() {
        let seen_here = seen_from_reference(e.layers);
        for (k, l) in e.layers.iter().enumerate().skip(1) {
            for (ti, t) in l.tiles.iter().enumerate() {
                verdict.stats.tiles += 1;
                let seen = tile_marked(&seen_here, &grid, k, t.id);
                // A ball proves nothing behind an occluder its radius spans more than the
                // parallax limit from: start at the first level whose balls are small enough
                // for the occluders the viewpoint sees in front of the tile (moved at most
                // the segment's length). Past the finest level nothing can be proven.
                let occluder = front_depth(e.layers, k, &grid, t.id) + length;
                let start = (0..=levels).find(|&l| radius(l) <= theta * occluder);
                cands.push(Candidate {
                    end: ei,
                    slab: k,
                    tile: ti,
                    start: if zero_length { Some(0) } else { start },
                    balls: Vec::new(),
                    next: Vec::new(),
                    kept: seen || (!zero_length && start.is_none()),
                    tests: 0,
                });
            }
        }
    }
    for level in 0..=levels {
        let pieces = top << level;
        for c in cands
            .iter_mut()
            .filter(|c| !c.kept && c.start == Some(level))
        {
            c.balls = (0..pieces as u32).collect();
        }
        let balls = if zero_length {
            vec![super::Ball {
                centre: path[0],
                radius: 0.0,
            }]
        } else {
            cover(path, pieces)
        };
        let mut needed: Vec<u32> = cands
            .iter()
            .filter(|c| !c.kept)
            .flat_map(|c| c.balls.iter().copied())
            .collect();
        needed.sort_unstable();
        needed.dedup();
        if needed.is_empty() {
            continue;
        }
        for chunk in needed.chunks(balls_at_a_time(grid.face_size)) {
            let centres: Vec<DVec3> = chunk.iter().map(|&b| balls[b as usize].centre).collect();
            let depths = render(&centres)?;
            verdict.stats.renders += chunk.len() as u64;
            let n = grid.face_size;
            let views: Vec<(u32, BallView)> = chunk
                .par_iter()
                .zip(depths)
                .map(|(&b, d)| {
                    let ball = balls[b as usize];
                    let d = d.unwrap_or_else(|| BallDepth::Map(CubeMap::filled(n, f32::INFINITY)));
                    let view =
                        BallView::new(ball, d, n, params.discontinuity, params.max_parallax_px);
                    (b, view)
                })
                .collect();
            let last = level == levels;
            cands.par_iter_mut().filter(|c| !c.kept).for_each(|c| {
                for (b, view) in &views {
                    if c.kept || !c.balls.contains(b) {
                        continue;
                    }
                    let e = &ends[c.end];
                    let layer = &e.layers[c.slab];
                    let tile = &layer.tiles[c.tile];
                    let rect = grid.pixel_rect(tile.id);
                    let probe = Probe {
                        v: e.viewpoint,
                        layer,
                        face: tile.id.face,
                        n,
                        tol,
                        grow: params.content.search_radius as f64,
                        // Above the finest level a block that fails sends the tile to the
                        // ball's halves; single pixels are worth testing only at the end.
                        min_block: if last { 1 } else { MIN_BLOCK_ABOVE_FINEST },
                    };
                    let (hidden, tests) =
                        probe.block_hidden(view, (rect.x0, rect.y0, rect.x1, rect.y1));
                    c.tests += tests;
                    if hidden {
                        continue;
                    }
                    if last || probe.seen(view, (rect.x0, rect.y0, rect.x1, rect.y1)) {
                        c.kept = true;
                        break;
                    }
                    c.next.extend([2 * b, 2 * b + 1]);
                }
            });
        }
        for c in &mut cands {
            c.balls = std::mem::take(&mut c.next);
        }
    }
    for c in &cands {
        verdict.stats.tests += c.tests;
        if !c.kept {
            verdict.hidden[c.end][c.slab][c.tile] = true;
            verdict.stats.culled += 1;
        }
    }
    Ok(Ok(verdict))
}

/// The ends' common tile grid (each end's layers checked against it) and the depth
/// tolerance of the oracle's match rule at its face size.
fn checked_ends(
    grid: &TileGrid,
    ends: &[SegmentEnd],
    params: &RenderedParams,
) -> Result<(TileGrid, f64), OcclusionError> {
    let grid = *grid;
    for e in ends {
        if *e.grid != grid {
            return Err(OcclusionError::Input {
                what: "segment ends".into(),
                message: "the two ends have different tile grids".into(),
            });
        }
        crate::cull::check_layers(&grid, e.layers)?;
    }
    let tol = crate::cull::content_tolerance(&params.content, grid.face_size)?;
    Ok((grid, tol))
}

/// The layer pixels the reference viewpoint itself sees: opaque, with no nearer slab opaque
/// at the same pixel.
fn seen_from_reference(layers: &[SlabLayer]) -> Visibility {
    let n = layers.first().map_or(1, |l| l.alpha.face_size());
    let vis = Visibility::new(n, layers.len());
    for face in Face::ALL {
        for y in 0..n {
            for x in 0..n {
                if let Some(k) = layers.iter().position(|l| *l.alpha.get(face, x, y) >= 128) {
                    vis.mark(k, face, x, y);
                }
            }
        }
    }
    vis
}

/// The farthest of the surfaces in front of tile `id` of slab `k` at its opaque pixels (the
/// nearest earlier slab opaque there); 0 where none is.
fn front_depth(layers: &[SlabLayer], k: usize, grid: &TileGrid, id: tracks::TileId) -> f64 {
    let r = grid.pixel_rect(id);
    let mut far = 0.0f64;
    for y in r.y0..r.y1 {
        for x in r.x0..r.x1 {
            if *layers[k].alpha.get(id.face, x, y) < 128 {
                continue;
            }
            if let Some(l) = layers[..k]
                .iter()
                .find(|l| *l.alpha.get(id.face, x, y) >= 128)
            {
                let d = *l.depth.get(id.face, x, y) as f64;
                if d.is_finite() {
                    far = far.max(d);
                }
            }
        }
    }
    far
}

/// Whether any pixel of tile `id` of slab `k` is marked.
fn tile_marked(vis: &Visibility, grid: &TileGrid, k: usize, id: tracks::TileId) -> bool {
    let r = grid.pixel_rect(id);
    (r.y0..r.y1).any(|y| (r.x0..r.x1).any(|x| vis.is_visible(k, id.face, x, y)))
}

/// What the block test needs of a tile's layer.
struct Probe<'a> {
    v: DVec3,
    layer: &'a SlabLayer,
    face: Face,
    n: u32,
    tol: f64,
    grow: f64,
    /// Blocks this small (pixels a side) that fail are not split further.
    min_block: u32,
}

impl Probe<'_> {
    /// Whether every opaque pixel of `block` (x0, y0, x1, y1; ends excluded) is hidden from
    /// every point of `view`'s ball: the block as one region first (its pixels' footprints
    /// grown by the search radius, over the depth band of all of them), its quarters where
    /// that fails, single pixels last — each region holds the regions of its pixels, so a
    /// region hidden hides them all. The tests made.
    fn block_hidden(&self, view: &BallView, block: (u32, u32, u32, u32)) -> (bool, u64) {
        let (x0, y0, x1, y1) = block;
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for y in y0..y1 {
            for x in x0..x1 {
                if *self.layer.alpha.get(self.face, x, y) < 128 {
                    continue;
                }
                let r = *self.layer.depth.get(self.face, x, y) as f64;
                if !(r.is_finite() && r > 0.0) {
                    return (false, 0);
                }
                lo = lo.min(r);
                hi = hi.max(r);
            }
        }
        if lo > hi {
            return (true, 0);
        }
        if (std::env::var_os("PIXELS_ONLY").is_none() || (x1 - x0 <= 1 && y1 - y0 <= 1))
            && self.region_hidden(view, block, lo, hi)
        {
            return (true, 1);
        }
        if x1 - x0 <= self.min_block && y1 - y0 <= self.min_block {
            return (false, 1);
        }
        let (xm, ym) = ((x0 + x1).div_ceil(2), (y0 + y1).div_ceil(2));
        let mut tests = 1;
        for q in [
            (x0, y0, xm, ym),
            (xm, y0, x1, ym),
            (x0, ym, xm, y1),
            (xm, ym, x1, y1),
        ] {
            if q.0 >= q.2 || q.1 >= q.3 {
                continue;
            }
            let (hidden, t) = self.block_hidden(view, q);
            tests += t;
            if !hidden {
                return (false, tests);
            }
        }
        (true, tests)
    }

    /// Whether the ball's centre sees an opaque pixel of `block` (its surface point is the
    /// first hit in its direction, within the matching tolerance): the tile is seen from the
    /// segment.
    fn seen(&self, view: &BallView, block: (u32, u32, u32, u32)) -> bool {
        let (x0, y0, x1, y1) = block;
        (y0..y1).any(|y| {
            (x0..x1).any(|x| {
                if *self.layer.alpha.get(self.face, x, y) < 128 {
                    return false;
                }
                let r = *self.layer.depth.get(self.face, x, y) as f64;
                let d = tracks::cubemap::pixel_dir(self.face, x, y, self.n);
                r.is_finite() && view.sees(self.v + r * d, self.tol)
            })
        })
    }

    /// The lemma of the module docs for the region of `block`'s pixels at radial depths
    /// `lo..=hi` from the viewpoint.
    fn region_hidden(
        &self,
        view: &BallView,
        block: (u32, u32, u32, u32),
        lo: f64,
        hi: f64,
    ) -> bool {
        let (x0, y0, x1, y1) = block;
        let (r_lo, r_hi) = (lo / (1.0 + self.tol), hi / (1.0 - self.tol));
        let g = self.grow;
        let (fx0, fy0) = (x0 as f64 - g, y0 as f64 - g);
        let (fx1, fy1) = (x1 as f64 + g, y1 as f64 + g);
        let dirs = [(fx0, fy0), (fx1, fy0), (fx0, fy1), (fx1, fy1)]
            .map(|(px, py)| subpixel_dir(self.face, px, py, self.n).normalize());
        let d0 = subpixel_dir(
            self.face,
            0.5 * (x0 + x1) as f64,
            0.5 * (y0 + y1) as f64,
            self.n,
        )
        .normalize();
        let half = dirs
            .iter()
            .map(|d| d0.angle_between(*d))
            .fold(0.0, f64::max);
        let corners: Vec<DVec3> = dirs
            .iter()
            .flat_map(|d| [self.v + r_lo * *d, self.v + r_hi * *d])
            .collect();
        let bulge = r_hi * (1.0 - half.cos());
        let nearest = nearest_distance(view.ball.centre - self.v, d0, half, r_lo, r_hi);
        view.hides(&corners, bulge, nearest)
    }
}
