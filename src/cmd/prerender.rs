//! `railview prerender`: render the reference viewpoints of a track with the built-in ray
//! tracer into a prerender directory (layout in `prerender::store`). `--shard K/N` renders
//! one shard's samples and leaves the report to the merge; `--merge` renders nothing, checks
//! that every sample is complete (naming those that are not) and writes the report.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use prerender::job::{self, ReportInput, RunStats, Shard};
use prerender::render::RenderOptions;
use prerender::runlog::RunLog;
use prerender::scene::Scene;
use prerender::store::{self, PrerenderDir, PrerenderReport};
use tracks::{SlabRange, Track, TrackSet};

/// Arguments of `railview prerender`.
#[derive(clap::Args)]
pub struct Args {
    /// Built-in scene name (`castle`, `nature`) or a scene TOML file.
    #[arg(long)]
    pub scene: String,
    /// A track of the scene (built-in or `[[track]]` in the scene file), or a track TOML file.
    #[arg(long, default_value = "main")]
    pub track: String,
    /// Pixels along a cube face.
    #[arg(long, default_value_t = 512)]
    pub face_size: u32,
    /// Output directory (created; resumable).
    #[arg(long)]
    pub out: PathBuf,
    /// Face size of the fast depth-only pass.
    #[arg(long, default_value_t = 64)]
    pub lowres_face_size: u32,
    /// Colour rays per pixel along each axis.
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Skip shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Also render slab layers for these depth ranges, e.g. `0-10,10-40,40-inf`.
    #[arg(long)]
    pub slabs: Option<String>,
    /// Render only viewpoints with index % N == K (`K/N`). Shards share one output directory;
    /// none of them writes `prerender.json` (the merge does).
    #[arg(long, conflicts_with = "merge")]
    pub shard: Option<String>,
    /// After the shards: render nothing, fail naming every sample (and its shard) that is not
    /// complete, else write `prerender.json` covering all shards.
    #[arg(long)]
    pub merge: bool,
}

/// The scene, its tracks (if it has any) and its display name.
fn load_scene(spec: &str) -> anyhow::Result<(Scene, Option<TrackSet>)> {
    if let Some(b) = prerender::scenes::builtin(spec) {
        return Ok((b.scene, Some(b.tracks)));
    }
    let path = Path::new(spec);
    if !path.exists() {
        bail!(
            "scene `{spec}` is neither a built-in scene ({}) nor an existing file",
            prerender::scenes::NAMES.join(", ")
        );
    }
    let text =
        super::read_text(path).with_context(|| format!("reading scene file {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let loader = move |rel: &str| -> Result<Vec<u8>, String> { super::read_asset(&base.join(rel)) };
    let scene = Scene::parse_toml_with(&text, spec, &loader)?;
    let tracks = prerender::parse::tracks_from_scene_toml(&text, spec)?;
    Ok((scene, tracks))
}

fn pick_track(spec: &str, scene_tracks: Option<&TrackSet>) -> anyhow::Result<Track> {
    if let Some(t) = scene_tracks.and_then(|s| s.get(spec)) {
        return Ok(t.clone());
    }
    let path = Path::new(spec);
    if !path.is_file() {
        let names = scene_tracks.map_or(String::from("none"), |s| s.names().join(", "));
        bail!("track `{spec}` is neither a track of the scene (tracks: {names}) nor a track file");
    }
    let text =
        super::read_text(path).with_context(|| format!("reading track file {}", path.display()))?;
    let set = TrackSet::parse(&text, spec)?;
    match set.tracks.as_slice() {
        [one] => Ok(one.clone()),
        _ => match set.get("main") {
            Some(t) => Ok(t.clone()),
            None => bail!(
                "{spec}: holds several tracks ({}) and none is named `main`",
                set.names().join(", ")
            ),
        },
    }
}

fn bar(len: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>14} [{elapsed_precise}] {wide_bar} {pos}/{len} (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(what.to_string());
    pb
}

/// Store errors already name the file and include their cause: keep the message single.
fn store_error(e: store::StoreError) -> anyhow::Error {
    anyhow::anyhow!("{e}")
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::face_size("--face-size", args.face_size)?;
    super::face_size("--lowres-face-size", args.lowres_face_size)?;
    if args.supersample == 0 || args.supersample > 16 {
        bail!("--supersample must be between 1 and 16");
    }
    let shard = args
        .shard
        .as_deref()
        .map(Shard::parse)
        .transpose()
        .map_err(anyhow::Error::msg)?;
    let explicit_slabs: Option<Vec<SlabRange>> = args
        .slabs
        .as_deref()
        .map(|s| SlabRange::parse_list(s).map_err(|e| anyhow::anyhow!("--slabs: {e}")))
        .transpose()?;
    let (scene, scene_tracks) = load_scene(&args.scene)?;
    let track = pick_track(&args.track, scene_tracks.as_ref())?;
    store::ensure_writable_dir(&args.out)
        .map_err(store_error)
        .context("output directory")?;
    let dir = PrerenderDir::new(&args.out);
    let viewpoints = track.viewpoints();
    // Without --slabs, a rerun keeps the slab layers an earlier run (or `railview slabs`)
    // rendered at this face size, so the report never forgets them: those of the report, or
    // (before any report, as after shards run with --slabs) those of the first sample.
    let slabs: Vec<SlabRange> = match explicit_slabs {
        Some(s) => s,
        None => dir
            .read_report()
            .ok()
            .filter(|r| r.face_size == args.face_size)
            .map(|r| r.slabs)
            .or_else(|| {
                let first = viewpoints.first()?;
                job::sample_is_complete(&dir, first, args.face_size, args.lowres_face_size)
                    .then(|| dir.layers_meta(first.index).map(|m| m.slabs))
                    .flatten()
            })
            .unwrap_or_default(),
    };
    let one = TrackSet {
        tracks: vec![track.clone()],
    };
    // Every shard writes the same bytes here; written only when it differs, so a shard
    // starting later never replaces the file under one already running.
    store::write_if_changed(&dir.track_toml(), one.to_toml().as_bytes()).map_err(store_error)?;

    let report_input = ReportInput {
        scene: &args.scene,
        renderer: "builtin",
        track: &track.name,
        viewpoints: &viewpoints,
        face_size: args.face_size,
        lowres_face_size: args.lowres_face_size,
        slabs: &slabs,
    };
    let opts = RenderOptions {
        face_size: args.face_size,
        supersample: args.supersample,
        shadows: !args.no_shadows,
    };
    if args.merge {
        return merge(&dir, &report_input, &opts, &args.out);
    }
    let log =
        RunLog::create(&args.out, "prerender", shard.map(|s| s.pair())).map_err(store_error)?;
    let mine: Vec<_> = viewpoints
        .iter()
        .copied()
        .filter(|v| shard.is_none_or(|s| s.covers(v.index)))
        .collect();
    // What the run will do, before it starts: a large face size is a long run.
    let px = 6.0 * (args.face_size as f64).powi(2);
    eprintln!(
        "rendering {} of {} samples: 6 faces of {} px per side, {:.1} Mpx per sample \
         (colour and depth ≈ {:.0} MiB per sample in memory); the bar's eta follows the first",
        mine.len(),
        viewpoints.len(),
        args.face_size,
        px / 1e6,
        px * 7.0 / 1048576.0
    );
    let pb = bar(mine.len(), "samples");
    let mut stats = job::render_track(
        &dir,
        &scene,
        &mine,
        opts,
        args.lowres_face_size,
        None,
        Some(&log),
        &|_, _| pb.inc(1),
    )
    .map_err(store_error)?;
    pb.finish();
    let mut layers = RunStats::default();
    if !slabs.is_empty() {
        let pb = bar(mine.len(), "slab layers");
        layers =
            job::write_slab_layers_with(&dir, &scene, &mine, &slabs, opts, Some(&log), &|_, _| {
                pb.inc(1)
            })
            .map_err(store_error)?;
        pb.finish();
        stats.render_seconds += layers.render_seconds;
    }
    let wall = log
        .end(&[
            ("rendered", stats.rendered.into()),
            ("skipped", stats.skipped.into()),
            ("layers_rendered", layers.rendered.into()),
            ("layers_skipped", layers.skipped.into()),
            ("render_seconds", stats.render_seconds.into()),
        ])
        .map_err(store_error)?;
    if let Some(s) = shard {
        eprintln!(
            "shard {}/{}: {} of {} samples rendered, {} already complete, in {wall:.1} s (log: {}). \
             Once every shard has finished, `railview prerender … --merge` checks the track and \
             writes prerender.json.",
            s.index,
            s.count,
            stats.rendered,
            mine.len(),
            stats.skipped,
            log.path().display()
        );
        return Ok(());
    }
    let report = job::write_report(&dir, &report_input).map_err(store_error)?;
    let report = record_render_options(&dir, report, &opts)?;
    eprintln!(
        "{} of {} samples complete in {} ({} rendered, {} skipped, {wall:.1} s); {:.0} primary rays/s",
        report.extra["complete_samples"],
        report.samples,
        args.out.display(),
        stats.rendered,
        stats.skipped,
        report.rays_per_second
    );
    Ok(())
}

/// Later stages render slab layers the way the panoramas were rendered: the report records
/// the rays per pixel and whether shadows were traced.
fn record_render_options(
    dir: &PrerenderDir,
    mut report: PrerenderReport,
    opts: &RenderOptions,
) -> anyhow::Result<PrerenderReport> {
    if let Some(extra) = report.extra.as_object_mut() {
        extra.insert("supersample".into(), opts.supersample.into());
        extra.insert("shadows".into(), opts.shadows.into());
    }
    store::write_json(&dir.report_json(), &report).map_err(store_error)?;
    Ok(report)
}

/// `--merge`: every sample (and, with slabs, every slab layer set) must be complete; then the
/// report covering every shard.
fn merge(
    dir: &PrerenderDir,
    input: &ReportInput<'_>,
    opts: &RenderOptions,
    out: &Path,
) -> anyhow::Result<()> {
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
        bail!(
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
        );
    }
    if !layers.is_empty() {
        let labels: Vec<String> = input.slabs.iter().map(|s| s.label()).collect();
        bail!(
            "{}: {}",
            out.display(),
            job::missing_message(
                &format!("slab layers {}", labels.join(",")),
                &layers,
                total,
                shards
            )
        );
    }
    let report = job::write_report(dir, input).map_err(store_error)?;
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
    eprintln!(
        "merged {}: all {} samples complete; rendered by {}; {:.1} s of rendering",
        out.display(),
        report.samples,
        if shard_list.is_empty() {
            "no logged run".to_string()
        } else {
            shard_list.join(", ")
        },
        report.seconds
    );
    Ok(())
}
