//! Sections of numbers: the culling tables in the paper's form and the size per stage.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::{fmt_int, fmt_mb, fmt_num, num, pngs_in, read_json, reduction, Ctx};
use crate::doc::{Block, Figure, Table};

pub(super) fn culling(c: &mut Ctx) -> Option<Value> {
    c.section(
        "culling",
        "Track-dependent occlusion culling (the paper's Tables 1–2)",
    );
    let cmd = c.command(
        "cull",
        format!(
            "railview cull {} --alpha 1.0,0.9,0.8 --oracle",
            c.path_arg(c.layout.prerender())
        ),
    );
    let (path, report) = c.stage_report(c.layout.find("cull.json"), "cull", "cull.json")?;
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
                fmt_int(num(s, "never_visible")),
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
                "never visible (ceiling)",
            ]
            .map(String::from)
            .to_vec(),
            rows: fc_rows,
        }));
    }
    // The culling stage's atlases (`cull/<variant>-a<alpha>.png`: kept and culled tiles).
    // The shrunk and conservative runs at α = 1 and the most aggressive paper run say the
    // most; other atlases are in the culling directory.
    let all: Vec<PathBuf> = path
        .parent()
        .map(|d| pngs_in(&d.join("cull")))
        .unwrap_or_default();
    let preferred: Vec<PathBuf> = ["shrunk-a1.png", "conservative-a1.png", "paper-a0.8.png"]
        .iter()
        .filter_map(|n| all.iter().find(|p| p.file_name().is_some_and(|f| f == *n)))
        .cloned()
        .collect();
    let debug = if preferred.is_empty() {
        all.into_iter().take(2).collect()
    } else {
        preferred
    };
    let mut figs = Vec::new();
    for p in debug {
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("atlas.png")
            .to_string();
        if let Some(name) = c.copy(&p, &format!("cull-{file}")) {
            figs.push(Figure {
                src: name,
                caption: format!("kept and culled tiles, {}", file.trim_end_matches(".png")),
                checker: false,
                vector: None,
            });
        }
    }
    if !figs.is_empty() {
        c.push(Block::Para(
            "Atlases: a row per viewpoint, a column per slab, the six faces side by side, a \
             block per tile: kept green (olive: the oracle never saw it), culled blue, culled \
             but seen magenta (a false cull), empty dark."
                .into(),
        ));
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

pub(super) fn sizes(c: &mut Ctx, pre: Option<&Value>, slabs: Option<&Value>, cull: Option<&Value>) {
    c.section("sizes", "Database size per stage");
    if let Some(path) = c.layout.find("build.json") {
        match read_json(&path) {
            Ok(build) => {
                build_sizes(c, &build);
                return;
            }
            Err(e) => c.missing(e),
        }
    }
    estimated_sizes(c, pre, slabs, cull);
}

/// Sizes and timings from the build stage's own report (`build.json`).
fn build_sizes(c: &mut Ctx, build: &Value) {
    let db = c.layout.db();
    let cmd = c.command(
        "build",
        format!(
            "railview build --scene {} --track {} --face-size {} --out {} --work {}",
            c.log.scene,
            c.log.track,
            c.log.face_size,
            db.display(),
            c.layout.work().display()
        ),
    );
    c.push(Block::Command(cmd));
    let culling = build
        .get("culling")
        .and_then(Value::as_str)
        .unwrap_or("?")
        .to_string();
    c.push(Block::Para(format!(
        "Colour as raw RGBA8 (4 bytes per pixel, the paper's Size unit) up to culling ({culling}), \
         then as stored: PTM levels range-coded, meshes in their compact coded form, and \
         every object of the database on disk (each payload once, however many tiles point at \
         it). Each stage is also weighed against the baseline: every reference panorama as a \
         PNG of its colour plus a 16-bit PNG of its disparity-quantised depth, what a viewer \
         with one depth map per panorama ships, measured on the same prerender directory."
    )));
    let sizes = build.get("sizes").cloned().unwrap_or(Value::Null);
    let raw = num(&sizes, "panoramas_rgba").filter(|r| *r > 0.0);
    let baseline = num(&sizes, "baseline").filter(|b| *b > 0.0);
    if let (Some(db), Some(b)) = (num(&sizes, "database_objects"), baseline) {
        c.push(Block::Para(format!(
            "Database {} MB = {:.2}× the baseline of {} MB (PNG colour {} MB, PNG16 depth {} MB).",
            fmt_mb(db),
            db / b,
            fmt_mb(b),
            num(&sizes, "baseline_colour_png").map_or("–".into(), fmt_mb),
            num(&sizes, "baseline_depth_png16").map_or("–".into(), fmt_mb),
        )));
    }
    let rows: Vec<Vec<String>> = [
        ("raw panoramas", "panoramas_rgba"),
        ("slab layers", "slab_layers_rgba"),
        ("empty tiles removed", "nonempty_tiles_rgba"),
        ("culled", "kept_tiles_rgba"),
        ("PTM compressed (kept tiles)", "kept_tiles_ptm"),
        ("meshes", "meshes"),
        ("backgrounds (PTM)", "backgrounds_ptm"),
        ("repeated payloads stored once (saved)", "bytes_shared"),
        ("database objects on disk", "database_objects"),
        ("baseline: PNG colour", "baseline_colour_png"),
        ("baseline: PNG16 disparity", "baseline_depth_png16"),
        ("baseline", "baseline"),
    ]
    .iter()
    .filter_map(|(label, key)| {
        let b = num(&sizes, key)?;
        let rel = raw.map_or("–".into(), |r| format!("{:.1}%", 100.0 * b / r));
        let ratio = baseline.map_or("–".into(), |r| format!("{:.2}×", b / r));
        Some(vec![label.to_string(), fmt_mb(b), rel, ratio])
    })
    .collect();
    if rows.is_empty() {
        c.missing("build.json has no sizes".into());
        return;
    }
    c.push(Block::Table(Table {
        id: "db-sizes".into(),
        caption: "Size per stage (MB; share of the raw panoramas; ÷ the baseline)".into(),
        header: ["stage", "MB", "of raw panoramas", "÷ baseline"]
            .map(String::from)
            .to_vec(),
        rows,
    }));
    let times: Vec<Vec<String>> = build
        .get("seconds")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .filter_map(|p| {
            let name = p.get(0)?.as_str()?;
            Some(vec![name.to_string(), fmt_num(p.get(1)?.as_f64(), 1)])
        })
        .collect();
    if !times.is_empty() {
        c.push(Block::Table(Table {
            id: "build-seconds".into(),
            caption: "Build time per stage (seconds; a resumed build counts only what it redid)"
                .into(),
            header: vec!["stage".into(), "seconds".into()],
            rows: times,
        }));
    }
}

/// Sizes estimated from the stage reports, when no build report exists.
fn estimated_sizes(c: &mut Ctx, pre: Option<&Value>, slabs: Option<&Value>, cull: Option<&Value>) {
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
        format!("railview slabs {}", c.path_arg(c.layout.prerender())),
    );
    let cull_cmd = c.command(
        "cull",
        format!("railview cull {}", c.path_arg(c.layout.prerender())),
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
    // The database's culling: the shrunk run (α = 1) where there is one, else the
    // conservative one at α = 1.
    let used = cull
        .and_then(|v| v.get("runs"))
        .and_then(Value::as_array)
        .and_then(|runs| {
            let of = |name: &'static str| {
                runs.iter()
                    .filter(move |r| r.get("variant").and_then(Value::as_str) == Some(name))
            };
            of("shrunk")
                .chain(of("conservative"))
                .chain(runs.iter())
                .find(|r| num(r, "alpha") == Some(1.0))
                .or(runs.first())
        });
    if let Some(run) = used {
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
