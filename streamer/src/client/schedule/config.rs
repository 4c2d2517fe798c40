//! The scheduler's settings and strategies.

use crate::client::budget::{BudgetParams, PriorityMode};
use crate::client::failures::FailurePolicy;

/// How a client chooses what to download.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Strategy {
    /// Whole full-resolution tiles in manifest order.
    Naive,
    /// Budget rules with a priority source, optionally prefetching the next segment.
    Budget { mode: PriorityMode, prefetch: bool },
}

impl Strategy {
    /// Whether the strategy ranks tiles by the segments' ACH lists (and so fetches them).
    pub fn uses_ach(&self) -> bool {
        matches!(
            self,
            Strategy::Budget {
                mode: PriorityMode::Ach | PriorityMode::Combined { .. },
                ..
            }
        )
    }

    /// Whether it prefetches the predicted next segment.
    pub fn prefetches(&self) -> bool {
        matches!(self, Strategy::Budget { prefetch: true, .. })
    }

    /// `naive`, `ach`, `visibility`, `ach+visibility`, each of the last three `+prefetch`.
    pub fn parse(text: &str) -> Result<Strategy, String> {
        let t = text.trim().to_ascii_lowercase();
        if t == "naive" {
            return Ok(Strategy::Naive);
        }
        let mut ach = false;
        let mut vis = false;
        let mut prefetch = false;
        for part in t.split('+') {
            match part {
                "ach" => ach = true,
                "visibility" | "vis" => vis = true,
                "prefetch" => prefetch = true,
                _ => {
                    return Err(format!(
                        "strategy `{text}`: use naive, ach, visibility, ach+visibility, with optional +prefetch"
                    ))
                }
            }
        }
        let mode = match (ach, vis) {
            (true, false) => PriorityMode::Ach,
            (false, true) => PriorityMode::Visibility,
            (true, true) => PriorityMode::Combined { ach_weight: 0.5 },
            (false, false) => return Err(format!("strategy `{text}`: no priority source")),
        };
        Ok(Strategy::Budget { mode, prefetch })
    }

    pub fn name(&self) -> String {
        match self {
            Strategy::Naive => "naive".into(),
            Strategy::Budget { mode, prefetch } => {
                let m = match mode {
                    PriorityMode::Ach => "ach",
                    PriorityMode::Visibility => "visibility",
                    PriorityMode::Combined { .. } => "ach+visibility",
                };
                if *prefetch {
                    format!("{m}+prefetch")
                } else {
                    m.into()
                }
            }
        }
    }
}

/// Settings of the scheduler; the same defaults for the viewer and the walk simulator.
#[derive(Clone, Debug)]
pub struct SchedulerConfig {
    pub strategy: Strategy,
    /// Byte budget of the cache of downloaded bytes (`naive` keeps everything).
    pub cache_bytes: u64,
    /// Memory/time budgets of the plan (PTM §6.2).
    pub budget: BudgetParams,
    /// Raise `M` and `M_static` to the largest segment known so far at full resolution
    /// ([`BudgetParams::scaled_to`]; never lowered as tables arrive).
    pub scale_budget: bool,
    /// Requests in flight at most.
    pub max_in_flight: usize,
    /// Pieces (meshes, PTM level groups, tables) one request carries at most.
    pub max_pieces: usize,
    /// Smallest byte limit of one request (see [`DispatchLimits::request_bytes`](super::DispatchLimits::request_bytes)).
    pub min_request_bytes: u64,
    /// Largest byte limit of one request.
    pub max_request_bytes: u64,
    /// How far ahead (seconds) motion is predicted for prefetch.
    pub prefetch_horizon_s: f64,
    /// Prefetch widens the view frustum by this turn of the head (degrees, each side).
    pub prefetch_turn_deg: f64,
    /// Prefetch with live counts takes the tiles covering this fraction of the predicted
    /// view's pixels (largest first).
    pub prefetch_coverage: f64,
    /// Rays (columns, rows) of the CPU visibility estimate.
    pub samples: (u32, u32),
    /// Link guess used until downloads have been timed.
    pub prior_bps: f64,
    pub prior_latency_s: f64,
    /// After a failed download, new requests wait this long (seconds).
    pub error_pause_s: f64,
    /// Parts with the same checksum and length fetched and cached once under one key
    /// ([`ItemTable::set_share_parts`](crate::client::ItemTable::set_share_parts); `naive` never shares).
    pub share_parts: bool,
    /// When a damaged or missing part or table is asked for again (seconds of the driver's
    /// clock), and when it is given up.
    pub failures: FailurePolicy,
    /// Tables are fetched in the background only for viewpoints within this distance along
    /// the network (metres), so that what a client asks for and holds grows with what is near
    /// the walker, not with the size of the network.
    pub background_table_radius_m: f64,
}

impl Default for SchedulerConfig {
    fn default() -> Self {
        SchedulerConfig {
            strategy: Strategy::Budget {
                mode: PriorityMode::Combined { ach_weight: 0.5 },
                prefetch: true,
            },
            cache_bytes: 64 << 20,
            budget: BudgetParams::default(),
            scale_budget: true,
            max_in_flight: 6,
            max_pieces: 64,
            min_request_bytes: 16 << 10,
            max_request_bytes: 4 << 20,
            prefetch_horizon_s: 1.0,
            prefetch_turn_deg: 10.0,
            prefetch_coverage: 0.9,
            samples: (48, 27),
            prior_bps: 10e6,
            prior_latency_s: 0.02,
            error_pause_s: 0.5,
            share_parts: true,
            failures: FailurePolicy::default(),
            background_table_radius_m: 200.0,
        }
    }
}
