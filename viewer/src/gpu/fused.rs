//! Fused frames (no view targets, no composite pass) and the half-resolution second view.

use super::pipelines::Pipe;
use super::{CompositeUniforms, GpuView, Renderer, Targets, SECOND_VIEW_MIN_WEIGHT};
use crate::plan::FramePlan;
use crate::refview::RefView;

impl Renderer {
    /// Fused frames (no tile ids, no overlays): the first view's meshes straight into the
    /// output, then the second view's meshes blended into the output against the first
    /// view's depth (and weighted by it, from a copy), then the sky of both views where
    /// neither drew (`render.wgsl`); no view targets, no composite pass.
    pub(super) fn encode_fused(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        views: &[RefView],
    ) {
        let passes: Vec<(&crate::plan::ViewPass, &GpuView)> = plan
            .passes
            .iter()
            .take(2)
            .filter_map(|p| Some((p, self.views.get(&views.get(p.view)?.index)?)))
            .collect();
        let uniforms = CompositeUniforms {
            weights: [
                passes.first().map_or(0.0, |p| p.0.weight as f32),
                passes.get(1).map_or(0.0, |p| p.0.weight as f32),
                passes.len() as f32,
                0.0,
            ],
            flags: [0; 4],
        };
        self.gpu
            .queue
            .write_buffer(&self.composite_uniforms, 0, bytemuck::bytes_of(&uniforms));
        let clear = |view| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })
        };
        if plan.half_res_second && passes.len() == 2 && self.gpu.caps.float_targets {
            self.encode_half(enc, targets, plan, &passes);
            return;
        }
        if passes.is_empty() {
            // Nothing to draw: a transparent (all-hole) frame.
            enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("empty frame"),
                color_attachments: &[clear(&targets.output_view)],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            return;
        }
        for (slot, (pass, g)) in passes.iter().enumerate() {
            self.gpu
                .queue
                .write_buffer(&g.uniforms, 0, bytemuck::bytes_of(&pass.uniforms));
            let first_targets = [clear(&targets.output_view)];
            // The second view reads the first view's depth from `depth_copy` while drawn
            // against `depth`: copied there, or, without depth copies, drawn there by the
            // first view and written into `depth` by a shader (below).
            let copies = self.gpu.caps.depth_copy;
            if slot == 1 && copies {
                // The second view's weights need the first view's depth where it is itself
                // depth-tested against (and writes) the same attachment: a copy.
                let copy = |texture| wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                };
                enc.copy_texture_to_texture(
                    copy(&targets.depth),
                    copy(&targets.depth_copy),
                    targets.depth.size(),
                );
            }
            let second_targets = [Some(wgpu::RenderPassColorAttachment {
                view: &targets.output_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })];
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some(if slot == 0 {
                    "first view"
                } else {
                    "second view"
                }),
                color_attachments: if slot == 0 {
                    &first_targets[..]
                } else {
                    &second_targets[..]
                },
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: if slot == 0 && passes.len() > 1 && !copies {
                        &targets.depth_copy_view
                    } else {
                        &targets.depth_view
                    },
                    depth_ops: Some(wgpu::Operations {
                        // The shader copy writes every pixel.
                        load: if slot == 0 || !copies {
                            wgpu::LoadOp::Clear(0.0)
                        } else {
                            wgpu::LoadOp::Load
                        },
                        store: if slot == 0 && passes.len() > 1 {
                            wgpu::StoreOp::Store
                        } else {
                            wgpu::StoreOp::Discard
                        },
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            rp.set_bind_group(0, &g.bind_group, &[]);
            if slot == 1 {
                rp.set_bind_group(1, &targets.second_group, &[]);
                // The other view (the first): its sky, for the second view near a sample.
                rp.set_bind_group(2, &passes[0].1.bind_group, &[]);
                if !copies {
                    rp.set_pipeline(self.pipeline(Pipe::CopyDepth));
                    rp.draw(0..3, 0..1);
                }
            }
            if !pass.runs.is_empty() {
                rp.set_pipeline(if slot == 0 {
                    self.pipeline(Pipe::FirstMesh)
                } else if pass.weight <= 0.0 {
                    self.pipeline(Pipe::SecondMeshAtSample)
                } else if pass.weight < SECOND_VIEW_MIN_WEIGHT {
                    self.pipeline(Pipe::SecondMeshHoles)
                } else {
                    self.pipeline(Pipe::SecondMesh)
                });
                self.draw_runs(&mut rp, plan, pass, g);
            }
            // The sky last, where no mesh drew: of the one view, or of both views blended.
            if passes.len() == 1 {
                rp.set_pipeline(self.pipeline(Pipe::FirstSky));
                rp.draw(0..3, 0..1);
            } else if slot == 1 {
                // The heavier view's sky, then the other's where that one has none.
                let (heavy, light) = if pass.weight > passes[0].0.weight {
                    (*g, passes[0].1)
                } else {
                    (passes[0].1, *g)
                };
                rp.set_bind_group(0, &heavy.bind_group, &[]);
                rp.set_bind_group(2, &light.bind_group, &[]);
                rp.set_pipeline(self.pipeline(Pipe::SkyHeavier));
                rp.draw(0..3, 0..1);
                // Nothing for the other view's sky to fill when the heavier view's has no
                // hole (a full-screen pass that llvmpipe would still bin and depth-test).
                if !heavy.sky_whole {
                    rp.set_pipeline(self.pipeline(Pipe::SkyOther));
                    rp.draw(0..3, 0..1);
                }
            }
        }
    }

    /// Fused frame with the second view at half resolution ([`FramePlan::half_res_second`]):
    /// the view with the smaller weight is drawn first at half the width and height into
    /// its own target (colour + distance), then the other view at full resolution writes
    /// every output pixel (meshes, then its background where no mesh drew), blending in the
    /// half-resolution view's nearest texel (`blend_half` in `render.wgsl`).
    pub(super) fn encode_half(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        passes: &[(&crate::plan::ViewPass, &GpuView)],
    ) {
        let (full, half) = if passes[1].0.weight <= passes[0].0.weight {
            (passes[0], passes[1])
        } else {
            (passes[1], passes[0])
        };
        let uniforms = CompositeUniforms {
            weights: [full.0.weight as f32, half.0.weight as f32, 2.0, 0.0],
            flags: [0; 4],
        };
        let queue = &self.gpu.queue;
        queue.write_buffer(&self.composite_uniforms, 0, bytemuck::bytes_of(&uniforms));
        queue.write_buffer(&full.1.uniforms, 0, bytemuck::bytes_of(&full.0.uniforms));
        // The same camera at half the framebuffer size (pixel rays of the background).
        let mut u = half.0.uniforms;
        u.params[1] = plan.width.div_ceil(2) as f32;
        u.params[2] = plan.height.div_ceil(2) as f32;
        queue.write_buffer(&half.1.uniforms, 0, bytemuck::bytes_of(&u));
        let depth = |view, load| {
            Some(wgpu::RenderPassDepthStencilAttachment {
                view,
                depth_ops: Some(wgpu::Operations {
                    load,
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            })
        };
        {
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("second view (half resolution)"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &targets.half_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: depth(&targets.half_depth, wgpu::LoadOp::Clear(0.0)),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            rp.set_bind_group(0, &half.1.bind_group, &[]);
            if !half.0.runs.is_empty() {
                rp.set_pipeline(self.pipeline(Pipe::Mesh));
                self.draw_runs(&mut rp, plan, half.0, half.1);
            }
            rp.set_pipeline(self.pipeline(Pipe::Background));
            rp.draw(0..3, 0..1);
        }
        // Every output pixel is written (the background pass has no discard): no clear.
        let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("first view over the second"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &targets.output_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: depth(&targets.depth_view, wgpu::LoadOp::Clear(0.0)),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        rp.set_bind_group(0, &full.1.bind_group, &[]);
        rp.set_bind_group(1, &targets.half_group, &[]);
        if !full.0.runs.is_empty() {
            rp.set_pipeline(self.pipeline(Pipe::MeshOverHalf));
            self.draw_runs(&mut rp, plan, full.0, full.1);
        }
        rp.set_pipeline(self.pipeline(Pipe::BackgroundOverHalf));
        rp.draw(0..3, 0..1);
    }

    /// Feedback frames without overlays: per view pass, its tile ids alone (depth + R32
    /// target, `fs_mesh_id_only`) at `1 / id_scale` of the frame's width and height; the
    /// picture is drawn by [`Renderer::encode_fused`]. The compute count then runs on the
    /// small target ([`Renderer::feedback`]).
    pub(super) fn encode_id_passes(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        views: &[RefView],
    ) {
        let (ids, depth) = targets.feedback_ids();
        for (slot, pass) in plan.passes.iter().take(2).enumerate() {
            let Some(g) = views.get(pass.view).and_then(|v| self.views.get(&v.index)) else {
                continue;
            };
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("tile ids"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &ids[slot],
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: depth,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if !pass.runs.is_empty() {
                rp.set_bind_group(0, &g.bind_group, &[]);
                rp.set_pipeline(self.pipeline(Pipe::MeshIdOnly));
                self.draw_runs(&mut rp, plan, pass, g);
            }
        }
    }

    /// Draw a pass's tile runs (vertex and index buffers of the plan's mesh level); the
    /// pipeline and bind groups are set.
    pub(super) fn draw_runs(
        &self,
        rp: &mut wgpu::RenderPass<'_>,
        plan: &FramePlan,
        pass: &crate::plan::ViewPass,
        g: &GpuView,
    ) {
        rp.set_vertex_buffer(0, g.vertices.slice(..));
        let (indices, starts) = match (plan.mesh_level as usize).checked_sub(1) {
            Some(k) => g
                .coarse
                .get(k)
                .or(g.coarse.last())
                .map_or((&g.indices, &g.index_start), |(b, s)| (b, s)),
            None => (&g.indices, &g.index_start),
        };
        rp.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
        for run in &pass.runs {
            let (a, b) = (starts[run.first], starts[run.first + run.count]);
            if b > a {
                rp.draw_indexed(a..b, 0, 0..1);
            }
        }
    }
}
