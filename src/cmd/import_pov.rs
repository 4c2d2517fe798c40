//! `railview import-pov`: render a POV-Ray scene along a track into a prerender directory
//! (the same layout `railview prerender` writes, so `slabs`, `cull` and `build` work on it).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use prerender::job::{self, Shard};
use prerender::pov::{PovImport, PovOptions, RenderRecord, RenderStats, UpAxis};
use prerender::runlog::{read_runs, RunEvent, RunLog};
use prerender::store::{self, PrerenderDir, PrerenderReport, SampleMeta};
use tracks::{SlabRange, TrackSet};

/// Arguments of `railview import-pov`.
#[derive(clap::Args)]
pub struct Args {
    /// The POV-Ray 3.7 scene (`.pov`), used unchanged.
    pub scene: PathBuf,
    /// Track TOML in railview coordinates (y up; for a y-up scene POV-Ray <x,y,z> = [x,y,-z],
    /// for a z-up scene POV-Ray <x,y,z> = [-x,z,-y]).
    #[arg(long)]
    pub track: PathBuf,
    /// Which track of the file (default: the first).
    #[arg(long)]
    pub track_name: Option<String>,
    /// Cube-map face size in pixels.
    #[arg(long)]
    pub face_size: u32,
    /// Output prerender directory (created; resumable).
    #[arg(long)]
    pub out: PathBuf,
    /// The scene's up axis: `y` or `z`.
    #[arg(long, default_value = "y")]
    pub up: UpAxis,
    /// Anti-aliased colour (2×2 supersampling; 4× the colour render time).
    #[arg(long)]
    pub aa: bool,
    /// Face size of the low-resolution depth pass.
    #[arg(long, default_value_t = 32)]
    pub lowres_face_size: u32,
    /// Slab layers to render, e.g. `0-300,300-700,700-inf` (scene units).
    #[arg(long)]
    pub slabs: Option<String>,
    /// Kill and fail a single POV-Ray render that runs longer than this.
    #[arg(long)]
    pub timeout_secs: Option<f64>,
    /// Render only samples with index % N == K (0 <= K < N). Shards share one output
    /// directory; none of them writes `prerender.json` (the merge does).
    #[arg(long, conflicts_with = "merge")]
    pub shard: Option<String>,
    /// After the shards: render nothing, fail naming every sample (and its shard) that is not
    /// complete, else write `prerender.json` covering all shards.
    #[arg(long)]
    pub merge: bool,
    /// The POV-Ray binary.
    #[arg(long, default_value = "povray")]
    pub povray: PathBuf,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// File_Gamma of the depth passes (default: the scene's assumed_gamma).
    #[arg(long)]
    pub gamma: Option<f64>,
    /// Also write an equirectangular colour preview of this width per sample
    /// (DIR/previews/NNNN.png, POV-Ray's spherical camera).
    #[arg(long)]
    pub preview_width: Option<u32>,
}

fn parse_shard(text: &str) -> anyhow::Result<(usize, usize)> {
    Shard::parse(text)
        .map(|s| s.pair())
        .map_err(|e| anyhow::anyhow!("--shard: {e}"))
}

/// Group of a pass name for the per-sample timing table.
fn pass_group(pass: &str) -> &'static str {
    if pass.starts_with("slab") {
        "slabs"
    } else if pass == "color" {
        "color"
    } else if pass == "preview" {
        "preview"
    } else {
        "depth"
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::face_size("--face-size", args.face_size)?;
    super::face_size("--lowres-face-size", args.lowres_face_size)?;
    let explicit_slabs = args
        .slabs
        .as_deref()
        .map(|s| SlabRange::parse_list(s).map_err(|e| anyhow::anyhow!("--slabs: {e}")))
        .transpose()?;
    let shard = args.shard.as_deref().map(parse_shard).transpose()?;
    let track_text = super::read_text(&args.track)
        .with_context(|| format!("cannot read track file {}", args.track.display()))?;
    let set = TrackSet::parse(&track_text, &args.track.display().to_string())?;
    let track = match &args.track_name {
        Some(name) => set.get(name).with_context(|| {
            format!(
                "{}: no track `{name}` (found: {})",
                args.track.display(),
                set.names().join(", ")
            )
        })?,
        None => set
            .tracks
            .first()
            .with_context(|| format!("{}: no [[track]] in the file", args.track.display()))?,
    };
    let viewpoints = track.viewpoints();

    let dir = PrerenderDir::new(&args.out);
    store::ensure_writable_dir(&args.out).context("cannot use the output directory")?;
    // Without --slabs, a rerun keeps the slab layers an earlier run (or `railview slabs`)
    // rendered at this face size, so the report never forgets them.
    let slabs: Vec<SlabRange> = match explicit_slabs {
        Some(s) => s,
        None => dir
            .read_report()
            .ok()
            .filter(|r| r.face_size == args.face_size)
            .map(|r| r.slabs)
            .unwrap_or_default(),
    };
    // Generated includes, wrappers and POV-Ray's own images: one work directory per shard, so
    // a shard finishing (it deletes its mesh includes) never pulls files from under another.
    let work = match shard {
        Some((k, n)) => args.out.join("pov-work").join(format!("shard-{k}-of-{n}")),
        None => args.out.join("pov-work"),
    };
    let mut opts = PovOptions::new(args.face_size, work);
    opts.lowres_face_size = args.lowres_face_size;
    opts.up = args.up;
    opts.antialias = args.aa;
    opts.povray = args.povray.clone();
    if let Some(t) = args.threads {
        opts.threads = t.max(1);
    }
    if let Some(t) = args.timeout_secs {
        if !(t.is_finite() && t > 0.0) {
            bail!("--timeout-secs must be a positive number of seconds, found {t}");
        }
        opts.timeout = Some(Duration::from_secs_f64(t));
    }
    opts.file_gamma = args.gamma;
    let mut import = PovImport::new(&args.scene, opts)?;
    import.set_progress(|r: &RenderRecord| {
        eprintln!(
            "sample {:>4} {:<18} {:>8.2} s  (parse {:.2} s, radiosity {:.2} s, trace {:.2} s)",
            r.sample,
            r.pass,
            r.stats.wall_seconds,
            r.stats.parse_seconds,
            r.stats.radiosity_seconds,
            r.stats.trace_seconds
        )
    });
    // Every shard writes the same bytes; only when they differ, so a shard starting later
    // never replaces the file under one already running.
    store::write_if_changed(&dir.track_toml(), track_text.as_bytes())?;

    if args.merge {
        let (base, layers) = job::missing_samples(
            &dir,
            &viewpoints,
            args.face_size,
            args.lowres_face_size,
            &slabs,
        );
        let shards = job::logged_shard_count(&dir);
        for (what, missing) in [
            ("base pass".to_string(), &base),
            (format!("slab layers {}", labels(&slabs)), &layers),
        ] {
            if !missing.is_empty() {
                bail!(
                    "{}: {}",
                    args.out.display(),
                    job::missing_message(&what, missing, viewpoints.len(), shards)
                );
            }
        }
        let report = write_report(&args, &import, &dir, &track.name, &viewpoints, &slabs)?;
        eprintln!(
            "merged {}: all {} samples complete; {:.1} s of POV-Ray rendering",
            args.out.display(),
            report.samples,
            report.seconds
        );
        return Ok(());
    }
    let log = Arc::new(RunLog::create(&args.out, "import-pov", shard)?);
    import.set_run_log(log.clone());

    let mine: Vec<_> = viewpoints
        .iter()
        .filter(|vp| shard.is_none_or(|(k, n)| vp.index % n == k))
        .collect();
    let mut resumed = 0usize;
    for (done, vp) in mine.iter().enumerate() {
        eprintln!(
            "viewpoint {} ({}/{}) at {}",
            vp.index,
            done + 1,
            mine.len(),
            vp.position
        );
        let have_base = import.base_done(&dir, vp);
        let have_slabs = slabs.is_empty() || import.slabs_done(&dir, vp, &slabs);
        if have_base && have_slabs {
            resumed += 1;
            eprintln!("  already complete, skipped");
            continue;
        }
        if !have_base {
            import.render_base(vp, &dir)?;
        }
        if !slabs.is_empty() && !import.slabs_done(&dir, vp, &slabs) {
            import.render_slabs(vp, &slabs, &dir)?;
        }
        if let Some(w) = args.preview_width {
            let path = args
                .out
                .join("previews")
                .join(format!("{:04}.png", vp.index));
            import.render_preview(vp, w, &path)?;
        }
    }
    import.remove_mesh_includes()?;
    let seconds = log.end(&[
        ("samples", mine.len().into()),
        ("resumed_samples", resumed.into()),
        ("renders", import.records().len().into()),
    ])?;
    if let Some((k, n)) = shard {
        eprintln!(
            "shard {k}/{n}: {} samples ({} already complete) in {seconds:.1} s (log: {}). Once \
             every shard has finished, `railview import-pov … --merge` checks the track and \
             writes prerender.json.",
            mine.len(),
            resumed,
            log.path().display()
        );
        return Ok(());
    }
    write_report(&args, &import, &dir, &track.name, &viewpoints, &slabs)?;
    eprintln!(
        "wrote {} ({} samples, {} resumed, {:.1} s)",
        args.out.display(),
        mine.len(),
        resumed,
        seconds
    );
    Ok(())
}

fn labels(slabs: &[SlabRange]) -> String {
    slabs
        .iter()
        .map(|s| s.label())
        .collect::<Vec<_>>()
        .join(",")
}

/// `prerender.json` and `prerender.md` of an import, for every complete sample: the
/// import's options as `slabs` re-creates them, and the POV-Ray renders of every run that
/// rendered a complete sample (the latest of each pass), from the run logs.
fn write_report(
    args: &Args,
    import: &PovImport,
    dir: &PrerenderDir,
    track: &str,
    viewpoints: &[tracks::ReferenceViewpoint],
    slabs: &[SlabRange],
) -> anyhow::Result<PrerenderReport> {
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
        eprintln!("run log: {w}");
    }
    // The latest render of every pass of every complete sample.
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
    let records: Vec<RenderRecord> = latest.into_values().collect();
    let mut total = RenderStats::default();
    for r in &records {
        total.add(&r.stats);
    }
    let rays: u64 = records.iter().map(|r| r.pixels).sum();
    let mut per_sample: BTreeMap<usize, serde_json::Map<String, serde_json::Value>> =
        Default::default();
    for r in &records {
        let e = per_sample.entry(r.sample).or_default();
        let key = format!("{}_seconds", pass_group(&r.pass));
        let prev = e.get(&key).and_then(|v| v.as_f64()).unwrap_or(0.0);
        e.insert(key, (prev + r.stats.wall_seconds).into());
    }
    let per_sample: Vec<serde_json::Value> = per_sample
        .into_iter()
        .map(|(i, mut m)| {
            m.insert("sample".into(), i.into());
            serde_json::Value::Object(m)
        })
        .collect();
    let info = import.scene_info();
    let missing: Vec<usize> = viewpoints
        .iter()
        .map(|v| v.index)
        .filter(|i| !complete.iter().any(|m| m.index == *i))
        .collect();
    let extra = serde_json::json!({
        "povray_version": import.povray_version(),
        "up": args.up.name(),
        "antialias": args.aa,
        "povray": args.povray.display().to_string(),
        "threads": args.threads,
        "timeout_secs": args.timeout_secs,
        "gamma": args.gamma,
        "file_gamma": args.gamma.unwrap_or(info.assumed_gamma),
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
        "per_sample": per_sample,
        "render_log": records,
    });
    let seconds = work
        .shards
        .iter()
        .fold(work.layer_seconds, |a, s| a + s.render_seconds);
    let report = PrerenderReport {
        scene: import.scene().display().to_string(),
        renderer: "povray".into(),
        track: track.to_string(),
        samples: viewpoints.len(),
        face_size: args.face_size,
        lowres_face_size: args.lowres_face_size,
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
    let mut md = format!(
        "# POV-Ray import\n\nscene `{}` (up {}), track `{}`, {} samples ({} complete), \
         face {} px, low-res {} px, slabs: {}\n\n{} — {} renders, {:.1} s of rendering \
         (POV-Ray parse {:.1} s, radiosity {:.1} s, trace {:.1} s)\n\n\
         | sample | depth s | colour s | slabs s |\n|---|---|---|---|\n",
        report.scene,
        args.up.name(),
        report.track,
        report.samples,
        complete.len(),
        args.face_size,
        args.lowres_face_size,
        if slabs.is_empty() {
            "none".to_string()
        } else {
            labels(slabs)
        },
        import.povray_version(),
        records.len(),
        total.wall_seconds,
        total.parse_seconds,
        total.radiosity_seconds,
        total.trace_seconds
    );
    for s in report.extra["per_sample"].as_array().into_iter().flatten() {
        let g = |k: &str| s[k].as_f64().unwrap_or(0.0);
        md.push_str(&format!(
            "| {} | {:.2} | {:.2} | {:.2} |\n",
            s["sample"],
            g("depth_seconds"),
            g("color_seconds"),
            g("slabs_seconds")
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
    store::write_atomic(&dir.report_md(), md.as_bytes())?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_syntax() {
        assert_eq!(parse_shard("1/3").unwrap(), (1, 3));
        assert!(parse_shard("3/3").is_err());
        assert!(parse_shard("0/0").is_err());
        assert!(parse_shard("a/2").is_err());
        assert!(parse_shard("2").is_err());
    }
}
