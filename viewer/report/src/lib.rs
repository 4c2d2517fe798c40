//! The demo report: `OUT/report/index.html` and `OUT/report/index.md` built from what the
//! pipeline stages left in a demo directory.
//!
//! - [`Layout`]: where each stage's outputs live inside the demo directory.
//! - [`RunLog`] / [`StageRecord`]: which commands the demo ran, how long they took and whether
//!   they were available (`OUT/demo.json`); every number in the report cites its command.
//! - [`write_report`]: reads the stage reports as the stages' own types
//!   ([`prerender::store::PrerenderReport`], [`slabs::report::SlabsReport`],
//!   [`occlusion::report::CullReport`], [`streamer::walk::WalkReport`],
//!   [`viewer::eval::report::EvalReport`], [`tune::report::SweepReport`]), copies and composes
//!   the pictures into `OUT/report/`, and writes both pages from one list of [`doc::Block`]s.
//!   A stage whose outputs are missing or unreadable gives a section that says so instead of
//!   failing the report.
//! - [`images`]: the pictures (horizon strips of stored cube maps, checked copies of plots).
//!
//! ```no_run
//! # fn main() -> Result<(), report::ReportError> {
//! let layout = report::Layout::new("railview-demo");
//! let log = report::RunLog::load_or_default(&layout, "castle", "main", 64);
//! let written = report::write_report(&layout, &log)?;
//! println!("{}", written.html.display());
//! # Ok(()) }
//! ```

pub mod doc;
pub mod images;
mod sections;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// What went wrong writing the report or one of its pictures. Each message names the file
/// and already includes the underlying error, so none is a `source` (a chain printed with
/// `{:#}` would repeat it).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// Reading a file or creating a directory failed.
    #[error("{action} {}: {error}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        error: std::io::Error,
    },
    /// Writing a file whole failed.
    #[error("writing {}: {error}", path.display())]
    Write {
        path: PathBuf,
        error: prerender::store::StoreError,
    },
    /// A picture does not decode, or encoding or composing one failed.
    #[error("{action} {}: {error}", path.display())]
    Image {
        action: &'static str,
        path: PathBuf,
        error: image::ImageError,
    },
    /// An image that should be a stored cube map (`N × 6N` pixels) is not.
    #[error("{}: expected a cube map of N × 6N pixels, found {width} × {height}", path.display())]
    NotACubeMap {
        path: PathBuf,
        width: u32,
        height: u32,
    },
    /// A plot's vector copy is not an SVG document.
    #[error("{} is not an SVG document", path.display())]
    NotSvg { path: PathBuf },
    /// `demo.json` could not be encoded.
    #[error("encoding demo.json: {0}")]
    Encode(serde_json::Error),
}

impl ReportError {
    fn io(action: &'static str, path: &Path, error: std::io::Error) -> ReportError {
        ReportError::Io {
            action,
            path: path.to_path_buf(),
            error,
        }
    }
    fn write(path: &Path, error: prerender::store::StoreError) -> ReportError {
        ReportError::Write {
            path: path.to_path_buf(),
            error,
        }
    }
}

/// Create `dir` and its parents.
fn create_dir(dir: &Path) -> Result<(), ReportError> {
    std::fs::create_dir_all(dir).map_err(|e| ReportError::io("creating", dir, e))
}

/// Write `bytes` to `path` whole.
fn write_file(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    prerender::store::write_atomic(path, bytes).map_err(|e| ReportError::write(path, e))
}

/// Where things live in a demo directory.
#[derive(Clone, Debug)]
pub struct Layout {
    root: PathBuf,
}

impl Layout {
    pub fn new(root: impl Into<PathBuf>) -> Layout {
        Layout { root: root.into() }
    }
    pub fn root(&self) -> &Path {
        &self.root
    }
    /// The build stage's work directory (`build.json`, encoded samples); the prerender
    /// directory is inside it, where `railview build --work` looks for it.
    pub fn work(&self) -> PathBuf {
        self.root.join("work")
    }
    /// The prerender directory (samples, `prerender.json`, `slabs.json`, `cull.json`).
    pub fn prerender(&self) -> PathBuf {
        self.work().join("prerender")
    }
    /// The walkthrough database.
    pub fn db(&self) -> PathBuf {
        self.root.join("db")
    }
    pub fn walk(&self) -> PathBuf {
        self.root.join("walk")
    }
    pub fn eval(&self) -> PathBuf {
        self.root.join("eval")
    }
    /// The small sweep over the build's knobs.
    pub fn tune(&self) -> PathBuf {
        self.root.join("tune")
    }
    /// The scene's network of tracks: `network/db`, `network/work` (its prerender directory
    /// inside), `network/walk`.
    pub fn network(&self) -> PathBuf {
        self.root.join("network")
    }
    /// Headless flythrough frames.
    pub fn frames(&self) -> PathBuf {
        self.root.join("frames")
    }
    pub fn report(&self) -> PathBuf {
        self.root.join("report")
    }
    /// The demo's own record of what it ran (`demo.json`).
    pub fn log(&self) -> PathBuf {
        self.root.join("demo.json")
    }
    /// The first existing file called `name` in the directories a stage may write it to.
    pub fn find(&self, name: &str) -> Option<PathBuf> {
        let pre = self.prerender();
        [pre.clone(), pre.join("slabs"), self.work(), self.db()]
            .into_iter()
            .map(|d| d.join(name))
            .find(|p| p.is_file())
    }
}

/// How a stage of the demo ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StageStatus {
    /// Ran to completion (now or in an earlier run whose outputs are still there).
    Done,
    /// This build of `railview` has no such command (or not with these arguments).
    Unavailable,
    /// The command ran and returned an error.
    Failed,
}

impl StageStatus {
    pub fn label(self) -> &'static str {
        match self {
            StageStatus::Done => "done",
            StageStatus::Unavailable => "not available",
            StageStatus::Failed => "failed",
        }
    }
}

/// One command the demo ran.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    /// Stage name (`build`, `walk`, …).
    pub name: String,
    /// The command line, as a person would type it.
    pub command: String,
    pub status: StageStatus,
    /// Wall time of the run that completed it.
    pub seconds: f64,
    /// CPU time of that run, user and system, every thread and the child processes it
    /// waited for (POV-Ray); absent where the system does not say, and in older logs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_seconds: Option<f64>,
    /// Why it is unavailable or failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
}

/// `OUT/demo.json`: the demo's parameters and its stages in the order they ran.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunLog {
    pub scene: String,
    pub track: String,
    pub face_size: u32,
    pub stages: Vec<StageRecord>,
    /// Stages that ran (rather than being reused) in this invocation: what depends on them
    /// must run again too.
    #[serde(skip)]
    pub ran_now: Vec<String>,
}

impl RunLog {
    /// The log of an earlier run in `layout`, or an empty one for these parameters.
    pub fn load_or_default(layout: &Layout, scene: &str, track: &str, face_size: u32) -> RunLog {
        let fresh = RunLog {
            scene: scene.to_string(),
            track: track.to_string(),
            face_size,
            stages: Vec::new(),
            ran_now: Vec::new(),
        };
        match std::fs::read(layout.log()) {
            Ok(bytes) => match serde_json::from_slice::<RunLog>(&bytes) {
                Ok(log) => log,
                Err(e) => {
                    tracing::warn!("{}: {e}; starting a new log", layout.log().display());
                    fresh
                }
            },
            Err(_) => fresh,
        }
    }

    pub fn stage(&self, name: &str) -> Option<&StageRecord> {
        self.stages.iter().find(|s| s.name == name)
    }

    /// Replace the record of `rec.name` (keeping its place) or append it.
    pub fn record(&mut self, rec: StageRecord) {
        match self.stages.iter_mut().find(|s| s.name == rec.name) {
            Some(s) => *s = rec,
            None => self.stages.push(rec),
        }
    }

    pub fn save(&self, layout: &Layout) -> Result<(), ReportError> {
        let bytes = serde_json::to_vec_pretty(self).map_err(ReportError::Encode)?;
        create_dir(layout.root())?;
        write_file(&layout.log(), &bytes)
    }
}

/// What [`write_report`] wrote.
#[derive(Clone, Debug)]
pub struct Written {
    pub html: PathBuf,
    pub markdown: PathBuf,
    /// Section ids whose inputs were missing.
    pub unavailable: Vec<String>,
    /// Table ids present in the page.
    pub tables: Vec<String>,
    /// Image files referenced by the page (relative to the report directory).
    pub images: Vec<String>,
}

/// Build `OUT/report/index.html` and `index.md` from whatever the stages left in `layout`.
pub fn write_report(layout: &Layout, log: &RunLog) -> Result<Written, ReportError> {
    let dir = layout.report();
    create_dir(&dir)?;
    let built = sections::build(layout, log, &dir);
    let title = format!(
        "railview demo: {} / {} at {}² per face",
        log.scene, log.track, log.face_size
    );
    let html = dir.join("index.html");
    let markdown = dir.join("index.md");
    write_file(&html, doc::to_html(&title, &built.blocks).as_bytes())?;
    write_file(
        &markdown,
        doc::to_markdown(&title, &built.blocks).as_bytes(),
    )?;
    let mut tables = Vec::new();
    let mut imgs = Vec::new();
    for b in &built.blocks {
        match b {
            doc::Block::Table(t) => tables.push(t.id.clone()),
            doc::Block::Figures(f) => imgs.extend(f.iter().map(|f| f.src.clone())),
            _ => {}
        }
    }
    Ok(Written {
        html,
        markdown,
        unavailable: built.unavailable,
        tables,
        images: imgs,
    })
}
