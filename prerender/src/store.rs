//! The prerender directory: the on-disk contract between `prerender`/`import-pov` and every
//! later stage (`slabs`, `cull`, `build`).
//!
//! ```text
//! DIR/prerender.json            PrerenderReport (written last; scripts read it)
//! DIR/prerender.md              the same for people
//! DIR/track.toml                the track the samples were taken along
//! DIR/samples/NNNN/             one directory per reference viewpoint
//!     color.png                 sRGB8 RGB, N × 6N: the six faces stacked in Face order
//!     depth.exr                 f32 channel "Z", N × 6N, radial metres, +inf = sky
//!     lowres_depth.exr          f32 "Z", n × 6n: the fast low-resolution depth pass
//!     sample.json               SampleMeta, written after the files above (completion marker)
//!     slab_K/color.png          RGBA8; alpha is the slab's binary opacity mask (0 or 255)
//!     slab_K/depth.exr          f32 "Z", +inf where the slab holds nothing
//!     layers.json               LayersMeta, written after every slab_K (completion marker)
//!
//! DIR/runs/*.jsonl             the run log: timings of every run (crate::runlog)
//! ```
//!
//! Every file is written to a uniquely named temporary file in the same directory and renamed
//! into place (`railview_files`), so a killed run never leaves a file that looks complete and
//! shards writing into one shared directory never disturb each other; a sample counts as done
//! only once its marker exists, which is what resume checks. Everything but the run log and
//! the reports (`prerender.json` and `.md`: times, which shard rendered what) is the same bytes
//! for the same inputs, whoever renders it: no timing in the markers, EXR tiles in a fixed
//! order.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::{CubeMap, Face, SlabRange};

/// Errors reading or writing a prerender directory; each names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// The message already includes the I/O error, so it is deliberately not a `#[source]`
    /// (an error chain printed with `{:#}` would repeat it).
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: io::Error },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

impl StoreError {
    fn io(path: &Path, error: io::Error) -> Self {
        StoreError::Io {
            path: path.to_path_buf(),
            error,
        }
    }
    fn format(path: &Path, message: impl Into<String>) -> Self {
        StoreError::Format {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// Per-sample metadata (`sample.json`). Content only: the same inputs give the same bytes, on
/// any machine; how long a sample took is in the run log ([`crate::runlog`]). (Markers
/// written before carried `seconds`; it is ignored when read.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleMeta {
    pub index: usize,
    /// Arc length along the track, metres.
    pub s: f64,
    pub position: DVec3,
    pub face_size: u32,
    pub lowres_face_size: u32,
    /// Primary rays traced for this sample (all passes).
    pub primary_rays: u64,
}

/// Per-sample slab layers metadata (`layers.json`); timings are in the run log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayersMeta {
    pub slabs: Vec<SlabRange>,
}

/// The report scripts read (`prerender.json`). Keep field names stable.
///
/// Written by a run without `--shard` or by the merge (`--merge`), never by a shard: it covers
/// every complete sample in the directory, and its times and [`ShardSummary`]s come from the
/// run logs ([`crate::runlog`]) of whichever runs rendered them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PrerenderReport {
    /// Scene name (`castle`, a TOML path, or a `.pov` path).
    pub scene: String,
    /// `builtin` or `povray`.
    pub renderer: String,
    pub track: String,
    /// Number of reference viewpoints on the track.
    pub samples: usize,
    pub face_size: u32,
    pub lowres_face_size: u32,
    /// Render time summed over the complete samples (base passes and slab layers), as their
    /// runs logged it, whichever machine rendered them.
    pub seconds: f64,
    pub rays_per_second: f64,
    pub viewpoints: Vec<tracks::ReferenceViewpoint>,
    /// Slab layers rendered per sample, empty if none yet.
    #[serde(default)]
    pub slabs: Vec<SlabRange>,
    /// Always `null` now (the report covers the whole track; see `shards`). Reports of older
    /// versions held the shard of the run that wrote them last.
    #[serde(default)]
    pub shard: Option<(usize, usize)>,
    /// Which run rendered which complete sample, grouped by shard.
    #[serde(default)]
    pub shards: Vec<ShardSummary>,
    /// Renderer-specific extra numbers (POV-Ray parse/trace times, …).
    #[serde(default)]
    pub extra: serde_json::Value,
}

/// The complete samples one shard (or the unsharded runs) rendered, from the run logs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardSummary {
    /// `[K, N]`; `null` for runs without `--shard`, and for samples no run log mentions
    /// (rendered by an older version, or copied without their `runs/`).
    pub shard: Option<(usize, usize)>,
    pub samples: Vec<usize>,
    /// Base-pass render time of these samples, summed.
    pub render_seconds: f64,
    pub primary_rays: u64,
    /// Hosts that rendered them.
    #[serde(default)]
    pub hosts: Vec<String>,
}

/// Paths of one prerender directory.
#[derive(Clone, Debug)]
pub struct PrerenderDir {
    root: PathBuf,
}

impl PrerenderDir {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        PrerenderDir { root: root.into() }
    }
    pub fn root(&self) -> &Path {
        &self.root
    }
    pub fn report_json(&self) -> PathBuf {
        self.root.join("prerender.json")
    }
    pub fn report_md(&self) -> PathBuf {
        self.root.join("prerender.md")
    }
    pub fn track_toml(&self) -> PathBuf {
        self.root.join("track.toml")
    }
    /// The sky alone in every direction (`crate::sky`), where the renderer can draw it.
    pub fn sky_png(&self) -> PathBuf {
        self.root.join("sky.png")
    }
    pub fn sample_dir(&self, index: usize) -> PathBuf {
        self.root.join("samples").join(format!("{index:04}"))
    }
    pub fn color_png(&self, index: usize) -> PathBuf {
        self.sample_dir(index).join("color.png")
    }
    pub fn depth_exr(&self, index: usize) -> PathBuf {
        self.sample_dir(index).join("depth.exr")
    }
    pub fn lowres_depth_exr(&self, index: usize) -> PathBuf {
        self.sample_dir(index).join("lowres_depth.exr")
    }
    pub fn sample_json(&self, index: usize) -> PathBuf {
        self.sample_dir(index).join("sample.json")
    }
    pub fn slab_color_png(&self, index: usize, slab: usize) -> PathBuf {
        self.sample_dir(index)
            .join(format!("slab_{slab}"))
            .join("color.png")
    }
    pub fn slab_depth_exr(&self, index: usize, slab: usize) -> PathBuf {
        self.sample_dir(index)
            .join(format!("slab_{slab}"))
            .join("depth.exr")
    }
    pub fn layers_json(&self, index: usize) -> PathBuf {
        self.sample_dir(index).join("layers.json")
    }

    /// The completed base pass of a sample, if its marker exists and parses.
    pub fn sample_meta(&self, index: usize) -> Option<SampleMeta> {
        read_json(&self.sample_json(index)).ok()
    }

    /// The completed slab layers of a sample, if its marker exists and parses.
    pub fn layers_meta(&self, index: usize) -> Option<LayersMeta> {
        read_json(&self.layers_json(index)).ok()
    }

    pub fn read_report(&self) -> Result<PrerenderReport, StoreError> {
        read_json(&self.report_json())
    }
}

/// Create `dir` and check that it is writable, with an error naming it.
pub fn ensure_writable_dir(dir: &Path) -> Result<(), StoreError> {
    railview_files::check_writable(dir).map_err(|e| StoreError::io(dir, e))
}

/// Write `bytes` to `path` whole: a uniquely named temporary file in the same directory,
/// fsync, rename (`railview_files::write`). Safe with any number of writers at once, on one
/// host or many sharing a file system.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    railview_files::write(path, bytes).map_err(|e| StoreError::io(path, e))
}

/// [`write_atomic`] unless `path` already holds exactly `bytes` (files every shard of a
/// sharded run writes with the same content, such as `track.toml`).
pub fn write_if_changed(path: &Path, bytes: &[u8]) -> Result<bool, StoreError> {
    railview_files::write_if_changed(path, bytes).map_err(|e| StoreError::io(path, e))
}

/// Remove the temporary files a killed writer left in `dir` (not below it), before
/// rewriting what is there (`railview_files::remove_temporaries`).
pub fn remove_temporaries(dir: &Path) -> Result<(), StoreError> {
    railview_files::remove_temporaries(dir)
        .map(|_| ())
        .map_err(|e| StoreError::io(dir, e))
}

/// Serialise `value` as pretty JSON and write it atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), StoreError> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| StoreError::format(path, format!("cannot serialise: {e}")))?;
    write_atomic(path, text.as_bytes())
}

pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, StoreError> {
    let text = fs::read_to_string(path).map_err(|e| StoreError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| StoreError::format(path, e.to_string()))
}

/// Encode a cube map of RGB8 as a PNG of `N × 6N`.
pub fn encode_rgb_png(map: &CubeMap<[u8; 3]>) -> Vec<u8> {
    encode_png(
        map.face_size(),
        bytemuck_flatten(map.as_slice()),
        image::ColorType::Rgb8,
    )
}

/// Encode a cube map of RGBA8 as a PNG of `N × 6N`.
pub fn encode_rgba_png(map: &CubeMap<[u8; 4]>) -> Vec<u8> {
    encode_png(
        map.face_size(),
        bytemuck_flatten(map.as_slice()),
        image::ColorType::Rgba8,
    )
}

fn bytemuck_flatten<const C: usize>(px: &[[u8; C]]) -> Vec<u8> {
    px.iter().flat_map(|p| p.iter().copied()).collect()
}

fn encode_png(n: u32, bytes: Vec<u8>, color: image::ColorType) -> Vec<u8> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    // Writing into a Vec cannot fail and the buffer size matches by construction.
    enc.write_image(&bytes, n, 6 * n, color.into())
        .expect("PNG encoding into memory");
    out
}

fn decode_png(path: &Path, bytes: &[u8]) -> Result<(u32, image::DynamicImage), StoreError> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| StoreError::format(path, format!("not a readable PNG: {e}")))?;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h != 6 * w {
        return Err(StoreError::format(
            path,
            format!("cube map must be N × 6N pixels, found {w} × {h}"),
        ));
    }
    Ok((w, img))
}

pub fn read_rgb_png(path: &Path) -> Result<CubeMap<[u8; 3]>, StoreError> {
    let bytes = fs::read(path).map_err(|e| StoreError::io(path, e))?;
    let (n, img) = decode_png(path, &bytes)?;
    let px = img.to_rgb8().pixels().map(|p| p.0).collect();
    CubeMap::from_vec(n, px).ok_or_else(|| StoreError::format(path, "size mismatch"))
}

pub fn read_rgba_png(path: &Path) -> Result<CubeMap<[u8; 4]>, StoreError> {
    let bytes = fs::read(path).map_err(|e| StoreError::io(path, e))?;
    let (n, img) = decode_png(path, &bytes)?;
    let px = img.to_rgba8().pixels().map(|p| p.0).collect();
    CubeMap::from_vec(n, px).ok_or_else(|| StoreError::format(path, "size mismatch"))
}

/// Encode a depth cube map as a single-channel f32 OpenEXR (`Z`) of `N × 6N`.
pub fn encode_depth_exr(map: &CubeMap<f32>) -> Result<Vec<u8>, String> {
    use exr::prelude::*;
    let n = map.face_size() as usize;
    // Tiles in increasing order: the writer compresses them in parallel and, with the line
    // order left unspecified, stores each as it finishes, so two writes of one map would
    // differ in bytes. In order, the same map always gives the same file.
    let encoding = Encoding {
        line_order: LineOrder::Increasing,
        ..Encoding::FAST_LOSSLESS
    };
    let layer = Layer::new(
        (n, 6 * n),
        LayerAttributes::named("depth"),
        encoding,
        AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
            "Z",
            FlatSamples::F32(map.as_slice().to_vec()),
        )])),
    );
    let mut cursor = io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut cursor)
        .map_err(|e| e.to_string())?;
    Ok(cursor.into_inner())
}

/// Write a depth cube map atomically.
pub fn write_depth_exr(path: &Path, map: &CubeMap<f32>) -> Result<(), StoreError> {
    let bytes = encode_depth_exr(map).map_err(|e| StoreError::format(path, e))?;
    write_atomic(path, &bytes)
}

/// Read a depth cube map. Depth must be non-negative and not NaN (`+inf` = sky); the first bad
/// pixel is named by face and position.
pub fn read_depth_exr(path: &Path) -> Result<CubeMap<f32>, StoreError> {
    use exr::prelude::*;
    let img = read_first_flat_layer_from_file(path).map_err(|e| match e {
        exr::error::Error::Io(io) => StoreError::io(path, io),
        other => StoreError::format(path, format!("not a readable OpenEXR: {other}")),
    })?;
    let size = img.layer_data.size;
    let (w, h) = (size.width(), size.height());
    if w == 0 || h != 6 * w {
        return Err(StoreError::format(
            path,
            format!("cube map must be N × 6N pixels, found {w} × {h}"),
        ));
    }
    let ch = img
        .layer_data
        .channel_data
        .list
        .iter()
        .find(|c| c.name.eq("Z"))
        .ok_or_else(|| StoreError::format(path, "no channel `Z`"))?;
    let z: Vec<f32> = match &ch.sample_data {
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
        FlatSamples::U32(_) => {
            return Err(StoreError::format(
                path,
                "channel `Z` is u32, expected float",
            ))
        }
    };
    let map =
        CubeMap::from_vec(w as u32, z).ok_or_else(|| StoreError::format(path, "size mismatch"))?;
    if let Some(i) = map.as_slice().iter().position(|d| d.is_nan() || *d < 0.0) {
        let n = w;
        let face = Face::from_index(i / (n * n)).unwrap_or(Face::PosX);
        let (x, y) = ((i % (n * n)) % n, (i % (n * n)) / n);
        return Err(StoreError::format(
            path,
            format!(
                "pixel ({x}, {y}) of face {} (image row {}) has depth {}: depth must be >= 0 or +inf",
                face.short_name(),
                y + face.index() * n,
                map.as_slice()[i]
            ),
        ));
    }
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("railview-store-{name}-{}", std::process::id()));
        fs::remove_dir_all(&d).ok();
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn depth_round_trip_keeps_infinity() {
        let d = tmpdir("depth");
        let m = CubeMap::from_fn(5, |f, x, y| {
            if x == 0 {
                f32::INFINITY
            } else {
                (f.index() * 100 + y as usize * 5 + x as usize) as f32 * 0.37
            }
        });
        let p = d.join("depth.exr");
        write_depth_exr(&p, &m).unwrap();
        assert_eq!(read_depth_exr(&p).unwrap(), m);
    }

    #[test]
    fn depth_exr_bytes_depend_on_the_map_alone() {
        // Face 200: 4 × 19 tiles of 64², compressed on every core. The same map must give the
        // same bytes every time, and the bytes a one-thread writer gives.
        let m = CubeMap::from_fn(200, |f, x, y| {
            if (x / 7 + y / 5) % 3 == 0 {
                f32::INFINITY
            } else {
                (f.index() * 1000 + y as usize * 3 + x as usize % 11) as f32 * 0.25
            }
        });
        let a = encode_depth_exr(&m).unwrap();
        for _ in 0..4 {
            assert!(
                encode_depth_exr(&m).unwrap() == a,
                "EXR bytes differ between writes"
            );
        }
        use exr::prelude::*;
        let layer = Layer::new(
            (200, 1200),
            LayerAttributes::named("depth"),
            Encoding {
                line_order: LineOrder::Increasing,
                ..Encoding::FAST_LOSSLESS
            },
            AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
                "Z",
                FlatSamples::F32(m.as_slice().to_vec()),
            )])),
        );
        let mut one = io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_buffered(&mut one)
            .unwrap();
        assert!(
            one.into_inner() == a,
            "parallel and sequential EXR bytes differ"
        );
    }

    #[test]
    fn nan_and_negative_depth_name_the_pixel() {
        let d = tmpdir("nan");
        for bad in [f32::NAN, -1.0] {
            let mut m = CubeMap::filled(4, 1.0f32);
            *m.get_mut(Face::NegY, 2, 3) = bad;
            let p = d.join("bad.exr");
            write_depth_exr(&p, &m).unwrap();
            let e = read_depth_exr(&p).unwrap_err().to_string();
            assert!(
                e.contains("bad.exr") && e.contains("(2, 3)") && e.contains("ny"),
                "{e}"
            );
        }
    }

    #[test]
    fn png_round_trip() {
        let d = tmpdir("png");
        let m = CubeMap::from_fn(3, |f, x, y| [f.index() as u8 * 40, x as u8, y as u8]);
        let p = d.join("c.png");
        write_atomic(&p, &encode_rgb_png(&m)).unwrap();
        assert_eq!(read_rgb_png(&p).unwrap(), m);
        let a = m.map(|c| [c[0], c[1], c[2], 255]);
        write_atomic(&p, &encode_rgba_png(&a)).unwrap();
        assert_eq!(read_rgba_png(&p).unwrap(), a);
    }

    #[test]
    fn atomic_write_leaves_no_temporary() {
        let d = tmpdir("atomic");
        let p = d.join("x.json");
        write_json(&p, &vec![1, 2, 3]).unwrap();
        let names: Vec<_> = fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1);
        let back: Vec<i32> = read_json(&p).unwrap();
        assert_eq!(back, vec![1, 2, 3]);
    }

    #[test]
    fn unwritable_dir_is_a_clear_error() {
        let e = ensure_writable_dir(Path::new("/proc/railview-cannot-exist")).unwrap_err();
        assert!(e.to_string().contains("/proc/railview-cannot-exist"), "{e}");
    }
}
