//! Cube-map texture layers with mip chains, and the CPU sampler that mirrors the GPU's.
//!
//! A [`Layer`] is one cube map (`N × 6N` on the GPU, faces stacked in `Face` order) with its
//! mip levels; colour is sRGB-encoded RGBA8, alpha is the opacity mask. Texels outside the
//! mask carry the colour of their nearest opaque neighbours ([`dilate_masked`]) so bilinear
//! filtering at a mask edge never pulls in black.

use std::sync::LazyLock;

use tracks::{CubeMap, Face, PixelRect};

/// One cube-map layer and its mip chain (level 0 first).
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    pub levels: Vec<CubeMap<[u8; 4]>>,
}

/// sRGB byte → linear (a table of [`srgb_to_linear_exact`]: mip levels and the CPU sampler
/// convert every texel they touch, and `powf` was most of a streamed tile's mip update).
pub fn srgb_to_linear(c: u8) -> f32 {
    static TABLE: LazyLock<[f32; 256]> =
        LazyLock::new(|| std::array::from_fn(|b| srgb_to_linear_exact(b as u8)));
    TABLE[c as usize]
}

/// sRGB byte → linear, computed.
pub fn srgb_to_linear_exact(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear → sRGB byte (rounded): the same byte as [`linear_to_srgb_exact`] for every `c`,
/// found among the 255 smallest linear values at which the computed byte steps up (NaN
/// gives 0, as the computed form does).
pub fn linear_to_srgb(c: f32) -> u8 {
    static STEPS: LazyLock<[f32; 255]> =
        LazyLock::new(|| std::array::from_fn(|b| first_at_least(b as u8 + 1)));
    if c.is_nan() {
        return 0;
    }
    STEPS.partition_point(|&t| t <= c) as u8
}

/// The smallest `f32` in [0, 1] whose computed sRGB byte is at least `b` (> 0): bisection
/// over the bit patterns, which order non-negative floats as their values.
fn first_at_least(b: u8) -> f32 {
    let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
    // Invariant: byte(lo) < b <= byte(hi).
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if linear_to_srgb_exact(f32::from_bits(mid)) >= b {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    f32::from_bits(hi)
}

/// Linear → sRGB byte (rounded), computed.
pub fn linear_to_srgb_exact(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

impl Layer {
    /// Level 0 from `rgba`, then halve while the face size is even.
    pub fn from_rgba(rgba: CubeMap<[u8; 4]>) -> Layer {
        let mut levels = vec![rgba];
        loop {
            let last = levels.last().expect("level 0 exists");
            let n = last.face_size();
            if n < 2 || n % 2 != 0 {
                break;
            }
            let next = downsample(last);
            levels.push(next);
        }
        Layer { levels }
    }

    pub fn face_size(&self) -> u32 {
        self.levels[0].face_size()
    }

    /// Bilinear sample of level `level` at level-0 face-pixel position `(x, y)` (continuous,
    /// clamped half a texel inside the face so faces never bleed into each other), linear RGBA.
    pub fn sample_level(&self, level: usize, face: Face, x: f64, y: f64) -> [f32; 4] {
        let level = level.min(self.levels.len() - 1);
        let margin = 0.5 / self.levels[level].face_size() as f64;
        self.sample_level_within(level, margin, face, x, y)
    }

    /// Bilinear sample of level `level` with the position clamped `margin` (face units, 0 to
    /// 1) inside the face.
    fn sample_level_within(
        &self,
        level: usize,
        margin: f64,
        face: Face,
        x: f64,
        y: f64,
    ) -> [f32; 4] {
        let map = &self.levels[level.min(self.levels.len() - 1)];
        let n0 = self.face_size() as f64;
        let n = map.face_size() as f64;
        let (x, y) = (
            (x / n0).clamp(margin, 1.0 - margin) * n,
            (y / n0).clamp(margin, 1.0 - margin) * n,
        );
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (ix, iy) = (fx.floor(), fy.floor());
        let (tx, ty) = ((fx - ix) as f32, (fy - iy) as f32);
        let max = map.face_size() - 1;
        let at = |dx: f64, dy: f64| -> [f32; 4] {
            let px = ((ix + dx).max(0.0) as u32).min(max);
            let py = ((iy + dy).max(0.0) as u32).min(max);
            let c = map.get(face, px, py);
            [
                srgb_to_linear(c[0]),
                srgb_to_linear(c[1]),
                srgb_to_linear(c[2]),
                c[3] as f32 / 255.0,
            ]
        };
        let (a, b, c, d) = (at(0.0, 0.0), at(1.0, 0.0), at(0.0, 1.0), at(1.0, 1.0));
        let mut out = [0.0f32; 4];
        for k in 0..4 {
            let top = a[k] + (b[k] - a[k]) * tx;
            let bottom = c[k] + (d[k] - c[k]) * tx;
            out[k] = top + (bottom - top) * ty;
        }
        out
    }

    /// Trilinear sample at level of detail `lod` (fractional, clamped to the chain), as the
    /// GPU's one lookup (`sample_face` in `cube.wgsl`): both levels clamped half a texel of the
    /// coarser level inside the face.
    pub fn sample(&self, lod: f32, face: Face, x: f64, y: f64) -> [f32; 4] {
        let max = (self.levels.len() - 1) as f32;
        let lod = lod.clamp(0.0, max);
        let l0 = lod.floor();
        let t = lod - l0;
        if t == 0.0 {
            return self.sample_level(l0 as usize, face, x, y);
        }
        let coarse = l0 as usize + 1;
        let margin = 0.5 / self.levels[coarse].face_size() as f64;
        let a = self.sample_level_within(l0 as usize, margin, face, x, y);
        let b = self.sample_level_within(coarse, margin, face, x, y);
        std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
    }
}

impl Layer {
    /// Bring the layer up to date after `dense` (the undilated map the layer was built
    /// from, [`Layer::from_rgba`]`(`[`dilate_masked`]`(dense))`) changed inside `rect` only,
    /// e.g. when one tile arrived: the dilation is redone over the rectangle and the two
    /// texels around it, and each mip level over the texels that cover that. The result is
    /// identical to rebuilding the whole layer. Returns, per level, the rectangle of texels
    /// that may have changed (for [`crate::gpu::Renderer::update_layer_region`]).
    pub fn update_region(&mut self, dense: &CubeMap<[u8; 4]>, rect: PixelRect) -> Vec<PixelRect> {
        let n = self.face_size();
        if dense.face_size() != n || rect.is_empty() {
            return Vec::new();
        }
        let out = rect.grown(DILATE_STEPS, n);
        let window = out.grown(DILATE_STEPS, n);
        let dilated = dilate_window(dense, window);
        let ww = (window.x1 - window.x0) as usize;
        let level0 = &mut self.levels[0];
        for y in out.y0..out.y1 {
            for x in out.x0..out.x1 {
                let i = (y - window.y0) as usize * ww + (x - window.x0) as usize;
                *level0.get_mut(out.face, x, y) = dilated[i];
            }
        }
        let mut rects = vec![out];
        for level in 1..self.levels.len() {
            let r = out.coarser(level as u32);
            let (finer, coarser) = self.levels.split_at_mut(level);
            let src = &finer[level - 1];
            let dst = &mut coarser[0];
            for y in r.y0..r.y1.min(dst.face_size()) {
                for x in r.x0..r.x1.min(dst.face_size()) {
                    *dst.get_mut(r.face, x, y) = downsample_texel(src, r.face, x, y);
                }
            }
            rects.push(r);
        }
        rects
    }
}

/// Texel `(x, y)` of face `f` of the half-size map of `map` ([`downsample`]).
fn downsample_texel(map: &CubeMap<[u8; 4]>, f: Face, x: u32, y: u32) -> [u8; 4] {
    let n = map.face_size() as usize;
    let top = map.index(f, 2 * x, 2 * y);
    let data = map.as_slice();
    let quad = [data[top], data[top + 1], data[top + n], data[top + n + 1]];
    downsample_quad(quad)
}

/// The mean of four texels: colour averaged in linear light weighted by alpha (plain where
/// all four are empty), alpha averaged.
fn downsample_quad(quad: [[u8; 4]; 4]) -> [u8; 4] {
    // Four equal texels average to themselves (sRGB bytes round-trip, see the tests): most
    // of a slab layer is empty, and most of the rest is flat.
    if quad[1] == quad[0] && quad[2] == quad[0] && quad[3] == quad[0] {
        return quad[0];
    }
    weighted_mean(quad)
}

/// [`downsample_quad`] without the shortcut.
fn weighted_mean(quad: [[u8; 4]; 4]) -> [u8; 4] {
    let mut rgb = [0.0f32; 3];
    let mut plain = [0.0f32; 3];
    let mut alpha = 0.0f32;
    for c in quad {
        let a = c[3] as f32 / 255.0;
        for k in 0..3 {
            let l = srgb_to_linear(c[k]);
            rgb[k] += l * a;
            plain[k] += l;
        }
        alpha += a;
    }
    let col: [f32; 3] = if alpha > 0.0 {
        rgb.map(|v| v / alpha)
    } else {
        plain.map(|v| v / 4.0)
    };
    [
        linear_to_srgb(col[0]),
        linear_to_srgb(col[1]),
        linear_to_srgb(col[2]),
        (alpha / 4.0 * 255.0).round() as u8,
    ]
}

/// Halve a cube map: colour averaged in linear light weighted by alpha, alpha averaged.
pub fn downsample(map: &CubeMap<[u8; 4]>) -> CubeMap<[u8; 4]> {
    CubeMap::from_fn(map.face_size() / 2, |f, x, y| {
        downsample_texel(map, f, x, y)
    })
}

/// Passes of [`dilate_masked`] (texels of the band it fills around the mask).
const DILATE_STEPS: u32 = 2;

/// Give texels with alpha 0 the mean colour of their opaque 8-neighbours (two passes, so a
/// two-texel band around every mask edge is filled); alpha is left as it is.
pub fn dilate_masked(map: &CubeMap<[u8; 4]>) -> CubeMap<[u8; 4]> {
    let n = map.face_size();
    let faces: Vec<Vec<[u8; 4]>> = Face::ALL
        .iter()
        .map(|&face| {
            dilate_window(
                map,
                PixelRect {
                    face,
                    x0: 0,
                    y0: 0,
                    x1: n,
                    y1: n,
                },
            )
        })
        .collect();
    CubeMap::from_vec(n, faces.concat()).expect("six whole faces")
}

/// [`dilate_masked`] computed inside `window` only (row-major texels of the window). Texels
/// of the window's border that are not the face's border see fewer neighbours than in the
/// whole map, so only texels at least [`DILATE_STEPS`] inside such a border are exact.
fn dilate_window(map: &CubeMap<[u8; 4]>, window: PixelRect) -> Vec<[u8; 4]> {
    let (w, h) = (
        (window.x1 - window.x0) as i64,
        (window.y1 - window.y0) as i64,
    );
    let n = map.face_size() as usize;
    let face = map.face(window.face);
    let mut cur: Vec<[u8; 4]> = Vec::with_capacity((w * h) as usize);
    for y in window.y0 as usize..window.y1 as usize {
        cur.extend_from_slice(&face[y * n + window.x0 as usize..y * n + window.x1 as usize]);
    }
    let mut filled: Vec<bool> = cur.iter().map(|c| c[3] > 0).collect();
    let mut prev = cur.clone();
    let mut prev_filled = filled.clone();
    // Per row, the first and last filled column (none: `(w, -1)`): a texel can only be
    // filled from a row within one of it, and within one column of that row's span.
    let mut spans = vec![(w, -1i64); h as usize];
    for _ in 0..DILATE_STEPS {
        prev.copy_from_slice(&cur);
        prev_filled.copy_from_slice(&filled);
        for (y, span) in spans.iter_mut().enumerate() {
            let row = &prev_filled[y * w as usize..(y + 1) * w as usize];
            *span = match (row.iter().position(|&f| f), row.iter().rposition(|&f| f)) {
                (Some(a), Some(b)) => (a as i64, b as i64),
                _ => (w, -1),
            };
        }
        for y in 0..h {
            let (ya, yb) = ((y - 1).max(0), (y + 1).min(h - 1));
            let (first, last) = (ya..=yb).fold((w, -1), |(a, b), r| {
                let (c, d) = spans[r as usize];
                (a.min(c), b.max(d))
            });
            if first > last {
                continue;
            }
            for x in (first - 1).max(0)..=(last + 1).min(w - 1) {
                let i = (y * w + x) as usize;
                if prev_filled[i] {
                    continue;
                }
                let (xa, xb) = ((x - 1).max(0), (x + 1).min(w - 1));
                let mut sum = [0u32; 3];
                let mut count = 0u32;
                for py in ya..=yb {
                    let row = (py * w) as usize;
                    for px in xa..=xb {
                        let j = row + px as usize;
                        if prev_filled[j] {
                            let c = prev[j];
                            sum[0] += c[0] as u32;
                            sum[1] += c[1] as u32;
                            sum[2] += c[2] as u32;
                            count += 1;
                        }
                    }
                }
                if count == 0 {
                    continue;
                }
                for k in 0..3 {
                    cur[i][k] = (sum[k] / count) as u8;
                }
                filled[i] = true;
            }
        }
    }
    cur
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tables_give_the_computed_conversions() {
        for b in 0..=255u8 {
            assert_eq!(
                srgb_to_linear(b).to_bits(),
                srgb_to_linear_exact(b).to_bits()
            );
        }
        // Around every step of the byte (a float either side), at the ends, past them, and
        // on a dense sweep of [0, 1].
        let mut probes = vec![-1.0, -0.0, 0.0, 1.0, 1.5, f32::INFINITY, f32::NEG_INFINITY];
        for b in 1..=255u8 {
            let t = first_at_least(b);
            probes.extend([
                t,
                f32::from_bits(t.to_bits() - 1),
                f32::from_bits(t.to_bits() + 1),
            ]);
        }
        probes.extend((0..=200_000).map(|i| i as f32 / 200_000.0));
        for c in probes {
            assert_eq!(linear_to_srgb(c), linear_to_srgb_exact(c), "{c:e}");
        }
        assert_eq!(linear_to_srgb(f32::NAN), linear_to_srgb_exact(f32::NAN));
    }

    proptest::proptest! {
        #[test]
        fn linear_to_srgb_table_matches_for_any_float(bits in proptest::prelude::any::<u32>()) {
            let c = f32::from_bits(bits);
            proptest::prop_assert_eq!(linear_to_srgb(c), linear_to_srgb_exact(c));
        }
    }

    /// The dilation as specified, texel by texel over each whole face (no row spans).
    fn dilate_reference(map: &CubeMap<[u8; 4]>) -> CubeMap<[u8; 4]> {
        let n = map.face_size() as i64;
        let mut cur = map.clone();
        let mut filled = map.map(|c| c[3] > 0);
        for _ in 0..DILATE_STEPS {
            let (prev, prev_filled) = (cur.clone(), filled.clone());
            for f in Face::ALL {
                for y in 0..n {
                    for x in 0..n {
                        if *prev_filled.get(f, x as u32, y as u32) {
                            continue;
                        }
                        let mut sum = [0u32; 3];
                        let mut count = 0;
                        for dy in -1..=1 {
                            for dx in -1..=1 {
                                let (px, py) = (x + dx, y + dy);
                                if px < 0 || py < 0 || px >= n || py >= n {
                                    continue;
                                }
                                if *prev_filled.get(f, px as u32, py as u32) {
                                    let c = prev.get(f, px as u32, py as u32);
                                    for k in 0..3 {
                                        sum[k] += c[k] as u32;
                                    }
                                    count += 1;
                                }
                            }
                        }
                        if count == 0 {
                            continue;
                        }
                        let t = cur.get_mut(f, x as u32, y as u32);
                        for k in 0..3 {
                            t[k] = (sum[k] / count) as u8;
                        }
                        *filled.get_mut(f, x as u32, y as u32) = true;
                    }
                }
            }
        }
        cur
    }

    proptest::proptest! {
        #[test]
        fn dilation_matches_the_texel_by_texel_rule(
            seed in proptest::prelude::any::<u64>(),
            density in 0.0f64..0.3,
        ) {
            let mut state = seed | 1;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let map = CubeMap::from_fn(12, |_, _, _| {
                let r = next();
                if (r % 10_000) as f64 / 10_000.0 < density {
                    [(r >> 16) as u8, (r >> 24) as u8, (r >> 32) as u8, (r >> 40) as u8 | 1]
                } else {
                    [(r >> 48) as u8, 0, 0, 0]
                }
            });
            proptest::prop_assert_eq!(dilate_masked(&map), dilate_reference(&map));
        }
    }

    #[test]
    fn four_equal_texels_average_to_themselves_by_the_general_rule() {
        // What makes the shortcut in `downsample_quad` exact: every alpha, with and without
        // colour, and every colour byte at several alphas.
        for v in 0..=255u8 {
            for c in [
                [v, v, v, v],
                [v, 255 - v, v / 2, 255],
                [0, 0, 0, v],
                [v, 17, 200, 0],
                [200, v, 3, 1],
                [9, 250, v, 128],
            ] {
                assert_eq!(weighted_mean([c; 4]), c, "{c:?}");
            }
        }
    }

    #[test]
    fn srgb_round_trips_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb(srgb_to_linear(b)), b);
        }
    }

    #[test]
    fn mip_chain_halves_while_even_and_keeps_constant_colour() {
        let l = Layer::from_rgba(CubeMap::filled(12, [200, 100, 50, 255]));
        let sizes: Vec<u32> = l.levels.iter().map(|m| m.face_size()).collect();
        assert_eq!(sizes, vec![12, 6, 3]);
        for m in &l.levels {
            assert!(m.as_slice().iter().all(|c| *c == [200, 100, 50, 255]));
        }
    }

    #[test]
    fn transparent_texels_do_not_darken_mips() {
        let mut m = CubeMap::filled(4, [0u8, 0, 0, 0]);
        *m.get_mut(Face::PosX, 0, 0) = [255, 255, 255, 255];
        let d = downsample(&m);
        assert_eq!(*d.get(Face::PosX, 0, 0), [255, 255, 255, 64]);
    }

    #[test]
    fn sampling_at_texel_centres_is_exact() {
        let m = CubeMap::from_fn(4, |f, x, y| {
            [x as u8 * 60, y as u8 * 60, f.index() as u8, 255]
        });
        let l = Layer::from_rgba(m.clone());
        for f in Face::ALL {
            for y in 0..4 {
                for x in 0..4 {
                    let s = l.sample(0.0, f, x as f64 + 0.5, y as f64 + 0.5);
                    let c = m.get(f, x, y);
                    for k in 0..3 {
                        assert!((s[k] - srgb_to_linear(c[k])).abs() < 1e-6);
                    }
                }
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Updating the region of a changed rectangle gives the same layer as rebuilding it.
        #[test]
        fn region_update_matches_a_rebuild(
            seed in 0u64..1000,
            face in 0usize..6,
            x0 in 0u32..16,
            y0 in 0u32..16,
            w in 1u32..8,
            h in 1u32..8,
        ) {
            let n = 16;
            let bits = |f: Face, x: u32, y: u32, salt: u64| {
                let v = (f.index() as u64 * 977 + x as u64 * 131 + y as u64 * 31 + seed * 7 + salt)
                    .wrapping_mul(0x9e37_79b9_7f4a_7c15);
                (v >> 40) as u8
            };
            let before = CubeMap::from_fn(n, |f, x, y| {
                let a = if bits(f, x, y, 1) > 140 { 255 } else { 0 };
                [bits(f, x, y, 2), bits(f, x, y, 3), bits(f, x, y, 4), a]
            });
            let rect = PixelRect {
                face: Face::ALL[face],
                x0,
                y0,
                x1: (x0 + w).min(n),
                y1: (y0 + h).min(n),
            };
            let mut after = before.clone();
            for y in rect.y0..rect.y1 {
                for x in rect.x0..rect.x1 {
                    *after.get_mut(rect.face, x, y) = [9, (x * 16) as u8, (y * 16) as u8, 255];
                }
            }
            let mut layer = Layer::from_rgba(dilate_masked(&before));
            let rects = layer.update_region(&after, rect);
            let rebuilt = Layer::from_rgba(dilate_masked(&after));
            proptest::prop_assert_eq!(rects.len(), rebuilt.levels.len());
            proptest::prop_assert!(layer == rebuilt);
        }
    }

    #[test]
    fn dilation_fills_a_band_around_the_mask() {
        let mut m = CubeMap::filled(8, [0u8, 0, 0, 0]);
        *m.get_mut(Face::PosY, 3, 3) = [90, 80, 70, 255];
        let d = dilate_masked(&m);
        assert_eq!(*d.get(Face::PosY, 5, 5), [90, 80, 70, 0]);
        assert_eq!(*d.get(Face::PosY, 6, 6), [0, 0, 0, 0]);
    }
}
