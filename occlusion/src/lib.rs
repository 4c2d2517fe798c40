//! Track-dependent occlusion culling of slab tiles (Yang & Crawfis §4), with α-acceleration
//! and an exact oracle that measures what culling costs.
//!
//! Main types:
//! - [`SlabLayer`] / [`TileInfo`]: one slab layer of a reference viewpoint (alpha, radial
//!   depth, non-empty tiles with depth ranges and sizes) — plain values, no files.
//! - [`Cell`]: where the viewer may be while a viewpoint is used (the track to both
//!   neighbours).
//! - [`cull_viewpoint`] with [`CullParams`] (α, [`Variant`]) → [`ViewpointCull`]: per slab the
//!   kept and culled tiles. Slabs go front to back; a tile's window is its footprint grown by
//!   its extended projection for every cell point ([`window`]: the paper's equations 1–5 in
//!   vector form on cube faces); the mean opacity of the kept earlier tiles over the window
//!   comes from summed-area tables ([`maps`]); mean ≥ α culls.
//! - [`shrunk`]: the third variant, [`cull_viewpoint_shrunk`] with the scene's [`Solids`]
//!   ([`SceneSolids`]): occluder shrinking against exact solids along the track, refined where
//!   visibility changes; conservative for every point of the cell, openings and occluders
//!   finer than a pixel included (the argument is in its module docs).
//! - [`rendered`]: the fourth variant, a segment at a time ([`hidden_from_segment`]: depth
//!   renders from balls along the segment, split where a tile needs smaller ones) and a
//!   viewpoint from the segments that touch it ([`cull_from_segments`]): image-space occluder
//!   shrinking for scenes whose solids are not at hand (POV-Ray imports); as good as the
//!   renders' sampling (its module docs say where).
//! - [`oracle`]: [`Geometry`] (exact first hits) or depth renders ([`DepthSource`]) at dense
//!   positions along each segment (offset from where the shrunk variant samples) →
//!   [`Visibility`] of every layer pixel → [`score`]: false culls and tightness per slab.
//! - [`report`]: the `cull.json` / `cull.md` report, the per-tile decision file and the
//!   kept/culled atlas image.
//! - [`synth`]: analytic box scenes and layers rendered from them, for tests and benches.
//!
//! ```
//! use glam::DVec3;
//! use occlusion::{cull_viewpoint, synth, Cell, CullParams, Variant};
//! use tracks::{SlabRange, TileGrid};
//!
//! let scene = synth::BoxScene::courtyard(DVec3::ZERO);
//! let grid = TileGrid::new(32, 8).unwrap();
//! let ranges = SlabRange::parse_list("0-5,5-inf").unwrap();
//! let track = [DVec3::new(0.0, 1.7, 0.0), DVec3::new(2.0, 1.7, 0.0)];
//! let layers = synth::render_layers(&scene, track[0], &grid, &ranges).unwrap();
//! let params = CullParams::new(1.0, Variant::Conservative).unwrap();
//! let cull = cull_viewpoint(&Cell::straight(&track, 0), &grid, &layers, &params).unwrap();
//! assert_eq!(cull.slabs[0].culled.len(), 0); // the nearest slab is never culled
//! assert!(cull.slabs[1].culled.len() > 0);   // most of the courtyard is behind the wall
//!
//! // The shrunk variant asks the scene's solids instead of the earlier slabs' depth. What a
//! // pixel holds grows with its size, so it needs finer layers to prove as much behind the
//! // courtyard's 0.4 m walls.
//! let grid = TileGrid::new(128, 16).unwrap();
//! let layers = synth::render_layers(&scene, track[0], &grid, &ranges).unwrap();
//! let solids = occlusion::SceneSolids::boxes(&scene);
//! let params = CullParams::new(1.0, Variant::Shrunk).unwrap();
//! let (shrunk, _) = occlusion::cull_viewpoint_shrunk(
//!     &Cell::straight(&track, 0), &grid, &layers, &params.shrunk, &solids,
//! ).unwrap();
//! assert!(shrunk.slabs[1].culled.len() > 0);
//! ```

pub mod cull;
pub mod input;
pub mod maps;
pub mod oracle;
pub mod rendered;
pub mod report;
pub mod shrunk;
pub mod synth;
pub mod window;

pub use cull::{cull_viewpoint, CullParams, SlabDecision, Variant, ViewpointCull};
pub use input::{raw_rgba_bytes, Cell, SlabLayer, TileInfo};
pub use maps::DiscontinuityRule;
pub use oracle::{
    mark_visible, oracle_track, score, DepthRenders, DepthSource, Geometry, MatchRule, RayCast,
    SlabScore, Visibility,
};
pub use rendered::{
    cull_from_segments, hidden_from_segment, Ball, BallDepth, BallView, RenderedParams,
    RenderedStats, SegmentEnd, SegmentVerdict,
};
pub use shrunk::{cull_viewpoint_shrunk, SceneSolids, ShrunkParams, ShrunkStats, Solids};

/// Errors of the culling library, by who is at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OcclusionError {
    /// A parameter out of range.
    #[error("parameter `{name}`: {message}")]
    Parameter { name: &'static str, message: String },
    /// Inputs that do not fit together (sizes, ranges, depths).
    #[error("{what}: {message}")]
    Input { what: String, message: String },
}
