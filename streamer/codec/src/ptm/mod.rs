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
//!
//! ```text
//! offset  bytes  field
//! 0       1      format version: 3
//! 1       1      method: 0 = raw (the paper's layout, no compression), 1 = parent
//!                prediction + zstd, 2 = parent prediction + context-modelled range coding
//! 2       1      bits 0–2: channels C (1 grey, 2 grey+alpha, 3 RGB, 4 RGBA);
//!                bit 4: colour within alpha — every colour sample is at most its pixel's
//!                alpha at every level (method 2 with C = 2 or 4 only; method 2 codes
//!                nothing it implies); every other bit 0
//! 3       1      level count L, 1 ..= 1 + ⌈log2 max(W, H)⌉
//! 4       1      near: the largest error of a colour sample, 0 (lossless) ..= 32; nonzero
//!                only with method 2
//! 5       …      LEB128 varints (7 bits a byte, least significant group first, high bit =
//!                more follows; at most 5 bytes, value < 2³²): W, H (both ≥ 1), then L
//!                payload lengths: group 0's .. group L−1's
//! then the L group payloads back to back, group 0 first; nothing after the last
//! ```
//!
//! Levels: level 0 is `W × H`; level `ℓ + 1` is `⌈w/2⌉ × ⌈h/2⌉` of level `ℓ`'s `w × h`
//! ([`level_dims`]). Group `g` holds level `L − 1 − g`: group 0 the lowest stored level
//! whole, group `g ≥ 1` what the level needs beyond its parent (level `L − g`, decoded by
//! the group before). Samples are interleaved (`(y·w + x)·C + c`), rows top to bottom.
//! A PTM is found through a table that says what it is, so the header has no magic and its
//! sizes are varints: 10–16 bytes for a tile instead of the 40 of format 2.
//! Group 0 as a *stream chunk* includes the header, so fetching chunk 0 gives everything
//! needed to ask for any other chunk by byte range ([`Encoded::groups`], [`Header::chunk_range`]).
//!
//! A decoder checks every field before allocating: the sizes against [`Limits`] (each side,
//! and the bytes of all `L` levels), and each payload length `len` against the group's
//! *plain length* — group 0: `w·h·C` of its level; group `g ≥ 1`: `s·C` for the stored
//! pixels, `s = w·h − pw·ph`, plus the residuals, `⌈pw·ph·C / 4⌉` bytes for method 0 and
//! `pw·ph·C` for methods 1 and 2 (`pw × ph` the parent's size). Method 0 needs
//! `len = plain`, method 1 `2 ≤ len ≤ plain + plain/128 + 1025`, method 2
//! `len ≤ 4·plain + 1024`.
//!
//! **Blocks.** Pixel `(x, y)` of a level belongs to the block of parent pixel
//! `(⌊x/2⌋, ⌊y/2⌋)`. A block has `n` = 4, 2 or 1 pixels (2 or 1 on an odd right or bottom
//! edge). Its *rebuilt* pixel is its last in raster order: `(x odd or x = w − 1) and
//! (y odd or y = h − 1)`; the others are *stored*. Rebuilt pixels, met in raster order, are
//! one per parent pixel in the parent's raster order. A rebuilt sample is
//! `v = n·parent + ε − others` (eq. 3), `others` the sum of the block's other samples of that
//! channel and `ε ∈ [0, n)` the block's residual; `v` outside 0..=255 or `ε ≥ n` is damage.
//!
//! ## Method 0 (raw)
//! Group 0: the level's samples. Group `g ≥ 1`: the residuals ε of every parent sample
//! (parent raster order, channels interleaved), 2 bits each, four to a byte from the low bits,
//! the unused bits of the last byte 0; then the samples of the stored pixels in raster order.
//!
//! ## Method 1 (zstd)
//! Each payload is a *mode* byte and one zstd frame that decompresses to exactly the plain
//! length. Group 0 (mode 0): per channel `c`, a plane of `w·h` bytes, each sample minus the
//! one before it in that plane (mod 256; the first minus 0). Group `g ≥ 1`, in plain
//! (interleaved) order: per parent sample a residual code `(ε − guess) mod 4` (one byte),
//! then per sample of the stored pixels `(I − pred) mod 256`, where a sample is predicted in
//! raster order from the level decoded so far (rebuilt pixels included as soon as their block
//! is complete): `pred = MED(W, N, NW) = clamp(W + N − NW, min(W, N), max(W, N))` inside the
//! level, `W` on the first row, `N` in the first column, and for pixel (0, 0) its parent's
//! sample; a rebuilt sample's `guess = clamp(others + pred − n·parent, 0, n − 1)` (a code
//! above 3 is damage). The plain bytes are stored rearranged: the colour channels' residual
//! codes (interleaved), their prediction errors (interleaved), then, with 2 or 4 channels,
//! the alpha residual codes and the alpha errors as planes of their own. Mode bit 0 (RGB and
//! RGBA only; every other bit 0, and group 0 always mode 0): the errors of red and blue are
//! stored as `(e_R − e_G) mod 256` and `(e_B − e_G) mod 256`.
//!
//! ## Method 2 (context-modelled range coding; what databases store)
//! Each payload is one range-coded stream ([`crate::entropy`], a fresh decoder per group,
//! zeros read past the payload's end). The context models are made once per PTM, every
//! probability at ½, and carried from group to group:
//!
//! ```text
//! colour[2][2][2][8]   Signed: [level class][green or grey: 0, red or blue: 1][edge][activity]
//! alpha[2][2][8]       Signed: [level class][parent sample is 0][activity]
//! residual[3][2][3]    three Bits: [channel class: alpha 0, green or grey 1, red or blue 2]
//!                      [block of 4 pixels][min(activity, 5) / 2]
//! ```
//!
//! (indices row-major, e.g. `colour[lc][k][e][a]` at `((lc·2 + k)·2 + e)·8 + a`). A group
//! codes level `ℓ` (`w × h`); its level class `lc` is 0 for `ℓ = 0`, else 1; `near` and the
//! colour-within-alpha flag `F` (with an alpha channel) come from the header. With 3 or 4
//! channels the group starts with one even decision, `D`: red and blue relative to green.
//! Then every pixel in raster order, its channels in the order
//!
//! ```text
//! C = 1: grey                C = 2: alpha, grey
//! C = 3: green, red, blue    C = 4: alpha, green, red, blue
//! ```
//!
//! and per pixel `g_err = 0`. Each sample, with `pv` the parent's sample of its block
//! (none in group 0), `lossy = (colour channel and near > 0)`, `A` the pixel's alpha
//! (decoded first; 255 without alpha) and `rebuilt` only when there is a parent:
//!
//! 1. `pv = 255` and not lossy: the sample is 255, nothing coded (the block's floor mean is
//!    255). `F`, a colour channel and `A = 0`: the sample is 0, nothing coded.
//! 2. Neighbours in the level decoded so far: `W` (x > 0), `N` (y > 0), `NW`, `NE`
//!    (x + 1 < w); with `F` on a colour channel a neighbour whose alpha is 0 is absent.
//!    `edge = F and colour and (A < 255 or W absent with x > 0 or N absent with y > 0)`.
//!    With `W` and `N`: `c = NW`, or `⌊(W + N)/2⌋` when `NW` is absent; `NE` defaults to `N`;
//!    `pred = clamp(W + N − c, min(W, N), max(W, N))` and
//!    `act = |W − c| + |N − c| + |N − NE|`. Only `W`: `pred = W`; only `N`: `pred = N`;
//!    neither: `pred = pv` (0 in group 0); `act = 0` in those three cases. Then
//!    `act += |pred − pv|` when there is a parent and the pixel is stored; `hi = A` with `F`
//!    on a colour channel, else 255; `pred = min(pred, hi)`; and `act` becomes its bucket,
//!    the number of the bounds 0, 2, 5, 10, 20, 40, 80 it exceeds (0 ..= 7).
//! 3. Rebuilt and not lossy: with the block's `n` and `others`, `n = 1` gives `pv`, nothing
//!    coded; else `guess = clamp(others + pred − n·pv, 0, n − 1)` and `d ∈ [0, n)` is read
//!    from the three bits `r = residual[class][n = 4][min(act, 5)/2]`: a 1 with `r[0]` is
//!    `d = 0`; else `n = 2` gives `d = 1`; else a 1 with `r[1]` is `d = 1`; else a 1 with
//!    `r[2]` is `d = 3`, a 0 is `d = 2`. `ε = (guess + d) mod n` and the sample is eq. 3.
//! 4. Otherwise the model is `alpha[lc][pv = 0][act]` for alpha, `colour[lc][k][edge][act]`
//!    for colour; `base = g_err` for red and blue when `D`, else 0; `s` is a Signed.
//!    Lossless: `e = wrap(s + base)` (`wrap`: to −128..=127 modulo 256), the sample is
//!    `(pred + e) mod 256`. Lossy colour: a rebuilt pixel's `pred` first becomes
//!    `clamp(pred, lo', max(min(n·pv + n − 1 − others, hi), lo'))` with
//!    `lo' = max(n·pv − others, 0)`; then `q = s + base` and the sample is
//!    `clamp(pred + q·(2·near + 1), 0, hi)` (the encoder's `q` is
//!    `sign(e)·⌊(|e| + near)/(2·near + 1)⌋` for `e = I − pred`). For green (or grey),
//!    `g_err = e` (lossless) or `q` (lossy).
//!
//! In the lossy mode a group is coded against the parent as the decoder rebuilt it, so every
//! sample of every level is within `near` of the lossless pyramid's; alpha stays exact.
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
