//! streamer: the PTM codec, the walkthrough database and ACH hints, the HTTP tile server and
//! client, and the walk simulator.
//!
//! - [`ptm`]: progressive texture maps — lossless mip levels sent coarse to fine.
//! - [`entropy`]: the adaptive binary range coder under the PTM's context-modelled levels
//!   and the compact meshes.
//! - [`db`]: the content-addressed database directory (writer, reader, `verify`), the split
//!   manifest (a small top plus one binary tile table per viewpoint, [`db::split`],
//!   [`db::table`], and one pack of its tiles' payloads, [`db::pack`]), the compact mesh
//!   format and ACH (average coverage hints) per track segment.
//! - [`server`]: the HTTP tile server (`run(listener, db, config, stats, shutdown)`): manifest
//!   and content-addressed objects with `Range:`, shaping, limits, graceful shutdown.
//! - [`client`]: checked downloads with reconnect ([`client::Connection`]), the prioritised
//!   cancellable [`client::Fetcher`], the distance-evicting [`client::Cache`], and the budget
//!   rules ([`client::plan`]) with prefetch ([`client::MotionTracker`]).
//! - [`visibility`]: CPU reference of the viewer's tile-visibility pass (live pixel counts and
//!   needed levels per tile for a camera).
//! - [`walk`]: the headless walk simulator, its report and plot, a synthetic test database and
//!   the load generator.
//! - [`hostile`]: slow header senders and stalled readers, for the server's tests and the
//!   attack benchmark.

pub mod client;
pub mod hostile;
pub mod server;
pub mod visibility;
pub mod walk;

// Compatibility path for the binary and the viewer until they import the crates directly.
pub use codec::{entropy, ptm};
// Compatibility path for the binary and the viewer until they import the crates directly.
pub use db;
