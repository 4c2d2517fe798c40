//! The prerender stage: the reference viewpoints of a track rendered into a prerender
//! directory (layout in `prerender::store`), by the built-in tracer ([`Renderer::Builtin`],
//! built-in scenes and scene TOML files) or by POV-Ray ([`Renderer::PovRay`], a `.pov` scene
//! used unchanged). A [`Shard`] renders one shard's samples and leaves the report to the
//! merge; [`PrerenderParams::merge`] renders nothing, checks that every sample is complete
//! (naming those that are not) and writes the report.

mod pov;

use std::path::{Path, PathBuf};

use prerender::job::{self, ReportInput, RunStats, Shard};
use prerender::render::RenderOptions;
use prerender::runlog::RunLog;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use tracks::{SlabRange, TrackSet};

pub use pov::PovParams;

use crate::error::{parameter, Context, Error, Result};
use crate::progress::{BarKind, Reporter};

/// Who renders the panoramas.
#[derive(Clone, Debug, PartialEq)]
pub enum Renderer {
    /// The built-in ray tracer: a built-in scene name or a scene TOML file.
    Builtin {
        /// Colour rays per pixel along each axis (1 to 16).
        supersample: u32,
        /// Trace shadow rays.
        shadows: bool,
    },
    /// POV-Ray 3.7 on a `.pov` scene.
    PovRay(PovParams),
}

/// Who rendered a prerender directory, as its report (`prerender.json`) says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RenderedBy {
    /// The built-in tracer (`builtin`): the scene's geometry is at hand.
    Builtin,
    /// POV-Ray (`povray`): the import can be re-created from the report.
    PovRay,
    /// Another renderer, which the stages cannot drive.
    Other,
}

impl RenderedBy {
    /// The renderer of `report`.
    pub fn of(report: &PrerenderReport) -> RenderedBy {
        match report.renderer.as_str() {
            "builtin" => RenderedBy::Builtin,
            "povray" => RenderedBy::PovRay,
            _ => RenderedBy::Other,
        }
    }
}

/// What to prerender, and where.
#[derive(Clone, Debug, PartialEq)]
pub struct PrerenderParams {
    /// Built-in: a built-in scene name or a scene TOML file. POV-Ray: the `.pov` scene.
    pub scene: String,
    /// Built-in: a track of the scene (`all` for every one, a network) or a track TOML file.
    /// POV-Ray: a track TOML file in railview coordinates.
    pub track: String,
    /// Which track of the file (POV-Ray default: the first; `all`: every one, a network).
    pub track_name: Option<String>,
    /// Pixels along a cube face.
    pub face_size: u32,
    /// Face size of the fast depth-only pass (default: 64 for the tracer, 32 for POV-Ray).
    pub lowres_face_size: Option<u32>,
    /// The prerender directory (created; resumable).
    pub out: PathBuf,
    /// Also render slab layers for these depth ranges (default: those already rendered).
    pub slabs: Option<Vec<SlabRange>>,
    /// Render only this shard's samples; the report is left to the merge.
    pub shard: Option<Shard>,
    /// Render nothing: check that every sample is complete and write the report.
    pub merge: bool,
    pub renderer: Renderer,
}

impl PrerenderParams {
    /// A built-in tracer's prerender with the command's defaults.
    pub fn builtin(scene: &str, track: &str, face_size: u32, out: &Path) -> PrerenderParams {
        PrerenderParams {
            scene: scene.to_string(),
            track: track.to_string(),
            track_name: None,
            face_size,
            lowres_face_size: None,
            out: out.to_path_buf(),
            slabs: None,
            shard: None,
            merge: false,
            renderer: Renderer::Builtin {
                supersample: 1,
                shadows: true,
            },
        }
    }

    /// The low-resolution depth pass's face size.
    pub fn lowres(&self) -> u32 {
        self.lowres_face_size.unwrap_or(match self.renderer {
            Renderer::Builtin { .. } => 64,
            Renderer::PovRay(_) => 32,
        })
    }

    /// The command line a person would type to run this stage (after `railview`), for
    /// reports and messages; never parsed.
    pub fn command_line(&self) -> Vec<String> {
        let mut v: Vec<String> = match &self.renderer {
            Renderer::Builtin {
                supersample,
                shadows,
            } => {
                let mut v = vec![
                    "prerender".into(),
                    "--scene".into(),
                    self.scene.clone(),
                    "--track".into(),
                    self.track.clone(),
                    "--supersample".into(),
                    supersample.to_string(),
                ];
                if !shadows {
                    v.push("--no-shadows".into());
                }
                v
            }
            Renderer::PovRay(p) => p.command_line(self),
        };
        v.extend([
            "--face-size".into(),
            self.face_size.to_string(),
            "--out".into(),
            self.out.display().to_string(),
        ]);
        if let Some(n) = self.lowres_face_size {
            v.extend(["--lowres-face-size".into(), n.to_string()]);
        }
        if let Some(s) = &self.slabs {
            v.extend(["--slabs".into(), labels(s)]);
        }
        if let Some(s) = self.shard {
            v.extend(["--shard".into(), format!("{}/{}", s.index, s.count)]);
        }
        if self.merge {
            v.push("--merge".into());
        }
        v
    }
}

/// What a prerender run did.
#[derive(Clone, Debug, PartialEq)]
pub struct Prerendered {
    /// Samples this run was responsible for (its shard's, or all).
    pub samples: usize,
    /// Samples rendered now, and found complete already.
    pub rendered: usize,
    pub skipped: usize,
    /// The report written (`prerender.json`); none for a shard.
    pub report: Option<PrerenderReport>,
}

/// Run the prerender stage.
pub fn run(params: &PrerenderParams, progress: &Reporter) -> Result<Prerendered> {
    crate::check_face_size("--face-size", params.face_size)?;
    crate::check_face_size("--lowres-face-size", params.lowres())?;
    match &params.renderer {
        Renderer::Builtin {
            supersample,
            shadows,
        } => {
            if *supersample == 0 || *supersample > 16 {
                return Err(parameter!("--supersample must be between 1 and 16"));
            }
            let opts = RenderOptions {
                face_size: params.face_size,
                supersample: *supersample,
                shadows: *shadows,
            };
            builtin(params, opts, progress)
        }
        Renderer::PovRay(pov) => pov::run(params, pov, progress),
    }
}

/// The built-in tracer's run.
fn builtin(
    params: &PrerenderParams,
    opts: RenderOptions,
    progress: &Reporter,
) -> Result<Prerendered> {
    let (scene, scene_tracks) = crate::scene::load_scene(&params.scene)?;
    let (track_name, tracks) = crate::scene::pick_tracks(
        &params.track,
        params.track_name.as_deref(),
        scene_tracks.as_ref(),
    )?;
    store::ensure_writable_dir(&params.out).context("output directory")?;
    let dir = PrerenderDir::new(&params.out);
    let (_, viewpoints) = crate::network::network_of_tracks(tracks.clone())?;
    let lowres = params.lowres();
    // Without slabs asked for, a rerun keeps the slab layers an earlier run (or the slabs
    // stage) rendered at this face size, so the report never forgets them: those of the
    // report, or (before any report, as after shards run with slabs) those of the first
    // sample.
    let slabs: Vec<SlabRange> = match &params.slabs {
        Some(s) => s.clone(),
        None => dir
            .read_report()
            .ok()
            .filter(|r| r.face_size == params.face_size)
            .map(|r| r.slabs)
            .or_else(|| {
                let first = viewpoints.first()?;
                job::sample_is_complete(&dir, first, params.face_size, lowres)
                    .then(|| dir.layers_meta(first.index).map(|m| m.slabs))
                    .flatten()
            })
            .unwrap_or_default(),
    };
    let one = TrackSet { tracks };
    // Every shard writes the same bytes here; written only when it differs, so a shard
    // starting later never replaces the file under one already running.
    store::write_if_changed(&dir.track_toml(), one.to_toml().as_bytes())?;
    // The sky alone, in every direction (the background behind occluders); the same bytes
    // from every shard.
    let sky = prerender::render::render_sky(&scene, params.face_size, opts.supersample);
    store::write_if_changed(&dir.sky_png(), &store::encode_rgb_png(&sky))?;

    let report_input = ReportInput {
        scene: &params.scene,
        renderer: "builtin",
        track: &track_name,
        viewpoints: &viewpoints,
        face_size: params.face_size,
        lowres_face_size: lowres,
        slabs: &slabs,
    };
    if params.merge {
        return merge(&dir, &report_input, &opts, &params.out, progress);
    }
    let shard = params.shard;
    let log = RunLog::create(&params.out, "prerender", shard.map(|s| s.pair()))?;
    let mine: Vec<_> = viewpoints
        .iter()
        .copied()
        .filter(|v| shard.is_none_or(|s| s.covers(v.index)))
        .collect();
    // What the run will do, before it starts: a large face size is a long run.
    let px = 6.0 * (params.face_size as f64).powi(2);
    progress.message(&format!(
        "rendering {} of {} samples: 6 faces of {} px per side, {:.1} Mpx per sample \
         (colour and depth ≈ {:.0} MiB per sample in memory); the bar's eta follows the first",
        mine.len(),
        viewpoints.len(),
        params.face_size,
        px / 1e6,
        px * 7.0 / 1048576.0
    ));
    let pb = progress.bar(mine.len() as u64, "samples", BarKind::Long);
    let mut stats = job::render_track(
        &dir,
        &scene,
        &mine,
        opts,
        lowres,
        None,
        Some(&log),
        &|_, _| pb.inc(1),
    )?;
    pb.finish();
    let mut layers = RunStats::default();
    if !slabs.is_empty() {
        let pb = progress.bar(mine.len() as u64, "slab layers", BarKind::Long);
        layers =
            job::write_slab_layers_with(&dir, &scene, &mine, &slabs, opts, Some(&log), &|_, _| {
                pb.inc(1)
            })?;
        pb.finish();
        stats.render_seconds += layers.render_seconds;
    }
    let wall = log.end(&[
        ("rendered", stats.rendered.into()),
        ("skipped", stats.skipped.into()),
        ("layers_rendered", layers.rendered.into()),
        ("layers_skipped", layers.skipped.into()),
        ("render_seconds", stats.render_seconds.into()),
    ])?;
    let mut done = Prerendered {
        samples: mine.len(),
        rendered: stats.rendered,
        skipped: stats.skipped,
        report: None,
    };
    if let Some(s) = shard {
        progress.message(&format!(
            "shard {}/{}: {} of {} samples rendered, {} already complete, in {wall:.1} s (log: {}). \
             Once every shard has finished, `railview prerender … --merge` checks the track and \
             writes prerender.json.",
            s.index,
            s.count,
            stats.rendered,
            mine.len(),
            stats.skipped,
            log.path().display()
        ));
        return Ok(done);
    }
    let report = job::write_report(&dir, &report_input)?;
    let report = record_render_options(&dir, report, &opts)?;
    progress.message(&format!(
        "{} of {} samples complete in {} ({} rendered, {} skipped, {wall:.1} s); {:.0} primary rays/s",
        report.extra["complete_samples"],
        report.samples,
        params.out.display(),
        stats.rendered,
        stats.skipped,
        report.rays_per_second
    ));
    done.report = Some(report);
    Ok(done)
}

/// Later stages render slab layers the way the panoramas were rendered: the report records
/// the rays per pixel and whether shadows were traced.
fn record_render_options(
    dir: &PrerenderDir,
    mut report: PrerenderReport,
    opts: &RenderOptions,
) -> Result<PrerenderReport> {
    if let Some(extra) = report.extra.as_object_mut() {
        extra.insert("supersample".into(), opts.supersample.into());
        extra.insert("shadows".into(), opts.shadows.into());
    }
    store::write_json(&dir.report_json(), &report)?;
    Ok(report)
}

/// The merge: every sample (and, with slabs, every slab layer set) must be complete; then the
/// report covering every shard.
fn merge(
    dir: &PrerenderDir,
    input: &ReportInput<'_>,
    opts: &RenderOptions,
    out: &Path,
    progress: &Reporter,
) -> Result<Prerendered> {
    let (base, layers) = job::missing_samples(
        dir,
        input.viewpoints,
        input.face_size,
        input.lowres_face_size,
        input.slabs,
    );
    let shards = job::logged_shard_count(dir);
    let total = input.viewpoints.len();
    if !base.is_empty() {
        return Err(Error::Input(format!(
            "{}: {}",
            out.display(),
            job::missing_message(
                &format!(
                    "base pass at face size {} (low-res {})",
                    input.face_size, input.lowres_face_size
                ),
                &base,
                total,
                shards
            )
        )));
    }
    if !layers.is_empty() {
        return Err(Error::Input(format!(
            "{}: {}",
            out.display(),
            job::missing_message(
                &format!("slab layers {}", labels(input.slabs)),
                &layers,
                total,
                shards
            )
        )));
    }
    let report = job::write_report(dir, input)?;
    let report = record_render_options(dir, report, opts)?;
    let shard_list: Vec<String> = report
        .shards
        .iter()
        .map(|s| {
            format!(
                "{} ({} samples)",
                s.shard
                    .map_or("unsharded runs".to_string(), |(k, n)| format!("{k}/{n}")),
                s.samples.len()
            )
        })
        .collect();
    progress.message(&format!(
        "merged {}: all {} samples complete; rendered by {}; {:.1} s of rendering",
        out.display(),
        report.samples,
        if shard_list.is_empty() {
            "no logged run".to_string()
        } else {
            shard_list.join(", ")
        },
        report.seconds
    ));
    Ok(Prerendered {
        samples: total,
        rendered: 0,
        skipped: 0,
        report: Some(report),
    })
}

/// `0-10,10-inf`.
pub(crate) fn labels(slabs: &[SlabRange]) -> String {
    slabs
        .iter()
        .map(|s| s.label())
        .collect::<Vec<_>>()
        .join(",")
}
