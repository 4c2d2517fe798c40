//! What a sweep measured of one configuration: its error over the views and its costs.

use serde::{Deserialize, Serialize};

use crate::knobs::Knobs;

/// Error of the reconstructed views between reference samples against the ground truth.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ErrorSummary {
    pub views: usize,
    pub psnr_mean_db: f64,
    /// The PSNR 95 % of the views meet or beat.
    pub psnr_worst5_db: f64,
    pub psnr_min_db: f64,
    pub ssim_mean: f64,
    pub ssim_worst5: f64,
    pub holes_mean: f64,
    pub holes_worst5: f64,
    /// Mean PSNR at the configuration's own reference samples (the resampling floor).
    pub psnr_at_samples_db: f64,
}

/// What a configuration costs. CPU seconds are those of the stages that made it, measured
/// when they ran (reused stages keep the cost measured then).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Costs {
    /// Rendering the panoramas and slab layers.
    pub prerender_cpu_s: f64,
    /// Slabs' tiles, culling, PTM encoding, ACH and the manifest.
    pub build_cpu_s: f64,
    /// Bytes of the database's files.
    pub db_bytes: u64,
    /// Bytes a standard walk streams (the whole track at walking speed, unlimited bandwidth).
    pub walk_bytes: u64,
    /// Mean frame time of the evaluated views on the evaluating adapter.
    pub frame_ms: f64,
}

/// One measured configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    pub label: String,
    pub knobs: Knobs,
    pub samples: usize,
    /// Mean distance between consecutive reference viewpoints, metres.
    pub spacing_m: f64,
    pub slab_count: usize,
    /// View pixel over panorama pixel at their centres (1 = matched).
    pub resolution_ratio: f64,
    pub error: ErrorSummary,
    pub costs: Costs,
    /// Directory holding the configuration's database (`db/`) and its evaluation, relative
    /// to the sweep's.
    pub dir: String,
}

/// The costs a configuration can be chosen by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Cost {
    PrerenderCpu,
    BuildCpu,
    DbBytes,
    WalkBytes,
    FrameMs,
}

impl Cost {
    pub const ALL: [Cost; 5] = [
        Cost::PrerenderCpu,
        Cost::BuildCpu,
        Cost::DbBytes,
        Cost::WalkBytes,
        Cost::FrameMs,
    ];

    /// As on the command line: `prerender-cpu`, `build-cpu`, `db-bytes`, `walk-bytes`,
    /// `frame-ms`.
    pub fn name(self) -> &'static str {
        match self {
            Cost::PrerenderCpu => "prerender-cpu",
            Cost::BuildCpu => "build-cpu",
            Cost::DbBytes => "db-bytes",
            Cost::WalkBytes => "walk-bytes",
            Cost::FrameMs => "frame-ms",
        }
    }

    pub fn parse(s: &str) -> Option<Cost> {
        Cost::ALL.into_iter().find(|c| c.name() == s)
    }

    /// Axis label with the unit the value is plotted in ([`Cost::plotted`]).
    pub fn axis(self) -> &'static str {
        match self {
            Cost::PrerenderCpu => "prerender CPU time (s)",
            Cost::BuildCpu => "build CPU time (s)",
            Cost::DbBytes => "database size (MB)",
            Cost::WalkBytes => "bytes streamed by a standard walk (MB)",
            Cost::FrameMs => "frame time (ms)",
        }
    }

    /// Whether it is a measured time (not deterministic from run to run).
    pub fn is_timing(self) -> bool {
        !matches!(self, Cost::DbBytes | Cost::WalkBytes)
    }

    pub fn value(self, m: &Measured) -> f64 {
        let c = &m.costs;
        match self {
            Cost::PrerenderCpu => c.prerender_cpu_s,
            Cost::BuildCpu => c.build_cpu_s,
            Cost::DbBytes => c.db_bytes as f64,
            Cost::WalkBytes => c.walk_bytes as f64,
            Cost::FrameMs => c.frame_ms,
        }
    }

    /// The value in the unit of [`Cost::axis`].
    pub fn plotted(self, m: &Measured) -> f64 {
        match self {
            Cost::DbBytes | Cost::WalkBytes => self.value(m) / 1e6,
            _ => self.value(m),
        }
    }

    /// The value for tables.
    pub fn format(self, v: f64) -> String {
        match self {
            Cost::DbBytes | Cost::WalkBytes => format!("{:.2} MB", v / 1e6),
            Cost::FrameMs => format!("{v:.1} ms"),
            _ => format!("{v:.1} s"),
        }
    }
}
