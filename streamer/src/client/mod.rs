//! The streaming client: what the viewer and the walk simulator use to get a database.
//!
//! - [`http`]: [`Connection`] — one HTTP/1 connection with reconnect and back-off, and
//!   checked downloads ([`Connection::fetch_checked`]: BLAKE3 of every body against the
//!   manifest, re-fetched on mismatch, never returned when wrong).
//! - [`fetcher`]: [`Fetcher`] — a priority queue served by a fixed number of workers (the
//!   limit on requests in flight), with cancellation of stale requests.
//! - [`failures`]: [`FailureBook`] — per-key object faults (retried later, then given up)
//!   and [`ProgressClock`] — time without progress, on any clock; what a scheduler keeps.
//! - [`cache`]: [`Cache`] — checked bytes under a byte budget, evicted by distance along the
//!   track, with reference counts for shared entries.
//! - [`budget`]: [`plan`] — the PTM memory/time budget rules, live pixel counts, prefetch;
//!   plain functions, no I/O.
//! - [`predict`]: [`MotionTracker`] — speed, stillness and the next segment from recent
//!   positions.
//! - [`items`]: [`ItemTable`] — a manifest flattened into streamable items and parts, grown
//!   as viewpoints' tables arrive ([`ItemTable::empty`], [`ItemTable::add_viewpoint`]; the
//!   tables themselves come from [`Connection::fetch_table`] or through the fetcher).
//! - [`live`]: [`LiveSession`] — all of the above on the wall clock for an interactive viewer.

pub mod budget;
pub mod cache;
pub mod failures;
pub mod fetcher;
pub mod http;
pub mod items;
pub mod live;
pub mod predict;

pub use budget::{
    plan, BudgetParams, ItemInfo, LinkEstimate, LiveCount, Plan, PlanInput, PriorityMode,
};
pub use cache::{Cache, CacheError};
pub use failures::{FailureBook, FailurePolicy, ProgressClock, Verdict};
pub use fetcher::{FetchOutcome, FetchRequest, Fetcher, FetcherConfig};
pub use http::{
    BundlePiece, ClientError, ClientStats, Connection, FetchKey, ManifestFetch, RetryPolicy,
    ServerUrl, TransferReport,
};
pub use items::{ItemTable, Part};
pub use live::{Arrival, LiveConfig, LiveError, LiveSession, LiveStats};
pub use predict::{next_segment, segment_at, MotionTracker};
