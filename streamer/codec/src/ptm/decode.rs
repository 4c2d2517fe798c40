//! Sans-IO PTM decoder: fed bytes in any chunks, it decodes each level group as soon as the
//! group is complete. Partial input is [`Status::NeedMore`], never an error; every length is
//! checked against the header and [`Limits`] before anything is allocated.

use std::borrow::Cow;

use super::arith;
use super::encode::{Method, MAX_NEAR};
use super::layout::{is_identity, merge, mode_allowed};
use super::pyramid::{is_rebuilt, level_dims, max_levels, stored_count};
use super::{
    Header, Image, Limits, PtmError, FIXED_HEADER_LEN, FLAG_COLOUR_WITHIN_ALPHA, FORMAT_VERSION,
};

/// What the decoder needs next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// More bytes are needed; everything complete so far is decoded.
    NeedMore,
    /// Every group is decoded; the finest level is the full image.
    Done,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Header,
    Group(usize),
    Done,
    Failed,
}

/// Streaming PTM decoder; keeps every decoded level (coarse to fine).
pub struct Decoder {
    limits: Limits,
    stage: Stage,
    pending: Vec<u8>,
    header: Option<Header>,
    /// Method 2's models, carried from group to group.
    models: Option<Box<arith::Models>>,
    /// Decoded levels, lowest stored level first.
    levels: Vec<Image>,
    /// Decompressed group payload, reused from group to group.
    scratch: Vec<u8>,
    /// The payload back in interleaved order (when its mode rearranged it), reused.
    merged: Vec<u8>,
}

impl std::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Decoder")
            .field("stage", &self.stage)
            .field("header", &self.header)
            .field("levels", &self.levels)
            .finish_non_exhaustive()
    }
}

/// Decodes a complete PTM file to its full-resolution image.
pub fn decode(bytes: &[u8], limits: Limits) -> Result<Image, PtmError> {
    let mut dec = Decoder::new(limits);
    match dec.push(bytes)? {
        Status::Done => Ok(dec.into_finest().expect("done implies a level")),
        Status::NeedMore => Err(PtmError::Truncated {
            have: bytes.len() as u64,
            needed: dec
                .header()
                .map_or(FIXED_HEADER_LEN as u64, Header::file_len),
        }),
    }
}

/// Decodes a PTM file, or a prefix of one, down to level `level` (0 = full resolution) and no
/// further: only the groups up to that level are read and decoded; the bytes after them may
/// be absent. A level coarser than the lowest stored one gives the lowest stored level.
pub fn decode_up_to(bytes: &[u8], level: u32, limits: Limits) -> Result<Image, PtmError> {
    let Some(h) = parse_header(bytes, &limits)? else {
        return Err(PtmError::Truncated {
            have: bytes.len() as u64,
            needed: (bytes.len() + 1).max(FIXED_HEADER_LEN) as u64,
        });
    };
    let groups = (h.levels as u32).saturating_sub(level).max(1) as usize;
    let end = h.chunk_range(groups - 1).expect("group exists").end;
    let have = bytes.len() as u64;
    if have < end {
        return Err(PtmError::Truncated { have, needed: end });
    }
    let mut dec = Decoder::new(limits);
    dec.push(&bytes[..end as usize])?;
    Ok(dec.into_finest().expect("groups decoded"))
}

/// The header at the start of `b`: `None` while incomplete. Every field is checked against
/// the format and `limits`.
pub(super) fn parse_header(b: &[u8], limits: &Limits) -> Result<Option<Header>, PtmError> {
    if b.len() < FIXED_HEADER_LEN {
        return Ok(None);
    }
    if b[0] != FORMAT_VERSION {
        return Err(PtmError::UnsupportedVersion(b[0]));
    }
    let method = Method::from_byte(b[1]).ok_or(PtmError::UnknownMethod(b[1]))?;
    let bad = |field, value: u64, reason| PtmError::BadHeader {
        field,
        value,
        reason,
    };
    let flags = b[2] & !7;
    let channels = b[2] & 7;
    let levels = b[3];
    let near = b[4];
    if flags & !FLAG_COLOUR_WITHIN_ALPHA != 0 {
        return Err(bad("flags", flags as u64, "unknown flag bits"));
    }
    if !(1..=4).contains(&channels) {
        return Err(bad("channels", channels as u64, "must be 1 to 4"));
    }
    if flags != 0 && (method != Method::Arith || (channels != 2 && channels != 4)) {
        return Err(bad(
            "flags",
            flags as u64,
            "colour within alpha needs method 2 and an alpha channel",
        ));
    }
    if near > MAX_NEAR || (near > 0 && method != Method::Arith) {
        return Err(bad(
            "near",
            near as u64,
            "at most 32, and only with method 2",
        ));
    }
    // The varints: width, height and one length per level, each at most 5 bytes; the sizes
    // are checked as soon as they are read.
    let mut vals = Vec::with_capacity(2 + levels as usize);
    let mut at = FIXED_HEADER_LEN;
    while vals.len() < 2 + levels as usize {
        let mut v = 0u64;
        let mut k = 0;
        loop {
            let Some(&byte) = b.get(at) else {
                return Ok(None);
            };
            at += 1;
            v |= ((byte & 0x7f) as u64) << (7 * k);
            k += 1;
            if byte & 0x80 == 0 {
                break;
            }
            if k == 5 {
                return Err(bad("size", v, "varint longer than 5 bytes"));
            }
        }
        if v > u32::MAX as u64 {
            return Err(bad("size", v, "larger than 32 bits"));
        }
        vals.push(v as u32);
        if vals.len() == 2 {
            check_sizes(vals[0], vals[1], channels, levels, limits)?;
        }
    }
    let (width, height) = (vals[0], vals[1]);
    let h = Header {
        method,
        channels,
        colour_within_alpha: flags & FLAG_COLOUR_WITHIN_ALPHA != 0,
        near,
        width,
        height,
        levels,
        group_lens: vals[2..].to_vec(),
        header_len: at,
    };
    for (g, &len) in h.group_lens.iter().enumerate() {
        let plain = plain_len(&h, g);
        let len = len as u64;
        let err = |reason| PtmError::GroupLength {
            group: g,
            level: h.level_of_group(g),
            len,
            reason,
        };
        match method {
            Method::Raw if len != plain => {
                return Err(err("raw groups hold exactly their level"));
            }
            Method::Zstd if len > plain + plain / 128 + 1025 => {
                return Err(err("larger than zstd can make the level"));
            }
            Method::Zstd if len < 2 => return Err(err("no mode byte and zstd frame")),
            Method::Arith if len > 4 * plain + 1024 => {
                return Err(err("larger than method 2 makes a level"));
            }
            _ => {}
        }
    }
    Ok(Some(h))
}

/// Width, height and level count against the format and the limits.
fn check_sizes(
    width: u32,
    height: u32,
    channels: u8,
    levels: u8,
    limits: &Limits,
) -> Result<(), PtmError> {
    let bad = |field, value: u64, reason| PtmError::BadHeader {
        field,
        value,
        reason,
    };
    if width == 0 {
        return Err(bad("width", 0, "must be positive"));
    }
    if height == 0 {
        return Err(bad("height", 0, "must be positive"));
    }
    for (what, v) in [("width", width), ("height", height)] {
        if v > limits.max_side {
            return Err(PtmError::LimitsExceeded {
                what,
                value: v as u64,
                limit: limits.max_side as u64,
            });
        }
    }
    if levels == 0 || levels > max_levels(width, height) {
        return Err(bad(
            "levels",
            levels as u64,
            "must be 1 to 1 + ceil(log2(max(width, height)))",
        ));
    }
    let decoded: u64 = (0..levels as u32)
        .map(|l| {
            let (w, h) = level_dims(width, height, l);
            w as u64 * h as u64 * channels as u64
        })
        .sum();
    if decoded > limits.max_decoded_bytes {
        return Err(PtmError::LimitsExceeded {
            what: "decoded bytes",
            value: decoded,
            limit: limits.max_decoded_bytes,
        });
    }
    Ok(())
}

/// Length of a group payload before compression.
fn plain_len(h: &Header, g: usize) -> u64 {
    let c = h.channels as u64;
    let level = h.level_of_group(g);
    let (w, h2) = level_dims(h.width, h.height, level);
    if g == 0 {
        w as u64 * h2 as u64 * c
    } else {
        let (pw, ph) = level_dims(h.width, h.height, level + 1);
        let residuals = match h.method {
            Method::Raw => (pw as u64 * ph as u64 * c).div_ceil(4),
            Method::Zstd | Method::Arith => pw as u64 * ph as u64 * c,
        };
        residuals + stored_count(w, h2) as u64 * c
    }
}

impl Decoder {
    pub fn new(limits: Limits) -> Decoder {
        Decoder {
            limits,
            stage: Stage::Header,
            pending: Vec::new(),
            header: None,
            models: None,
            levels: Vec::new(),
            scratch: Vec::new(),
            merged: Vec::new(),
        }
    }

    /// The header, once its bytes have arrived.
    pub fn header(&self) -> Option<&Header> {
        self.header.as_ref()
    }

    /// Number of groups decoded so far.
    pub fn groups_decoded(&self) -> usize {
        self.levels.len()
    }

    /// The finest level decoded so far.
    pub fn finest(&self) -> Option<&Image> {
        self.levels.last()
    }

    /// Level number (0 = full resolution) of [`Decoder::finest`].
    pub fn finest_level(&self) -> Option<u32> {
        let h = self.header.as_ref()?;
        (!self.levels.is_empty()).then(|| h.levels as u32 - self.levels.len() as u32)
    }

    /// Decoded level `level` (0 = full resolution), if it has arrived.
    pub fn level(&self, level: u32) -> Option<&Image> {
        let h = self.header.as_ref()?;
        let g = (h.levels as u32).checked_sub(level + 1)? as usize;
        self.levels.get(g)
    }

    /// Takes the finest decoded level.
    pub fn into_finest(mut self) -> Option<Image> {
        self.levels.pop()
    }

    /// Takes every decoded level, lowest stored level first.
    pub fn into_levels(self) -> Vec<Image> {
        self.levels
    }

    /// Feeds bytes; decodes every group they complete.
    pub fn push(&mut self, input: &[u8]) -> Result<Status, PtmError> {
        let r = self.push_inner(input);
        if r.is_err() {
            self.stage = Stage::Failed;
            self.pending = Vec::new();
        }
        r
    }

    fn push_inner(&mut self, mut input: &[u8]) -> Result<Status, PtmError> {
        loop {
            let need = match self.stage {
                Stage::Failed => return Err(PtmError::Poisoned),
                Stage::Done if input.is_empty() => return Ok(Status::Done),
                Stage::Done => return Err(PtmError::TrailingBytes(input.len() as u64)),
                Stage::Header => {
                    // A byte at a time (a header is at most a few hundred bytes), so that no
                    // byte of group 0 is taken for it.
                    let Some((&b, rest)) = input.split_first() else {
                        return Ok(Status::NeedMore);
                    };
                    input = rest;
                    self.pending.push(b);
                    if let Some(h) = parse_header(&self.pending, &self.limits)? {
                        self.header = Some(h);
                        self.pending.clear();
                        self.stage = Stage::Group(0);
                    }
                    continue;
                }
                Stage::Group(g) => self.header.as_ref().map_or(0, |h| h.group_lens[g] as usize),
            };
            let chunk: Cow<[u8]> = if self.pending.is_empty() && input.len() >= need {
                let (a, b) = input.split_at(need);
                input = b;
                Cow::Borrowed(a)
            } else {
                let take = (need - self.pending.len()).min(input.len());
                self.pending.extend_from_slice(&input[..take]);
                input = &input[take..];
                if self.pending.len() < need {
                    return Ok(Status::NeedMore);
                }
                Cow::Owned(std::mem::take(&mut self.pending))
            };
            if let Stage::Group(g) = self.stage {
                let img = self.decode_group(g, &chunk)?;
                self.levels.push(img);
                let total = self.header.as_ref().map_or(0, |h| h.levels as usize);
                self.stage = if g + 1 == total {
                    Stage::Done
                } else {
                    Stage::Group(g + 1)
                };
            }
        }
    }

    fn decode_group(&mut self, g: usize, payload: &[u8]) -> Result<Image, PtmError> {
        let h = self.header.as_ref().expect("groups follow the header");
        let (method, c) = (h.method, h.channels);
        let level = h.level_of_group(g);
        let (w, hh) = level_dims(h.width, h.height, level);
        let expected = plain_len(h, g) as usize;
        if method == Method::Arith {
            let params = arith::Params {
                colour_within_alpha: h.colour_within_alpha,
                near: h.near,
                level,
            };
            let mut out = vec![0u8; w as usize * hh as usize * c as usize];
            let models = self
                .models
                .get_or_insert_with(|| Box::new(arith::Models::new()));
            let mut d = crate::entropy::Decoder::new(payload);
            arith::level(
                &mut d,
                models,
                params,
                None,
                if g == 0 { None } else { self.levels.last() },
                &mut out,
                (w, hh, c),
            )?;
            return Ok(Image {
                width: w,
                height: hh,
                channels: c,
                data: out,
            });
        }
        let plain: Cow<[u8]> = match method {
            Method::Raw | Method::Arith => Cow::Borrowed(payload),
            Method::Zstd => {
                let zerr = |message: String| PtmError::Compression {
                    group: g,
                    level,
                    message,
                };
                let (&mode, frame) = payload.split_first().expect("length checked");
                let c = c as usize;
                if (g == 0 && mode != 0) || !mode_allowed(mode, c) {
                    return Err(PtmError::UnknownGroupMode {
                        group: g,
                        level,
                        mode,
                    });
                }
                // The capacity bounds what a hostile frame can make zstd write.
                self.scratch.clear();
                self.scratch.reserve(expected);
                let n = with_zstd(|z| z.decompress_to_buffer(frame, &mut self.scratch))
                    .map_err(|e| zerr(format!("zstd: {e}")))?;
                if n != expected {
                    return Err(zerr(format!(
                        "decompressed to {n} bytes, expected {expected}"
                    )));
                }
                if g == 0 || is_identity(mode, c) {
                    Cow::Borrowed(&self.scratch[..])
                } else {
                    let (pw, ph) = level_dims(h.width, h.height, level + 1);
                    merge(
                        &self.scratch,
                        pw as usize * ph as usize,
                        c,
                        mode,
                        &mut self.merged,
                    );
                    Cow::Borrowed(&self.merged[..])
                }
            }
        };
        if g == 0 {
            return Ok(lowest_from_plain(&plain, w, hh, c, method));
        }
        let parent = self.levels.last().expect("parent decoded first");
        level_from_plain(&plain, parent, w, hh, level, method)
    }
}

thread_local! {
    /// One zstd decompression context per thread, reused by every decoder on it: a PTM is a
    /// few kilobytes, and setting up a context for each was a tenth of opening a database.
    static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// Run `f` with this thread's decompression context (created on first use).
fn with_zstd<T>(
    f: impl FnOnce(&mut zstd::bulk::Decompressor<'static>) -> std::io::Result<T>,
) -> std::io::Result<T> {
    ZSTD.with(|cell| {
        let mut slot = cell.borrow_mut();
        if slot.is_none() {
            *slot = Some(zstd::bulk::Decompressor::new()?);
        }
        match slot.as_mut() {
            Some(z) => f(z),
            None => Err(std::io::Error::other("no zstd context")),
        }
    })
}

fn lowest_from_plain(plain: &[u8], w: u32, h: u32, c: u8, method: Method) -> Image {
    let data = match method {
        Method::Raw | Method::Arith => plain.to_vec(),
        Method::Zstd => {
            let c = c as usize;
            let n = w as usize * h as usize;
            let mut data = vec![0u8; n * c];
            for k in 0..c {
                let mut prev = 0u8;
                for (i, d) in plain[k * n..(k + 1) * n].iter().enumerate() {
                    prev = prev.wrapping_add(*d);
                    data[i * c + k] = prev;
                }
            }
            data
        }
    };
    Image {
        width: w,
        height: h,
        channels: c,
        data,
    }
}

/// Rebuilds level `level` (`w × h`) from its parent, residuals and partial level (eq. 3).
/// (Method::Zstd levels go through `predict::decode_level`.)
fn level_from_plain(
    plain: &[u8],
    parent: &Image,
    w: u32,
    h: u32,
    level: u32,
    method: Method,
) -> Result<Image, PtmError> {
    let c = parent.channels as usize;
    if method == Method::Zstd {
        let data = super::predict::decode_level(plain, parent, w, h, level)?;
        return Ok(Image {
            width: w,
            height: h,
            channels: c as u8,
            data,
        });
    }
    let (pw, ph) = (parent.width, parent.height);
    let n_res = pw as usize * ph as usize * c;
    let (res_bytes, pixels) = plain.split_at(n_res.div_ceil(4));
    if !n_res.is_multiple_of(4) && res_bytes[res_bytes.len() - 1] >> (2 * (n_res % 4)) != 0 {
        return Err(PtmError::BadResidual {
            level,
            x: pw - 1,
            y: ph - 1,
            channel: (c - 1) as u8,
            value: (res_bytes[res_bytes.len() - 1] >> (2 * (n_res % 4))) as i32,
        });
    }
    let mut data = vec![0u8; w as usize * h as usize * c];
    let mut src = pixels.iter();
    for y in 0..h {
        for x in 0..w {
            if !is_rebuilt(x, y, w, h) {
                let at = (y as usize * w as usize + x as usize) * c;
                for v in &mut data[at..at + c] {
                    *v = *src.next().expect("length checked");
                }
            }
        }
    }
    let row = w as usize * c;
    for j in 0..ph {
        let y0 = 2 * j;
        let two_rows = y0 + 1 < h;
        for i in 0..pw {
            let x0 = 2 * i;
            let two_cols = x0 + 1 < w;
            let n = 1 + two_rows as i32 + two_cols as i32 + (two_rows && two_cols) as i32;
            let (mx, my) = (x0 + two_cols as u32, y0 + two_rows as u32);
            let base = y0 as usize * row + x0 as usize * c;
            let missing = my as usize * row + mx as usize * c;
            let pidx = (j as usize * pw as usize + i as usize) * c;
            for k in 0..c {
                let t = pidx + k;
                let r = ((res_bytes[t / 4] >> (2 * (t % 4))) & 3) as i32;
                // Every pixel of the block except the last (the rebuilt one).
                let others = match n {
                    4 => {
                        data[base + k] as i32
                            + data[base + c + k] as i32
                            + data[base + row + k] as i32
                    }
                    2 => data[base + k] as i32,
                    _ => 0,
                };
                let v = n * parent.data[t] as i32 + r - others;
                if r >= n || !(0..=255).contains(&v) {
                    return Err(PtmError::BadResidual {
                        level,
                        x: mx,
                        y: my,
                        channel: k as u8,
                        value: if r >= n { r } else { v },
                    });
                }
                data[missing + k] = v as u8;
            }
        }
    }
    Ok(Image {
        width: w,
        height: h,
        channels: c as u8,
        data,
    })
}
