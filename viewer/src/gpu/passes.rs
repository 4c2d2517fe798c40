//! What every pass of a frame shares, composite path and fused alike: attachments, the
//! plan's view passes with their uploaded views, a view's tile meshes and full-screen
//! draws, the composite uniforms.

use super::pipelines::Pipe;
use super::{CompositeUniforms, GpuView, Renderer};
use crate::plan::{FramePlan, ViewPass};
use crate::refview::RefView;

/// A view pass of a plan (one of the first two) with its uploaded view.
pub(super) type DrawnPass<'a> = (&'a ViewPass, &'a GpuView);

/// A colour attachment, cleared to transparent (`clear`) or loaded, and stored.
pub(super) fn color(
    view: &wgpu::TextureView,
    clear: bool,
) -> Option<wgpu::RenderPassColorAttachment<'_>> {
    Some(wgpu::RenderPassColorAttachment {
        view,
        depth_slice: None,
        resolve_target: None,
        ops: wgpu::Operations {
            load: if clear {
                wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT)
            } else {
                wgpu::LoadOp::Load
            },
            store: wgpu::StoreOp::Store,
        },
    })
}

/// A depth attachment, cleared to the far plane (0: reversed Z) or loaded, and stored or
/// discarded.
pub(super) fn depth(
    view: &wgpu::TextureView,
    clear: bool,
    store: bool,
) -> Option<wgpu::RenderPassDepthStencilAttachment<'_>> {
    Some(wgpu::RenderPassDepthStencilAttachment {
        view,
        depth_ops: Some(wgpu::Operations {
            load: if clear {
                wgpu::LoadOp::Clear(0.0)
            } else {
                wgpu::LoadOp::Load
            },
            store: if store {
                wgpu::StoreOp::Store
            } else {
                wgpu::StoreOp::Discard
            },
        }),
        stencil_ops: None,
    })
}

/// Begin a render pass into `colors` and `depth`.
pub(super) fn begin<'e>(
    enc: &'e mut wgpu::CommandEncoder,
    label: &str,
    colors: &[Option<wgpu::RenderPassColorAttachment<'_>>],
    depth: Option<wgpu::RenderPassDepthStencilAttachment<'_>>,
) -> wgpu::RenderPass<'e> {
    enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: colors,
        depth_stencil_attachment: depth,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// The blend weights of the first two passes (0 where there is none).
pub(super) fn pass_weights(passes: &[DrawnPass<'_>]) -> [f64; 2] {
    [
        passes.first().map_or(0.0, |p| p.0.weight),
        passes.get(1).map_or(0.0, |p| p.0.weight),
    ]
}

impl CompositeUniforms {
    /// Blend `weights` of the two views, the number of views drawn, the heat map's scale
    /// (log2(1 + pixels); 0 where unused) and the overlay flags (overlay bits, tiles of view
    /// 0, tiles of view 1, unused).
    pub(super) fn new(
        weights: [f64; 2],
        views: usize,
        heat_scale: f32,
        flags: [u32; 4],
    ) -> CompositeUniforms {
        CompositeUniforms {
            weights: [
                weights[0] as f32,
                weights[1] as f32,
                views as f32,
                heat_scale,
            ],
            flags,
        }
    }
}

impl Renderer {
    /// The first two view passes of `plan` whose views are uploaded (after
    /// [`Renderer::prepare`], all of them), in slot order.
    pub(super) fn drawn_passes<'a>(
        &'a self,
        plan: &'a FramePlan,
        views: &[RefView],
    ) -> Vec<DrawnPass<'a>> {
        plan.passes
            .iter()
            .take(2)
            .filter_map(|p| Some((p, self.views.get(&views.get(p.view)?.index)?)))
            .collect()
    }

    /// Write the uniforms the composite pass and the fused second view read.
    pub(super) fn write_composite_uniforms(&self, uniforms: CompositeUniforms) {
        self.gpu
            .queue
            .write_buffer(&self.composite_uniforms, 0, bytemuck::bytes_of(&uniforms));
    }

    /// Write a view pass's uniforms into its view's buffer.
    pub(super) fn write_view_uniforms(&self, (pass, g): DrawnPass<'_>) {
        self.gpu
            .queue
            .write_buffer(&g.uniforms, 0, bytemuck::bytes_of(&pass.uniforms));
    }

    /// Draw a pass's tile meshes with `pipe`, where it has any; the bind groups are set.
    pub(super) fn draw_meshes(
        &self,
        rp: &mut wgpu::RenderPass<'_>,
        plan: &FramePlan,
        (pass, g): DrawnPass<'_>,
        pipe: Pipe,
    ) {
        if !pass.runs.is_empty() {
            rp.set_pipeline(self.pipeline(pipe));
            self.draw_runs(rp, plan, pass, g);
        }
    }

    /// One full-screen triangle with `pipe` (a sky, a copy, a composite); the bind groups
    /// are set.
    pub(super) fn draw_full(&self, rp: &mut wgpu::RenderPass<'_>, pipe: Pipe) {
        rp.set_pipeline(self.pipeline(pipe));
        rp.draw(0..3, 0..1);
    }

    /// Draw a pass's tile runs (vertex and index buffers of the plan's mesh level); the
    /// pipeline and bind groups are set.
    pub(super) fn draw_runs(
        &self,
        rp: &mut wgpu::RenderPass<'_>,
        plan: &FramePlan,
        pass: &ViewPass,
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
