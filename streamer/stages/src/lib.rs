//! The offline pipeline as typed functions. Each stage takes a parameter struct built from
//! the crates' enums, reports what it is doing through a [`Progress`] (it prints nothing
//! itself) and returns a typed result; the `railview` binary only turns command lines into
//! these structs.
//!
//! - [`prerender`]: the reference viewpoints of a track rendered into a prerender directory,
//!   by the built-in tracer or POV-Ray ([`prerender::Renderer`]), sharded and merged.
//! - [`slabs`]: slab boundaries chosen, missing layers rendered, every layer tiled and meshed.
//! - [`cull`]: track-dependent culling of the tiles for every α and variant, with the oracle.
//! - [`encode`]: the kept tiles into the database (PTM textures, meshes, ACH, the manifest)
//!   and the build's report ([`encode::BuildReport`]).
//! - [`build`]: the whole pipeline ([`build::BuildParams`]), each stage a function call.
//! - [`scene`]: scenes and tracks as the stages name them (built-in, TOML files, track files).
//! - [`knobs`]: [`Knobs`], the one knob struct of a build (and of a sweep's configurations),
//!   with [`SlabSpec`] and [`CullChoice`].
//! - [`cost`]: CPU and wall seconds of a stage.
//! - [`progress`]: [`Progress`], [`Bar`], [`Silent`]; [`error`]: [`Error`].
//!
//! ```
//! use stages::{CullChoice, Knobs, SlabSpec};
//! let k = Knobs {
//!     slabs: "fewer".parse().unwrap(),
//!     cull: CullChoice::Off,
//!     ..Knobs::default()
//! };
//! assert_eq!(k.slabs, SlabSpec::Auto(-1));
//! assert_eq!(k.label(&Knobs::default()), "slabs fewer, no culling");
//! ```

pub mod build;
pub mod cost;
pub mod cull;
pub mod encode;
pub mod error;
pub mod knobs;
pub mod network;
pub mod prerender;
pub mod progress;
pub mod scene;
pub mod slabs;

pub use error::{Error, Result};
pub use knobs::{CullChoice, Knobs, SlabSpec};
pub use progress::{Bar, BarKind, Progress, Reporter, Silent};

/// A face size (`--face-size`, `--lowres-face-size`, …): 1 to
/// [`tracks::limits::MAX_FACE_SIZE`] pixels.
pub fn check_face_size(flag: &str, v: u32) -> Result<u32> {
    Ok(tracks::limits::check_u64(flag, v as u64, 1, tracks::limits::MAX_FACE_SIZE as u64)? as u32)
}

/// A count (frames, segments, samples): 1 to `max`.
pub fn check_count(flag: &str, v: usize, max: usize) -> Result<usize> {
    Ok(tracks::limits::check_u64(flag, v as u64, 1, max as u64)? as usize)
}
