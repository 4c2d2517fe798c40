//! Progressive texture maps (PTM, Marvie & Bouatouch §4): a lossless mip pyramid sent level by
//! level, each level costing only 3/4 of its pixels plus a 2-bit residual per 2×2 block.
//!
//! Main types: [`Image`] (8-bit, 1–4 interleaved channels), [`encode`] → [`Encoded`] (the file
//! bytes plus the byte range of every level group), the sans-IO [`Decoder`] fed bytes in any
//! chunks, [`Limits`] that bound what untrusted input may allocate, and [`PtmError`].
//!
//! ## The pyramid (eq. 1, eq. 3)
//! Level 0 is the full image; level `n+1` is level `n` filtered by the 2×2 box filter with
//! integer arithmetic: `parent = sum >> 2` and the residual `ε = sum & 3` (eq. 1). Knowing the
//! parent, `ε` and three pixels of a block gives the fourth exactly (eq. 3):
//! `I(2i+1,2j+1) = 4·parent + ε − I(2i,2j) − I(2i+1,2j) − I(2i,2j+1)`.
//!
//! **Odd edges.** A level `w × h` has a parent `⌈w/2⌉ × ⌈h/2⌉`. On an odd right or bottom edge
//! the blocks are partial (2×1, 1×2 or 1×1 pixels). The parent of a block with `n` pixels is
//! `⌊sum / n⌋` and its residual `sum − n·parent ∈ [0, n)`, so eq. 3 still reconstructs it.
//! The pixel rebuilt from the others is always the *last* pixel of its block in raster order
//! (the bottom-right one for full blocks): `(x odd or x = w−1) and (y odd or y = h−1)`; a
//! 1×1 block stores nothing and is its parent.
//!
//! ## File layout (format 3)
//! ```text
//! 0   1  format version (3)
//! 1   1  method: 0 = raw (the paper's layout, no compression), 1 = parent prediction + zstd,
//!        2 = parent prediction + context-modelled range coding
//! 2   1  channels (1 grey, 2 grey+alpha, 3 RGB, 4 RGBA) in bits 0–2; bit 4: every colour
//!        sample is at most its alpha at every level (method 2 codes nothing it implies)
//! 3   1  level count L (1 ..= 1 + ⌈log2 max(w, h)⌉)
//! 4   1  near: the largest error of a colour sample (0 = lossless; only method 2)
//! 5   …  varint width of level 0, varint height, then L varints: the payload length of
//!        group 0 .. L−1 (LEB128)
//! then group 0: the lowest level (L−1) whole, in line-major order
//! then group g = 1 .. L−1: level L−1−g — residuals (2 bits per channel per parent pixel,
//!      raster order over the parent, channels interleaved, four per byte from the low bits),
//!      then the partial level (every pixel except the rebuilt ones, raster order)
//! ```
//! A PTM is found through a table that says what it is, so the header has no magic and its
//! sizes are varints: 10–16 bytes for a tile instead of the 40 of format 2.
//! Group 0 as a *stream chunk* includes the header, so fetching chunk 0 gives everything
//! needed to ask for any other chunk by byte range ([`Encoded::groups`], [`Header::chunk_range`]).
//!
//! With method 1 each group's payload is a mode byte and one zstd frame of: one byte per
//! residual, coded relative to the residual the neighbours predict, then every stored
//! sample's difference (mod 256) from its prediction (see `predict.rs`), the colour channels
//! interleaved and the alpha channel in planes of its own, red and blue optionally relative
//! to green (the mode byte, chosen per group by the encoder; see `layout.rs`). The lowest
//! level is coded as differences from the previous value in each channel plane (mode 0).
//! With method 2 each group is one adaptive range-coded stream whose context models carry
//! over from the groups before it (see `arith.rs`); it is what databases store. A group
//! decodes once its parent level is known.
//!
//! ```
//! use codec::ptm::{encode, Decoder, EncodeOptions, Image, Limits, Status};
//! let img = Image::from_fn(5, 3, 3, |x, y, c| (x * 40 + y * 7 + c as u32 * 3) as u8);
//! let enc = encode(&img, &EncodeOptions::default()).unwrap();
//! let mut dec = Decoder::new(Limits::default());
//! // Feed only the first two chunks: a coarser image is already available.
//! let first_two = &enc.bytes[..enc.groups[1].offset as usize + enc.groups[1].len as usize];
//! assert_eq!(dec.push(first_two).unwrap(), Status::NeedMore);
//! assert_eq!(dec.finest().unwrap().width(), 2); // 5×3 → 3×2 → 2×1 → 1×1
//! assert_eq!(dec.push(&enc.bytes[first_two.len()..]).unwrap(), Status::Done);
//! assert_eq!(dec.finest().unwrap(), &img);
//! ```

mod arith;
mod decode;
mod encode;
mod layout;
mod predict;
mod pyramid;

pub use decode::{decode, decode_up_to, Decoder, Status};
pub use encode::{encode, EncodeOptions, Encoded, GroupSpan, Method, MAX_NEAR};
pub use pyramid::{level_dims, max_levels, MipChain};

/// Format version written and read by this module (3: no magic, varint sizes, method 2 and
/// the lossy mode; files of versions 1 and 2 are refused with
/// [`PtmError::UnsupportedVersion`]).
pub const FORMAT_VERSION: u8 = 3;
/// Size of the fixed part of the header; the varints follow.
pub const FIXED_HEADER_LEN: usize = 5;
/// Header flag (in the channels byte): every colour sample is at most its alpha.
pub(crate) const FLAG_COLOUR_WITHIN_ALPHA: u8 = 0x10;

/// An 8-bit image with 1–4 interleaved channels, rows top to bottom.
#[derive(Clone, PartialEq, Eq)]
pub struct Image {
    width: u32,
    height: u32,
    channels: u8,
    data: Vec<u8>,
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Image({}×{}×{})", self.width, self.height, self.channels)
    }
}

impl Image {
    /// An image from interleaved bytes; checks sizes and channel count.
    pub fn new(width: u32, height: u32, channels: u8, data: Vec<u8>) -> Result<Image, PtmError> {
        if width == 0 || height == 0 {
            return Err(PtmError::InvalidImage(format!(
                "size {width}×{height} is empty"
            )));
        }
        if !(1..=4).contains(&channels) {
            return Err(PtmError::InvalidImage(format!(
                "{channels} channels (1 to 4 supported)"
            )));
        }
        let expected = width as u64 * height as u64 * channels as u64;
        if data.len() as u64 != expected {
            return Err(PtmError::InvalidImage(format!(
                "{} bytes for {width}×{height}×{channels} (expected {expected})",
                data.len()
            )));
        }
        Ok(Image {
            width,
            height,
            channels,
            data,
        })
    }

    /// An image whose sample (x, y, channel) is `f(x, y, channel)`.
    ///
    /// # Panics
    /// On an empty size or a channel count outside 1..=4 (a caller bug, not data).
    pub fn from_fn(
        width: u32,
        height: u32,
        channels: u8,
        mut f: impl FnMut(u32, u32, u8) -> u8,
    ) -> Image {
        assert!(width > 0 && height > 0 && (1..=4).contains(&channels));
        let mut data = Vec::with_capacity(width as usize * height as usize * channels as usize);
        for y in 0..height {
            for x in 0..width {
                for c in 0..channels {
                    data.push(f(x, y, c));
                }
            }
        }
        Image {
            width,
            height,
            channels,
            data,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn channels(&self) -> u8 {
        self.channels
    }
    /// Interleaved samples, `(y * width + x) * channels + c`.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    pub fn into_data(self) -> Vec<u8> {
        self.data
    }
    /// Sample at (x, y, c); `None` outside the image.
    pub fn get(&self, x: u32, y: u32, c: u8) -> Option<u8> {
        (x < self.width && y < self.height && c < self.channels).then(|| {
            self.data[(y as usize * self.width as usize + x as usize) * self.channels as usize
                + c as usize]
        })
    }
}

/// What untrusted PTM input may make the decoder allocate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted width and height of level 0.
    pub max_side: u32,
    /// Largest accepted total of decoded bytes over all levels (the whole pyramid is kept).
    pub max_decoded_bytes: u64,
}

impl Default for Limits {
    /// 16384 px per side, 1 GiB of decoded levels.
    fn default() -> Self {
        Limits {
            max_side: 16_384,
            max_decoded_bytes: 1 << 30,
        }
    }
}

/// Everything that can go wrong encoding or decoding a PTM.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PtmError {
    /// The encoder was given an inconsistent image or options.
    #[error("invalid image: {0}")]
    InvalidImage(String),
    #[error("unsupported PTM format version {0} (this decoder reads version {FORMAT_VERSION}; rebuild the database with `railview build`)")]
    UnsupportedVersion(u8),
    #[error("unknown PTM method {0}")]
    UnknownMethod(u8),
    /// A header field is impossible (zero size, level count too large, …).
    #[error("bad PTM header field {field} = {value}: {reason}")]
    BadHeader {
        field: &'static str,
        value: u64,
        reason: &'static str,
    },
    #[error("PTM {what} = {value} exceeds the limit {limit}")]
    LimitsExceeded {
        what: &'static str,
        value: u64,
        limit: u64,
    },
    /// A group's declared payload length cannot hold its level.
    #[error("PTM group {group} (level {level}): payload length {len} invalid ({reason})")]
    GroupLength {
        group: usize,
        level: u32,
        len: u64,
        reason: &'static str,
    },
    /// The group's zstd frame is damaged or does not decompress to the exact expected size.
    #[error("PTM group {group} (level {level}): {message}")]
    Compression {
        group: usize,
        level: u32,
        message: String,
    },
    /// A zstd group's mode byte has bits this decoder does not know or that do not fit the
    /// channel count (see the group layout).
    #[error("PTM group {group} (level {level}): unknown or inapplicable group mode {mode:#04x}")]
    UnknownGroupMode { group: usize, level: u32, mode: u8 },
    /// A residual larger than its block allows, or a rebuilt pixel outside 0..=255.
    #[error(
        "PTM level {level}: inconsistent residual at pixel ({x}, {y}) channel {channel} (value {value})"
    )]
    BadResidual {
        level: u32,
        x: u32,
        y: u32,
        channel: u8,
        value: i32,
    },
    /// The input ended before the last group (one-shot decode only; the streaming decoder
    /// answers [`Status::NeedMore`]).
    #[error("PTM truncated: {have} of {needed} bytes present")]
    Truncated { have: u64, needed: u64 },
    #[error("PTM has {0} bytes after its last group")]
    TrailingBytes(u64),
    /// A previous call failed; the decoder does not resynchronise.
    #[error("PTM decoder used after an error")]
    Poisoned,
}

/// The decoded header of a PTM file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    pub method: Method,
    pub channels: u8,
    /// Every colour sample is at most its alpha, at every level.
    pub colour_within_alpha: bool,
    /// Largest error of a colour sample (0: lossless).
    pub near: u8,
    pub width: u32,
    pub height: u32,
    /// Number of stored levels (level 0 = full resolution … `levels − 1` = lowest stored).
    pub levels: u8,
    /// Payload length of each group, group 0 = the lowest level.
    pub group_lens: Vec<u32>,
    /// Bytes of the header (the fixed part and the varints).
    pub header_len: usize,
}

impl Header {
    /// Bytes of the header including the group lengths.
    pub fn len(&self) -> usize {
        self.header_len
    }

    /// Never empty; here for clippy's `len_without_is_empty`.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Level number (0 = full resolution) decoded by group `g`.
    pub fn level_of_group(&self, g: usize) -> u32 {
        self.levels as u32 - 1 - g as u32
    }

    /// Byte range of stream chunk `g` in the file: chunk 0 is the header plus group 0, chunk
    /// `g > 0` is group `g`'s payload.
    pub fn chunk_range(&self, g: usize) -> Option<std::ops::Range<u64>> {
        if g >= self.levels as usize {
            return None;
        }
        let mut start = 0u64;
        let mut end = self.len() as u64 + self.group_lens[0] as u64;
        for len in &self.group_lens[1..=g] {
            start = end;
            end += *len as u64;
        }
        Some(start..end)
    }

    /// Total file size.
    pub fn file_len(&self) -> u64 {
        self.len() as u64 + self.group_lens.iter().map(|&l| l as u64).sum::<u64>()
    }
}

#[cfg(test)]
mod tests;
