//! [`Method::Arith`](super::Method::Arith): each level group one adaptive range-coded
//! stream ([`crate::entropy`]) with context models that carry over from group to group, so a
//! tile's fine levels start from what its coarse ones taught.
//!
//! A level is scanned in raster order; within a pixel the alpha channel comes first (2 and 4
//! channels), then green (or grey), red, blue. A stored sample is predicted from its causal
//! neighbours in the same level by the median edge detector of LOCO-I (`MED(W, N, NW)`; on the
//! first row W, on the first column N, the very first pixel its parent) and its error is
//! coded as a [`Signed`] whose context is the channel's class (alpha, green or grey, red or
//! blue), the level's class (level 0, coarser) and the local activity
//! `|W − NW| + |N − NW| + |N − NE|` in eight buckets (alpha: with its parent is 0 or not). With
//! the group's first decision set (three colour channels), red's and blue's errors are coded
//! relative to green's. The rebuilt pixel of each block (eq. 3) codes only its residual ε,
//! relative to the one its own prediction implies (as method 1 does), as the difference
//! modulo the block's pixel count through a tree of three adaptive bits.
//!
//! Nothing is coded for what is known: where the parent is 255, every pixel of its block is
//! 255 (the parent is the floor of their mean); with the header's *colour within alpha* flag
//! — every colour sample at most its alpha, at every level, which format-5 databases promise
//! by clearing the colour under the mask — a pixel of alpha 0 has colour 0, and a colour
//! prediction is clamped to the alpha. Most of a slab tile is empty or opaque, so most of its
//! samples cost nothing.
//!
//! **Lossy** (`near > 0`, the header's byte): colour samples are coded within `near` of the
//! level, as JPEG-LS's near-lossless mode does — the error quantised in steps of
//! `2·near + 1`, predictions made from what the decoder rebuilds — and the rebuilt pixel of a
//! block as well, predicted by its neighbours clamped to what the block sum allows; alpha
//! stays exact (it is the opacity mask) and so do the rules above that rest on it. Every
//! sample of every level is then within `near` of the lossless pyramid's.
//!
//! The exact rules, for a second decoder, are in the [module docs](super) ("Method 2").

use super::pyramid::is_rebuilt;
use super::{Image, PtmError};
use crate::entropy::{Bit, Decoder, Encoder, Signed};

/// Activity buckets: upper bounds of `|W − NW| + |N − NW| + |N − NE|`.
const ACT: [u32; 7] = [0, 2, 5, 10, 20, 40, 80];
const ACTS: usize = ACT.len() + 1;

#[inline(always)]
fn bucket(a: u32) -> usize {
    ACT.iter().take_while(|&&b| a > b).count()
}

/// Channel classes: alpha, green or grey, red or blue.
const ALPHA: usize = 0;
const GREEN: usize = 1;
const RED_BLUE: usize = 2;

/// The models of one PTM, carried from group to group.
#[derive(Clone)]
pub(crate) struct Models {
    /// Stored colour errors by [level class][channel class − 1][at an outline][activity].
    colour: Vec<Signed>,
    /// Stored alpha errors by [level class][parent is 0][activity].
    alpha: Vec<Signed>,
    /// Rebuilt residuals by [channel class][block of 4][min(activity, 5) / 2]: the three bits
    /// of the tree (`d = 0`, `d = 1`, `d = 3` rather than 2).
    residual: Vec<[Bit; 3]>,
}

impl Models {
    pub(crate) fn new() -> Models {
        Models {
            colour: vec![Signed::new(); 2 * 2 * 2 * ACTS],
            alpha: vec![Signed::new(); 2 * 2 * ACTS],
            residual: vec![[Bit::new(); 3]; 3 * 2 * 3],
        }
    }
}

/// One side of the coder: the encoder codes the value it is given and returns it, the decoder
/// ignores it and returns what it decodes. The level traversal is written once for both.
pub(crate) trait Io {
    fn signed(&mut self, m: &mut Signed, v: i32) -> i32;
    fn bit(&mut self, m: &mut Bit, b: bool) -> bool;
    fn even(&mut self, b: bool) -> bool;
}

impl Io for Encoder {
    #[inline(always)]
    fn signed(&mut self, m: &mut Signed, v: i32) -> i32 {
        m.encode(self, v);
        v
    }
    #[inline(always)]
    fn bit(&mut self, m: &mut Bit, b: bool) -> bool {
        Encoder::bit(self, m, b);
        b
    }
    #[inline(always)]
    fn even(&mut self, b: bool) -> bool {
        Encoder::even(self, b);
        b
    }
}

impl Io for Decoder<'_> {
    #[inline(always)]
    fn signed(&mut self, m: &mut Signed, _: i32) -> i32 {
        m.decode(self)
    }
    #[inline(always)]
    fn bit(&mut self, m: &mut Bit, _: bool) -> bool {
        Decoder::bit(self, m)
    }
    #[inline(always)]
    fn even(&mut self, _: bool) -> bool {
        Decoder::even(self)
    }
}

/// What a group's coding needs besides its samples.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Params {
    /// Every colour sample ≤ its alpha at every level (the header's flag).
    pub colour_within_alpha: bool,
    /// Largest error of a colour sample (0: lossless).
    pub near: u8,
    /// Level number (0: full resolution).
    pub level: u32,
}

/// A level's source when encoding: its samples and (lossless) the residuals of its blocks
/// (`MipChain::residuals`, one per parent sample). Empty when decoding.
#[derive(Clone, Copy)]
pub(crate) struct Source<'a> {
    pub samples: &'a [u8],
    pub residuals: &'a [u8],
}

/// `v` as a signed byte difference in −128..=127.
#[inline(always)]
fn wrap(v: i32) -> i32 {
    (v as i8) as i32
}

/// The channel order within a pixel and each channel's class.
fn order<const C: usize>() -> ([usize; C], [usize; C]) {
    let mut ch = [0usize; C];
    let mut class = [GREEN; C];
    match C {
        1 => {}
        2 => {
            ch[0] = 1;
            class[0] = ALPHA;
        }
        3 => {
            ch[..3].copy_from_slice(&[1, 0, 2]);
            class[1] = RED_BLUE;
            class[2] = RED_BLUE;
        }
        _ => {
            ch.copy_from_slice(&[3, 1, 0, 2][..C]);
            class.copy_from_slice(&[ALPHA, GREEN, RED_BLUE, RED_BLUE][..C]);
        }
    }
    (ch, class)
}

/// Codes (or decodes, into `out`) one level of `w × h` pixels of `channels` channels
/// (`shape`). `parent` is the level above (`None` for the lowest stored level). `out` holds
/// `w · h · channels` samples on return: the level a decoder rebuilds (the source itself when
/// lossless).
pub(crate) fn level<I: Io>(
    io: &mut I,
    m: &mut Models,
    p: Params,
    src: Option<Source>,
    parent: Option<&Image>,
    out: &mut [u8],
    shape: (u32, u32, u8),
) -> Result<(), PtmError> {
    let (w, h, channels) = shape;
    match channels {
        1 => level_c::<I, 1>(io, m, p, src, parent, out, (w, h)),
        2 => level_c::<I, 2>(io, m, p, src, parent, out, (w, h)),
        3 => level_c::<I, 3>(io, m, p, src, parent, out, (w, h)),
        _ => level_c::<I, 4>(io, m, p, src, parent, out, (w, h)),
    }
}

/// What the coding of one level keeps fixed.
#[derive(Clone, Copy)]
struct LevelCtx {
    /// Width and height in pixels, samples per row.
    w: usize,
    h: usize,
    row: usize,
    /// Colour within alpha, and the level has an alpha channel.
    within: bool,
    /// Level class: 0 for level 0, 1 coarser.
    lc: usize,
    near: i32,
    /// The lossy quantisation step, `2·near + 1`.
    step: i32,
    level: u32,
}

/// One sample being coded: where it is and what is known of it before its neighbours.
#[derive(Clone, Copy)]
struct Sample {
    x: usize,
    y: usize,
    /// Index of the sample in the level, of its pixel's first sample in the parent.
    i: usize,
    pidx: usize,
    ch: usize,
    class: usize,
    /// A colour channel (not alpha).
    colour: bool,
    /// The pixel rebuilt from its block's others (eq. 3).
    rebuilt: bool,
    /// The parent's sample (`None` for the lowest stored level).
    pv: Option<i32>,
    /// The pixel's alpha (255 without an alpha channel).
    alpha: i32,
    /// The largest value the sample may take (its alpha, with colour within alpha).
    hi: i32,
}

fn level_c<I: Io, const C: usize>(
    io: &mut I,
    m: &mut Models,
    p: Params,
    src: Option<Source>,
    parent: Option<&Image>,
    out: &mut [u8],
    (w, h): (u32, u32),
) -> Result<(), PtmError> {
    let (wu, hu) = (w as usize, h as usize);
    let row = wu * C;
    let has_alpha = C == 2 || C == 4;
    let alpha_ch = C - 1;
    let (chans, classes) = order::<C>();
    let within = p.colour_within_alpha && has_alpha;
    let near = p.near as i32;
    let lv = LevelCtx {
        w: wu,
        h: hu,
        row,
        within,
        lc: usize::from(p.level > 0),
        near,
        step: 2 * near + 1,
        level: p.level,
    };
    // The group's first decision: red and blue relative to green.
    let decorrelate = if C >= 3 {
        let choice = src.is_some_and(|s| choose_decorrelation::<C>(s.samples));
        io.even(choice)
    } else {
        false
    };
    let pw = parent.map_or(0, |q| q.width as usize);
    for y in 0..hu {
        for x in 0..wu {
            let at = y * row + x * C;
            let rebuilt = parent.is_some() && is_rebuilt(x as u32, y as u32, w, h);
            let pidx = (y / 2 * pw + x / 2) * C;
            // The error of green at this pixel (lossless: mod 256; lossy: quantised).
            let mut green_err = 0i32;
            for k in 0..C {
                let ch = chans[k];
                let class = classes[k];
                let i = at + ch;
                let colour = class != ALPHA;
                let lossy = colour && near > 0;
                let pv = parent.map(|q| q.data[pidx + ch] as i32);
                if pv == Some(255) && !lossy {
                    out[i] = 255;
                    continue;
                }
                let alpha = if has_alpha {
                    out[at + alpha_ch] as i32
                } else {
                    255
                };
                if within && colour && alpha == 0 {
                    out[i] = 0;
                    continue;
                }
                let hi = if within && colour { alpha } else { 255 };
                let s = Sample {
                    x,
                    y,
                    i,
                    pidx,
                    ch,
                    class,
                    colour,
                    rebuilt,
                    pv,
                    alpha,
                    hi,
                };
                let (pred, act, edge) = predict::<C>(out, &lv, &s);
                if rebuilt && !lossy {
                    out[i] = rebuilt_lossless::<I, C>(io, m, &lv, &s, src, out, pred, act)?;
                    continue;
                }
                let model = if class == ALPHA {
                    &mut m.alpha[(lv.lc * 2 + usize::from(pv == Some(0))) * ACTS + act]
                } else {
                    &mut m.colour[((lv.lc * 2 + class - 1) * 2 + usize::from(edge)) * ACTS + act]
                };
                // Red and blue relative to green: green's error, else 0.
                let base = if decorrelate && class == RED_BLUE {
                    green_err
                } else {
                    0
                };
                let (v, err) = if lossy {
                    lossy_colour::<I, C>(io, model, &lv, &s, src, out, pred, base)
                } else {
                    lossless_stored(io, model, &s, src, pred, base)
                };
                if class == GREEN {
                    green_err = err;
                }
                out[i] = v;
            }
        }
    }
    Ok(())
}

/// The prediction of a sample from its causal neighbours in the level (rebuilt pixels
/// included), clamped to its `hi`; its activity bucket; whether it lies at an outline (with
/// colour within alpha).
#[inline(always)]
fn predict<const C: usize>(out: &[u8], lv: &LevelCtx, s: &Sample) -> (i32, usize, bool) {
    let (x, y, i, ch, row) = (s.x, s.y, s.i, s.ch, lv.row);
    let alpha_ch = C - 1;
    // With colour within alpha, a transparent neighbour's colour (0) says nothing about this
    // one's.
    let masked = lv.within && s.colour;
    let usable = |j: usize| !masked || out[j - ch + alpha_ch] > 0;
    let wv = (x > 0 && usable(i - C)).then(|| out[i - C] as i32);
    let nv = (y > 0 && usable(i - row)).then(|| out[i - row] as i32);
    let nwv = (x > 0 && y > 0 && usable(i - row - C)).then(|| out[i - row - C] as i32);
    let edge = masked && (s.alpha < 255 || (x > 0 && wv.is_none()) || (y > 0 && nv.is_none()));
    let (pred, act) = match (wv, nv) {
        (Some(a), Some(b)) => {
            let c = nwv.unwrap_or((a + b) / 2);
            let ne = if x + 1 < lv.w && usable(i - row + C) {
                out[i - row + C] as i32
            } else {
                b
            };
            let pred = (a + b - c).clamp(a.min(b), a.max(b));
            (
                pred,
                (a - c).unsigned_abs() + (b - c).unsigned_abs() + (b - ne).unsigned_abs(),
            )
        }
        (Some(a), None) => (a, 0),
        (None, Some(b)) => (b, 0),
        (None, None) => (s.pv.unwrap_or(0), 0),
    };
    // How far the neighbours' prediction strays from the block's mean (the parent) counts as
    // activity too.
    let act = match s.pv {
        Some(pp) if !s.rebuilt => act + (pred - pp).unsigned_abs(),
        _ => act,
    };
    (pred.min(s.hi), bucket(act), edge)
}

/// The rebuilt pixel's sample, lossless: ε of the block, relative to the one the prediction
/// implies (eq. 3), through the residual tree.
#[expect(
    clippy::too_many_arguments,
    reason = "inlined into the per-sample loop; a struct would only rename them"
)]
#[inline(always)]
fn rebuilt_lossless<I: Io, const C: usize>(
    io: &mut I,
    m: &mut Models,
    lv: &LevelCtx,
    s: &Sample,
    src: Option<Source>,
    out: &[u8],
    pred: i32,
    act: usize,
) -> Result<u8, PtmError> {
    let pv = s.pv.unwrap_or(0);
    let (others, cnt) = block_others::<C>(out, s.x, s.y, lv.w, lv.h, lv.row, s.ch);
    let n = cnt as i32;
    if cnt == 1 {
        return Ok(pv as u8);
    }
    let guess = (others + pred - n * pv).clamp(0, n - 1);
    let d = src.map_or(0, |src| {
        (src.residuals[s.pidx + s.ch] as i32 - guess).rem_euclid(n)
    });
    let ms = &mut m.residual[(s.class * 2 + usize::from(cnt == 4)) * 3 + act.min(5) / 2];
    let d = residual_tree(io, ms, cnt, d as u32) as i32;
    let eps = (guess + d) % n;
    let v = n * pv + eps - others;
    if !(0..=255).contains(&v) {
        return Err(PtmError::BadResidual {
            level: lv.level,
            x: s.x as u32,
            y: s.y as u32,
            channel: s.ch as u8,
            value: v,
        });
    }
    Ok(v as u8)
}

/// A stored sample, lossless: its error against the prediction (mod 256), coded relative
/// to `base` (green's error for red and blue when decorrelated, else 0). Returns the sample
/// and its error.
#[inline(always)]
fn lossless_stored<I: Io>(
    io: &mut I,
    model: &mut Signed,
    s: &Sample,
    src: Option<Source>,
    pred: i32,
    base: i32,
) -> (u8, i32) {
    let e = src.map_or(0, |src| wrap(src.samples[s.i] as i32 - pred));
    let coded = io.signed(model, wrap(e - base));
    let e = wrap(coded.wrapping_add(base));
    ((pred + e) as u8, e)
}

/// A colour sample, lossy: its error quantised in steps of `2·near + 1`, the rebuilt pixel
/// predicted within what the block sum allows; coded relative to `base` (green's quantised
/// error for red and blue when decorrelated, else 0). Returns the sample and its quantised
/// error.
#[expect(
    clippy::too_many_arguments,
    reason = "inlined into the per-sample loop; a struct would only rename them"
)]
#[inline(always)]
fn lossy_colour<I: Io, const C: usize>(
    io: &mut I,
    model: &mut Signed,
    lv: &LevelCtx,
    s: &Sample,
    src: Option<Source>,
    out: &[u8],
    pred: i32,
    base: i32,
) -> (u8, i32) {
    let pred = if s.rebuilt {
        let pv = s.pv.unwrap_or(0);
        let (others, cnt) = block_others::<C>(out, s.x, s.y, lv.w, lv.h, lv.row, s.ch);
        let n = cnt as i32;
        let (lo, top) = (n * pv - others, n * pv + n - 1 - others);
        if lo <= top {
            pred.clamp(lo.max(0), top.min(s.hi).max(lo.max(0)))
        } else {
            pred
        }
    } else {
        pred
    };
    let q = src.map_or(0, |src| {
        let e = src.samples[s.i] as i32 - pred;
        e.signum() * ((e.abs() + lv.near) / lv.step)
    });
    let coded = io.signed(model, q - base);
    let q = coded.saturating_add(base);
    let v = (pred as i64 + q as i64 * lv.step as i64).clamp(0, s.hi as i64);
    (v as u8, q)
}

/// Sum of the block's pixels other than the rebuilt one at `(x, y)`, channel `ch`, and the
/// block's pixel count.
#[inline(always)]
fn block_others<const C: usize>(
    out: &[u8],
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    row: usize,
    ch: usize,
) -> (i32, u32) {
    let (x0, y0) = (x & !1, y & !1);
    let two_cols = x0 + 1 < w;
    let two_rows = y0 + 1 < h;
    let base = y0 * row + x0 * C + ch;
    match (two_cols, two_rows) {
        (true, true) => (
            out[base] as i32 + out[base + C] as i32 + out[base + row] as i32,
            4,
        ),
        (true, false) | (false, true) => (out[base] as i32, 2),
        (false, false) => (0, 1),
    }
}

/// `d` in `0..cnt` through the tree: "0?", then (blocks of 4) "1?", then "3 (rather than 2)?".
#[inline(always)]
fn residual_tree<I: Io>(io: &mut I, ms: &mut [Bit; 3], cnt: u32, d: u32) -> u32 {
    if io.bit(&mut ms[0], d == 0) {
        return 0;
    }
    if cnt == 2 || io.bit(&mut ms[1], d == 1) {
        return 1;
    }
    if io.bit(&mut ms[2], d == 3) {
        3
    } else {
        2
    }
}

/// Whether coding red and blue against green pays on these samples: their errors against
/// the left neighbour vary less that way.
fn choose_decorrelation<const C: usize>(samples: &[u8]) -> bool {
    let (mut plain, mut relative) = (0u64, 0u64);
    let mut prev = [0i32; 3];
    for px in samples.chunks_exact(C) {
        let d = [0, 1, 2].map(|k| px[k] as i32 - prev[k]);
        plain += (d[0].unsigned_abs() + d[2].unsigned_abs()) as u64;
        relative += ((d[0] - d[1]).unsigned_abs() + (d[2] - d[1]).unsigned_abs()) as u64;
        prev = [0, 1, 2].map(|k| px[k] as i32);
    }
    relative < plain
}
