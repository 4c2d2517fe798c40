//! The standard walk of a sweep's database: the whole track at walking speed over loopback
//! HTTP with unlimited bandwidth, ACH with prefetch (what `railview walk DB --bandwidth
//! unlimited --strategy ach+prefetch --pause 1` does: the same stage,
//! `streamer::walk::stage`).

use std::path::Path;

use stages::progress::{BarKind, Reporter};
use streamer::walk::stage::{self, WalkParams, WalkSource, WalkStageError};
use streamer::walk::{self, Strategy, WalkConfig, WalkEvent};

use crate::error::{Error, Result};

/// The walk's parameters: `railview walk`'s defaults at `speed_mps` with a pause of 1 s.
fn params(db: &Path, out: &Path, speed_mps: f64) -> Result<WalkParams> {
    let strategies = vec![Strategy::parse("ach+prefetch").map_err(Error::Parameter)?];
    let base = WalkParams::new(
        WalkSource::Dir(db.to_path_buf()),
        out.to_path_buf(),
        strategies,
        vec![None],
    );
    Ok(WalkParams {
        config: WalkConfig {
            speed_mps,
            pause_s: 1.0,
            ..base.config
        },
        ..base
    })
}

/// Walk database `db` (served on 127.0.0.1 for the walk) and write the walk's outputs to
/// `out` (`walk.json`, …); the summary goes to the progress's output.
pub fn standard_walk(db: &Path, out: &Path, speed_mps: f64, progress: &Reporter) -> Result<()> {
    let params = params(db, out, speed_mps)?;
    let frame_dt_s = params.config.frame_dt_s;
    let mut bar = None;
    let result = stage::run(&params, |e| match e {
        WalkEvent::Planned {
            runs,
            frames_per_run,
        } => {
            progress.message(&format!(
                "walk: {runs} runs of {frames_per_run} frames each ({:.0} s of simulated walk per run)",
                frames_per_run as f64 * frame_dt_s
            ));
            bar = Some(progress.bar(runs as u64 * frames_per_run, "", BarKind::Steps));
        }
        WalkEvent::Frame { .. } => {
            if let Some(b) = &bar {
                b.inc(1);
            }
        }
        WalkEvent::Finished(_) => {}
    });
    if let Some(b) = &bar {
        b.finish();
    }
    // The summary of what was measured, also when the walk stopped early.
    let report = match &result {
        Ok(report) => Some(report),
        Err(e) => e.report(),
    };
    if let Some(report) = report {
        progress.output(&walk::summary_markdown(report));
    }
    result?;
    Ok(())
}

impl From<WalkStageError> for Error {
    /// The walk's error as the sweep's, its causes in the same order.
    fn from(e: WalkStageError) -> Error {
        let context = e.to_string();
        match e {
            WalkStageError::Runtime(io) => Error::Io(io).context(context),
            WalkStageError::Synthetic { source, .. } => Error::Io(source).context(context),
            WalkStageError::Server(e) => Error::Server(e),
            WalkStageError::Walk(e) => Error::Walk(e),
            WalkStageError::Stopped { source, .. } => Error::Walk(*source).context(context),
            other => Error::Outcome(other.to_string()),
        }
    }
}
