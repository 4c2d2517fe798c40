//! The cull stage: track-dependent occlusion culling of the slab tiles the slabs stage wrote,
//! for every α and variant, optionally judged by the exact oracle.
//!
//! Variants: `shrunk` (occluder shrinking against the scene's exact solids, α = 1 only; it
//! needs the geometry of a built-in or TOML scene and is left out for POV-Ray imports),
//! `rendered` (image-space occluder shrinking in depth renders from balls along every
//! segment, α = 1 only: rays through the scene, or POV-Ray's depth passes for an import),
//! `conservative` and `paper` (both on the slab layers alone, every α).
//!
//! Writes (each atomically):
//! - `DIR/cull.json`: `runs`, one per (α, variant), each with `alpha`, `variant` and per slab
//!   `tiles_before`, `tiles_after`, `bytes_before`, `bytes_after` (raw RGBA8 tile sizes) and,
//!   with the oracle, `false_culls`, `false_cull_pixels`, `kept_never_visible`,
//!   `visible_tiles` and `never_visible` (tiles no oracle position saw: the ceiling of any
//!   culling without false culls).
//! - `DIR/cull.md`: the paper's Tables 1–2 per variant.
//! - `DIR/cull_tiles.json`: the kept/culled decision of every tile of every run, for the
//!   database build (format: `occlusion::report::TileDecisions`).
//! - `DIR/cull/<variant>-a<alpha>.png`: one atlas per run; a row per viewpoint, a column per
//!   slab, faces side by side, a block per tile: kept green (olive: never seen by the oracle),
//!   culled blue, culled but seen magenta, empty dark.

mod oracle;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use occlusion::oracle::oracle_positions;
use occlusion::report::{
    atlas_png, markdown, paper_table, CullReport, OracleInfo, RunDecisions, RunReport,
    TileDecisions, ViewpointDecisions,
};
use occlusion::{
    cull_from_segments, cull_viewpoint, cull_viewpoint_shrunk, hidden_from_segment, mark_visible,
    score, BallDepth, Cell, CullParams as RunParams, MatchRule, RenderedStats, SceneSolids,
    SegmentEnd, Visibility,
};
use prerender::runlog::RunLog;
use prerender::scene::Scene;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use tracks::network::Network;
use tracks::{SlabRange, TileGrid};

pub use occlusion::Variant;

use self::oracle::{load_viewpoint, same_geometry, Loaded, OracleSource};
use crate::error::{input, parameter, Context, Result};
use crate::network::network_of;
use crate::prerender::RenderedBy;
use crate::progress::{BarKind, Reporter};

/// Which variants run.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Variants {
    /// The four; `shrunk` only where the scene's geometry is at hand.
    All,
    /// `conservative` and `paper`.
    Both,
    /// These, named one by one: one that cannot run here is an error.
    These(Vec<Variant>),
}

impl Variants {
    /// The variants, and whether they were named one by one.
    fn list(&self) -> (Vec<Variant>, bool) {
        match self {
            Variants::All => (Variant::ALL.to_vec(), false),
            Variants::Both => (vec![Variant::Conservative, Variant::Paper], false),
            Variants::These(v) => (v.clone(), true),
        }
    }
}

/// The exact oracle's sampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OracleParams {
    /// Positions per track segment besides its two ends, at offset fractions of its length
    /// that the shrunk variant never samples.
    pub per_segment: usize,
    /// Rays per face side (default: the layers' face size).
    pub face_size: Option<u32>,
}

/// What the cull stage does to a prerender directory.
#[derive(Clone, Debug, PartialEq)]
pub struct CullParams {
    /// The prerender directory, after the slabs stage.
    pub dir: PathBuf,
    /// Opacity thresholds α, each in (0, 1] (the shrunk variant runs at 1 only).
    pub alphas: Vec<f64>,
    pub variants: Variants,
    /// Also run the exact oracle: built-in or TOML scenes cast rays through the geometry;
    /// POV-Ray imports render depth with POV-Ray at every oracle position.
    pub oracle: Option<OracleParams>,
    /// The rendered variant: balls per segment at the finest level (default
    /// [`occlusion::RenderedParams`]'s 64; renders are made only where tiles need them).
    pub renders_per_segment: Option<usize>,
}

impl CullParams {
    /// The command line a person would type to run this stage (after `railview`), for
    /// reports and messages; never parsed.
    pub fn command_line(&self) -> Vec<String> {
        let alphas: Vec<String> = self.alphas.iter().map(|a| a.to_string()).collect();
        let mut v = vec![
            "cull".into(),
            self.dir.display().to_string(),
            "--alpha".into(),
            alphas.join(","),
        ];
        match &self.variants {
            Variants::All => {}
            Variants::Both => v.extend(["--variant".into(), "both".into()]),
            Variants::These(l) => {
                let names: Vec<&str> = l.iter().map(|v| v.name()).collect();
                v.extend(["--variant".into(), names.join(",")]);
            }
        }
        if let Some(o) = self.oracle {
            v.extend([
                "--oracle".into(),
                "--oracle-per-segment".into(),
                o.per_segment.to_string(),
            ]);
            if let Some(n) = o.face_size {
                v.extend(["--oracle-face-size".into(), n.to_string()]);
            }
        }
        if let Some(n) = self.renders_per_segment {
            v.extend(["--renders-per-segment".into(), n.to_string()]);
        }
        v
    }
}

/// The variants that run, and the scene's solids where the shrunk variant is among them.
fn variants_and_solids(
    params: &CullParams,
    pre: &PrerenderReport,
    progress: &Reporter,
) -> Result<(Vec<Variant>, Option<Box<Scene>>)> {
    let (variants, explicit) = params.variants.list();
    // The shrunk variant needs the scene's solids: built-in and TOML scenes only.
    let solids: Option<Box<Scene>> = if variants.contains(&Variant::Shrunk) {
        if RenderedBy::of(pre) == RenderedBy::Builtin {
            Some(Box::new(
                oracle::load_geometry(pre).context("the shrunk variant")?,
            ))
        } else if explicit {
            return Err(parameter!(
                "--variant shrunk: scene `{}` was rendered by `{}`; the shrunk variant needs the \
                 exact geometry of a built-in or TOML scene (use conservative or paper)",
                pre.scene,
                pre.renderer
            ));
        } else {
            progress.message(&format!(
                "note: no shrunk variant for `{}` (rendered by {}: no scene geometry)",
                pre.scene, pre.renderer
            ));
            None
        }
    } else {
        None
    };
    let variants = variants
        .into_iter()
        .filter(|v| *v != Variant::Shrunk || solids.is_some())
        .collect();
    Ok((variants, solids))
}

/// Run the cull stage.
pub fn run(params: &CullParams, progress: &Reporter) -> Result<CullReport> {
    let t_start = Instant::now();
    let dir = PrerenderDir::new(&params.dir);
    let pre: PrerenderReport = dir
        .read_report()
        .context("reading the prerender report (run `railview prerender` first)")?;
    let log = RunLog::create(&params.dir, "cull", None)?;
    let (variants, solids) = variants_and_solids(params, &pre, progress)?;
    let solids = solids.as_deref().map(SceneSolids::new);
    // α-acceleration is a threshold on window opacity; the shrunk and rendered variants
    // run at α = 1.
    let runs: Vec<RunParams> = variants
        .iter()
        .flat_map(|&v| match v.takes_alpha() {
            false => vec![(1.0, v)],
            true => params.alphas.iter().map(|&a| (a, v)).collect(),
        })
        .map(|(a, v)| {
            let mut p = RunParams::new(a, v)?;
            if let Some(n) = params.renders_per_segment {
                p.rendered.per_segment = n;
            }
            Ok::<_, occlusion::OcclusionError>(p)
        })
        .collect::<std::result::Result<_, _>>()?;
    if let Some(n) = params.renders_per_segment {
        crate::check_count("--renders-per-segment", n, 1024)?;
        if n == 0 {
            return Err(parameter!("--renders-per-segment must be at least 1"));
        }
    }
    if pre.viewpoints.is_empty() {
        return Err(input!("{}: no viewpoints", dir.report_json().display()));
    }
    if let Some(o) = params.oracle {
        crate::check_count("--oracle-per-segment", o.per_segment, 10_000)?;
        if let Some(n) = o.face_size {
            crate::check_face_size("--oracle-face-size", n)?;
        }
    }
    let rendered = variants.contains(&Variant::Rendered);
    let renderer = if params.oracle.is_some() || rendered {
        let face = params.oracle.and_then(|o| o.face_size);
        Some(OracleSource::load(&dir, &pre, face)?)
    } else {
        None
    };
    let mut culling = Culling {
        net: network_of(&dir, &pre)?,
        pre: &pre,
        runs: &runs,
        solids: solids.as_ref(),
        oracle: params.oracle,
        renderer,
        open: BTreeMap::new(),
        reports: Vec::new(),
        decisions: runs
            .iter()
            .map(|p| RunDecisions {
                alpha: p.alpha,
                variant: p.variant,
                viewpoints: Vec::new(),
            })
            .collect(),
        vis_all: Vec::new(),
        vis_done: Vec::new(),
        first: None,
        load_seconds: 0.0,
        oracle_seconds: 0.0,
        render_seconds: 0.0,
        inside: 0,
    };
    culling.all(&dir, progress)?;
    if culling.inside > 0 {
        progress.message(&format!(
            "note: {} depth-render positions between the viewpoints are inside a solid (the \
             track passes through an object): they see nothing, and prove nothing hidden",
            culling.inside
        ));
    }
    let report = culling.report()?;
    write_outputs(params, &report, &culling, &variants, progress)?;
    log.end(&[
        ("viewpoints", pre.viewpoints.len().into()),
        ("runs", report.runs.len().into()),
        ("load_seconds", culling.load_seconds.into()),
        ("oracle_seconds", culling.oracle_seconds.into()),
        ("render_seconds", culling.render_seconds.into()),
        ("positions_inside_solids", culling.inside.into()),
    ])?;
    progress.output(&format!(
        "wrote {}, cull.md, cull_tiles.json, cull/*.png ({:.2} s)\n",
        params.dir.join("cull.json").display(),
        t_start.elapsed().as_secs_f64()
    ));
    Ok(report)
}

/// The files of the stage and its tables on the output.
fn write_outputs(
    params: &CullParams,
    report: &CullReport,
    culling: &Culling,
    variants: &[Variant],
    progress: &Reporter,
) -> Result<()> {
    let out = &params.dir;
    let (grid, _) = culling
        .first
        .as_ref()
        .ok_or_else(|| input!("no viewpoint was loaded"))?;
    store::write_json(&out.join("cull.json"), report)?;
    store::write_atomic(&out.join("cull.md"), markdown(report).as_bytes())?;
    store::write_json(
        &out.join("cull_tiles.json"),
        &TileDecisions {
            grid: *grid,
            runs: culling.decisions.clone(),
        },
    )?;
    let vis = (!culling.vis_done.is_empty()).then_some(culling.vis_done.as_slice());
    for d in &culling.decisions {
        let name = format!("{}-a{}.png", d.variant.name(), d.alpha);
        store::write_atomic(
            &out.join("cull").join(name),
            &atlas_png(grid, &d.viewpoints, vis),
        )?;
    }
    for v in variants {
        let rs: Vec<&RunReport> = report.runs.iter().filter(|r| r.variant == *v).collect();
        progress.output(&format!("variant {}:\n{}\n", v.name(), paper_table(&rs)));
    }
    for r in &report.runs {
        progress.output(&format!(
            "{} α = {}: {:.2} s culling{}\n",
            r.variant.name(),
            r.alpha,
            r.seconds,
            r.later_slabs()
                .kept_per_seen()
                .map_or(String::new(), |x| format!(
                    ", later slabs kept ÷ seen {x:.2}×"
                ))
        ));
    }
    if let Some(o) = &report.oracle {
        progress.output(&format!(
            "oracle: both ends and {} offset positions per segment, {}² per face, {:.2} s\n",
            o.per_segment, o.face_size, o.seconds
        ));
    }
    Ok(())
}

/// A viewpoint whose segments are still being traced: its layers, the oracle's marks so far
/// and the rendered variant's verdict from each segment done.
struct Open {
    loaded: Loaded,
    vis: Option<Visibility>,
    hidden: Vec<Vec<Vec<bool>>>,
    /// Segments that touch it and are not traced yet.
    left: usize,
}

/// The culling of a network a segment at a time: a viewpoint is loaded when the first segment
/// that touches it is traced and decided once the last one is.
struct Culling<'a> {
    net: Network,
    pre: &'a PrerenderReport,
    runs: &'a [RunParams],
    solids: Option<&'a SceneSolids<'a, Scene>>,
    oracle: Option<OracleParams>,
    /// Depth renders for the oracle and the rendered variant.
    renderer: Option<OracleSource>,
    open: BTreeMap<usize, Open>,
    reports: Vec<RunReport>,
    decisions: Vec<RunDecisions>,
    vis_all: Vec<(usize, Visibility)>,
    /// The oracle's marks per viewpoint in order, once every viewpoint is decided.
    vis_done: Vec<Visibility>,
    /// The tile grid and slab ranges every viewpoint must share.
    first: Option<(TileGrid, Vec<SlabRange>)>,
    load_seconds: f64,
    oracle_seconds: f64,
    /// Depth renders of the rendered variant.
    render_seconds: f64,
    /// Positions of depth renders found inside a solid (the track passes through an object).
    inside: usize,
}

impl Culling<'_> {
    /// Every segment traced, every viewpoint decided.
    fn all(&mut self, dir: &PrerenderDir, progress: &Reporter) -> Result<()> {
        let count = self.net.viewpoints.len();
        let pb = progress.bar(count as u64, "cull", BarKind::Steps);
        for e in 0..self.net.segments.len() {
            let sg = self.net.segments[e];
            for v in [sg.from, sg.to] {
                self.load(dir, v)?;
            }
            self.trace(dir, Some(e))?;
            let ends = if sg.from == sg.to {
                vec![sg.from]
            } else {
                vec![sg.from, sg.to]
            };
            for v in ends {
                let done = self.open.get_mut(&v).is_some_and(|o| {
                    o.left = o.left.saturating_sub(1);
                    o.left == 0
                });
                if done {
                    self.finish(v)?;
                    pb.inc(1);
                }
            }
        }
        // Viewpoints no segment touches (a track of one viewpoint).
        for v in 0..count {
            if self.net.incident(v).is_empty() {
                self.load(dir, v)?;
                self.trace(dir, None)?;
                self.finish(v)?;
                pb.inc(1);
            }
        }
        pb.finish();
        self.decisions
            .iter_mut()
            .for_each(|d| d.viewpoints.sort_by_key(|x| x.index));
        self.vis_all.sort_by_key(|x| x.0);
        self.vis_done = std::mem::take(&mut self.vis_all)
            .into_iter()
            .map(|x| x.1)
            .collect();
        Ok(())
    }

    /// Viewpoint `v`'s layers, loaded (and checked against the first's grid and slabs) unless
    /// they already are.
    fn load(&mut self, dir: &PrerenderDir, v: usize) -> Result<()> {
        if self.open.contains_key(&v) {
            return Ok(());
        }
        let vp = &self.pre.viewpoints[v];
        let t = Instant::now();
        let cur = load_viewpoint(dir, vp.index)?;
        self.load_seconds += t.elapsed().as_secs_f64();
        if let Some(s) = self.solids {
            same_geometry(s.scene(), vp.position, &cur.layers).with_context(|| {
                format!(
                    "viewpoint {}: the shrunk variant needs scene `{}`",
                    vp.index, self.pre.scene
                )
            })?;
        }
        let ranges: Vec<SlabRange> = cur.layers.iter().map(|l| l.range).collect();
        match &self.first {
            None => {
                self.first = Some((cur.grid, ranges));
                self.reports = self
                    .runs
                    .iter()
                    .map(|p| RunReport::new(p.alpha, p.variant, cur.layers.len()))
                    .collect();
            }
            Some((g, r)) => {
                if *g != cur.grid || *r != ranges {
                    return Err(input!(
                        "viewpoint {}: tile grid or slab ranges differ from viewpoint {} (re-run `railview slabs`)",
                        vp.index,
                        self.pre.viewpoints[0].index
                    ));
                }
            }
        }
        let vis = self
            .oracle
            .map(|_| Visibility::new(cur.grid.face_size, cur.layers.len()));
        self.open.insert(
            v,
            Open {
                loaded: cur,
                vis,
                hidden: Vec::new(),
                left: self.net.incident(v).len(),
            },
        );
        Ok(())
    }

    /// Segment `e` (or, with `None`, the one viewpoint of a track without segments, the last
    /// one loaded): the oracle's positions marked in both ends' layers, and the rendered
    /// variant's verdict on both ends' tiles.
    fn trace(&mut self, dir: &PrerenderDir, e: Option<usize>) -> Result<()> {
        let (path, ends): (Vec<glam::DVec3>, Vec<usize>) = match e {
            Some(e) => {
                let sg = self.net.segments[e];
                let ends = if sg.from == sg.to {
                    vec![sg.from]
                } else {
                    vec![sg.from, sg.to]
                };
                (self.net.segment_path(e), ends)
            }
            None => {
                let v = *self
                    .open
                    .keys()
                    .find(|&&v| self.net.incident(v).is_empty())
                    .ok_or_else(|| input!("no viewpoint to trace"))?;
                (vec![self.pre.viewpoints[v].position], vec![v])
            }
        };
        let refs: Vec<tracks::ReferenceViewpoint> =
            ends.iter().map(|&v| self.pre.viewpoints[v]).collect();
        let ref_list: Vec<&tracks::ReferenceViewpoint> = refs.iter().collect();
        let grid = self
            .first
            .as_ref()
            .map(|f| f.0)
            .ok_or_else(|| input!("no viewpoint was loaded"))?;
        if let Some(j) = self
            .runs
            .iter()
            .position(|p| p.variant == Variant::Rendered)
        {
            let p = self.runs[j].rendered;
            let renderer = self
                .renderer
                .as_mut()
                .ok_or_else(|| input!("no depth renderer"))?;
            let seg_ends: Vec<SegmentEnd> = ends
                .iter()
                .map(|&v| SegmentEnd {
                    viewpoint: self.pre.viewpoints[v].position,
                    grid: &self.open[&v].loaded.grid,
                    layers: &self.open[&v].loaded.layers,
                })
                .collect();
            let t = Instant::now();
            let (mut render_s, mut inside) = (0.0, 0usize);
            // Built-in and TOML scenes: rays cast where the tests look; POV-Ray: whole renders.
            let verdict = match renderer {
                OracleSource::Geometry(scene) => {
                    let g: &dyn occlusion::Geometry = &**scene;
                    hidden_from_segment(&path, &seg_ends, &p, |centres| {
                        Ok::<_, crate::Error>(
                            centres.iter().map(|_| Some(BallDepth::Rays(g))).collect(),
                        )
                    })?
                }
                source => hidden_from_segment(&path, &seg_ends, &p, |centres| {
                    let t = Instant::now();
                    let d = source.depths(dir, centres, grid.face_size, &ref_list);
                    render_s += t.elapsed().as_secs_f64();
                    if let Ok(d) = &d {
                        inside += d.iter().filter(|x| x.is_none()).count();
                    }
                    Ok::<_, crate::Error>(d?.into_iter().map(|d| d.map(BallDepth::Map)).collect())
                })?,
            }
            .context("the rendered variant")?;
            let total = t.elapsed().as_secs_f64();
            self.render_seconds += render_s;
            self.inside += inside;
            let run = &mut self.reports[j];
            // The variant's cost is its renders too: they are most of it for an import.
            run.seconds += total;
            let stats = RenderedStats {
                render_ms: (render_s * 1e3).round() as u64,
                ..verdict.stats
            };
            run.rendered
                .get_or_insert_with(Default::default)
                .add(&stats);
            for (v, h) in ends.iter().zip(verdict.hidden) {
                if let Some(o) = self.open.get_mut(v) {
                    o.hidden.push(h);
                }
            }
        }
        let (Some(o), Some(source)) = (self.oracle, self.renderer.as_mut()) else {
            return Ok(());
        };
        let rule = MatchRule::default();
        let t = Instant::now();
        let n = o.face_size.unwrap_or(grid.face_size);
        let positions = oracle_positions(&path, o.per_segment);
        let depths = source.depths(dir, &positions, n, &ref_list)?;
        for (x, depth) in positions.into_iter().zip(depths) {
            // A position inside a solid sees nothing.
            let Some(depth) = depth else {
                self.inside += 1;
                continue;
            };
            for &v in &ends {
                let at = self.pre.viewpoints[v].position;
                if let Some(Open {
                    loaded,
                    vis: Some(vis),
                    ..
                }) = self.open.get(&v)
                {
                    mark_visible(x, &depth, at, &loaded.layers, &rule, vis);
                }
            }
        }
        self.oracle_seconds += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Run every (α, variant) on viewpoint `v`, whose segments are all traced, and record the
    /// results.
    fn finish(&mut self, v: usize) -> Result<()> {
        let Some(open) = self.open.remove(&v) else {
            return Ok(());
        };
        let l = &open.loaded;
        let cell = Cell {
            viewpoint: self.pre.viewpoints[v].position,
            paths: self.net.cell_paths(v),
        };
        for (j, p) in self.runs.iter().enumerate() {
            let t = Instant::now();
            let mut stats = None;
            let c = match (p.variant, self.solids) {
                (Variant::Shrunk, Some(scene)) => {
                    let (c, s) = cull_viewpoint_shrunk(&cell, &l.grid, &l.layers, &p.shrunk, scene)
                        .with_context(|| format!("culling viewpoint {}", l.index))?;
                    stats = Some(s);
                    c
                }
                (Variant::Rendered, _) => {
                    let hidden: Vec<&[Vec<bool>]> =
                        open.hidden.iter().map(|h| h.as_slice()).collect();
                    cull_from_segments(&l.layers, &hidden)
                        .with_context(|| format!("culling viewpoint {}", l.index))?
                }
                _ => cull_viewpoint(&cell, &l.grid, &l.layers, p)
                    .with_context(|| format!("culling viewpoint {}", l.index))?,
            };
            let secs = t.elapsed().as_secs_f64();
            let run = &mut self.reports[j];
            if let Some(s) = stats {
                run.shrunk.get_or_insert_with(Default::default).add(&s);
            }
            let scores = open.vis.as_ref().map(|vis| score(&c, &l.grid, vis));
            run.add(&c, scores.as_deref());
            run.seconds += secs;
            self.decisions[j]
                .viewpoints
                .push(ViewpointDecisions::new(l.index, &l.grid, &c));
        }
        if let Some(vis) = open.vis {
            self.vis_all.push((v, vis));
        }
        Ok(())
    }

    /// `cull.json`.
    fn report(&self) -> Result<CullReport> {
        let (grid, ranges) = self
            .first
            .clone()
            .ok_or_else(|| input!("no viewpoint was loaded"))?;
        Ok(CullReport {
            viewpoints: self.net.viewpoints.len(),
            face_size: grid.face_size,
            tile_size: grid.tile_size,
            slab_ranges: ranges,
            runs: self.reports.clone(),
            oracle: self
                .oracle
                .zip(self.renderer.as_ref())
                .map(|(o, source)| OracleInfo {
                    per_segment: o.per_segment,
                    face_size: o.face_size.unwrap_or(grid.face_size),
                    source: source.name().into(),
                    seconds: self.oracle_seconds,
                }),
            load_seconds: self.load_seconds,
        })
    }
}
