//! The renderer's pipelines, bind group layouts and shared resources.
//!
//! Every render pipeline is a row of [`PIPELINES`] (shader entry points, bind groups,
//! vertex input, colour targets with their blending, depth test, the second view's
//! `depth_scale`), and [`Renderer::new`] builds them all with one function,
//! [`build_pipeline`]. The bind group layouts are lists of [`Binding`]s likewise.

use std::collections::HashMap;

use super::{
    shader_source, CompositeUniforms, Gpu, GpuError, GpuVertex, Renderer, DEPTH_FORMAT,
    FALLBACK_VIEW_FORMAT, ID_FORMAT, NEARER_ONLY, OUTPUT_FORMAT, SECOND_VIEW_DEPTH_SCALE,
    VIEW_FORMAT,
};

use wgpu::CompareFunction::{Always, Equal, Greater, GreaterEqual};

/// The renderer's render pipelines, each built from its row of [`PIPELINES`] and fetched
/// with [`Renderer::pipeline`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pipe {
    /// Background (sky) where no tile drew, with the tile-id target. Drawn after the meshes
    /// at depth 0 (the reversed-Z far plane, the clear value): only pixels no mesh covered
    /// pass, and the rasteriser skips the shader on covered blocks.
    BackgroundIds,
    /// Background (sky) where no tile drew, colour only.
    Background,
    /// Tile meshes writing colour and tile ids.
    MeshIds,
    /// Tile meshes writing tile ids only (feedback frames without overlays, usually at
    /// reduced resolution).
    MeshIdOnly,
    /// Composite frames with overlays but no tile ids (the hole overlay): the first view's
    /// sky writing depth; the second view's meshes are then drawn against the first view's
    /// depth ([`Pipe::MeshBehind`], see `depth_scale` in render.wgsl).
    SkyDepth,
    MeshBehind,
    /// Tile meshes writing colour only.
    Mesh,
    /// Fused frames: the first view's meshes write the output alone (no blending; the
    /// second view reads their depth).
    FirstMesh,
    /// A one-view fused frame's sky at the far plane (depth 0, the clear value) after the
    /// meshes, no depth write and no `discard`, so the depth test skips covered blocks
    /// before shading.
    FirstSky,
    /// Fused frames: the second view blended into the output against the first view's
    /// depth.
    SecondMesh,
    /// The second view only where it is clearly nearer than the first view or the first
    /// view has sky or a hole (weight below `SECOND_VIEW_MIN_WEIGHT`).
    SecondMeshHoles,
    /// The same at a sample (weight 0): only where the first view has neither a mesh nor sky.
    SecondMeshAtSample,
    /// The sky of a two-view fused frame, after both views' meshes (see `fs_sky_heavier` in
    /// render.wgsl): the heavier view's where it has sky, at SKY_DEPTH (writing depth), then
    /// the other view's where the depth is still clear ([`Pipe::SkyOther`]; the sky is at
    /// infinity, the same from both viewpoints).
    SkyHeavier,
    SkyOther,
    /// Half-resolution second view: the first view drawn over it, blending it in.
    MeshOverHalf,
    BackgroundOverHalf,
    /// The plain panorama (one cube map, no slabs, no blending).
    Panorama,
    /// The composite pass, without and with the debug overlays.
    Composite,
    CompositeOverlays,
    /// Devices without depth copies: the first view's depth (bound as in the second view's
    /// pass) written into the attached depth, every pixel; the output untouched
    /// (`fs_copy_depth`).
    CopyDepth,
    /// Last in every frame: pixels no view covers filled from the farther side (`fs_fill`),
    /// reading a copy of the output and of the final depth (group 1), the depth attached
    /// read-only and tested equal to the cleared 0 (only holes are shaded).
    Fill,
    /// The same on devices without depth copies: no depth attachment, the final depth
    /// itself read.
    FillUntested,
}

/// The shader module a pipeline's entry points are in.
#[derive(Clone, Copy, Debug)]
enum Shader {
    /// `render.wgsl` (after `cube.wgsl`): view passes and fused frames.
    Render,
    /// `composite.wgsl` (after `cube.wgsl`).
    Composite,
}

/// Bind groups of a pipeline.
#[derive(Clone, Copy, Debug)]
enum Layout {
    /// Group 0: a view (uniforms, layers, sampler, tile info).
    View,
    /// Group 0 a view, group 1 the second view's (composite uniforms, the half-resolution
    /// target, the first view's depth copy).
    Second,
    /// As [`Layout::Second`], and group 2 the other view.
    TwoViews,
    /// Group 0: the composite's (uniforms, view targets, tile ids, tile info, counts).
    Composite,
}

/// Colour targets of a pipeline.
#[derive(Clone, Copy, Debug)]
enum Targets {
    /// A view target (colour + distance).
    View,
    /// A view target and the tile-id target.
    ViewAndIds,
    /// The tile-id target alone.
    Ids,
    /// The output, written.
    Output,
    /// The output, the fragment blended in: colour β·src + (1 − β)·dst with β the
    /// fragment's alpha; alpha max(src, dst) (covered when either view covers).
    OutputBlended,
    /// The output attached but not written (a pass that writes depth only).
    OutputUntouched,
}

/// One render pipeline, as data.
#[derive(Clone, Copy, Debug)]
struct PipelineRow {
    pipe: Pipe,
    label: &'static str,
    shader: Shader,
    layout: Layout,
    /// Vertex and fragment entry points.
    vs: &'static str,
    fs: &'static str,
    /// Tile meshes (one vertex buffer of [`GpuVertex`]); otherwise a full-screen triangle.
    mesh: bool,
    targets: Targets,
    /// Depth test and whether it writes depth; `None`: no depth attachment.
    depth: Option<(wgpu::CompareFunction, bool)>,
    /// The override `depth_scale` of both stages (the second view's fragments undo it).
    depth_scale: Option<f64>,
}

const NEARER_ONLY_SCALE: f64 = 1.0 / NEARER_ONLY;

/// A full-screen pass of `render.wgsl` on one view.
const fn full(pipe: Pipe, label: &'static str, vs: &'static str, fs: &'static str) -> PipelineRow {
    PipelineRow {
        pipe,
        label,
        shader: Shader::Render,
        layout: Layout::View,
        vs,
        fs,
        mesh: false,
        targets: Targets::Output,
        depth: Some((GreaterEqual, false)),
        depth_scale: None,
    }
}

/// Tile meshes of one view, depth-tested and writing depth.
const fn mesh(pipe: Pipe, label: &'static str, fs: &'static str, targets: Targets) -> PipelineRow {
    PipelineRow {
        pipe,
        label,
        shader: Shader::Render,
        layout: Layout::View,
        vs: "vs_mesh",
        fs,
        mesh: true,
        targets,
        depth: Some((Greater, true)),
        depth_scale: None,
    }
}

/// Every render pipeline, in [`Pipe`] order.
const PIPELINES: [PipelineRow; 22] = [
    PipelineRow {
        targets: Targets::ViewAndIds,
        ..full(
            Pipe::BackgroundIds,
            "background+ids",
            "vs_full",
            "fs_background_ids",
        )
    },
    PipelineRow {
        targets: Targets::View,
        ..full(Pipe::Background, "background", "vs_full", "fs_background")
    },
    mesh(
        Pipe::MeshIds,
        "mesh+ids",
        "fs_mesh_ids",
        Targets::ViewAndIds,
    ),
    mesh(
        Pipe::MeshIdOnly,
        "mesh ids only",
        "fs_mesh_id_only",
        Targets::Ids,
    ),
    PipelineRow {
        targets: Targets::View,
        depth: Some((GreaterEqual, true)),
        ..full(
            Pipe::SkyDepth,
            "background (sky depth)",
            "vs_sky_depth",
            "fs_background_sky_depth",
        )
    },
    PipelineRow {
        depth_scale: Some(SECOND_VIEW_DEPTH_SCALE),
        ..mesh(
            Pipe::MeshBehind,
            "mesh (against the first view)",
            "fs_mesh",
            Targets::View,
        )
    },
    mesh(Pipe::Mesh, "mesh", "fs_mesh", Targets::View),
    mesh(
        Pipe::FirstMesh,
        "first view mesh (fused)",
        "fs_mesh_first",
        Targets::Output,
    ),
    PipelineRow {
        depth: Some((Greater, true)),
        ..full(
            Pipe::FirstSky,
            "one-view sky (fused)",
            "vs_sky_depth",
            "fs_sky_first",
        )
    },
    PipelineRow {
        layout: Layout::Second,
        depth_scale: Some(SECOND_VIEW_DEPTH_SCALE),
        ..mesh(
            Pipe::SecondMesh,
            "second view mesh (fused)",
            "fs_mesh_second",
            Targets::OutputBlended,
        )
    },
    PipelineRow {
        layout: Layout::Second,
        depth_scale: Some(NEARER_ONLY_SCALE),
        ..mesh(
            Pipe::SecondMeshHoles,
            "second view mesh, nearer only (fused)",
            "fs_mesh_second",
            Targets::OutputBlended,
        )
    },
    PipelineRow {
        layout: Layout::TwoViews,
        depth_scale: Some(NEARER_ONLY_SCALE),
        ..mesh(
            Pipe::SecondMeshAtSample,
            "second view mesh at a sample (fused)",
            "fs_mesh_second_at_sample",
            Targets::OutputBlended,
        )
    },
    PipelineRow {
        layout: Layout::TwoViews,
        depth: Some((Greater, true)),
        ..full(
            Pipe::SkyHeavier,
            "sky of the heavier of two views (fused)",
            "vs_sky_depth",
            "fs_sky_heavier",
        )
    },
    PipelineRow {
        layout: Layout::TwoViews,
        ..full(
            Pipe::SkyOther,
            "sky of the other view (fused)",
            "vs_full",
            "fs_sky_other",
        )
    },
    PipelineRow {
        layout: Layout::Second,
        ..mesh(
            Pipe::MeshOverHalf,
            "mesh over the half-resolution second view",
            "fs_mesh_over_half",
            Targets::Output,
        )
    },
    PipelineRow {
        layout: Layout::Second,
        depth: Some((Greater, true)),
        ..full(
            Pipe::BackgroundOverHalf,
            "background over the half-resolution second view",
            "vs_sky_depth",
            "fs_background_over_half",
        )
    },
    PipelineRow {
        depth: None,
        ..full(Pipe::Panorama, "panorama", "vs_full", "fs_panorama")
    },
    PipelineRow {
        shader: Shader::Composite,
        layout: Layout::Composite,
        depth: Some((Always, true)),
        ..full(Pipe::Composite, "composite", "vs_full", "fs_composite")
    },
    PipelineRow {
        shader: Shader::Composite,
        layout: Layout::Composite,
        depth: Some((Always, true)),
        ..full(
            Pipe::CompositeOverlays,
            "composite+overlays",
            "vs_full",
            "fs_composite_overlays",
        )
    },
    PipelineRow {
        layout: Layout::Second,
        targets: Targets::OutputUntouched,
        depth: Some((Always, true)),
        ..full(
            Pipe::CopyDepth,
            "first view's depth, copied by a shader",
            "vs_full",
            "fs_copy_depth",
        )
    },
    PipelineRow {
        layout: Layout::Second,
        depth: Some((Equal, false)),
        ..full(Pipe::Fill, "fill what no view covers", "vs_full", "fs_fill")
    },
    PipelineRow {
        layout: Layout::Second,
        depth: None,
        ..full(
            Pipe::FillUntested,
            "fill what no view covers (no depth copies)",
            "vs_full",
            "fs_fill",
        )
    },
];

/// One binding of a bind group layout, as data.
#[derive(Clone, Copy, Debug)]
enum Binding {
    /// A uniform buffer, read by both stages.
    Uniform,
    /// A filterable float texture, read per fragment.
    Texture(wgpu::TextureViewDimension),
    /// A filtering sampler.
    Sampler,
    /// A 2D unsigned-integer texture, read per fragment or, with `vertex`, per vertex too.
    Uint { vertex: bool },
    /// A 2D texture read as unfilterable float (texel loads only): a depth texture.
    Unfilterable,
}

/// A view: uniforms, its layers, their sampler, per-tile info (read per vertex).
const VIEW_GROUP: [Binding; 4] = [
    Binding::Uniform,
    Binding::Texture(wgpu::TextureViewDimension::D2Array),
    Binding::Sampler,
    Binding::Uint { vertex: true },
];

/// The composite pass: uniforms, the two view targets, the two tile-id targets, the two
/// views' tile info and their visible-pixel counts.
const COMPOSITE_GROUP: [Binding; 9] = [
    Binding::Uniform,
    Binding::Texture(wgpu::TextureViewDimension::D2),
    Binding::Texture(wgpu::TextureViewDimension::D2),
    Binding::Uint { vertex: false },
    Binding::Uint { vertex: false },
    Binding::Uint { vertex: false },
    Binding::Uint { vertex: false },
    Binding::Uint { vertex: false },
    Binding::Uint { vertex: false },
];

/// The second view of a fused frame: composite uniforms, the half-resolution target, and
/// the first view's depth (a copy) for the second view's blend weights.
const SECOND_GROUP: [Binding; 3] = [
    Binding::Uniform,
    Binding::Texture(wgpu::TextureViewDimension::D2),
    Binding::Unfilterable,
];

fn bind_group_layout(
    device: &wgpu::Device,
    label: &str,
    bindings: &[Binding],
) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
        .iter()
        .enumerate()
        .map(|(i, b)| binding_entry(i as u32, *b))
        .collect();
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    })
}

fn binding_entry(binding: u32, b: Binding) -> wgpu::BindGroupLayoutEntry {
    let texture = |sample_type, view_dimension| wgpu::BindingType::Texture {
        sample_type,
        view_dimension,
        multisampled: false,
    };
    let (vertex, ty) = match b {
        Binding::Uniform => (
            true,
            wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
        ),
        Binding::Texture(dim) => (
            false,
            texture(wgpu::TextureSampleType::Float { filterable: true }, dim),
        ),
        Binding::Sampler => (
            false,
            wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
        ),
        Binding::Uint { vertex } => (
            vertex,
            texture(
                wgpu::TextureSampleType::Uint,
                wgpu::TextureViewDimension::D2,
            ),
        ),
        Binding::Unfilterable => (
            false,
            texture(
                wgpu::TextureSampleType::Float { filterable: false },
                wgpu::TextureViewDimension::D2,
            ),
        ),
    };
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: if vertex {
            wgpu::ShaderStages::VERTEX_FRAGMENT
        } else {
            wgpu::ShaderStages::FRAGMENT
        },
        ty,
        count: None,
    }
}

/// What the rows of [`PIPELINES`] refer to: shader modules, pipeline layouts, and the
/// format of view targets on this device.
struct Shared<'a> {
    device: &'a wgpu::Device,
    render: wgpu::ShaderModule,
    composite: wgpu::ShaderModule,
    view: wgpu::PipelineLayout,
    second: wgpu::PipelineLayout,
    two_views: wgpu::PipelineLayout,
    composite_layout: wgpu::PipelineLayout,
    view_format: wgpu::TextureFormat,
}

impl<'a> Shared<'a> {
    fn new(
        device: &'a wgpu::Device,
        [view_bgl, second_bgl, composite_bgl]: [&wgpu::BindGroupLayout; 3],
        view_format: wgpu::TextureFormat,
    ) -> Shared<'a> {
        let module = |label, source: String| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            })
        };
        let layout = |label, groups: &[Option<&wgpu::BindGroupLayout>]| {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: groups,
                immediate_size: 0,
            })
        };
        Shared {
            device,
            render: module("render.wgsl", shader_source(include_str!("../render.wgsl"))),
            composite: module(
                "composite.wgsl",
                shader_source(include_str!("../composite.wgsl")),
            ),
            view: layout("view", &[Some(view_bgl)]),
            second: layout("second view", &[Some(view_bgl), Some(second_bgl)]),
            two_views: layout(
                "two views",
                &[Some(view_bgl), Some(second_bgl), Some(view_bgl)],
            ),
            composite_layout: layout("composite", &[Some(composite_bgl)]),
            view_format,
        }
    }

    fn color_targets(&self, targets: Targets) -> Vec<Option<wgpu::ColorTargetState>> {
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        match targets {
            Targets::View => vec![target(self.view_format)],
            Targets::ViewAndIds => vec![target(self.view_format), target(ID_FORMAT)],
            Targets::Ids => vec![target(ID_FORMAT)],
            Targets::Output => vec![target(OUTPUT_FORMAT)],
            Targets::OutputBlended => vec![Some(wgpu::ColorTargetState {
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
            })],
            Targets::OutputUntouched => vec![Some(wgpu::ColorTargetState {
                format: OUTPUT_FORMAT,
                blend: None,
                write_mask: wgpu::ColorWrites::empty(),
            })],
        }
    }
}

/// The render pipeline of one row of [`PIPELINES`].
fn build_pipeline(shared: &Shared<'_>, row: &PipelineRow) -> wgpu::RenderPipeline {
    let module = match row.shader {
        Shader::Render => &shared.render,
        Shader::Composite => &shared.composite,
    };
    let layout = match row.layout {
        Layout::View => &shared.view,
        Layout::Second => &shared.second,
        Layout::TwoViews => &shared.two_views,
        Layout::Composite => &shared.composite_layout,
    };
    let vertex_attrs = wgpu::vertex_attr_array![0 => Float32x2, 1 => Float32, 2 => Uint32];
    let mesh_buffers = [Some(wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<GpuVertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &vertex_attrs,
    })];
    let constants: Vec<(&str, f64)> = row
        .depth_scale
        .map(|scale| ("depth_scale", scale))
        .into_iter()
        .collect();
    let targets = shared.color_targets(row.targets);
    shared
        .device
        .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(row.label),
            layout: Some(layout),
            vertex: wgpu::VertexState {
                module,
                entry_point: Some(row.vs),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                buffers: if row.mesh { &mesh_buffers } else { &[] },
            },
            primitive: wgpu::PrimitiveState {
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: row.depth.map(|(compare, write)| wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(write),
                depth_compare: Some(compare),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module,
                entry_point: Some(row.fs),
                // Both stages: the second view's fragments undo `depth_scale`.
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                targets: &targets,
            }),
            multiview_mask: None,
            cache: None,
        })
}

impl Renderer {
    /// The renderer's pipelines on `gpu`, for what the device can do ([`super::Caps`]). An
    /// error wgpu reports while they are made (a shader the backend cannot translate, a
    /// limit) comes back as [`GpuError::Wgpu`] naming the adapter, the backend and the
    /// pipeline.
    pub fn new(gpu: Gpu) -> Result<Renderer, GpuError> {
        // Errors of an earlier user of the device are not ours.
        gpu.check("work on this device before the renderer")?;
        let view_format = if gpu.caps.float_targets {
            VIEW_FORMAT
        } else {
            FALLBACK_VIEW_FORMAT
        };
        let device = &gpu.device;
        let view_bgl = bind_group_layout(device, "view", &VIEW_GROUP);
        let composite_bgl = bind_group_layout(device, "composite", &COMPOSITE_GROUP);
        let second_bgl = bind_group_layout(device, "second view", &SECOND_GROUP);
        let shared = Shared::new(
            device,
            [&view_bgl, &second_bgl, &composite_bgl],
            view_format,
        );
        let pipelines = PIPELINES
            .iter()
            .enumerate()
            .map(|(i, row)| {
                debug_assert_eq!(row.pipe as usize, i, "PIPELINES out of Pipe order");
                build_pipeline(&shared, row)
            })
            .collect();
        let feedback = gpu.caps.compute.then(|| {
            let feedback_src = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("feedback.wgsl"),
                source: wgpu::ShaderSource::Wgsl(include_str!("../feedback.wgsl").into()),
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("feedback"),
                layout: None,
                module: &feedback_src,
                entry_point: Some("count"),
                compilation_options: Default::default(),
                cache: None,
            })
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("layers"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let composite_uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("composite"),
            size: std::mem::size_of::<CompositeUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.check("creating the renderer's pipelines")?;
        Ok(Renderer {
            gpu,
            view_bgl,
            composite_bgl,
            second_bgl,
            pipelines,
            feedback,
            view_format,
            sampler,
            composite_uniforms,
            views: HashMap::new(),
            targets: None,
            ids_valid: [false; 2],
            ids_scale: 1,
            skirts: true,
            composite_groups: HashMap::new(),
        })
    }

    /// The render pipeline `pipe` ([`PIPELINES`]).
    pub(super) fn pipeline(&self, pipe: Pipe) -> &wgpu::RenderPipeline {
        &self.pipelines[pipe as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pipeline_rows_are_in_pipe_order() {
        for (i, row) in PIPELINES.iter().enumerate() {
            assert_eq!(row.pipe as usize, i, "{:?}", row.pipe);
        }
    }

    #[test]
    fn mesh_pipelines_test_and_write_depth() {
        for row in PIPELINES.iter().filter(|r| r.mesh) {
            assert_eq!(row.vs, "vs_mesh", "{:?}", row.pipe);
            assert_eq!(row.depth, Some((Greater, true)), "{:?}", row.pipe);
        }
    }
}
