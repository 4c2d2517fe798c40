//! POV-Ray import: render an unmodified POV-Ray 3.7 scene at a track's reference viewpoints
//! into the same prerender directory the built-in tracer writes ([`crate::store`]).
//!
//! - [`PovImport`]: one scene and its options; [`PovImport::render_base`] renders a sample's
//!   colour, radial depth and low-resolution depth, [`PovImport::render_slabs`] its slab
//!   layers, [`PovImport::render_depths`] depth alone from free positions (for culling),
//!   [`PovImport::render_preview`] an equirectangular preview.
//! - [`PovOptions`]: face sizes, the scene's [`UpAxis`], anti-aliasing, the `povray` binary,
//!   threads, per-render timeout and the work directory for generated files.
//! - [`PovError`]: every failure, each naming its cause (file and line for POV-Ray's own
//!   parse errors, the viewpoint for a camera inside a solid).
//!
//! How (details and measurements in the POV-Ray notes): a wrapper `.pov` includes the scene
//! unchanged and adds a `mesh_camera` with one triangle per cube-map pixel ([`frame`]), so all
//! six faces come out of one render, pixel for pixel in [`tracks::cubemap`]'s convention.
//! Depth is exact via the fog trick ([`decode`]): fogs write `K(1 − e^(−d/Dᵢ))` into the three
//! channels of a 16-bit PNG. A slab `[near, far)` moves every ray's origin out to `near`
//! (mesh camera `location <0,0,near>`) and cuts it at `far` (the mesh camera's maximum ray
//! distance), so lighting, shadows and reflections still come from the whole scene.
//! Coordinates: see [`frame`] for the railview ↔ POV-Ray mapping.
//!
//! ```no_run
//! use prerender::{pov::{PovImport, PovOptions, UpAxis}, store::PrerenderDir};
//! let mut opts = PovOptions::new(64, "out/pov-work");
//! opts.up = UpAxis::Z;
//! let mut import = PovImport::new("/usr/share/povray-3.7/scenes/advanced/landscape.pov", opts)?;
//! let vp = tracks::ReferenceViewpoint { index: 0, s: 0.0, position: glam::DVec3::new(-1.0, 0.3, -1.0) };
//! let dir = PrerenderDir::new("out");
//! let meta = import.render_base(&vp, &dir)?;
//! let slabs = tracks::SlabRange::parse_list("0-2,2-inf").unwrap();
//! import.render_slabs(&vp, &slabs, &dir)?;
//! # Ok::<(), prerender::pov::PovError>(())
//! ```

pub mod decode;
pub mod frame;
mod import;
pub mod runner;
pub mod sdl;

use std::io;
use std::path::PathBuf;
use std::time::Duration;

pub use frame::UpAxis;
pub use import::{
    radiosity_file, DepthRequest, DepthSummary, PovImport, RenderRecord, MAX_PARALLEL_RUNS,
    MAX_SUPERSAMPLE,
};
pub use runner::RenderStats;

use crate::store::StoreError;

/// Errors of a POV-Ray import; each names what went wrong and where.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PovError {
    #[error("cannot read the POV-Ray scene {path}")]
    Scene { path: PathBuf, source: io::Error },
    #[error(
        "POV-Ray is not available: cannot run `{binary}` (install POV-Ray 3.7, on Debian \
         `apt-get install povray povray-includes`, or give the binary's path: \
         `railview import-pov --povray PATH`)"
    )]
    PovrayMissing { binary: PathBuf, source: io::Error },
    #[error("POV-Ray failed on {render} ({status}):\n{message}\n(full log: {log})")]
    Render {
        render: String,
        status: String,
        message: String,
        log: PathBuf,
    },
    #[error("POV-Ray render {render} ran longer than {seconds} s and was stopped (log: {log})")]
    Timeout {
        render: String,
        seconds: f64,
        log: PathBuf,
    },
    #[error("viewpoint {index} at {position_railview} (POV-Ray <{position_pov}>): {message}")]
    Viewpoint {
        index: usize,
        position_railview: glam::DVec3,
        position_pov: glam::DVec3,
        message: String,
    },
    #[error("POV-Ray output {path}: {message}")]
    Output { path: PathBuf, message: String },
    #[error("{path}")]
    Io { path: PathBuf, source: io::Error },
    #[error("option `{name}`: {message}")]
    Parameter { name: &'static str, message: String },
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Options of an import.
#[derive(Clone, Debug)]
pub struct PovOptions {
    /// Cube-map face size of the colour and depth passes and of the slab layers.
    pub face_size: u32,
    /// Face size of the fast low-resolution depth pass (the slab splitter's histogram).
    pub lowres_face_size: u32,
    /// The scene's up axis.
    pub up: UpAxis,
    /// Colour rays per pixel along each axis, 1 to 4, box-filtered in linear light (the mesh
    /// camera cannot anti-alias within a pixel, so colour is rendered at this many times the
    /// face size).
    pub supersample: u32,
    /// The `povray` binary (a name looked up on `PATH`, or a path).
    pub povray: PathBuf,
    /// Render threads (`+WT`).
    pub threads: usize,
    /// Longest a single POV-Ray render may run before it is killed.
    pub timeout: Option<Duration>,
    /// Where wrappers, mesh includes, logs and raw images go.
    pub work_dir: PathBuf,
    /// `File_Gamma` of depth passes; `None`: the scene's first `assumed_gamma` (1.0 if none).
    pub file_gamma: Option<f64>,
}

impl PovOptions {
    /// Defaults: low-res faces of 32, y up, no AA, `povray` from `PATH`, all cores, no timeout.
    pub fn new(face_size: u32, work_dir: impl Into<PathBuf>) -> PovOptions {
        PovOptions {
            face_size,
            lowres_face_size: 32,
            up: UpAxis::Y,
            supersample: 1,
            povray: PathBuf::from("povray"),
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
            timeout: None,
            work_dir: work_dir.into(),
            file_gamma: None,
        }
    }
}
