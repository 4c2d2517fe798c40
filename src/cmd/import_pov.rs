//! `railview import-pov`: render a POV-Ray scene along a track into a prerender directory
//! (the same layout `railview prerender` writes, so `slabs`, `cull` and `build` work on it).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use prerender::pov::{PovImport, PovOptions, RenderRecord, UpAxis};
use prerender::store::{self, PrerenderDir, PrerenderReport};
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
    /// Render only samples with index % N == K (0 <= K < N).
    #[arg(long)]
    pub shard: Option<String>,
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
    let (k, n) = text
        .split_once('/')
        .with_context(|| format!("--shard `{text}`: expected K/N"))?;
    let k: usize = k
        .trim()
        .parse()
        .with_context(|| format!("--shard `{text}`: K is not a number"))?;
    let n: usize = n
        .trim()
        .parse()
        .with_context(|| format!("--shard `{text}`: N is not a number"))?;
    if n == 0 || k >= n {
        bail!("--shard `{text}`: needs 0 <= K < N");
    }
    Ok((k, n))
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
    let start = Instant::now();
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
    let mut opts = PovOptions::new(args.face_size, args.out.join("pov-work"));
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
    store::write_atomic(&dir.track_toml(), track_text.as_bytes())?;

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

    let seconds = start.elapsed().as_secs_f64();
    let rays: u64 = import.records().iter().map(|r| r.pixels).sum();
    let mut per_sample: std::collections::BTreeMap<
        usize,
        serde_json::Map<String, serde_json::Value>,
    > = Default::default();
    for r in import.records() {
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
    let total = import.total_stats();
    let info = import.scene_info();
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
        "renders": import.records().len(),
        "resumed_samples": resumed,
        "povray_wall_seconds": total.wall_seconds,
        "parse_seconds": total.parse_seconds,
        "bounding_seconds": total.bounding_seconds,
        "photon_seconds": total.photon_seconds,
        "radiosity_seconds": total.radiosity_seconds,
        "trace_seconds": total.trace_seconds,
        "per_sample": per_sample,
        "render_log": import.records(),
    });
    let report = PrerenderReport {
        scene: import.scene().display().to_string(),
        renderer: "povray".into(),
        track: track.name.clone(),
        samples: viewpoints.len(),
        face_size: args.face_size,
        lowres_face_size: args.lowres_face_size,
        seconds,
        rays_per_second: if seconds > 0.0 {
            rays as f64 / seconds
        } else {
            0.0
        },
        viewpoints: viewpoints.clone(),
        slabs: slabs.clone(),
        shard,
        extra,
    };
    store::write_json(&dir.report_json(), &report)?;
    let mut md = format!(
        "# POV-Ray import\n\nscene `{}` (up {}), track `{}`, {} samples ({} rendered here, {} resumed), \
         face {} px, low-res {} px, slabs: {}\n\n{} — {} renders, {:.1} s wall \
         (POV-Ray parse {:.1} s, radiosity {:.1} s, trace {:.1} s)\n\n\
         | sample | depth s | colour s | slabs s |\n|---|---|---|---|\n",
        report.scene,
        args.up.name(),
        report.track,
        report.samples,
        mine.len() - resumed,
        resumed,
        args.face_size,
        args.lowres_face_size,
        if slabs.is_empty() {
            "none".to_string()
        } else {
            slabs.iter().map(|s| s.label()).collect::<Vec<_>>().join(", ")
        },
        import.povray_version(),
        import.records().len(),
        seconds,
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
    store::write_atomic(&dir.report_md(), md.as_bytes())?;
    eprintln!(
        "wrote {} ({} samples, {:.1} s)",
        args.out.display(),
        mine.len(),
        seconds
    );
    Ok(())
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
