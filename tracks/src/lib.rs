//! Shared vocabulary of railview: plain data used by every other crate.
//!
//! - [`cubemap`]: the six faces of a panorama, pixel ↔ direction, tile grids, [`CubeMap`]
//!   storage. Every crate addresses panoramas through this module.
//! - [`rect`]: [`PixelRect`], a rectangle of pixels on one face (a tile's pixels, texels
//!   to rewrite, a window's cover).
//! - [`camera`]: the perspective camera (yaw/pitch/FOV convention) used everywhere.
//! - [`manifest`]: the walkthrough database manifest (content-addressed objects, tiles, PTM
//!   level ranges, ACH per segment).
//! - [`segment`]: where an arc length falls between reference viewpoints and how the two
//!   views around it blend (smoothstep): the one rule of the renderer, the client and the
//!   walk simulator.
//! - [`limits`]: the stated limits on numbers from outside (face sizes, counts, lengths)
//!   that every reader checks before allocating or looping.
//! - [`track`]: named 3D polylines read from TOML, optionally Catmull-Rom smoothed, sampled
//!   into [`ReferenceViewpoint`]s; consecutive viewpoints bound a segment.
//!
//! Units are metres, right-handed, y up. Positions and directions are `f64` ([`glam::DVec3`]).
//! This crate does no I/O: parsers take text and a source name for error messages.
//!
//! ```
//! use tracks::{cubemap::{Face, FaceCoord}, TrackSet};
//! let set = TrackSet::parse(r#"
//!     [[track]]
//!     name = "main"
//!     points = [[0, 1.7, 0], [10, 1.7, 0]]
//!     spacing = 2.5
//! "#, "example.toml").unwrap();
//! let vps = set.get("main").unwrap().viewpoints();
//! assert_eq!(vps.len(), 5);
//! let c = FaceCoord::from_dir(glam::DVec3::X).unwrap();
//! assert_eq!(c.face, Face::PosX);
//! ```

pub mod camera;
pub mod cubemap;
pub mod limits;
pub mod manifest;
pub mod mesh;
pub mod network;
pub mod rect;
pub mod segment;
pub mod slab;
pub mod track;

pub use camera::PerspectiveCamera;
pub use cubemap::{CubeMap, Face, FaceCoord, TileGrid, TileId};
pub use mesh::TileMesh;
pub use rect::PixelRect;
pub use slab::SlabRange;
pub use track::{ReferenceViewpoint, Sampling, Smoothing, Track, TrackError, TrackSet};
