//! The device: adapter choice, the limits requested, what the device can do ([`Caps`], read
//! from the adapter's downlevel flags, format features and the device's limits, never
//! assumed), and the errors wgpu reports, turned into [`GpuError`]s that name the adapter,
//! the backend and what failed instead of wgpu's default (a panic).

use std::sync::{Arc, Mutex};

use super::{GpuError, TIMESTAMPS};

/// How long [`Gpu::wait`] waits for submitted work before it reports the GPU as stuck.
const GPU_WAIT_LIMIT: std::time::Duration = std::time::Duration::from_secs(600);

/// What the device can do, and so which paths the renderer takes. Every path gives the same
/// picture; a missing capability costs speed or a debug overlay, never a frame.
///
/// [`Gpu::new`] reads them from the adapter and the device. A caller may turn any of them off
/// before [`super::Renderer::new`] (tests do, to run the fallbacks on any machine): a renderer
/// then uses less of the device than it has, which is always valid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Caps {
    /// Compute shaders with storage buffers and atomics (`COMPUTE_SHADERS` and non-zero
    /// compute and storage limits; not on WebGL2-class devices): visible pixels per tile are
    /// counted on the GPU (`feedback.wgsl`). Without: the tile ids are read back and counted
    /// on the CPU.
    pub compute: bool,
    /// Copies of depth textures (`DEPTH_TEXTURE_AND_BUFFER_COPIES`; OpenGL ES and WebGL have
    /// none, and wgpu's GL backend copies through a colour attachment): a fused frame copies
    /// the first view's depth for the second view's blend weights. Without: the first view
    /// draws into a second depth texture and a full-screen pass writes its depth back into
    /// the one the second view is drawn against (`fs_copy_depth`).
    pub depth_copy: bool,
    /// Texture views in another format than the texture's (`VIEW_FORMATS`; not on GL): the
    /// output's plain-UNORM view for UIs that want the sRGB-encoded bytes undecoded. Without:
    /// [`super::Renderer::output_view_unorm`] is `None`; the window's copy encodes sRGB in its
    /// shader instead.
    pub view_formats: bool,
    /// `Rgba16Float` render targets (a view pass's colour + distance): the composite path
    /// (debug overlays) and the half-resolution second view. Without (OpenGL ES 3.0 without
    /// `EXT_color_buffer_half_float`): every frame is drawn fused at full resolution and
    /// overlays are not drawn.
    pub float_targets: bool,
}

impl Caps {
    /// Everything on (Vulkan, Metal, DX12 and desktop-class GL drivers have it all).
    pub const ALL: Caps = Caps {
        compute: true,
        depth_copy: true,
        view_formats: true,
        float_targets: true,
    };

    /// What `adapter` and a device with `limits` from it can do.
    pub fn of(adapter: &wgpu::Adapter, limits: &wgpu::Limits) -> Caps {
        let flags = adapter.get_downlevel_capabilities().flags;
        let renders = |f: wgpu::TextureFormat| {
            adapter
                .get_texture_format_features(f)
                .allowed_usages
                .contains(
                    wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
                )
        };
        Caps {
            compute: flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
                && limits.max_compute_workgroups_per_dimension > 0
                && limits.max_compute_invocations_per_workgroup >= 64
                && limits.max_compute_workgroup_size_x >= 8
                && limits.max_compute_workgroup_size_y >= 8
                && limits.max_storage_buffers_per_shader_stage > 0
                && limits.max_storage_buffer_binding_size > 0,
            depth_copy: flags.contains(wgpu::DownlevelFlags::DEPTH_TEXTURE_AND_BUFFER_COPIES),
            view_formats: flags.contains(wgpu::DownlevelFlags::VIEW_FORMATS),
            float_targets: renders(wgpu::TextureFormat::Rgba16Float),
        }
    }

    /// The capabilities that are off, by name (`"none"` when all are on).
    pub fn missing(&self) -> String {
        let off: Vec<&str> = [
            (self.compute, "compute"),
            (self.depth_copy, "depth copies"),
            (self.view_formats, "view formats"),
            (self.float_targets, "float render targets"),
        ]
        .into_iter()
        .filter(|(on, _)| !on)
        .map(|(_, name)| name)
        .collect();
        if off.is_empty() {
            "none".into()
        } else {
            off.join(", ")
        }
    }
}

/// The limits a device is asked for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceLimits {
    /// WebGPU's defaults where the adapter has them, else the downlevel (GLES 3.1-class)
    /// defaults, else the WebGL2-class ones; texture sizes always the adapter's.
    #[default]
    Best,
    /// WebGL2-class limits (no storage buffers, no compute; texture sizes the adapter's):
    /// what a GLES 3.0 driver offers, and what eframe asks of a GL adapter by default.
    WebGl2,
}

/// Which adapter and device [`Gpu::request`] asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpuRequest {
    /// Backends to search; `None`: `WGPU_BACKEND` if set, else every backend compiled in
    /// (Vulkan and GL on Linux).
    pub backends: Option<wgpu::Backends>,
    pub limits: DeviceLimits,
}

impl GpuRequest {
    /// One backend by the name `WGPU_BACKEND` takes (`vulkan`, `gl`, `metal`, `dx12`).
    pub fn for_backend(name: &str) -> Option<GpuRequest> {
        let backends = match name.to_ascii_lowercase().as_str() {
            "vulkan" | "vk" => wgpu::Backends::VULKAN,
            "gl" | "gles" | "opengl" => wgpu::Backends::GL,
            "metal" | "mtl" => wgpu::Backends::METAL,
            "dx12" | "d3d12" => wgpu::Backends::DX12,
            _ => return None,
        };
        Some(GpuRequest {
            backends: Some(backends),
            ..Default::default()
        })
    }
}

/// Errors wgpu reported on a device outside any error scope (validation, out of memory,
/// internal errors such as a shader a backend cannot translate, device loss), kept until the
/// renderer asks ([`Gpu::check`]).
#[derive(Clone, Default)]
struct ErrorSink(Arc<Mutex<Vec<String>>>);

impl ErrorSink {
    /// Keep the first few; later ones are usually consequences of the first.
    fn push(&self, message: String) {
        let mut v = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if v.len() < 4 {
            v.push(message);
        }
    }

    fn take(&self) -> Vec<String> {
        std::mem::take(&mut *self.0.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// Device and queue, with what they can do.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// What the renderer may use (turn capabilities off before [`super::Renderer::new`] to
    /// force a fallback).
    pub caps: Caps,
    errors: ErrorSink,
}

impl Gpu {
    /// The default adapter (`WGPU_BACKEND` may force `vulkan` or `gl`): a GPU where there is
    /// one, else Mesa's software drivers (lavapipe for Vulkan, llvmpipe for GL).
    pub fn new() -> Result<Gpu, GpuError> {
        Gpu::request(&GpuRequest::default())
    }

    /// An adapter of `request.backends` and a device with `request.limits`.
    pub fn request(request: &GpuRequest) -> Result<Gpu, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if let Some(b) = request.backends {
            desc.backends = b;
        }
        let backends = desc.backends;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| no_adapter(backends, &e.to_string()))?;
        let limits = device_limits(&adapter, request.limits);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("railview"),
            required_limits: limits.clone(),
            // Timestamps around frames for `Renderer::throughput`, where the adapter has them.
            required_features: adapter.features() & TIMESTAMPS,
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: describe_adapter(&adapter.get_info()),
            message: one_paragraph(&e.to_string()),
        })?;
        Ok(Gpu::from_device(device, queue, &adapter))
    }

    /// A device made elsewhere (the window's, by eframe): reads its capabilities and takes
    /// over its error reporting (wgpu's default panics on the first error).
    pub fn from_device(device: wgpu::Device, queue: wgpu::Queue, adapter: &wgpu::Adapter) -> Gpu {
        let errors = ErrorSink::default();
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            sink.push(one_paragraph(&e.to_string()));
        }));
        let sink = errors.clone();
        device.set_device_lost_callback(move |reason, message| {
            // Dropping the device reports a loss too; that is not an error.
            if reason != wgpu::DeviceLostReason::Destroyed {
                sink.push(one_paragraph(&format!(
                    "device lost ({reason:?}): {message}"
                )));
            }
        });
        let caps = Caps::of(adapter, &device.limits());
        Gpu {
            device,
            queue,
            info: adapter.get_info(),
            caps,
            errors,
        }
    }

    /// Wait until the GPU has finished everything submitted. wgpu's GL backend gives up a
    /// wait after 4.3 s (the largest timeout GL takes), which a software rasteriser on a busy
    /// machine can need for a few large frames: it waits again, up to `GPU_WAIT_LIMIT` in all.
    pub fn wait(&self, what: &str) -> Result<(), GpuError> {
        let start = std::time::Instant::now();
        loop {
            match self.device.poll(wgpu::PollType::wait_indefinitely()) {
                Ok(_) => return Ok(()),
                Err(wgpu::PollError::Timeout) if start.elapsed() < GPU_WAIT_LIMIT => {}
                Err(e) => {
                    return Err(GpuError::Wgpu {
                        what: what.to_string(),
                        adapter: self.describe(),
                        message: format!(
                            "waiting for the GPU: {e} (after {:.0} s)",
                            start.elapsed().as_secs_f64()
                        ),
                    })
                }
            }
        }
    }

    /// `llvmpipe (LLVM 15.0.6, 256 bits), GL backend`: the adapter and backend, for messages.
    pub fn describe(&self) -> String {
        describe_adapter(&self.info)
    }

    /// `Err` naming the adapter, the backend and `what` failed when wgpu reported an error on
    /// this device since the last check.
    pub fn check(&self, what: &str) -> Result<(), GpuError> {
        let errors = self.errors.take();
        if errors.is_empty() {
            return Ok(());
        }
        Err(GpuError::Wgpu {
            what: what.to_string(),
            adapter: self.describe(),
            message: errors.join("; then: "),
        })
    }
}

/// [`GpuError::NoAdapter`] after a search of `backends` failed with `detail` (wgpu's
/// reason, of which the backends it was not asked to search are left out).
pub fn no_adapter(backends: wgpu::Backends, detail: &str) -> GpuError {
    let detail = one_paragraph(detail);
    let reasons: Vec<&str> = detail
        .split("; ")
        .flat_map(|part| part.split(", "))
        .map(str::trim)
        .filter(|r| {
            !r.is_empty()
                && !r.ends_with("not requested")
                && !r.ends_with("not compiled in")
                && !r.starts_with("No suitable graphics adapter found")
        })
        .collect();
    GpuError::NoAdapter {
        backends: backend_names(backends & wgpu::Instance::enabled_backend_features()),
        detail: if reasons.is_empty() {
            detail.clone()
        } else {
            reasons.join("; ")
        },
        forced: std::env::var("WGPU_BACKEND").ok().filter(|v| !v.is_empty()),
    }
}

/// The limits to ask of `adapter`.
pub fn device_limits(adapter: &wgpu::Adapter, class: DeviceLimits) -> wgpu::Limits {
    let has = adapter.limits();
    let with_sizes = |l: wgpu::Limits| l.using_resolution(has.clone());
    match class {
        DeviceLimits::WebGl2 => with_sizes(wgpu::Limits::downlevel_webgl2_defaults()),
        DeviceLimits::Best => [
            wgpu::Limits::default(),
            wgpu::Limits::downlevel_defaults(),
            wgpu::Limits::downlevel_webgl2_defaults(),
        ]
        .into_iter()
        .map(with_sizes)
        .find(|l| l.check_limits(&has))
        // An adapter below WebGL2 is asked for what it has; the device request then says
        // what is missing.
        .unwrap_or(has),
    }
}

/// `llvmpipe (LLVM 15.0.6, 256 bits), GL backend`.
pub fn describe_adapter(info: &wgpu::AdapterInfo) -> String {
    let backend = match info.backend {
        wgpu::Backend::Vulkan => "Vulkan",
        wgpu::Backend::Gl => "GL",
        wgpu::Backend::Metal => "Metal",
        wgpu::Backend::Dx12 => "DX12",
        wgpu::Backend::BrowserWebGpu => "WebGPU",
        wgpu::Backend::Noop => "no-op",
    };
    let name = if info.name.is_empty() {
        "an unnamed adapter"
    } else {
        info.name.as_str()
    };
    format!("{name}, {backend} backend")
}

/// `Vulkan and GL` for a set of backends.
fn backend_names(b: wgpu::Backends) -> String {
    let names: Vec<&str> = [
        (wgpu::Backends::VULKAN, "Vulkan"),
        (wgpu::Backends::GL, "GL"),
        (wgpu::Backends::METAL, "Metal"),
        (wgpu::Backends::DX12, "DX12"),
        (wgpu::Backends::BROWSER_WEBGPU, "WebGPU"),
    ]
    .into_iter()
    .filter(|(flag, _)| b.contains(*flag))
    .map(|(_, n)| n)
    .collect();
    match names.len() {
        0 => "no backend".into(),
        1 => names[0].into(),
        n => format!("{} and {}", names[..n - 1].join(", "), names[n - 1]),
    }
}

/// wgpu's multi-line error text as one line: lines trimmed and joined with `: `.
pub fn one_paragraph(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(": ")
        .replace(":: ", ": ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_text_becomes_one_line() {
        let t = "Validation Error\n\nCaused by:\n  In Device::create_render_pipeline, label = 'x'\n    Internal error\n";
        assert_eq!(
            one_paragraph(t),
            "Validation Error: Caused by: In Device::create_render_pipeline, label = 'x': Internal error"
        );
    }

    #[test]
    fn no_adapter_keeps_the_reasons_of_the_backends_searched() {
        let e = no_adapter(
            wgpu::Backends::VULKAN,
            "No suitable graphics adapter found; noop not requested, vulkan drivers/libraries could not be loaded, metal not requested, gl not requested",
        );
        let GpuError::NoAdapter { detail, .. } = &e else {
            panic!("{e:?}")
        };
        assert_eq!(detail, "vulkan drivers/libraries could not be loaded");
        assert!(
            e.to_string()
                .contains("apt-get install mesa-vulkan-drivers"),
            "{e}"
        );
    }

    #[test]
    fn backends_by_name() {
        assert_eq!(backend_names(wgpu::Backends::VULKAN), "Vulkan");
        assert_eq!(
            backend_names(wgpu::Backends::VULKAN | wgpu::Backends::GL),
            "Vulkan and GL"
        );
        assert_eq!(backend_names(wgpu::Backends::empty()), "no backend");
    }

    #[test]
    fn missing_capabilities_by_name() {
        assert_eq!(Caps::ALL.missing(), "none");
        let gl = Caps {
            depth_copy: false,
            view_formats: false,
            ..Caps::ALL
        };
        assert_eq!(gl.missing(), "depth copies, view formats");
    }
}
