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

use std::path::PathBuf;
use std::time::Instant;

use occlusion::oracle::oracle_positions;
use occlusion::report::{
    atlas_png, markdown, paper_table, CullReport, OracleInfo, RunDecisions, RunReport,
    TileDecisions, ViewpointDecisions,
};
use occlusion::{
    cull_viewpoint, cull_viewpoint_rendered, cull_viewpoint_shrunk, mark_visible, score, Ball,
    BallView, CullParams as RunParams, MatchRule, SceneSolids, Visibility,
};
use prerender::runlog::RunLog;
use prerender::scene::Scene;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use tracks::{CubeMap, SlabRange, TileGrid};

pub use occlusion::Variant;

use self::oracle::{load_viewpoint, same_geometry, Loaded, OracleSource, TrackPath};
use crate::error::{input, parameter, Context, Result};
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
    /// The rendered variant: depth renders per segment (default
    /// [`occlusion::RenderedParams`]'s 32).
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
        count: pre.viewpoints.len(),
        path: TrackPath::new(&dir, &pre),
        runs: &runs,
        solids: solids.as_ref(),
        oracle: params.oracle,
        renderer,
        views: Vec::new(),
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
        first: None,
        load_seconds: 0.0,
        oracle_seconds: 0.0,
        render_seconds: 0.0,
        inside: 0,
    };
    culling.all(&dir, &pre, progress)?;
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
    let vis = (!culling.vis_all.is_empty()).then_some(culling.vis_all.as_slice());
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

/// The culling of every viewpoint, one after the other.
struct Culling<'a> {
    count: usize,
    path: TrackPath,
    runs: &'a [RunParams],
    solids: Option<&'a SceneSolids<'a, Scene>>,
    oracle: Option<OracleParams>,
    /// Depth renders for the oracle and the rendered variant.
    renderer: Option<OracleSource>,
    /// The rendered variant: per segment, its balls and their depth renders (dropped once
    /// both viewpoints of the segment are decided).
    views: Vec<Option<Vec<BallView>>>,
    reports: Vec<RunReport>,
    decisions: Vec<RunDecisions>,
    vis_all: Vec<Visibility>,
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
    /// Every viewpoint: loaded, traced by the oracle, culled.
    fn all(
        &mut self,
        dir: &PrerenderDir,
        pre: &PrerenderReport,
        progress: &Reporter,
    ) -> Result<()> {
        let count = pre.viewpoints.len();
        let pb = progress.bar(count as u64, "cull", BarKind::Steps);
        // Viewpoint i is finished once the segment to i + 1 has been traced (oracle) — keep
        // the previous one loaded until then.
        let mut prev: Option<(Loaded, Option<Visibility>)> = None;
        for (k, vp) in pre.viewpoints.iter().enumerate() {
            let t = Instant::now();
            let cur = load_viewpoint(dir, vp.index)?;
            self.load_seconds += t.elapsed().as_secs_f64();
            if let Some(s) = self.solids {
                same_geometry(s.scene(), vp.position, &cur.layers).with_context(|| {
                    format!(
                        "viewpoint {}: the shrunk variant needs scene `{}`",
                        vp.index, pre.scene
                    )
                })?;
            }
            let ranges: Vec<SlabRange> = cur.layers.iter().map(|l| l.range).collect();
            match &self.first {
                None => self.first = Some((cur.grid, ranges)),
                Some((g, r)) => {
                    if *g != cur.grid || *r != ranges {
                        return Err(input!(
                            "viewpoint {}: tile grid or slab ranges differ from viewpoint {} (re-run `railview slabs`)",
                            vp.index,
                            pre.viewpoints[0].index
                        ));
                    }
                }
            }
            let cur_vis = self.trace(dir, pre, k, &cur, prev.as_ref())?;
            if let Some((p, pv)) = prev.take() {
                self.finish(&p, k - 1, pv)?;
                pb.inc(1);
            }
            prev = Some((cur, cur_vis));
        }
        if let Some((p, pv)) = prev.take() {
            self.finish(&p, count - 1, pv)?;
            pb.inc(1);
        }
        pb.finish();
        Ok(())
    }

    /// The segment ending at viewpoint `k`: the rendered variant's depth renders from its
    /// balls, and the oracle's positions marked visible in the previous viewpoint and this
    /// one; this one's visibility so far.
    fn trace(
        &mut self,
        dir: &PrerenderDir,
        pre: &PrerenderReport,
        k: usize,
        cur: &Loaded,
        prev: Option<&(Loaded, Option<Visibility>)>,
    ) -> Result<Option<Visibility>> {
        let count = pre.viewpoints.len();
        let ends: Vec<&tracks::ReferenceViewpoint> = match k {
            0 => vec![&pre.viewpoints[0]],
            _ => vec![&pre.viewpoints[k - 1], &pre.viewpoints[k]],
        };
        if let Some(p) = self.runs.iter().find(|p| p.variant == Variant::Rendered) {
            let path = match k {
                0 if count == 1 => vec![self.path.position(0)],
                0 => Vec::new(),
                _ => self.path.between(k - 1),
            };
            if !path.is_empty() {
                let t = Instant::now();
                let balls = occlusion::rendered::cover(&path, p.rendered.per_segment);
                let centres: Vec<glam::DVec3> = balls.iter().map(|b| b.centre).collect();
                let renderer = self
                    .renderer
                    .as_mut()
                    .ok_or_else(|| input!("no depth renderer"))?;
                let n = cur.grid.face_size;
                let depths = renderer.depths(dir, &centres, n, &ends)?;
                // A ball whose centre is inside a solid (a track through an object) is
                // replaced by the balls of its two halves; one of those inside a solid too
                // shows nothing and proves nothing.
                let mut renders: Vec<(Ball, Option<CubeMap<f32>>)> = Vec::new();
                for (j, (b, d)) in balls.into_iter().zip(depths).enumerate() {
                    if d.is_some() {
                        renders.push((b, d));
                        continue;
                    }
                    let hs = occlusion::rendered::halves(&path, p.rendered.per_segment, j);
                    let hc: Vec<glam::DVec3> = hs.iter().map(|b| b.centre).collect();
                    let hd = renderer.depths(dir, &hc, n, &ends)?;
                    renders.extend(hs.into_iter().zip(hd));
                }
                self.inside += renders.iter().filter(|(_, d)| d.is_none()).count();
                let views = renders
                    .into_iter()
                    .map(|(b, d)| {
                        let d = d.unwrap_or_else(|| CubeMap::filled(n, f32::INFINITY));
                        BallView::new(b, d, p.rendered.discontinuity)
                    })
                    .collect();
                self.views.resize_with(k.max(1), || None);
                self.views[k.max(1) - 1] = Some(views);
                self.render_seconds += t.elapsed().as_secs_f64();
            }
        }
        let (Some(o), Some(source)) = (self.oracle, self.renderer.as_mut()) else {
            return Ok(None);
        };
        let cur_vis = Visibility::new(cur.grid.face_size, cur.layers.len());
        let rule = MatchRule::default();
        let t = Instant::now();
        let n = o.face_size.unwrap_or(cur.grid.face_size);
        let positions = match prev {
            Some(_) => oracle_positions(&self.path.between(k - 1), o.per_segment),
            None if count == 1 => vec![self.path.position(k)],
            None => Vec::new(),
        };
        let depths = source.depths(dir, &positions, n, &ends)?;
        for (x, depth) in positions.into_iter().zip(depths) {
            // A position inside a solid sees nothing.
            let Some(depth) = depth else {
                self.inside += 1;
                continue;
            };
            if let Some((p, Some(pv))) = prev {
                mark_visible(x, &depth, self.path.position(k - 1), &p.layers, &rule, pv);
            }
            mark_visible(
                x,
                &depth,
                self.path.position(k),
                &cur.layers,
                &rule,
                &cur_vis,
            );
        }
        self.oracle_seconds += t.elapsed().as_secs_f64();
        Ok(Some(cur_vis))
    }

    /// Run every (α, variant) on one loaded viewpoint and record the results.
    fn finish(&mut self, l: &Loaded, k: usize, vis: Option<Visibility>) -> Result<()> {
        let cell = self.path.cell(k);
        for (j, p) in self.runs.iter().enumerate() {
            let t = Instant::now();
            let (mut stats, mut rstats) = (None, None);
            let c = match (p.variant, self.solids) {
                (Variant::Shrunk, Some(scene)) => {
                    let (c, s) = cull_viewpoint_shrunk(&cell, &l.grid, &l.layers, &p.shrunk, scene)
                        .with_context(|| format!("culling viewpoint {}", l.index))?;
                    stats = Some(s);
                    c
                }
                (Variant::Rendered, _) => {
                    // The balls of the segments before and after the viewpoint.
                    let near: Vec<&BallView> = [k.checked_sub(1), Some(k)]
                        .into_iter()
                        .flatten()
                        .filter_map(|j| self.views.get(j).and_then(|v| v.as_ref()))
                        .flatten()
                        .collect();
                    let (c, s) =
                        cull_viewpoint_rendered(&cell, &l.grid, &l.layers, &near, &p.rendered)
                            .with_context(|| format!("culling viewpoint {}", l.index))?;
                    rstats = Some(s);
                    c
                }
                _ => cull_viewpoint(&cell, &l.grid, &l.layers, p)
                    .with_context(|| format!("culling viewpoint {}", l.index))?,
            };
            let secs = t.elapsed().as_secs_f64();
            if self.reports.len() <= j {
                self.reports
                    .push(RunReport::new(p.alpha, p.variant, l.layers.len()));
            }
            let run = &mut self.reports[j];
            if let Some(s) = stats {
                run.shrunk.get_or_insert_with(Default::default).add(&s);
            }
            if let Some(s) = rstats {
                run.rendered.get_or_insert_with(Default::default).add(&s);
            }
            let scores = vis.as_ref().map(|v| score(&c, &l.grid, v));
            run.add(&c, scores.as_deref());
            run.seconds += secs;
            self.decisions[j]
                .viewpoints
                .push(ViewpointDecisions::new(l.index, &l.grid, &c));
        }
        if let Some(v) = vis {
            self.vis_all.push(v);
        }
        // The segment before this viewpoint is not needed again.
        if let Some(v) = k.checked_sub(1).and_then(|j| self.views.get_mut(j)) {
            *v = None;
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
            viewpoints: self.count,
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
