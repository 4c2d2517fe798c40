//! The run log: when and where each run of a stage ran, how long each sample took, what it
//! did. Kept apart from the content, so that the content (panoramas, markers, slab tiles,
//! culling decisions, the database) is the same bytes whoever produced it, on one laptop or
//! a cluster, while the reports can still say what the rendering cost.
//!
//! ```text
//! DIR/runs/{stage}[-shard-K-of-N]-{random}.jsonl
//! ```
//!
//! One file per run, created under a name no other run has (`railview_files::create_unique`),
//! so concurrent runs never share a log; one JSON object per line ([`RunEvent`]), appended as
//! the run goes, so a killed run keeps what it logged (its last line may be cut; readers
//! skip it). `railview prerender` without `--shard`, and `--merge`, read every prerender log
//! back to write `prerender.json`: which shard rendered which sample and the summed render
//! time ([`read_runs`]).

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use tracks::SlabRange;

use crate::store::StoreError;

/// The run logs' directory inside a prerender (or build work) directory.
pub const RUNS_DIR: &str = "runs";

/// Largest run log read back (a prerender run logs about 150 bytes per sample; a POV-Ray
/// import about 400 bytes per render). Bigger files are skipped with a warning.
pub const MAX_LOG_BYTES: u64 = 64 << 20;

/// Most run logs read back from one directory; the rest are skipped with a warning.
pub const MAX_LOGS: usize = 100_000;

/// Environment variables of batch systems recorded at the start of a run, so a log line can
/// be traced back to its job (Slurm array task, Kubernetes pod).
const BATCH_VARS: &[&str] = &[
    "SLURM_JOB_ID",
    "SLURM_ARRAY_JOB_ID",
    "SLURM_ARRAY_TASK_ID",
    "SLURM_RESTART_COUNT",
    "SLURMD_NODENAME",
    "JOB_COMPLETION_INDEX",
    "HOSTNAME",
];

/// The first line of every run log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunStart {
    /// `prerender`, `import-pov`, `slabs`, `cull`, `build`.
    pub stage: String,
    /// `K/N` of a sharded run.
    #[serde(default)]
    pub shard: Option<(usize, usize)>,
    pub host: String,
    pub pid: u32,
    /// Seconds since 1970-01-01 UTC.
    pub unix_time: f64,
    pub args: Vec<String>,
    /// Batch-system variables that were set (job and task ids, pod name).
    #[serde(default)]
    pub batch: BTreeMap<String, String>,
}

/// One sample's base pass (colour, depth, low-resolution depth).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleTiming {
    pub index: usize,
    pub face_size: u32,
    pub lowres_face_size: u32,
    pub seconds: f64,
    pub primary_rays: u64,
}

/// One sample's slab layers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayersTiming {
    pub index: usize,
    pub slabs: Vec<SlabRange>,
    pub seconds: f64,
}

/// One line of a run log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum RunEvent {
    Start(RunStart),
    Sample(SampleTiming),
    Layers(LayersTiming),
    /// One POV-Ray render of an import (its timings as POV-Ray reported them).
    Povray(crate::pov::RenderRecord),
    /// The run finished without error: its wall time and what it counted.
    End {
        seconds: f64,
        #[serde(default)]
        counts: BTreeMap<String, serde_json::Value>,
    },
}

/// A run log being written.
#[derive(Debug)]
pub struct RunLog {
    path: PathBuf,
    file: Mutex<File>,
    started: Instant,
}

fn host_name() -> String {
    fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown".into())
}

impl RunLog {
    /// Start the log of a run of `stage` in `dir/runs/`, writing its [`RunStart`] line.
    pub fn create(
        dir: &Path,
        stage: &str,
        shard: Option<(usize, usize)>,
    ) -> Result<RunLog, StoreError> {
        let runs = dir.join(RUNS_DIR);
        let prefix = match shard {
            Some((k, n)) => format!("{stage}-shard-{k}-of-{n}-"),
            None => format!("{stage}-"),
        };
        let (file, path) =
            railview_files::create_unique(&runs, &prefix, ".jsonl").map_err(|error| {
                StoreError::Io {
                    path: runs.clone(),
                    error,
                }
            })?;
        let log = RunLog {
            path,
            file: Mutex::new(file),
            started: Instant::now(),
        };
        let batch = BATCH_VARS
            .iter()
            .filter_map(|v| std::env::var(v).ok().map(|x| (v.to_string(), x)))
            .collect();
        log.log(&RunEvent::Start(RunStart {
            stage: stage.into(),
            shard,
            host: host_name(),
            pid: std::process::id(),
            unix_time: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
            args: std::env::args().collect(),
            batch,
        }))?;
        Ok(log)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Append one event (one line, written and flushed at once).
    pub fn log(&self, event: &RunEvent) -> Result<(), StoreError> {
        let mut line = serde_json::to_string(event).map_err(|e| StoreError::Format {
            path: self.path.clone(),
            message: format!("cannot serialise a log event: {e}"),
        })?;
        line.push('\n');
        // A poisoned lock only means another thread panicked mid-write; the file is still ours.
        let mut f = self.file.lock().unwrap_or_else(|p| p.into_inner());
        f.write_all(line.as_bytes())
            .and_then(|()| f.flush())
            .map_err(|error| StoreError::Io {
                path: self.path.clone(),
                error,
            })
    }

    /// Log the end of the run: its wall time since [`RunLog::create`] and `counts`.
    pub fn end(&self, counts: &[(&str, serde_json::Value)]) -> Result<f64, StoreError> {
        let seconds = self.started.elapsed().as_secs_f64();
        self.log(&RunEvent::End {
            seconds,
            counts: counts
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect(),
        })?;
        Ok(seconds)
    }
}

/// One run read back.
#[derive(Clone, Debug)]
pub struct Run {
    pub path: PathBuf,
    pub start: RunStart,
    /// Every event after the start, in order.
    pub events: Vec<RunEvent>,
}

impl Run {
    /// Whether the run logged its end (it finished without error).
    pub fn ended(&self) -> bool {
        self.events
            .iter()
            .any(|e| matches!(e, RunEvent::End { .. }))
    }
}

/// Every readable run log in `dir/runs/`, oldest start first (ties by file name), and
/// warnings for what was skipped: files too large, without a start line, lines that do not
/// parse (a killed run's last line). A missing `runs/` is no runs.
pub fn read_runs(dir: &Path) -> Result<(Vec<Run>, Vec<String>), StoreError> {
    let runs_dir = dir.join(RUNS_DIR);
    let entries = match fs::read_dir(&runs_dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((Vec::new(), Vec::new())),
        Err(error) => {
            return Err(StoreError::Io {
                path: runs_dir,
                error,
            })
        }
    };
    let mut paths: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "jsonl"))
        .collect();
    paths.sort();
    let mut warnings = Vec::new();
    if paths.len() > MAX_LOGS {
        warnings.push(format!(
            "{}: {} run logs, reading the first {MAX_LOGS}",
            runs_dir.display(),
            paths.len()
        ));
        paths.truncate(MAX_LOGS);
    }
    let mut runs = Vec::new();
    for path in paths {
        let file = match File::open(&path) {
            Ok(f) => f,
            Err(e) => {
                warnings.push(format!("{}: {e}", path.display()));
                continue;
            }
        };
        let len = file.metadata().map(|m| m.len()).unwrap_or(0);
        if len > MAX_LOG_BYTES {
            warnings.push(format!(
                "{}: {len} bytes, more than a run log may hold ({MAX_LOG_BYTES}); skipped",
                path.display()
            ));
            continue;
        }
        let mut start = None;
        let mut events = Vec::new();
        let reader = BufReader::new(file.take(MAX_LOG_BYTES));
        for (n, line) in reader.lines().enumerate() {
            let line = match line {
                Ok(l) => l,
                Err(e) => {
                    warnings.push(format!("{} line {}: {e}", path.display(), n + 1));
                    break;
                }
            };
            if line.trim().is_empty() {
                continue;
            }
            match serde_json::from_str::<RunEvent>(&line) {
                Ok(RunEvent::Start(s)) if start.is_none() && n == 0 => start = Some(s),
                Ok(e) if start.is_some() => events.push(e),
                Ok(_) => {
                    warnings.push(format!(
                        "{} line {}: a run log starts with one `start` line",
                        path.display(),
                        n + 1
                    ));
                    break;
                }
                Err(e) => warnings.push(format!("{} line {}: {e}", path.display(), n + 1)),
            }
        }
        match start {
            Some(start) => runs.push(Run {
                path,
                start,
                events,
            }),
            None => warnings.push(format!("{}: no start line; skipped", path.display())),
        }
    }
    runs.sort_by(|a, b| {
        a.start
            .unix_time
            .total_cmp(&b.start.unix_time)
            .then_with(|| a.path.cmp(&b.path))
    });
    Ok((runs, warnings))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("railview-runlog-{name}-{}", std::process::id()));
        fs::remove_dir_all(&d).ok();
        d
    }

    fn timing(index: usize, seconds: f64) -> RunEvent {
        RunEvent::Sample(SampleTiming {
            index,
            face_size: 8,
            lowres_face_size: 4,
            seconds,
            primary_rays: 100,
        })
    }

    #[test]
    fn logs_round_trip_and_each_run_has_its_own_file() {
        let d = scratch("round");
        let a = RunLog::create(&d, "prerender", Some((1, 4))).unwrap();
        let b = RunLog::create(&d, "prerender", Some((1, 4))).unwrap();
        assert_ne!(a.path(), b.path());
        assert!(a
            .path()
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("prerender-shard-1-of-4-"));
        a.log(&timing(1, 0.5)).unwrap();
        a.end(&[("rendered", 1.into())]).unwrap();
        b.log(&timing(5, 0.25)).unwrap();
        let (runs, warnings) = read_runs(&d).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(runs.len(), 2);
        let ra = runs.iter().find(|r| r.path == a.path()).unwrap();
        assert_eq!(ra.start.shard, Some((1, 4)));
        assert_eq!(ra.start.stage, "prerender");
        assert_eq!(ra.events[0], timing(1, 0.5));
        assert!(ra.ended());
        let rb = runs.iter().find(|r| r.path == b.path()).unwrap();
        assert!(!rb.ended());
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn a_cut_last_line_is_skipped_with_a_warning() {
        let d = scratch("cut");
        let a = RunLog::create(&d, "prerender", None).unwrap();
        a.log(&timing(0, 1.0)).unwrap();
        let path = a.path().to_path_buf();
        drop(a);
        let mut f = fs::OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"{\"event\":\"sample\",\"ind").unwrap();
        fs::write(
            d.join(RUNS_DIR).join("stray.jsonl"),
            b"{\"event\":\"end\"}\n",
        )
        .unwrap();
        fs::write(d.join(RUNS_DIR).join("notes.txt"), b"not a log").unwrap();
        let (runs, warnings) = read_runs(&d).unwrap();
        assert_eq!(runs.len(), 1);
        assert_eq!(runs[0].events, vec![timing(0, 1.0)]);
        assert_eq!(warnings.len(), 3, "{warnings:?}");
        assert!(warnings.iter().any(|w| w.contains("stray.jsonl")));
        fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn no_runs_directory_is_no_runs() {
        let d = scratch("none");
        let (runs, warnings) = read_runs(&d).unwrap();
        assert!(runs.is_empty() && warnings.is_empty());
    }
}
