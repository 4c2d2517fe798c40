//! Slabs: depth ranges from a track's depth histogram, and per slab layer the opacity
//! mask, tiles and depth meshes.
//!
//! - [`boundaries::choose`] → [`boundaries::SlabChoice`]: slab boundaries at the valleys of
//!   the [`histogram::DepthHistogram`] of all low-resolution depth passes, as few as the
//!   parallax criterion allows, with a [`boundaries::CriterionReport`] that says why.
pub mod boundaries;
pub mod histogram;

pub use boundaries::{choose, ChooseParams, CriterionReport, SlabChoice};
pub use histogram::DepthHistogram;
