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
//!
//! Inside: `pipelines` (every render pipeline a row of one table, built by one function),
//! `passes` (what the passes of both paths share: attachments, view passes, mesh and
//! full-screen draws), `composite` (the composite path), `fused` (fused frames, the
//! half-resolution second view, the reduced tile-id passes), `upload` (views, targets),
//! `readback` and `device`.

use std::collections::HashMap;

use crate::plan::{FramePlan, Overlays};
use crate::refview::RefView;
use pipelines::Pipe;

pub use crate::frame::Frame;
pub use device::{
    describe_adapter, device_limits, no_adapter, Caps, DeviceLimits, Gpu, GpuRequest,
};

mod composite;
mod device;
mod fused;
mod passes;
mod pipelines;
mod readback;
mod upload;

/// Colour + distance of a view pass; where the device cannot render to it
/// ([`Caps::float_targets`]) the paths that need it are not taken, and their targets are made
/// in `FALLBACK_VIEW_FORMAT` only to keep every pipeline and bind group valid.
const VIEW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const FALLBACK_VIEW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// Texels per row of the per-tile textures (`TILE_ROW` in cube.wgsl): tile info
/// (`Rgba32Uint`) and visible-pixel counts (`R32Uint`, 1 KiB a row, a multiple of the
/// buffer-to-texture copy alignment).
const TILE_ROW: u32 = 256;
const TILE_INFO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;
const COUNTS_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
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

/// Errors of the GPU path. Every message names what failed; those from the device also name
/// the adapter and the backend.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    #[error(
        "no GPU adapter found ({backends}{}): {detail}. railview draws with wgpu, which needs a \
         Vulkan or OpenGL ES driver; without a GPU, Mesa's software drivers do: on Debian or \
         Ubuntu run `apt-get install mesa-vulkan-drivers libvulkan1` (Vulkan) or `apt-get \
         install libegl1 libegl-mesa0 libgl1-mesa-dri` (OpenGL ES), as root",
        forced_note(forced)
    )]
    NoAdapter {
        /// The backends searched (`Vulkan and GL`).
        backends: String,
        /// wgpu's reason.
        detail: String,
        /// `WGPU_BACKEND` when set.
        forced: Option<String>,
    },
    #[error("requesting a device from {adapter} failed: {message}")]
    Device { adapter: String, message: String },
    /// An error wgpu reported on the device (validation, a shader the backend cannot
    /// translate, out of memory, device loss).
    #[error("{what} failed on {adapter}: {message}")]
    Wgpu {
        what: String,
        adapter: String,
        message: String,
    },
    #[error("reading the frame back failed: {0}")]
    Readback(String),
    #[error("plan refers to view {0}, but only {1} views were given")]
    MissingView(usize, usize),
    #[error("image {width}x{height} exceeds the device limit {limit}")]
    TooLarge { width: u32, height: u32, limit: u32 },
    #[error("{0}")]
    Limit(String),
}

fn forced_note(forced: &Option<String>) -> String {
    match forced {
        Some(v) => format!("; WGPU_BACKEND={v} limits the search, unset it to try every backend"),
        None => String::new(),
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
    /// Overlay bits, tiles of view 0, tiles of view 1, unused.
    flags: [u32; 4],
}

/// Shader source: the shared cube-map helpers followed by `main`.
fn shader_source(main: &str) -> String {
    [include_str!("../cube.wgsl"), main].concat()
}

fn tex(v: &wgpu::TextureView) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::TextureView(v)
}

/// Rows of a per-tile texture for `tiles` tiles (at least one).
fn tile_rows(tiles: usize) -> u32 {
    (tiles.max(1) as u32).div_ceil(TILE_ROW)
}

/// Width and height of a per-tile texture for `tiles` tiles: `TILE_ROW` wide, or as wide as
/// the tiles where there are fewer (a view with nothing yet holds one texel).
fn tile_extent(tiles: usize) -> wgpu::Extent3d {
    wgpu::Extent3d {
        width: (tiles as u32).clamp(1, TILE_ROW),
        height: tile_rows(tiles),
        depth_or_array_layers: 1,
    }
}

/// One tile's entry of the tile-info texture (`tile_info` in `render.wgsl`).
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
    /// Per-tile info (`TILE_ROW` texels a row).
    tile_info: wgpu::Texture,
    tile_info_view: wgpu::TextureView,
    /// What `tile_info` holds now (rewritten only when a level or highlight changes).
    info: Vec<[u32; 4]>,
    /// Visible pixels per tile, counted by the compute pass (devices with
    /// [`Caps::compute`]), `TILE_ROW` a row.
    counts: Option<wgpu::Buffer>,
    /// The same counts as a texture, for the heat-map overlay.
    counts_tex: wgpu::Texture,
    counts_view: wgpu::TextureView,
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
    /// target unused, that copy). Without depth copies ([`Caps::depth_copy`]) the first view
    /// draws into this texture and a shader pass writes it into `depth`.
    depth_copy: wgpu::Texture,
    depth_copy_view: wgpu::TextureView,
    second_group: wgpu::BindGroup,
    /// Half-resolution second view: colour + distance, its depth, and the bind group 1 of
    /// the first view drawn over it.
    half_view: wgpu::TextureView,
    half_depth: wgpu::TextureView,
    half_group: wgpu::BindGroup,
    /// The fill pass (`fs_fill`): a copy of the output once both views are drawn, and the
    /// bind group 1 holding it and the final depth.
    fill_color: wgpu::Texture,
    fill_group: wgpu::BindGroup,
    output: wgpu::Texture,
    output_view: wgpu::TextureView,
    /// The same texels as plain UNORM (sRGB-encoded bytes), for UIs that expect them;
    /// `None` without [`Caps::view_formats`].
    output_view_unorm: Option<wgpu::TextureView>,
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
    /// Every render pipeline, in [`pipelines::Pipe`] order ([`Renderer::pipeline`]).
    pipelines: Vec<wgpu::RenderPipeline>,
    /// The visible-pixel count (devices with [`Caps::compute`]).
    feedback: Option<wgpu::ComputePipeline>,
    /// Colour + distance targets of view passes (`VIEW_FORMAT`, or a stand-in where the
    /// device cannot render to it and those passes are never drawn).
    view_format: wgpu::TextureFormat,
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
            self.ensure_view(v)?;
        }
        self.ensure_targets(plan.width, plan.height, plan.id_scale)?;
        for p in &plan.passes {
            self.update_tile_info(p, &views[p.view]);
        }
        self.prepare_composite(plan, views);
        Ok(())
    }

    /// Whether `plan` is drawn through view targets and the composite pass (frames with
    /// overlays, on devices that render to float targets); otherwise fused.
    fn composite_path(&self, plan: &FramePlan) -> bool {
        plan.overlays != Overlays::default() && self.gpu.caps.float_targets
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
        if self.composite_path(plan) && plan.overlays.heat && !self.gpu.caps.compute {
            // No compute: the heat map's counts come from the tile ids read back.
            self.draw_heat_on_cpu(enc, plan, views)?;
        } else {
            self.encode(&mut enc, plan, views);
            self.gpu.queue.submit([enc.finish()]);
        }
        let ids = plan.tile_ids || plan.overlays.needs_tile_ids();
        self.ids_valid = [ids && !plan.passes.is_empty(), ids && plan.passes.len() > 1];
        self.ids_scale = if self.composite_path(plan) {
            1
        } else {
            plan.id_scale.max(1)
        };
        self.gpu.wait("drawing a frame")?;
        self.gpu.check("drawing a frame")
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
        let rows = g.tile_info.height();
        let mut data = vec![[0u32; 4]; (rows * TILE_ROW) as usize];
        let n = g.info.len().min(data.len());
        data[..n].copy_from_slice(&g.info[..n]);
        self.gpu.queue.write_texture(
            g.tile_info.as_image_copy(),
            bytemuck::cast_slice(&data),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(16 * TILE_ROW),
                rows_per_image: Some(rows),
            },
            g.tile_info.size(),
        );
    }

    /// Encode the frame's passes into the internal output target. Views, targets and tile
    /// info must have been prepared ([`Renderer::draw`] does it).
    fn encode(&self, enc: &mut wgpu::CommandEncoder, plan: &FramePlan, views: &[RefView]) {
        let Some(targets) = &self.targets else {
            return;
        };
        let ids = plan.tile_ids || plan.overlays.needs_tile_ids();
        if !self.composite_path(plan) {
            // The picture as on frames without tile ids (no change every few frames), and
            // for feedback frames the tile ids in a cheap pass of their own, at
            // `1 / id_scale` resolution. Devices without float targets draw overlays' frames
            // so too, without the overlays.
            self.encode_fused(enc, targets, plan, views);
            if ids {
                self.encode_id_passes(enc, targets, plan, views);
            }
            return;
        }
        self.encode_composite_path(enc, targets, plan, views, ids);
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
        self.gpu.wait("drawing a panorama")?;
        self.gpu.check("drawing a panorama")
    }

    fn prepare_panorama(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<(), GpuError> {
        let pass = plan.passes.first().ok_or(GpuError::MissingView(0, 0))?;
        let v = views
            .get(pass.view)
            .ok_or(GpuError::MissingView(pass.view, views.len()))?;
        self.ensure_view(v)?;
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
        self.write_view_uniforms((pass, g));
        let mut rp = passes::begin(
            enc,
            "panorama",
            &[passes::color(&targets.output_view, true)],
            None,
        );
        rp.set_bind_group(0, &g.bind_group, &[]);
        self.draw_full(&mut rp, Pipe::Panorama);
    }

    /// The internal output target of the last draw (for showing it in a window).
    pub fn output_view(&self) -> Option<&wgpu::TextureView> {
        self.targets.as_ref().map(|t| &t.output_view)
    }

    /// The output target viewed as plain `Rgba8Unorm` (the sRGB-encoded bytes undecoded):
    /// what egui's renderer expects of a user texture. `None` before the first draw and on
    /// devices without [`Caps::view_formats`].
    pub fn output_view_unorm(&self) -> Option<&wgpu::TextureView> {
        self.targets.as_ref()?.output_view_unorm.as_ref()
    }

    /// Draw a plan and read it back.
    pub fn render(&mut self, plan: &FramePlan, views: &[RefView]) -> Result<Frame, GpuError> {
        self.draw(plan, views)?;
        self.read_output()
    }
}

/// Visible pixels per tile from a tile-id image (tile index + 1 per pixel, 0 = none): the
/// compute pass's count (`feedback.wgsl`) done on the CPU.
fn count_ids(ids: &[u32], tiles: usize) -> Vec<u32> {
    let mut counts = vec![0u32; tiles];
    for &t in ids {
        if let Some(c) = (t as usize).checked_sub(1).and_then(|i| counts.get_mut(i)) {
            *c += 1;
        }
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_counted_per_tile_and_unknown_ids_ignored() {
        assert_eq!(count_ids(&[0, 1, 1, 3, 9, 0], 3), vec![2, 0, 1]);
        assert_eq!(count_ids(&[], 2), vec![0, 0]);
    }

    #[test]
    fn per_tile_textures_have_a_row_per_256_tiles() {
        assert_eq!(tile_rows(0), 1);
        assert_eq!(tile_rows(256), 1);
        assert_eq!(tile_rows(257), 2);
        assert_eq!((tile_extent(0).width, tile_extent(0).height), (1, 1));
        assert_eq!((tile_extent(7).width, tile_extent(7).height), (7, 1));
        assert_eq!((tile_extent(300).width, tile_extent(300).height), (256, 2));
    }
}
