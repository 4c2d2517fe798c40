//! Decoding POV-Ray's images: the two dropped mesh-camera rows, 16-bit fog-trick depth, and
//! the 2×2 supersampled colour of `--aa`.
//!
//! Fog trick (see the POV-Ray notes): channel `i` holds `K·(1 − exp(−d/Dᵢ))`, so
//! `d = −Dᵢ·ln(1 − v/K)`. Each channel's 16-bit value gives an interval of distances; the
//! narrowest (relative) interval gives the depth, and every other channel's interval must
//! contain it. A pixel whose channels disagree did not get the fog (its ray started inside a
//! solid, or the scene's own fog or gamma leaked in).

use std::path::Path;

use tracks::CubeMap;

use super::frame::{BlockLayout, MeshLayout};
use super::PovError;

/// Fog distances and strength of one depth pass.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FogScales {
    /// `D₁ ≤ D₂ ≤ D₃`, scene units.
    pub d: [f64; 3],
    /// Fog colour strength `K` (0.5 when a fog-only pass is subtracted, else 1).
    pub k: f64,
}

impl FogScales {
    /// Wide scales for the low-resolution pass, before anything is known about the scene:
    /// distances from 1e-3 to 1e5 scene units decode to ~1e-3 relative error.
    pub fn wide(k: f64) -> FogScales {
        FogScales {
            d: [0.01, 10.0, 1.0e4],
            k,
        }
    }

    /// Scales suited to depths seen between `min` and `max` (from the low-resolution pass):
    /// the nearest depth sits at `x = d/D₁ ≈ 1`, the farthest at `x ≈ 0.5` of `D₃`, which keeps
    /// the relative error near 2e-5 and leaves room for farther surfaces the low-resolution
    /// pass missed (saturation only beyond ~11·D₃).
    pub fn for_range(min: f64, max: f64, k: f64) -> FogScales {
        if !(min.is_finite() && max.is_finite() && min > 0.0 && max >= min) {
            return FogScales::wide(k);
        }
        let d3 = 2.0 * max;
        let d1 = min.max(d3 * 1e-4).min(d3);
        FogScales {
            d: [d1, (d1 * d3).sqrt(), d3],
            k,
        }
    }

    /// Scales for a slab whose rays travel at most `range` (the note's choice `D₃ = range/2`).
    pub fn for_slab(range: f64, k: f64) -> FogScales {
        let d3 = range / 2.0;
        FogScales {
            d: [d3 / 100.0, d3 / 10.0, d3],
            k,
        }
    }
}

/// A decoded fog-trick image.
#[derive(Clone, Debug, PartialEq)]
pub struct FogDepth {
    /// Distance along each ray from its origin; `+inf` where the ray hit nothing.
    pub t: Vec<f64>,
    /// The largest distance each pixel's code allows (the upper end of the chosen channel's
    /// interval; `+inf` with `t`): a slab's hit whose interval reaches the slab's far end
    /// cannot be told from a ray cut there ([`slab_depth`]).
    pub t_hi: Vec<f64>,
    /// Pixels whose channels disagree.
    pub inconsistent: usize,
    /// Hit pixels that decode to distance 0.
    pub zero: usize,
    /// Pixels with a finite distance.
    pub hits: usize,
    /// Pixels whose channels all clipped on top of the scene's fog (decoded as misses).
    pub clipped: usize,
}

/// Decode fog-trick pixels. `fog_only` is the same view rendered with only the black filter
/// fog (the scene's own fog), subtracted when present.
pub fn decode_fog(p1: &[[u16; 3]], fog_only: Option<&[[u16; 3]]>, s: &FogScales) -> FogDepth {
    // Half a quantisation step per rounding, two roundings when a pass is subtracted, doubled
    // for the tolerance of POV-Ray's own float arithmetic.
    let steps = if fog_only.is_some() { 2.0 } else { 1.0 };
    let e = steps / 65535.0 / s.k;
    let mut out = FogDepth {
        t: Vec::with_capacity(p1.len()),
        t_hi: Vec::with_capacity(p1.len()),
        inconsistent: 0,
        zero: 0,
        hits: 0,
        clipped: 0,
    };
    for (i, px) in p1.iter().enumerate() {
        let v: [f64; 3] = std::array::from_fn(|c| {
            let base = fog_only.map_or(0.0, |p0| p0[i][c] as f64);
            (px[c] as f64 - base) / 65535.0 / s.k
        });
        if v.iter().all(|&x| x >= 1.0 - e) {
            out.t.push(f64::INFINITY);
            out.t_hi.push(f64::INFINITY);
            continue;
        }
        let dist = |c: usize, x: f64| -> f64 {
            if x <= 0.0 {
                0.0
            } else if x >= 1.0 {
                f64::INFINITY
            } else {
                -s.d[c] * (-x).ln_1p()
            }
        };
        // A channel at 65535 on top of the scene's own fog was clipped: it only bounds the
        // distance from below.
        let clipped: [bool; 3] =
            std::array::from_fn(|c| px[c] == u16::MAX && fog_only.is_some_and(|p0| p0[i][c] > 0));
        let intervals: [(f64, f64); 3] = std::array::from_fn(|c| {
            let hi = if clipped[c] {
                f64::INFINITY
            } else {
                dist(c, v[c] + e)
            };
            (dist(c, v[c] - e), hi)
        });
        let best = (0..3)
            .min_by(|&a, &b| {
                // Relative width; saturated channels (infinite interval) rank last. The
                // explicit check matters: inf/inf is a negative NaN on x86, which
                // `total_cmp` would rank first.
                let w = |c: usize| {
                    let (lo, hi) = intervals[c];
                    let r = (hi - lo) / dist(c, v[c]).max(f64::MIN_POSITIVE);
                    if r.is_finite() {
                        r
                    } else {
                        f64::INFINITY
                    }
                };
                w(a).total_cmp(&w(b))
            })
            .unwrap_or(0);
        let t = dist(best, v[best]);
        if clipped[best] {
            // Every channel clipped (a ray into dense scene fog that hits nothing, e.g. one
            // starting underground): nothing to decode; counted, and treated as a miss.
            out.clipped += 1;
            out.t.push(f64::INFINITY);
            out.t_hi.push(f64::INFINITY);
            continue;
        }
        if !t.is_finite() {
            out.t.push(f64::INFINITY);
            out.t_hi.push(f64::INFINITY);
            continue;
        }
        let slack = 1e-9 * t;
        if intervals
            .iter()
            .any(|&(lo, hi)| t < lo - slack || t > hi + slack)
        {
            out.inconsistent += 1;
        }
        if t == 0.0 {
            out.zero += 1;
        }
        out.hits += 1;
        out.t.push(t);
        out.t_hi.push(intervals[best].1.max(t));
    }
    out
}

/// The colour of a slab layer's pixel: the panorama's where the layer holds the surface the
/// panorama sees there (both depths finite and within 1e-3 of each other: the panorama's
/// first hit lies in the slab, and the slab's ray, starting nearer, hits it too), else the
/// slab render's own (a surface behind nearer slabs, or nothing). A slab render differs from
/// the panorama where it should not: the scene's fog and media are integrated from the
/// slab's near sphere rather than the camera, radiosity is sampled anew in every render,
/// and the panorama may be anti-aliased at edges the layer cuts. A view at the sample then
/// shows POV-Ray's own render of it.
pub fn layer_colour(slab: [u8; 3], slab_depth: f64, pano: [u8; 3], pano_depth: f64) -> [u8; 3] {
    let same = slab_depth.is_finite()
        && pano_depth.is_finite()
        && (slab_depth - pano_depth).abs() <= 1e-3 * pano_depth;
    if same {
        pano
    } else {
        slab
    }
}

/// A slab ray's decoded distance `t` (upper bound `t_hi`, [`FogDepth`]) as the layer's radial
/// depth: `near + t`, or `+inf` for nothing in the slab. A ray that hits nothing before the
/// slab's far end is cut there and decodes to about `range` (`far − near`; 0 for an
/// unbounded slab), within the decoding error — which a scene's own fog, subtracted at half
/// strength, makes as large as a few 1e-4 of `range`. So a hit whose code allows `range`
/// is empty, as is one within 1e-4 of it; a surface that close to the far end belongs to the
/// next slab's near edge.
pub fn slab_depth(near: f64, range: f64, t: f64, t_hi: f64) -> f64 {
    let cut = range > 0.0 && (t_hi >= range || t >= range * (1.0 - 1e-4));
    if !t.is_finite() || cut {
        f64::INFINITY
    } else {
        near + t
    }
}

/// Read a PNG POV-Ray wrote, checking its size.
fn read_png(path: &Path, width: u32, height: u32) -> Result<image::DynamicImage, PovError> {
    let bytes = std::fs::read(path).map_err(|source| PovError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let img =
        image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| {
            PovError::Output {
                path: path.to_path_buf(),
                message: format!("not a readable PNG: {e}"),
            }
        })?;
    if img.width() != width || img.height() != height {
        return Err(PovError::Output {
            path: path.to_path_buf(),
            message: format!(
                "expected {width} × {height} pixels, found {} × {}",
                img.width(),
                img.height()
            ),
        });
    }
    Ok(img)
}

/// The cube-map rows of a mesh-camera image (dummy rows dropped), row-major.
fn cube_rows<P: Copy>(img: &[P], layout: &MeshLayout) -> Vec<P> {
    let (w, h) = layout.image_size();
    let w = w as usize;
    (0..h)
        .filter(|&j| layout.cube_row(j).is_some())
        .flat_map(|j| img[j as usize * w..(j as usize + 1) * w].iter().copied())
        .collect()
}

/// A PNG of `w` × `h` pixels that must hold 16 bits a channel.
fn read_png16(path: &Path, w: u32, h: u32) -> Result<image::DynamicImage, PovError> {
    let img = read_png(path, w, h)?;
    if img.color().bits_per_pixel() / img.color().channel_count() as u16 != 16 {
        return Err(PovError::Output {
            path: path.to_path_buf(),
            message: format!("expected a 16-bit PNG, found {:?}", img.color()),
        });
    }
    Ok(img)
}

/// A mesh-camera render as 16-bit RGB cube-map pixels, face-major.
pub fn read_mesh_png16(path: &Path, layout: &MeshLayout) -> Result<Vec<[u16; 3]>, PovError> {
    let (w, h) = layout.image_size();
    let img = read_png16(path, w, h)?;
    let px: Vec<[u16; 3]> = img.to_rgb16().pixels().map(|p| p.0).collect();
    Ok(cube_rows(&px, layout))
}

/// A [`BlockLayout`] render as 16-bit RGB cube-map pixels, face-major, one list a position.
pub fn read_block_png16(path: &Path, layout: &BlockLayout) -> Result<Vec<Vec<[u16; 3]>>, PovError> {
    let (w, h) = layout.image_size();
    let img = read_png16(path, w, h)?;
    let img = img.to_rgb16();
    let w = w as usize;
    let n = layout.face_size as usize;
    let mut out = vec![vec![[0u16; 3]; 6 * n * n]; layout.positions as usize];
    for (j, row) in img.chunks_exact(3 * w).enumerate() {
        if let Some((k, r)) = layout.cube_row(j as u32) {
            let dst = &mut out[k as usize][r as usize * w..(r as usize + 1) * w];
            for (d, p) in dst.iter_mut().zip(row.chunks_exact(3)) {
                *d = [p[0], p[1], p[2]];
            }
        }
    }
    Ok(out)
}

/// A mesh-camera colour render as a cube map.
pub fn read_mesh_png8(path: &Path, layout: &MeshLayout) -> Result<CubeMap<[u8; 3]>, PovError> {
    let (w, h) = layout.image_size();
    let img = read_png(path, w, h)?;
    let px: Vec<[u8; 3]> = img.to_rgb8().pixels().map(|p| p.0).collect();
    CubeMap::from_vec(layout.face_size, cube_rows(&px, layout)).ok_or_else(|| PovError::Output {
        path: path.to_path_buf(),
        message: "pixel count does not match the cube map".into(),
    })
}

fn srgb_to_linear(c: u8) -> f64 {
    let c = c as f64 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn linear_to_srgb(l: f64) -> u8 {
    let c = if l <= 0.0031308 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Average `ss × ss` blocks of an sRGB8 image of `(w·ss) × (h·ss)` pixels (RGB, rows from
/// the top) into one of `w × h`, in linear light.
pub fn box_filter(fine: &[u8], w: u32, h: u32, ss: u32) -> Vec<[u8; 3]> {
    let (w, h, ss) = (w as usize, h as usize, ss.max(1) as usize);
    let stride = w * ss;
    let n = (ss * ss) as f64;
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let mut acc = [0.0f64; 3];
            for dy in 0..ss {
                for dx in 0..ss {
                    let i = 3 * ((y * ss + dy) * stride + x * ss + dx);
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a += srgb_to_linear(fine.get(i + c).copied().unwrap_or(0));
                    }
                }
            }
            acc.map(|a| linear_to_srgb(a / n))
        })
        .collect()
}

/// Average `ss × ss` blocks of a cube map of `ss·N` into one of `N`, in linear light.
pub fn downsample(fine: &CubeMap<[u8; 3]>, ss: u32) -> CubeMap<[u8; 3]> {
    let ss = ss.max(1);
    let n = fine.face_size() / ss;
    CubeMap::from_fn(n, |face, x, y| {
        let mut acc = [0.0f64; 3];
        for dy in 0..ss {
            for dx in 0..ss {
                let p = fine.get(face, ss * x + dx, ss * y + dy);
                for c in 0..3 {
                    acc[c] += srgb_to_linear(p[c]);
                }
            }
        }
        acc.map(|a| linear_to_srgb(a / (ss * ss) as f64))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn encode(d: f64, s: &FogScales, p0: [f64; 3]) -> [u16; 3] {
        std::array::from_fn(|c| {
            let v = s.k * (1.0 - (-d / s.d[c]).exp()) + p0[c];
            (v.clamp(0.0, 1.0) * 65535.0).round() as u16
        })
    }

    proptest! {
        #[test]
        fn round_trip_is_within_1e4(d in 0.2f64..60.0) {
            let s = FogScales::for_range(0.5, 30.0, 1.0);
            let r = decode_fog(&[encode(d, &s, [0.0; 3])], None, &s);
            prop_assert_eq!(r.inconsistent, 0);
            prop_assert!(((r.t[0] - d) / d).abs() < 1e-4, "{} vs {}", r.t[0], d);
        }

        #[test]
        fn fog_only_pass_is_subtracted(d in 1.0f64..500.0, f in 0.0f64..0.45) {
            let s = FogScales::for_range(1.0, 300.0, 0.5);
            let p0 = [f, f * 0.9, f * 0.8];
            let q0 = std::array::from_fn(|c| (p0[c] * 65535.0).round() as u16);
            let r = decode_fog(&[encode(d, &s, p0)], Some(&[q0]), &s);
            prop_assert_eq!(r.inconsistent, 0);
            prop_assert!(((r.t[0] - d) / d).abs() < 3e-4, "{} vs {}", r.t[0], d);
        }
    }

    #[test]
    fn saturated_channel_is_never_chosen() {
        // Regression: a saturated first channel (width inf/inf = NaN) was picked as the best.
        let s = FogScales::wide(1.0);
        let r = decode_fog(&[[65535, 19080, 23]], None, &s);
        assert!((r.t[0] - 3.44).abs() < 0.01, "{}", r.t[0]);
        assert_eq!(r.inconsistent, 0);
    }

    #[test]
    fn clipped_channels_only_bound_the_distance() {
        // Regression: underground rays in the patio's ground fog clipped every channel.
        let s = FogScales::for_range(40.0, 10000.0, 0.5);
        let p0 = [[50000u16, 52000, 55000]; 2];
        let d = 300.0;
        let hit: [u16; 3] = std::array::from_fn(|c| {
            let v = 0.5 * (1.0 - (-d / s.d[c]).exp()) + p0[0][c] as f64 / 65535.0;
            (v.min(1.0) * 65535.0).round() as u16
        });
        let r = decode_fog(&[[65535; 3], hit], Some(&p0), &s);
        assert_eq!(r.t[0], f64::INFINITY);
        assert_eq!((r.clipped, r.inconsistent), (1, 0));
        assert!(
            hit.contains(&65535) && !hit.iter().all(|&c| c == 65535),
            "{hit:?}"
        );
        assert!(((r.t[1] - d) / d).abs() < 1e-3, "{}", r.t[1]);
    }

    #[test]
    fn sky_is_infinite_and_colours_are_inconsistent() {
        let s = FogScales::for_range(1.0, 10.0, 1.0);
        let r = decode_fog(&[[65535; 3], [30000, 30000, 30000], [0, 0, 0]], None, &s);
        assert_eq!(r.t[0], f64::INFINITY);
        assert_eq!(r.inconsistent, 1, "a grey object colour is not a fog code");
        assert_eq!((r.zero, r.hits), (1, 2));
    }

    proptest! {
        /// A ray cut at the slab's far end under a scene's fog decodes as empty however the
        /// two passes round; a hit 1e-3 short of it stays a hit.
        #[test]
        fn a_ray_cut_at_the_far_end_under_scene_fog_is_empty(
            range in 0.5f64..50.0, f in 0.0f64..0.45, bias in -0.9f64..0.9,
        ) {
            let s = FogScales::for_slab(range, 0.5);
            let p0 = [f, f * 0.95, f * 0.9];
            let q0: [u16; 3] = std::array::from_fn(|c| (p0[c] * 65535.0).round() as u16);
            // The cut ray, its two passes disagreeing by up to a code beyond their rounding
            // (the decoder allows two codes in all: a rounding each, doubled).
            let cut: [u16; 3] = std::array::from_fn(|c| {
                let v = s.k * (1.0 - (-range / s.d[c]).exp()) + p0[c];
                (v * 65535.0 + bias).round().clamp(0.0, 65535.0) as u16
            });
            let near_end = encode(range * (1.0 - 1e-3), &s, p0);
            let r = decode_fog(&[cut, near_end], Some(&[q0, q0]), &s);
            prop_assert_eq!(slab_depth(1.0, range, r.t[0], r.t_hi[0]), f64::INFINITY);
            let hit = slab_depth(1.0, range, r.t[1], r.t_hi[1]);
            prop_assert!((hit - 1.0 - range * (1.0 - 1e-3)).abs() < 1e-3 * range, "{}", hit);
        }
    }

    #[test]
    fn layers_take_the_panoramas_colour_only_on_its_surface() {
        let (slab, pano) = ([10, 20, 30], [200, 210, 220]);
        assert_eq!(layer_colour(slab, 5.0, pano, 5.004), pano);
        assert_eq!(
            layer_colour(slab, 5.0, pano, 4.0),
            slab,
            "behind a nearer surface"
        );
        assert_eq!(layer_colour(slab, 5.0, pano, f64::INFINITY), slab);
        assert_eq!(layer_colour(slab, f64::INFINITY, pano, f64::INFINITY), slab);
    }

    #[test]
    fn unbounded_slabs_and_misses() {
        assert_eq!(slab_depth(2.0, 0.0, 1e6, 1e6), 2.0 + 1e6);
        assert_eq!(
            slab_depth(2.0, 5.0, f64::INFINITY, f64::INFINITY),
            f64::INFINITY
        );
        assert_eq!(slab_depth(2.0, 5.0, 4.9994, 4.9996), 2.0 + 4.9994);
        assert_eq!(slab_depth(2.0, 5.0, 4.9994, 5.0001), f64::INFINITY);
    }

    #[test]
    fn downsample_of_uniform_is_identity() {
        let fine = CubeMap::filled(4, [10u8, 128, 250]);
        let coarse = downsample(&fine, 2);
        assert_eq!(coarse.face_size(), 2);
        assert_eq!(downsample(&fine, 4).face_size(), 1);
        assert!(downsample(&fine, 4)
            .as_slice()
            .iter()
            .all(|p| *p == [10, 128, 250]));
        assert!(coarse.as_slice().iter().all(|p| *p == [10, 128, 250]));
    }
}
