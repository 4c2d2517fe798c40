//! Rendering a track into a prerender directory (layout in [`crate::store`]).
//!
//! - [`write_sample`]: one viewpoint's base pass (`color.png`, `depth.exr`,
//!   `lowres_depth.exr`, then `sample.json` as the completion marker).
//! - [`write_layers`]: one viewpoint's slab layers (`slab_K/*`, then `layers.json`).
//! - [`render_track`] / [`write_slab_layers`]: loops over viewpoints with resume (a viewpoint
//!   whose marker exists and matches the options is skipped); each rendered sample's time goes
//!   to the run log ([`crate::runlog`]), not into the directory's content.
//! - [`write_report`]: `prerender.json` + `prerender.md` covering every complete sample found
//!   in the directory, whoever rendered it, with the shards and times from the run logs.
//!
//! Sharding: shard `K/N` renders the viewpoints with `index % N == K`. Shards write into one
//! shared directory and touch only their own samples, their own run log and the track copy
//! (same bytes from every shard, written only when it differs). The report is written by the
//! merge alone (`railview prerender --merge`, or any run without `--shard`), which reads
//! what every shard left: [`missing_samples`] names what is not there yet.

use tracks::{ReferenceViewpoint, SlabRange};

use crate::render::{render_cube, render_depth_lowres, render_slabs, RenderOptions};
use crate::runlog::{read_runs, LayersTiming, RunEvent, RunLog, SampleTiming};
use crate::scene::Scene;
use crate::store::{
    self, encode_rgb_png, encode_rgba_png, write_atomic, write_depth_exr, write_json, LayersMeta,
    PrerenderDir, PrerenderReport, SampleMeta, ShardSummary, StoreError,
};
use glam::DVec3;
use std::time::Instant;

/// `K/N`: this run covers viewpoints with `index % N == K`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

/// Largest shard count accepted (more shards than this is a typo, not a cluster).
pub const MAX_SHARDS: usize = 1 << 20;

impl Shard {
    /// Parse `K/N` with `0 <= K < N <= MAX_SHARDS`.
    pub fn parse(text: &str) -> Result<Shard, String> {
        let (k, n) = text
            .split_once('/')
            .ok_or_else(|| format!("shard `{text}`: expected K/N, e.g. 0/4"))?;
        let k: usize = k
            .trim()
            .parse()
            .map_err(|_| format!("shard `{text}`: K is not a number"))?;
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| format!("shard `{text}`: N is not a number"))?;
        if n == 0 || k >= n {
            return Err(format!("shard `{text}`: needs 0 <= K < N"));
        }
        if n > MAX_SHARDS {
            return Err(format!("shard `{text}`: N is limited to {MAX_SHARDS}"));
        }
        Ok(Shard { index: k, count: n })
    }

    pub fn covers(&self, viewpoint_index: usize) -> bool {
        viewpoint_index % self.count == self.index
    }

    pub fn pair(&self) -> (usize, usize) {
        (self.index, self.count)
    }
}

/// What one run did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunStats {
    pub rendered: usize,
    pub skipped: usize,
    pub primary_rays: u64,
    pub render_seconds: f64,
}

fn same_position(a: DVec3, b: DVec3) -> bool {
    a.distance(b) <= 1e-9 * (1.0 + a.length())
}

/// Whether the sample's marker exists and matches these options.
pub fn sample_is_complete(
    dir: &PrerenderDir,
    vp: &ReferenceViewpoint,
    face_size: u32,
    lowres_face_size: u32,
) -> bool {
    dir.sample_meta(vp.index).is_some_and(|m| {
        m.face_size == face_size
            && m.lowres_face_size == lowres_face_size
            && same_position(m.position, vp.position)
    })
}

/// Viewpoints (indices) of `viewpoints` whose base pass is not complete with these options,
/// and, when `slabs` is not empty, those whose slab layers are not exactly `slabs`.
pub fn missing_samples(
    dir: &PrerenderDir,
    viewpoints: &[ReferenceViewpoint],
    face_size: u32,
    lowres_face_size: u32,
    slabs: &[SlabRange],
) -> (Vec<usize>, Vec<usize>) {
    let base = viewpoints
        .iter()
        .filter(|v| !sample_is_complete(dir, v, face_size, lowres_face_size))
        .map(|v| v.index)
        .collect();
    let layers = if slabs.is_empty() {
        Vec::new()
    } else {
        viewpoints
            .iter()
            .filter(|v| dir.layers_meta(v.index).is_none_or(|m| m.slabs != slabs))
            .map(|v| v.index)
            .collect()
    };
    (base, layers)
}

/// Render and write one viewpoint's base pass; the marker is written last. Returns the
/// marker and the render time (which belongs in the run log, not in the marker).
pub fn write_sample(
    dir: &PrerenderDir,
    scene: &Scene,
    vp: &ReferenceViewpoint,
    opts: RenderOptions,
    lowres_face_size: u32,
) -> Result<(SampleMeta, f64), StoreError> {
    // A stale marker must not vouch for files about to be replaced.
    remove_if_exists(&dir.sample_json(vp.index))?;
    // A killed earlier run of this shard may have left temporary files here.
    store::remove_temporaries(&dir.sample_dir(vp.index))?;
    let t = Instant::now();
    let cube = render_cube(scene, vp.position, opts);
    let low = render_depth_lowres(scene, vp.position, lowres_face_size);
    let seconds = t.elapsed().as_secs_f64();
    write_atomic(&dir.color_png(vp.index), &encode_rgb_png(&cube.color))?;
    write_depth_exr(&dir.depth_exr(vp.index), &cube.depth)?;
    write_depth_exr(&dir.lowres_depth_exr(vp.index), &low)?;
    let meta = SampleMeta {
        index: vp.index,
        s: vp.s,
        position: vp.position,
        face_size: opts.face_size,
        lowres_face_size,
        primary_rays: cube.primary_rays + 6 * (lowres_face_size as u64).pow(2),
    };
    write_json(&dir.sample_json(vp.index), &meta)?;
    Ok((meta, seconds))
}

/// Render and write one viewpoint's slab layers; `layers.json` is written last. Returns the
/// marker and the render time.
pub fn write_layers(
    dir: &PrerenderDir,
    scene: &Scene,
    vp: &ReferenceViewpoint,
    slabs: &[SlabRange],
    opts: RenderOptions,
) -> Result<(LayersMeta, f64), StoreError> {
    remove_if_exists(&dir.layers_json(vp.index))?;
    store::remove_temporaries(&dir.sample_dir(vp.index))?;
    for k in 0..slabs.len() {
        let slab_dir = dir.slab_color_png(vp.index, k);
        if let Some(d) = slab_dir.parent() {
            store::remove_temporaries(d)?;
        }
    }
    let t = Instant::now();
    let layers = render_slabs(scene, vp.position, slabs, opts);
    let seconds = t.elapsed().as_secs_f64();
    for (k, l) in layers.iter().enumerate() {
        write_atomic(&dir.slab_color_png(vp.index, k), &encode_rgba_png(&l.color))?;
        write_depth_exr(&dir.slab_depth_exr(vp.index, k), &l.depth)?;
    }
    let meta = LayersMeta {
        slabs: slabs.to_vec(),
    };
    write_json(&dir.layers_json(vp.index), &meta)?;
    Ok((meta, seconds))
}

fn remove_if_exists(path: &std::path::Path) -> Result<(), StoreError> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(error) => Err(StoreError::Io {
            path: path.to_path_buf(),
            error,
        }),
    }
}

/// Base passes for `viewpoints` (those this shard covers), skipping complete ones. Each
/// rendered sample's time goes to `log`. `on_done(index, skipped)` is called after each
/// covered viewpoint.
#[allow(clippy::too_many_arguments)]
pub fn render_track(
    dir: &PrerenderDir,
    scene: &Scene,
    viewpoints: &[ReferenceViewpoint],
    opts: RenderOptions,
    lowres_face_size: u32,
    shard: Option<Shard>,
    log: Option<&RunLog>,
    on_done: &dyn Fn(usize, bool),
) -> Result<RunStats, StoreError> {
    let mut stats = RunStats::default();
    for vp in viewpoints
        .iter()
        .filter(|v| shard.is_none_or(|s| s.covers(v.index)))
    {
        if sample_is_complete(dir, vp, opts.face_size, lowres_face_size) {
            stats.skipped += 1;
            on_done(vp.index, true);
            continue;
        }
        let (meta, seconds) = write_sample(dir, scene, vp, opts, lowres_face_size)?;
        if let Some(log) = log {
            log.log(&RunEvent::Sample(SampleTiming {
                index: vp.index,
                face_size: meta.face_size,
                lowres_face_size: meta.lowres_face_size,
                seconds,
                primary_rays: meta.primary_rays,
            }))?;
        }
        stats.rendered += 1;
        stats.primary_rays += meta.primary_rays;
        stats.render_seconds += seconds;
        on_done(vp.index, false);
    }
    Ok(stats)
}

/// Slab layers for every viewpoint in `viewpoints`, skipping those whose `layers.json` already
/// lists exactly `slabs`. The caller picks the viewpoints (e.g. one shard's).
pub fn write_slab_layers(
    dir: &PrerenderDir,
    scene: &Scene,
    viewpoints: &[ReferenceViewpoint],
    slabs: &[SlabRange],
    opts: RenderOptions,
) -> Result<RunStats, StoreError> {
    write_slab_layers_with(dir, scene, viewpoints, slabs, opts, None, &|_, _| {})
}

/// [`write_slab_layers`] with a run log for the times and a progress callback
/// `on_done(index, skipped)`.
pub fn write_slab_layers_with(
    dir: &PrerenderDir,
    scene: &Scene,
    viewpoints: &[ReferenceViewpoint],
    slabs: &[SlabRange],
    opts: RenderOptions,
    log: Option<&RunLog>,
    on_done: &dyn Fn(usize, bool),
) -> Result<RunStats, StoreError> {
    let mut stats = RunStats::default();
    for vp in viewpoints {
        if dir
            .layers_meta(vp.index)
            .is_some_and(|m| m.slabs.as_slice() == slabs)
        {
            stats.skipped += 1;
            on_done(vp.index, true);
            continue;
        }
        let (_, seconds) = write_layers(dir, scene, vp, slabs, opts)?;
        if let Some(log) = log {
            log.log(&RunEvent::Layers(LayersTiming {
                index: vp.index,
                slabs: slabs.to_vec(),
                seconds,
            }))?;
        }
        stats.rendered += 1;
        stats.primary_rays += 6 * (opts.face_size as u64).pow(2);
        stats.render_seconds += seconds;
        on_done(vp.index, false);
    }
    Ok(stats)
}

/// What the report describes besides the samples found on disk.
pub struct ReportInput<'a> {
    pub scene: &'a str,
    /// `builtin` or `povray`.
    pub renderer: &'a str,
    pub track: &'a str,
    pub viewpoints: &'a [ReferenceViewpoint],
    pub face_size: u32,
    pub lowres_face_size: u32,
    pub slabs: &'a [SlabRange],
}

/// What the run logs say about the complete samples of a directory.
#[derive(Clone, Debug, Default)]
pub struct LoggedWork {
    /// Per shard (runs without `--shard` under `None`), sorted by shard.
    pub shards: Vec<ShardSummary>,
    /// Complete samples no run log mentions.
    pub unlogged: Vec<usize>,
    /// Slab-layer render time of the complete layers, summed.
    pub layer_seconds: f64,
    /// What could not be read (cut lines of killed runs and the like).
    pub warnings: Vec<String>,
}

/// The run (its shard and host) that last logged a sample, and the timing it logged.
type Attributed<'a> = (Option<(usize, usize)>, &'a str, &'a SampleTiming);

/// Attribute every complete sample in `complete` (index, face size, low-res face size) to the
/// last run that logged rendering it with those sizes, and sum the times per shard. Runs of
/// every stage count (`prerender`, `import-pov`, `slabs` for layers).
pub fn logged_work(
    dir: &PrerenderDir,
    complete: &[SampleMeta],
    layers: &[(usize, Vec<SlabRange>)],
) -> Result<LoggedWork, StoreError> {
    use std::collections::{BTreeMap, BTreeSet};
    let (runs, warnings) = read_runs(dir.root())?;
    // Looked up once per logged event: sets, not scans (a city logs 10⁵ samples).
    let complete_keys: BTreeSet<(usize, u32, u32)> = complete
        .iter()
        .map(|m| (m.index, m.face_size, m.lowres_face_size))
        .collect();
    let mut layers_of: BTreeMap<usize, Vec<&Vec<SlabRange>>> = BTreeMap::new();
    for (i, s) in layers {
        layers_of.entry(*i).or_default().push(s);
    }
    // Latest timing per sample: runs are oldest first, events in order, so later ones win.
    let mut base: BTreeMap<usize, Attributed<'_>> = BTreeMap::new();
    let mut layer_time: BTreeMap<usize, f64> = BTreeMap::new();
    for run in &runs {
        for e in &run.events {
            match e {
                RunEvent::Sample(t)
                    if complete_keys.contains(&(t.index, t.face_size, t.lowres_face_size)) =>
                {
                    base.insert(t.index, (run.start.shard, run.start.host.as_str(), t));
                }
                RunEvent::Layers(t)
                    if layers_of
                        .get(&t.index)
                        .is_some_and(|l| l.iter().any(|s| **s == t.slabs)) =>
                {
                    layer_time.insert(t.index, t.seconds);
                }
                _ => {}
            }
        }
    }
    let mut shards: BTreeMap<Option<(usize, usize)>, ShardSummary> = BTreeMap::new();
    let mut unlogged = Vec::new();
    for m in complete {
        match base.get(&m.index) {
            Some((shard, host, t)) => {
                let s = shards.entry(*shard).or_insert_with(|| ShardSummary {
                    shard: *shard,
                    samples: Vec::new(),
                    render_seconds: 0.0,
                    primary_rays: 0,
                    hosts: Vec::new(),
                });
                s.samples.push(m.index);
                s.render_seconds += t.seconds;
                s.primary_rays += t.primary_rays;
                if !s.hosts.iter().any(|h| h == host) {
                    s.hosts.push(host.to_string());
                }
            }
            None => unlogged.push(m.index),
        }
    }
    let mut shards: Vec<ShardSummary> = shards.into_values().collect();
    for s in &mut shards {
        s.samples.sort_unstable();
        s.hosts.sort();
    }
    Ok(LoggedWork {
        shards,
        unlogged,
        layer_seconds: layer_time.values().fold(0.0, |a, b| a + b),
        warnings,
    })
}

/// The shard count of the latest sharded prerender run logged in `dir`, if any: what the
/// merge names missing samples by.
pub fn logged_shard_count(dir: &PrerenderDir) -> Option<usize> {
    let (runs, _) = read_runs(dir.root()).ok()?;
    runs.iter()
        .rev()
        .find_map(|r| r.start.shard.map(|(_, n)| n))
}

/// Write `prerender.json` and `prerender.md` for every complete sample in the directory.
/// Times, rays per second and the per-shard summary come from the run logs, so they are the
/// same whichever run writes the report (a shard never does; the merge or an unsharded run).
pub fn write_report(
    dir: &PrerenderDir,
    input: &ReportInput<'_>,
) -> Result<PrerenderReport, StoreError> {
    let metas: Vec<SampleMeta> = input
        .viewpoints
        .iter()
        .filter(|v| sample_is_complete(dir, v, input.face_size, input.lowres_face_size))
        .filter_map(|v| dir.sample_meta(v.index))
        .collect();
    let complete: std::collections::BTreeSet<usize> = metas.iter().map(|m| m.index).collect();
    let missing: Vec<usize> = input
        .viewpoints
        .iter()
        .filter(|v| !complete.contains(&v.index))
        .map(|v| v.index)
        .collect();
    let layers: Vec<(usize, Vec<SlabRange>)> = if input.slabs.is_empty() {
        Vec::new()
    } else {
        input
            .viewpoints
            .iter()
            .filter_map(|v| dir.layers_meta(v.index).map(|m| (v.index, m.slabs)))
            .filter(|(_, s)| s == input.slabs)
            .collect()
    };
    let work = logged_work(dir, &metas, &layers)?;
    for w in &work.warnings {
        eprintln!("run log: {w}");
    }
    let rays: u64 = metas.iter().map(|m| m.primary_rays).sum();
    let logged_rays: u64 = work.shards.iter().map(|s| s.primary_rays).sum();
    let base_secs: f64 = work.shards.iter().fold(0.0, |a, s| a + s.render_seconds);
    let report = PrerenderReport {
        scene: input.scene.to_string(),
        renderer: input.renderer.into(),
        track: input.track.to_string(),
        samples: input.viewpoints.len(),
        face_size: input.face_size,
        lowres_face_size: input.lowres_face_size,
        seconds: base_secs + work.layer_seconds,
        rays_per_second: if base_secs > 0.0 {
            logged_rays as f64 / base_secs
        } else {
            0.0
        },
        viewpoints: input.viewpoints.to_vec(),
        slabs: input.slabs.to_vec(),
        shard: None,
        shards: work.shards.clone(),
        extra: serde_json::json!({
            "complete_samples": metas.len(),
            "missing_samples": missing,
            "samples_with_layers": layers.len(),
            "render_seconds_all_samples": base_secs,
            "layer_seconds_all_samples": work.layer_seconds,
            "primary_rays_all_samples": rays,
            "samples_without_run_log": work.unlogged,
        }),
    };
    store::write_json(&dir.report_json(), &report)?;
    let shard_rows: String = work
        .shards
        .iter()
        .map(|s| {
            format!(
                "| {} | {} | {:.2} | {} |\n",
                s.shard
                    .map_or("none (whole track)".to_string(), |(k, n)| format!(
                        "{k}/{n}"
                    )),
                s.samples.len(),
                s.render_seconds,
                s.hosts.join(", ")
            )
        })
        .collect();
    let md = format!(
        "# Prerender report\n\n| | |\n|---|---|\n| scene | `{}` |\n| track | `{}` |\n| renderer | {} |\n\
         | samples on track | {} |\n| complete samples | {} |\n| missing samples | {} |\n| face size | {} (low-res {}) |\n\
         | slabs | {} |\n| samples with slab layers | {} |\n| render time (all complete samples) | {:.2} s |\n\
         | primary rays/s | {:.0} |\n\n## Who rendered what (from the run logs in `runs/`)\n\n\
         | shard | samples | render s | hosts |\n|---|---|---|---|\n{}{}",
        report.scene,
        report.track,
        report.renderer,
        report.samples,
        metas.len(),
        if missing.is_empty() {
            "none".to_string()
        } else {
            list(&missing)
        },
        report.face_size,
        report.lowres_face_size,
        if input.slabs.is_empty() {
            "none".to_string()
        } else {
            input.slabs.iter().map(|s| s.label()).collect::<Vec<_>>().join(", ")
        },
        layers.len(),
        report.seconds,
        report.rays_per_second,
        shard_rows,
        if work.unlogged.is_empty() {
            String::new()
        } else {
            format!(
                "\nSamples no run log mentions (rendered by an older version, or copied without `runs/`): {}\n",
                list(&work.unlogged)
            )
        }
    );
    write_atomic(&dir.report_md(), md.as_bytes())?;
    Ok(report)
}

/// `1, 5, 9` (the first 50, then how many more).
pub fn list(indices: &[usize]) -> String {
    let mut s = indices
        .iter()
        .take(50)
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(", ");
    if indices.len() > 50 {
        s += &format!(" and {} more", indices.len() - 50);
    }
    s
}

/// The error of a merge that finds samples missing: names them, and the shard of `count`
/// each belongs to, so the user knows which task to run again.
pub fn missing_message(
    what: &str,
    missing: &[usize],
    total: usize,
    shard_count: Option<usize>,
) -> String {
    let mut m = format!(
        "{} of {total} samples have no complete {what}: {}",
        missing.len(),
        list(missing)
    );
    if let Some(n) = shard_count {
        let mut shards: Vec<usize> = missing.iter().map(|i| i % n).collect();
        shards.sort_unstable();
        shards.dedup();
        let names: Vec<String> = shards.iter().map(|k| format!("{k}/{n}")).collect();
        let ks: Vec<String> = shards.iter().map(|k| k.to_string()).collect();
        m += &format!(
            ". They belong to shard{} {} (of the {n} the last sharded run used): run {} \
             (`railview prerender … --shard {}`; in the Slurm array, `sbatch --array={} …`), \
             then merge again",
            if names.len() == 1 { "" } else { "s" },
            names.join(", "),
            if names.len() == 1 { "it" } else { "them" },
            if names.len() == 1 {
                names[0].as_str()
            } else {
                "K/N"
            },
            ks.join(","),
        );
    } else {
        m += ". Render them (a run without --shard renders what is missing), then merge again";
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::builtin;
    use std::path::PathBuf;

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("railview-job-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&d).ok();
        d
    }

    #[test]
    fn shard_parse() {
        assert_eq!(Shard::parse("1/3").unwrap(), Shard { index: 1, count: 3 });
        assert!(Shard::parse("3/3").is_err());
        assert!(Shard::parse("0/0").is_err());
        assert!(Shard::parse("a/2").is_err());
        assert!(Shard::parse("2").is_err());
        assert!(Shard::parse("0/2000000").is_err());
        let s = Shard::parse("1/3").unwrap();
        assert!(s.covers(4) && !s.covers(3));
    }

    #[test]
    fn shards_resume_and_merge_into_one_report() {
        let b = builtin("castle").unwrap();
        let vps: Vec<_> = b
            .tracks
            .get("main")
            .unwrap()
            .viewpoints()
            .into_iter()
            .take(3)
            .collect();
        let root = tmpdir("shards");
        let dir = PrerenderDir::new(&root);
        let opts = RenderOptions {
            face_size: 8,
            supersample: 1,
            shadows: true,
        };
        let mut total = RunStats::default();
        for k in 0..2 {
            let shard = Shard { index: k, count: 2 };
            let log = RunLog::create(&root, "prerender", Some(shard.pair())).unwrap();
            let s = render_track(
                &dir,
                &b.scene,
                &vps,
                opts,
                4,
                Some(shard),
                Some(&log),
                &|_, _| {},
            )
            .unwrap();
            total.rendered += s.rendered;
        }
        assert_eq!(total.rendered, 3);
        // Resume: nothing left to do.
        let again = render_track(&dir, &b.scene, &vps, opts, 4, None, None, &|_, _| {}).unwrap();
        assert_eq!((again.rendered, again.skipped), (0, 3));
        // A changed face size re-renders.
        let bigger = RenderOptions {
            face_size: 10,
            ..opts
        };
        assert!(!sample_is_complete(&dir, &vps[0], 10, 4));
        write_sample(&dir, &b.scene, &vps[0], bigger, 4).unwrap();
        assert!(!sample_is_complete(&dir, &vps[0], 8, 4));
        assert!(sample_is_complete(&dir, &vps[0], 10, 4));
        let input = ReportInput {
            scene: "castle",
            renderer: "builtin",
            track: "main",
            viewpoints: &vps,
            face_size: 8,
            lowres_face_size: 4,
            slabs: &[],
        };
        let report = write_report(&dir, &input).unwrap();
        assert_eq!(report.samples, 3);
        assert_eq!(report.extra["complete_samples"], 2);
        assert_eq!(report.extra["missing_samples"], serde_json::json!([0]));
        assert_eq!(
            missing_samples(&dir, &vps, 8, 4, &[]),
            (vec![0], Vec::new())
        );
        // Sample 0 was re-rendered at another size without a log; 1 and 2 came from shards
        // 1/2 and 0/2, whose logs the report reads.
        let by_shard: Vec<_> = report
            .shards
            .iter()
            .map(|s| (s.shard, s.samples.clone()))
            .collect();
        assert_eq!(
            by_shard,
            vec![(Some((0, 2)), vec![2]), (Some((1, 2)), vec![1])]
        );
        assert!(report.shards.iter().all(|s| s.render_seconds > 0.0));
        let summed: f64 = report.shards.iter().map(|s| s.render_seconds).sum();
        assert_eq!(report.seconds, summed);
        assert!(report.rays_per_second > 0.0);
        // Whoever writes it, the report says the same (times come from the logs).
        let again_report = write_report(&dir, &input).unwrap();
        assert_eq!(again_report, report);
        assert_eq!(logged_shard_count(&dir), Some(2));
        // (serde_json reads floats to within an ulp, so compare what scripts read.)
        let back = dir.read_report().unwrap();
        assert_eq!((back.samples, back.face_size), (3, 8));
        assert_eq!(back.extra, report.extra);
        assert!(dir.report_md().exists());
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn markers_hold_no_timing_and_rerender_to_the_same_bytes() {
        let b = builtin("castle").unwrap();
        let vp = b.tracks.get("main").unwrap().viewpoints()[1];
        let opts = RenderOptions {
            face_size: 12,
            supersample: 1,
            shadows: true,
        };
        let slabs = SlabRange::parse_list("0-8,8-inf").unwrap();
        let files = |root: &std::path::Path| -> Vec<(String, Vec<u8>)> {
            let d = PrerenderDir::new(root);
            let mut v = vec![
                d.color_png(1),
                d.depth_exr(1),
                d.lowres_depth_exr(1),
                d.sample_json(1),
                d.layers_json(1),
            ];
            for k in 0..2 {
                v.push(d.slab_color_png(1, k));
                v.push(d.slab_depth_exr(1, k));
            }
            v.into_iter()
                .map(|p| (p.display().to_string(), std::fs::read(&p).unwrap()))
                .map(|(p, b)| (p.replace(root.to_str().unwrap(), ""), b))
                .collect()
        };
        let mut got = Vec::new();
        for run in ["a", "b"] {
            let root = tmpdir(&format!("bytes-{run}"));
            let dir = PrerenderDir::new(&root);
            write_sample(&dir, &b.scene, &vp, opts, 6).unwrap();
            write_layers(&dir, &b.scene, &vp, &slabs, opts).unwrap();
            let text = std::fs::read_to_string(dir.sample_json(1)).unwrap();
            assert!(!text.contains("seconds"), "{text}");
            got.push(files(&root));
            std::fs::remove_dir_all(&root).ok();
        }
        assert!(
            got[0] == got[1],
            "two renders of one sample differ in bytes"
        );
    }

    #[test]
    fn interrupted_sample_does_not_look_complete() {
        let b = builtin("nature").unwrap();
        let vp = b.tracks.get("main").unwrap().viewpoints()[0];
        let root = tmpdir("interrupted");
        let dir = PrerenderDir::new(&root);
        let opts = RenderOptions {
            face_size: 8,
            supersample: 1,
            shadows: false,
        };
        write_sample(&dir, &b.scene, &vp, opts, 4).unwrap();
        assert!(sample_is_complete(&dir, &vp, 8, 4));
        // Simulate a run killed after its first file: the marker goes first, so the sample is
        // not complete even though older files are still there.
        remove_if_exists(&dir.sample_json(vp.index)).unwrap();
        write_atomic(&dir.color_png(vp.index), b"partial").unwrap();
        assert!(!sample_is_complete(&dir, &vp, 8, 4));
        let s = render_track(&dir, &b.scene, &[vp], opts, 4, None, None, &|_, _| {}).unwrap();
        assert_eq!(s.rendered, 1);
        assert!(store::read_rgb_png(&dir.color_png(vp.index)).is_ok());
        // Layers: written and then skipped when the slabs match.
        let slabs = SlabRange::parse_list("0-5,5-inf").unwrap();
        let w = write_slab_layers(&dir, &b.scene, &[vp], &slabs, opts).unwrap();
        assert_eq!(w.rendered, 1);
        let w = write_slab_layers(&dir, &b.scene, &[vp], &slabs, opts).unwrap();
        assert_eq!((w.rendered, w.skipped), (0, 1));
        assert_eq!(
            store::read_rgba_png(&dir.slab_color_png(vp.index, 1))
                .unwrap()
                .face_size(),
            8
        );
        std::fs::remove_dir_all(&root).ok();
    }
}
