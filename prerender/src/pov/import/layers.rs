//! A sample's slab layers: every slab's passes at once.

use std::time::Instant;

use tracks::{CubeMap, ReferenceViewpoint, SlabRange};

use super::{finite_range, remove, to_cube, DepthSummary, PovImport, View, MAX_SUPERSAMPLE};
use crate::pov::decode::{self, FogScales};
use crate::pov::frame::MeshLayout;
use crate::pov::runner::RenderJob;
use crate::pov::sdl::PassKind;
use crate::pov::PovError;
use crate::runlog::{LayersTiming, RunEvent};
use crate::store::{self, LayersMeta, PrerenderDir};

/// One render of a slab: which slab, its pass name and kind.
struct SlabRun {
    slab: usize,
    pass: String,
    kind: PassKind,
    job: RenderJob,
}

impl PovImport {
    /// Render a sample's slab layers (colour + depth per slab) and write them with the
    /// layers marker last. Needs the sample's base pass (its low-resolution depth sets the
    /// fog scales of an unbounded last slab; where a layer holds the surface the panorama
    /// sees, its colour is the panorama's, [`decode::layer_colour`]). Pixels with nothing in
    /// a slab get alpha 0 and depth `+inf`; their colour is what the ray saw (background or
    /// sky) and is kept.
    ///
    /// The passes of all slabs are independent, so they run several at a time
    /// (up to twice the cores): POV-Ray spends most of a short run starting up.
    pub fn render_slabs(
        &mut self,
        vp: &ReferenceViewpoint,
        slabs: &[SlabRange],
        dir: &PrerenderDir,
    ) -> Result<LayersMeta, PovError> {
        let start = Instant::now();
        remove(&dir.layers_json(vp.index))?;
        store::remove_temporaries(&dir.sample_dir(vp.index))?;
        for i in 0..slabs.len() {
            if let Some(d) = dir.slab_color_png(vp.index, i).parent() {
                store::remove_temporaries(d)?;
            }
        }
        let lowres = store::read_depth_exr(&dir.lowres_depth_exr(vp.index))?;
        let low: Vec<f64> = lowres.as_slice().iter().map(|&d| d as f64).collect();
        let (min, max) = finite_range(&low);
        let fog = self.scene_fog(vp)?;
        let k = if fog { 0.5 } else { 1.0 };
        // Where a layer holds the surface the panorama sees, it takes the panorama's colour.
        let base_colour = store::read_rgb_png(&dir.color_png(vp.index))?;
        let base_depth = store::read_depth_exr(&dir.depth_exr(vp.index))?;
        let pov = self.opts.up.pov_from_railview(vp.position);
        let n = self.opts.face_size;
        let ss = self.opts.supersample.clamp(1, MAX_SUPERSAMPLE);
        let mut runs: Vec<SlabRun> = Vec::new();
        let mut scales_of = Vec::new();
        for (i, slab) in slabs.iter().enumerate() {
            let range = if slab.far.is_finite() {
                slab.far - slab.near
            } else {
                0.0
            };
            let view = View {
                pov,
                near: slab.near,
                range,
            };
            let scales = if range > 0.0 {
                FogScales::for_slab(range, k)
            } else {
                FogScales::for_range(min, max, k)
            };
            scales_of.push((range, scales));
            let mut passes = vec![
                (format!("slab{i}-depth"), PassKind::Depth, n),
                (format!("slab{i}-color"), PassKind::Color, ss * n),
            ];
            if fog {
                passes.insert(0, (format!("slab{i}-depth-fog"), PassKind::FogOnly, n));
            }
            for (pass, kind, size) in passes {
                let f = (kind == PassKind::Depth).then_some(&scales);
                let mut job = self.job(&format!("s{:04}_{pass}", vp.index), kind, size, view, f)?;
                job.name = format!("sample {} {pass} ({})", vp.index, self.scene.display());
                runs.push(SlabRun {
                    slab: i,
                    pass,
                    kind,
                    job,
                });
            }
        }
        let jobs: Vec<RenderJob> = runs.iter().map(|r| r.job.clone()).collect();
        let stats = self.run_parallel(&jobs)?;
        let mut fog_px: Option<Vec<[u16; 3]>> = None;
        let mut depth: Option<CubeMap<f32>> = None;
        for (r, st) in runs.iter().zip(stats) {
            let size = r.job.width;
            self.record(vp.index, &r.pass, size, &r.job, st)?;
            let (range, scales) = scales_of[r.slab];
            let slab = &slabs[r.slab];
            match r.kind {
                PassKind::FogOnly => {
                    fog_px = Some(decode::read_mesh_png16(&r.job.output, &MeshLayout::new(n))?);
                }
                PassKind::Depth => {
                    let p1 = decode::read_mesh_png16(&r.job.output, &MeshLayout::new(n))?;
                    let d = decode::decode_fog(&p1, fog_px.take().as_deref(), &scales);
                    if let Some(last) = self.records.last_mut() {
                        last.depth = Some(DepthSummary::of(&d, &scales));
                    }
                    let t: Vec<f64> = (0..d.t.len())
                        .map(|i| decode::slab_depth(slab.near, range, d.t[i], d.t_hi[i]))
                        .collect();
                    depth = Some(to_cube(n, &t, |t| t)?);
                }
                PassKind::Color => {
                    let map = decode::read_mesh_png8(&r.job.output, &MeshLayout::new(ss * n))?;
                    let color = if ss > 1 {
                        decode::downsample(&map, ss)
                    } else {
                        map
                    };
                    let depth = depth.take().ok_or_else(|| PovError::Output {
                        path: r.job.output.clone(),
                        message: "a slab's colour came before its depth".into(),
                    })?;
                    let path = dir.slab_color_png(vp.index, r.slab);
                    write_layer((&path, &depth), &color, (&base_colour, &base_depth))?;
                    store::write_depth_exr(&dir.slab_depth_exr(vp.index, r.slab), &depth)?;
                }
            }
            remove(&r.job.output)?;
        }
        let meta = LayersMeta {
            slabs: slabs.to_vec(),
        };
        store::write_json(&dir.layers_json(vp.index), &meta)?;
        self.log(RunEvent::Layers(LayersTiming {
            index: vp.index,
            slabs: slabs.to_vec(),
            seconds: start.elapsed().as_secs_f64(),
        }))?;
        Ok(meta)
    }
}

/// A slab layer's RGBA image: its colour (the panorama's where it holds the surface the
/// panorama sees), opaque where its depth is finite.
fn write_layer(
    (path, depth): (&std::path::Path, &CubeMap<f32>),
    color: &CubeMap<[u8; 3]>,
    (base_colour, base_depth): (&CubeMap<[u8; 3]>, &CubeMap<f32>),
) -> Result<(), PovError> {
    let n = depth.face_size();
    let rgba = CubeMap::from_vec(
        n,
        (0..depth.as_slice().len())
            .map(|i| {
                let z = depth.as_slice()[i];
                let c = decode::layer_colour(
                    color.as_slice()[i],
                    z as f64,
                    base_colour.as_slice()[i],
                    base_depth.as_slice()[i] as f64,
                );
                [c[0], c[1], c[2], if z.is_finite() { 255 } else { 0 }]
            })
            .collect(),
    )
    .ok_or_else(|| PovError::Output {
        path: path.to_path_buf(),
        message: "colour and depth sizes differ".into(),
    })?;
    store::write_atomic(path, &store::encode_rgba_png(&rgba))?;
    Ok(())
}
