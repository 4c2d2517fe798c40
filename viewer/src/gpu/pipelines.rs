//! The renderer's pipelines, bind group layouts and shared resources.

use std::collections::HashMap;

use super::{
    shader_source, CompositeUniforms, Gpu, GpuError, GpuVertex, Renderer, DEPTH_FORMAT,
    FALLBACK_VIEW_FORMAT, ID_FORMAT, NEARER_ONLY, OUTPUT_FORMAT, SECOND_VIEW_DEPTH_SCALE,
    VIEW_FORMAT,
};

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
                // Per-tile info, read per vertex.
                wgpu::BindGroupLayoutEntry {
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ..uint_texture_entry(3)
                },
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
                uint_texture_entry(5),
                uint_texture_entry(6),
                uint_texture_entry(7),
                uint_texture_entry(8),
            ],
        });
        let second_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("second view"),
            entries: &[
                uniform_entry(0),
                texture_entry(1, wgpu::TextureViewDimension::D2),
                // The first view's depth (a copy), for the second view's blend weights: a
                // depth texture read as unfilterable float (texel loads only).
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let render = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shader_source(include_str!("../render.wgsl")).into()),
        });
        let composite_src = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("composite.wgsl"),
            source: wgpu::ShaderSource::Wgsl(
                shader_source(include_str!("../composite.wgsl")).into(),
            ),
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
        let id_targets = [target(view_format), target(ID_FORMAT)];
        let color_targets = [target(view_format)];
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
                    // Both stages: the second view's fragments undo `depth_scale`.
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants,
                        ..Default::default()
                    },
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
        // Feedback frames: tile ids only (depth + R32), usually at reduced resolution.
        let id_only_targets = [target(ID_FORMAT)];
        let mesh_id_only = mk(
            "mesh ids only",
            &render,
            &view_layout,
            "vs_mesh",
            "fs_mesh_id_only",
            &mesh_buffers,
            &id_only_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        // Composite frames with overlays but no tile ids (the hole overlay): the first view's
        // sky writes depth, the second view is drawn against the first view's depth (see
        // `depth_scale` in render.wgsl).
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
        // Fused frames: the first view writes the output alone (no blending; the second view
        // reads its depth). A one-view frame's sky at the far plane (depth 0, the clear value)
        // after the meshes, no depth write and no `discard`, so the depth test skips covered
        // blocks before shading.
        let first_targets = [target(OUTPUT_FORMAT)];
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
            "one-view sky (fused)",
            &render,
            &view_layout,
            "vs_full",
            "fs_sky_first",
            &[],
            &first_targets,
            depth(wgpu::CompareFunction::GreaterEqual, false),
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
        let two_view_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("two views"),
            bind_group_layouts: &[Some(&view_bgl), Some(&second_bgl), Some(&view_bgl)],
            immediate_size: 0,
        });
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
        let second_mesh_at_sample = mk(
            "second view mesh at a sample (fused)",
            &render,
            &two_view_layout,
            "vs_mesh",
            "fs_mesh_second_at_sample",
            &mesh_buffers,
            &second_targets,
            depth(wgpu::CompareFunction::Greater, true),
            &[("depth_scale", 1.0 / NEARER_ONLY)],
        );
        // The two-view sky (see `fs_sky_heavier` in render.wgsl): the heavier view's sky at
        // SKY_DEPTH where it has sky, then the other view's where the depth is still clear.
        let sky_heavier = mk(
            "sky of the heavier of two views (fused)",
            &render,
            &two_view_layout,
            "vs_sky_depth",
            "fs_sky_heavier",
            &[],
            &output_target,
            depth(wgpu::CompareFunction::Greater, true),
            &[],
        );
        let sky_other = mk(
            "sky of the other view (fused)",
            &render,
            &two_view_layout,
            "vs_full",
            "fs_sky_other",
            &[],
            &output_target,
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
        // Devices without depth copies: the first view's depth (bound as in the second
        // view's pass) written into the attached depth, every pixel; the output untouched.
        let depth_only = [Some(wgpu::ColorTargetState {
            format: OUTPUT_FORMAT,
            blend: None,
            write_mask: wgpu::ColorWrites::empty(),
        })];
        let copy_depth = mk(
            "first view's depth, copied by a shader",
            &render,
            &second_layout,
            "vs_full",
            "fs_copy_depth",
            &[],
            &depth_only,
            depth(wgpu::CompareFunction::Always, true),
            &[],
        );
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
            first_mesh,
            first_sky,
            second_mesh,
            second_mesh_holes,
            second_mesh_at_sample,
            sky_heavier,
            sky_other,
            mesh_over_half,
            background_over_half,
            mesh_ids,
            mesh_id_only,
            mesh,
            panorama,
            composite,
            composite_overlays,
            background_ids,
            background,
            sky_depth,
            mesh_behind,
            copy_depth,
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
