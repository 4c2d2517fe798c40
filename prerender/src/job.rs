//! Rendering a track into a prerender directory (layout in [`crate::store`]).
//!
//! - [`write_sample`]: one viewpoint's base pass (`color.png`, `depth.exr`,
//!   `lowres_depth.exr`, then `sample.json` as the completion marker).
//! - [`write_layers`]: one viewpoint's slab layers (`slab_K/*`, then `layers.json`).
//! - [`render_track`] / [`write_slab_layers`]: loops over viewpoints with resume (a viewpoint
//!   whose marker exists and matches the options is skipped) and sharding (`K/N` covers the
//!   viewpoints with `index % N == K`).
//! - [`write_report`]: `prerender.json` + `prerender.md` covering every complete sample found in
//!   the directory, whoever rendered it.
//!
//! Sharded runs merge by directory: copy the shards' `samples/NNNN/` directories into one
//! directory (they never overlap) and run the same command again without `--shard`: every
//! sample is found complete and skipped, and the report is rewritten to cover all of them.
//! Shards writing into one shared directory need no copying; the last one to finish writes a
//! report covering everything complete at that moment.

use std::time::Instant;

use glam::DVec3;
use tracks::{ReferenceViewpoint, SlabRange};

use crate::render::{render_cube, render_depth_lowres, render_slabs, RenderOptions};
use crate::scene::Scene;
use crate::store::{
    self, encode_rgb_png, encode_rgba_png, write_atomic, write_depth_exr, write_json, LayersMeta,
    PrerenderDir, PrerenderReport, SampleMeta, StoreError,
};

/// `K/N`: this run covers viewpoints with `index % N == K`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// Parse `K/N` with `0 <= K < N`.
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
        Ok(Shard { index: k, count: n })
    }

    pub fn covers(&self, viewpoint_index: usize) -> bool {
        viewpoint_index % self.count == self.index
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

/// Render and write one viewpoint's base pass; the marker is written last.
pub fn write_sample(
    dir: &PrerenderDir,
    scene: &Scene,
    vp: &ReferenceViewpoint,
    opts: RenderOptions,
    lowres_face_size: u32,
) -> Result<SampleMeta, StoreError> {
    // A stale marker must not vouch for files about to be replaced.
    remove_if_exists(&dir.sample_json(vp.index))?;
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
        seconds,
        primary_rays: cube.primary_rays + 6 * (lowres_face_size as u64).pow(2),
    };
    write_json(&dir.sample_json(vp.index), &meta)?;
    Ok(meta)
}

/// Render and write one viewpoint's slab layers; `layers.json` is written last.
pub fn write_layers(
    dir: &PrerenderDir,
    scene: &Scene,
    vp: &ReferenceViewpoint,
    slabs: &[SlabRange],
    opts: RenderOptions,
) -> Result<LayersMeta, StoreError> {
    remove_if_exists(&dir.layers_json(vp.index))?;
    let t = Instant::now();
    let layers = render_slabs(scene, vp.position, slabs, opts);
    let seconds = t.elapsed().as_secs_f64();
    for (k, l) in layers.iter().enumerate() {
        write_atomic(&dir.slab_color_png(vp.index, k), &encode_rgba_png(&l.color))?;
        write_depth_exr(&dir.slab_depth_exr(vp.index, k), &l.depth)?;
    }
    let meta = LayersMeta {
        slabs: slabs.to_vec(),
        seconds,
    };
    write_json(&dir.layers_json(vp.index), &meta)?;
    Ok(meta)
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

/// Base passes for `viewpoints` (those this shard covers), skipping complete ones.
/// `on_done(index, skipped)` is called after each covered viewpoint.
pub fn render_track(
    dir: &PrerenderDir,
    scene: &Scene,
    viewpoints: &[ReferenceViewpoint],
    opts: RenderOptions,
    lowres_face_size: u32,
    shard: Option<Shard>,
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
        let meta = write_sample(dir, scene, vp, opts, lowres_face_size)?;
        stats.rendered += 1;
        stats.primary_rays += meta.primary_rays;
        stats.render_seconds += meta.seconds;
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
    write_slab_layers_with(dir, scene, viewpoints, slabs, opts, &|_, _| {})
}

/// [`write_slab_layers`] with a progress callback `on_done(index, skipped)`.
pub fn write_slab_layers_with(
    dir: &PrerenderDir,
    scene: &Scene,
    viewpoints: &[ReferenceViewpoint],
    slabs: &[SlabRange],
    opts: RenderOptions,
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
        let meta = write_layers(dir, scene, vp, slabs, opts)?;
        stats.rendered += 1;
        stats.primary_rays += 6 * (opts.face_size as u64).pow(2);
        stats.render_seconds += meta.seconds;
        on_done(vp.index, false);
    }
    Ok(stats)
}

/// What the report describes besides the samples found on disk.
pub struct ReportInput<'a> {
    pub scene: &'a str,
    pub track: &'a str,
    pub viewpoints: &'a [ReferenceViewpoint],
    pub face_size: u32,
    pub lowres_face_size: u32,
    pub slabs: &'a [SlabRange],
    pub shard: Option<Shard>,
    /// Wall time of this run.
    pub seconds: f64,
    pub stats: &'a RunStats,
}

/// Write `prerender.json` and `prerender.md`. `rays_per_second` is over every complete
/// sample in the directory (their recorded rays and render times), so it survives resume
/// and merging shards; `extra` says what is complete and what this run did.
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
    let missing: Vec<usize> = input
        .viewpoints
        .iter()
        .filter(|v| !metas.iter().any(|m| m.index == v.index))
        .map(|v| v.index)
        .collect();
    let with_layers = if input.slabs.is_empty() {
        0
    } else {
        input
            .viewpoints
            .iter()
            .filter(|v| {
                dir.layers_meta(v.index)
                    .is_some_and(|m| m.slabs == input.slabs)
            })
            .count()
    };
    let rays: u64 = metas.iter().map(|m| m.primary_rays).sum();
    let secs: f64 = metas.iter().map(|m| m.seconds).sum();
    let report = PrerenderReport {
        scene: input.scene.to_string(),
        renderer: "builtin".into(),
        track: input.track.to_string(),
        samples: input.viewpoints.len(),
        face_size: input.face_size,
        lowres_face_size: input.lowres_face_size,
        seconds: input.seconds,
        rays_per_second: if secs > 0.0 { rays as f64 / secs } else { 0.0 },
        viewpoints: input.viewpoints.to_vec(),
        slabs: input.slabs.to_vec(),
        shard: input.shard.map(|s| (s.index, s.count)),
        extra: serde_json::json!({
            "complete_samples": metas.len(),
            "missing_samples": missing,
            "samples_with_layers": with_layers,
            "render_seconds_all_samples": secs,
            "primary_rays_all_samples": rays,
            "rendered_this_run": input.stats.rendered,
            "skipped_this_run": input.stats.skipped,
            "render_seconds_this_run": input.stats.render_seconds,
        }),
    };
    store::write_json(&dir.report_json(), &report)?;
    let md = format!(
        "# Prerender report\n\n| | |\n|---|---|\n| scene | `{}` |\n| track | `{}` |\n| renderer | builtin ray tracer |\n\
         | samples on track | {} |\n| complete samples | {} |\n| missing samples | {} |\n| face size | {} (low-res {}) |\n\
         | slabs | {} |\n| samples with slab layers | {} |\n| shard | {} |\n| wall time of this run | {:.2} s |\n\
         | rendered / skipped this run | {} / {} |\n| primary rays/s (all complete samples) | {:.0} |\n",
        report.scene,
        report.track,
        report.samples,
        metas.len(),
        missing.len(),
        report.face_size,
        report.lowres_face_size,
        if input.slabs.is_empty() {
            "none".to_string()
        } else {
            input.slabs.iter().map(|s| s.label()).collect::<Vec<_>>().join(", ")
        },
        with_layers,
        input
            .shard
            .map_or("none".to_string(), |s| format!("{}/{}", s.index, s.count)),
        input.seconds,
        input.stats.rendered,
        input.stats.skipped,
        report.rays_per_second,
    );
    write_atomic(&dir.report_md(), md.as_bytes())?;
    Ok(report)
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
            let s = render_track(
                &dir,
                &b.scene,
                &vps,
                opts,
                4,
                Some(Shard { index: k, count: 2 }),
                &|_, _| {},
            )
            .unwrap();
            total.rendered += s.rendered;
        }
        assert_eq!(total.rendered, 3);
        // Resume: nothing left to do.
        let again = render_track(&dir, &b.scene, &vps, opts, 4, None, &|_, _| {}).unwrap();
        assert_eq!((again.rendered, again.skipped), (0, 3));
        // A changed face size re-renders.
        let bigger = RenderOptions {
            face_size: 10,
            ..opts
        };
        assert!(!sample_is_complete(&dir, &vps[0], 10, 4));
        write_sample(&dir, &b.scene, &vps[0], bigger, 4).unwrap();
        assert!(sample_is_complete(&dir, &vps[0], 10, 4));
        let report = write_report(
            &dir,
            &ReportInput {
                scene: "castle",
                track: "main",
                viewpoints: &vps,
                face_size: 8,
                lowres_face_size: 4,
                slabs: &[],
                shard: None,
                seconds: 1.0,
                stats: &again,
            },
        )
        .unwrap();
        assert_eq!(report.samples, 3);
        assert_eq!(report.extra["complete_samples"], 2);
        assert_eq!(report.extra["missing_samples"], serde_json::json!([0]));
        assert!(report.rays_per_second > 0.0);
        // (serde_json reads floats to within an ulp, so compare what scripts read.)
        let back = dir.read_report().unwrap();
        assert_eq!((back.samples, back.face_size), (3, 8));
        assert_eq!(back.extra, report.extra);
        assert!(dir.report_md().exists());
        std::fs::remove_dir_all(&root).ok();
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
        let s = render_track(&dir, &b.scene, &[vp], opts, 4, None, &|_, _| {}).unwrap();
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
