//! Showing the renderer's output in the window: a paint callback that copies it into egui's
//! render pass texel for pixel, or scales it up bilinearly where the frame-time budget drew
//! it smaller ([`crate::DrawBudget::render_scale`]).
//!
//! Shown as an egui image, the view went through egui's own shader, which handles every case
//! an image may need (filtering in the shader or the sampler, wrap modes, dithering); a
//! software rasteriser runs every branch of it for every pixel, and at 700×650 that cost
//! about 11 ms a frame on lavapipe. At full size the view's output has the size of the
//! rectangle it is shown in (the same rounding as the callback's viewport), so a copy needs
//! one texel load and no blending; each case has its own pipeline, no branch.

use eframe::egui;
use eframe::egui_wgpu::{self, wgpu};

/// The copy's pipeline, kept in egui's callback resources for the window's lifetime.
pub struct BlitResources {
    /// Texel for pixel.
    copy: wgpu::RenderPipeline,
    /// Bilinear, for an output smaller than the viewport.
    scale_up: wgpu::RenderPipeline,
    sampler: wgpu::Sampler,
    layout: wgpu::BindGroupLayout,
    /// Bind the output's sRGB view: the window's colour target is sRGB-encoding (decoded on
    /// load, encoded on store: the same bytes), or the device has no plain view of it and
    /// the pipelines encode. Otherwise its plain view (the stored bytes).
    bind_srgb: bool,
    /// This frame's output and whether it is scaled up (set by `prepare`).
    bind_group: Option<(wgpu::BindGroup, bool)>,
}

const SHADER: &str = r#"
@group(0) @binding(0) var view_image: texture_2d<f32>;
@group(0) @binding(1) var view_sampler: sampler;

struct Out {
    @builtin(position) pos: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

// One triangle over the whole viewport (the callback's rectangle); `uv` runs 0..1 across it.
@vertex
fn vs(@builtin(vertex_index) i: u32) -> Out {
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var o: Out;
    o.pos = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 0.0, 1.0);
    o.uv = uv;
    return o;
}

fn texel(uv: vec2<f32>) -> vec3<f32> {
    let size = vec2<i32>(textureDimensions(view_image));
    let at = clamp(vec2<i32>(uv * vec2<f32>(size)), vec2<i32>(0), size - vec2<i32>(1));
    return textureLoad(view_image, at, 0).rgb;
}

fn bilinear(uv: vec2<f32>) -> vec3<f32> {
    return textureSampleLevel(view_image, view_sampler, uv, 0.0).rgb;
}

@fragment
fn fs(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(texel(in.uv), 1.0);
}

@fragment
fn fs_scaled(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(bilinear(in.uv), 1.0);
}

// A plain (not sRGB-encoding) window target on a device without view formats: the output's
// sRGB view decodes on load, so encode again here (the same bytes up to rounding).
fn encode_srgb(c: vec3<f32>) -> vec3<f32> {
    let lo = c * 12.92;
    let hi = 1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(hi, lo, c <= vec3<f32>(0.0031308));
}

@fragment
fn fs_encode(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(encode_srgb(texel(in.uv)), 1.0);
}

@fragment
fn fs_scaled_encode(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(encode_srgb(bilinear(in.uv)), 1.0);
}
"#;

impl BlitResources {
    /// Build the pipeline for the window's colour target and keep it in egui's callback
    /// resources; `view_formats`: whether the renderer's output has a plain UNORM view
    /// ([`crate::gpu::Caps::view_formats`]).
    pub fn install(rs: &egui_wgpu::RenderState, view_formats: bool) {
        let device = &rs.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("view blit"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view blit"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("view blit"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("view blit"),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: rs.target_format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                primitive: wgpu::PrimitiveState::default(),
                // eframe's render pass: no depth buffer, no multisampling (the window's
                // defaults).
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                multiview_mask: None,
                cache: None,
            })
        };
        let srgb_target = rs.target_format.is_srgb();
        let encode = !srgb_target && !view_formats;
        let copy = pipeline(if encode { "fs_encode" } else { "fs" });
        let scale_up = pipeline(if encode {
            "fs_scaled_encode"
        } else {
            "fs_scaled"
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("view blit"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        rs.renderer
            .write()
            .callback_resources
            .insert(BlitResources {
                copy,
                scale_up,
                sampler,
                layout,
                bind_srgb: srgb_target || !view_formats,
                bind_group: None,
            });
    }
}

/// This frame's copy of the view: the renderer's output in its sRGB view (`srgb`) and its
/// plain view (`unorm`, where the device has one), the one matching the window's target is
/// bound; `scaled` where the output is smaller than the viewport.
pub struct BlitCallback {
    pub srgb: wgpu::TextureView,
    pub unorm: Option<wgpu::TextureView>,
    pub scaled: bool,
}

impl egui_wgpu::CallbackTrait for BlitCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        _queue: &wgpu::Queue,
        _screen: &egui_wgpu::ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        if let Some(r) = resources.get_mut::<BlitResources>() {
            let view = match &self.unorm {
                Some(unorm) if !r.bind_srgb => unorm,
                _ => &self.srgb,
            };
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("view blit"),
                layout: &r.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::Sampler(&r.sampler),
                    },
                ],
            });
            r.bind_group = Some((group, self.scaled));
        }
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        render_pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        let Some(r) = resources.get::<BlitResources>() else {
            return;
        };
        let Some((group, scaled)) = &r.bind_group else {
            return;
        };
        render_pass.set_pipeline(if *scaled { &r.scale_up } else { &r.copy });
        render_pass.set_bind_group(0, group, &[]);
        render_pass.draw(0..3, 0..1);
    }
}

/// The size in pixels of the viewport egui gives a paint callback over `rect` (the same
/// rounding as `egui::ViewportInPixels`, without the clamp to the screen).
pub fn viewport_px(rect: egui::Rect, pixels_per_point: f32) -> [u32; 2] {
    let px = |v: f32| (pixels_per_point * v).round() as i64;
    let w = (px(rect.max.x) - px(rect.min.x)).max(1);
    let h = (px(rect.max.y) - px(rect.min.y)).max(1);
    [w as u32, h as u32]
}

/// The size the view is drawn at for a viewport of `px` pixels at `scale` (at least 1×1).
pub fn drawn_px(px: [u32; 2], scale: f32) -> [u32; 2] {
    let s = if scale.is_finite() {
        scale.clamp(0.1, 1.0)
    } else {
        1.0
    };
    px.map(|v| ((v as f32 * s).round() as u32).clamp(1, v.max(1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viewport_size_rounds_the_edges_as_egui_does() {
        let r = egui::Rect::from_min_max(egui::pos2(10.3, 20.0), egui::pos2(110.6, 70.4));
        assert_eq!(viewport_px(r, 1.0), [101, 50]);
        assert_eq!(viewport_px(r, 1.5), [151, 76]);
        // An empty rectangle still gets one pixel (the renderer needs a target).
        let empty = egui::Rect::from_min_max(egui::pos2(5.0, 5.0), egui::pos2(5.0, 5.0));
        assert_eq!(viewport_px(empty, 2.0), [1, 1]);
    }

    #[test]
    fn the_drawn_size_scales_the_viewport_and_stays_inside_it() {
        assert_eq!(drawn_px([700, 650], 1.0), [700, 650]);
        assert_eq!(drawn_px([700, 650], 0.75), [525, 488]);
        assert_eq!(drawn_px([701, 651], 0.5), [351, 326]);
        assert_eq!(drawn_px([1, 1], 0.5), [1, 1]);
        assert_eq!(drawn_px([640, 360], f32::NAN), [640, 360]);
        assert_eq!(drawn_px([640, 360], 3.0), [640, 360]);
    }
}
