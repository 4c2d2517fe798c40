//! streamer: railview databases over the network — the HTTP tile server, the streaming
//! client and the walk simulator. The payloads' formats are [`codec`]'s, the database's
//! [`db`]'s; this crate adds tokio and hyper on top of them.
//!
//! - [`server`]: the HTTP tile server (`run(listener, db, config, stats, shutdown)`): manifest
//!   and content-addressed objects with `Range:`, `/bundle`, shaping, limits, graceful
//!   shutdown, hardened against hostile and broken peers.
//! - [`client`]: checked downloads with reconnect ([`client::Connection`]), the prioritised
//!   cancellable [`client::Fetcher`], the distance-evicting [`client::Cache`], the budget
//!   rules ([`client::plan`]) with prefetch ([`client::MotionTracker`]), the I/O-free
//!   [`client::Scheduler`] and [`client::LiveSession`], which drives it on the wall clock for
//!   a viewer.
//! - [`visibility`]: CPU reference of the viewer's tile-visibility pass (live pixel counts and
//!   needed levels per tile for a camera).
//! - [`walk`]: the headless walk simulator (the scheduler on a virtual clock and link), its
//!   report and plot, a synthetic test database and the load generator.
//! - [`hostile`]: slow header senders and stalled readers, for the server's tests and the
//!   attack benchmark.
//!
//! ```no_run
//! # async fn serve() -> Result<(), Box<dyn std::error::Error>> {
//! use std::sync::Arc;
//! use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
//!
//! let db = ServedDb::open(std::path::Path::new("db"))?;
//! let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
//! let stats = Arc::new(ServerStats::default());
//! server::run(listener, db, ServerConfig::default(), stats, std::future::pending()).await?;
//! # Ok(())
//! # }
//! ```

pub mod client;
pub mod hostile;
pub mod server;
pub mod visibility;
pub mod walk;
