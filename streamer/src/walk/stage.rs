//! The walk as a typed stage: [`WalkParams`] (where the database is, where the outputs go,
//! the walk's settings, the runs) → [`run`] → the [`WalkReport`], with `walk.json`,
//! `walk.csv`, `walk.svg`, `walk.png` and `summary.md` written whatever happened: the runs
//! that finished and what a failed one measured stay, and a database that does not open
//! leaves a `walk.json` saying why. `railview walk` turns its options into [`WalkParams`];
//! the demo and the sweep's standard walk build them directly.
//!
//! ```no_run
//! use streamer::walk::stage::{self, WalkParams, WalkSource};
//! use streamer::walk::Strategy;
//! let params = WalkParams::new(
//!     WalkSource::Dir("db".into()),
//!     "walk".into(),
//!     vec![Strategy::Naive],
//!     vec![Some(2_000_000), None],
//! );
//! let report = stage::run(&params, |_| {})?;
//! print!("{}", streamer::walk::summary_markdown(&report));
//! # Ok::<(), stage::WalkStageError>(())
//! ```

use std::path::PathBuf;
use std::time::Duration;

use super::{
    run_walk, synth, write_outputs, Strategy, WalkConfig, WalkError, WalkEvent, WalkReport,
};
use crate::client::{RetryPolicy, ServerUrl};
use crate::server::{Loopback, ServedDb, ServerError};

/// Where a walk streams from.
#[derive(Clone, Debug, PartialEq)]
pub enum WalkSource {
    /// A database directory, served on 127.0.0.1 (a port the system picks) for the walk.
    Dir(PathBuf),
    /// A server, and its URL as given (messages name it so).
    Url { url: ServerUrl, text: String },
}

impl WalkSource {
    /// How messages name the source: the directory, or the URL as given.
    pub fn name(&self) -> String {
        match self {
            WalkSource::Dir(dir) => dir.display().to_string(),
            WalkSource::Url { text, .. } => text.clone(),
        }
    }
}

/// Everything a walk needs.
#[derive(Clone, Debug)]
pub struct WalkParams {
    pub source: WalkSource,
    /// Output directory: `walk.json`, `walk.csv`, `walk.svg`, `walk.png`, `summary.md`.
    pub out: PathBuf,
    /// The walker, the simulated link's latency and the client's settings.
    pub config: WalkConfig,
    /// Each strategy is run at each bandwidth (bits per second; `None`: unlimited), the
    /// strategies inside the bandwidths.
    pub strategies: Vec<Strategy>,
    pub bandwidths: Vec<Option<u64>>,
    /// Write a synthetic corridor database into the source directory first (tests and
    /// demos; nothing is written for a URL).
    pub synthetic: Option<synth::SynthParams>,
}

/// The walk's timeouts and give-up time, `railview walk`'s defaults: 10 s for a connection
/// and a response head, 10 s between two pieces of a body, a request given up after 30 s.
pub fn default_retry() -> RetryPolicy {
    let ten = Duration::from_secs(10);
    RetryPolicy {
        response_timeout: ten,
        stall_timeout: ten,
        connect_timeout: ten,
        give_up_after: Duration::from_secs(30),
        ..RetryPolicy::default()
    }
}

impl WalkParams {
    /// A walk of `source` into `out` with `railview walk`'s settings ([`WalkConfig`]'s
    /// defaults, [`default_retry`]) over the given runs.
    pub fn new(
        source: WalkSource,
        out: PathBuf,
        strategies: Vec<Strategy>,
        bandwidths: Vec<Option<u64>>,
    ) -> WalkParams {
        WalkParams {
            source,
            out,
            config: WalkConfig {
                retry: default_retry(),
                ..WalkConfig::default()
            },
            strategies,
            bandwidths,
            synthetic: None,
        }
    }
}

/// A bandwidth as `railview walk --bandwidth` takes it (`2mbit`, `56kbit`, `unlimited`),
/// for command lines a person would type; never parsed here.
pub fn rate_arg(bandwidth_bps: Option<u64>) -> String {
    match bandwidth_bps {
        None => "unlimited".into(),
        Some(b) if b >= 1_000_000_000 && b.is_multiple_of(1_000_000_000) => {
            format!("{}gbit", b / 1_000_000_000)
        }
        Some(b) if b >= 1_000_000 && b.is_multiple_of(1_000_000) => {
            format!("{}mbit", b / 1_000_000)
        }
        Some(b) if b >= 1000 && b.is_multiple_of(1000) => format!("{}kbit", b / 1000),
        Some(b) => format!("{b}bit"),
    }
}

/// Errors of a walk stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WalkStageError {
    #[error("starting the async runtime")]
    Runtime(#[source] std::io::Error),
    #[error("writing a synthetic database to {}", .dir.display())]
    Synthetic {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The database does not open (its `walk.json` says so), or the loopback server failed.
    #[error(transparent)]
    Server(#[from] ServerError),
    /// Writing the outputs.
    #[error(transparent)]
    Walk(#[from] WalkError),
    /// The walk stopped before every run finished; the outputs hold what it measured.
    #[error(
        "walk of {name} stopped ({finished} of {runs} runs finished; what was measured is in {})",
        .json.display()
    )]
    Stopped {
        name: String,
        finished: usize,
        runs: usize,
        json: PathBuf,
        report: Box<WalkReport>,
        source: Box<WalkError>,
    },
}

impl WalkStageError {
    /// What a walk that stopped measured (what its outputs hold).
    pub fn report(&self) -> Option<&WalkReport> {
        match self {
            WalkStageError::Stopped { report, .. } => Some(report),
            _ => None,
        }
    }
}

/// Walk every (strategy, bandwidth) of `params` and write the outputs. With a directory, a
/// server is started in-process on 127.0.0.1 and the walk streams from it over loopback
/// HTTP (and it is stopped after); with a URL it streams from there. `progress` hears what
/// the walk does as it goes.
pub fn run(
    params: &WalkParams,
    mut progress: impl FnMut(WalkEvent),
) -> Result<WalkReport, WalkStageError> {
    let config = &params.config;
    let rt = tokio::runtime::Runtime::new().map_err(WalkStageError::Runtime)?;
    let result = rt.block_on(async {
        let (url, server) = match &params.source {
            WalkSource::Url { url, .. } => (url.clone(), None),
            WalkSource::Dir(dir) => {
                if let Some(synthetic) = &params.synthetic {
                    synth::write_synthetic(dir, synthetic).map_err(|source| {
                        WalkStageError::Synthetic {
                            dir: dir.clone(),
                            source,
                        }
                    })?;
                }
                let db = match ServedDb::open(dir) {
                    Ok(db) => db,
                    Err(e) => {
                        // Nothing measured, but walk.json says why.
                        let report = WalkReport {
                            speed_mps: config.speed_mps,
                            latency_s: config.latency_s,
                            error: Some(e.to_string()),
                            ..WalkReport::default()
                        };
                        write_outputs(&report, &params.out)?;
                        return Err(e.into());
                    }
                };
                let server = Loopback::start(db).await?;
                (server.url.clone(), Some(server))
            }
        };
        let strategies = &params.strategies;
        let result = run_walk(&url, config, strategies, &params.bandwidths, &mut progress).await;
        if let Some(server) = server {
            server.stop().await?;
        }
        Ok::<_, WalkStageError>(result)
    })?;
    // walk.json is written whatever happened: the finished runs and what a failed one
    // measured stay.
    let (report, error) = match result {
        Ok(r) => (r, None),
        Err(failed) => (failed.report, Some(failed.error)),
    };
    write_outputs(&report, &params.out)?;
    match error {
        None => Ok(report),
        Some(source) => Err(WalkStageError::Stopped {
            name: params.source.name(),
            finished: report.runs.iter().filter(|r| r.completed).count(),
            runs: params.strategies.len() * params.bandwidths.len(),
            json: params.out.join("walk.json"),
            report: Box::new(report),
            source: Box::new(source),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::server::parse_rate;

    #[test]
    fn rates_print_as_the_command_line_takes_them() {
        for text in ["56kbit", "2mbit", "10mbit", "1gbit", "1500bit", "unlimited"] {
            let rate = parse_rate(text).unwrap();
            assert_eq!(rate_arg(rate), text);
        }
        assert_eq!(rate_arg(Some(2_500_000)), "2500kbit");
    }

    #[test]
    fn a_database_that_does_not_open_leaves_a_walk_json_saying_why() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("walk");
        let params = WalkParams::new(
            WalkSource::Dir(dir.path().join("missing")),
            out.clone(),
            vec![Strategy::Naive],
            vec![None],
        );
        let e = run(&params, |_| {}).unwrap_err();
        assert!(matches!(e, WalkStageError::Server(_)), "{e}");
        let report: WalkReport =
            serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
        assert!(report.error.is_some() && report.runs.is_empty());
    }

    #[test]
    fn a_synthetic_database_is_walked_over_loopback() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("walk");
        let mut params = WalkParams::new(
            WalkSource::Dir(dir.path().join("db")),
            out.clone(),
            vec![Strategy::Naive],
            vec![None],
        );
        params.config.speed_mps = 20.0;
        params.config.pause_s = 0.0;
        params.synthetic = Some(synth::SynthParams::for_face(16, 2.0));
        let mut frames = 0;
        let report = run(&params, |e| {
            if let WalkEvent::Frame { .. } = e {
                frames += 1;
            }
        })
        .unwrap();
        assert_eq!(report.runs.len(), 1);
        assert!(report.runs[0].completed && frames > 0);
        assert!(out.join("walk.json").is_file() && out.join("summary.md").is_file());
    }
}
