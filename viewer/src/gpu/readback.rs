//! Reading results back: the output image, tile ids, feedback counts, throughput timings.

use super::{count_ids, Frame, GpuError, Renderer, Throughput, TIMESTAMPS};
use crate::plan::FramePlan;
use crate::refview::RefView;

impl Renderer {
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
        let t = self.timed_frames(frames, |enc| self.encode(enc, plan, views))?;
        self.gpu.check("timing frames")?;
        Ok(t)
    }

    /// `frames` frames recorded by `encode`, submitted back to back, one wait; timestamps
    /// around each where the device has them.
    pub(super) fn timed_frames(
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
        self.gpu.wait("timing frames")?;
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

    /// [`Renderer::throughput`] of the plain panorama ([`Renderer::draw_panorama`]).
    pub fn throughput_panorama(
        &mut self,
        plan: &FramePlan,
        views: &[RefView],
        frames: usize,
    ) -> Result<Throughput, GpuError> {
        self.prepare_panorama(plan, views)?;
        let t = self.timed_frames(frames, |enc| self.encode_panorama(enc, plan, views))?;
        self.gpu.check("timing panorama frames")?;
        Ok(t)
    }

    /// Copy the internal output target to the CPU.
    pub fn read_output(&self) -> Result<Frame, GpuError> {
        let t = self
            .targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing drawn yet".into()))?;
        let (w, h) = (t.width, t.height);
        let (enc, buf, bpr) = self.copy_for_readback(&t.output, "readback");
        let words = self.map_read(enc, &buf)?;
        let data: &[u8] = bytemuck::cast_slice(&words);
        let mut rgba = Vec::with_capacity((w * h * 4) as usize);
        for row in 0..h as usize {
            let start = row * bpr as usize;
            rgba.extend_from_slice(&data[start..start + 4 * w as usize]);
        }
        self.gpu.check("reading the frame back")?;
        Ok(Frame {
            width: w,
            height: h,
            rgba,
        })
    }

    /// Visible pixels per tile of every view pass of the last [`Renderer::draw`] (tile-id
    /// targets counted by a compute pass with atomics, or, on devices without compute
    /// ([`super::Caps::compute`]), read back and counted on the CPU); `plan` must be the plan drawn, with
    /// [`FramePlan::tile_ids`] set. Where the ids were drawn at reduced resolution
    /// ([`FramePlan::id_scale`] > 1, frames without overlays) each id texel's count is
    /// scaled by the area factor (frame pixels / id texels, about `id_scale²`), rounded: an
    /// estimate of the full-resolution count (a tile narrower than `id_scale` pixels may
    /// count 0).
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
            let ids = t.ids_of(slot, self.ids_scale);
            let mut pixels: Vec<u32> = match &g.counts {
                Some(counts) => {
                    let mut enc = self.gpu.device.create_command_encoder(&Default::default());
                    self.encode_counts(&mut enc, ids, g);
                    self.read_buffer(enc, counts)?
                }
                None => count_ids(&self.read_ids(ids.texture())?, v.tiles.len()),
            };
            pixels.truncate(v.tiles.len());
            let (iw, ih) = (ids.texture().width(), ids.texture().height());
            if (iw, ih) != (t.width, t.height) {
                let area = (t.width as f64 * t.height as f64) / (iw as f64 * ih as f64);
                for p in &mut pixels {
                    *p = (*p as f64 * area).round().min(u32::MAX as f64) as u32;
                }
            }
            out.push(crate::feedback::ViewCounts {
                view: pass.view,
                pixels,
            });
        }
        self.gpu.check("counting visible pixels per tile")?;
        Ok(out)
    }

    /// The tile drawn at every pixel (row-major from the top; tile index + 1, 0 = none) by
    /// view pass `slot` (0 or 1) of the last [`Renderer::draw`], which must have written tile
    /// ids. Ids drawn at reduced resolution ([`FramePlan::id_scale`] > 1) are widened to the
    /// frame's size: pixel (x, y) takes the id of texel (x / id_scale, y / id_scale), which
    /// was sampled at that texel's centre.
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
        let texture = t.ids_of(slot, self.ids_scale).texture();
        let rows = self.read_ids(texture)?;
        let stride = texture.width() as usize;
        let s = self.ids_scale.max(1) as usize;
        let (fw, fh) = (t.width as usize, t.height as usize);
        Ok((0..fh)
            .flat_map(|y| {
                let row = &rows[(y / s) * stride..];
                (0..fw).map(move |x| row[x / s])
            })
            .collect())
    }

    /// The texels of a tile-id texture, row-major from the top, rows unpadded.
    pub(super) fn read_ids(&self, texture: &wgpu::Texture) -> Result<Vec<u32>, GpuError> {
        let (enc, buf, bpr) = self.copy_for_readback(texture, "ids readback");
        let padded: Vec<u32> = self.map_read(enc, &buf)?;
        let (w, stride) = (texture.width() as usize, (bpr / 4) as usize);
        let ids: Vec<u32> = padded
            .chunks(stride)
            .flat_map(|row| &row[..w.min(row.len())])
            .copied()
            .collect();
        self.gpu.check("reading tile ids back")?;
        Ok(ids)
    }

    /// Copy a storage buffer out (after the commands in `enc`) and read it as `u32`s.
    pub(super) fn read_buffer(
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

    /// An encoder that copies mip 0 of `texture` (4 bytes per texel) into a new mappable
    /// buffer with rows padded to the copy alignment; the encoder, the buffer, bytes per row.
    fn copy_for_readback(
        &self,
        texture: &wgpu::Texture,
        label: &str,
    ) -> (wgpu::CommandEncoder, wgpu::Buffer, u32) {
        let (w, h) = (texture.width(), texture.height());
        let bpr = (w * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buf = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
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
        (enc, buf, bpr)
    }

    /// Submit `enc`, wait, and read the mappable buffer `buf` as `u32`s.
    pub(super) fn map_read(
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
        self.gpu.wait("reading back")?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        Ok(bytemuck::cast_slice(&data[..]).to_vec())
    }
}
