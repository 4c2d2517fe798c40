//! The standard walk of a sweep's database: the whole track at walking speed over loopback
//! HTTP with unlimited bandwidth, ACH with prefetch (what `railview walk DB --bandwidth
//! unlimited --strategy ach+prefetch --pause 1` does).

use std::path::Path;
use std::time::Duration;

use stages::progress::{BarKind, Reporter};
use streamer::client::RetryPolicy;
use streamer::server::{self, ServedDb};
use streamer::walk::{self, Strategy, WalkConfig, WalkEvent};

use crate::error::{Context, Error, Result};

/// The walk's settings: `railview walk`'s defaults at `speed_mps` with a pause of 1 s.
fn config(speed_mps: f64) -> WalkConfig {
    let ten = Duration::from_secs(10);
    WalkConfig {
        speed_mps,
        pause_s: 1.0,
        retry: RetryPolicy {
            response_timeout: ten,
            stall_timeout: ten,
            connect_timeout: ten,
            give_up_after: Duration::from_secs(30),
            ..RetryPolicy::default()
        },
        ..WalkConfig::default()
    }
}

/// Walk database `db` (served on 127.0.0.1 for the walk) and write the walk's outputs to
/// `out` (`walk.json`, …); the summary goes to the progress's output.
pub fn standard_walk(db: &Path, out: &Path, speed_mps: f64, progress: &Reporter) -> Result<()> {
    let config = config(speed_mps);
    let strategies = [Strategy::parse("ach+prefetch").map_err(Error::Parameter)?];
    let bandwidths = [None];
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let result = rt.block_on(async {
        let served = match ServedDb::open(db) {
            Ok(d) => d,
            Err(e) => {
                // Nothing measured, but walk.json says why.
                let report = walk::WalkReport {
                    speed_mps: config.speed_mps,
                    latency_s: config.latency_s,
                    error: Some(e.to_string()),
                    ..walk::WalkReport::default()
                };
                walk::write_outputs(&report, out)?;
                return Err(Error::from(e));
            }
        };
        let server = server::Loopback::start(served).await?;
        let mut bar = None;
        let result = walk::run_walk(&server.url, &config, &strategies, &bandwidths, |e| match e {
            WalkEvent::Planned {
                runs,
                frames_per_run,
            } => {
                progress.message(&format!(
                    "walk: {runs} runs of {frames_per_run} frames each ({:.0} s of simulated walk per run)",
                    frames_per_run as f64 * config.frame_dt_s
                ));
                bar = Some(progress.bar(runs as u64 * frames_per_run, "", BarKind::Steps));
            }
            WalkEvent::Frame { .. } => {
                if let Some(b) = &bar {
                    b.inc(1);
                }
            }
            WalkEvent::Finished(_) => {}
        })
        .await;
        if let Some(b) = &bar {
            b.finish();
        }
        server.stop().await?;
        Ok(result)
    })?;
    // walk.json is written whatever happened: the finished runs and what a failed one
    // measured stay.
    let (report, error) = match result {
        Ok(r) => (r, None),
        Err(failed) => (failed.report, Some(failed.error)),
    };
    walk::write_outputs(&report, out)?;
    progress.output(&walk::summary_markdown(&report));
    match error {
        None => Ok(()),
        Some(e) => Err(Error::from(e).context(format!(
            "walk of {} stopped ({} of {} runs finished; what was measured is in {})",
            db.display(),
            report.runs.iter().filter(|r| r.completed).count(),
            strategies.len() * bandwidths.len(),
            out.join("walk.json").display()
        ))),
    }
}
