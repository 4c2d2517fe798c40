//! PTM encoder: pyramid → header, lowest level, one group per level coarse to fine.

use super::arith;
use super::layout::{mode_allowed, split, MODE_DECORRELATE};
use super::pyramid::{is_rebuilt, max_levels, stored_count, MipChain};
use super::{Image, PtmError, FLAG_COLOUR_WITHIN_ALPHA, FORMAT_VERSION};

/// How group payloads are coded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The paper's layout byte for byte: packed residuals, then the partial level.
    Raw = 0,
    /// Prediction from the level's own neighbours and the parent (`predict.rs`), samples laid
    /// out per group mode (`layout.rs`), a mode byte and one zstd frame per group.
    Zstd = 1,
    /// The same prediction, each group one adaptive range-coded stream with context models
    /// shared across the levels (`arith.rs`): the smallest, what databases store.
    Arith = 2,
}

impl Method {
    pub(crate) fn from_byte(b: u8) -> Option<Method> {
        match b {
            0 => Some(Method::Raw),
            1 => Some(Method::Zstd),
            2 => Some(Method::Arith),
            _ => None,
        }
    }
}

/// Encoder settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncodeOptions {
    pub method: Method,
    /// zstd level for [`Method::Zstd`] (1 fast … 19 small).
    pub zstd_level: i32,
    /// Number of levels to store; `None` = down to 1 × 1.
    pub levels: Option<u8>,
    /// Largest error of a colour sample, [`Method::Arith`] only (0 = lossless, the default;
    /// at most [`MAX_NEAR`]).
    pub near: u8,
}

/// Largest `near` of the lossy mode.
pub const MAX_NEAR: u8 = 32;

impl Default for EncodeOptions {
    fn default() -> Self {
        EncodeOptions {
            method: Method::Arith,
            zstd_level: 19,
            levels: None,
            near: 0,
        }
    }
}

/// A stream chunk of an encoded PTM: what a client fetches to add one level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GroupSpan {
    /// Level completed by this chunk (0 = full resolution).
    pub level: u32,
    pub width: u32,
    pub height: u32,
    /// Byte range in the file (chunk 0 includes the header).
    pub offset: u64,
    pub len: u64,
}

/// An encoded PTM file and its chunk table (coarse to fine).
#[derive(Clone, Debug)]
pub struct Encoded {
    pub bytes: Vec<u8>,
    pub groups: Vec<GroupSpan>,
}

/// Encodes `image` as a PTM.
pub fn encode(image: &Image, opts: &EncodeOptions) -> Result<Encoded, PtmError> {
    encode_with_modes(image, opts, None)
}

/// [`encode`], with every zstd group above the lowest in `mode` when it is given and applies
/// to the channel count (tests cover each mode this way).
pub(crate) fn encode_with_modes(
    image: &Image,
    opts: &EncodeOptions,
    mode: Option<u8>,
) -> Result<Encoded, PtmError> {
    let level_count = opts
        .levels
        .unwrap_or_else(|| max_levels(image.width, image.height));
    if opts.near > 0 && opts.method != Method::Arith {
        return Err(PtmError::InvalidImage(format!(
            "near {} needs method 2 (only it codes with an error)",
            opts.near
        )));
    }
    if opts.near > MAX_NEAR {
        return Err(PtmError::InvalidImage(format!(
            "near {} (at most {MAX_NEAR})",
            opts.near
        )));
    }
    let chain = MipChain::build(image, level_count)?;
    let within = colour_within_alpha(&chain);
    let payloads = match opts.method {
        Method::Arith => arith_groups(&chain, within, opts.near)?,
        _ => {
            let lowest = chain.levels.last().expect("at least one level");
            let mut payloads = Vec::with_capacity(level_count as usize);
            payloads.push(code(lowest_plain(lowest, opts.method), 0, opts)?);
            for n in (0..level_count as usize - 1).rev() {
                let (level, parent) = (&chain.levels[n], &chain.levels[n + 1]);
                let plain = group_plain(level, parent, &chain.residuals[n], opts.method);
                let payload = match opts.method {
                    Method::Zstd => zstd_group(&plain, parent, opts, mode)?,
                    _ => plain,
                };
                payloads.push(payload);
            }
            payloads
        }
    };
    let flags = if within && opts.method == Method::Arith {
        FLAG_COLOUR_WITHIN_ALPHA
    } else {
        0
    };
    let mut bytes = Vec::with_capacity(32 + payloads.iter().map(Vec::len).sum::<usize>());
    bytes.push(FORMAT_VERSION);
    bytes.push(opts.method as u8);
    bytes.push(image.channels | flags);
    bytes.push(level_count);
    bytes.push(opts.near);
    put_varint(&mut bytes, image.width as u64);
    put_varint(&mut bytes, image.height as u64);
    for p in &payloads {
        u32::try_from(p.len()).map_err(|_| {
            PtmError::InvalidImage(format!("a group of {} bytes is too large", p.len()))
        })?;
        put_varint(&mut bytes, p.len() as u64);
    }
    let mut groups = Vec::with_capacity(payloads.len());
    for (g, p) in payloads.iter().enumerate() {
        let start = if g == 0 { 0 } else { bytes.len() };
        bytes.extend_from_slice(p);
        let level = &chain.levels[level_count as usize - 1 - g];
        groups.push(GroupSpan {
            level: (level_count as usize - 1 - g) as u32,
            width: level.width,
            height: level.height,
            offset: start as u64,
            len: (bytes.len() - start) as u64,
        });
    }
    Ok(Encoded { bytes, groups })
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Whether every colour sample is at most its alpha at every level (images with alpha).
fn colour_within_alpha(chain: &MipChain) -> bool {
    let c = chain.levels[0].channels as usize;
    if c != 2 && c != 4 {
        return false;
    }
    chain.levels.iter().all(|l| {
        l.data
            .chunks_exact(c)
            .all(|px| px[..c - 1].iter().all(|&v| v <= px[c - 1]))
    })
}

/// Method 2's group payloads, coarse to fine, the models carried from group to group; with
/// `near > 0` each level coded against the parent the decoder rebuilds.
fn arith_groups(chain: &MipChain, within: bool, near: u8) -> Result<Vec<Vec<u8>>, PtmError> {
    let count = chain.levels.len();
    let c = chain.levels[0].channels;
    let mut models = arith::Models::new();
    let mut payloads = Vec::with_capacity(count);
    let mut parent: Option<Image> = None;
    for n in (0..count).rev() {
        let level = &chain.levels[n];
        let residuals: &[u8] = if n + 1 < count {
            &chain.residuals[n]
        } else {
            &[]
        };
        let mut e = crate::entropy::Encoder::new();
        let mut out = vec![0u8; level.data.len()];
        let params = arith::Params {
            colour_within_alpha: within,
            near,
            level: n as u32,
        };
        let src = arith::Source {
            samples: &level.data,
            residuals,
        };
        arith::level(
            &mut e,
            &mut models,
            params,
            Some(src),
            parent.as_ref(),
            &mut out,
            (level.width, level.height, c),
        )?;
        debug_assert!(
            near > 0 || out == level.data,
            "lossless coding rebuilds the level"
        );
        payloads.push(e.finish());
        parent = Some(Image {
            width: level.width,
            height: level.height,
            channels: c,
            data: out,
        });
    }
    Ok(payloads)
}

/// A group payload from its plain bytes: raw as is; zstd as the mode byte and one frame.
fn code(plain: Vec<u8>, mode: u8, opts: &EncodeOptions) -> Result<Vec<u8>, PtmError> {
    match opts.method {
        Method::Raw | Method::Arith => Ok(plain),
        Method::Zstd => {
            let mut out = vec![mode];
            out.extend_from_slice(&compress(&plain, opts.zstd_level)?);
            Ok(out)
        }
    }
}

/// One zstd compression at `level`, through compressors kept per thread and level (a build
/// compresses every group of every tile, each at a fast level to pick its layout and then at
/// the asked level; a new context for each call made the encode stage of castle face 128 at
/// level 3 about 15 % slower). The output is the same byte for byte.
fn compress(plain: &[u8], level: i32) -> Result<Vec<u8>, PtmError> {
    type Kept = Vec<(i32, zstd::bulk::Compressor<'static>)>;
    thread_local! {
        static COMPRESSORS: std::cell::RefCell<Kept> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let err = |e: std::io::Error| PtmError::InvalidImage(format!("zstd: {e}"));
    COMPRESSORS.with(|cell| {
        let mut kept = cell.borrow_mut();
        let k = match kept.iter().position(|(l, _)| *l == level) {
            Some(k) => k,
            None => {
                kept.push((level, zstd::bulk::Compressor::new(level).map_err(err)?));
                kept.len() - 1
            }
        };
        kept[k].1.compress(plain).map_err(err)
    })
}

/// A zstd group in the layout of the mode that compresses it best. Modes are compared at a
/// fast zstd level (at most 3; on the castle tiles this picks the same mode as comparing at
/// level 19 for all but a few small groups), then the winner is compressed at the asked level.
fn zstd_group(
    plain: &[u8],
    parent: &Image,
    opts: &EncodeOptions,
    forced: Option<u8>,
) -> Result<Vec<u8>, PtmError> {
    let c = parent.channels as usize;
    let np = parent.width as usize * parent.height as usize;
    let forced = forced.filter(|&m| mode_allowed(m, c)).map(|m| [m]);
    let modes: &[u8] = match &forced {
        Some(m) => m,
        None if mode_allowed(MODE_DECORRELATE, c) => &[0, MODE_DECORRELATE],
        None => &[0],
    };
    let mut best: Option<(usize, u8, Vec<u8>)> = None;
    for &mode in modes {
        let coded = split(plain, np, c, mode);
        let size = if modes.len() > 1 {
            compress(&coded, opts.zstd_level.min(3))?.len()
        } else {
            0
        };
        if best.as_ref().is_none_or(|b| size < b.0) {
            best = Some((size, mode, coded));
        }
    }
    let (_, mode, coded) = best.expect("at least one mode");
    code(coded, mode, opts)
}

/// The lowest level before compression.
fn lowest_plain(img: &Image, method: Method) -> Vec<u8> {
    match method {
        Method::Raw | Method::Arith => img.data.clone(),
        Method::Zstd => {
            let c = img.channels as usize;
            let mut out = Vec::with_capacity(img.data.len());
            for k in 0..c {
                let mut prev = 0u8;
                for v in img.data.iter().skip(k).step_by(c) {
                    out.push(v.wrapping_sub(prev));
                    prev = *v;
                }
            }
            out
        }
    }
}

/// Packs values 0..=3 four to a byte, low bits first.
pub(crate) fn pack_residuals(res: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; res.len().div_ceil(4)];
    for (t, &r) in res.iter().enumerate() {
        out[t / 4] |= (r & 3) << (2 * (t % 4));
    }
    out
}

/// One level group before compression: packed residuals, then the partial level (raw: pixels
/// interleaved; zstd: per channel plane, difference from the parent prediction).
fn group_plain(level: &Image, parent: &Image, residuals: &[u8], method: Method) -> Vec<u8> {
    if method == Method::Zstd {
        return super::predict::encode_level(level, parent, residuals);
    }
    let (w, h, c) = (level.width, level.height, level.channels as usize);
    let mut out = pack_residuals(residuals);
    out.reserve(stored_count(w, h) * c);
    match method {
        Method::Raw => {
            for y in 0..h {
                for x in 0..w {
                    if !is_rebuilt(x, y, w, h) {
                        let at = (y as usize * w as usize + x as usize) * c;
                        out.extend_from_slice(&level.data[at..at + c]);
                    }
                }
            }
        }
        Method::Zstd | Method::Arith => unreachable!("handled above"),
    }
    out
}
