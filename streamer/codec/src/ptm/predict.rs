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
//!
//! **Decoding.** Every sample waits for its left neighbour (the MED recurrence), so a row is a
//! serial chain. The decoder keeps it short: the channels of a pixel sit in the lanes of one
//! `wide::i16x8` vector (a few vector instructions per pixel instead of a few scalar ones per
//! channel), and a stored-only row and the alternating row below it are rebuilt in one pass,
//! the lower one trailing by a pair, so the two chains overlap. Damage is collected as a lane
//! mask; a damaged row is rebuilt again by the scalar path, which names the first bad pixel.
//! (Measured alternatives that remove the left dependency — predicting the first pixel of
//! each block from above, or from the parent — cost 5–12 % in size on the castle tiles.)

use wide::i16x8;

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

/// A pixel's `C` samples.
type Px<const C: usize> = [u8; C];

#[inline(always)]
fn px<const C: usize>(s: &[u8]) -> Px<C> {
    let mut p = [0u8; C];
    p.copy_from_slice(&s[..C]);
    p
}

/// MED of whole pixels, channel by channel.
#[inline(always)]
fn med_px<const C: usize>(w: Px<C>, n: Px<C>, nw: Px<C>) -> Px<C> {
    // The same function on bytes with saturating arithmetic (so it maps to byte-wise vector
    // instructions): `a + b − c` saturated to 0..=255 is `b + (a − c)⁺ − (c − a)⁺` with
    // saturation, and saturating changes nothing once clamped to `[min(a, b), max(a, b)]`.
    let mut p = [0u8; C];
    for k in 0..C {
        let (a, b, c) = (w[k], n[k], nw[k]);
        let grad = b
            .saturating_add(a.saturating_sub(c))
            .saturating_sub(c.saturating_sub(a));
        p[k] = grad.min(a.max(b)).max(a.min(b));
    }
    p
}

#[inline(always)]
fn add_px<const C: usize>(a: Px<C>, b: &[u8]) -> Px<C> {
    let mut p = [0u8; C];
    for k in 0..C {
        p[k] = a[k].wrapping_add(b[k]);
    }
    p
}

/// Eq. 3 for one rebuilt pixel: `cnt` pixels in the block, `others` the sum of the rest,
/// `pred` its prediction, `parent` and `coded` its parent's samples and coded residuals.
/// On damage, the channel and the offending value.
#[inline(always)]
fn rebuild_px<const C: usize>(
    others: [i32; C],
    cnt: i32,
    pred: Px<C>,
    parent: &[u8],
    coded: &[u8],
) -> Result<Px<C>, (u8, i32)> {
    let mut out = [0u8; C];
    let mut ok = true;
    for k in 0..C {
        let pv = parent[k];
        let r = (coded[k].wrapping_add(residual_guess(others[k], pred[k], cnt, pv)) & 3) as i32;
        let v = cnt * pv as i32 + r - others[k];
        ok &= coded[k] <= 3 && r < cnt && (0..=255).contains(&v);
        out[k] = v as u8;
    }
    if ok {
        Ok(out)
    } else {
        Err(rebuild_error(others, cnt, pred, parent, coded))
    }
}

/// The first damaged channel of a rebuilt pixel and its value, as reported in
/// [`PtmError::BadResidual`].
#[cold]
#[inline(never)]
fn rebuild_error<const C: usize>(
    others: [i32; C],
    cnt: i32,
    pred: Px<C>,
    parent: &[u8],
    coded: &[u8],
) -> (u8, i32) {
    for k in 0..C {
        let pv = parent[k];
        let r = (coded[k].wrapping_add(residual_guess(others[k], pred[k], cnt, pv)) & 3) as i32;
        let v = cnt * pv as i32 + r - others[k];
        if coded[k] > 3 {
            return (k as u8, coded[k] as i32);
        }
        if r >= cnt {
            return (k as u8, r);
        }
        if !(0..=255).contains(&v) {
            return (k as u8, v);
        }
    }
    unreachable!("called only on a damaged pixel")
}

/// [`decode_level`] for `C` channels, row by row (the channel loops unroll). The first row
/// takes a general per-pixel path; the others use two specialised loops: rows without rebuilt
/// pixels (even rows except the last) and rows of alternating stored and rebuilt pixels.
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
    let (res_plane, mut src) = plain.split_at(np * C);
    let row = wu * C;
    let mut data = vec![0u8; row * hu];
    let bad = |x: usize, y: usize, (channel, value): (u8, i32)| PtmError::BadResidual {
        level,
        x: x as u32,
        y: y as u32,
        channel,
        value,
    };
    // Row 0: every case of the general rule.
    {
        let cur = &mut data[..row];
        let last_of_block_row = hu == 1;
        for x in 0..wu {
            let p: Px<C> = if x > 0 {
                px(&cur[(x - 1) * C..])
            } else {
                px(&parent.data[..C])
            };
            let rebuilt = last_of_block_row && (x & 1 == 1 || x + 1 == wu);
            if !rebuilt {
                let (s, rest) = src.split_at(C);
                src = rest;
                cur[x * C..(x + 1) * C].copy_from_slice(&add_px(p, s));
                continue;
            }
            let x0 = x & !1;
            let (cnt, others) = if x0 + 1 < wu {
                (2, px::<C>(&cur[x0 * C..]).map(i32::from))
            } else {
                (1, [0; C])
            };
            let m = x >> 1;
            let v = rebuild_px(
                others,
                cnt,
                p,
                &parent.data[m * C..(m + 1) * C],
                &res_plane[m * C..(m + 1) * C],
            )
            .map_err(|e| bad(x, 0, e))?;
            cur[x * C..(x + 1) * C].copy_from_slice(&v);
        }
    }
    let mut y = 1;
    while y < hu {
        let (above, rest) = data.split_at_mut(y * row);
        let prev = &above[(y - 1) * row..];
        let pairs = wu / 2;
        let rebuild_row = y & 1 == 1 || y + 1 == hu;
        if !rebuild_row {
            let (s, rest_src) = src.split_at(row);
            src = rest_src;
            let (cur, below) = rest.split_at_mut(row);
            if y + 1 == hu || pairs == 0 {
                stored_row::<C>(prev, s, cur);
                y += 1;
                continue;
            }
            // The row below is an alternating row of 2×2 blocks: both rows are rebuilt in one
            // pass, the lower one trailing by a pair, so their two serial chains overlap.
            let odd = &mut below[..row];
            let (s_odd, rest_src) = src.split_at(pairs * C);
            src = rest_src;
            let prow = ((y + 1) >> 1) * pw * C;
            let parents = &parent.data[prow..prow + pw * C];
            let coded_row = &res_plane[prow..prow + pw * C];
            if !stored_and_pair_rows::<C>(prev, s, cur, s_odd, parents, coded_row, odd) {
                // Damaged: the scalar path rebuilds the row again and names the first bad pixel.
                pair_row_scalar::<C>(cur, s_odd, parents, coded_row, odd, true)
                    .map_err(|(x, e)| bad(x, y + 1, e))?;
            }
            right_edge::<C>(cur, odd, parents, coded_row, true)
                .map_err(|e| bad(wu - 1, y + 1, e))?;
            y += 2;
            continue;
        }
        // Alternating row: stored pixel 2i, rebuilt pixel 2i + 1 (a full 2×2 block when y is
        // odd, a 2×1 block on an odd last row), and a lone rebuilt pixel on an odd right edge.
        let cur = &mut rest[..row];
        let two_rows = y & 1 == 1;
        let (s, rest_src) = src.split_at(pairs * C);
        src = rest_src;
        let prow = (y >> 1) * pw * C;
        let parents = &parent.data[prow..prow + pw * C];
        let coded_row = &res_plane[prow..prow + pw * C];
        let row_ok = if two_rows {
            pair_row_lanes::<C, true>(prev, s, parents, coded_row, cur)
        } else {
            pair_row_lanes::<C, false>(prev, s, parents, coded_row, cur)
        };
        if !row_ok {
            // Damaged: the scalar path rebuilds the row again and names the first bad pixel.
            pair_row_scalar::<C>(prev, s, parents, coded_row, cur, two_rows)
                .map_err(|(x, e)| bad(x, y, e))?;
        }
        right_edge::<C>(prev, cur, parents, coded_row, two_rows).map_err(|e| bad(wu - 1, y, e))?;
        y += 1;
    }
    Ok(data)
}

/// The lone rebuilt pixel of an alternating row on an odd right edge (nothing to do on an
/// even width): a 1×2 block below `prev`'s last pixel when `two_rows`, else a 1×1 block.
fn right_edge<const C: usize>(
    prev: &[u8],
    cur: &mut [u8],
    parents: &[u8],
    coded_row: &[u8],
    two_rows: bool,
) -> Result<(), (u8, i32)> {
    let wu = cur.len() / C;
    if wu & 1 == 0 {
        return Ok(());
    }
    let (x, pairs) = (wu - 1, wu / 2);
    let n: Px<C> = px(&prev[x * C..]);
    let p = if x == 0 {
        n
    } else {
        med_px(px(&cur[(x - 1) * C..]), n, px(&prev[(x - 1) * C..]))
    };
    let (cnt, others) = if two_rows {
        (2, n.map(i32::from))
    } else {
        (1, [0; C])
    };
    let v = rebuild_px(
        others,
        cnt,
        p,
        &parents[pairs * C..(pairs + 1) * C],
        &coded_row[pairs * C..(pairs + 1) * C],
    )?;
    cur[x * C..(x + 1) * C].copy_from_slice(&v);
    Ok(())
}

/// A row without rebuilt pixels: MED of every pixel plus its coded error.
fn stored_row<const C: usize>(prev: &[u8], s: &[u8], cur: &mut [u8]) {
    // The serial chain through the left pixel: the channels in the lanes of a vector.
    let mask = i16x8::splat(0xff);
    let mut nw = lanes::<C>(prev);
    let mut left = (nw + lanes::<C>(s)) & mask;
    store_lanes::<C>(left, cur);
    for ((out, s), n) in cur[C..]
        .chunks_exact_mut(C)
        .zip(s[C..].chunks_exact(C))
        .zip(prev[C..].chunks_exact(C))
    {
        let n = lanes::<C>(n);
        left = (med_lanes(left, n, nw) + lanes::<C>(s)) & mask;
        store_lanes::<C>(left, out);
        nw = n;
    }
}

/// Constants of [`pair_step`] for blocks of `cnt` pixels.
#[derive(Clone, Copy)]
struct PairConsts {
    cnt: i16x8,
    top: i16x8,
    zero: i16x8,
    three: i16x8,
    max: i16x8,
}

impl PairConsts {
    #[inline(always)]
    fn new(cnt: i16) -> PairConsts {
        PairConsts {
            cnt: i16x8::splat(cnt),
            top: i16x8::splat(cnt - 1),
            zero: i16x8::splat(0),
            three: i16x8::splat(3),
            max: i16x8::splat(255),
        }
    }
}

/// One (stored, rebuilt) pair of an alternating row, channels in lanes: `left`/`nw` are the
/// pixel left of the pair and the one above that, `n0`/`n1` the two above the pair, `two_rows`
/// whether the block includes them. Returns both pixels and the lanes found damaged.
#[inline(always)]
#[expect(clippy::too_many_arguments, reason = "a hot helper on vectors")]
fn pair_step(
    left: i16x8,
    nw: i16x8,
    n0: i16x8,
    n1: i16x8,
    s: i16x8,
    par: i16x8,
    coded: i16x8,
    two_rows: bool,
    k: PairConsts,
) -> (i16x8, i16x8, i16x8) {
    let a = (med_lanes(left, n0, nw) + s) & k.max;
    // Eq. 3 with the residual guessed from the rebuilt pixel's MED (see `rebuild_px`): `t`
    // is the pixel's value for ε = 0.
    let p1 = med_lanes(a, n1, n0);
    let others = if two_rows { a + n0 + n1 } else { a };
    let t = k.cnt * par - others;
    let r = (coded + (p1 - t).max(k.zero).min(k.top)) & k.three;
    let b = t + r;
    let damaged = b.simd_gt(k.max) | b.simd_lt(k.zero) | r.simd_gt(k.top) | coded.simd_gt(k.three);
    (a, b, damaged)
}

/// A stored-only row (`cur`, below `prev`) and the alternating row of 2×2 blocks below it
/// (`odd`) in one pass: the lower row's pair `i − 1` is rebuilt right after the upper row's
/// pair `i`, from the upper pixels still in registers, so the two serial chains overlap.
/// Needs at least one pair. On an odd width the upper row's last pixel is rebuilt here, the
/// lower one's (a 1×2 block) is left to [`right_edge`]. Returns false on damage (as
/// [`pair_row_lanes`]).
fn stored_and_pair_rows<const C: usize>(
    prev: &[u8],
    s: &[u8],
    cur: &mut [u8],
    s_odd: &[u8],
    parents: &[u8],
    coded_row: &[u8],
    odd: &mut [u8],
) -> bool {
    let k = PairConsts::new(4);
    let mask = k.max;
    let wu = cur.len() / C;
    // The upper row's first pair (first column: MED is the pixel above).
    let mut nw = lanes::<C>(prev);
    let mut u0 = (nw + lanes::<C>(s)) & mask;
    let n1 = lanes::<C>(&prev[C..]);
    let mut u1 = (med_lanes(u0, n1, nw) + lanes::<C>(&s[C..])) & mask;
    store_lanes::<C>(u0, cur);
    store_lanes::<C>(u1, &mut cur[C..]);
    nw = n1;
    let mut left = u1;
    // The lower row starts below (u0, u1), its first column predicted from above.
    let (mut nw_odd, mut left_odd) = (u0, u0);
    let mut damaged = k.zero;
    let upper = cur[2 * C..]
        .chunks_exact_mut(2 * C)
        .zip(prev[2 * C..].chunks_exact(2 * C))
        .zip(s[2 * C..].chunks_exact(2 * C));
    let mut lower = odd
        .chunks_exact_mut(2 * C)
        .zip(s_odd.chunks_exact(C))
        .zip(parents.chunks_exact(C).zip(coded_row.chunks_exact(C)));
    for ((out, up), su) in upper {
        let n0 = lanes::<C>(up);
        let n1 = lanes::<C>(&up[C..]);
        let a = (med_lanes(left, n0, nw) + lanes::<C>(su)) & mask;
        let b = (med_lanes(a, n1, n0) + lanes::<C>(&su[C..])) & mask;
        store_lanes::<C>(a, out);
        store_lanes::<C>(b, &mut out[C..]);
        left = b;
        nw = n1;
        let ((o, so), (par, coded)) = lower.next().expect("one lower pair per upper pair");
        let (c, d, bad) = pair_step(
            left_odd,
            nw_odd,
            u0,
            u1,
            lanes::<C>(so),
            lanes::<C>(par),
            lanes::<C>(coded),
            true,
            k,
        );
        damaged |= bad;
        store_lanes::<C>(c, o);
        store_lanes::<C>(d, &mut o[C..]);
        (left_odd, nw_odd) = (d, u1);
        (u0, u1) = (a, b);
    }
    // The lower row's last pair, below the upper row's last pair.
    let ((o, so), (par, coded)) = lower.next().expect("at least one pair");
    let (c, d, bad) = pair_step(
        left_odd,
        nw_odd,
        u0,
        u1,
        lanes::<C>(so),
        lanes::<C>(par),
        lanes::<C>(coded),
        true,
        k,
    );
    damaged |= bad;
    store_lanes::<C>(c, o);
    store_lanes::<C>(d, &mut o[C..]);
    if wu & 1 == 1 {
        let x = wu - 1;
        let n = lanes::<C>(&prev[x * C..]);
        let v = (med_lanes(left, n, nw) + lanes::<C>(&s[x * C..])) & mask;
        store_lanes::<C>(v, &mut cur[x * C..]);
    }
    damaged.to_array() == [0; 8]
}

/// The first `C` samples of `b` in the low lanes of a vector, the other lanes 0.
#[inline(always)]
fn lanes<const C: usize>(b: &[u8]) -> i16x8 {
    let mut a = [0i16; 8];
    for (v, s) in a.iter_mut().zip(&b[..C]) {
        *v = *s as i16;
    }
    i16x8::new(a)
}

/// Writes the low `C` lanes of `v` (each in 0..=255) to `out`.
#[inline(always)]
fn store_lanes<const C: usize>(v: i16x8, out: &mut [u8]) {
    for (o, v) in out[..C].iter_mut().zip(v.to_array()) {
        *o = v as u8;
    }
}

/// MED of every lane (the lanes are 0..=255, so nothing overflows 16 bits).
#[inline(always)]
fn med_lanes(w: i16x8, n: i16x8, nw: i16x8) -> i16x8 {
    (w + n - nw).max(w.min(n)).min(w.max(n))
}

/// An alternating row (stored pixel 2i, rebuilt pixel 2i + 1, for every full pair) with the
/// `C` channels of a pixel in the lanes of one vector: the serial chain through the left
/// pixel costs a few vector instructions per pixel instead of a few scalar ones per channel.
/// `TWO_ROWS`: the blocks are 2×2 (odd rows), else 2×1 (an odd last row). Returns false when
/// a pixel is damaged (a coded residual above 3, a residual too large for its block, or a
/// rebuilt value outside 0..=255); the row's content is then unspecified.
fn pair_row_lanes<const C: usize, const TWO_ROWS: bool>(
    prev: &[u8],
    s: &[u8],
    parents: &[u8],
    coded_row: &[u8],
    cur: &mut [u8],
) -> bool {
    let k = PairConsts::new(if TWO_ROWS { 4 } else { 2 });
    // Up-left and left of the first stored pixel set so that its MED is its upper neighbour,
    // as on any first column.
    let mut nw = lanes::<C>(prev);
    let mut left = nw;
    let mut damaged = k.zero;
    let rows = cur
        .chunks_exact_mut(2 * C)
        .zip(prev.chunks_exact(2 * C))
        .zip(s.chunks_exact(C))
        .zip(parents.chunks_exact(C).zip(coded_row.chunks_exact(C)));
    for (((out, up), s), (par, coded)) in rows {
        let n1 = lanes::<C>(&up[C..]);
        let (a, b, bad) = pair_step(
            left,
            nw,
            lanes::<C>(up),
            n1,
            lanes::<C>(s),
            lanes::<C>(par),
            lanes::<C>(coded),
            TWO_ROWS,
            k,
        );
        damaged |= bad;
        store_lanes::<C>(a, out);
        store_lanes::<C>(b, &mut out[C..]);
        left = b;
        nw = n1;
    }
    damaged.to_array() == [0; 8]
}

/// [`pair_row_lanes`] channel by channel; on damage, the x of the first damaged pixel with
/// its channel and value.
fn pair_row_scalar<const C: usize>(
    prev: &[u8],
    s: &[u8],
    parents: &[u8],
    coded_row: &[u8],
    cur: &mut [u8],
    two_rows: bool,
) -> Result<(), (usize, (u8, i32))> {
    let cnt = if two_rows { 4 } else { 2 };
    let mut nw: [i16; C] = px::<C>(prev).map(i16::from);
    let mut left: [i16; C] = nw;
    let rows = cur
        .chunks_exact_mut(2 * C)
        .zip(prev.chunks_exact(2 * C))
        .zip(s.chunks_exact(C))
        .zip(parents.chunks_exact(C).zip(coded_row.chunks_exact(C)));
    for (i, (((out, up), s), (par, coded))) in rows.enumerate() {
        let n0: [i16; C] = px::<C>(up).map(i16::from);
        let n1: [i16; C] = px::<C>(&up[C..]).map(i16::from);
        let mut a = [0i16; C];
        let mut p1 = [0u8; C];
        let mut others = [0i32; C];
        for k in 0..C {
            let (l, n, d) = (left[k], n0[k], nw[k]);
            let p0 = (l + n - d).max(l.min(n)).min(l.max(n));
            a[k] = (p0 + s[k] as i16) & 0xff;
            let (l, n, d) = (a[k], n1[k], n0[k]);
            p1[k] = (l + n - d).max(l.min(n)).min(l.max(n)) as u8;
            others[k] = a[k] as i32 + if two_rows { (n0[k] + n1[k]) as i32 } else { 0 };
        }
        let b = rebuild_px(others, cnt, p1, par, coded).map_err(|e| (2 * i + 1, e))?;
        out[..C].copy_from_slice(&a.map(|v| v as u8));
        out[C..].copy_from_slice(&b);
        left = b.map(i16::from);
        nw = n1;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// Vector and scalar alternating rows agree on arbitrary (mostly damaged) input: the same
    /// verdict, and the same pixels when intact.
    fn lanes_match_scalar<const C: usize>(bytes: &[u8], pairs: usize, two_rows: bool) {
        let take = |at: &mut usize, n: usize| {
            let v: Vec<u8> = (0..n).map(|i| bytes[(*at + i) % bytes.len()]).collect();
            *at += n;
            v
        };
        let mut at = 0;
        let prev = take(&mut at, 2 * pairs * C + C);
        let s = take(&mut at, pairs * C);
        let parents = take(&mut at, pairs * C);
        // Residual codes mostly valid (0..=3), sometimes not.
        let coded: Vec<u8> = take(&mut at, pairs * C)
            .into_iter()
            .map(|c| if c < 250 { c & 3 } else { c })
            .collect();
        let mut by_lanes = vec![0u8; 2 * pairs * C];
        let mut by_scalar = vec![0u8; 2 * pairs * C];
        let ok = if two_rows {
            pair_row_lanes::<C, true>(&prev, &s, &parents, &coded, &mut by_lanes)
        } else {
            pair_row_lanes::<C, false>(&prev, &s, &parents, &coded, &mut by_lanes)
        };
        let scalar = pair_row_scalar::<C>(&prev, &s, &parents, &coded, &mut by_scalar, two_rows);
        assert_eq!(ok, scalar.is_ok(), "{scalar:?}");
        if ok {
            assert_eq!(by_lanes, by_scalar);
        }
    }

    /// The fused pass over a stored row and the alternating row below it agrees with the two
    /// rows rebuilt one after the other.
    fn fused_matches_separate<const C: usize>(bytes: &[u8], wu: usize) {
        let row = wu * C;
        let take = |at: &mut usize, n: usize| {
            let v: Vec<u8> = (0..n).map(|i| bytes[(*at + i) % bytes.len()]).collect();
            *at += n;
            v
        };
        let mut at = 0;
        let pw = wu.div_ceil(2);
        let prev = take(&mut at, row);
        let s = take(&mut at, row);
        let s_odd = take(&mut at, (wu / 2) * C);
        let parents = take(&mut at, pw * C);
        let coded: Vec<u8> = take(&mut at, pw * C)
            .into_iter()
            .map(|c| if c < 250 { c & 3 } else { c })
            .collect();
        let (mut up_f, mut low_f) = (vec![0u8; row], vec![0u8; row]);
        let fused =
            stored_and_pair_rows::<C>(&prev, &s, &mut up_f, &s_odd, &parents, &coded, &mut low_f);
        let (mut up_s, mut low_s) = (vec![0u8; row], vec![0u8; row]);
        stored_row::<C>(&prev, &s, &mut up_s);
        let separate = pair_row_scalar::<C>(&up_s, &s_odd, &parents, &coded, &mut low_s, true);
        assert_eq!(up_f, up_s);
        assert_eq!(fused, separate.is_ok(), "{separate:?}");
        if fused {
            assert_eq!(low_f, low_s);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

        #[test]
        fn fused_rows_match_separate_rows(
            bytes in proptest::collection::vec(any::<u8>(), 1..200),
            wu in 2usize..25,
            c in 1usize..=4,
        ) {
            match c {
                1 => fused_matches_separate::<1>(&bytes, wu),
                2 => fused_matches_separate::<2>(&bytes, wu),
                3 => fused_matches_separate::<3>(&bytes, wu),
                _ => fused_matches_separate::<4>(&bytes, wu),
            }
        }

        #[test]
        fn vector_rows_match_scalar_rows(
            bytes in proptest::collection::vec(any::<u8>(), 1..200),
            pairs in 0usize..12,
            c in 1usize..=4,
            two_rows in any::<bool>(),
        ) {
            match c {
                1 => lanes_match_scalar::<1>(&bytes, pairs, two_rows),
                2 => lanes_match_scalar::<2>(&bytes, pairs, two_rows),
                3 => lanes_match_scalar::<3>(&bytes, pairs, two_rows),
                _ => lanes_match_scalar::<4>(&bytes, pairs, two_rows),
            }
        }
    }

    /// Intact rows: pixels that agree with a real block (constant images give every
    /// residual, parent and prediction exactly).
    #[test]
    fn vector_rows_rebuild_intact_blocks() {
        for v in [0u8, 1, 128, 254, 255] {
            // A constant 2×2 block: parent v, residual 0, guess 0, error 0.
            let prev = vec![v; 4 * 4 + 4];
            let s = vec![0u8; 2 * 4];
            let parents = vec![v; 2 * 4];
            let coded = vec![0u8; 2 * 4];
            let mut out = vec![0u8; 4 * 4];
            assert!(pair_row_lanes::<4, true>(
                &prev, &s, &parents, &coded, &mut out
            ));
            assert_eq!(out, vec![v; 16]);
        }
    }
}
