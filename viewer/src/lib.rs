//! The railview viewer: draws a walkthrough from reference views along a track.
//!
//! - [`RefView`] (`refview`): one reference viewpoint's texture layers (background + one per
//!   slab, with mip chains, see [`texture::Layer`]) and kept tiles, each a depth mesh placed in
//!   3D along the viewpoint's rays.
//! - [`FramePlan`] (`plan`): what one frame draws, as plain data: the two views around the
//!   camera and their smooth blend weights, visible tiles per view within a [`DrawBudget`],
//!   camera-relative reversed-Z uniforms. Unit-tested without a GPU.
//! - [`gpu::Renderer`] executes a plan with wgpu (headless or into a window);
//!   [`cpu::render`] executes the same plan on the CPU as a reference; both return a
//!   [`Frame`] (`frame`, plain data: the CPU path does not go through the GPU module).
//! - [`bench::Bench`] (`bench`): the viewer benchmark (`railview bench-viewer`), its frame
//!   types as data ([`bench::FrameKind`]).
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use viewer::{plan_frame, DrawBudget, RefView};
//! let views: Vec<RefView> = Vec::new(); // e.g. from a prerender directory
//! let camera = tracks::PerspectiveCamera {
//!     position: glam::DVec3::new(0.0, 1.7, 0.0), yaw_deg: 0.0, pitch_deg: 0.0,
//!     fov_deg: 90.0, width: 256, height: 128,
//! };
//! let plan = plan_frame(&views, &camera, 0.0, DrawBudget::default())?;
//! let mut renderer = viewer::gpu::Renderer::new(viewer::gpu::Gpu::new()?)?;
//! let frame = renderer.render(&plan, &views)?;
//! # Ok(()) }
//! ```

pub mod app;
pub mod bench;
pub mod cpu;
pub mod eval;
pub mod feedback;
pub mod flythrough;
pub mod frame;
pub mod gpu;
pub mod headless;
pub mod metrics;
pub mod plan;
pub mod refview;
pub mod source;
pub mod stream;
pub mod synth;
pub mod texture;
pub mod web;

pub use frame::Frame;
pub use plan::{plan_frame, DrawBudget, FramePlan, PlanError};
pub use refview::{LayerMeshing, RefView, ViewError};
