//! The composite path (frames with overlays): a view pass per view into the view and
//! tile-id targets, the visible-pixel counts of the heat map, and the composite pass that
//! blends the two views and draws the overlays.

use super::passes::{begin, color, depth};
use super::pipelines::Pipe;
use super::{count_ids, tex, CompositeUniforms, GpuError, GpuView, Renderer, Targets, TILE_ROW};
use crate::plan::{FramePlan, Overlays};
use crate::refview::RefView;

impl Renderer {
    /// The composite path of [`Renderer::encode`]: the view passes, the heat map's counts
    /// (devices with compute), the composite pass.
    pub(super) fn encode_composite_path(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        views: &[RefView],
        ids: bool,
    ) {
        // Without tile ids the second view is drawn against the first view's depth: it then
        // skips what the first view hides and its sky where the first view has sky.
        let shared_depth = !ids && plan.passes.len() > 1;
        let drawn = self.encode_view_passes(enc, targets, plan, views, ids, shared_depth);
        if drawn.is_empty() {
            return;
        }
        if plan.overlays.heat && self.gpu.caps.compute {
            for (slot, g) in drawn.iter().enumerate() {
                self.encode_counts(enc, &targets.id_views[slot], g);
                if let Some(counts) = &g.counts {
                    enc.copy_buffer_to_texture(
                        wgpu::TexelCopyBufferInfo {
                            buffer: counts,
                            layout: wgpu::TexelCopyBufferLayout {
                                offset: 0,
                                bytes_per_row: Some(4 * TILE_ROW),
                                rows_per_image: Some(g.counts_tex.height()),
                            },
                        },
                        g.counts_tex.as_image_copy(),
                        g.counts_tex.size(),
                    );
                }
            }
        }
        self.encode_composite(enc, targets, plan, views, drawn.len());
        // The fill as in fused frames, unless the hole overlay is to show the holes.
        if !plan.overlays.holes {
            let passes = self.drawn_passes(plan, views);
            if let Some(heavy) = super::fused::heavier(&passes) {
                self.encode_fill(enc, targets, heavy);
            }
        }
    }

    /// A composite frame with the heat map on a device without compute: the view passes,
    /// then the visible pixels per tile counted on the CPU from the tile ids read back, then
    /// the composite with them.
    pub(super) fn draw_heat_on_cpu(
        &self,
        mut enc: wgpu::CommandEncoder,
        plan: &FramePlan,
        views: &[RefView],
    ) -> Result<(), GpuError> {
        let Some(targets) = &self.targets else {
            return Ok(());
        };
        let drawn = self.encode_view_passes(&mut enc, targets, plan, views, true, false);
        self.gpu.queue.submit([enc.finish()]);
        for (slot, g) in drawn.iter().enumerate() {
            let ids = self.read_ids(targets.id_views[slot].texture())?;
            let counts = count_ids(&ids, g.face_layer.len());
            self.write_counts(g, &counts);
        }
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        if !drawn.is_empty() {
            self.encode_composite(&mut enc, targets, plan, views, drawn.len());
        }
        self.gpu.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Write a view's visible-pixel counts into its counts texture (the heat map's input).
    fn write_counts(&self, g: &GpuView, counts: &[u32]) {
        let rows = g.counts_tex.height();
        let mut data = vec![0u32; (rows * TILE_ROW) as usize];
        let n = counts.len().min(data.len());
        data[..n].copy_from_slice(&counts[..n]);
        self.gpu.queue.write_texture(
            g.counts_tex.as_image_copy(),
            bytemuck::cast_slice(&data),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * TILE_ROW),
                rows_per_image: Some(rows),
            },
            g.counts_tex.size(),
        );
    }

    /// Make (once) the composite bind group of the views drawn by `plan`.
    pub(super) fn prepare_composite(&mut self, plan: &FramePlan, views: &[RefView]) {
        let Some(targets) = &self.targets else {
            return;
        };
        let slots: Vec<&RefView> = plan
            .passes
            .iter()
            .take(2)
            .filter_map(|p| views.get(p.view))
            .collect();
        let Some(first) = slots.first() else {
            return;
        };
        let key = (first.index, slots.get(1).map_or(usize::MAX, |v| v.index));
        if self.composite_groups.contains_key(&key) {
            return;
        }
        let Some(g0) = self.views.get(&first.index) else {
            return;
        };
        let g1 = slots
            .get(1)
            .and_then(|v| self.views.get(&v.index))
            .unwrap_or(g0);
        let resources = [
            self.composite_uniforms.as_entire_binding(),
            tex(&targets.view_views[0]),
            tex(&targets.view_views[1]),
            tex(&targets.id_views[0]),
            tex(&targets.id_views[1]),
            tex(&g0.tile_info_view),
            tex(&g1.tile_info_view),
            tex(&g0.counts_view),
            tex(&g1.counts_view),
        ];
        let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
            .into_iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource,
            })
            .collect();
        let bg = self
            .gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("composite"),
                layout: &self.composite_bgl,
                entries: &entries,
            });
        self.composite_groups.insert(key, bg);
    }

    /// The composite pass of a frame whose `drawn` view passes are encoded.
    fn encode_composite(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        views: &[RefView],
        drawn: usize,
    ) {
        let tiles = |slot: usize| {
            plan.passes
                .get(slot)
                .and_then(|p| views.get(p.view))
                .map_or(0, |v| v.tiles.len() as u32)
        };
        let pixels = plan.width as f32 * plan.height as f32;
        let weight = |slot: usize| plan.passes.get(slot).map_or(0.0, |p| p.weight);
        self.write_composite_uniforms(CompositeUniforms::new(
            [weight(0), weight(1)],
            drawn,
            (1.0 + pixels).log2(),
            [plan.overlays.bits(), tiles(0), tiles(1), 0],
        ));
        let index = |slot: usize| {
            plan.passes
                .get(slot)
                .and_then(|p| views.get(p.view))
                .map_or(usize::MAX, |v| v.index)
        };
        let Some(bg) = self.composite_groups.get(&(index(0), index(1))) else {
            return;
        };
        // The composite writes the nearer view's depth (`fs_composite`) for the fill.
        let mut rp = begin(
            enc,
            "composite",
            &[color(&targets.output_view, true)],
            depth(&targets.depth_view, true, true),
        );
        rp.set_bind_group(0, bg, &[]);
        self.draw_full(
            &mut rp,
            if plan.overlays == Overlays::default() {
                Pipe::Composite
            } else {
                Pipe::CompositeOverlays
            },
        );
    }

    /// The view passes of the composite path (tile meshes, then the sky, into the view and,
    /// with `ids`, tile-id targets); returns the views drawn, slot order.
    fn encode_view_passes<'a>(
        &'a self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &'a FramePlan,
        views: &[RefView],
        ids: bool,
        shared_depth: bool,
    ) -> Vec<&'a GpuView> {
        let passes = self.drawn_passes(plan, views);
        for (slot, &drawn) in passes.iter().enumerate() {
            self.write_view_uniforms(drawn);
            let with_ids = [
                color(&targets.view_views[slot], true),
                color(&targets.id_views[slot], true),
            ];
            let mut rp = begin(
                enc,
                "view",
                if ids { &with_ids[..] } else { &with_ids[..1] },
                depth(
                    &targets.depth_view,
                    !(shared_depth && slot == 1),
                    shared_depth && slot == 0,
                ),
            );
            rp.set_bind_group(0, &drawn.1.bind_group, &[]);
            let (mesh, sky) = if ids {
                (Pipe::MeshIds, Pipe::BackgroundIds)
            } else if shared_depth && slot == 1 {
                (Pipe::MeshBehind, Pipe::Background)
            } else if shared_depth && slot == 0 {
                (Pipe::Mesh, Pipe::SkyDepth)
            } else {
                (Pipe::Mesh, Pipe::Background)
            };
            self.draw_meshes(&mut rp, plan, drawn, mesh);
            self.draw_full(&mut rp, sky);
        }
        passes.into_iter().map(|(_, g)| g).collect()
    }

    /// Encode the feedback count of one view pass: zero the view's counts, then count the
    /// visible pixels of every tile in its tile-id target (devices with
    /// [`super::Caps::compute`]; nothing elsewhere).
    pub(super) fn encode_counts(
        &self,
        enc: &mut wgpu::CommandEncoder,
        ids: &wgpu::TextureView,
        g: &GpuView,
    ) {
        let (Some(feedback), Some(counts)) = (&self.feedback, &g.counts) else {
            return;
        };
        enc.clear_buffer(counts, 0, None);
        let bg = self
            .gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("feedback"),
                layout: &feedback.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(ids),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: counts.as_entire_binding(),
                    },
                ],
            });
        let (w, h) = (ids.texture().width(), ids.texture().height());
        let mut cp = enc.begin_compute_pass(&Default::default());
        cp.set_pipeline(feedback);
        cp.set_bind_group(0, &bg, &[]);
        cp.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
    }
}
