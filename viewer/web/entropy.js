// The adaptive binary range decoder of railview's codecs (codec::entropy): the LZMA range
// coder with 16-bit probabilities learning at the Krichevsky–Trofimov rate down to 1/32.
// The stream's exact definition is the Rust module's documentation; this follows it step by
// step. Zeros are read past the end of a stream, so a cut stream decodes to something; the
// callers bound how much they decode (pixels, vertices), never the bytes.

const ONE = 1 << 16;
const P_MIN = 31;
const LEARN = 30;
const RATE = new Int32Array(LEARN + 1);
for (let n = 0; n <= LEARN; n++) RATE[n] = Math.floor(ONE / (n + 2));
const TOP = 1 << 24;

// Bits of one unsigned model: unary[33] then high[33][3].
export const UNSIGNED_BITS = 33 + 99;
// Bits of one signed model: zero, negative, then an unsigned magnitude.
export const SIGNED_BITS = 2 + UNSIGNED_BITS;

// A block of adaptive bits, each P(1) = 1/2 with nothing learnt.
export class Models {
  constructor(count) {
    this.p = new Int32Array(count).fill(ONE / 2);
    this.n = new Uint8Array(count);
  }
}

export class Decoder {
  constructor(bytes) {
    this.b = bytes;
    this.at = 0;
    this.range = 0xffffffff;
    this.code = 0;
    for (let i = 0; i < 4; i++) this.code = ((this.code << 8) | this.next()) >>> 0;
  }

  next() {
    const v = this.at < this.b.length ? this.b[this.at] : 0;
    this.at++;
    return v;
  }

  normalise() {
    while (this.range < TOP) {
      this.range = (this.range * 256) >>> 0;
      this.code = ((this.code << 8) | this.next()) >>> 0;
    }
  }

  // A decision with adaptive bit `i` of models `m`; updates it.
  bit(m, i) {
    const p = m.p[i];
    const bound = (this.range >>> 16) * p;
    let bit;
    if (this.code < bound) {
      this.range = bound;
      bit = 1;
    } else {
      this.code -= bound;
      this.range -= bound;
      bit = 0;
    }
    const n = m.n[i];
    const step = ((bit ? ONE - p : -p) * RATE[n]) >> 16;
    let q = p + step;
    if (q < P_MIN) q = P_MIN;
    else if (q > ONE - P_MIN) q = ONE - P_MIN;
    m.p[i] = q;
    if (n < LEARN) m.n[i] = n + 1;
    this.normalise();
    return bit;
  }

  // A decision at probability 1/2.
  even() {
    this.range = this.range >>> 1;
    let bit = 1;
    if (this.code >= this.range) {
      this.code -= this.range;
      bit = 0;
    }
    this.normalise();
    return bit;
  }

  // An adaptive Elias-gamma value (0 ..= 2^32 - 1, saturated) with the unsigned model at
  // `base` of `m`.
  unsigned(m, base) {
    let k = 0;
    while (k < 32 && this.bit(m, base + k)) k++;
    const modelled = Math.min(k, 2);
    let rest = 0;
    let node = 0;
    const high = base + 33 + k * 3;
    for (let i = 0; i < modelled; i++) {
      const b = this.bit(m, high + node);
      rest = rest * 2 + b;
      node = 1 + b;
    }
    for (let i = modelled; i < k; i++) rest = rest * 2 + this.even();
    const x = 2 ** k + rest;
    return Math.min(x - 1, 0xffffffff);
  }

  // A signed value (magnitudes saturate at 2^31 - 1) with the signed model at `base`.
  signed(m, base) {
    if (this.bit(m, base)) return 0;
    const negative = this.bit(m, base + 1);
    const mag = Math.min(this.unsigned(m, base + 2) + 1, 0x7fffffff);
    return negative ? -mag : mag;
  }
}
