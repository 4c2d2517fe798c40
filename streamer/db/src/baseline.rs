//! The naive alternative a database is weighed against: each reference panorama stored as a
//! PNG of its colour plus a 16-bit PNG of its depth quantised in disparity — what a viewer
//! with one depth map per panorama ships.
//!
//! Both images are the cube map as the prerender directory lays it out (`N × 6N`, the faces
//! one below the other), written with the PNG encoder's best compression and adaptive row
//! filters. Depth becomes `round(65535 · r_min / r)` — disparity, scaled so that the nearest
//! pixel of the panorama is 65535 — and 0 for the sky (infinite depth); a viewer keeps
//! `r_min` beside it. [`measure`] does every viewpoint on every core.
//!
//! ```
//! use db::baseline::panorama;
//! use tracks::CubeMap;
//! let colour = CubeMap::filled(8, [90u8, 120, 200]);
//! let depth = CubeMap::filled(8, 4.0f32);
//! let b = panorama(&colour, &depth).unwrap();
//! assert!(b.colour_png > 0 && b.depth_png16 > 0);
//! ```

use image::ImageEncoder;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tracks::CubeMap;

/// The baseline's bytes for one panorama.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PanoramaBaseline {
    /// PNG of the RGB colour.
    pub colour_png: u64,
    /// 16-bit greyscale PNG of the disparity-quantised depth.
    pub depth_png16: u64,
}

impl PanoramaBaseline {
    pub fn total(&self) -> u64 {
        self.colour_png + self.depth_png16
    }
}

/// Why a baseline could not be measured.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BaselineError {
    #[error("colour ({0} px a face) and depth ({1} px a face) differ in size")]
    Size(u32, u32),
    #[error("PNG encoding: {0}")]
    Png(String),
}

/// Depth as 16-bit disparity: `round(65535 · r_min / r)` with `r_min` the nearest finite
/// positive depth; 0 where the depth is infinite, not positive or not a number.
pub fn disparity_u16(depth: &[f32]) -> Vec<u16> {
    let near = depth
        .iter()
        .copied()
        .filter(|r| r.is_finite() && *r > 0.0)
        .fold(f32::INFINITY, f32::min);
    depth
        .iter()
        .map(|&r| {
            if r.is_finite() && r > 0.0 {
                (65535.0 * (near as f64 / r as f64))
                    .round()
                    .clamp(1.0, 65535.0) as u16
            } else {
                0
            }
        })
        .collect()
}

fn png(
    bytes: &[u8],
    w: u32,
    h: u32,
    colour: image::ExtendedColorType,
) -> Result<u64, BaselineError> {
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Best,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(bytes, w, h, colour)
    .map_err(|e| BaselineError::Png(e.to_string()))?;
    Ok(out.len() as u64)
}

/// The baseline's bytes for one panorama (colour and radial depth of the same cube map).
pub fn panorama(
    colour: &CubeMap<[u8; 3]>,
    depth: &CubeMap<f32>,
) -> Result<PanoramaBaseline, BaselineError> {
    let n = colour.face_size();
    if depth.face_size() != n {
        return Err(BaselineError::Size(n, depth.face_size()));
    }
    let rgb: Vec<u8> = colour.as_slice().iter().flatten().copied().collect();
    let d: Vec<u8> = disparity_u16(depth.as_slice())
        .into_iter()
        .flat_map(u16::to_be_bytes)
        .collect();
    Ok(PanoramaBaseline {
        colour_png: png(&rgb, n, 6 * n, image::ExtendedColorType::Rgb8)?,
        depth_png16: png(&d, n, 6 * n, image::ExtendedColorType::L16)?,
    })
}

/// [`panorama`] of `count` panoramas, each loaded by `load(i)`, on every core; the first
/// error (of loading or measuring) in index order is returned.
pub fn measure<E>(
    count: usize,
    load: impl Fn(usize) -> Result<(CubeMap<[u8; 3]>, CubeMap<f32>), E> + Sync,
) -> Result<Vec<PanoramaBaseline>, E>
where
    E: From<BaselineError> + Send,
{
    (0..count)
        .into_par_iter()
        .map(|i| {
            let (c, d) = load(i)?;
            Ok(panorama(&c, &d)?)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disparity_maps_the_nearest_pixel_to_the_top_and_the_sky_to_zero() {
        let d = disparity_u16(&[2.0, 4.0, f32::INFINITY, 8.0, f32::NAN, -1.0, 1e9]);
        assert_eq!(d, vec![65535, 32768, 0, 16384, 0, 0, 1]);
        assert_eq!(disparity_u16(&[f32::INFINITY; 3]), vec![0, 0, 0]);
        assert!(disparity_u16(&[]).is_empty());
    }

    #[test]
    fn flat_panoramas_cost_little_and_noise_costs_more() {
        let flat = panorama(
            &CubeMap::filled(32, [10, 20, 30]),
            &CubeMap::filled(32, 3.0),
        )
        .unwrap();
        let mut s = 1u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        let noisy_c =
            CubeMap::from_vec(32, (0..6 * 32 * 32).map(|_| [next() as u8; 3]).collect()).unwrap();
        let noisy_d = CubeMap::from_vec(
            32,
            (0..6 * 32 * 32)
                .map(|_| 1.0 + (next() % 1000) as f32)
                .collect(),
        )
        .unwrap();
        let noisy = panorama(&noisy_c, &noisy_d).unwrap();
        assert!(flat.total() < 1000, "{flat:?}");
        assert!(
            noisy.colour_png > 10 * flat.colour_png && noisy.depth_png16 > 10 * flat.depth_png16
        );
        assert!(matches!(
            panorama(&CubeMap::filled(8, [0; 3]), &CubeMap::filled(4, 1.0)),
            Err(BaselineError::Size(8, 4))
        ));
    }
}
