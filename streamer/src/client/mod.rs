//! The streaming client: what the viewer and the walk simulator use to get a database.
//!
//! - [`schedule`]: [`Scheduler`] — the one request policy (what to fetch, when, in what order,
//!   what to keep), without I/O: the viewer's live session drives it on the wall clock, the
//!   walk simulator on a virtual clock and link; [`Dispatcher`] — when its requests go out
//!   and what each carries, the rule both executors follow.
//! - [`http`]: [`Connection`] — one HTTP/1 connection with reconnect and back-off, and
//!   checked downloads ([`Connection::fetch_checked`]: BLAKE3 of every body against the
//!   manifest, re-fetched on mismatch, never returned when wrong).
//! - [`transport`]: [`Source`] and [`Transport`] — a server over HTTP or a database directory,
//!   read the same way (a directory is just another server).
//! - [`pool`]: [`Pool`] — the live executor: workers taking the scheduler's requests as
//!   request slots free up, with cancellation.
//! - [`fetcher`]: [`Fetcher`] — a stand-alone priority queue of checked downloads.
//! - [`failures`]: [`FailureBook`] — per-key object faults (retried later, then given up)
//!   and [`ProgressClock`] — time without progress, on any clock; what a scheduler keeps.
//! - [`cache`]: [`Cache`] — checked bytes under a byte budget, evicted by distance along the
//!   network, with reference counts for shared entries.
//! - [`route`]: [`Walker`] — a position on a network of tracks and the branch taken at a
//!   junction (the user's, else the one nearest the view), [`branch_weights`] for prefetch,
//!   [`Route`] — a walk through named tracks.
//! - [`budget`]: [`plan`] — the PTM memory/time budget rules, live pixel counts, prefetch;
//!   plain functions, no I/O.
//! - [`predict`]: [`MotionTracker`] — speed, stillness and the next segment from recent
//!   positions.
//! - [`items`]: [`ItemTable`] — a manifest's viewpoints flattened into streamable items and
//!   parts, grown as viewpoints' tables arrive.
//! - [`live`]: [`LiveSession`] — the scheduler and the pool on a [`Clock`] for an interactive
//!   viewer.

pub mod budget;
pub mod byteranges;
pub mod cache;
pub mod clock;
pub mod failures;
pub mod fetcher;
pub mod http;
pub mod items;
pub mod live;
pub mod pool;
pub mod predict;
pub mod route;
pub mod schedule;
pub mod transport;

pub use budget::{
    plan, BudgetParams, ItemInfo, LinkEstimate, LiveCount, Plan, PlanInput, PriorityMode,
};
pub use cache::{Cache, CacheError};
pub use clock::{Clock, ManualClock, WallClock};
pub use failures::{FailureBook, FailurePolicy, ProgressClock, Verdict};
pub use fetcher::{FetchOutcome, FetchRequest, Fetcher, FetcherConfig};
pub use http::{
    BundlePiece, ClientError, ClientStats, Connection, FetchKey, ManifestFetch, RetryPolicy,
    ServerUrl, TransferReport,
};
pub use items::{ItemTable, Part};
pub use live::{LiveConfig, LiveError, LiveSession, LiveStats};
pub use pool::{Completion, Pool};
pub use predict::{next_segment, segment_at, MotionTracker};
pub use route::{branch_weights, NetPos, Route, Turn, Walker};
pub use schedule::{
    Actions, Arrival, Batch, DispatchLimits, Dispatcher, Piece, Scheduler, SchedulerConfig,
    Strategy, ViewStats, Want, WantClass,
};
pub use transport::{BatchData, Source, Transport};
