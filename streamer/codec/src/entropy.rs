//! Adaptive binary range coding: the entropy coder of the PTM's context-modelled groups
//! ([`crate::ptm`], method 2) and of the compact meshes ([`crate::mesh`]).
//!
//! Main types: [`Bit`] (an adaptive probability), the [`Encoder`] and the sans-IO [`Decoder`]
//! over one byte stream, and the binarisations built on them: [`Unsigned`] (an adaptive
//! Elias-gamma code for integers ≥ 0) and [`Signed`] (a zero flag, a sign and an
//! [`Unsigned`] magnitude).
//!
//! The coder is the carry-propagating range coder of LZMA (32-bit range, a byte at a time,
//! the first byte — always 0 — left out), with 16-bit probabilities. A [`Bit`] starts at ½
//! and learns at the rate of a Krichevsky–Trofimov estimator, `1/(n + 2)` after `n` bits,
//! until that reaches `1/32`, then keeps that rate: a context seen a handful of times is
//! already well estimated, which matters for streams of a few hundred bytes (a 32² tile's
//! level), and an old one keeps following its data. The stream ends with as few bytes as
//! leave its value inside the final interval; a decoder reads zeros past the end, so a
//! stream of any length decodes to something, and how much it decodes is bounded by its
//! caller (a number of pixels or vertices), never by the bytes.
//!
//! No well-kept crate exposes an adaptive binary range coder as a library (LZMA
//! implementations keep theirs private); this one is ~150 lines and its round trip is
//! property-tested below.
//!
//! ## The stream, exactly
//!
//! All arithmetic below is on unsigned integers unless it says otherwise; `>>` is a shift
//! (on a negative `i32`, arithmetic: it rounds towards −∞).
//!
//! **Adaptive bit.** A [`Bit`] is `p` (16 bits: P(bit = 1) in units of 2⁻¹⁶) and `n` (the
//! observations so far, 0 ..= 30). It starts at `p = 32768, n = 0`. After coding `bit` it
//! becomes, in `i32` arithmetic,
//!
//! ```text
//! target = 65536 if bit = 1, else 0
//! rate   = ⌊65536 / (n + 2)⌋            (n = 30: 2048, i.e. 1/32)
//! p      = clamp(p + ((target − p) · rate >> 16), 31, 65505)
//! n      = n + 1 if n < 30
//! ```
//!
//! **Decoder state.** `range` and `code`, 32 bits each. At the start `range = 0xFFFF_FFFF`
//! and `code` is the first 4 bytes of the stream, big-endian. Every byte read past the end
//! of the stream is 0 (a stream may be empty). *Renormalisation*, after every decision:
//! while `range < 2²⁴`: `range = range << 8`, `code = (code << 8) | next byte` (both kept to
//! 32 bits).
//!
//! **Modelled decision** with bit model `m`: `bound = (range >> 16) · m.p`; the bit is 1 when
//! `code < bound`, then `range = bound`; else it is 0, `code −= bound` and `range −= bound`.
//! Then `m` is updated (above) and the state renormalised. The 1 takes the *lower* part of
//! the interval.
//!
//! **Even decision** (probability ½, no model): `range = range >> 1`; the bit is 1 when
//! `code < range`, else it is 0 and `code −= range`; then renormalise.
//!
//! **Encoder.** The carry-propagating range encoder of LZMA: a 33-bit `low` (0 at the
//! start), `range = 0xFFFF_FFFF`, a cached byte (0) and a count of pending bytes (1). A
//! decision narrows `[low, low + range)` exactly as the decoder narrows `code` (a 0 adds
//! `bound`, or the halved range, to `low`); renormalising shifts out the top byte of `low`
//! through LZMA's `shift_low` (a byte is held back while it could still receive a carry).
//! To finish, `low` is replaced by the value in `[low, low + range − 1]` with the most
//! trailing zero bits, five bytes are shifted out, and then the first output byte (always
//! 0: the coded value starts below 1) and every trailing 0 byte are dropped — the decoder
//! reads those zeros back past the end. The stream is therefore the shortest one whose
//! value, read with zeros past its end, lies in the final interval.
//!
//! **Unsigned** (an adaptive Elias-gamma code of `v ≥ 0` up to 2³² − 1): models `unary[0..33]`
//! and `high[0..33][0..3]`, bits all. Let `x = v + 1` and `k = ⌊log2 x⌋` (0 ..= 32):
//!
//! ```text
//! unary    for i in 0 .. min(k, 32): a 1 with unary[i]; then, if k < 32, a 0 with unary[k]
//!          (a decoder counts the 1s, stopping at a 0 or at 32)
//! mantissa the k bits of x − 2^k, most significant first: the first min(k, 2) with
//!          high[k][node] — node 0 for the first, then 1 + (first bit) for the second —
//!          the rest as even decisions
//! ```
//!
//! A decoded value is `x − 1`, saturated to 2³² − 1.
//!
//! **Signed** (`i32`): models `zero` and `negative` (bits) and `magnitude` (an [`Unsigned`]).
//! A 1 with `zero` means 0; else a decision with `negative` (1: negative) and the magnitude
//! minus one as an [`Unsigned`]. A decoded magnitude is saturated to 2³¹ − 1.
//!
//! ```
//! use codec::entropy::{Bit, Decoder, Encoder, Signed};
//! let mut enc = Encoder::new();
//! let (mut flag, mut value) = (Bit::new(), Signed::new());
//! for v in [0i32, 3, -7, 0, 120] {
//!     enc.bit(&mut flag, v == 0);
//!     value.encode(&mut enc, v);
//! }
//! let bytes = enc.finish();
//! let mut dec = Decoder::new(&bytes);
//! let (mut flag, mut value) = (Bit::new(), Signed::new());
//! for v in [0i32, 3, -7, 0, 120] {
//!     assert_eq!(dec.bit(&mut flag), v == 0);
//!     assert_eq!(value.decode(&mut dec), v);
//! }
//! ```

/// Probability scale: a [`Bit`]'s `p` is P(1) in units of 2⁻¹⁶.
const ONE: u32 = 1 << 16;
/// Probabilities stay inside `[P_MIN, ONE − P_MIN]` so that neither symbol's interval is
/// ever empty.
const P_MIN: u32 = 31;
/// Observations after which a [`Bit`] adapts at its final rate.
const LEARN: u8 = 30;
/// `2¹⁶ / (n + 2)`: the learning rate after `n` observations (KT), the last entry the final
/// rate 1/32.
const RATE: [u32; LEARN as usize + 1] = {
    let mut t = [0u32; LEARN as usize + 1];
    let mut n = 0;
    while n <= LEARN as usize {
        t[n] = ONE / (n as u32 + 2);
        n += 1;
    }
    t
};
const TOP: u32 = 1 << 24;

/// An adaptive binary probability.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bit {
    /// P(bit = 1) in units of 2⁻¹⁶.
    p: u16,
    /// Observations so far, up to [`LEARN`].
    n: u8,
}

impl Default for Bit {
    fn default() -> Self {
        Bit::new()
    }
}

impl Bit {
    /// P(1) = ½, nothing learnt yet.
    pub const fn new() -> Bit {
        Bit {
            p: (ONE / 2) as u16,
            n: 0,
        }
    }

    /// P(1) ≈ `p1` (clamped into the coder's range), as if learnt from `seen` observations.
    pub fn with(p1: f64, seen: u8) -> Bit {
        let p = (p1 * ONE as f64).round() as i64;
        Bit {
            p: p.clamp(P_MIN as i64, (ONE - P_MIN) as i64) as u16,
            n: seen.min(LEARN),
        }
    }

    /// The current P(1), for tests and statistics.
    pub fn p1(&self) -> f64 {
        self.p as f64 / ONE as f64
    }

    #[inline(always)]
    fn update(&mut self, bit: bool) {
        let p = self.p as i32;
        let target = if bit { ONE as i32 } else { 0 };
        let step = ((target - p) * RATE[self.n as usize] as i32) >> 16;
        self.p = (p + step).clamp(P_MIN as i32, (ONE - P_MIN) as i32) as u16;
        self.n += u8::from(self.n < LEARN);
    }
}

/// Range encoder writing into a byte vector.
#[derive(Debug)]
pub struct Encoder {
    out: Vec<u8>,
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
}

impl Default for Encoder {
    fn default() -> Self {
        Encoder::new()
    }
}

impl Encoder {
    pub fn new() -> Encoder {
        Encoder {
            out: Vec::new(),
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
        }
    }

    /// Codes `bit` with the adaptive probability `m`, then updates `m`.
    #[inline]
    pub fn bit(&mut self, m: &mut Bit, bit: bool) {
        let bound = (self.range >> 16) * m.p as u32;
        if bit {
            self.range = bound;
        } else {
            self.low += bound as u64;
            self.range -= bound;
        }
        m.update(bit);
        self.normalise();
    }

    /// Codes `bit` at probability ½ (no model).
    #[inline]
    pub fn even(&mut self, bit: bool) {
        self.range >>= 1;
        if !bit {
            self.low += self.range as u64;
        }
        self.normalise();
    }

    /// Codes the low `n` bits of `v` (most significant first) at probability ½ each.
    pub fn evens(&mut self, v: u32, n: u32) {
        for k in (0..n).rev() {
            self.even((v >> k) & 1 == 1);
        }
    }

    #[inline(always)]
    fn normalise(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    fn shift_low(&mut self) {
        if self.low < 0xFF00_0000 || self.low >= 1 << 32 {
            let carry = (self.low >> 32) as u8;
            let mut byte = self.cache;
            loop {
                self.out.push(byte.wrapping_add(carry));
                byte = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = (self.low >> 24) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// The coded bytes: the shortest stream whose value (read with zeros past its end) lies in
    /// the final interval.
    pub fn finish(mut self) -> Vec<u8> {
        // The value with the most trailing zero bits inside [low, low + range).
        let end = self.low + self.range as u64 - 1;
        let mut mask = (1u64 << 32) - 1;
        let value = loop {
            let v = (self.low + mask) & !mask;
            if v <= end || mask == 0 {
                break v;
            }
            mask >>= 1;
        };
        self.low = value;
        for _ in 0..5 {
            self.shift_low();
        }
        // The first byte is always 0 (the value starts below 1) and trailing zeros are what a
        // decoder reads past the end anyway.
        debug_assert_eq!(self.out.first(), Some(&0));
        let mut out = if self.out.is_empty() {
            Vec::new()
        } else {
            self.out.split_off(1)
        };
        while out.last() == Some(&0) {
            out.pop();
        }
        out
    }

    /// Bytes written so far (the stream's length up to a few bytes).
    pub fn len(&self) -> usize {
        self.out.len()
    }

    pub fn is_empty(&self) -> bool {
        self.out.is_empty()
    }
}

/// Range decoder over a complete stream (zeros are read past its end).
#[derive(Debug)]
pub struct Decoder<'a> {
    input: &'a [u8],
    at: usize,
    range: u32,
    code: u32,
}

impl<'a> Decoder<'a> {
    pub fn new(input: &'a [u8]) -> Decoder<'a> {
        let mut d = Decoder {
            input,
            at: 0,
            range: u32::MAX,
            code: 0,
        };
        for _ in 0..4 {
            d.code = (d.code << 8) | d.next() as u32;
        }
        d
    }

    #[inline(always)]
    fn next(&mut self) -> u8 {
        let b = self.input.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        b
    }

    /// Decodes a bit coded with the adaptive probability `m`, then updates `m`.
    #[inline]
    pub fn bit(&mut self, m: &mut Bit) -> bool {
        let bound = (self.range >> 16) * m.p as u32;
        let bit = self.code < bound;
        if bit {
            self.range = bound;
        } else {
            self.code -= bound;
            self.range -= bound;
        }
        m.update(bit);
        self.normalise();
        bit
    }

    /// Decodes a bit coded at probability ½.
    #[inline]
    pub fn even(&mut self) -> bool {
        self.range >>= 1;
        let bit = self.code < self.range;
        if !bit {
            self.code -= self.range;
        }
        self.normalise();
        bit
    }

    /// Decodes `n` bits coded by [`Encoder::evens`].
    pub fn evens(&mut self, n: u32) -> u32 {
        let mut v = 0;
        for _ in 0..n {
            v = (v << 1) | u32::from(self.even());
        }
        v
    }

    #[inline(always)]
    fn normalise(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next() as u32;
        }
    }
}

/// Exponent classes of an [`Unsigned`]: `⌊log2(v + 1)⌋` of every `u32` (0 ..= 32).
const CLASSES: usize = 33;

/// An adaptive Elias-gamma code for integers `v ≥ 0`: the class `k = ⌊log2(v + 1)⌋` in unary
/// (one adaptive bit per step), then the `k` bits below the leading one of `v + 1`, the first
/// [`Unsigned::MODELLED`] of them adaptive per class, the rest at probability ½.
#[derive(Clone, Debug)]
pub struct Unsigned {
    unary: [Bit; CLASSES],
    high: [[Bit; 3]; CLASSES],
}

impl Default for Unsigned {
    fn default() -> Self {
        Unsigned::new()
    }
}

impl Unsigned {
    /// Mantissa bits with a model of their own per class (the most significant; the next ones
    /// modelled by the first's value).
    pub const MODELLED: u32 = 2;

    pub fn new() -> Unsigned {
        Unsigned {
            unary: [Bit::new(); CLASSES],
            high: [[Bit::new(); 3]; CLASSES],
        }
    }

    pub fn encode(&mut self, e: &mut Encoder, v: u32) {
        let x = v as u64 + 1;
        let k = 63 - x.leading_zeros() as usize; // ≤ 32
        for i in 0..k.min(CLASSES - 1) {
            e.bit(&mut self.unary[i], true);
        }
        if k < CLASSES - 1 {
            e.bit(&mut self.unary[k], false);
        }
        let rest = x - (1 << k);
        let k = k as u32;
        let modelled = k.min(Self::MODELLED);
        let c = (k as usize).min(CLASSES - 1);
        let mut node = 0usize;
        for i in 0..modelled {
            let b = (rest >> (k - 1 - i)) & 1 == 1;
            e.bit(&mut self.high[c][node], b);
            node = 1 + usize::from(b);
        }
        e.evens((rest & ((1u64 << (k - modelled)) - 1)) as u32, k - modelled);
    }

    /// Decodes a value; values that do not fit in `u32` (only from damaged streams) saturate.
    pub fn decode(&mut self, d: &mut Decoder) -> u32 {
        let mut k = 0usize;
        while k < CLASSES - 1 && d.bit(&mut self.unary[k]) {
            k += 1;
        }
        let c = k;
        let k = k as u32;
        let modelled = k.min(Self::MODELLED);
        let mut rest = 0u64;
        let mut node = 0usize;
        for _ in 0..modelled {
            let b = d.bit(&mut self.high[c][node]);
            rest = (rest << 1) | u64::from(b);
            node = 1 + usize::from(b);
        }
        rest = (rest << (k - modelled)) | d.evens(k - modelled) as u64;
        let x = (1u64 << k) + rest;
        u32::try_from(x - 1).unwrap_or(u32::MAX)
    }
}

/// A signed integer: a zero flag, a sign and the magnitude − 1 as an [`Unsigned`].
#[derive(Clone, Debug, Default)]
pub struct Signed {
    zero: Bit,
    negative: Bit,
    magnitude: Unsigned,
}

impl Signed {
    pub fn new() -> Signed {
        Signed::default()
    }

    pub fn encode(&mut self, e: &mut Encoder, v: i32) {
        e.bit(&mut self.zero, v == 0);
        if v != 0 {
            e.bit(&mut self.negative, v < 0);
            self.magnitude.encode(e, v.unsigned_abs() - 1);
        }
    }

    /// Decodes a value; magnitudes beyond `i32` (only from damaged streams) saturate.
    pub fn decode(&mut self, d: &mut Decoder) -> i32 {
        if d.bit(&mut self.zero) {
            return 0;
        }
        let negative = d.bit(&mut self.negative);
        let m = self
            .magnitude
            .decode(d)
            .saturating_add(1)
            .min(i32::MAX as u32) as i32;
        if negative {
            -m
        } else {
            m
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[derive(Clone, Debug)]
    enum Sym {
        Bit(usize, bool),
        Even(bool),
        U(usize, u32),
        S(usize, i32),
    }

    fn sym() -> impl Strategy<Value = Sym> {
        prop_oneof![
            (0usize..4, any::<bool>()).prop_map(|(c, b)| Sym::Bit(c, b)),
            (0usize..4, prop::bool::weighted(0.9)).prop_map(|(c, b)| Sym::Bit(c, b)),
            any::<bool>().prop_map(Sym::Even),
            (0usize..2, prop_oneof![0u32..20, any::<u32>()]).prop_map(|(c, v)| Sym::U(c, v)),
            (0usize..2, prop_oneof![-20i32..20, any::<i32>()]).prop_map(|(c, v)| Sym::S(c, v)),
        ]
    }

    fn code(syms: &[Sym]) -> Vec<u8> {
        let mut e = Encoder::new();
        let mut bits = [Bit::new(); 4];
        let mut us = [Unsigned::new(), Unsigned::new()];
        let mut ss = [Signed::new(), Signed::new()];
        for s in syms {
            match *s {
                Sym::Bit(c, b) => e.bit(&mut bits[c], b),
                Sym::Even(b) => e.even(b),
                Sym::U(c, v) => us[c].encode(&mut e, v),
                Sym::S(c, v) => ss[c].encode(&mut e, v.max(-i32::MAX)),
            }
        }
        e.finish()
    }

    fn check(syms: &[Sym], bytes: &[u8]) -> bool {
        let mut d = Decoder::new(bytes);
        let mut bits = [Bit::new(); 4];
        let mut us = [Unsigned::new(), Unsigned::new()];
        let mut ss = [Signed::new(), Signed::new()];
        syms.iter().all(|s| match *s {
            Sym::Bit(c, b) => d.bit(&mut bits[c]) == b,
            Sym::Even(b) => d.even() == b,
            Sym::U(c, v) => us[c].decode(&mut d) == v,
            Sym::S(c, v) => ss[c].decode(&mut d) == v.max(-i32::MAX),
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn round_trips(syms in proptest::collection::vec(sym(), 0..400)) {
            let bytes = code(&syms);
            prop_assert!(check(&syms, &bytes));
        }

        #[test]
        fn arbitrary_streams_decode_without_panicking(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let mut d = Decoder::new(&bytes);
            let mut u = Unsigned::new();
            let mut s = Signed::new();
            for _ in 0..100 {
                u.decode(&mut d);
                s.decode(&mut d);
            }
        }
    }

    #[test]
    fn skewed_bits_cost_their_entropy() {
        // 10 000 bits with P(1) = 0.05: entropy 0.286 bits each = 358 bytes.
        let mut e = Encoder::new();
        let mut m = Bit::new();
        let bits: Vec<bool> = (0..10_000u32).map(|i| (i * 7919) % 20 == 0).collect();
        for &b in &bits {
            e.bit(&mut m, b);
        }
        let out = e.finish();
        assert!(out.len() < 400, "{} bytes", out.len());
        let mut d = Decoder::new(&out);
        let mut m = Bit::new();
        assert!(bits.iter().all(|&b| d.bit(&mut m) == b));
    }

    #[test]
    fn empty_and_all_zero_streams_are_short() {
        assert!(Encoder::new().finish().is_empty());
        let mut e = Encoder::new();
        let mut m = Bit::new();
        for _ in 0..1000 {
            e.bit(&mut m, false);
        }
        assert!(e.finish().len() <= 6);
    }

    #[test]
    fn learning_follows_kt_then_a_fixed_rate() {
        let mut m = Bit::new();
        m.update(true);
        assert!((m.p1() - 0.75).abs() < 1e-3, "{}", m.p1());
        m.update(true);
        assert!((m.p1() - 5.0 / 6.0).abs() < 1e-3, "{}", m.p1());
        for _ in 0..1000 {
            m.update(true);
        }
        assert!(m.p1() > 0.99);
        assert!(Bit::with(2.0, 255).p1() < 1.0 && Bit::with(-1.0, 0).p1() > 0.0);
    }

    #[test]
    fn extreme_unsigned_values_round_trip() {
        let vals = [0, 1, 2, 3, 1 << 20, u32::MAX - 1, u32::MAX];
        let mut e = Encoder::new();
        let mut u = Unsigned::new();
        for &v in &vals {
            u.encode(&mut e, v);
        }
        let b = e.finish();
        let mut d = Decoder::new(&b);
        let mut u = Unsigned::new();
        for &v in &vals {
            assert_eq!(u.decode(&mut d), v);
        }
    }
}
