//! The wgpu executor of a [`FramePlan`]: headless (offscreen targets + readback) or into any
//! colour target the caller owns (the egui app).
//!
//! Per reference view it keeps a [`GpuView`]: one 2D-array texture (layer 0 background,
//! layer `k + 1` slab `k`, faces stacked `N × 6N`, full mip chain), one vertex and index buffer
//! with every tile mesh, and a small storage buffer of per-tile face/layer/min-level/highlight/
//! slab (rewritten only when it changes). A frame is one render pass per view (tile runs front
//! slab first with a reversed-Z depth test and the opacity mask) into an `Rgba16Float` target
//! (alpha = distance, 0 where no tile drew) and, when the plan asks for feedback or overlays,
//! an `R32Uint` tile-id target; then one full-screen composite pass (`composite.wgsl`) that
//! samples each view's background where its tiles left the pixel empty, blends the two views
//! and draws the debug overlays ([`crate::plan::Overlays`]). The heat-map overlay counts the
//! visible pixels per tile with the feedback compute pass inside the same frame.
//!
//! Each view pass draws its tile meshes, then its background (sky) at the far plane behind a
//! depth test, so the sky costs only where no tile drew. That is the path of frames with tile
//! ids or overlays. Frames without them ([`FramePlan::tile_ids`] off, no overlays: most
//! frames in the window, and `eval`) are *fused*: two passes straight into the output, no
//! view targets and no composite pass. The first view writes the output (sRGB, alpha 1) and
//! its distance (an `R16Float` target); its sky writes a tiny depth. The second view is drawn
//! against the first view's depth (scaled by `SECOND_VIEW_DEPTH_SCALE`, skipping what the
//! blend would weigh at almost nothing) with hardware blending: each of its fragments carries
//! the share β = w_b / (w_a + w_b) the composite would give it there, computed from the first
//! view's distance; its sky fills the first view's holes only. Same image as the composite
//! up to 8-bit rounding of the first view's colour.
//! [`FramePlan::half_res_second`] (a [`crate::DrawBudget`] choice, off by default) draws the
//! view with the smaller weight first at half width and height into its own target, then the
//! other view writes every output pixel, blending the half-resolution texel in. Its feedback
//! frames (tile ids, no overlays) draw the view passes for the ids only and the image as on
//! the other frames, so the picture does not change every few frames.
//! [`FramePlan::mesh_level`] selects decimated index buffers over the same vertices.
//!
//! Streaming: [`Renderer::update_layer_region`] writes the texels around one tile that
//! arrived (from [`crate::texture::Layer::update_region`]) into an uploaded view; when tiles
//! join a view, the next draw rebuilds its meshes and keeps its texture.

use std::collections::HashMap;

use wgpu::util::DeviceExt;

use crate::plan::{FramePlan, Overlays, ViewUniforms};
use crate::refview::{decimated_indices, mesh_cell, RefView, MESH_LEVELS};

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
/// Fused frames: the first view's distance to the camera (0 = hole), read by the second view.
const DIST_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R16Float;
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
    [include_str!("cube.wgsl"), main].concat()
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
}

struct Targets {
    width: u32,
    height: u32,
    view_views: [wgpu::TextureView; 2],
    id_views: [wgpu::TextureView; 2],
    depth_view: wgpu::TextureView,
    /// Fused frames: the first view's distance, and the second view's bind group 1
    /// (composite uniforms + that distance).
    dist_view: wgpu::TextureView,
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
}

/// Executes frame plans.
pub struct Renderer {
    pub gpu: Gpu,
    view_bgl: wgpu::BindGroupLayout,
    composite_bgl: wgpu::BindGroupLayout,
    /// Fused frames (no tile ids, no overlays): the first view into the output and its
    /// distance target, the second view blended into the output (`render.wgsl`).
    second_bgl: wgpu::BindGroupLayout,
    first_mesh: wgpu::RenderPipeline,
    first_sky: wgpu::RenderPipeline,
    second_mesh: wgpu::RenderPipeline,
    /// The second view only where it is clearly nearer than the first view or the first view
    /// has sky or a hole (weight below `SECOND_VIEW_MIN_WEIGHT`).
    second_mesh_holes: wgpu::RenderPipeline,
    second_sky: wgpu::RenderPipeline,
    /// Half-resolution second view: the first view drawn over it, blending it in.
    mesh_over_half: wgpu::RenderPipeline,
    background_over_half: wgpu::RenderPipeline,
    /// Background (sky) where no tile drew, with and without the tile-id target.
    background_ids: wgpu::RenderPipeline,
    background: wgpu::RenderPipeline,
    /// Fast path: first view's sky with depth; second view's meshes against it.
    sky_depth: wgpu::RenderPipeline,
    mesh_behind: wgpu::RenderPipeline,
    /// Tile meshes writing colour and tile ids.
    mesh_ids: wgpu::RenderPipeline,
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
    /// Composite bind groups by the reference-view indices of slots 0 and 1 (made once:
    /// binding many textures anew every frame is slow on some drivers).
    composite_groups: HashMap<(usize, usize), wgpu::BindGroup>,
}

fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    bgl_entry(
        binding,
        wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
    )
}

fn bgl_entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty,
        count: None,
    }
}

fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    bgl_entry(
        binding,
        wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
    )
}

fn texture_entry(binding: u32, dim: wgpu::TextureViewDimension) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: dim,
            multisampled: false,
        },
        count: None,
    }
}

fn uint_texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Uint,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

impl Renderer {
    pub fn new(gpu: Gpu) -> Renderer {
        let device = &gpu.device;
        let view_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view"),
            entries: &[
                uniform_entry(0),
                texture_entry(1, wgpu::TextureViewDimension::D2Array),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                storage_entry(3),
            ],
        });
        let composite_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("composite"),
            entries: &[
                uniform_entry(0),
                texture_entry(1, wgpu::TextureViewDimension::D2),
                texture_entry(2, wgpu::TextureViewDimension::D2),
                uint_texture_entry(3),
                uint_texture_entry(4),
                storage_entry(5),
                storage_entry(6),
                storage_entry(7),
                storage_entry(8),
            ],
        });
        let second_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("second view"),
            entries: &[
                uniform_entry(0),
                texture_entry(1, wgpu::TextureViewDimension::D2),
            ],
        });
        let render = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shader_source(include_str!("render.wgsl")).into()),
        });
        let composite_src = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("composite.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shader_source(include_str!("composite.wgsl")).into()),
        });
        let view_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("view"),
            bind_group_layouts: &[Some(&view_bgl)],
            immediate_size: 0,
        });
        let second_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("second view"),
            bind_group_layouts: &[Some(&view_bgl), Some(&second_bgl)],
            immediate_size: 0,
        });
        let composite_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("composite"),
            bind_group_layouts: &[Some(&composite_bgl)],
            immediate_size: 0,
        });
        let depth = |compare, write| {
            Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(write),
                depth_compare: Some(compare),
                stencil: Default::default(),
                bias: Default::default(),
            })
        };
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let id_targets = [target(VIEW_FORMAT), target(ID_FORMAT)];
        let color_targets = [target(VIEW_FORMAT)];
        let output_target = [target(OUTPUT_FORMAT)];
        let vertex_attrs = wgpu::vertex_attr_array![0 => Float32x2, 1 => Float32, 2 => Uint32];
        let mk = |label: &str,
                  module: &wgpu::ShaderModule,
                  layout: &wgpu::PipelineLayout,
                  vs: &str,
                  fs: &str,
                  buffers: &[Option<wgpu::VertexBufferLayout<'_>>],
                  targets: &[Option<wgpu::ColorTargetState>],
                  depth_stencil: Option<wgpu::DepthStencilState>,
                  constants: &[(&str, f64)]| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module,
                    entry_point: Some(vs),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants,
                        ..Default::default()
                    },
                    buffers,
                },
                primitive: wgpu::PrimitiveState {
                    cull_mode: None,
                    ..Default::default()
                },
                depth_stencil,
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let mesh_buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<GpuVertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &vertex_attrs,
        })];
        // Drawn after the meshes at depth 0 (the reversed-Z far plane, the clear value): only
        // pixels no mesh covered pass, and the rasteriser skips the shader on covered blocks.
        let background_ids = mk(
            "background+ids",
            &render,
            &view_layout,
            "vs_full",
            "fs_background_ids",
            &[],
            &id_targets,
            depth(wgpu::CompareFunction::GreaterEqual, false),
            &[],
        );
        let background = mk(
            "background",
            &render,
            &view_layout,
            "vs_full",
            "fs_background",
            &[],
            &color_targets,
            depth(wgpu::CompareFunction::GreaterEqual, false),
            &[],
        );
        let mesh_ids = mk(
            "mesh+ids",
            &render,
            &view_layout,
            "vs_mesh",
            "fs_mesh_ids",
            &mesh_buffers,
            &id_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        // The fast path without tile ids: the first view's sky writes depth, the second view
        // is drawn against the first view's depth (see `depth_scale` in render.wgsl).
        let sky_depth = mk(
            "background (sky depth)",
            &render,
            &view_layout,
            "vs_sky_depth",
            "fs_background_sky_depth",
            &[],
            &color_targets,
            depth(wgpu::CompareFunction::GreaterEqual, true),
            &[],
        );
        let mesh_behind = mk(
            "mesh (against the first view)",
            &render,
            &view_layout,
            "vs_mesh",
            "fs_mesh",
            &mesh_buffers,
            &color_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[("depth_scale", SECOND_VIEW_DEPTH_SCALE)],
        );
        let mesh = mk(
            "mesh",
            &render,
            &view_layout,
            "vs_mesh",
            "fs_mesh",
            &mesh_buffers,
            &color_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        // Fused frames: the first view writes the output (no blending) and its distance.
        let first_targets = [target(OUTPUT_FORMAT), target(DIST_FORMAT)];
        let first_mesh = mk(
            "first view mesh (fused)",
            &render,
            &view_layout,
            "vs_mesh",
            "fs_mesh_first",
            &mesh_buffers,
            &first_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        let first_sky = mk(
            "first view sky (fused)",
            &render,
            &view_layout,
            "vs_sky_depth",
            "fs_sky_first",
            &[],
            &first_targets,
            depth(wgpu::CompareFunction::GreaterEqual, true),
            &[],
        );
        // The second view blends into the output: colour β·src + (1 − β)·dst with β the
        // fragment's alpha; alpha max(src, dst) (covered when either view covers).
        let second_targets = [Some(wgpu::ColorTargetState {
            format: OUTPUT_FORMAT,
            blend: Some(wgpu::BlendState {
                color: wgpu::BlendComponent {
                    src_factor: wgpu::BlendFactor::SrcAlpha,
                    dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
                    operation: wgpu::BlendOperation::Add,
                },
                alpha: wgpu::BlendComponent {
                    src_factor: wgpu::BlendFactor::One,
                    dst_factor: wgpu::BlendFactor::One,
                    operation: wgpu::BlendOperation::Max,
                },
            }),
            write_mask: wgpu::ColorWrites::ALL,
        })];
        let second_mesh = mk(
            "second view mesh (fused)",
            &render,
            &second_layout,
            "vs_mesh",
            "fs_mesh_second",
            &mesh_buffers,
            &second_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[("depth_scale", SECOND_VIEW_DEPTH_SCALE)],
        );
        let second_mesh_holes = mk(
            "second view mesh, nearer only (fused)",
            &render,
            &second_layout,
            "vs_mesh",
            "fs_mesh_second",
            &mesh_buffers,
            &second_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[("depth_scale", 1.0 / NEARER_ONLY)],
        );
        let second_sky = mk(
            "second view sky (fused)",
            &render,
            &second_layout,
            "vs_full",
            "fs_sky_second",
            &[],
            &second_targets,
            depth(wgpu::CompareFunction::GreaterEqual, false),
            &[],
        );
        let mesh_over_half = mk(
            "mesh over the half-resolution second view",
            &render,
            &second_layout,
            "vs_mesh",
            "fs_mesh_over_half",
            &mesh_buffers,
            &output_target,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        let background_over_half = mk(
            "background over the half-resolution second view",
            &render,
            &second_layout,
            "vs_full",
            "fs_background_over_half",
            &[],
            &output_target,
            depth(wgpu::CompareFunction::GreaterEqual, false),
            &[],
        );
        let panorama = mk(
            "panorama",
            &render,
            &view_layout,
            "vs_full",
            "fs_panorama",
            &[],
            &output_target,
            None,
            &[],
        );
        let composite = mk(
            "composite",
            &composite_src,
            &composite_layout,
            "vs_full",
            "fs_composite",
            &[],
            &output_target,
            None,
            &[],
        );
        let composite_overlays = mk(
            "composite+overlays",
            &composite_src,
            &composite_layout,
            "vs_full",
            "fs_composite_overlays",
            &[],
            &output_target,
            None,
            &[],
        );
        let feedback_src = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("feedback.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("feedback.wgsl").into()),
        });
        let feedback = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("feedback"),
            layout: None,
            module: &feedback_src,
            entry_point: Some("count"),
            compilation_options: Default::default(),
            cache: None,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("layers"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Nearest,
            ..Default::default()
        });
        let composite_uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("composite"),
            size: std::mem::size_of::<CompositeUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Renderer {
            gpu,
            view_bgl,
            composite_bgl,
            second_bgl,
            first_mesh,
            first_sky,
            second_mesh,
            second_mesh_holes,
            second_sky,
            mesh_over_half,
            background_over_half,
            mesh_ids,
            mesh,
            panorama,
            composite,
            composite_overlays,
            background_ids,
            background,
            sky_depth,
            mesh_behind,
            feedback,
            sampler,
            composite_uniforms,
            views: HashMap::new(),
            targets: None,
            ids_valid: [false; 2],
            composite_groups: HashMap::new(),
        }
    }

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

    /// Bytes held by uploaded views.
    pub fn uploaded_bytes(&self) -> u64 {
        self.views.values().map(|v| v.bytes).sum()
    }

    fn upload(&self, view: &RefView) -> GpuView {
        let (texture, bytes) = self.upload_texture(view);
        self.upload_meshes(view, texture, bytes)
    }

    /// The view's texture array with every layer and level written; bytes written.
    fn upload_texture(&self, view: &RefView) -> (wgpu::Texture, u64) {
        let device = &self.gpu.device;
        let n = view.face_size;
        let layers = view.layers.len().max(1) as u32;
        let mips = view.layers.first().map_or(1, |l| l.levels.len()) as u32;
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("view layers"),
            size: wgpu::Extent3d {
                width: n,
                height: 6 * n,
                depth_or_array_layers: layers,
            },
            mip_level_count: mips,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let mut bytes = 0u64;
        for (li, layer) in view.layers.iter().enumerate() {
            for (level, map) in layer.levels.iter().enumerate().take(mips as usize) {
                let m = map.face_size();
                let data: &[u8] = bytemuck::cast_slice(map.as_slice());
                bytes += data.len() as u64;
                self.gpu.queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &texture,
                        mip_level: level as u32,
                        origin: wgpu::Origin3d {
                            x: 0,
                            y: 0,
                            z: li as u32,
                        },
                        aspect: wgpu::TextureAspect::All,
                    },
                    data,
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(4 * m),
                        rows_per_image: Some(6 * m),
                    },
                    wgpu::Extent3d {
                        width: m,
                        height: 6 * m,
                        depth_or_array_layers: 1,
                    },
                );
            }
        }
        (texture, bytes)
    }

    /// Everything of a [`GpuView`] but the texture: meshes, tile info, bind group.
    fn upload_meshes(&self, view: &RefView, texture: wgpu::Texture, tex_bytes: u64) -> GpuView {
        let mut bytes = tex_bytes;
        let device = &self.gpu.device;
        let n = view.face_size;
        let mut verts: Vec<GpuVertex> = Vec::new();
        let mut idx: Vec<u32> = Vec::new();
        let mut index_start = Vec::with_capacity(view.tiles.len() + 1);
        let mut face_layer = Vec::with_capacity(view.tiles.len());
        // Decimated index lists per coarser mesh level (same vertices).
        let grid = tracks::TileGrid::new(n, view.tile_size);
        let mut coarse: Vec<(Vec<u32>, Vec<u32>)> = (0..MESH_LEVELS)
            .map(|_| (Vec::new(), Vec::with_capacity(view.tiles.len() + 1)))
            .collect();
        let jump = crate::refview::MeshParams::default().jump;
        for (ti, tile) in view.tiles.iter().enumerate() {
            index_start.push(idx.len() as u32);
            let base = verts.len() as u32;
            for (k, (cidx, cstart)) in coarse.iter_mut().enumerate() {
                cstart.push(cidx.len() as u32);
                match &grid {
                    Some(g) => {
                        let cell = mesh_cell(view.tile_size, k as u32 + 1);
                        let d = decimated_indices(&tile.mesh, g.pixel_rect(tile.tile), cell, jump);
                        cidx.extend(d.iter().map(|i| base + i));
                    }
                    None => cidx.extend(tile.mesh.indices.iter().map(|i| base + i)),
                }
            }
            let face = tile.tile.face.index() as u32;
            verts.extend(tile.mesh.vertices.iter().map(|v| GpuVertex {
                pos_in_face: v.pos_in_face,
                depth_m: v.depth_m,
                packed: ((ti as u32) << 3) | face,
            }));
            idx.extend(tile.mesh.indices.iter().map(|i| base + i));
            face_layer.push(face | ((tile.slab + 1) << 8));
        }
        index_start.push(idx.len() as u32);
        let coarse: Vec<(wgpu::Buffer, Vec<u32>)> = coarse
            .into_iter()
            .map(|(mut cidx, mut cstart)| {
                cstart.push(cidx.len() as u32);
                cidx.resize(cidx.len().max(4), 0);
                bytes += cidx.len() as u64 * 4;
                let buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("coarse tile indices"),
                    contents: bytemuck::cast_slice(&cidx),
                    usage: wgpu::BufferUsages::INDEX,
                });
                (buf, cstart)
            })
            .collect();
        // Buffers are never empty (bindings of size 0 are invalid).
        if verts.is_empty() {
            verts.push(GpuVertex {
                pos_in_face: [0.0; 2],
                depth_m: 0.0,
                packed: 0,
            });
        }
        idx.resize(idx.len().max(4), 0);
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tile vertices"),
            contents: bytemuck::cast_slice(&verts),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tile indices"),
            contents: bytemuck::cast_slice(&idx),
            usage: wgpu::BufferUsages::INDEX,
        });
        bytes += (verts.len() * std::mem::size_of::<GpuVertex>() + idx.len() * 4) as u64;
        let tile_info = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tile info"),
            size: (16 * face_layer.len().max(1)) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let counts = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tile counts"),
            size: (4 * face_layer.len().max(1)) as u64,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view uniforms"),
            size: std::mem::size_of::<ViewUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layers_view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view"),
            layout: &self.view_bgl,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniforms.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&layers_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: tile_info.as_entire_binding(),
                },
            ],
        });
        GpuView {
            texture,
            vertices,
            indices,
            tile_info,
            info: Vec::new(),
            counts,
            uniforms,
            bind_group,
            index_start,
            coarse,
            face_layer,
            bytes,
            mesh_bytes: bytes - tex_bytes,
        }
    }

    /// Whether the uploaded texture of a view has the view's shape (face size, layers, levels).
    fn texture_fits(g: &GpuView, view: &RefView) -> bool {
        let size = g.texture.size();
        size.width == view.face_size
            && size.depth_or_array_layers == view.layers.len().max(1) as u32
            && g.texture.mip_level_count()
                == view.layers.first().map_or(1, |l| l.levels.len()) as u32
    }

    fn ensure_view(&mut self, view: &RefView) {
        let state = self.views.get(&view.index).map(|g| {
            (
                Self::texture_fits(g, view),
                g.face_layer.len() == view.tiles.len(),
            )
        });
        match state {
            Some((true, true)) => return,
            // Tiles joined (or left): new meshes over the same texture, whose changed
            // regions the caller wrote with `update_layer_region`.
            Some((true, false)) => {
                let Some(old) = self.views.remove(&view.index) else {
                    return;
                };
                let tex_bytes = old.bytes - old.mesh_bytes;
                let g = self.upload_meshes(view, old.texture, tex_bytes);
                self.views.insert(view.index, g);
            }
            _ => {
                let g = self.upload(view);
                self.views.insert(view.index, g);
            }
        }
        self.composite_groups.clear();
    }

    /// Write the texels of `rects` (per mip level, as [`crate::texture::Layer::update_region`]
    /// returns them) of layer `layer` of an uploaded view from `view.layers[layer]`: what
    /// changes when one tile arrives, without re-uploading the view. Returns `false` when the
    /// view is not uploaded with this shape (the next draw then uploads it whole anyway).
    /// When tiles joined the view, the next draw rebuilds its meshes only.
    pub fn update_layer_region(
        &mut self,
        view: &RefView,
        layer: usize,
        rects: &[crate::texture::FaceRect],
    ) -> bool {
        let (Some(g), Some(src)) = (self.views.get(&view.index), view.layers.get(layer)) else {
            return false;
        };
        if !Self::texture_fits(g, view) {
            return false;
        }
        for (level, (r, map)) in rects.iter().zip(&src.levels).enumerate() {
            let m = map.face_size();
            let (x1, y1) = (r.x1.min(m), r.y1.min(m));
            if r.x0 >= x1 || r.y0 >= y1 {
                continue;
            }
            let data: Vec<[u8; 4]> = (r.y0..y1)
                .flat_map(|y| (r.x0..x1).map(move |x| *map.get(r.face, x, y)))
                .collect();
            self.gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &g.texture,
                    mip_level: level as u32,
                    origin: wgpu::Origin3d {
                        x: r.x0,
                        y: r.face.index() as u32 * m + r.y0,
                        z: layer as u32,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                bytemuck::cast_slice(&data),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * (x1 - r.x0)),
                    rows_per_image: Some(y1 - r.y0),
                },
                wgpu::Extent3d {
                    width: x1 - r.x0,
                    height: y1 - r.y0,
                    depth_or_array_layers: 1,
                },
            );
        }
        true
    }

    fn ensure_targets(&mut self, width: u32, height: u32) -> Result<(), GpuError> {
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if width > limit || height > limit {
            return Err(GpuError::TooLarge {
                width,
                height,
                limit,
            });
        }
        if matches!(&self.targets, Some(t) if t.width == width && t.height == height) {
            return Ok(());
        }
        let device = &self.gpu.device;
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let tex = |label, format, usage| {
            let unorm = [wgpu::TextureFormat::Rgba8Unorm];
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: if format == OUTPUT_FORMAT { &unorm } else { &[] },
            })
        };
        let view_usage =
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let views = [
            tex("view 0", VIEW_FORMAT, view_usage),
            tex("view 1", VIEW_FORMAT, view_usage),
        ];
        let depth = tex(
            "depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let output = tex(
            "output",
            OUTPUT_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let id_usage = wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC;
        let id_views = [
            tex("ids 0", ID_FORMAT, id_usage).create_view(&Default::default()),
            tex("ids 1", ID_FORMAT, id_usage).create_view(&Default::default()),
        ];
        let view_views = [
            views[0].create_view(&Default::default()),
            views[1].create_view(&Default::default()),
        ];
        let dist_view =
            tex("first view distance", DIST_FORMAT, view_usage).create_view(&Default::default());
        let group = |view: &wgpu::TextureView| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("second view"),
                layout: &self.second_bgl,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.composite_uniforms.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(view),
                    },
                ],
            })
        };
        let second_group = group(&dist_view);
        let half_tex = |label, format, usage| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: width.div_ceil(2),
                        height: height.div_ceil(2),
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let half_view = half_tex("second view (half resolution)", VIEW_FORMAT, view_usage);
        let half_depth = half_tex(
            "depth (half resolution)",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let half_group = group(&half_view);
        self.composite_groups.clear();
        self.targets = Some(Targets {
            width,
            height,
            dist_view,
            second_group,
            half_view,
            half_depth,
            half_group,
            depth_view: depth.create_view(&Default::default()),
            output_view: output.create_view(&Default::default()),
            output_view_unorm: output.create_view(&wgpu::TextureViewDescriptor {
                format: Some(wgpu::TextureFormat::Rgba8Unorm),
                ..Default::default()
            }),
            view_views,
            id_views,
            output,
        });
        Ok(())
    }

    /// Upload what `plan` needs (views, targets, tile info, composite bind group).
    fn prepare(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        for p in &plan.passes {
            let v = views
                .get(p.view)
                .ok_or(GpuError::MissingView(p.view, views.len()))?;
            self.ensure_view(v);
        }
        self.ensure_targets(plan.width, plan.height)?;
        for p in &plan.passes {
            self.update_tile_info(p, &views[p.view]);
        }
        self.prepare_composite(plan, views);
        Ok(())
    }

    /// Throughput: `frames` frames of `plan` submitted back to back with one wait at the
    /// end (as a window's frames overlap), and, where the adapter has timestamp queries
    /// (`TIMESTAMP_QUERY` and `TIMESTAMP_QUERY_INSIDE_ENCODERS`), the GPU time of each
    /// frame's commands. At most 2000 frames.
    pub fn throughput(
        &mut self,
        plan: &FramePlan,
        views: &[RefView],
        frames: usize,
    ) -> Result<Throughput, GpuError> {
        self.prepare(plan, views)?;
        self.timed_frames(frames, |enc| self.encode(enc, plan, views))
    }

    /// `frames` frames recorded by `encode`, submitted back to back, one wait; timestamps
    /// around each where the device has them.
    fn timed_frames(
        &self,
        frames: usize,
        encode: impl Fn(&mut wgpu::CommandEncoder),
    ) -> Result<Throughput, GpuError> {
        let frames = frames.clamp(1, 2000);
        let device = &self.gpu.device;
        let queries = device.features().contains(TIMESTAMPS).then(|| {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("frame timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * frames as u32,
            })
        });
        let t0 = std::time::Instant::now();
        for i in 0..frames as u32 {
            let mut enc = device.create_command_encoder(&Default::default());
            if let Some(q) = &queries {
                enc.write_timestamp(q, 2 * i);
            }
            encode(&mut enc);
            if let Some(q) = &queries {
                enc.write_timestamp(q, 2 * i + 1);
            }
            self.gpu.queue.submit([enc.finish()]);
        }
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let wall_ms = t0.elapsed().as_secs_f64() * 1e3 / frames as f64;
        let gpu_ms = match &queries {
            Some(q) => {
                let size = 16 * frames as u64;
                let resolved = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamps"),
                    size,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                });
                let mut enc = device.create_command_encoder(&Default::default());
                enc.resolve_query_set(q, 0..2 * frames as u32, &resolved, 0);
                let words = self.read_buffer(enc, &resolved)?;
                let period = self.gpu.queue.get_timestamp_period() as f64;
                let mut ms: Vec<f64> = words
                    .chunks_exact(4)
                    .map(|w| {
                        let t = |lo: u32, hi: u32| (hi as u64) << 32 | lo as u64;
                        t(w[2], w[3]).saturating_sub(t(w[0], w[1])) as f64 * period / 1e6
                    })
                    .collect();
                ms.sort_by(f64::total_cmp);
                ms.get(ms.len() / 2).copied()
            }
            None => None,
        };
        Ok(Throughput { wall_ms, gpu_ms })
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
        if plan.overlays == Overlays::default() && (!ids || plan.half_res_second) {
            if ids {
                // A feedback frame with the half-resolution second view: tile ids from the
                // view passes, the image as on the other frames (no flicker every few
                // frames).
                self.encode_view_passes(enc, targets, plan, views, true, false);
            }
            self.encode_fused(enc, targets, plan, views);
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

    /// Fused frames (no tile ids, no overlays): the first view straight into the output and
    /// its distance target, then the second view blended into the output against the first
    /// view's depth (`render.wgsl`); no view targets, no composite pass.
    fn encode_fused(
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
        if plan.half_res_second && passes.len() == 2 {
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
            let first_targets = [clear(&targets.output_view), clear(&targets.dist_view)];
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
                    view: &targets.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: if slot == 0 {
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
            }
            if !pass.runs.is_empty() {
                rp.set_pipeline(if slot == 0 {
                    &self.first_mesh
                } else if pass.weight < SECOND_VIEW_MIN_WEIGHT {
                    &self.second_mesh_holes
                } else {
                    &self.second_mesh
                });
                self.draw_runs(&mut rp, plan, pass, g);
            }
            rp.set_pipeline(if slot == 0 {
                &self.first_sky
            } else {
                &self.second_sky
            });
            rp.draw(0..3, 0..1);
        }
    }

    /// Fused frame with the second view at half resolution ([`FramePlan::half_res_second`]):
    /// the view with the smaller weight is drawn first at half the width and height into
    /// its own target (colour + distance), then the other view at full resolution writes
    /// every output pixel (meshes, then its background where no mesh drew), blending in the
    /// half-resolution view's nearest texel (`blend_half` in `render.wgsl`).
    fn encode_half(
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
                rp.set_pipeline(&self.mesh);
                self.draw_runs(&mut rp, plan, half.0, half.1);
            }
            rp.set_pipeline(&self.background);
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
            rp.set_pipeline(&self.mesh_over_half);
            self.draw_runs(&mut rp, plan, full.0, full.1);
        }
        rp.set_pipeline(&self.background_over_half);
        rp.draw(0..3, 0..1);
    }

    /// Draw a pass's tile runs (vertex and index buffers of the plan's mesh level); the
    /// pipeline and bind groups are set.
    fn draw_runs(
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
        let (w, h) = self
            .targets
            .as_ref()
            .map_or((1, 1), |t| (t.width, t.height));
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

    /// [`Renderer::throughput`] of the plain panorama ([`Renderer::draw_panorama`]).
    pub fn throughput_panorama(
        &mut self,
        plan: &FramePlan,
        views: &[RefView],
        frames: usize,
    ) -> Result<Throughput, GpuError> {
        self.prepare_panorama(plan, views)?;
        self.timed_frames(frames, |enc| self.encode_panorama(enc, plan, views))
    }

    fn prepare_panorama(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        let pass = plan.passes.first().ok_or(GpuError::MissingView(0, 0))?;
        let v = views
            .get(pass.view)
            .ok_or(GpuError::MissingView(pass.view, views.len()))?;
        self.ensure_view(v);
        self.ensure_targets(plan.width, plan.height)
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

    /// Copy the internal output target to the CPU.
    pub fn read_output(&self) -> Result<Frame, GpuError> {
        let t = self
            .targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing drawn yet".into()))?;
        let (w, h) = (t.width, t.height);
        let bpr = (w * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let device = &self.gpu.device;
        let buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: (bpr * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = device.create_command_encoder(&Default::default());
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &t.output,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(bpr),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        self.gpu.queue.submit([enc.finish()]);
        let slice = buf.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            // The receiver outlives the poll below; a send error cannot happen.
            tx.send(r).ok();
        });
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let mut rgba = Vec::with_capacity((w * h * 4) as usize);
        for row in 0..h as usize {
            let start = row * bpr as usize;
            rgba.extend_from_slice(&data[start..start + 4 * w as usize]);
        }
        Ok(Frame {
            width: w,
            height: h,
            rgba,
        })
    }

    /// Visible pixels per tile of every view pass of the last [`Renderer::draw`] (tile-id
    /// targets counted by a compute pass with atomics); `plan` must be the plan drawn, with
    /// [`FramePlan::tile_ids`] set.
    pub fn feedback(
        &self,
        plan: &FramePlan,
        views: &[RefView],
    ) -> Result<Vec<crate::feedback::ViewCounts>, GpuError> {
        let t = self
            .targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing drawn yet".into()))?;
        let mut out = Vec::new();
        for (slot, pass) in plan.passes.iter().take(2).enumerate() {
            if !self.ids_valid[slot] {
                return Err(GpuError::Readback(
                    "the last frame drew no tile ids (FramePlan::tile_ids was off)".into(),
                ));
            }
            let Some((v, g)) = views
                .get(pass.view)
                .and_then(|v| Some((v, self.views.get(&v.index)?)))
            else {
                return Err(GpuError::MissingView(pass.view, views.len()));
            };
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            self.encode_counts(&mut enc, &t.id_views[slot], g);
            let mut pixels: Vec<u32> = self.read_buffer(enc, &g.counts)?;
            pixels.truncate(v.tiles.len());
            out.push(crate::feedback::ViewCounts {
                view: pass.view,
                pixels,
            });
        }
        Ok(out)
    }

    /// The tile drawn at every pixel (row-major from the top; tile index + 1, 0 = none) by
    /// view pass `slot` (0 or 1) of the last [`Renderer::draw`], which must have written tile
    /// ids.
    pub fn read_tile_ids(&self, slot: usize) -> Result<Vec<u32>, GpuError> {
        let t = self
            .targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing drawn yet".into()))?;
        if !self.ids_valid.get(slot).copied().unwrap_or(false) {
            return Err(GpuError::Readback(format!(
                "the last frame wrote no tile ids for view pass {slot}"
            )));
        }
        let texture = t.id_views[slot].texture();
        let (w, h) = (t.width, t.height);
        let bpr = (w * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buf = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ids readback"),
            size: (bpr * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(bpr),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        let rows: Vec<u32> = self.map_read(enc, &buf)?;
        let stride = (bpr / 4) as usize;
        Ok((0..h as usize)
            .flat_map(|y| rows[y * stride..y * stride + w as usize].iter().copied())
            .collect())
    }

    /// Copy a storage buffer out (after the commands in `enc`) and read it as `u32`s.
    fn read_buffer(
        &self,
        mut enc: wgpu::CommandEncoder,
        src: &wgpu::Buffer,
    ) -> Result<Vec<u32>, GpuError> {
        let size = src.size();
        let readback = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        enc.copy_buffer_to_buffer(src, 0, &readback, 0, size);
        self.map_read(enc, &readback)
    }

    /// Submit `enc`, wait, and read the mappable buffer `buf` as `u32`s.
    fn map_read(
        &self,
        enc: wgpu::CommandEncoder,
        buf: &wgpu::Buffer,
    ) -> Result<Vec<u32>, GpuError> {
        self.gpu.queue.submit([enc.finish()]);
        let slice = buf.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            // The receiver outlives the poll below; a send error cannot happen.
            tx.send(r).ok();
        });
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        Ok(bytemuck::cast_slice(&data[..]).to_vec())
    }

    /// Draw a plan and read it back.
    pub fn render(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<Frame, GpuError> {
        self.draw(plan, views)?;
        self.read_output()
    }
}
