//! The report's sections, each built from one stage's outputs. Stage reports are read as the
//! types their stages write (a stage that adds fields never breaks the report: unknown fields
//! are ignored), and a missing or unreadable one gives a "not available" note.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

mod network;
mod results;
mod scene;
mod tables;

use super::doc::{Block, Figure, Table};
use super::images;
use super::{Layout, RunLog, StageRecord, StageStatus};

/// The blocks of the page and the ids of sections whose inputs were missing.
pub struct Built {
    pub blocks: Vec<Block>,
    pub unavailable: Vec<String>,
}

struct Ctx<'a> {
    layout: &'a Layout,
    log: &'a RunLog,
    dir: &'a Path,
    blocks: Vec<Block>,
    unavailable: Vec<String>,
    current: String,
}

impl Ctx<'_> {
    fn section(&mut self, id: &str, title: &str) {
        self.current = id.to_string();
        self.blocks.push(Block::Section {
            id: id.into(),
            title: title.into(),
        });
    }
    fn push(&mut self, b: Block) {
        self.blocks.push(b);
    }
    /// Note that (part of) the current section is missing, and why.
    fn missing(&mut self, why: String) {
        if !self.unavailable.contains(&self.current) {
            self.unavailable.push(self.current.clone());
        }
        self.blocks.push(Block::Unavailable(why));
    }
    /// The command the demo ran for `stage`, or the one a person would run.
    fn command(&self, stage: &str, fallback: String) -> String {
        self.log
            .stage(stage)
            .map(|s| s.command.clone())
            .unwrap_or(fallback)
    }
    /// Why a stage's outputs are missing, from the log.
    fn why_missing(&self, stage: &str, file: &str) -> String {
        match self.log.stage(stage) {
            Some(s) if s.status != StageStatus::Done => format!(
                "`{}` {}{}",
                s.command,
                s.status.label(),
                s.message
                    .as_deref()
                    .map(|m| format!(": {}", first_line(m)))
                    .unwrap_or_default()
            ),
            _ => format!("no `{file}` was found in {}", self.layout.root().display()),
        }
    }
    /// A stage's JSON report as its type, or `None` with a note saying why it is missing or
    /// unreadable.
    fn stage_report<T: DeserializeOwned>(
        &mut self,
        path: Option<PathBuf>,
        stage: &str,
        file: &str,
    ) -> Option<(PathBuf, T)> {
        let Some(path) = path.filter(|p| p.is_file()) else {
            let why = self.why_missing(stage, file);
            self.missing(why);
            return None;
        };
        match read_json(&path) {
            Ok(v) => Some((path, v)),
            Err(e) => {
                self.missing(e);
                None
            }
        }
    }
    fn path_arg(&self, p: PathBuf) -> String {
        p.display().to_string()
    }
    /// Compose a cube map's horizon strip into the report directory; `None` (with a note)
    /// when the source is missing or unreadable.
    fn strip(&mut self, src: &Path, name: &str) -> Option<String> {
        match images::horizon_strip(src)
            .and_then(|img| images::save_png(&img, &self.dir.join(name)))
        {
            Ok(()) => Some(name.to_string()),
            Err(e) => {
                self.missing(format!("{e:#}"));
                None
            }
        }
    }
    /// A plot: its PNG (for the Markdown page) and, when the stage wrote one beside it, its
    /// SVG (for the HTML page), copied as `NAME.png` / `NAME.svg`.
    fn plot(&mut self, png: &Path, name: &str, caption: &str) -> Option<Figure> {
        let src = self.copy(png, &format!("{name}.png"))?;
        let svg = png.with_extension("svg");
        let vector = match images::copy_svg(&svg, &self.dir.join(format!("{name}.svg"))) {
            Ok(true) => Some(format!("{name}.svg")),
            Ok(false) => None,
            Err(e) => {
                self.missing(format!("{e:#}"));
                None
            }
        };
        Some(Figure {
            src,
            caption: caption.to_string(),
            checker: false,
            vector,
        })
    }
    fn copy(&mut self, src: &Path, name: &str) -> Option<String> {
        match images::copy_checked(src, &self.dir.join(name)) {
            Ok(()) => Some(name.to_string()),
            Err(e) => {
                self.missing(format!("{e:#}"));
                None
            }
        }
    }
}

fn first_line(s: &str) -> &str {
    s.lines().next().unwrap_or("")
}

/// A JSON file as `T`; the error names the file.
fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

fn fmt_num(x: Option<f64>, decimals: usize) -> String {
    match x {
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        Some(_) => "∞".into(),
        None => "–".into(),
    }
}

fn fmt_int(x: Option<f64>) -> String {
    fmt_num(x, 0)
}

/// An error statistic, which JSON holds as `null` where it is not finite (the mean over no
/// views, the PSNR of a view without error): `–` then.
fn fmt_stat(x: f64, decimals: usize) -> String {
    fmt_num(Some(x).filter(|x| x.is_finite()), decimals)
}

fn fmt_mb(bytes: f64) -> String {
    format!("{:.3}", bytes / 1e6)
}

fn reduction(before: f64, after: f64) -> String {
    if before > 0.0 {
        format!("{:.1}%", 100.0 * (before - after.min(before)) / before)
    } else {
        "–".into()
    }
}

/// Depth in metres; infinity (JSON `null`, the slab convention) is ∞.
fn fmt_depth(depth_m: f64) -> String {
    fmt_num(Some(depth_m), 2)
}

fn pngs_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| {
                    p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")) && p.is_file()
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// First, middle and last of `n` (deduplicated).
fn spread(n: usize) -> Vec<usize> {
    let mut v = Vec::new();
    for i in [0, n / 2, n.saturating_sub(1)] {
        if i < n && !v.contains(&i) {
            v.push(i);
        }
    }
    v
}

/// Every section, in reading order.
pub fn build(layout: &Layout, log: &RunLog, dir: &Path) -> Built {
    let mut c = Ctx {
        layout,
        log,
        dir,
        blocks: Vec::new(),
        unavailable: Vec::new(),
        current: String::new(),
    };
    overview(&mut c);
    let prerender = scene::viewpoints(&mut c);
    let slabs = scene::histogram(&mut c);
    scene::layers(&mut c);
    let cull = tables::culling(&mut c);
    tables::sizes(&mut c, prerender.as_ref(), slabs.as_ref(), cull.as_ref());
    results::streaming(&mut c);
    results::evaluation(&mut c);
    results::tuning(&mut c);
    results::frames(&mut c);
    network::network(&mut c);
    results::later(&mut c);
    Built {
        blocks: c.blocks,
        unavailable: c.unavailable,
    }
}

fn overview(c: &mut Ctx) {
    c.section("overview", "What ran");
    c.push(Block::Para(format!(
        "The `{}` scene along its `{}` track, pre-rendered as cube maps of {}² pixels per face, \
         split into depth slabs, culled, encoded as progressive texture maps, streamed and \
         viewed. Each section starts with the command that reproduces its numbers and \
         pictures; the stage outputs live in {}.",
        c.log.scene,
        c.log.track,
        c.log.face_size,
        c.layout.root().display()
    )));
    let done = |s: &&StageRecord| s.status == StageStatus::Done;
    let cpu = |s: &StageRecord| s.cpu_seconds.map_or("–".into(), |c| format!("{c:.1}"));
    let mut rows: Vec<Vec<String>> = c
        .log
        .stages
        .iter()
        .map(|s| {
            vec![
                s.name.clone(),
                s.status.label().to_string(),
                if s.status == StageStatus::Done {
                    format!("{:.1}", s.seconds)
                } else {
                    "–".into()
                },
                if s.status == StageStatus::Done {
                    cpu(s)
                } else {
                    "–".into()
                },
                s.command.clone(),
                s.message
                    .as_deref()
                    .map(first_line)
                    .unwrap_or("")
                    .to_string(),
            ]
        })
        .collect();
    let completed: Vec<&StageRecord> = c.log.stages.iter().filter(done).collect();
    let cpu_all: Option<f64> = completed.iter().map(|s| s.cpu_seconds).sum();
    rows.push(vec![
        "all stages".into(),
        format!("{} done", completed.len()),
        format!("{:.1}", completed.iter().map(|s| s.seconds).sum::<f64>()),
        cpu_all.map_or("–".into(), |c| format!("{c:.1}")),
        String::new(),
        String::new(),
    ]);
    c.push(Block::Table(Table {
        id: "stages".into(),
        caption: "Stages of this demo: wall and CPU time of the run that completed each (CPU \
                  of every thread and of the POV-Ray processes it ran)"
            .into(),
        header: ["stage", "status", "wall s", "CPU s", "command", "note"]
            .map(String::from)
            .to_vec(),
        rows,
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_picks_first_middle_last_once() {
        assert_eq!(spread(0), Vec::<usize>::new());
        assert_eq!(spread(1), vec![0]);
        assert_eq!(spread(2), vec![0, 1]);
        assert_eq!(spread(9), vec![0, 4, 8]);
    }

    #[test]
    fn depth_null_is_infinity() {
        let far: slabs::report::SlabSummary = serde_json::from_value(serde_json::json!({
            "near": 12.5, "far": null, "tiles_before": 1, "tiles_after": 1,
            "opaque_pixels": 1, "pixels": 1, "texture_bytes": 4, "mesh_bytes": 0}))
        .unwrap();
        assert_eq!(fmt_depth(far.far), "∞");
        assert_eq!(fmt_depth(far.near), "12.50");
        assert_eq!(fmt_num(None, 2), "–");
    }

    /// The report reads `walk.json` as `WalkReport`, which gained `Deserialize` for it: what
    /// the walk writes (unlimited bandwidth and a first frame never reached are `null`) reads
    /// back the same.
    #[test]
    fn walk_json_reads_back_as_written() {
        use streamer::walk::{RunReport, WalkReport};
        let walk = WalkReport {
            scene: "castle".into(),
            track: "main".into(),
            length_m: 72.0,
            speed_mps: 36.0,
            latency_s: 0.05,
            runs: vec![
                RunReport {
                    strategy: "naive".into(),
                    bandwidth_bps: Some(2_000_000),
                    time_to_first_frame_s: Some(0.75),
                    bytes: 90_000,
                    ..RunReport::default()
                },
                RunReport {
                    strategy: "ach+prefetch".into(),
                    error: Some("the server stopped answering".into()),
                    ..RunReport::default()
                },
            ],
            error: None,
        };
        let json = serde_json::to_vec_pretty(&walk).unwrap();
        let back: WalkReport = serde_json::from_slice(&json).unwrap();
        assert_eq!(serde_json::to_vec_pretty(&back).unwrap(), json);
        assert_eq!(back.runs[1].bandwidth_bps, None);
        assert_eq!(back.runs[1].time_to_first_frame_s, None);
    }

    #[test]
    fn reduction_of_nothing_is_a_dash() {
        assert_eq!(reduction(0.0, 0.0), "–");
        assert_eq!(reduction(200.0, 50.0), "75.0%");
        assert_eq!(reduction(10.0, 20.0), "0.0%");
    }

    #[test]
    fn criterion_numbers_are_flattened() {
        let v = serde_json::json!({"criterion": {"max_spacing_m": 2.5, "parallax_px": [1.25, 0.5]},
                                   "tile_size": 32, "huge": [[1]]});
        let mut out = Vec::new();
        for (k, x) in v.as_object().unwrap() {
            scene::flatten(k, x, &mut out);
        }
        assert!(out.contains(&("criterion.max_spacing_m".into(), "2.5".into())));
        assert!(out.contains(&("criterion.parallax_px".into(), "1.25, 0.5".into())));
        assert!(out.contains(&("tile_size".into(), "32".into())));
        assert!(!out.iter().any(|(k, _)| k == "huge"));
    }
}
