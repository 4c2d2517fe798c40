//! The culling pass of one reference viewpoint (the paper's §4 algorithm, on cube maps).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::{Face, TileGrid};

use crate::input::{Cell, SlabLayer, TileInfo};
use crate::maps::{hole_punched, DiscontinuityRule, OcclusionMap, WindowQuery};
use crate::window::{extended_window, face_pieces, offset_in_face, PixelRect, UvRect};
use crate::OcclusionError;

/// Which depths the extended projections use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// Nearest occluder depth in the window and the occludee's farthest depth, every
    /// direction of motion, depth discontinuities of the occluders treated as holes, and no
    /// culling when the cell reaches the nearest occluder. Zero false culls at α = 1 for
    /// surfaces the occlusion map resolves.
    Conservative,
    /// The paper's simplification: every occluder at the slab boundary, the occludee flat at
    /// its farthest depth (Figure 4c), opacity taken as is.
    Paper,
}

impl Variant {
    pub fn name(self) -> &'static str {
        match self {
            Variant::Conservative => "conservative",
            Variant::Paper => "paper",
        }
    }

    /// Parse `conservative` or `paper`.
    pub fn parse(s: &str) -> Option<Variant> {
        match s.trim() {
            "conservative" => Some(Variant::Conservative),
            "paper" => Some(Variant::Paper),
            _ => None,
        }
    }
}

/// Parameters of one culling run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CullParams {
    /// Opacity threshold: a tile is culled when the mean opacity over its window is ≥ α
    /// (1 = fully opaque; the paper's α-acceleration uses 0.9 and 0.8).
    pub alpha: f64,
    pub variant: Variant,
    /// Conservative variant: which occluder depth jumps are gaps.
    pub discontinuity: DiscontinuityRule,
    /// Conservative variant: rounds of "window → nearest occluder in it → window" before
    /// giving up and keeping the tile.
    pub max_iterations: u32,
}

impl CullParams {
    /// Checked constructor: `alpha` must be in `(0, 1]`.
    pub fn new(alpha: f64, variant: Variant) -> Result<CullParams, OcclusionError> {
        if !(alpha > 0.0 && alpha <= 1.0) {
            return Err(OcclusionError::Parameter {
                name: "alpha",
                message: format!("must be in (0, 1], found {alpha}"),
            });
        }
        Ok(CullParams {
            alpha,
            variant,
            discontinuity: DiscontinuityRule::default(),
            max_iterations: 8,
        })
    }
}

/// The decision for one slab of one viewpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabDecision {
    pub slab: usize,
    pub kept: Vec<TileInfo>,
    pub culled: Vec<TileInfo>,
}

impl SlabDecision {
    pub fn tiles_before(&self) -> usize {
        self.kept.len() + self.culled.len()
    }
    pub fn bytes_before(&self) -> u64 {
        self.bytes_after() + self.culled.iter().map(|t| t.bytes).sum::<u64>()
    }
    pub fn bytes_after(&self) -> u64 {
        self.kept.iter().map(|t| t.bytes).sum()
    }
}

/// The decisions for every slab of one viewpoint, nearest slab first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewpointCull {
    pub slabs: Vec<SlabDecision>,
}

/// Cull the tiles of one reference viewpoint's slab layers (`layers`, nearest first) for the
/// motion in `cell`. Slabs are processed front to back; each tile is tested against the
/// occlusion map of the tiles kept in earlier slabs, and the kept tiles of a slab join the map
/// once the whole slab is done.
pub fn cull_viewpoint(
    cell: &Cell,
    grid: &TileGrid,
    layers: &[SlabLayer],
    params: &CullParams,
) -> Result<ViewpointCull, OcclusionError> {
    check_inputs(cell, grid, layers)?;
    let n = grid.face_size;
    let offsets = cell.offsets();
    let offsets_face: Vec<Vec<_>> = Face::ALL
        .iter()
        .map(|&f| offsets.iter().map(|&b| offset_in_face(f, b)).collect())
        .collect();
    let radius = cell.radius();
    let mut map = OcclusionMap::new(n);
    let mut any_occluder = false;
    let mut out = Vec::with_capacity(layers.len());
    for (k, layer) in layers.iter().enumerate() {
        let keep: Vec<bool> = if !any_occluder {
            vec![true; layer.tiles.len()]
        } else {
            let q = match params.variant {
                Variant::Conservative => WindowQuery::new(
                    &hole_punched(&map, params.discontinuity, radius),
                    &map.opaque,
                    &map.depth,
                ),
                Variant::Paper => WindowQuery::opacity_only(&map.opaque),
            };
            let ctx = TileCtx {
                grid,
                q: &q,
                offsets_face: &offsets_face,
                params,
                near: layer.range.near,
            };
            layer
                .tiles
                .par_iter()
                .map(|t| match params.variant {
                    Variant::Conservative => ctx.keep_conservative(t),
                    Variant::Paper => ctx.keep_paper(t),
                })
                .collect()
        };
        let mut d = SlabDecision {
            slab: k,
            kept: Vec::new(),
            culled: Vec::new(),
        };
        for (t, kept) in layer.tiles.iter().zip(keep) {
            if kept {
                map.add_rect(t.id.face, grid.pixel_rect(t.id), &layer.alpha, &layer.depth);
                any_occluder = true;
                d.kept.push(*t);
            } else {
                d.culled.push(*t);
            }
        }
        out.push(d);
    }
    Ok(ViewpointCull { slabs: out })
}

fn check_inputs(cell: &Cell, grid: &TileGrid, layers: &[SlabLayer]) -> Result<(), OcclusionError> {
    let bad = |message: String| OcclusionError::Input {
        what: "culling input".into(),
        message,
    };
    if !cell.viewpoint.is_finite() || cell.paths.iter().flatten().any(|p| !p.is_finite()) {
        return Err(bad("cell positions must be finite".into()));
    }
    for (k, l) in layers.iter().enumerate() {
        if l.alpha.face_size() != grid.face_size || l.depth.face_size() != grid.face_size {
            return Err(bad(format!(
                "slab {k}: maps are {}² / {}², tile grid is {}²",
                l.alpha.face_size(),
                l.depth.face_size(),
                grid.face_size
            )));
        }
        if k > 0 && l.range.near < layers[k - 1].range.far {
            return Err(bad(format!(
                "slab {k} ({}) starts before slab {} ends ({})",
                l.range.label(),
                k - 1,
                layers[k - 1].range.label()
            )));
        }
        if let Some(t) = l
            .tiles
            .iter()
            .find(|t| t.depth_min.is_nan() || t.depth_max.is_nan() || t.depth_min > t.depth_max)
        {
            return Err(bad(format!(
                "slab {k}: tile {:?} has depth range [{}, {}]",
                t.id, t.depth_min, t.depth_max
            )));
        }
    }
    Ok(())
}

struct TileCtx<'a> {
    grid: &'a TileGrid,
    q: &'a WindowQuery,
    offsets_face: &'a [Vec<glam::DVec3>],
    params: &'a CullParams,
    near: f64,
}

impl TileCtx<'_> {
    fn pieces(&self, face: Face, w: UvRect) -> Vec<PixelRect> {
        face_pieces(face, w, self.grid.face_size)
    }

    fn min_planar(&self, pieces: &[PixelRect], along: Face) -> f64 {
        pieces
            .iter()
            .map(|p| self.q.min_planar_depth(p, along))
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether the mean opacity over the window reaches α.
    fn occluded(&self, pieces: &[PixelRect]) -> bool {
        let area: u64 = pieces.iter().map(|p| p.area()).sum();
        let opaque: u64 = pieces.iter().map(|p| self.q.opaque_count(p)).sum();
        if area == 0 {
            return false;
        }
        if self.params.alpha >= 1.0 {
            opaque == area
        } else {
            opaque as f64 >= self.params.alpha * area as f64
        }
    }

    fn keep_conservative(&self, t: &TileInfo) -> bool {
        let face = t.id.face;
        let rect = UvRect::of_tile(self.grid, t.id);
        let offs = &self.offsets_face[face.index()];
        let h2 = if t.depth_max.is_finite() {
            t.depth_max / (1.0 + rect.min_norm2()).sqrt()
        } else {
            f64::INFINITY
        };
        // h1: a lower bound on the planar depth (along `face`) of every occluder in the
        // window; the window grows as h1 falls, so iterate to a consistent pair.
        let mut h1 = self.min_planar(&self.pieces(face, rect), face);
        for _ in 0..self.params.max_iterations {
            if !(h1.is_finite() && h1 > 0.0) {
                return true;
            }
            let Some(win) = extended_window(rect, offs, h1, h2.max(h1)) else {
                return true;
            };
            if !win.is_finite() {
                return true;
            }
            let pieces = self.pieces(face, win);
            let h_win = self.min_planar(&pieces, face);
            if h_win >= h1 {
                return !self.occluded(&pieces);
            }
            h1 = h_win;
        }
        true
    }

    fn keep_paper(&self, t: &TileInfo) -> bool {
        let face = t.id.face;
        let rect = UvRect::of_tile(self.grid, t.id);
        let (cu, cv) = rect.centre();
        let f = 1.0 / (1.0 + cu * cu + cv * cv).sqrt();
        let h1 = self.near * f;
        let h2 = (t.depth_max * f).max(h1);
        match extended_window(rect, &self.offsets_face[face.index()], h1, h2) {
            Some(win) if win.is_finite() => !self.occluded(&self.pieces(face, win)),
            _ => true,
        }
    }
}
