//! The report's sections, each built from one stage's outputs. Stage reports are read as JSON
//! values by their documented field names (issues 2–8), so a stage that adds fields never
//! breaks the report and a missing stage gives an "not available" note.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::doc::{Block, Figure, Table};
use super::images;
use super::{Layout, RunLog, StageStatus};

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

fn read_json(path: &Path) -> Result<Value, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

fn num(v: &Value, key: &str) -> Option<f64> {
    v.get(key).and_then(Value::as_f64)
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

/// Depth in metres; JSON `null` is infinity (the slab convention).
fn fmt_depth(v: Option<&Value>) -> String {
    match v {
        Some(Value::Null) => "∞".into(),
        Some(v) => fmt_num(v.as_f64(), 2),
        None => "–".into(),
    }
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
    let prerender = viewpoints(&mut c);
    let slabs = histogram(&mut c);
    layers(&mut c);
    let cull = culling(&mut c);
    sizes(&mut c, prerender.as_ref(), slabs.as_ref(), cull.as_ref());
    streaming(&mut c);
    evaluation(&mut c);
    frames(&mut c);
    later(&mut c);
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
         viewed. Each number below is followed by the command that reproduces it; the stage \
         outputs live in {}.",
        c.log.scene,
        c.log.track,
        c.log.face_size,
        c.layout.root().display()
    )));
    let rows = c
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
                s.command.clone(),
                s.message
                    .as_deref()
                    .map(first_line)
                    .unwrap_or("")
                    .to_string(),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "stages".into(),
        caption: "Stages of this demo (wall time of the run that completed each)".into(),
        header: ["stage", "status", "seconds", "command", "note"]
            .map(String::from)
            .to_vec(),
        rows,
    }));
}

fn viewpoints(c: &mut Ctx) -> Option<Value> {
    c.section("viewpoints", "The scene from a few reference viewpoints");
    let work = c.layout.work();
    let cmd = c.command(
        "prerender",
        format!(
            "railview prerender --scene {} --track {} --face-size {} --out {}",
            c.log.scene,
            c.log.track,
            c.log.face_size,
            c.path_arg(work.clone())
        ),
    );
    let Some(path) = c.layout.find("prerender.json") else {
        let why = c.why_missing("prerender", "prerender.json");
        c.missing(why);
        return None;
    };
    let report = match read_json(&path) {
        Ok(v) => v,
        Err(e) => {
            c.missing(e);
            return None;
        }
    };
    c.push(Block::Command(cmd));
    c.push(Block::Table(Table {
        id: "prerender".into(),
        caption: format!("Prerender ({})", path.display()),
        header: [
            "samples",
            "face size",
            "low-res face",
            "seconds",
            "primary rays/s",
        ]
        .map(String::from)
        .to_vec(),
        rows: vec![vec![
            fmt_int(num(&report, "samples")),
            fmt_int(num(&report, "face_size")),
            fmt_int(num(&report, "lowres_face_size")),
            fmt_num(num(&report, "seconds"), 2),
            fmt_num(num(&report, "rays_per_second"), 0),
        ]],
    }));
    let pre_dir = prerender::store::PrerenderDir::new(path.parent().unwrap_or(Path::new(".")));
    let n = num(&report, "samples").unwrap_or(0.0) as usize;
    let mut figs = Vec::new();
    for i in spread(n) {
        let src = pre_dir.color_png(i);
        let at = pre_dir
            .sample_meta(i)
            .map(|m| format!(" at s = {:.2} m", m.s))
            .unwrap_or_default();
        if let Some(name) = c.strip(&src, &format!("view-{i:04}.png")) {
            figs.push(Figure {
                src: name,
                caption: format!("viewpoint {i}{at}: +x, +z, −x, −z faces (360° around)"),
                checker: false,
            });
        }
    }
    if figs.is_empty() {
        c.missing(format!(
            "no colour cube maps under {}",
            pre_dir.root().display()
        ));
    } else {
        c.push(Block::Figures(figs));
    }
    Some(report)
}

fn histogram(c: &mut Ctx) -> Option<Value> {
    c.section("slabs", "Depth histogram and slab boundaries");
    let cmd = c.command(
        "slabs",
        format!("railview slabs {}", c.path_arg(c.layout.work())),
    );
    let Some(path) = c.layout.find("slabs.json") else {
        let why = c.why_missing("slabs", "slabs.json");
        c.missing(why);
        return None;
    };
    let report = match read_json(&path) {
        Ok(v) => v,
        Err(e) => {
            c.missing(e);
            return None;
        }
    };
    c.push(Block::Command(cmd));
    if let Some(hist) = path
        .parent()
        .map(|d| d.join("histogram.png"))
        .filter(|p| p.is_file())
    {
        if let Some(name) = c.copy(&hist, "histogram.png") {
            c.push(Block::Figures(vec![Figure {
                src: name,
                caption: "depth histogram of the whole track with the chosen slab boundaries"
                    .into(),
                checker: false,
            }]));
        }
    } else {
        c.missing("the slab stage wrote no histogram.png".into());
    }
    let slabs = report
        .get("slabs")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let rows = slabs
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let before = num(s, "tiles_before").unwrap_or(0.0);
            let after = num(s, "tiles_after").unwrap_or(0.0);
            vec![
                k.to_string(),
                fmt_depth(s.get("near")),
                fmt_depth(s.get("far")),
                fmt_int(num(s, "tiles_before")),
                fmt_int(num(s, "tiles_after")),
                reduction(before, after),
                fmt_int(num(s, "pixels")),
                fmt_int(num(s, "bytes")),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "slab-table".into(),
        caption: "Slabs, nearest first: tiles before and after empty-tile removal".into(),
        header: [
            "slab",
            "near (m)",
            "far (m)",
            "tiles",
            "non-empty tiles",
            "removed",
            "pixels",
            "bytes",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
    // The criterion's numbers: every other scalar the slab stage reported.
    let mut crit = Vec::new();
    if let Some(obj) = report.as_object() {
        for (k, v) in obj {
            if k == "slabs" {
                continue;
            }
            flatten(k, v, &mut crit);
        }
    }
    if !crit.is_empty() {
        c.push(Block::Table(Table {
            id: "slab-criterion".into(),
            caption: "Why this many slabs: the numbers of the slab-count criterion".into(),
            header: vec!["quantity".into(), "value".into()],
            rows: crit.into_iter().map(|(k, v)| vec![k, v]).collect(),
        }));
    }
    Some(report)
}

/// Scalars of a JSON object as `a.b` = value rows (arrays of scalars joined, big arrays skipped).
fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, String)>) {
    match v {
        Value::Number(n) => out.push((prefix.into(), format_number(n))),
        Value::String(s) => out.push((prefix.into(), s.clone())),
        Value::Bool(b) => out.push((prefix.into(), b.to_string())),
        Value::Null => out.push((prefix.into(), "∞ / none".into())),
        Value::Object(o) if out.len() < 40 => {
            for (k, v) in o {
                flatten(&format!("{prefix}.{k}"), v, out);
            }
        }
        Value::Array(a) if a.len() <= 16 && a.iter().all(|x| !x.is_object() && !x.is_array()) => {
            let items: Vec<String> = a
                .iter()
                .map(|x| match x {
                    Value::Number(n) => format_number(n),
                    Value::Null => "∞".into(),
                    other => other.to_string().trim_matches('"').to_string(),
                })
                .collect();
            out.push((prefix.into(), items.join(", ")));
        }
        _ => {}
    }
}

fn format_number(n: &serde_json::Number) -> String {
    match (n.as_i64(), n.as_f64()) {
        (Some(i), _) => i.to_string(),
        (None, Some(f)) if f.abs() >= 1e-3 && f.abs() < 1e7 => format!("{f:.4}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string(),
        (None, Some(f)) => format!("{f:.4e}"),
        _ => n.to_string(),
    }
}

fn layers(c: &mut Ctx) {
    c.section("layers", "Slab layers of one viewpoint");
    let Some(path) = c.layout.find("prerender.json") else {
        let why = c.why_missing("prerender", "prerender.json");
        c.missing(why);
        return;
    };
    let pre_dir = prerender::store::PrerenderDir::new(path.parent().unwrap_or(Path::new(".")));
    let n = read_json(&path)
        .ok()
        .and_then(|v| num(&v, "samples"))
        .unwrap_or(0.0) as usize;
    let i = n / 2;
    let Some(meta) = pre_dir.layers_meta(i) else {
        c.missing(format!(
            "viewpoint {i} has no slab layers yet ({} is missing)",
            pre_dir.layers_json(i).display()
        ));
        return;
    };
    let cmd = c.command(
        "slabs",
        format!("railview slabs {}", pre_dir.root().display()),
    );
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "Viewpoint {i}: each slab layer holds the first surface whose distance lies in the \
         slab's range (nearer surfaces removed); transparent pixels (checkerboard) are outside \
         the slab. The full view is first."
    )));
    let mut figs = Vec::new();
    if let Some(name) = c.strip(&pre_dir.color_png(i), &format!("layer-{i:04}-all.png")) {
        figs.push(Figure {
            src: name,
            caption: "all slabs (the panorama)".into(),
            checker: false,
        });
    }
    for (k, range) in meta.slabs.iter().enumerate() {
        let src = pre_dir.slab_color_png(i, k);
        if let Some(name) = c.strip(&src, &format!("layer-{i:04}-slab{k}.png")) {
            let far = if range.far.is_finite() {
                format!("{:.1} m", range.far)
            } else {
                "∞".into()
            };
            figs.push(Figure {
                src: name,
                caption: format!("slab {k}: [{:.1} m, {far})", range.near),
                checker: true,
            });
        }
    }
    c.push(Block::Figures(figs));
}

fn culling(c: &mut Ctx) -> Option<Value> {
    c.section(
        "culling",
        "Track-dependent occlusion culling (the paper's Tables 1–2)",
    );
    let cmd = c.command(
        "cull",
        format!(
            "railview cull {} --alpha 1.0,0.9,0.8 --oracle",
            c.path_arg(c.layout.work())
        ),
    );
    let Some(path) = c.layout.find("cull.json") else {
        let why = c.why_missing("cull", "cull.json");
        c.missing(why);
        return None;
    };
    let report = match read_json(&path) {
        Ok(v) => v,
        Err(e) => {
            c.missing(e);
            return None;
        }
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(
        "Tiles and sizes summed over every reference viewpoint, per slab; size is raw RGBA8 \
         tile colour (the paper's Size column). False culls come from the oracle: tiles culled \
         yet seen as the first visible surface from dense viewpoints along the track."
            .into(),
    ));
    let runs = report
        .get("runs")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let mut variants: Vec<String> = Vec::new();
    for r in &runs {
        let v = r
            .get("variant")
            .and_then(Value::as_str)
            .unwrap_or("?")
            .to_string();
        if !variants.contains(&v) {
            variants.push(v);
        }
    }
    for variant in &variants {
        let rs: Vec<&Value> = runs
            .iter()
            .filter(|r| r.get("variant").and_then(Value::as_str).unwrap_or("?") == variant)
            .collect();
        let slab_count = rs
            .iter()
            .map(|r| r.get("slabs").and_then(Value::as_array).map_or(0, Vec::len))
            .max()
            .unwrap_or(0);
        let mut header = vec!["α".to_string(), "".to_string()];
        for k in 0..slab_count {
            header.push(format!("slab {} before", k + 1));
            header.push("after".into());
            header.push("reduction".into());
        }
        let mut rows = Vec::new();
        for r in &rs {
            let alpha = fmt_num(num(r, "alpha"), 2);
            let slabs = r
                .get("slabs")
                .and_then(Value::as_array)
                .cloned()
                .unwrap_or_default();
            let mut tiles = vec![alpha, "Tiles".to_string()];
            let mut size = vec![String::new(), "Size (MB)".to_string()];
            for s in &slabs {
                let (tb, ta) = (
                    num(s, "tiles_before").unwrap_or(0.0),
                    num(s, "tiles_after").unwrap_or(0.0),
                );
                let (bb, ba) = (
                    num(s, "bytes_before").unwrap_or(0.0),
                    num(s, "bytes_after").unwrap_or(0.0),
                );
                tiles.extend([fmt_int(Some(tb)), fmt_int(Some(ta)), reduction(tb, ta)]);
                size.extend([fmt_mb(bb), fmt_mb(ba), reduction(bb, ba)]);
            }
            rows.push(tiles);
            rows.push(size);
        }
        c.push(Block::Table(Table {
            id: format!("culling-{variant}"),
            caption: format!("Variant `{variant}`: tiles and size before and after culling"),
            header,
            rows,
        }));
    }
    let mut fc_rows = Vec::new();
    for r in &runs {
        for s in r
            .get("slabs")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            if s.get("false_culls").is_none() {
                continue;
            }
            fc_rows.push(vec![
                fmt_num(num(r, "alpha"), 2),
                r.get("variant")
                    .and_then(Value::as_str)
                    .unwrap_or("?")
                    .to_string(),
                fmt_int(num(s, "slab").map(|k| k + 1.0)),
                fmt_int(num(s, "false_culls")),
                fmt_int(num(s, "false_cull_pixels")),
                fmt_int(num(s, "kept_never_visible")),
                fmt_int(num(s, "visible_tiles")),
            ]);
        }
    }
    if fc_rows.is_empty() {
        c.missing("the culling run had no oracle, so false culls were not measured".into());
    } else {
        c.push(Block::Table(Table {
            id: "false-culls".into(),
            caption:
                "The oracle: false culls (culled yet visible) and tightness (kept, never seen)"
                    .into(),
            header: [
                "α",
                "variant",
                "slab",
                "false culls (tiles)",
                "false-cull pixels",
                "kept never visible",
                "visible tiles",
            ]
            .map(String::from)
            .to_vec(),
            rows: fc_rows,
        }));
    }
    let debug: Vec<PathBuf> = path
        .parent()
        .map(pngs_in)
        .unwrap_or_default()
        .into_iter()
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("cull"))
        })
        .take(4)
        .collect();
    let mut figs = Vec::new();
    for p in debug {
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("cull.png")
            .to_string();
        if let Some(name) = c.copy(&p, &file) {
            figs.push(Figure {
                src: name,
                caption: format!("kept and culled tiles ({file})"),
                checker: false,
            });
        }
    }
    if !figs.is_empty() {
        c.push(Block::Figures(figs));
    }
    Some(report)
}

/// Total size of the files under `dir` (recursively).
fn dir_bytes(dir: &Path) -> Option<u64> {
    let mut total = 0;
    let mut stack = vec![dir.to_path_buf()];
    let mut any = false;
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).ok()?.filter_map(Result::ok) {
            let Ok(md) = e.metadata() else { continue };
            if md.is_dir() {
                stack.push(e.path());
            } else {
                total += md.len();
                any = true;
            }
        }
    }
    any.then_some(total)
}

fn sizes(c: &mut Ctx, pre: Option<&Value>, slabs: Option<&Value>, cull: Option<&Value>) {
    c.section("sizes", "Database size per stage");
    c.push(Block::Para(
        "Colour as raw RGBA8 (4 bytes per pixel, the paper's Size unit) up to culling; the last \
         row is the database as written to disk (PTM levels compressed, meshes, manifest)."
            .into(),
    ));
    let mut rows: Vec<Vec<String>> = Vec::new();
    let mut raw = None;
    let add = |rows: &mut Vec<Vec<String>>,
               stage: &str,
               bytes: f64,
               how: String,
               cmd: String,
               raw: Option<f64>| {
        let rel = raw
            .filter(|r| *r > 0.0)
            .map_or("–".into(), |r| format!("{:.1}%", 100.0 * bytes / r));
        rows.push(vec![stage.into(), fmt_mb(bytes), rel, how, cmd]);
    };
    let face = pre.and_then(|p| num(p, "face_size"));
    let samples = pre.and_then(|p| num(p, "samples"));
    let pre_cmd = c.command(
        "prerender",
        format!(
            "railview prerender --scene {} --track {} --face-size {}",
            c.log.scene, c.log.track, c.log.face_size
        ),
    );
    let slab_cmd = c.command(
        "slabs",
        format!("railview slabs {}", c.path_arg(c.layout.work())),
    );
    let cull_cmd = c.command(
        "cull",
        format!("railview cull {}", c.path_arg(c.layout.work())),
    );
    if let (Some(n), Some(s)) = (face, samples) {
        let b = s * 6.0 * n * n * 4.0;
        raw = Some(b);
        add(
            &mut rows,
            "raw panoramas",
            b,
            format!("{s} samples × 6 × {n}² px"),
            pre_cmd.clone(),
            raw,
        );
    }
    let slab_list = slabs.and_then(|v| v.get("slabs")).and_then(Value::as_array);
    let tile_size = slabs
        .and_then(|v| num(v, "tile_size"))
        .or_else(|| cull.and_then(|v| num(v, "tile_size")));
    if let (Some(list), Some(n), Some(s)) = (slab_list, face, samples) {
        let k = list.len() as f64;
        add(
            &mut rows,
            "slab layers",
            s * k * 6.0 * n * n * 4.0,
            format!("{k} slab layers per sample"),
            slab_cmd.clone(),
            raw,
        );
        if let Some(t) = tile_size {
            let after: f64 = list.iter().filter_map(|x| num(x, "tiles_after")).sum();
            add(
                &mut rows,
                "empty tiles removed",
                after * t * t * 4.0,
                format!("{after} tiles of {t}²"),
                slab_cmd.clone(),
                raw,
            );
        }
    }
    let conservative = cull
        .and_then(|v| v.get("runs"))
        .and_then(Value::as_array)
        .and_then(|runs| {
            runs.iter()
                .filter(|r| r.get("variant").and_then(Value::as_str) == Some("conservative"))
                .chain(runs.iter())
                .find(|r| num(r, "alpha") == Some(1.0))
                .or(runs.first())
        });
    if let Some(run) = conservative {
        let list = run
            .get("slabs")
            .and_then(Value::as_array)
            .cloned()
            .unwrap_or_default();
        let after: f64 = list.iter().filter_map(|x| num(x, "bytes_after")).sum();
        add(
            &mut rows,
            "culled",
            after,
            format!(
                "α = {}, variant {}",
                fmt_num(num(run, "alpha"), 2),
                run.get("variant").and_then(Value::as_str).unwrap_or("?")
            ),
            cull_cmd,
            raw,
        );
    }
    let db = c.layout.db();
    if let Some(b) = dir_bytes(&db) {
        let cmd = c.command(
            "build",
            format!(
                "railview build --scene {} --track {} --face-size {} --out {}",
                c.log.scene,
                c.log.track,
                c.log.face_size,
                db.display()
            ),
        );
        add(
            &mut rows,
            "PTM compressed (database on disk)",
            b as f64,
            format!("du -b {}", db.display()),
            cmd,
            raw,
        );
    }
    if rows.is_empty() {
        let why = c.why_missing("build", "prerender.json");
        c.missing(why);
        return;
    }
    if rows.len() < 5 {
        c.missing(format!(
            "{} of 5 stages have sizes so far (see the sections above)",
            rows.len()
        ));
    }
    c.push(Block::Table(Table {
        id: "db-sizes".into(),
        caption: "Size per stage".into(),
        header: ["stage", "MB", "of raw", "what", "command"]
            .map(String::from)
            .to_vec(),
        rows,
    }));
}

fn streaming(c: &mut Ctx) {
    c.section(
        "streaming",
        "Streaming: quality over time per strategy and bandwidth",
    );
    let dir = c.layout.walk();
    let cmd = c.command(
        "walk",
        format!(
            "railview walk {} --out {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    let path = dir.join("walk.json");
    if !path.is_file() {
        let why = c.why_missing("walk", "walk/walk.json");
        c.missing(why);
        return;
    }
    let report = match read_json(&path) {
        Ok(v) => v,
        Err(e) => {
            c.missing(e);
            return;
        }
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "A simulated walk of {} m at {} m/s with {} ms latency, streaming from a server on \
         loopback. Quality is the paper's progressive downloading quality; the needed fraction \
         is the share of visible pixels present at the level they need.",
        fmt_num(num(&report, "length_m"), 1),
        fmt_num(num(&report, "speed_mps"), 2),
        fmt_num(num(&report, "latency_s").map(|s| s * 1000.0), 0)
    )));
    let png = dir.join("walk.png");
    if png.is_file() {
        if let Some(name) = c.copy(&png, "walk.png") {
            c.push(Block::Figures(vec![Figure {
                src: name,
                caption: "quality (solid) and needed fraction (dotted) over time, one panel per bandwidth".into(),
                checker: false,
            }]));
        }
    } else {
        c.missing("the walk wrote no walk.png".into());
    }
    let rows = report
        .get("runs")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .map(|r| {
            let bw = match r.get("bandwidth_bps") {
                Some(Value::Null) | None => "unlimited".to_string(),
                Some(v) => v.as_u64().map_or("?".into(), streamer::walk::format_bps),
            };
            vec![
                r.get("strategy")
                    .and_then(Value::as_str)
                    .unwrap_or("?")
                    .to_string(),
                bw,
                match r.get("time_to_first_frame_s") {
                    Some(Value::Null) => "never".into(),
                    v => fmt_num(v.and_then(Value::as_f64), 2),
                },
                fmt_num(num(r, "mean_needed_fraction"), 3),
                fmt_num(num(r, "mean_quality"), 3),
                fmt_int(num(r, "bytes")),
                fmt_num(num(r, "bytes_per_m"), 0),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "walk".into(),
        caption: "Walk summary per strategy and bandwidth".into(),
        header: [
            "strategy",
            "bandwidth",
            "first frame (s)",
            "needed fraction",
            "quality",
            "bytes",
            "bytes/m",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
}

fn evaluation(c: &mut Ctx) {
    c.section("eval", "Error against run time");
    let dir = c.layout.eval();
    let cmd = c.command(
        "eval",
        format!(
            "railview eval {} --out {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    let path = dir.join("eval.json");
    if !path.is_file() {
        let why = c.why_missing("eval", "eval/eval.json");
        c.missing(why);
        return;
    }
    let report = match read_json(&path) {
        Ok(v) => v,
        Err(e) => {
            c.missing(e);
            return;
        }
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(
        "Reconstructed views compared with the ray tracer's ground truth from the same camera. \
         At the reference samples the error is the resampling floor; between them it adds the \
         interpolation error."
            .into(),
    ));
    let mut figs = Vec::new();
    for p in pngs_in(&dir).into_iter().take(8) {
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("eval.png")
            .to_string();
        if let Some(name) = c.copy(&p, &format!("eval-{file}")) {
            figs.push(Figure {
                src: name,
                caption: file,
                checker: false,
            });
        }
    }
    if figs.is_empty() {
        c.missing("the evaluation wrote no plots".into());
    } else {
        c.push(Block::Figures(figs));
    }
    // Mean per configuration, the reference samples apart from the rest.
    let mut groups: Vec<(String, [Acc; 2])> = Vec::new();
    for row in report
        .get("rows")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        let config = match row.get("config") {
            Some(Value::String(s)) => s.clone(),
            Some(v) => v.to_string(),
            None => "?".into(),
        };
        let at_ref = row
            .get("at_reference")
            .and_then(Value::as_bool)
            .unwrap_or(false);
        let g = match groups.iter().position(|(k, _)| *k == config) {
            Some(i) => i,
            None => {
                groups.push((config, [Acc::default(), Acc::default()]));
                groups.len() - 1
            }
        };
        groups[g].1[usize::from(!at_ref)].add(row);
    }
    let rows = groups
        .iter()
        .map(|(config, [at, between])| {
            vec![
                config.clone(),
                between.n.to_string(),
                at.mean(0),
                between.mean(0),
                between.mean(1),
                between.mean(2),
                between.mean(3),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "eval".into(),
        caption: "Mean per configuration (PSNR at the reference samples = resampling floor)".into(),
        header: [
            "config",
            "views between",
            "PSNR at refs (dB)",
            "PSNR between (dB)",
            "SSIM between",
            "hole fraction between",
            "frame ms",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
}

/// Sums of `psnr_db`, `ssim`, `hole_fraction`, `frame_ms`.
#[derive(Default)]
struct Acc {
    n: usize,
    sums: [f64; 4],
    counts: [usize; 4],
}

impl Acc {
    fn add(&mut self, row: &Value) {
        self.n += 1;
        for (i, key) in ["psnr_db", "ssim", "hole_fraction", "frame_ms"]
            .iter()
            .enumerate()
        {
            if let Some(x) = num(row, key).filter(|x| x.is_finite()) {
                self.sums[i] += x;
                self.counts[i] += 1;
            }
        }
    }
    fn mean(&self, i: usize) -> String {
        if self.counts[i] == 0 {
            "–".into()
        } else {
            format!("{:.3}", self.sums[i] / self.counts[i] as f64)
        }
    }
}

fn frames(c: &mut Ctx) {
    c.section("frames", "Flythrough");
    let dir = c.layout.frames();
    let all = pngs_in(&dir);
    if all.is_empty() {
        let why = match c.log.stage("view") {
            Some(s) if s.status == StageStatus::Done => {
                "the viewer window was shown instead of a headless flythrough".to_string()
            }
            _ => c.why_missing("flythrough", "frames/*.png"),
        };
        c.missing(why);
        return;
    }
    let cmd = c.command(
        "flythrough",
        format!(
            "railview flythrough {} -o {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    c.push(Block::Command(cmd));
    let mut figs = Vec::new();
    for i in spread(all.len()) {
        let p = &all[i];
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("frame.png")
            .to_string();
        if let Some(name) = c.copy(p, &format!("frame-{file}")) {
            figs.push(Figure {
                src: name,
                caption: format!("frame {} of {}", i + 1, all.len()),
                checker: false,
            });
        }
    }
    c.push(Block::Figures(figs));
}

fn later(c: &mut Ctx) {
    c.section("later", "Open it again later");
    let db = c.layout.db();
    let root = c.layout.root();
    c.push(Block::Code(format!(
        "railview view {db}                      # the viewer window on the database\n\
         railview serve {db} --addr 127.0.0.1:8080  # or serve it, then: railview view http://127.0.0.1:8080\n\
         railview flythrough {db} -o {frames}\n\
         railview demo --out {root}                # reuses everything built so far",
        db = db.display(),
        frames = c.layout.frames().display(),
        root = root.display()
    )));
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
        assert_eq!(fmt_depth(Some(&Value::Null)), "∞");
        assert_eq!(fmt_depth(Some(&serde_json::json!(12.5))), "12.50");
        assert_eq!(fmt_depth(None), "–");
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
            flatten(k, x, &mut out);
        }
        assert!(out.contains(&("criterion.max_spacing_m".into(), "2.5".into())));
        assert!(out.contains(&("criterion.parallax_px".into(), "1.25, 0.5".into())));
        assert!(out.contains(&("tile_size".into(), "32".into())));
        assert!(!out.iter().any(|(k, _)| k == "huge"));
    }
}
