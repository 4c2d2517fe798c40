//! Sections of numbers: the culling tables in the paper's form and the size per stage.

use std::path::{Path, PathBuf};

use occlusion::cull::Variant;
use occlusion::report::{CullReport, RunReport};
use prerender::store::PrerenderReport;
use slabs::report::SlabsReport;
use stages::encode::BuildReport;

use super::{fmt_int, fmt_mb, fmt_num, pngs_in, read_json, reduction, Ctx};
use crate::doc::{Block, Figure, Table};

pub(super) fn culling(c: &mut Ctx) -> Option<CullReport> {
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
    let (path, report): (_, CullReport) =
        c.stage_report(c.layout.find("cull.json"), "cull", "cull.json")?;
    c.push(Block::Command(cmd));
    c.push(Block::Para(
        "Tiles and sizes summed over every reference viewpoint, per slab; size is raw RGBA8 \
         tile colour (the paper's Size column). False culls come from the oracle: tiles culled \
         yet seen as the first visible surface from dense viewpoints along the track."
            .into(),
    ));
    let mut variants: Vec<Variant> = Vec::new();
    for r in &report.runs {
        if !variants.contains(&r.variant) {
            variants.push(r.variant);
        }
    }
    for variant in variants {
        c.push(Block::Table(variant_table(&report.runs, variant)));
    }
    false_culls(c, &report.runs);
    atlases(c, &path);
    Some(report)
}

/// The paper's table for the runs of one variant: tiles and size per slab, before and after.
fn variant_table(runs: &[RunReport], variant: Variant) -> Table {
    let rs: Vec<&RunReport> = runs.iter().filter(|r| r.variant == variant).collect();
    let slab_count = rs.iter().map(|r| r.slabs.len()).max().unwrap_or(0);
    let mut header = vec!["α".to_string(), "".to_string()];
    for k in 0..slab_count {
        header.push(format!("slab {} before", k + 1));
        header.push("after".into());
        header.push("reduction".into());
    }
    let mut rows = Vec::new();
    for r in &rs {
        let mut tiles = vec![fmt_num(Some(r.alpha), 2), "Tiles".to_string()];
        let mut size = vec![String::new(), "Size (MB)".to_string()];
        for s in &r.slabs {
            let (tb, ta) = (s.tiles_before as f64, s.tiles_after as f64);
            let (bb, ba) = (s.bytes_before as f64, s.bytes_after as f64);
            tiles.extend([fmt_int(Some(tb)), fmt_int(Some(ta)), reduction(tb, ta)]);
            size.extend([fmt_mb(bb), fmt_mb(ba), reduction(bb, ba)]);
        }
        rows.push(tiles);
        rows.push(size);
    }
    let name = variant.name();
    Table {
        id: format!("culling-{name}"),
        caption: format!("Variant `{name}`: tiles and size before and after culling"),
        header,
        rows,
    }
}

/// The oracle's table: per run and slab, false culls and tiles kept but never seen.
fn false_culls(c: &mut Ctx, runs: &[RunReport]) {
    let count = |x: Option<u64>| fmt_int(x.map(|x| x as f64));
    let mut rows = Vec::new();
    for r in runs {
        for s in r.slabs.iter().filter(|s| s.false_culls.is_some()) {
            rows.push(vec![
                fmt_num(Some(r.alpha), 2),
                r.variant.name().to_string(),
                (s.slab + 1).to_string(),
                count(s.false_culls),
                count(s.false_cull_pixels),
                count(s.kept_never_visible),
                count(s.visible_tiles),
                count(s.never_visible),
            ]);
        }
    }
    if rows.is_empty() {
        c.missing("the culling run had no oracle, so false culls were not measured".into());
        return;
    }
    c.push(Block::Table(Table {
        id: "false-culls".into(),
        caption: "The oracle: false culls (culled yet visible) and tightness (kept, never seen)"
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
        rows,
    }));
}

/// The culling stage's atlases (`cull/<variant>-a<alpha>.png`: kept and culled tiles) beside
/// `cull.json`. The shrunk and conservative runs at α = 1 and the most aggressive paper run
/// say the most; other atlases are in the culling directory.
fn atlases(c: &mut Ctx, cull_json: &Path) {
    let all: Vec<PathBuf> = cull_json
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

pub(super) fn sizes(
    c: &mut Ctx,
    pre: Option<&PrerenderReport>,
    slabs: Option<&SlabsReport>,
    cull: Option<&CullReport>,
) {
    c.section("sizes", "Database size per stage");
    if let Some(path) = c.layout.find("build.json") {
        match read_json::<BuildReport>(&path) {
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
fn build_sizes(c: &mut Ctx, build: &BuildReport) {
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
    let culling = if build.culling.is_empty() {
        "?"
    } else {
        build.culling.as_str()
    };
    c.push(Block::Para(format!(
        "Colour as raw RGBA8 (4 bytes per pixel, the paper's Size unit) up to culling ({culling}), \
         then as stored: PTM levels range-coded, meshes in their compact coded form, and \
         every object of the database on disk (each payload once, however many tiles point at \
         it). Each stage is also weighed against the baseline: every reference panorama as a \
         PNG of its colour plus a 16-bit PNG of its disparity-quantised depth, what a viewer \
         with one depth map per panorama ships, measured on the same prerender directory."
    )));
    let sizes = &build.sizes;
    let raw = Some(sizes.panoramas_rgba as f64).filter(|r| *r > 0.0);
    let baseline = Some(sizes.baseline as f64).filter(|b| *b > 0.0);
    if let Some(b) = baseline {
        let db = sizes.database_objects as f64;
        c.push(Block::Para(format!(
            "Database {} MB = {:.2}× the baseline of {} MB (PNG colour {} MB, PNG16 depth {} MB).",
            fmt_mb(db),
            db / b,
            fmt_mb(b),
            fmt_mb(sizes.baseline_colour_png as f64),
            fmt_mb(sizes.baseline_depth_png16 as f64),
        )));
    }
    let rows: Vec<Vec<String>> = [
        ("raw panoramas", sizes.panoramas_rgba),
        ("slab layers", sizes.slab_layers_rgba),
        ("empty tiles removed", sizes.nonempty_tiles_rgba),
        ("culled", sizes.kept_tiles_rgba),
        ("PTM compressed (kept tiles)", sizes.kept_tiles_ptm),
        ("meshes", sizes.meshes),
        ("backgrounds (PTM)", sizes.backgrounds_ptm),
        ("repeated payloads stored once (saved)", sizes.bytes_shared),
        ("database objects on disk", sizes.database_objects),
        ("baseline: PNG colour", sizes.baseline_colour_png),
        ("baseline: PNG16 disparity", sizes.baseline_depth_png16),
        ("baseline", sizes.baseline),
    ]
    .iter()
    .map(|&(label, bytes)| {
        let b = bytes as f64;
        let rel = raw.map_or("–".into(), |r| format!("{:.1}%", 100.0 * b / r));
        let ratio = baseline.map_or("–".into(), |r| format!("{:.2}×", b / r));
        vec![label.to_string(), fmt_mb(b), rel, ratio]
    })
    .collect();
    c.push(Block::Table(Table {
        id: "db-sizes".into(),
        caption: "Size per stage (MB; share of the raw panoramas; ÷ the baseline)".into(),
        header: ["stage", "MB", "of raw panoramas", "÷ baseline"]
            .map(String::from)
            .to_vec(),
        rows,
    }));
    let times: Vec<Vec<String>> = build
        .seconds
        .iter()
        .map(|(name, s)| vec![name.clone(), fmt_num(Some(*s), 1)])
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

/// Rows of the estimated size table (stage, MB, share of the raw panoramas, how, command).
struct SizeRows {
    rows: Vec<Vec<String>>,
    /// Bytes of the raw panoramas, once known.
    raw: Option<f64>,
}

impl SizeRows {
    fn add(&mut self, stage: &str, bytes: f64, how: String, cmd: String) {
        let rel = self
            .raw
            .filter(|r| *r > 0.0)
            .map_or("–".into(), |r| format!("{:.1}%", 100.0 * bytes / r));
        self.rows
            .push(vec![stage.into(), fmt_mb(bytes), rel, how, cmd]);
    }
}

/// Sizes estimated from the stage reports, when no build report exists.
fn estimated_sizes(
    c: &mut Ctx,
    pre: Option<&PrerenderReport>,
    slabs: Option<&SlabsReport>,
    cull: Option<&CullReport>,
) {
    c.push(Block::Para(
        "Colour as raw RGBA8 (4 bytes per pixel, the paper's Size unit) up to culling; the last \
         row is the database as written to disk (PTM levels compressed, meshes, manifest)."
            .into(),
    ));
    let mut rows = SizeRows {
        rows: Vec::new(),
        raw: None,
    };
    layer_sizes(c, &mut rows, pre, slabs, cull);
    if let Some(run) = cull.and_then(|v| database_run(&v.runs)) {
        let cull_cmd = c.command(
            "cull",
            format!("railview cull {}", c.path_arg(c.layout.prerender())),
        );
        let after: f64 = run.slabs.iter().map(|x| x.bytes_after as f64).sum();
        rows.add(
            "culled",
            after,
            format!(
                "α = {}, variant {}",
                fmt_num(Some(run.alpha), 2),
                run.variant.name()
            ),
            cull_cmd,
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
        rows.add(
            "PTM compressed (database on disk)",
            b as f64,
            format!("du -b {}", db.display()),
            cmd,
        );
    }
    let rows = rows.rows;
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

/// The raw panoramas, the slab layers and the tiles left after empty-tile removal.
fn layer_sizes(
    c: &Ctx,
    rows: &mut SizeRows,
    pre: Option<&PrerenderReport>,
    slabs: Option<&SlabsReport>,
    cull: Option<&CullReport>,
) {
    let Some(pre) = pre else { return };
    let (n, s) = (pre.face_size as f64, pre.samples as f64);
    let pre_cmd = c.command(
        "prerender",
        format!(
            "railview prerender --scene {} --track {} --face-size {}",
            c.log.scene, c.log.track, c.log.face_size
        ),
    );
    let b = s * 6.0 * n * n * 4.0;
    rows.raw = Some(b);
    rows.add(
        "raw panoramas",
        b,
        format!("{s} samples × 6 × {n}² px"),
        pre_cmd,
    );
    let Some(slabs) = slabs else { return };
    let slab_cmd = c.command(
        "slabs",
        format!("railview slabs {}", c.path_arg(c.layout.prerender())),
    );
    let k = slabs.slabs.len() as f64;
    rows.add(
        "slab layers",
        s * k * 6.0 * n * n * 4.0,
        format!("{k} slab layers per sample"),
        slab_cmd.clone(),
    );
    let tile_size = Some(slabs.tile_size)
        .filter(|t| *t > 0)
        .or_else(|| cull.map(|v| v.tile_size));
    if let Some(t) = tile_size.map(f64::from) {
        let after: f64 = slabs.slabs.iter().map(|x| x.tiles_after as f64).sum();
        rows.add(
            "empty tiles removed",
            after * t * t * 4.0,
            format!("{after} tiles of {t}²"),
            slab_cmd,
        );
    }
}

/// The database's culling: the shrunk run (α = 1) where there is one, else the rendered one
/// (an import's), else the conservative one at α = 1, else any at α = 1, else the first.
fn database_run(runs: &[RunReport]) -> Option<&RunReport> {
    let of = |v: Variant| runs.iter().filter(move |r| r.variant == v);
    of(Variant::Shrunk)
        .chain(of(Variant::Rendered))
        .chain(of(Variant::Conservative))
        .chain(runs.iter())
        .find(|r| r.alpha == 1.0)
        .or(runs.first())
}
