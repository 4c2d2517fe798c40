//! `railview cull DIR`: track-dependent occlusion culling of the slab tiles that
//! `railview slabs DIR` wrote, for every α and variant, optionally judged by the exact oracle.
//!
//! Variants: `shrunk` (occluder shrinking against the scene's exact solids, α = 1 only; it
//! needs the geometry of a built-in or TOML scene and is left out for POV-Ray imports),
//! `conservative` and `paper` (both on the slab layers alone, every α).
//!
//! Writes (each atomically):
//! - `DIR/cull.json`: `runs`, one per (α, variant), each with `alpha`, `variant` and per slab
//!   `tiles_before`, `tiles_after`, `bytes_before`, `bytes_after` (raw RGBA8 tile sizes) and,
//!   with `--oracle`, `false_culls`, `false_cull_pixels`, `kept_never_visible`,
//!   `visible_tiles` and `never_visible` (tiles no oracle position saw: the ceiling of any
//!   culling without false culls).
//! - `DIR/cull.md`: the paper's Tables 1–2 per variant.
//! - `DIR/cull_tiles.json`: the kept/culled decision of every tile of every run, for the
//!   database build (format: `occlusion::report::TileDecisions`).
//! - `DIR/cull/<variant>-a<alpha>.png`: one atlas per run; a row per viewpoint, a column per
//!   slab, faces side by side, a block per tile: kept green (olive: never seen by the oracle),
//!   culled blue, culled but seen magenta, empty dark.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use glam::DVec3;
use indicatif::{ProgressBar, ProgressStyle};
use occlusion::oracle::oracle_positions;
use occlusion::report::{
    atlas_png, markdown, paper_table, CullReport, OracleInfo, RunDecisions, RunReport,
    TileDecisions, ViewpointDecisions,
};
use occlusion::{
    cull_viewpoint, cull_viewpoint_shrunk, mark_visible, raw_rgba_bytes, score, Cell, CullParams,
    MatchRule, SceneSolids, SlabLayer, TileInfo, Variant, Visibility,
};
use prerender::runlog::RunLog;
use prerender::scene::Scene;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use slabs::io::{self as sio, TilesFile};
use tracks::{SlabRange, TileGrid, TrackSet};

/// Arguments of `railview cull`.
#[derive(clap::Args)]
pub struct Args {
    /// Prerender directory, after `railview slabs DIR`.
    pub dir: PathBuf,
    /// Opacity thresholds α, comma-separated (1 = fully opaque windows only).
    #[arg(long, default_value = "1.0,0.9,0.8")]
    pub alpha: String,
    /// Variants, comma-separated: `shrunk`, `conservative`, `paper`; `all` for the three
    /// (`shrunk` only where the scene's geometry is at hand), `both` for the last two.
    #[arg(long, default_value = "all")]
    pub variant: String,
    /// Also run the exact oracle: built-in or TOML scenes cast rays through the geometry;
    /// POV-Ray imports render depth with POV-Ray at every oracle position (use a small
    /// `--oracle-face-size`: each position is one POV-Ray base pass).
    #[arg(long)]
    pub oracle: bool,
    /// Oracle positions per track segment besides its two ends, at offset fractions of its
    /// length that the shrunk variant never samples (at least twice its base sampling).
    #[arg(long, default_value_t = 16)]
    pub oracle_per_segment: usize,
    /// Oracle rays per face side (default: the layers' face size).
    #[arg(long)]
    pub oracle_face_size: Option<u32>,
}

/// Everything loaded for one reference viewpoint.
struct Loaded {
    index: usize,
    grid: TileGrid,
    layers: Vec<SlabLayer>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let t_start = Instant::now();
    let dir = PrerenderDir::new(&args.dir);
    let pre: PrerenderReport = dir
        .read_report()
        .context("reading the prerender report (run `railview prerender` first)")?;
    let log = RunLog::create(&args.dir, "cull", None)?;
    let alphas = parse_alphas(&args.alpha)?;
    let (variants, explicit) = parse_variants(&args.variant)?;
    // The shrunk variant needs the scene's solids: built-in and TOML scenes only.
    let solids: Option<Box<Scene>> = if variants.contains(&Variant::Shrunk) {
        if pre.renderer == "builtin" {
            Some(Box::new(load_geometry(&pre).context("the shrunk variant")?))
        } else if explicit {
            bail!(
                "--variant shrunk: scene `{}` was rendered by `{}`; the shrunk variant needs the \
                 exact geometry of a built-in or TOML scene (use conservative or paper)",
                pre.scene,
                pre.renderer
            );
        } else {
            eprintln!(
                "note: no shrunk variant for `{}` (rendered by {}: no scene geometry)",
                pre.scene, pre.renderer
            );
            None
        }
    } else {
        None
    };
    let variants: Vec<Variant> = variants
        .into_iter()
        .filter(|v| *v != Variant::Shrunk || solids.is_some())
        .collect();
    let solids = solids.as_deref().map(SceneSolids::new);
    // α-acceleration is a threshold on window opacity; the shrunk variant runs at α = 1.
    let params: Vec<CullParams> = variants
        .iter()
        .flat_map(|&v| match v {
            Variant::Shrunk => vec![(1.0, v)],
            _ => alphas.iter().map(|&a| (a, v)).collect(),
        })
        .map(|(a, v)| CullParams::new(a, v))
        .collect::<Result<_, _>>()?;
    if pre.viewpoints.is_empty() {
        bail!("{}: no viewpoints", dir.report_json().display());
    }
    if args.oracle {
        super::count("--oracle-per-segment", args.oracle_per_segment, 10_000)?;
    }
    if let Some(n) = args.oracle_face_size {
        super::face_size("--oracle-face-size", n)?;
    }
    let mut geometry = if args.oracle {
        Some(OracleSource::load(&dir, &pre, args.oracle_face_size)?)
    } else {
        None
    };
    let path = TrackPath::new(&dir, &pre);
    let count = pre.viewpoints.len();

    let mut runs: Vec<RunReport> = Vec::new();
    let mut decisions: Vec<RunDecisions> = params
        .iter()
        .map(|p| RunDecisions {
            alpha: p.alpha,
            variant: p.variant,
            viewpoints: Vec::new(),
        })
        .collect();
    let mut vis_all: Vec<Visibility> = Vec::new();
    let mut first: Option<(TileGrid, Vec<SlabRange>)> = None;
    let mut load_seconds = 0.0;
    let mut oracle_seconds = 0.0;
    let oracle_n = args.oracle_face_size;
    let rule = MatchRule::default();

    let pb = ProgressBar::new(count as u64);
    pb.set_style(
        ProgressStyle::with_template("cull {bar:40} {pos}/{len} viewpoints {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // Viewpoint i is finished once the segment to i + 1 has been traced (oracle) — keep the
    // previous one loaded until then.
    let mut prev: Option<(Loaded, Option<Visibility>)> = None;
    for (k, vp) in pre.viewpoints.iter().enumerate() {
        let t = Instant::now();
        let cur = load_viewpoint(&dir, vp.index)?;
        load_seconds += t.elapsed().as_secs_f64();
        if let Some(s) = &solids {
            same_geometry(s.scene(), vp.position, &cur.layers).with_context(|| {
                format!(
                    "viewpoint {}: the shrunk variant needs scene `{}`",
                    vp.index, pre.scene
                )
            })?;
        }
        match &first {
            None => first = Some((cur.grid, cur.layers.iter().map(|l| l.range).collect())),
            Some((g, r)) => {
                let ranges: Vec<SlabRange> = cur.layers.iter().map(|l| l.range).collect();
                if *g != cur.grid || *r != ranges {
                    bail!(
                        "viewpoint {}: tile grid or slab ranges differ from viewpoint {} (re-run `railview slabs`)",
                        vp.index,
                        pre.viewpoints[0].index
                    );
                }
            }
        }
        let cur_vis = geometry
            .as_ref()
            .map(|_| Visibility::new(cur.grid.face_size, cur.layers.len()));
        if let Some(source) = &mut geometry {
            let t = Instant::now();
            let n = oracle_n.unwrap_or(cur.grid.face_size);
            let positions = match &prev {
                Some(_) => oracle_positions(&path.between(k - 1), args.oracle_per_segment),
                None if count == 1 => vec![vp.position],
                None => Vec::new(),
            };
            for x in positions {
                let depth = source.depth_from(x, n)?;
                if let Some((p, Some(pv))) = &prev {
                    mark_visible(x, &depth, path.position(k - 1), &p.layers, &rule, pv);
                }
                if let Some(cv) = &cur_vis {
                    mark_visible(x, &depth, path.position(k), &cur.layers, &rule, cv);
                }
            }
            oracle_seconds += t.elapsed().as_secs_f64();
        }
        if let Some((p, pv)) = prev.take() {
            finish(
                &p,
                k - 1,
                &path,
                &params,
                solids.as_ref(),
                &mut runs,
                &mut decisions,
                pv.as_ref(),
            )?;
            if let Some(v) = pv {
                vis_all.push(v);
            }
            pb.inc(1);
        }
        prev = Some((cur, cur_vis));
    }
    if let Some((p, pv)) = prev.take() {
        finish(
            &p,
            count - 1,
            &path,
            &params,
            solids.as_ref(),
            &mut runs,
            &mut decisions,
            pv.as_ref(),
        )?;
        if let Some(v) = pv {
            vis_all.push(v);
        }
        pb.inc(1);
    }
    pb.finish_and_clear();

    let (grid, ranges) = first.context("no viewpoint was loaded")?;
    let report = CullReport {
        viewpoints: count,
        face_size: grid.face_size,
        tile_size: grid.tile_size,
        slab_ranges: ranges,
        runs,
        oracle: geometry.as_ref().map(|o| OracleInfo {
            per_segment: args.oracle_per_segment,
            face_size: oracle_n.unwrap_or(grid.face_size),
            source: o.name().into(),
            seconds: oracle_seconds,
        }),
        load_seconds,
    };
    store::write_json(&args.dir.join("cull.json"), &report)?;
    store::write_atomic(&args.dir.join("cull.md"), markdown(&report).as_bytes())?;
    store::write_json(
        &args.dir.join("cull_tiles.json"),
        &TileDecisions {
            grid,
            runs: decisions.clone(),
        },
    )?;
    let vis = (!vis_all.is_empty()).then_some(vis_all.as_slice());
    for d in &decisions {
        let name = format!("{}-a{}.png", d.variant.name(), d.alpha);
        store::write_atomic(
            &args.dir.join("cull").join(name),
            &atlas_png(&grid, &d.viewpoints, vis),
        )?;
    }
    for v in &variants {
        let rs: Vec<&RunReport> = report.runs.iter().filter(|r| r.variant == *v).collect();
        println!("variant {}:\n{}", v.name(), paper_table(&rs));
    }
    for r in &report.runs {
        println!(
            "{} α = {}: {:.2} s culling{}",
            r.variant.name(),
            r.alpha,
            r.seconds,
            r.later_slabs()
                .kept_per_seen()
                .map_or(String::new(), |x| format!(
                    ", later slabs kept ÷ seen {x:.2}×"
                ))
        );
    }
    if let Some(o) = &report.oracle {
        println!(
            "oracle: both ends and {} offset positions per segment, {}² per face, {:.2} s",
            o.per_segment, o.face_size, o.seconds
        );
    }
    log.end(&[
        ("viewpoints", count.into()),
        ("runs", report.runs.len().into()),
        ("load_seconds", load_seconds.into()),
        ("oracle_seconds", oracle_seconds.into()),
    ])?;
    println!(
        "wrote {}, cull.md, cull_tiles.json, cull/*.png ({:.2} s)",
        args.dir.join("cull.json").display(),
        t_start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Run every (α, variant) on one loaded viewpoint and record the results.
#[allow(clippy::too_many_arguments)]
fn finish(
    l: &Loaded,
    k: usize,
    path: &TrackPath,
    params: &[CullParams],
    solids: Option<&SceneSolids<Scene>>,
    runs: &mut Vec<RunReport>,
    decisions: &mut [RunDecisions],
    vis: Option<&Visibility>,
) -> anyhow::Result<()> {
    let cell = path.cell(k);
    for (j, p) in params.iter().enumerate() {
        let t = Instant::now();
        let (c, stats) = match (p.variant, solids) {
            (Variant::Shrunk, Some(scene)) => {
                let (c, s) = cull_viewpoint_shrunk(&cell, &l.grid, &l.layers, &p.shrunk, scene)
                    .with_context(|| format!("culling viewpoint {}", l.index))?;
                (c, Some(s))
            }
            _ => (
                cull_viewpoint(&cell, &l.grid, &l.layers, p)
                    .with_context(|| format!("culling viewpoint {}", l.index))?,
                None,
            ),
        };
        let secs = t.elapsed().as_secs_f64();
        if runs.len() <= j {
            runs.push(RunReport::new(p.alpha, p.variant, l.layers.len()));
        }
        if let Some(s) = stats {
            runs[j].shrunk.get_or_insert_with(Default::default).add(&s);
        }
        let scores = vis.map(|v| score(&c, &l.grid, v));
        runs[j].add(&c, scores.as_deref());
        runs[j].seconds += secs;
        decisions[j]
            .viewpoints
            .push(ViewpointDecisions::new(l.index, &l.grid, &c));
    }
    Ok(())
}

/// `--variant`: the variants and whether they were named one by one (`all` and `both` are
/// not: a variant they name that cannot run here is left out with a note, not an error).
fn parse_variants(s: &str) -> anyhow::Result<(Vec<Variant>, bool)> {
    match s.trim() {
        "all" => return Ok((Variant::ALL.to_vec(), false)),
        "both" => return Ok((vec![Variant::Conservative, Variant::Paper], false)),
        _ => {}
    }
    let mut out = Vec::new();
    for part in s.split(',') {
        let v = Variant::parse(part).with_context(|| {
            format!("--variant `{part}`: expected shrunk, conservative, paper, all or both")
        })?;
        if !out.contains(&v) {
            out.push(v);
        }
    }
    Ok((out, true))
}

fn parse_alphas(s: &str) -> anyhow::Result<Vec<f64>> {
    s.split(',')
        .map(|a| {
            let v: f64 = a
                .trim()
                .parse()
                .with_context(|| format!("--alpha `{a}`: not a number"))?;
            if !(v > 0.0 && v <= 1.0) {
                bail!("--alpha {v}: must be in (0, 1]");
            }
            Ok(v)
        })
        .collect()
}

/// The tiles and layers of one viewpoint, from `tiles.json` and the slab layer images.
fn load_viewpoint(dir: &PrerenderDir, index: usize) -> anyhow::Result<Loaded> {
    let jp = sio::tiles_json(dir, index);
    let file: TilesFile = store::read_json(&jp).with_context(|| {
        format!("reading tiles of viewpoint {index} (run `railview slabs` first)")
    })?;
    let grid = file.grid;
    let mut layers = Vec::with_capacity(file.layers.len());
    for rec in &file.layers {
        let (depth, mask) = sio::read_layer(dir, index, rec.slab)?;
        if depth.face_size() != grid.face_size {
            bail!(
                "{}: slab {} layer is {}² but the tile grid is {}²",
                jp.display(),
                rec.slab,
                depth.face_size(),
                grid.face_size
            );
        }
        let tiles = rec
            .tiles
            .iter()
            .map(|t| TileInfo {
                id: t.tile,
                depth_min: t.depth_min as f64,
                depth_max: t.depth_max as f64,
                bytes: raw_rgba_bytes(&grid, t.tile),
            })
            .collect();
        layers.push(SlabLayer {
            range: rec.range,
            alpha: mask.map(|&m| if m { 255 } else { 0 }),
            depth,
            tiles,
        });
    }
    Ok(Loaded {
        index,
        grid,
        layers,
    })
}

/// Where the oracle's depth maps come from.
enum OracleSource {
    /// Ray casting through the exact geometry of a built-in or TOML scene.
    Geometry(Box<Scene>),
    /// POV-Ray base passes at the oracle positions (a POV-Ray import), written to a scratch
    /// prerender directory that is removed afterwards.
    Pov {
        import: Box<prerender::pov::PovImport>,
        scratch: PrerenderDir,
        renders: usize,
    },
}

impl OracleSource {
    fn load(
        dir: &PrerenderDir,
        pre: &PrerenderReport,
        face_size: Option<u32>,
    ) -> anyhow::Result<OracleSource> {
        if pre.renderer == "povray" {
            let scratch = PrerenderDir::new(dir.root().join("cull-oracle"));
            std::fs::remove_dir_all(scratch.root()).ok();
            // The import as `import-pov` recorded it, at the oracle's face size.
            let mut at_size = pre.clone();
            at_size.face_size = face_size.unwrap_or(pre.face_size);
            at_size.lowres_face_size = pre.lowres_face_size.min(at_size.face_size);
            let import = super::slabs::pov_import_from_report(&scratch, &at_size)
                .context("--oracle: POV-Ray depth renders at the oracle positions")?;
            return Ok(OracleSource::Pov {
                import: Box::new(import),
                scratch,
                renders: 0,
            });
        }
        Ok(OracleSource::Geometry(Box::new(load_geometry(pre)?)))
    }

    fn name(&self) -> &'static str {
        match self {
            OracleSource::Geometry(_) => "geometry",
            OracleSource::Pov { .. } => "depth-renders (POV-Ray)",
        }
    }

    /// Radial depth seen from `x` at `n` pixels a face side (POV-Ray: the import's size).
    fn depth_from(&mut self, x: DVec3, n: u32) -> anyhow::Result<tracks::CubeMap<f32>> {
        match self {
            OracleSource::Geometry(scene) => {
                Ok(occlusion::oracle::depth_from_geometry(scene.as_ref(), x, n))
            }
            OracleSource::Pov {
                import,
                scratch,
                renders,
            } => {
                let vp = tracks::ReferenceViewpoint {
                    index: *renders,
                    s: 0.0,
                    position: x,
                };
                *renders += 1;
                import
                    .render_base(&vp, scratch)
                    .with_context(|| format!("--oracle: POV-Ray depth at {x}"))?;
                let path = scratch.depth_exr(vp.index);
                let depth = store::read_depth_exr(&path)
                    .with_context(|| format!("--oracle: reading {}", path.display()))?;
                std::fs::remove_dir_all(scratch.sample_dir(vp.index)).ok();
                Ok(depth)
            }
        }
    }
}

impl Drop for OracleSource {
    fn drop(&mut self) {
        if let OracleSource::Pov { scratch, .. } = self {
            std::fs::remove_dir_all(scratch.root()).ok();
        }
    }
}

/// Whether `scene` is the geometry the layers were rendered from: its first hit from the
/// viewpoint along each pixel centre of a grid of about 4 000 pixels is the depth of the
/// nearest layer opaque there, and lies in no slab's range where every layer is empty (a few
/// per cent may differ where an edge splits a pixel). The shrunk variant's guarantee is
/// about the solids it is given, so a scene file edited since `prerender` must not be used.
fn same_geometry(scene: &Scene, position: DVec3, layers: &[SlabLayer]) -> anyhow::Result<()> {
    let Some(l0) = layers.first() else {
        return Ok(());
    };
    let n = l0.depth.face_size();
    let stride = ((6 * n * n) as f64 / 4000.0).sqrt().ceil().max(1.0) as usize;
    let (mut checked, mut differ) = (0u32, 0u32);
    for face in tracks::Face::ALL {
        for y in (0..n).step_by(stride) {
            for x in (0..n).step_by(stride) {
                let stored = layers
                    .iter()
                    .find(|l| *l.alpha.get(face, x, y) >= 128)
                    .map(|l| *l.depth.get(face, x, y) as f64);
                let dir = tracks::cubemap::pixel_dir(face, x, y, n);
                let hit = scene.first_hit(position, dir, f64::INFINITY);
                checked += 1;
                let same = match (stored, hit) {
                    (Some(d), Some(h)) => (h - d).abs() <= 1e-3 * d + 1e-4,
                    (Some(_), None) => false,
                    (None, Some(h)) => !layers.iter().any(|l| h >= l.range.near && h < l.range.far),
                    (None, None) => true,
                };
                if !same {
                    differ += 1;
                }
            }
        }
    }
    if checked > 0 && differ as f64 > 0.05 * checked as f64 {
        bail!(
            "its first hits differ from the stored depth at {differ} of {checked} pixels: \
             the scene changed since `railview prerender` (render again)"
        );
    }
    Ok(())
}

/// Exact geometry of a built-in or TOML scene for the oracle.
fn load_geometry(pre: &PrerenderReport) -> anyhow::Result<Scene> {
    if pre.renderer != "builtin" {
        bail!(
            "--oracle: scene `{}` was rendered by `{}`; the oracle needs exact geometry \
             (built-in or TOML scenes) or a POV-Ray import (depth rendered by POV-Ray)",
            pre.scene,
            pre.renderer
        );
    }
    if let Some(b) = prerender::scenes::builtin(&pre.scene) {
        return Ok(b.scene);
    }
    let path = Path::new(&pre.scene);
    let text = super::read_text(path)
        .with_context(|| format!("--oracle: reading scene file {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let loader = move |rel: &str| -> Result<Vec<u8>, String> { super::read_asset(&base.join(rel)) };
    Ok(Scene::parse_toml_with(&text, &pre.scene, &loader)?)
}

/// The track between the reference viewpoints: the curve from `DIR/track.toml` when it
/// matches the report, else straight segments.
struct TrackPath {
    positions: Vec<DVec3>,
    arcs: Vec<f64>,
    curve: Option<(Vec<DVec3>, Vec<f64>)>,
}

impl TrackPath {
    fn new(dir: &PrerenderDir, pre: &PrerenderReport) -> TrackPath {
        let positions: Vec<DVec3> = pre.viewpoints.iter().map(|v| v.position).collect();
        let arcs: Vec<f64> = pre.viewpoints.iter().map(|v| v.s).collect();
        let curve = std::fs::read_to_string(dir.track_toml())
            .ok()
            .and_then(|t| TrackSet::parse(&t, "track.toml").ok())
            .and_then(|set| {
                let t = set.get(&pre.track).or_else(|| set.tracks.first())?.clone();
                let c = t.curve().to_vec();
                let a = tracks::segment::arc_lengths(&c);
                // Use the curve only if it reproduces the viewpoints.
                let ok = positions.iter().zip(&arcs).all(|(p, &s)| {
                    tracks::segment::point_at(&c, &a, s).distance(*p) <= 1e-6 * (1.0 + p.length())
                });
                ok.then_some((c, a))
            });
        TrackPath {
            positions,
            arcs,
            curve,
        }
    }

    fn position(&self, k: usize) -> DVec3 {
        self.positions[k]
    }

    fn cell(&self, k: usize) -> Cell {
        match &self.curve {
            Some((c, a)) => {
                let mut cell = Cell::along_curve(c, a, &self.arcs, k);
                cell.viewpoint = self.positions[k];
                cell
            }
            None => Cell::straight(&self.positions, k),
        }
    }

    /// The polyline from viewpoint `k` to `k + 1`, both ends included.
    fn between(&self, k: usize) -> Vec<DVec3> {
        let (a, b) = (self.positions[k], self.positions[k + 1]);
        let mut out = vec![a];
        if let Some((c, arc)) = &self.curve {
            let (s0, s1) = (self.arcs[k], self.arcs[k + 1]);
            out.extend(
                c.iter()
                    .zip(arc)
                    .filter(|(_, &s)| s > s0 && s < s1)
                    .map(|(p, _)| *p),
            );
        }
        out.push(b);
        out
    }
}
