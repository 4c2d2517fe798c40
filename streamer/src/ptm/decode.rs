//! Sans-IO PTM decoder: fed bytes in any chunks, it decodes each level group as soon as the
//! group is complete. Partial input is [`Status::NeedMore`], never an error; every length is
//! checked against the header and [`Limits`] before anything is allocated.

use std::borrow::Cow;

use super::encode::Method;
use super::layout::{is_identity, merge, mode_allowed};
use super::pyramid::{is_rebuilt, level_dims, max_levels, stored_count};
use super::{Header, Image, Limits, PtmError, FIXED_HEADER_LEN, FORMAT_VERSION, MAGIC};

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
    Fixed,
    Table,
    Group(usize),
    Done,
    Failed,
}

/// Streaming PTM decoder; keeps every decoded level (coarse to fine).
pub struct Decoder {
    limits: Limits,
    stage: Stage,
    pending: Vec<u8>,
    fixed: Option<(Method, u8, u8, u32, u32)>,
    header: Option<Header>,
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
    let mut dec = Decoder::new(limits);
    let fixed = bytes.len().min(FIXED_HEADER_LEN);
    dec.push(&bytes[..fixed])?;
    let table_end = dec
        .fixed
        .map_or(FIXED_HEADER_LEN, |f| FIXED_HEADER_LEN + 4 * f.2 as usize);
    dec.push(&bytes[fixed..bytes.len().min(table_end)])?;
    let Some(h) = dec.header().cloned() else {
        return Err(PtmError::Truncated {
            have: bytes.len() as u64,
            needed: table_end as u64,
        });
    };
    let groups = (h.levels as u32).saturating_sub(level).max(1) as usize;
    let end = h.chunk_range(groups - 1).expect("group exists").end;
    let have = bytes.len() as u64;
    if have < end {
        return Err(PtmError::Truncated { have, needed: end });
    }
    dec.push(&bytes[table_end..end as usize])?;
    Ok(dec.into_finest().expect("groups decoded"))
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
            Method::Zstd => pw as u64 * ph as u64 * c,
        };
        residuals + stored_count(w, h2) as u64 * c
    }
}

impl Decoder {
    pub fn new(limits: Limits) -> Decoder {
        Decoder {
            limits,
            stage: Stage::Fixed,
            pending: Vec::new(),
            fixed: None,
            header: None,
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
                Stage::Fixed => FIXED_HEADER_LEN,
                Stage::Table => 4 * self.fixed.map_or(0, |f| f.2 as usize),
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
            match self.stage {
                Stage::Fixed => {
                    self.fixed = Some(self.parse_fixed(&chunk)?);
                    self.stage = Stage::Table;
                }
                Stage::Table => {
                    let h = self.parse_table(&chunk)?;
                    self.header = Some(h);
                    self.stage = Stage::Group(0);
                }
                Stage::Group(g) => {
                    let img = self.decode_group(g, &chunk)?;
                    self.levels.push(img);
                    let total = self.header.as_ref().map_or(0, |h| h.levels as usize);
                    self.stage = if g + 1 == total {
                        Stage::Done
                    } else {
                        Stage::Group(g + 1)
                    };
                }
                Stage::Done | Stage::Failed => unreachable!("handled above"),
            }
        }
    }

    fn parse_fixed(&self, b: &[u8]) -> Result<(Method, u8, u8, u32, u32), PtmError> {
        let magic = [b[0], b[1], b[2], b[3]];
        if magic != MAGIC {
            return Err(PtmError::BadMagic(magic));
        }
        if b[4] != FORMAT_VERSION {
            return Err(PtmError::UnsupportedVersion(b[4]));
        }
        let method = Method::from_byte(b[5]).ok_or(PtmError::UnknownMethod(b[5]))?;
        let channels = b[6];
        let levels = b[7];
        let width = u32::from_le_bytes([b[8], b[9], b[10], b[11]]);
        let height = u32::from_le_bytes([b[12], b[13], b[14], b[15]]);
        let bad = |field, value: u64, reason| PtmError::BadHeader {
            field,
            value,
            reason,
        };
        if !(1..=4).contains(&channels) {
            return Err(bad("channels", channels as u64, "must be 1 to 4"));
        }
        if width == 0 {
            return Err(bad("width", 0, "must be positive"));
        }
        if height == 0 {
            return Err(bad("height", 0, "must be positive"));
        }
        for (what, v) in [("width", width), ("height", height)] {
            if v > self.limits.max_side {
                return Err(PtmError::LimitsExceeded {
                    what,
                    value: v as u64,
                    limit: self.limits.max_side as u64,
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
        if decoded > self.limits.max_decoded_bytes {
            return Err(PtmError::LimitsExceeded {
                what: "decoded bytes",
                value: decoded,
                limit: self.limits.max_decoded_bytes,
            });
        }
        Ok((method, channels, levels, width, height))
    }

    fn parse_table(&self, b: &[u8]) -> Result<Header, PtmError> {
        let (method, channels, levels, width, height) =
            self.fixed.expect("table follows the fixed header");
        let group_lens: Vec<u32> = b
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let h = Header {
            method,
            channels,
            width,
            height,
            levels,
            group_lens,
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
                _ => {}
            }
        }
        Ok(h)
    }

    fn decode_group(&mut self, g: usize, payload: &[u8]) -> Result<Image, PtmError> {
        let h = self.header.as_ref().expect("groups follow the header");
        let (method, c) = (h.method, h.channels);
        let level = h.level_of_group(g);
        let (w, hh) = level_dims(h.width, h.height, level);
        let expected = plain_len(h, g) as usize;
        let plain: Cow<[u8]> = match method {
            Method::Raw => Cow::Borrowed(payload),
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
        Method::Raw => plain.to_vec(),
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
