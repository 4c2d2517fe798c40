//! The integer mip pyramid: box filter with remainders (eq. 1), block geometry on odd edges,
//! and which pixel eq. 3 rebuilds.

use super::{Image, PtmError};

/// Size of level `level` of a `width × height` image (each level halves, rounding up).
pub fn level_dims(width: u32, height: u32, level: u32) -> (u32, u32) {
    let mut w = width;
    let mut h = height;
    for _ in 0..level {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
    }
    (w, h)
}

/// Largest sensible level count: down to 1 × 1 (`1 + ⌈log2 max(w, h)⌉`).
pub fn max_levels(width: u32, height: u32) -> u8 {
    let m = width.max(height).max(1);
    let ceil_log2 = 32 - (m - 1).leading_zeros();
    1 + ceil_log2 as u8
}

/// True when pixel (x, y) of a `w × h` level is the one rebuilt by eq. 3: the last pixel of
/// its 2×2 block in raster order.
#[inline]
pub(crate) fn is_rebuilt(x: u32, y: u32, w: u32, h: u32) -> bool {
    (x & 1 == 1 || x + 1 == w) && (y & 1 == 1 || y + 1 == h)
}

/// Number of pixels stored in the partial level of a `w × h` level.
pub(crate) fn stored_count(w: u32, h: u32) -> usize {
    let (pw, ph) = (w.div_ceil(2), h.div_ceil(2));
    w as usize * h as usize - pw as usize * ph as usize
}

/// The full pyramid of an image with its residuals; `levels[0]` is the image itself.
#[derive(Clone, Debug)]
pub struct MipChain {
    pub levels: Vec<Image>,
    /// `residuals[n]`: one value in 0..=3 per pixel and channel of `levels[n + 1]`, the
    /// remainder of the box filter from level `n`.
    pub residuals: Vec<Vec<u8>>,
}

impl MipChain {
    /// Builds `level_count` levels (1 ..= [`max_levels`]).
    pub fn build(image: &Image, level_count: u8) -> Result<MipChain, PtmError> {
        let max = max_levels(image.width, image.height);
        if level_count == 0 || level_count > max {
            return Err(PtmError::InvalidImage(format!(
                "{level_count} levels requested; a {}×{} image has 1 to {max}",
                image.width, image.height
            )));
        }
        let mut levels = vec![image.clone()];
        let mut residuals = Vec::new();
        for _ in 1..level_count {
            let (parent, res) = reduce(levels.last().expect("level 0 exists"));
            levels.push(parent);
            residuals.push(res);
        }
        Ok(MipChain { levels, residuals })
    }
}

/// One step of eq. 1: the parent level and the remainders.
fn reduce(img: &Image) -> (Image, Vec<u8>) {
    let (w, h, c) = (img.width, img.height, img.channels as usize);
    let (pw, ph) = (w.div_ceil(2), h.div_ceil(2));
    let mut parent = vec![0u8; pw as usize * ph as usize * c];
    let mut res = vec![0u8; parent.len()];
    let row = w as usize * c;
    for j in 0..ph {
        let y0 = 2 * j as usize;
        let two_rows = y0 + 1 < h as usize;
        for i in 0..pw {
            let x0 = 2 * i as usize;
            let two_cols = x0 + 1 < w as usize;
            let n = 1 + two_rows as u32 + two_cols as u32 + (two_rows && two_cols) as u32;
            let base = y0 * row + x0 * c;
            let out = (j as usize * pw as usize + i as usize) * c;
            for k in 0..c {
                let mut sum = img.data[base + k] as u32;
                if two_cols {
                    sum += img.data[base + c + k] as u32;
                }
                if two_rows {
                    sum += img.data[base + row + k] as u32;
                    if two_cols {
                        sum += img.data[base + row + c + k] as u32;
                    }
                }
                let p = if n == 4 { sum >> 2 } else { sum / n };
                parent[out + k] = p as u8;
                res[out + k] = (sum - n * p) as u8;
            }
        }
    }
    let parent = Image {
        width: pw,
        height: ph,
        channels: img.channels,
        data: parent,
    };
    (parent, res)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_sizes_round_up_down_to_one_pixel() {
        assert_eq!(level_dims(5, 3, 1), (3, 2));
        assert_eq!(level_dims(5, 3, 2), (2, 1));
        assert_eq!(level_dims(5, 3, 3), (1, 1));
        assert_eq!(max_levels(1, 1), 1);
        assert_eq!(max_levels(2, 1), 2);
        assert_eq!(max_levels(3, 3), 3);
        assert_eq!(max_levels(4, 4), 3);
        assert_eq!(max_levels(5, 3), 4);
        assert_eq!(max_levels(256, 256), 9);
        assert_eq!(max_levels(u32::MAX, 1), 33);
    }

    #[test]
    fn box_filter_keeps_remainders_eq1() {
        // 3×3 grey: a full block, two 2-pixel edge blocks and a 1×1 corner.
        let img = Image::new(3, 3, 1, vec![1, 2, 10, 3, 5, 11, 7, 8, 9]).unwrap();
        let (p, r) = reduce(&img);
        assert_eq!((p.width, p.height), (2, 2));
        // full block 1+2+3+5 = 11 → 2 rem 3; right column 10+11 = 21 → 10 rem 1;
        // bottom row 7+8 = 15 → 7 rem 1; corner 9 → 9 rem 0.
        assert_eq!(p.data, vec![2, 10, 7, 9]);
        assert_eq!(r, vec![3, 1, 1, 0]);
    }

    #[test]
    fn rebuilt_pixel_is_last_of_each_block() {
        let rebuilt: Vec<(u32, u32)> = (0..3)
            .flat_map(|y| (0..3).map(move |x| (x, y)))
            .filter(|&(x, y)| is_rebuilt(x, y, 3, 3))
            .collect();
        assert_eq!(rebuilt, vec![(1, 1), (2, 1), (1, 2), (2, 2)]);
        assert_eq!(stored_count(3, 3), 5);
        assert_eq!(stored_count(1, 1), 0);
        assert_eq!(stored_count(256, 256), 3 * 128 * 128);
    }
}
