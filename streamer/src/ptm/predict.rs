//! The prediction of [`Method::Zstd`](super::Method::Zstd) groups.
//!
//! A level is scanned in raster order, its samples interleaved. A stored sample is predicted
//! from its causal neighbours in the same level — left W, up N, up-left NW, all already
//! decoded, rebuilt pixels included — with the median edge detector of LOCO-I:
//! `MED = min(W, N) if NW ≥ max(W, N), max(W, N) if NW ≤ min(W, N), else W + N − NW`; on the
//! first row W, on the first column N, and the very first pixel is predicted by its parent.
//! The coded value is `(I − pred) mod 256`.
//!
//! The parent level predicts the rebuilt pixel (eq. 3) instead: once W, N, NW of the block's
//! last pixel are known, the parent fixes the block sum to `n·parent + ε`, so the residual is
//! coded relative to the one the MED prediction implies,
//! `guess = clamp(others + MED − n·parent, 0, n − 1)`, as `(ε − guess) mod 4`, one byte per
//! sample (zstd's entropy coder packs them). Rebuilt pixels are computed as soon as the rest of
//! their block is known, so they serve as neighbours immediately.
//!
//! (Measured on rendered castle tiles: predicting stored pixels from the bilinear upsampling
//! of the parent, alone or corrected by the neighbours' detail, coded 1.5× larger than this.)

use super::pyramid::is_rebuilt;
use super::{Image, PtmError};

/// MED written branch-free: `a + b − c` clamped to `[min(a, b), max(a, b)]` is the same
/// function, and avoids mispredicted branches on textured content.
#[inline(always)]
fn med(a: i32, b: i32, c: i32) -> i32 {
    (a + b - c).clamp(a.min(b), a.max(b))
}

/// Prediction of sample `at` (pixel (x, y)) from the decoded samples of `data`; `first` is
/// the parent's sample for the very first pixel.
#[inline(always)]
fn predict(data: &[u8], first: u8, at: usize, x: usize, y: usize, row: usize, c: usize) -> u8 {
    match (x > 0, y > 0) {
        (true, true) => med(
            data[at - c] as i32,
            data[at - row] as i32,
            data[at - row - c] as i32,
        ) as u8,
        (true, false) => data[at - c],
        (false, true) => data[at - row],
        (false, false) => first,
    }
}

/// The residual predicted from the rebuilt pixel's own prediction: what `ε` would be if the
/// pixel equalled `pred`, clamped to the block's range.
#[inline(always)]
fn residual_guess(others: i32, pred: u8, cnt: i32, parent: u8) -> u8 {
    (others + pred as i32 - cnt * parent as i32).clamp(0, cnt - 1) as u8
}

/// Sum of the block's pixels other than the rebuilt one, its pixel count, and the block's
/// first sample offset, for rebuilt pixel (x, y).
#[inline(always)]
#[expect(clippy::too_many_arguments, reason = "a hot helper on plain integers")]
fn block_of(
    data: &[u8],
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    row: usize,
    c: usize,
    k: usize,
) -> (i32, i32) {
    let (x0, y0) = ((x & !1) as usize, (y & !1) as usize);
    let two_cols = x0 + 1 < w as usize;
    let two_rows = y0 + 1 < h as usize;
    let cnt = 1 + two_rows as i32 + two_cols as i32 + (two_rows && two_cols) as i32;
    let base = y0 * row + x0 * c + k;
    let others = match cnt {
        4 => data[base] as i32 + data[base + c] as i32 + data[base + row] as i32,
        2 => data[base] as i32,
        _ => 0,
    };
    (others, cnt)
}

/// The coded planes of a level: one residual plane (`(ε − guess) mod 4` per parent sample),
/// then `(I − pred) mod 256` of every stored sample, samples interleaved.
pub(crate) fn encode_level(level: &Image, parent: &Image, residuals: &[u8]) -> Vec<u8> {
    let (w, h, c) = (level.width, level.height, level.channels as usize);
    let row = w as usize * c;
    let stored = super::pyramid::stored_count(w, h);
    let np = parent.width as usize * parent.height as usize;
    let mut out = vec![0u8; np * c + stored * c];
    let (res_out, out) = out.split_at_mut(np * c);
    let mut n = 0;
    let mut m = 0;
    for y in 0..h {
        for x in 0..w {
            let at = y as usize * row + x as usize * c;
            if is_rebuilt(x, y, w, h) {
                for k in 0..c {
                    let p = predict(
                        &level.data,
                        parent.data[k],
                        at + k,
                        x as usize,
                        y as usize,
                        row,
                        c,
                    );
                    let (others, cnt) = block_of(&level.data, x, y, w, h, row, c, k);
                    let guess = residual_guess(others, p, cnt, parent.data[m * c + k]);
                    res_out[m * c + k] = residuals[m * c + k].wrapping_sub(guess) & 3;
                }
                m += 1;
                continue;
            }
            for k in 0..c {
                let p = predict(
                    &level.data,
                    parent.data[k],
                    at + k,
                    x as usize,
                    y as usize,
                    row,
                    c,
                );
                out[n * c + k] = level.data[at + k].wrapping_sub(p);
            }
            n += 1;
        }
    }
    let mut all = res_out.to_vec();
    all.extend_from_slice(out);
    all
}

/// Inverse of [`encode_level`] plus eq. 3 for the rebuilt pixels.
pub(crate) fn decode_level(
    plain: &[u8],
    parent: &Image,
    w: u32,
    h: u32,
    level: u32,
) -> Result<Vec<u8>, PtmError> {
    match parent.channels {
        1 => decode_level_c::<1>(plain, parent, w, h, level),
        2 => decode_level_c::<2>(plain, parent, w, h, level),
        3 => decode_level_c::<3>(plain, parent, w, h, level),
        _ => decode_level_c::<4>(plain, parent, w, h, level),
    }
}

/// [`decode_level`] for `C` channels, row by row (the channel loops unroll).
fn decode_level_c<const C: usize>(
    plain: &[u8],
    parent: &Image,
    w: u32,
    h: u32,
    level: u32,
) -> Result<Vec<u8>, PtmError> {
    let (wu, hu) = (w as usize, h as usize);
    let pw = parent.width as usize;
    let np = pw * parent.height as usize;
    let (res_plane, planes) = plain.split_at(np * C);
    let row = wu * C;
    let mut data = vec![0u8; row * hu];
    let mut src = planes.chunks_exact(C);
    let mut first = [0u8; C];
    first.copy_from_slice(&parent.data[..C]);
    for y in 0..hu {
        let (above, rest) = data.split_at_mut(y * row);
        let cur = &mut rest[..row];
        let prev: &[u8] = if y > 0 { &above[(y - 1) * row..] } else { &[] };
        let last_of_block_row = y & 1 == 1 || y + 1 == hu;
        for x in 0..wu {
            let mut p = [0u8; C];
            if y > 0 && x > 0 {
                for k in 0..C {
                    let (a, b, c) = (cur[(x - 1) * C + k], prev[x * C + k], prev[(x - 1) * C + k]);
                    p[k] = med(a as i32, b as i32, c as i32) as u8;
                }
            } else if x > 0 {
                p.copy_from_slice(&cur[(x - 1) * C..x * C]);
            } else if y > 0 {
                p.copy_from_slice(&prev[..C]);
            } else {
                p = first;
            }
            let rebuilt = last_of_block_row && (x & 1 == 1 || x + 1 == wu);
            if !rebuilt {
                let s = src.next().expect("length checked against the header");
                for k in 0..C {
                    cur[x * C + k] = s[k].wrapping_add(p[k]);
                }
                continue;
            }
            // Eq. 3: the last pixel of the block from its parent, residual and the others.
            let x0 = x & !1;
            let two_cols = x0 + 1 < wu;
            let two_rows = (y & !1) + 1 < hu;
            let m = (y >> 1) * pw + (x >> 1);
            let cnt = 1 + two_rows as i32 + two_cols as i32 + (two_rows && two_cols) as i32;
            for k in 0..C {
                let others = match cnt {
                    4 => {
                        prev[x0 * C + k] as i32
                            + prev[(x0 + 1) * C + k] as i32
                            + cur[x0 * C + k] as i32
                    }
                    2 if two_cols => cur[x0 * C + k] as i32,
                    2 => prev[x0 * C + k] as i32,
                    _ => 0,
                };
                let pv = parent.data[m * C + k];
                let coded = res_plane[m * C + k];
                let r = (coded.wrapping_add(residual_guess(others, p[k], cnt, pv)) & 3) as i32;
                let v = cnt * pv as i32 + r - others;
                if coded > 3 || r >= cnt || !(0..=255).contains(&v) {
                    return Err(PtmError::BadResidual {
                        level,
                        x: x as u32,
                        y: y as u32,
                        channel: k as u8,
                        value: if coded > 3 {
                            coded as i32
                        } else if r >= cnt {
                            r
                        } else {
                            v
                        },
                    });
                }
                cur[x * C + k] = v as u8;
            }
        }
    }
    Ok(data)
}
