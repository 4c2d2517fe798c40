//! Slab layers the samples lack, rendered as their panoramas were: by the built-in tracer, or
//! by POV-Ray re-created from what the import recorded.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use prerender::pov::PovImport;
use prerender::runlog::{LayersTiming, RunEvent, RunLog};
use prerender::store::{self, LayersMeta, PrerenderDir, PrerenderReport};
use tracks::SlabRange;

use crate::error::{input, parameter, Context, Result};
use crate::prerender::{labels, RenderedBy};
use crate::progress::{BarKind, Reporter};

/// Render slab layers of `missing` samples with the renderer of the panoramas.
pub(super) fn render(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    slabs: &[SlabRange],
    missing: &[usize],
    log: &Arc<RunLog>,
    progress: &Reporter,
) -> Result<()> {
    match RenderedBy::of(pre) {
        RenderedBy::PovRay => return render_pov(dir, pre, slabs, missing, log, progress),
        RenderedBy::Builtin => {}
        RenderedBy::Other => {
            return Err(parameter!(
                "samples {:?} have no slab layers {} and renderer `{}` cannot be driven from `railview slabs` (only `builtin` and `povray` can): render them with that renderer's own command",
                missing,
                labels(slabs),
                pre.renderer
            ))
        }
    }
    let scene = match prerender::scenes::builtin(&pre.scene) {
        Some(b) => b.scene,
        None => {
            let text = crate::scene::read_text(Path::new(&pre.scene))
                .with_context(|| format!("reading scene `{}`", pre.scene))?;
            prerender::scene::Scene::parse_toml(&text, &pre.scene)?
        }
    };
    // As the panoramas were rendered (`prerender` records it; 1 ray, shadows if not).
    let opts = prerender::render::RenderOptions {
        face_size: pre.face_size,
        supersample: pre.extra["supersample"]
            .as_u64()
            .map_or(1, |s| s.clamp(1, 16) as u32),
        shadows: pre.extra["shadows"].as_bool().unwrap_or(true),
    };
    let bar = progress.bar(
        missing.len() as u64,
        "rendering slab layers",
        BarKind::Steps,
    );
    for &i in missing {
        let vp = pre
            .viewpoints
            .iter()
            .find(|v| v.index == i)
            .ok_or_else(|| input!("viewpoint {i} is not in prerender.json"))?;
        let t = Instant::now();
        let layers = prerender::render::render_slabs(&scene, vp.position, slabs, opts);
        for (k, l) in layers.iter().enumerate() {
            // Temporary files of a killed earlier run, before rewriting the layer.
            if let Some(d) = dir.slab_color_png(i, k).parent() {
                store::remove_temporaries(d)?;
            }
            store::write_atomic(&dir.slab_color_png(i, k), &store::encode_rgba_png(&l.color))?;
            store::write_depth_exr(&dir.slab_depth_exr(i, k), &l.depth)?;
        }
        store::write_json(
            &dir.layers_json(i),
            &LayersMeta {
                slabs: slabs.to_vec(),
            },
        )?;
        log.log(&RunEvent::Layers(LayersTiming {
            index: i,
            slabs: slabs.to_vec(),
            seconds: t.elapsed().as_secs_f64(),
        }))?;
        bar.inc(1);
    }
    bar.finish();
    let mut pre = pre.clone();
    pre.slabs = slabs.to_vec();
    store::write_json(&dir.report_json(), &pre)?;
    Ok(())
}

/// The POV-Ray import that wrote `pre`, re-created from what the import recorded in
/// `prerender.json`, with its generated files in `DIR/pov-work`.
pub(crate) fn pov_import_from_report(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
) -> Result<PovImport> {
    PovImport::from_report(dir, pre, &dir.root().join("pov-work")).with_context(|| {
        format!(
            "re-creating the POV-Ray import of `{}` recorded in {}",
            pre.scene,
            dir.report_json().display()
        )
    })
}

/// Render slab layers of `missing` samples of a POV-Ray import with POV-Ray.
fn render_pov(
    dir: &PrerenderDir,
    pre: &PrerenderReport,
    slabs: &[SlabRange],
    missing: &[usize],
    log: &Arc<RunLog>,
    progress: &Reporter,
) -> Result<()> {
    let mut import = pov_import_from_report(dir, pre)?;
    import.set_run_log(log.clone());
    let p = progress.clone();
    import.set_progress(move |r| {
        p.message(&format!(
            "sample {:>4} {:<18} {:>8.2} s  (parse {:.2} s, trace {:.2} s)",
            r.sample, r.pass, r.stats.wall_seconds, r.stats.parse_seconds, r.stats.trace_seconds
        ))
    });
    for &i in missing {
        let vp = pre
            .viewpoints
            .iter()
            .find(|v| v.index == i)
            .ok_or_else(|| input!("viewpoint {i} is not in prerender.json"))?;
        if !import.base_done(dir, vp) {
            return Err(input!(
                "sample {i}: its base pass is missing or was rendered with other face sizes; run `railview import-pov` on {} first",
                dir.root().display()
            ));
        }
        progress.message(&format!(
            "sample {i}: POV-Ray slab layers {}",
            labels(slabs)
        ));
        import
            .render_slabs(vp, slabs, dir)
            .with_context(|| format!("sample {i}: rendering slab layers with POV-Ray"))?;
    }
    import.remove_mesh_includes()?;
    let total = import.total_stats();
    let mut pre = pre.clone();
    pre.slabs = slabs.to_vec();
    if let Some(extra) = pre.extra.as_object_mut() {
        extra.insert("slab_renders".into(), import.records().len().into());
        extra.insert("slab_povray_wall_seconds".into(), total.wall_seconds.into());
        extra.insert(
            "slab_render_log".into(),
            serde_json::to_value(import.records())?,
        );
    }
    store::write_json(&dir.report_json(), &pre)?;
    Ok(())
}
