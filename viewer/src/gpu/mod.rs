//! The wgpu executor of a [`FramePlan`]: headless (offscreen targets + readback) or into any
//! colour target the caller owns (the egui app).
//!
//! Per reference view it keeps a [`GpuView`]: one 2D-array texture (layer 0 background,
//! layer `k + 1` slab `k`, faces stacked `N × 6N`, full mip chain), one vertex and index buffer
//! with every tile mesh, and a small storage buffer of per-tile face/layer/min-level/highlight/
//! slab (rewritten only when it changes). A frame with overlays is one render pass per view
//! (tile runs front slab first with a reversed-Z depth test and the opacity mask) into an
//! `Rgba16Float` target (alpha = distance, 0 where no tile drew) and an `R32Uint` tile-id
//! target; then one full-screen composite pass (`composite.wgsl`) that
//! samples each view's background where its tiles left the pixel empty, blends the two views
//! and draws the debug overlays ([`crate::plan::Overlays`]). The heat-map overlay counts the
//! visible pixels per tile with the feedback compute pass inside the same frame.
//!
//! Each view pass draws its tile meshes, then its background (sky) at the far plane behind a
//! depth test, so the sky costs only where no tile drew. That is the path of frames with
//! overlays only. Frames without overlays (most frames in the window, feedback frames, and
//! `eval`) are *fused*: two passes straight into the output, no view targets and no
//! composite pass. Feedback frames ([`FramePlan::tile_ids`]) draw the same picture and, per
//! view, a cheap depth + `R32Uint` tile-id pass (`fs_mesh_id_only`: the opacity-mask lookup
//! and the id, no colour, no sky) at `1 / `[`FramePlan::id_scale`] of the width and height
//! (a quarter by default); the compute count runs on that small target and
//! [`Renderer::feedback`] scales its counts by the area factor. The first view's meshes write
//! the output (sRGB, alpha 1) and the depth. The second view's meshes are drawn against the
//! first view's depth (scaled by `SECOND_VIEW_DEPTH_SCALE`, skipping what the blend would
//! weigh at almost nothing) with hardware blending: each of its fragments carries the share
//! β = w_b / (w_a + w_b) the composite would give it there, computed from the first view's
//! distance, which a copy of the first view's depth gives along the fragment's ray (reversed
//! Z: d_a = d_b · z_b / z_a; 0 where the first view drew no mesh: the sky is
//! farther than any mesh, so there the second view's mesh wins as in the composite). Last,
//! the sky of both views, blended by their weights, where neither view's meshes drew (a
//! depth test against the cleared depth, no `discard`, so llvmpipe skips covered blocks
//! before shading). Same image as the composite up to 8-bit rounding of the first view's
//! colour.
//! [`FramePlan::half_res_second`] (a [`crate::DrawBudget`] choice, off by default) draws the
//! view with the smaller weight first at half width and height into its own target, then the
//! other view writes every output pixel, blending the half-resolution texel in.
//! [`FramePlan::mesh_level`] selects decimated index buffers over the same vertices.
//!
//! Streaming: [`Renderer::update_layer_region`] writes the texels around one tile that
//! arrived (from [`crate::texture::Layer::update_region`]) into an uploaded view; when tiles
//! join a view, the next draw rebuilds its meshes and keeps its texture.

use std::collections::HashMap;

use crate::plan::{FramePlan, Overlays};
use crate::refview::RefView;

mod fused;
mod pipelines;
mod readback;
mod upload;

const VIEW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Tile-id target of a view pass: tile index + 1, 0 = no tile.
const ID_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// Fast path (frames without tile ids): the second view is drawn against the first view's
/// depth scaled by this, so its fragments more than this factor farther than the first
/// view's surface are skipped. Their blend weight would be below exp(-20 · 0.5) ≈ 5e-5 of
/// the nearer surface's (`SHARPNESS` in composite.wgsl), so the image does not change;
/// meshes nearer than `NEAR_M × 1.5` are clipped in the second view.
const SECOND_VIEW_DEPTH_SCALE: f64 = 1.5;
/// Fused frames: below this weight the second view is drawn only where its surface is
/// clearly nearer than the first view's (by `NEARER_ONLY`, its depth scaled by
/// `1 / NEARER_ONLY`) or the first view has sky or a hole: there the depth-aware blend gives
/// it (almost) everything whatever its weight. Elsewhere its share would be below
/// w / (1 − w) · exp(SHARPNESS · (NEARER_ONLY − 1)) < 0.01, under 2.5/255 of the colour
/// difference, so it is skipped (near the reference samples, t < 0.03 of a segment).
const SECOND_VIEW_MIN_WEIGHT: f64 = 0.003;
const NEARER_ONLY: f64 = 1.05;
/// Features [`Renderer::throughput`] needs for GPU times (requested where available).
const TIMESTAMPS: wgpu::Features =
    wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS);
/// Format of the final image (sRGB-encoded RGBA8, alpha 0 = hole).
pub const OUTPUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

/// Errors of the GPU path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    #[error("no GPU adapter (wgpu found none; install mesa-vulkan-drivers for lavapipe): {0}")]
    NoAdapter(String),
    #[error("requesting a device failed: {0}")]
    Device(String),
    #[error("reading the frame back failed: {0}")]
    Readback(String),
    #[error("plan refers to view {0}, but only {1} views were given")]
    MissingView(usize, usize),
    #[error("image {width}x{height} exceeds the device limit {limit}")]
    TooLarge { width: u32, height: u32, limit: u32 },
}

/// A rendered frame: sRGB RGBA8, rows from the top; alpha 0 marks hole pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Frame {
    /// Fraction of pixels that no view covers.
    pub fn hole_fraction(&self) -> f64 {
        let n = (self.width as usize * self.height as usize).max(1);
        self.rgba.chunks(4).filter(|p| p[3] == 0).count() as f64 / n as f64
    }
}

/// [`Renderer::throughput`]: milliseconds per frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Throughput {
    /// Wall clock per frame, frames submitted back to back with one wait at the end.
    pub wall_ms: f64,
    /// Median GPU time of one frame's commands (timestamp queries); `None` where the adapter
    /// has none.
    pub gpu_ms: Option<f64>,
}

/// Device and queue.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
}

impl Gpu {
    /// The default adapter (`WGPU_BACKEND` may force `vulkan` or `gl`); lavapipe on machines
    /// without a GPU.
    pub fn new() -> Result<Gpu, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("railview"),
            required_limits: wgpu::Limits::default().using_resolution(adapter.limits()),
            // Timestamps around frames for `Renderer::throughput`, where the adapter has them.
            required_features: adapter.features() & TIMESTAMPS,
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(Gpu {
            device,
            queue,
            info,
        })
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuVertex {
    pos_in_face: [f32; 2],
    depth_m: f32,
    packed: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CompositeUniforms {
    /// w0, w1, number of views, log2(1 + pixels) (heat-map scale).
    weights: [f32; 4],
    /// Overlay bits, unused.
    flags: [u32; 4],
}

/// Shader source: the shared cube-map helpers followed by `main`.
fn shader_source(main: &str) -> String {
    [include_str!("../cube.wgsl"), main].concat()
}

fn tex(v: &wgpu::TextureView) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::TextureView(v)
}

/// One tile's entry of the tile-info storage buffer (`tile_info` in `render.wgsl`).
fn tile_info(face_layer: u32, min_level: u32, tile: &crate::refview::ViewTile) -> [u32; 4] {
    let highlight = if tile.highlight.is_finite() {
        tile.highlight.clamp(0.0, 1.0)
    } else {
        0.0
    };
    [face_layer, min_level, highlight.to_bits(), tile.slab]
}

/// GPU copy of one reference view.
pub struct GpuView {
    texture: wgpu::Texture,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    tile_info: wgpu::Buffer,
    /// What `tile_info` holds now (rewritten only when a level or highlight changes).
    info: Vec<[u32; 4]>,
    /// Visible pixels per tile (feedback and the heat-map overlay).
    counts: wgpu::Buffer,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// First index of every tile, plus the end.
    index_start: Vec<u32>,
    /// Decimated meshes (mesh levels 1, 2, …): index buffer into `vertices` and the first
    /// index of every tile, plus the end.
    coarse: Vec<(wgpu::Buffer, Vec<u32>)>,
    /// Per tile `face | layer << 8`, uploaded with the frame's min levels.
    face_layer: Vec<u32>,
    /// Bytes uploaded (textures + meshes).
    pub bytes: u64,
    /// Of which meshes and tile buffers.
    mesh_bytes: u64,
    /// The background layer has sky (alpha > 0) at every texel, so at every level: where
    /// this view is the heavier one, a fused frame needs no other view's sky.
    sky_whole: bool,
}

struct Targets {
    width: u32,
    height: u32,
    view_views: [wgpu::TextureView; 2],
    id_views: [wgpu::TextureView; 2],
    depth: wgpu::Texture,
    depth_view: wgpu::TextureView,
    /// Fused two-view frames: the first view's depth copied before the second view is drawn
    /// against it, and the second view's bind group 1 (composite uniforms, the half-resolution
    /// target unused, that copy).
    depth_copy: wgpu::Texture,
    second_group: wgpu::BindGroup,
    /// Half-resolution second view: colour + distance, its depth, and the bind group 1 of
    /// the first view drawn over it.
    half_view: wgpu::TextureView,
    half_depth: wgpu::TextureView,
    half_group: wgpu::BindGroup,
    output: wgpu::Texture,
    output_view: wgpu::TextureView,
    /// The same texels as plain UNORM (sRGB-encoded bytes), for UIs that expect them.
    output_view_unorm: wgpu::TextureView,
    /// Reduced-resolution tile ids (feedback frames without overlays): the scale, the id
    /// targets and their depth (the full-resolution ones when the scale is 1).
    id_scale: u32,
    small: Option<([wgpu::TextureView; 2], wgpu::TextureView)>,
}

impl Targets {
    /// The id targets of feedback frames without overlays and their depth.
    fn feedback_ids(&self) -> (&[wgpu::TextureView; 2], &wgpu::TextureView) {
        match &self.small {
            Some((ids, depth)) => (ids, depth),
            None => (&self.id_views, &self.depth_view),
        }
    }

    /// The id target of view pass `slot` of the last frame drawn with `scale`.
    fn ids_of(&self, slot: usize, scale: u32) -> &wgpu::TextureView {
        if scale > 1 {
            &self.feedback_ids().0[slot]
        } else {
            &self.id_views[slot]
        }
    }
}

/// Executes frame plans.
pub struct Renderer {
    pub gpu: Gpu,
    view_bgl: wgpu::BindGroupLayout,
    composite_bgl: wgpu::BindGroupLayout,
    /// Fused frames (no tile ids, no overlays): the first view into the output, the second
    /// view blended into it, weighted by the first view's depth (`render.wgsl`).
    second_bgl: wgpu::BindGroupLayout,
    /// Fused frames: the first view's meshes into the output alone, and a one-view frame's sky.
    first_mesh: wgpu::RenderPipeline,
    first_sky: wgpu::RenderPipeline,
    second_mesh: wgpu::RenderPipeline,
    /// The second view only where it is clearly nearer than the first view or the first view
    /// has sky or a hole (weight below `SECOND_VIEW_MIN_WEIGHT`).
    second_mesh_holes: wgpu::RenderPipeline,
    /// The same at a sample (weight 0): only where the first view has neither a mesh nor sky.
    second_mesh_at_sample: wgpu::RenderPipeline,
    /// The sky of a two-view fused frame, after both views' meshes: the heavier view's where
    /// it has sky (writing depth), then the other view's where it has none (the sky is at
    /// infinity, the same from both viewpoints).
    sky_heavier: wgpu::RenderPipeline,
    sky_other: wgpu::RenderPipeline,
    /// Half-resolution second view: the first view drawn over it, blending it in.
    mesh_over_half: wgpu::RenderPipeline,
    background_over_half: wgpu::RenderPipeline,
    /// Background (sky) where no tile drew, with and without the tile-id target.
    background_ids: wgpu::RenderPipeline,
    background: wgpu::RenderPipeline,
    /// Composite frames with the hole overlay: first view's sky with depth; second view's
    /// meshes against it.
    sky_depth: wgpu::RenderPipeline,
    mesh_behind: wgpu::RenderPipeline,
    /// Tile meshes writing colour and tile ids.
    mesh_ids: wgpu::RenderPipeline,
    /// Tile meshes writing tile ids only (feedback frames without overlays).
    mesh_id_only: wgpu::RenderPipeline,
    /// Tile meshes writing colour only.
    mesh: wgpu::RenderPipeline,
    panorama: wgpu::RenderPipeline,
    composite: wgpu::RenderPipeline,
    composite_overlays: wgpu::RenderPipeline,
    feedback: wgpu::ComputePipeline,
    sampler: wgpu::Sampler,
    composite_uniforms: wgpu::Buffer,
    views: HashMap<usize, GpuView>,
    targets: Option<Targets>,
    /// Whether the last frame wrote the tile-id targets (slot 0, slot 1).
    ids_valid: [bool; 2],
    /// The [`FramePlan::id_scale`] of the last frame's tile ids (1 = full resolution).
    ids_scale: u32,
    /// Draw half-texel skirts around meshes on pixel centres ([`crate::refview::skirt`]).
    skirts: bool,
    /// Composite bind groups by the reference-view indices of slots 0 and 1 (made once:
    /// binding many textures anew every frame is slow on some drivers).
    composite_groups: HashMap<(usize, usize), wgpu::BindGroup>,
}

impl Renderer {
    /// Drop every uploaded view (call when the set of views changes identity).
    pub fn forget_views(&mut self) {
        self.views.clear();
        self.composite_groups.clear();
    }

    /// Drop one uploaded view (e.g. after new tiles or levels arrived for it).
    pub fn invalidate_view(&mut self, index: usize) {
        self.views.remove(&index);
        self.composite_groups.clear();
    }

    /// Draw the half-texel skirts that close the outlines of meshes on pixel centres
    /// ([`crate::refview::skirt`]; on by default, as the CPU reference draws them). Off
    /// only to measure what they cost; changing it drops the uploaded views.
    pub fn set_skirts(&mut self, on: bool) {
        if self.skirts != on {
            self.skirts = on;
            self.forget_views();
        }
    }

    /// Bytes held by uploaded views.
    pub fn uploaded_bytes(&self) -> u64 {
        self.views.values().map(|v| v.bytes).sum()
    }

    /// Upload what `plan` needs (views, targets, tile info, composite bind group).
    fn prepare(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        for p in &plan.passes {
            let v = views
                .get(p.view)
                .ok_or(GpuError::MissingView(p.view, views.len()))?;
            self.ensure_view(v);
        }
        self.ensure_targets(plan.width, plan.height, plan.id_scale)?;
        for p in &plan.passes {
            self.update_tile_info(p, &views[p.view]);
        }
        self.prepare_composite(plan, views);
        Ok(())
    }

    /// Record and submit the frame into the internal output target; waits for the GPU.
    pub fn draw(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        self.prepare(plan, views)?;
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        self.encode(&mut enc, plan, views);
        self.gpu.queue.submit([enc.finish()]);
        let ids = plan.tile_ids || plan.overlays.needs_tile_ids();
        self.ids_valid = [ids && !plan.passes.is_empty(), ids && plan.passes.len() > 1];
        self.ids_scale = if plan.overlays == Overlays::default() {
            plan.id_scale.max(1)
        } else {
            1
        };
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        Ok(())
    }

    /// Rewrite a view's per-tile info (face, layer, min level, highlight, slab) when it changed
    /// since the last frame; most frames write nothing.
    fn update_tile_info(&mut self, pass: &crate::plan::ViewPass, view: &RefView) {
        let Some(g) = self.views.get_mut(&view.index) else {
            return;
        };
        let changed = g.info.len() != g.face_layer.len()
            || g.info
                .iter()
                .zip(&g.face_layer)
                .zip(pass.tile_min_level.iter().zip(&view.tiles))
                .any(|((i, &fl), (&lvl, t))| *i != tile_info(fl, lvl, t));
        if !changed {
            return;
        }
        g.info = g
            .face_layer
            .iter()
            .zip(pass.tile_min_level.iter().chain(std::iter::repeat(&0)))
            .zip(&view.tiles)
            .map(|((&fl, &lvl), t)| tile_info(fl, lvl, t))
            .collect();
        if !g.info.is_empty() {
            self.gpu
                .queue
                .write_buffer(&g.tile_info, 0, bytemuck::cast_slice(&g.info));
        }
    }

    /// Make (once) the composite bind group of the views drawn by `plan`.
    fn prepare_composite(&mut self, plan: &FramePlan, views: &[RefView]) {
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
            g0.tile_info.as_entire_binding(),
            g1.tile_info.as_entire_binding(),
            g0.counts.as_entire_binding(),
            g1.counts.as_entire_binding(),
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

    /// Encode the frame's passes into the internal output target. Views, targets and tile
    /// info must have been prepared ([`Renderer::draw`] does it).
    fn encode(&self, enc: &mut wgpu::CommandEncoder, plan: &FramePlan, views: &[RefView]) {
        let Some(targets) = &self.targets else {
            return;
        };
        let ids = plan.tile_ids || plan.overlays.needs_tile_ids();
        if plan.overlays == Overlays::default() {
            // The picture as on frames without tile ids (no change every few frames), and
            // for feedback frames the tile ids in a cheap pass of their own, at
            // `1 / id_scale` resolution.
            self.encode_fused(enc, targets, plan, views);
            if ids {
                self.encode_id_passes(enc, targets, plan, views);
            }
            return;
        }
        // Without tile ids the second view is drawn against the first view's depth: it then
        // skips what the first view hides and its sky where the first view has sky.
        let shared_depth = !ids && plan.passes.len() > 1;
        let drawn = self.encode_view_passes(enc, targets, plan, views, ids, shared_depth);
        if drawn.is_empty() {
            return;
        }
        if plan.overlays.heat {
            for (slot, g) in drawn.iter().enumerate() {
                self.encode_counts(enc, &targets.id_views[slot], g);
            }
        }
        let pixels = plan.width as f32 * plan.height as f32;
        let uniforms = CompositeUniforms {
            weights: [
                plan.passes.first().map_or(0.0, |p| p.weight as f32),
                plan.passes.get(1).map_or(0.0, |p| p.weight as f32),
                drawn.len() as f32,
                (1.0 + pixels).log2(),
            ],
            flags: [plan.overlays.bits(), 0, 0, 0],
        };
        self.gpu
            .queue
            .write_buffer(&self.composite_uniforms, 0, bytemuck::bytes_of(&uniforms));
        let index = |slot: usize| {
            plan.passes
                .get(slot)
                .and_then(|p| views.get(p.view))
                .map_or(usize::MAX, |v| v.index)
        };
        let Some(bg) = self.composite_groups.get(&(index(0), index(1))) else {
            return;
        };
        let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("composite"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &targets.output_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        rp.set_pipeline(if plan.overlays == Overlays::default() {
            &self.composite
        } else {
            &self.composite_overlays
        });
        rp.set_bind_group(0, bg, &[]);
        rp.draw(0..3, 0..1);
    }

    /// The view passes of the composite path (tile meshes, then the sky, into the view and,
    /// with `ids`, tile-id targets); returns the views drawn, slot order.
    fn encode_view_passes<'a>(
        &'a self,
        enc: &mut wgpu::CommandEncoder,
        targets: &Targets,
        plan: &FramePlan,
        views: &[RefView],
        ids: bool,
        shared_depth: bool,
    ) -> Vec<&'a GpuView> {
        let mut drawn: Vec<&GpuView> = Vec::new();
        for (slot, pass) in plan.passes.iter().take(2).enumerate() {
            let Some(g) = views.get(pass.view).and_then(|v| self.views.get(&v.index)) else {
                continue;
            };
            drawn.push(g);
            self.gpu
                .queue
                .write_buffer(&g.uniforms, 0, bytemuck::bytes_of(&pass.uniforms));
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
            let with_ids = [
                clear(&targets.view_views[slot]),
                clear(&targets.id_views[slot]),
            ];
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("view"),
                color_attachments: if ids { &with_ids[..] } else { &with_ids[..1] },
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &targets.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: if shared_depth && slot == 1 {
                            wgpu::LoadOp::Load
                        } else {
                            wgpu::LoadOp::Clear(0.0)
                        },
                        store: if shared_depth && slot == 0 {
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
            if !pass.runs.is_empty() {
                rp.set_pipeline(if ids {
                    &self.mesh_ids
                } else if shared_depth && slot == 1 {
                    &self.mesh_behind
                } else {
                    &self.mesh
                });
                self.draw_runs(&mut rp, plan, pass, g);
            }
            rp.set_pipeline(if ids {
                &self.background_ids
            } else if shared_depth && slot == 0 {
                &self.sky_depth
            } else {
                &self.background
            });
            rp.draw(0..3, 0..1);
        }
        drawn
    }

    /// Encode the feedback count of one view pass: zero the view's counts, then count the
    /// visible pixels of every tile in its tile-id target.
    fn encode_counts(&self, enc: &mut wgpu::CommandEncoder, ids: &wgpu::TextureView, g: &GpuView) {
        enc.clear_buffer(&g.counts, 0, None);
        let bg = self
            .gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("feedback"),
                layout: &self.feedback.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(ids),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: g.counts.as_entire_binding(),
                    },
                ],
            });
        let (w, h) = (ids.texture().width(), ids.texture().height());
        let mut cp = enc.begin_compute_pass(&Default::default());
        cp.set_pipeline(&self.feedback);
        cp.set_bind_group(0, &bg, &[]);
        cp.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
    }

    /// Draw the plain panorama of `plan.passes[0]`'s view (its background layer as one cube
    /// map, no slabs, no blending) into the internal output target; waits for the GPU.
    pub fn draw_panorama(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        self.prepare_panorama(plan, views)?;
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("pano"),
            });
        self.encode_panorama(&mut enc, plan, views);
        self.gpu.queue.submit([enc.finish()]);
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        Ok(())
    }

    fn prepare_panorama(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        let pass = plan.passes.first().ok_or(GpuError::MissingView(0, 0))?;
        let v = views
            .get(pass.view)
            .ok_or(GpuError::MissingView(pass.view, views.len()))?;
        self.ensure_view(v);
        self.ensure_targets(plan.width, plan.height, plan.id_scale)
    }

    fn encode_panorama(&self, enc: &mut wgpu::CommandEncoder, plan: &FramePlan, views: &[RefView]) {
        let Some(pass) = plan.passes.first() else {
            return;
        };
        let Some(g) = views.get(pass.view).and_then(|v| self.views.get(&v.index)) else {
            return;
        };
        let Some(targets) = &self.targets else {
            return;
        };
        self.gpu
            .queue
            .write_buffer(&g.uniforms, 0, bytemuck::bytes_of(&pass.uniforms));
        {
            let mut rp = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("panorama"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &targets.output_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            rp.set_pipeline(&self.panorama);
            rp.set_bind_group(0, &g.bind_group, &[]);
            rp.draw(0..3, 0..1);
        }
    }

    /// The internal output target of the last draw (for showing it in a window).
    pub fn output_view(&self) -> Option<&wgpu::TextureView> {
        self.targets.as_ref().map(|t| &t.output_view)
    }

    /// The output target viewed as plain `Rgba8Unorm` (the sRGB-encoded bytes undecoded):
    /// what egui's renderer expects of a user texture.
    pub fn output_view_unorm(&self) -> Option<&wgpu::TextureView> {
        self.targets.as_ref().map(|t| &t.output_view_unorm)
    }

    /// Draw a plan and read it back.
    pub fn render(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<Frame, GpuError> {
        self.draw(plan, views)?;
        self.read_output()
    }
}
