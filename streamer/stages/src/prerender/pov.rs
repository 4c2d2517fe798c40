//! The prerender stage with POV-Ray: a `.pov` scene rendered along a track into the same
//! layout the built-in tracer writes, so that the later stages work on it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use prerender::job;
use prerender::pov::{PovImport, PovOptions, RenderRecord, RenderStats, UpAxis};
use prerender::runlog::{read_runs, RunEvent, RunLog};
use prerender::store::{self, PrerenderDir, PrerenderReport, SampleMeta};
use tracks::{ReferenceViewpoint, SlabRange, TrackSet};

use super::{labels, PrerenderParams, Prerendered};
use crate::error::{input, parameter, Context, Error, Result};
use crate::progress::Reporter;

/// How POV-Ray renders.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PovParams {
    /// The scene's up axis (default: y).
    pub up: Option<UpAxis>,
    /// Colour rays per pixel along each axis (0 or 1: none; 2 is `--aa`; at most
    /// [`prerender::pov::MAX_SUPERSAMPLE`]); `n²` times the colour render time.
    pub supersample: u32,
    /// Kill and fail a single render that runs longer than this many seconds.
    pub timeout_secs: Option<f64>,
    /// The POV-Ray binary (default: `povray`).
    pub povray: Option<PathBuf>,
    /// Render threads (default: all cores).
    pub threads: Option<usize>,
    /// File_Gamma of the depth passes (default: the scene's assumed_gamma).
    pub gamma: Option<f64>,
    /// Also write an equirectangular colour preview of this width per sample
    /// (`DIR/previews/NNNN.png`).
    pub preview_width: Option<u32>,
}

impl PovParams {
    fn up(&self) -> UpAxis {
        self.up.unwrap_or(UpAxis::Y)
    }

    fn povray(&self) -> PathBuf {
        self.povray
            .clone()
            .unwrap_or_else(|| PathBuf::from("povray"))
    }

    /// The start of the command line, up to the options every renderer shares.
    pub(super) fn command_line(&self, params: &PrerenderParams) -> Vec<String> {
        let mut v = vec![
            "import-pov".into(),
            params.scene.clone(),
            "--track".into(),
            params.track.clone(),
        ];
        if let Some(name) = &params.track_name {
            v.extend(["--track-name".into(), name.clone()]);
        }
        if let Some(up) = self.up {
            v.extend(["--up".into(), up.name().into()]);
        }
        if self.supersample > 1 {
            v.extend(["--supersample".into(), self.supersample.to_string()]);
        }
        if let Some(b) = &self.povray {
            v.extend(["--povray".into(), b.display().to_string()]);
        }
        if let Some(t) = self.timeout_secs {
            v.extend(["--timeout-secs".into(), t.to_string()]);
        }
        if let Some(t) = self.threads {
            v.extend(["--threads".into(), t.to_string()]);
        }
        if let Some(g) = self.gamma {
            v.extend(["--gamma".into(), g.to_string()]);
        }
        if let Some(w) = self.preview_width {
            v.extend(["--preview-width".into(), w.to_string()]);
        }
        v
    }
}

/// Group of a pass name for the per-sample timing table.
fn pass_group(pass: &str) -> &'static str {
    if pass.starts_with("slab") {
        "slabs"
    } else if pass == "color" {
        "color"
    } else if pass == "radiosity" {
        "radiosity"
    } else if pass == "sky" {
        "sky"
    } else if pass == "preview" {
        "preview"
    } else {
        "depth"
    }
}

/// The track file's tracks: the one named (`all`: every one, a network), or the first; the
/// name for the report, the viewpoints and the file's text.
fn read_track(params: &PrerenderParams) -> Result<(String, Vec<ReferenceViewpoint>, String)> {
    let path = Path::new(&params.track);
    let text = crate::scene::read_text(path)
        .with_context(|| format!("cannot read track file {}", path.display()))?;
    let source = path.display().to_string();
    let set = TrackSet::parse(&text, &source)?;
    let (name, tracks) =
        crate::network::choose_tracks(&set, params.track_name.as_deref(), &source, true)?;
    let (_, viewpoints) = crate::network::network_of_tracks(tracks)?;
    Ok((name, viewpoints, text))
}

/// The import with its options.
fn import(params: &PrerenderParams, pov: &PovParams, progress: &Reporter) -> Result<PovImport> {
    let most = prerender::pov::MAX_SUPERSAMPLE;
    if pov.supersample > most {
        return Err(parameter!(
            "--supersample {}: POV-Ray imports render colour at most {most}×{most} rays a pixel",
            pov.supersample
        ));
    }
    // Generated includes, wrappers and POV-Ray's own images: one work directory per shard, so
    // a shard finishing (it deletes its mesh includes) never pulls files from under another.
    let work = match params.shard {
        Some(s) => params
            .out
            .join("pov-work")
            .join(format!("shard-{}-of-{}", s.index, s.count)),
        None => params.out.join("pov-work"),
    };
    let mut opts = PovOptions::new(params.face_size, work);
    opts.lowres_face_size = params.lowres();
    opts.up = pov.up();
    opts.supersample = pov.supersample.max(1);
    opts.povray = pov.povray();
    if let Some(t) = pov.threads {
        opts.threads = t.max(1);
    }
    if let Some(t) = pov.timeout_secs {
        if !(t.is_finite() && t > 0.0) {
            return Err(parameter!(
                "--timeout-secs must be a positive number of seconds, found {t}"
            ));
        }
        opts.timeout = Some(Duration::from_secs_f64(t));
    }
    opts.file_gamma = pov.gamma;
    let mut import = PovImport::new(&params.scene, opts)?;
    let p = progress.clone();
    import.set_progress(move |r: &RenderRecord| {
        p.message(&format!(
            "sample {:>4} {:<18} {:>8.2} s  (parse {:.2} s, radiosity {:.2} s, trace {:.2} s)",
            r.sample,
            r.pass,
            r.stats.wall_seconds,
            r.stats.parse_seconds,
            r.stats.radiosity_seconds,
            r.stats.trace_seconds
        ))
    });
    Ok(import)
}

/// The run with POV-Ray.
pub(super) fn run(
    params: &PrerenderParams,
    pov: &PovParams,
    progress: &Reporter,
) -> Result<Prerendered> {
    let (track_name, viewpoints, track_text) = read_track(params)?;
    let out = &params.out;
    let dir = PrerenderDir::new(out);
    store::ensure_writable_dir(out).context("cannot use the output directory")?;
    // Without slabs asked for, a rerun keeps the slab layers an earlier run (or the slabs
    // stage) rendered at this face size, so the report never forgets them.
    let slabs: Vec<SlabRange> = match &params.slabs {
        Some(s) => s.clone(),
        None => dir
            .read_report()
            .ok()
            .filter(|r| r.face_size == params.face_size)
            .map(|r| r.slabs)
            .unwrap_or_default(),
    };
    let mut import = import(params, pov, progress)?;
    // Every shard writes the same bytes; only when they differ, so a shard starting later
    // never replaces the file under one already running.
    store::write_if_changed(&dir.track_toml(), track_text.as_bytes())?;
    let facts = Facts {
        params,
        pov,
        dir: &dir,
        track: &track_name,
        viewpoints: &viewpoints,
        slabs: &slabs,
    };
    if params.merge {
        return merge(&facts, &mut import, progress);
    }
    let shard = params.shard.map(|s| s.pair());
    let log = Arc::new(RunLog::create(out, "import-pov", shard)?);
    import.set_run_log(log.clone());
    let mine: Vec<_> = viewpoints
        .iter()
        .filter(|vp| shard.is_none_or(|(k, n)| vp.index % n == k))
        .collect();
    // Radiosity sampled once for the whole track (every shard gathers the same file), so
    // that every colour render is lit alike and reproducibly.
    if import.prepare_radiosity(&dir, &viewpoints)? {
        progress.message("radiosity: samples gathered once for the track, shared by every render");
    }
    let mut resumed = 0usize;
    // Seconds of the samples rendered so far, for an estimate of the rest from the first on.
    let (mut spent, mut rendered) = (0.0f64, 0usize);
    for (done, vp) in mine.iter().enumerate() {
        progress.message(&format!(
            "viewpoint {} ({}/{}) at {}",
            vp.index,
            done + 1,
            mine.len(),
            vp.position
        ));
        let t = std::time::Instant::now();
        if render_sample(&facts, &mut import, vp)? {
            resumed += 1;
            progress.message("  already complete, skipped");
            continue;
        }
        spent += t.elapsed().as_secs_f64();
        rendered += 1;
        let left = mine.len() - done - 1;
        if left > 0 {
            progress.message(&format!(
                "  {:.1} s; about {:.0} s left for {left} more (at {:.1} s a viewpoint so far)",
                t.elapsed().as_secs_f64(),
                spent / rendered as f64 * left as f64,
                spent / rendered as f64
            ));
        }
    }
    import.remove_mesh_includes()?;
    let seconds = log.end(&[
        ("samples", mine.len().into()),
        ("resumed_samples", resumed.into()),
        ("renders", import.records().len().into()),
    ])?;
    let mut done = Prerendered {
        samples: mine.len(),
        rendered: mine.len() - resumed,
        skipped: resumed,
        report: None,
    };
    if let Some((k, n)) = shard {
        progress.message(&format!(
            "shard {k}/{n}: {} samples ({} already complete) in {seconds:.1} s (log: {}). Once \
             every shard has finished, `railview import-pov … --merge` checks the track and \
             writes prerender.json.",
            mine.len(),
            resumed,
            log.path().display()
        ));
        return Ok(done);
    }
    sky_alone(&facts, &mut import, progress)?;
    done.report = Some(write_report(&facts, &import, progress)?);
    progress.message(&format!(
        "wrote {} ({} samples, {} resumed, {:.1} s)",
        out.display(),
        mine.len(),
        resumed,
        seconds
    ));
    Ok(done)
}

/// Render what one sample lacks; whether it was complete already.
fn render_sample(facts: &Facts, import: &mut PovImport, vp: &ReferenceViewpoint) -> Result<bool> {
    let (dir, slabs) = (facts.dir, facts.slabs);
    let have_base = import.base_done(dir, vp);
    let have_slabs = slabs.is_empty() || import.slabs_done(dir, vp, slabs);
    if have_base && have_slabs {
        return Ok(true);
    }
    if !have_base {
        import.render_base(vp, dir)?;
    }
    if !slabs.is_empty() && !import.slabs_done(dir, vp, slabs) {
        import.render_slabs(vp, slabs, dir)?;
    }
    if let Some(w) = facts.pov.preview_width {
        let path = facts
            .params
            .out
            .join("previews")
            .join(format!("{:04}.png", vp.index));
        import.render_preview(vp, w, &path)?;
    }
    Ok(false)
}

/// The sky rendered alone (`sky.png`, the background behind every occluder), kept where it
/// matches the panoramas' own sky ([`prerender::sky::SKY_MATCH`]); removed where they see
/// no sky or it does not match, so that the sky is assembled from them instead.
fn sky_alone(facts: &Facts, import: &mut PovImport, progress: &Reporter) -> Result<()> {
    let dir = facts.dir;
    let path = dir.sky_png();
    let n = facts.params.face_size;
    let mut acc = prerender::sky::SkyAccumulator::new(n);
    let mut far = 0.0f64;
    let mut done = Vec::new();
    for vp in facts
        .viewpoints
        .iter()
        .filter(|vp| import.base_done(dir, vp))
    {
        let colour = store::read_rgb_png(&dir.color_png(vp.index))?;
        let depth = store::read_depth_exr(&dir.depth_exr(vp.index))?;
        acc.add(&colour, &depth)
            .map_err(|e| input!("{}: {e}", dir.color_png(vp.index).display()))?;
        far = depth
            .as_slice()
            .iter()
            .filter(|d| d.is_finite())
            .fold(far, |a, &d| a.max(d as f64));
        done.push(vp.position);
    }
    std::fs::remove_file(&path).ok();
    let (Some(first), true) = (done.first(), acc.covered() > 0) else {
        return Ok(());
    };
    let reach = done.iter().map(|p| p.distance(*first)).fold(0.0, f64::max);
    let sky = import.render_sky(*first, 2.0 * far.max(1.0) + reach)?;
    match prerender::sky::difference(&sky, &acc) {
        Some(d) if d <= prerender::sky::SKY_MATCH => {
            store::write_atomic(&path, &store::encode_rgb_png(&sky))?;
            progress.message(&format!(
                "sky: rendered alone, {d:.2} levels from the panoramas' own where they see it"
            ));
        }
        d => progress.message(&format!(
            "sky: rendered alone it differs from the panoramas' own sky by {:.1} levels (more \
             than {}): assembled from the panoramas instead",
            d.unwrap_or(f64::NAN),
            prerender::sky::SKY_MATCH
        )),
    }
    Ok(())
}

/// What the report of an import is made from.
struct Facts<'a> {
    params: &'a PrerenderParams,
    pov: &'a PovParams,
    dir: &'a PrerenderDir,
    track: &'a str,
    viewpoints: &'a [ReferenceViewpoint],
    slabs: &'a [SlabRange],
}

/// After the shards: every sample complete, then the report.
fn merge(facts: &Facts, import: &mut PovImport, progress: &Reporter) -> Result<Prerendered> {
    let p = facts.params;
    let (base, layers) = job::missing_samples(
        facts.dir,
        facts.viewpoints,
        p.face_size,
        p.lowres(),
        facts.slabs,
    );
    let shards = job::logged_shard_count(facts.dir);
    for (what, missing) in [
        ("base pass".to_string(), &base),
        (format!("slab layers {}", labels(facts.slabs)), &layers),
    ] {
        if !missing.is_empty() {
            return Err(Error::Input(format!(
                "{}: {}",
                p.out.display(),
                job::missing_message(&what, missing, facts.viewpoints.len(), shards)
            )));
        }
    }
    sky_alone(facts, import, progress)?;
    let report = write_report(facts, import, progress)?;
    progress.message(&format!(
        "merged {}: all {} samples complete; {:.1} s of POV-Ray rendering",
        p.out.display(),
        report.samples,
        report.seconds
    ));
    Ok(Prerendered {
        samples: facts.viewpoints.len(),
        rendered: 0,
        skipped: 0,
        report: Some(report),
    })
}

/// The latest render of every pass of every complete sample, from the run logs.
fn latest_renders(dir: &PrerenderDir, complete: &[SampleMeta]) -> Result<Vec<RenderRecord>> {
    let (runs, _) = read_runs(dir.root())?;
    let mut latest: BTreeMap<(usize, String), RenderRecord> = BTreeMap::new();
    for run in runs.iter().filter(|r| r.start.stage == "import-pov") {
        for e in &run.events {
            if let RunEvent::Povray(r) = e {
                if complete.iter().any(|m| m.index == r.sample) {
                    latest.insert((r.sample, r.pass.clone()), r.clone());
                }
            }
        }
    }
    Ok(latest.into_values().collect())
}

/// How neighbouring complete samples agree on the surfaces both see
/// ([`prerender::agreement`]): per pair, and the mean over all points.
fn neighbour_agreement(dir: &PrerenderDir, complete: &[SampleMeta]) -> Result<serde_json::Value> {
    let load = |m: &SampleMeta| -> Result<_> {
        let colour = store::read_rgb_png(&dir.color_png(m.index))?;
        let depth = store::read_depth_exr(&dir.depth_exr(m.index))?;
        Ok((m.position, colour, depth))
    };
    let mut pairs = Vec::new();
    let (mut pixels, mut sum) = (0u64, 0.0);
    let mut prev = None;
    for m in complete {
        let cur = load(m)?;
        if let Some((i, (pa, ca, da))) = &prev {
            let pano = |p, c, d| prerender::agreement::Panorama {
                position: p,
                colour: c,
                depth: d,
            };
            let a =
                prerender::agreement::agreement(&pano(*pa, ca, da), &pano(cur.0, &cur.1, &cur.2));
            pixels += a.pixels;
            sum += a.mean * a.pixels as f64;
            pairs.push(serde_json::json!({"from": i, "to": m.index, "agreement": a}));
        }
        prev = Some((m.index, cur));
    }
    Ok(serde_json::json!({
        "pairs": pairs,
        "pixels": pixels,
        "mean": (pixels > 0).then(|| sum / pixels as f64),
    }))
}

/// Seconds per pass group of every sample, for the timing table.
fn per_sample(records: &[RenderRecord]) -> Vec<serde_json::Value> {
    let mut per_sample: BTreeMap<usize, serde_json::Map<String, serde_json::Value>> =
        Default::default();
    for r in records {
        let e = per_sample.entry(r.sample).or_default();
        let key = format!("{}_seconds", pass_group(&r.pass));
        let prev = e.get(&key).and_then(|v| v.as_f64()).unwrap_or(0.0);
        e.insert(key, (prev + r.stats.wall_seconds).into());
    }
    per_sample
        .into_iter()
        .map(|(i, mut m)| {
            m.insert("sample".into(), i.into());
            serde_json::Value::Object(m)
        })
        .collect()
}

/// `prerender.json` and `prerender.md` of an import, for every complete sample: the
/// import's options as the slabs stage re-creates them, and the POV-Ray renders of every run
/// that rendered a complete sample (the latest of each pass), from the run logs.
fn write_report(facts: &Facts, import: &PovImport, progress: &Reporter) -> Result<PrerenderReport> {
    let (dir, viewpoints, slabs) = (facts.dir, facts.viewpoints, facts.slabs);
    let (p, pov) = (facts.params, facts.pov);
    let complete: Vec<SampleMeta> = viewpoints
        .iter()
        .filter(|vp| import.base_done(dir, vp))
        .filter_map(|vp| dir.sample_meta(vp.index))
        .collect();
    let layers: Vec<(usize, Vec<SlabRange>)> = viewpoints
        .iter()
        .filter_map(|v| dir.layers_meta(v.index).map(|m| (v.index, m.slabs)))
        .filter(|(_, s)| !slabs.is_empty() && s == slabs)
        .collect();
    let work = job::logged_work(dir, &complete, &layers)?;
    for w in &work.warnings {
        progress.message(&format!("run log: {w}"));
    }
    let records = latest_renders(dir, &complete)?;
    let mut total = RenderStats::default();
    for r in &records {
        total.add(&r.stats);
    }
    let rays: u64 = records.iter().map(|r| r.pixels).sum();
    let info = import.scene_info();
    let missing: Vec<usize> = viewpoints
        .iter()
        .map(|v| v.index)
        .filter(|i| !complete.iter().any(|m| m.index == *i))
        .collect();
    let extra = serde_json::json!({
        "povray_version": import.povray_version(),
        "up": pov.up().name(),
        "antialias": pov.supersample > 1,
        "supersample": pov.supersample.max(1),
        "povray": pov.povray().display().to_string(),
        "threads": pov.threads,
        "timeout_secs": pov.timeout_secs,
        "gamma": pov.gamma,
        "file_gamma": pov.gamma.unwrap_or(info.assumed_gamma),
        "scene_radiosity": info.radiosity,
        "complete_samples": complete.len(),
        "missing_samples": missing,
        "samples_with_layers": layers.len(),
        "samples_without_run_log": work.unlogged,
        "renders": records.len(),
        "povray_wall_seconds": total.wall_seconds,
        "parse_seconds": total.parse_seconds,
        "bounding_seconds": total.bounding_seconds,
        "photon_seconds": total.photon_seconds,
        "radiosity_seconds": total.radiosity_seconds,
        "trace_seconds": total.trace_seconds,
        "per_sample": per_sample(&records),
        "radiosity_shared": import.radiosity().is_some(),
        "agreement": neighbour_agreement(dir, &complete)?,
        "render_log": records,
    });
    let seconds = work
        .shards
        .iter()
        .fold(work.layer_seconds, |a, s| a + s.render_seconds);
    let report = PrerenderReport {
        scene: import.scene().display().to_string(),
        renderer: "povray".into(),
        track: facts.track.to_string(),
        samples: viewpoints.len(),
        face_size: p.face_size,
        lowres_face_size: p.lowres(),
        seconds,
        rays_per_second: if total.wall_seconds > 0.0 {
            rays as f64 / total.wall_seconds
        } else {
            0.0
        },
        viewpoints: viewpoints.to_vec(),
        slabs: slabs.to_vec(),
        shard: None,
        shards: work.shards.clone(),
        extra,
    };
    store::write_json(&dir.report_json(), &report)?;
    let md = markdown(
        facts,
        import,
        &report,
        &total,
        complete.len(),
        records.len(),
        &work,
    );
    store::write_atomic(&dir.report_md(), md.as_bytes())?;
    Ok(report)
}

/// `prerender.md` of an import.
fn markdown(
    facts: &Facts,
    import: &PovImport,
    report: &PrerenderReport,
    total: &RenderStats,
    complete: usize,
    renders: usize,
    work: &job::LoggedWork,
) -> String {
    let (p, slabs) = (facts.params, facts.slabs);
    let mut md = format!(
        "# POV-Ray import\n\nscene `{}` (up {}), track `{}`, {} samples ({} complete), \
         face {} px, low-res {} px, slabs: {}\n\n{} — {} renders, {:.1} s of rendering \
         (POV-Ray parse {:.1} s, radiosity {:.1} s, trace {:.1} s)\n\n\
         | sample | depth s | colour s | slabs s | radiosity s |\n|---|---|---|---|---|\n",
        report.scene,
        facts.pov.up().name(),
        report.track,
        report.samples,
        complete,
        p.face_size,
        p.lowres(),
        if slabs.is_empty() {
            "none".to_string()
        } else {
            labels(slabs)
        },
        import.povray_version(),
        renders,
        total.wall_seconds,
        total.parse_seconds,
        total.radiosity_seconds,
        total.trace_seconds
    );
    for s in report.extra["per_sample"].as_array().into_iter().flatten() {
        let g = |k: &str| s[k].as_f64().unwrap_or(0.0);
        md.push_str(&format!(
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} |\n",
            s["sample"],
            g("depth_seconds"),
            g("color_seconds"),
            g("slabs_seconds"),
            g("radiosity_seconds")
        ));
    }
    let a = &report.extra["agreement"];
    if let Some(mean) = a["mean"].as_f64() {
        md.push_str(&format!(
            "\nNeighbouring references on the surfaces both see: colour differs by {mean:.2} \
             levels of 255 on average over {} points ({}; radiosity {}).\n",
            a["pixels"],
            a["pairs"].as_array().map_or(0, |p| p.len()),
            match (
                report.extra["scene_radiosity"].as_bool(),
                report.extra["radiosity_shared"].as_bool()
            ) {
                (Some(true), Some(true)) => "sampled once for the track",
                (Some(true), _) => "sampled in every render",
                _ => "none",
            }
        ));
    }
    if !work.shards.is_empty() {
        md.push_str("\n| shard | samples | render s | hosts |\n|---|---|---|---|\n");
        for s in &work.shards {
            md.push_str(&format!(
                "| {} | {} | {:.2} | {} |\n",
                s.shard
                    .map_or("none (whole track)".to_string(), |(k, n)| format!(
                        "{k}/{n}"
                    )),
                s.samples.len(),
                s.render_seconds,
                s.hosts.join(", ")
            ));
        }
    }
    md
}
