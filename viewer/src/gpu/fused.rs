//! Fused frames (no view targets, no composite pass) and the half-resolution second view.

use super::passes::{begin, color, depth, pass_weights, DrawnPass};
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
        let passes = self.drawn_passes(plan, views);
        self.write_composite_uniforms(CompositeUniforms::new(
            pass_weights(&passes),
            passes.len(),
            0.0,
            [0; 4],
        ));
        if plan.half_res_second && passes.len() == 2 && self.gpu.caps.float_targets {
            self.encode_half(enc, targets, plan, &passes);
            return;
        }
        if passes.is_empty() {
            // Nothing to draw: a transparent (all-hole) frame.
            begin(
                enc,
                "empty frame",
                &[color(&targets.output_view, true)],
                None,
            );
            return;
        }
        for slot in 0..passes.len() {
            self.encode_fused_view(enc, targets, plan, &passes, slot);
        }
        if let Some(heavy) = heavier(&passes) {
            self.encode_fill(enc, targets, heavy);
        }
    }

    /// The fill pass, last in every frame (fused, half-resolution, composite without the
    /// hole overlay): every pixel that no view covers (no mesh, no sky its panorama sees;
    /// alpha 0) takes the colour of the farther side (`fs_fill`), read from a copy of the
    /// output, the farther side found in the frame's final depth; where that is sky, the
    /// complete sky of `heavy`, the heavier view (group 0).
    pub(super) fn encode_fill(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        heavy: &GpuView,
    ) {
        enc.copy_texture_to_texture(
            targets.output.as_image_copy(),
            targets.fill_color.as_image_copy(),
            targets.output.size(),
        );
        let tested = self.gpu.caps.depth_copy;
        if tested {
            // The fill reads a copy of the depth it is tested against.
            enc.copy_texture_to_texture(
                targets.depth.as_image_copy(),
                targets.depth_copy.as_image_copy(),
                targets.depth.size(),
            );
        }
        let read_only = wgpu::RenderPassDepthStencilAttachment {
            view: &targets.depth_view,
            depth_ops: None,
            stencil_ops: None,
        };
        let mut rp = begin(
            enc,
            "fill",
            &[color(&targets.output_view, false)],
            tested.then_some(read_only),
        );
        // Group 0: the heavier view (its uniforms, written for its pass, and its layers).
        rp.set_bind_group(0, &heavy.bind_group, &[]);
        rp.set_bind_group(1, &targets.fill_group, &[]);
        self.draw_full(
            &mut rp,
            if tested {
                Pipe::Fill
            } else {
                Pipe::FillUntested
            },
        );
    }

    /// View pass `slot` of a fused frame: the first view writes the output and the depth;
    /// the second is blended in against (and weighted by) the first view's depth, then the
    /// sky goes where no mesh drew: of the one view, or of both views.
    fn encode_fused_view(
        &self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        passes: &[DrawnPass<'_>],
        slot: usize,
    ) {
        let (pass, g) = passes[slot];
        self.write_view_uniforms(passes[slot]);
        let two = passes.len() > 1;
        // The second view reads the first view's depth from `depth_copy` while drawn
        // against `depth`: copied there, or, without depth copies, drawn there by the
        // first view and written into `depth` by a shader (below).
        let copies = self.gpu.caps.depth_copy;
        if slot == 1 && copies {
            // The second view's weights need the first view's depth where it is itself
            // depth-tested against (and writes) the same attachment: a copy.
            enc.copy_texture_to_texture(
                targets.depth.as_image_copy(),
                targets.depth_copy.as_image_copy(),
                targets.depth.size(),
            );
        }
        let depth_view = if slot == 0 && two && !copies {
            &targets.depth_copy_view
        } else {
            &targets.depth_view
        };
        let mut rp = begin(
            enc,
            if slot == 0 {
                "first view"
            } else {
                "second view"
            },
            // The first view clears the output, the second blends into it.
            &[color(&targets.output_view, slot == 0)],
            // The shader copy writes every pixel. Stored: the second view reads the first
            // view's, the fill pass the final one.
            depth(depth_view, slot == 0 || !copies, true),
        );
        rp.set_bind_group(0, &g.bind_group, &[]);
        if slot == 1 {
            rp.set_bind_group(1, &targets.second_group, &[]);
            // The other view (the first): its sky, for the second view near a sample.
            rp.set_bind_group(2, &passes[0].1.bind_group, &[]);
            if !copies {
                self.draw_full(&mut rp, Pipe::CopyDepth);
            }
        }
        let mesh = if slot == 0 {
            Pipe::FirstMesh
        } else if pass.weight <= 0.0 {
            Pipe::SecondMeshAtSample
        } else if pass.weight < SECOND_VIEW_MIN_WEIGHT {
            Pipe::SecondMeshHoles
        } else {
            Pipe::SecondMesh
        };
        self.draw_meshes(&mut rp, plan, passes[slot], mesh);
        // The sky last, where no mesh drew: of the one view, or of both views blended.
        if !two {
            self.draw_full(&mut rp, Pipe::FirstSky);
        } else if slot == 1 {
            self.draw_two_view_sky(&mut rp, passes);
        }
    }

    /// The sky of a two-view fused frame, in the second view's pass: the heavier view's,
    /// then the other's where that one has none.
    fn draw_two_view_sky(&self, rp: &mut wgpu::RenderPass<'_>, passes: &[DrawnPass<'_>]) {
        let ((first, a), (second, b)) = (passes[0], passes[1]);
        let (heavy, light) = if second.weight > first.weight {
            (b, a)
        } else {
            (a, b)
        };
        rp.set_bind_group(0, &heavy.bind_group, &[]);
        rp.set_bind_group(2, &light.bind_group, &[]);
        self.draw_full(rp, Pipe::SkyHeavier);
        // Nothing for the other view's sky to fill when the heavier view's has no
        // hole (a full-screen pass that llvmpipe would still bin and depth-test).
        if !heavy.sky_whole {
            self.draw_full(rp, Pipe::SkyOther);
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
        passes: &[DrawnPass<'_>],
    ) {
        let (full, half) = if passes[1].0.weight <= passes[0].0.weight {
            (passes[0], passes[1])
        } else {
            (passes[1], passes[0])
        };
        self.write_composite_uniforms(CompositeUniforms::new(
            [full.0.weight, half.0.weight],
            2,
            0.0,
            [0; 4],
        ));
        self.write_view_uniforms(full);
        // The same camera at half the framebuffer size (pixel rays of the background).
        let mut u = half.0.uniforms;
        u.params[1] = plan.width.div_ceil(2) as f32;
        u.params[2] = plan.height.div_ceil(2) as f32;
        self.gpu
            .queue
            .write_buffer(&half.1.uniforms, 0, bytemuck::bytes_of(&u));
        {
            let mut rp = begin(
                enc,
                "second view (half resolution)",
                &[color(&targets.half_view, true)],
                depth(&targets.half_depth, true, false),
            );
            rp.set_bind_group(0, &half.1.bind_group, &[]);
            self.draw_meshes(&mut rp, plan, half, Pipe::Mesh);
            self.draw_full(&mut rp, Pipe::Background);
        }
        // Every output pixel is written (the background pass has no discard): no clear.
        // The full-resolution view's depth is stored for the fill (the half-resolution
        // view's own surfaces are not in it: there the fill's farther side counts as sky).
        {
            let mut rp = begin(
                enc,
                "first view over the second",
                &[color(&targets.output_view, false)],
                depth(&targets.depth_view, true, true),
            );
            rp.set_bind_group(0, &full.1.bind_group, &[]);
            rp.set_bind_group(1, &targets.half_group, &[]);
            self.draw_meshes(&mut rp, plan, full, Pipe::MeshOverHalf);
            self.draw_full(&mut rp, Pipe::BackgroundOverHalf);
        }
        self.encode_fill(enc, targets, full.1);
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
        let (ids, depth_view) = targets.feedback_ids();
        for (slot, drawn) in self.drawn_passes(plan, views).into_iter().enumerate() {
            let mut rp = begin(
                enc,
                "tile ids",
                &[color(&ids[slot], true)],
                depth(depth_view, true, false),
            );
            if !drawn.0.runs.is_empty() {
                rp.set_bind_group(0, &drawn.1.bind_group, &[]);
                self.draw_meshes(&mut rp, plan, drawn, Pipe::MeshIdOnly);
            }
        }
    }
}

/// The view with the larger weight of a frame's drawn passes (the first of equal weights).
pub(super) fn heavier<'a>(passes: &[DrawnPass<'a>]) -> Option<&'a GpuView> {
    match passes {
        [a, b, ..] if b.0.weight > a.0.weight => Some(b.1),
        [a, ..] => Some(a.1),
        [] => None,
    }
}
