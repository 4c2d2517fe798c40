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
