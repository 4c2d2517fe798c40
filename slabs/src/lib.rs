//! Slabs: depth ranges from a track's depth histogram, and per slab layer the opacity
//! mask, tiles and depth meshes.
//!
//! - [`boundaries::choose`] → [`boundaries::SlabChoice`]: slab boundaries at the valleys of
//!   the [`histogram::DepthHistogram`] of all low-resolution depth passes, as few as the
//!   parallax criterion allows, with a [`boundaries::CriterionReport`] that says why.
//! - [`tiles::tile_sample`] → [`tiles::SampleTiles`]: each slab layer of a viewpoint cut
//!   into [`tracks::TileGrid`] tiles; empty tiles dropped; every kept [`tiles::SlabTile`]
//!   carries its depth range, opacity bits and a [`mesh::TileMesh`].
//! - [`mesh`]: the regular and the adaptive (`spade`) depth mesh of a tile and their error
//!   as parallax pixels at the track's largest baseline.
//! - [`io`]: the per-sample `tiles.json` + `tiles.bin` files later stages read;
//!   [`report`] and [`plot`]: `slabs.json`, `slabs.md`, `histogram.png`.
//!
//! ```
//! use slabs::{choose, tile_sample, ChooseParams, LayerInput, MeshKind, MeshParams, TileParams};
//! use slabs::tiles::{mask_from_depth, split_depth};
//! use tracks::CubeMap;
//!
//! // A wall 2 m away on the left third of every face, a far surface at 50 m elsewhere.
//! let depth = CubeMap::from_fn(16, |_, x, _| if x < 5 { 2.0f32 } else { 50.0 });
//! // Viewpoints 4 m apart, layers of 256 px per face: the wall can reveal the far surface.
//! let choice = choose(&[depth.clone()], 4.0, 256, &ChooseParams::default());
//! assert_eq!(choice.slabs.len(), 2);
//!
//! let layers = split_depth(&depth, &choice.slabs);
//! let masks: Vec<_> = layers.iter().map(mask_from_depth).collect();
//! let inputs: Vec<LayerInput> =
//!     layers.iter().zip(&masks).map(|(depth, mask)| LayerInput { depth, mask }).collect();
//! let params = TileParams {
//!     tile_size: 8,
//!     mesh: MeshParams { baseline_m: 4.0, ..MeshParams::default() },
//!     keep: MeshKind::Adaptive,
//!     measure_both: false,
//! };
//! let tiles = tile_sample(0, &inputs, &params).unwrap();
//! assert_eq!(tiles.layers[0].tiles_before, 12 * 2);
//! assert!(tiles.layers[0].tiles.len() < 24); // tiles with no wall pixel are removed
//! ```
pub mod boundaries;
pub mod histogram;
pub mod io;
pub mod mesh;
pub mod plot;
pub mod report;
pub mod tiles;

pub use boundaries::{choose, ChooseParams, CriterionReport, SlabChoice};
pub use histogram::DepthHistogram;
pub use mesh::{MeshParams, MeshStats, TileMesh};
pub use tiles::{tile_sample, LayerInput, MeshKind, SampleTiles, SlabTile, TileParams};

/// Errors of the slab stage, grouped by who is at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SlabsError {
    /// A parameter or input combination that cannot work (sizes, tile size, …).
    #[error("{0}")]
    Parameter(String),
    /// A tiles file that does not parse.
    #[error("{what}: {message}")]
    Format { what: String, message: String },
}
