//! Uploads: a view's texture array and meshes, region updates of one layer, render targets.

use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::{
    tile_extent, tile_rows, GpuError, GpuVertex, GpuView, Renderer, Targets, COUNTS_FORMAT,
    DEPTH_FORMAT, ID_FORMAT, OUTPUT_FORMAT, TILE_INFO_FORMAT, TILE_ROW,
};
use tracks::PixelRect;

use crate::plan::ViewUniforms;
use crate::refview::stretch::{split_stretched, STRETCHED_BIT};
use crate::refview::{decimated_indices, mesh_cell, RefView, MESH_LEVELS};

impl Renderer {
    pub(super) fn upload(&self, view: &RefView) -> GpuView {
        let (texture, bytes) = self.upload_texture(view);
        let mut g = self.upload_meshes(view, texture, bytes);
        g.sky_whole = sky_whole(view);
        g
    }

    /// The view's texture array with every layer and level written; its bytes in GPU memory.
    pub(super) fn upload_texture(&self, view: &RefView) -> (wgpu::Texture, u64) {
        let device = &self.gpu.device;
        let n = texture_face_size(view);
        let layers = texture_layers(view);
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
        let bytes: u64 = (0..mips)
            .map(|l| 24 * u64::from((n >> l).max(1)).pow(2) * u64::from(layers))
            .sum();
        for (li, layer) in view.layers.iter().enumerate() {
            for (level, map) in layer.levels.iter().enumerate().take(mips as usize) {
                let m = map.face_size();
                let data: &[u8] = bytemuck::cast_slice(map.as_slice());
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
    pub(super) fn upload_meshes(
        &self,
        view: &RefView,
        texture: wgpu::Texture,
        tex_bytes: u64,
    ) -> GpuView {
        let mut bytes = tex_bytes;
        let device = &self.gpu.device;
        let MeshArrays {
            mut verts,
            mut idx,
            index_start,
            face_layer,
            coarse,
        } = mesh_arrays(view, self.skirts);
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
        let tiles = self.tile_textures(face_layer.len());
        bytes += tiles.bytes;
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view uniforms"),
            size: std::mem::size_of::<ViewUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = self.view_bind_group(&texture, &uniforms, &tiles.info_view);
        GpuView {
            texture,
            vertices,
            indices,
            tile_info: tiles.info,
            tile_info_view: tiles.info_view,
            info: Vec::new(),
            counts: tiles.counts,
            counts_view: tiles.counts_view,
            counts_tex: tiles.counts_tex,
            uniforms,
            bind_group,
            index_start,
            coarse,
            face_layer,
            bytes,
            mesh_bytes: bytes - tex_bytes,
            sky_whole: false,
        }
    }

    /// A view's per-tile textures (tile info, visible-pixel counts) for `tiles` tiles,
    /// `TILE_ROW` tiles a row (`ensure_view` checked the rows fit), and the counts' storage
    /// buffer on devices with compute.
    fn tile_textures(&self, tiles: usize) -> TileTextures {
        let device = &self.gpu.device;
        let rows = tile_rows(tiles);
        let extent = tile_extent(tiles);
        let per_tile = |label, format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: extent,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let info = per_tile(
            "tile info",
            TILE_INFO_FORMAT,
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        let counts_tex = per_tile(
            "tile counts",
            COUNTS_FORMAT,
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        let counts = self.gpu.caps.compute.then(|| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("tile counts"),
                size: u64::from(4 * rows * TILE_ROW),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        TileTextures {
            info_view: info.create_view(&Default::default()),
            info,
            counts_view: counts_tex.create_view(&Default::default()),
            counts_tex,
            counts,
            bytes: u64::from(extent.width * extent.height) * 20,
        }
    }

    /// A view's bind group 0: uniforms, its layers, the sampler, its tile info.
    fn view_bind_group(
        &self,
        texture: &wgpu::Texture,
        uniforms: &wgpu::Buffer,
        tile_info_view: &wgpu::TextureView,
    ) -> wgpu::BindGroup {
        let layers_view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
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
                        resource: wgpu::BindingResource::TextureView(tile_info_view),
                    },
                ],
            })
    }

    /// Whether the uploaded texture of a view has the view's shape (face size, layers, levels).
    pub(super) fn texture_fits(g: &GpuView, view: &RefView) -> bool {
        let size = g.texture.size();
        size.width == texture_face_size(view)
            && size.depth_or_array_layers == texture_layers(view)
            && g.texture.mip_level_count()
                == view.layers.first().map_or(1, |l| l.levels.len()) as u32
    }

    /// What a view needs of the device's limits: its texture array's size and layers, the
    /// rows of its per-tile textures.
    fn check_view_limits(&self, view: &RefView) -> Result<(), GpuError> {
        let l = self.gpu.device.limits();
        let n = texture_face_size(view);
        let layers = texture_layers(view);
        let rows = tile_rows(view.tiles.len());
        let over = |what: String, value: u64, limit: u32, name: &str| {
            GpuError::Limit(format!(
                "view {}: {what} ({value}) exceeds this device's limit {limit} ({name}) on {}",
                view.index,
                self.gpu.describe()
            ))
        };
        if u64::from(n) * 6 > u64::from(l.max_texture_dimension_2d) {
            return Err(over(
                format!(
                    "a texture of {n}×{} texels for its cube faces",
                    6 * u64::from(n)
                ),
                6 * u64::from(n),
                l.max_texture_dimension_2d,
                "max_texture_dimension_2d",
            ));
        }
        if layers > l.max_texture_array_layers {
            return Err(over(
                "texture layers (one per slab and the background)".into(),
                layers.into(),
                l.max_texture_array_layers,
                "max_texture_array_layers",
            ));
        }
        if rows > l.max_texture_dimension_2d {
            return Err(over(
                format!("{} tiles", view.tiles.len()),
                rows.into(),
                l.max_texture_dimension_2d,
                "max_texture_dimension_2d, rows of 256 tiles",
            ));
        }
        Ok(())
    }

    pub(super) fn ensure_view(&mut self, view: &RefView) -> Result<(), GpuError> {
        self.check_view_limits(view)?;
        let state = self.views.get(&view.index).map(|g| {
            (
                Self::texture_fits(g, view),
                g.face_layer.len() == view.tiles.len(),
            )
        });
        match state {
            Some((true, true)) => return Ok(()),
            // Tiles joined (or left): new meshes over the same texture, whose changed
            // regions the caller wrote with `update_layer_region`.
            Some((true, false)) => {
                let Some(old) = self.views.remove(&view.index) else {
                    return Ok(());
                };
                let tex_bytes = old.bytes - old.mesh_bytes;
                let mut g = self.upload_meshes(view, old.texture, tex_bytes);
                g.sky_whole = old.sky_whole;
                self.views.insert(view.index, g);
            }
            _ => {
                let g = self.upload(view);
                self.views.insert(view.index, g);
            }
        }
        self.composite_groups.clear();
        Ok(())
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
        rects: &[PixelRect],
    ) -> bool {
        let (Some(g), Some(src)) = (self.views.get_mut(&view.index), view.layers.get(layer)) else {
            return false;
        };
        if !Self::texture_fits(g, view) {
            return false;
        }
        if layer == 0 {
            g.sky_whole = sky_whole(view);
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

    /// Make the render targets for frames of `width × height` with tile ids at
    /// `1 / id_scale` of that, unless the current ones are so.
    pub(super) fn ensure_targets(
        &mut self,
        width: u32,
        height: u32,
        id_scale: u32,
    ) -> Result<(), GpuError> {
        let id_scale = id_scale.max(1);
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if width > limit || height > limit {
            return Err(GpuError::TooLarge {
                width,
                height,
                limit,
            });
        }
        if matches!(&self.targets, Some(t) if t.width == width && t.height == height && t.id_scale == id_scale)
        {
            return Ok(());
        }
        let targets = self.make_targets(width, height, id_scale);
        self.composite_groups.clear();
        self.targets = Some(targets);
        Ok(())
    }

    fn make_targets(&self, width: u32, height: u32, id_scale: u32) -> Targets {
        let device = &self.gpu.device;
        // The output also as plain UNORM where the device has view formats.
        let view_formats = self.gpu.caps.view_formats;
        let tex = |label, format, usage| {
            let unorm = format == OUTPUT_FORMAT && view_formats;
            target(device, label, (width, height), format, usage, unorm)
        };
        let view_format = self.view_format;
        let views = [
            tex("view 0", view_format, VIEW_USAGE),
            tex("view 1", view_format, VIEW_USAGE),
        ];
        // Read by the fill pass once the views are drawn (`fs_fill`).
        let depth = tex(
            "depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        // Written by a copy, or (without depth copies) drawn into by the first view.
        let depth_copy = tex(
            "first view depth (copy)",
            DEPTH_FORMAT,
            wgpu::TextureUsages::COPY_DST
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let depth_copy_view = depth_copy.create_view(&Default::default());
        let output = tex(
            "output",
            OUTPUT_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let id_views = [
            tex("ids 0", ID_FORMAT, ID_USAGE).create_view(&Default::default()),
            tex("ids 1", ID_FORMAT, ID_USAGE).create_view(&Default::default()),
        ];
        let view_views = [
            views[0].create_view(&Default::default()),
            views[1].create_view(&Default::default()),
        ];
        let half_size = (width.div_ceil(2), height.div_ceil(2));
        let half_view = target(
            device,
            "second view (half resolution)",
            half_size,
            view_format,
            VIEW_USAGE,
            false,
        )
        .create_view(&Default::default());
        let half_depth = target(
            device,
            "depth (half resolution)",
            half_size,
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
            false,
        )
        .create_view(&Default::default());
        let half_group = self.second_group(&half_view, &depth_copy_view);
        // The fill pass: a copy of the output and the final depth (`fs_fill`).
        let fill_color = target(
            device,
            "output (copy for the fill)",
            (width, height),
            OUTPUT_FORMAT,
            wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::TEXTURE_BINDING,
            false,
        );
        let depth_view = depth.create_view(&Default::default());
        // The fill reads a copy of the final depth where the device copies depth, else the
        // depth itself (not attached then).
        let fill_depth = if self.gpu.caps.depth_copy {
            &depth_copy_view
        } else {
            &depth_view
        };
        let fill_group =
            self.second_group(&fill_color.create_view(&Default::default()), fill_depth);
        // The fused second view reads the first view's depth, not binding 1.
        let second_group = self.second_group(&half_view, &depth_copy_view);
        Targets {
            width,
            height,
            depth_copy,
            depth_copy_view,
            second_group,
            half_view,
            half_depth,
            half_group,
            depth_view,
            depth,
            fill_color,
            fill_group,
            output_view: output.create_view(&Default::default()),
            output_view_unorm: view_formats.then(|| {
                output.create_view(&wgpu::TextureViewDescriptor {
                    format: Some(wgpu::TextureFormat::Rgba8Unorm),
                    ..Default::default()
                })
            }),
            view_views,
            id_views,
            output,
            id_scale,
            small: (id_scale > 1).then(|| small_targets(device, width, height, id_scale)),
        }
    }

    /// A bind group 1 of the second view's pipelines: composite uniforms, `view` (the
    /// half-resolution target), the first view's depth copy.
    fn second_group(
        &self,
        view: &wgpu::TextureView,
        depth_copy_view: &wgpu::TextureView,
    ) -> wgpu::BindGroup {
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
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
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(depth_copy_view),
                    },
                ],
            })
    }
}

/// Usage of the colour + distance targets of view passes.
const VIEW_USAGE: wgpu::TextureUsages =
    wgpu::TextureUsages::RENDER_ATTACHMENT.union(wgpu::TextureUsages::TEXTURE_BINDING);
/// Usage of tile-id targets.
const ID_USAGE: wgpu::TextureUsages = wgpu::TextureUsages::RENDER_ATTACHMENT
    .union(wgpu::TextureUsages::TEXTURE_BINDING)
    .union(wgpu::TextureUsages::COPY_SRC);

/// A 2D render target of `size`; with `unorm`, also viewable as plain `Rgba8Unorm`.
fn target(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
    unorm: bool,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: if unorm {
            &[wgpu::TextureFormat::Rgba8Unorm]
        } else {
            &[]
        },
    })
}

/// The reduced-resolution tile-id targets of feedback frames (`1 / id_scale` of the
/// frame's width and height) and their depth.
fn small_targets(
    device: &wgpu::Device,
    width: u32,
    height: u32,
    id_scale: u32,
) -> ([wgpu::TextureView; 2], wgpu::TextureView) {
    let size = (width.div_ceil(id_scale), height.div_ceil(id_scale));
    let small = |label, format, usage| {
        target(device, label, size, format, usage, false).create_view(&Default::default())
    };
    (
        [
            small("ids 0 (reduced)", ID_FORMAT, ID_USAGE),
            small("ids 1 (reduced)", ID_FORMAT, ID_USAGE),
        ],
        small(
            "depth (reduced ids)",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        ),
    )
}

/// Layers of a view's texture array: one per layer, at least two. wgpu's GL backend makes a
/// 2D texture of one layer a plain `TEXTURE_2D`, which a `texture_2d_array` binding cannot
/// sample (it reads black); a view with its background alone (the sky, or a streamed view
/// not laid out yet) gets an empty second layer.
fn texture_layers(view: &RefView) -> u32 {
    (view.layers.len() as u32).max(2)
}

/// Face size of a view's texture: its layers' (a streamed view not laid out yet has 1×1
/// placeholder layers, which need no full-size texture), else the view's.
fn texture_face_size(view: &RefView) -> u32 {
    view.layers
        .first()
        .map_or(view.face_size, |l| l.face_size())
}

/// Whether `view`'s background layer has sky its reference sees (alpha 255, not the sky
/// behind its occluders) at every texel of its finest level; then every coarser level has
/// too (alpha averages of four), and so has any filtered lookup.
fn sky_whole(view: &RefView) -> bool {
    view.layers
        .first()
        .and_then(|l| l.levels.first())
        .is_some_and(|m| m.as_slice().iter().all(|p| p[3] == db::SKY_SEEN_ALPHA))
}

/// A view's per-tile textures ([`Renderer::tile_textures`]) and their bytes.
struct TileTextures {
    info: wgpu::Texture,
    info_view: wgpu::TextureView,
    counts_tex: wgpu::Texture,
    counts_view: wgpu::TextureView,
    counts: Option<wgpu::Buffer>,
    bytes: u64,
}

/// A view's meshes as the GPU draws them: every tile's vertices (and its skirt's) in one
/// list, indices into it, the first index of every tile, per tile `face | layer << 8`, and
/// per coarser mesh level the decimated indices with the first index of every tile (the
/// end not yet pushed).
struct MeshArrays {
    verts: Vec<GpuVertex>,
    idx: Vec<u32>,
    index_start: Vec<u32>,
    face_layer: Vec<u32>,
    coarse: Vec<(Vec<u32>, Vec<u32>)>,
}

/// The meshes of `view`, with half-texel skirts where `skirts`.
fn mesh_arrays(view: &RefView, skirts: bool) -> MeshArrays {
    let mut verts: Vec<GpuVertex> = Vec::new();
    let mut idx: Vec<u32> = Vec::new();
    let mut index_start = Vec::with_capacity(view.tiles.len() + 1);
    let mut face_layer = Vec::with_capacity(view.tiles.len());
    // Decimated index lists per coarser mesh level (same vertices).
    let mut coarse: Vec<(Vec<u32>, Vec<u32>)> = (0..MESH_LEVELS)
        .map(|_| (Vec::new(), Vec::with_capacity(view.tiles.len() + 1)))
        .collect();
    let skirts = if skirts {
        crate::refview::view_skirts(view)
    } else {
        Vec::new()
    };
    let decimated = decimated_levels(view);
    for (ti, tile) in view.tiles.iter().enumerate() {
        index_start.push(idx.len() as u32);
        let base = verts.len() as u32;
        // Half-texel skirts close the outline of meshes on pixel centres (databases'
        // adaptive meshes); drawn at every mesh level.
        let (skirt_verts, skirt_idx) = skirts
            .get(ti)
            .map_or((&[][..], &[][..]), |(v, i)| (&v[..], &i[..]));
        for (k, (cidx, cstart)) in coarse.iter_mut().enumerate() {
            cstart.push(cidx.len() as u32);
            match decimated.get(ti).and_then(|d| d.get(k)) {
                Some(d) => cidx.extend(d.iter().map(|i| base + i)),
                None => cidx.extend(tile.mesh.indices.iter().map(|i| base + i)),
            }
            cidx.extend(skirt_idx.iter().map(|i| base + i));
        }
        let face = tile.tile.face.index() as u32;
        let vertex = |v: &[f32; 3], flag: u32| GpuVertex {
            pos_in_face: [v[0], v[1]],
            depth_m: v[2],
            packed: ((ti as u32) << 3) | face | flag,
        };
        // Stretched triangles on copies of their vertices, after the skirt's, flagged
        // (`refview::stretch`); the coarser levels keep the shared vertices.
        let (stretched, full) = split_stretched(&tile.mesh, tile.tile.face, view.face_size);
        let (own, skirt_n) = (tile.mesh.vertices.len() as u32, skirt_verts.len() as u32);
        verts.extend(
            tile.mesh
                .vertices
                .iter()
                .chain(skirt_verts)
                .map(|v| vertex(v, 0))
                .chain(stretched.iter().map(|v| vertex(v, STRETCHED_BIT))),
        );
        idx.extend(
            full.iter()
                .map(|&i| base + if i >= own { i + skirt_n } else { i })
                .chain(skirt_idx.iter().map(|i| base + i)),
        );
        face_layer.push(face | ((tile.slab + 1) << 8));
    }
    index_start.push(idx.len() as u32);
    MeshArrays {
        verts,
        idx,
        index_start,
        face_layer,
        coarse,
    }
}

/// The coarser levels' index lists of every tile of `view` (none without a tile grid), on
/// every core (three quarters of a view's upload on one).
fn decimated_levels(view: &RefView) -> Vec<Vec<Vec<u32>>> {
    let Some(grid) = tracks::TileGrid::new(view.face_size, view.tile_size) else {
        return Vec::new();
    };
    let jump = crate::refview::LayerMeshing::default().jump;
    view.tiles
        .par_iter()
        .map(|tile| {
            (0..MESH_LEVELS)
                .map(|k| {
                    let cell = mesh_cell(view.tile_size, k + 1);
                    decimated_indices(&tile.mesh, grid.pixel_rect(tile.tile), cell, jump)
                })
                .collect()
        })
        .collect()
}
