//! Error against cost over a build's knobs, and the cheapest database for an error target.
//!
//! - [`knobs`]: [`Knobs`], one configuration of `railview build` (viewpoint spacing, face
//!   size, supersampling, slab count, tile size, mesh error, culling, texture levels), and
//!   [`SweepSpec`], the configurations of a sweep: each knob varied on its own around a base.
//! - [`plan`]: how each configuration's database is made from stages that configurations
//!   share ([`plan::nodes`]: typed stage parameters, [`plan::StageParams`]), each run once
//!   in its own directory.
//! - [`sweep`]: [`Sweep`], running a sweep: the stages as function calls, every database
//!   evaluated on the GPU (`viewer::eval`) and walked ([`walk`], `streamer::walk`).
//! - [`target`]: a build for a PSNR target ([`target::build_for_target`]).
//! - [`record`]: what was measured of a configuration ([`Measured`]: error over the views,
//!   CPU time, bytes, bytes a walk streams, frame time) and the [`Cost`]s to choose by.
//! - [`pareto`]: Pareto fronts of error against each cost, and [`pareto::select`]: the
//!   cheapest configuration whose worst 5 % of views meet a PSNR target (Yang and Crawfis'
//!   future work, sampling chosen by reconstruction error, done per scene).
//! - [`report`]: `sweep.json`, `sweep.csv`, `sweep.md` and the Pareto figures.
//! - [`link`]: starting a stage from another's files.
//!
//! ```
//! use tune::{Knobs, SweepSpec};
//! let spec = SweepSpec {
//!     every: vec![1, 2],
//!     drop_levels: vec![0, 1],
//!     ..SweepSpec::base_only(Knobs::default())
//! };
//! let configs = spec.configs();
//! assert_eq!(configs.len(), 3); // the base, every 2nd viewpoint, the finest level left out
//! assert_eq!(configs[1].label(&spec.base), "every 2nd reference viewpoint");
//! ```

pub mod error;
pub mod knobs;
pub mod link;
pub mod pareto;
pub mod plan;
pub mod record;
pub mod report;
pub mod sweep;
pub mod target;
pub mod walk;

pub use error::{Error, Result};
pub use knobs::{CullChoice, Knobs, SlabSpec, SweepSpec};
pub use record::{Cost, Measured};
/// CPU seconds of a stage (`stages::cost`).
pub use stages::cost;
pub use sweep::{Sweep, SweepParams};
