// Progressive texture maps (codec::ptm, format 3): a streaming decoder fed bytes in any
// chunks, each level group decoded as soon as it is complete. Methods 0 (raw) and 2 (context
// modelled range coding, what databases store); method 1 (zstd) is refused with a clear
// error. The byte layout and the method-2 rules are the Rust module's documentation.

import { Decoder as RangeDecoder, Models, SIGNED_BITS } from "./entropy.js";

export const FORMAT_VERSION = 3;
const FLAG_WITHIN = 0x10;
const MAX_NEAR = 32;

// What untrusted input may allocate (the Rust defaults).
export const DEFAULT_LIMITS = { maxSide: 16384, maxDecodedBytes: 1 << 30 };

export class PtmError extends Error {}

export function levelDims(w, h, level) {
  for (let i = 0; i < level; i++) {
    w = Math.ceil(w / 2);
    h = Math.ceil(h / 2);
  }
  return [w, h];
}

export function maxLevels(w, h) {
  return 1 + ceilLog2(Math.max(w, h, 1));
}

function ceilLog2(m) {
  let k = 0;
  while (2 ** k < m) k++;
  return k;
}

function storedCount(w, h) {
  return w * h - Math.ceil(w / 2) * Math.ceil(h / 2);
}

// Parses a header from the start of `b`; null while incomplete.
export function parseHeader(b, limits = DEFAULT_LIMITS) {
  if (b.length < 5) return null;
  if (b[0] !== FORMAT_VERSION) {
    throw new PtmError(`unsupported PTM format version ${b[0]} (rebuild the database)`);
  }
  const method = b[1];
  if (method > 2) throw new PtmError(`unknown PTM method ${method}`);
  if (method === 1) throw new PtmError("PTM method 1 (zstd) is not read by the browser viewer");
  const flags = b[2] & ~7;
  const channels = b[2] & 7;
  const levels = b[3];
  const near = b[4];
  if (flags & ~FLAG_WITHIN) throw new PtmError(`PTM header: unknown flag bits ${flags}`);
  if (channels < 1 || channels > 4) throw new PtmError(`PTM header: ${channels} channels`);
  if (flags && (method !== 2 || (channels !== 2 && channels !== 4))) {
    throw new PtmError("PTM header: colour within alpha needs method 2 and alpha");
  }
  if (near > MAX_NEAR || (near > 0 && method !== 2)) throw new PtmError(`PTM header: near ${near}`);
  const vals = [];
  let at = 5;
  while (vals.length < 2 + levels) {
    let v = 0;
    let k = 0;
    for (;;) {
      if (at >= b.length) return null;
      const byte = b[at++];
      v += (byte & 0x7f) * 2 ** (7 * k);
      k++;
      if (!(byte & 0x80)) break;
      if (k === 5) throw new PtmError("PTM header: varint longer than 5 bytes");
    }
    if (v > 0xffffffff) throw new PtmError("PTM header: size larger than 32 bits");
    vals.push(v);
    if (vals.length === 2) checkSizes(vals[0], vals[1], channels, levels, limits);
  }
  const h = {
    method, channels, within: (flags & FLAG_WITHIN) !== 0, near,
    width: vals[0], height: vals[1], levels, groupLens: vals.slice(2), headerLen: at,
  };
  h.groupLens.forEach((len, g) => {
    const plain = plainLen(h, g);
    if (method === 0 && len !== plain) throw new PtmError(`PTM group ${g}: raw length ${len} ≠ ${plain}`);
    if (method === 2 && len > 4 * plain + 1024) throw new PtmError(`PTM group ${g}: length ${len} too large`);
  });
  return h;
}

function checkSizes(width, height, channels, levels, limits) {
  if (width === 0 || height === 0) throw new PtmError("PTM header: empty size");
  if (width > limits.maxSide || height > limits.maxSide) {
    throw new PtmError(`PTM header: ${width}×${height} exceeds the limit ${limits.maxSide}`);
  }
  if (levels === 0 || levels > 1 + ceilLog2(Math.max(width, height))) {
    throw new PtmError(`PTM header: ${levels} levels for ${width}×${height}`);
  }
  let decoded = 0;
  for (let l = 0; l < levels; l++) {
    const [w, h] = levelDims(width, height, l);
    decoded += w * h * channels;
  }
  if (decoded > limits.maxDecodedBytes) throw new PtmError(`PTM: ${decoded} decoded bytes exceed the limit`);
}

function levelOfGroup(h, g) {
  return h.levels - 1 - g;
}

function plainLen(h, g) {
  const c = h.channels;
  const level = levelOfGroup(h, g);
  const [w, hh] = levelDims(h.width, h.height, level);
  if (g === 0) return w * hh * c;
  const [pw, ph] = levelDims(h.width, h.height, level + 1);
  const residuals = h.method === 0 ? Math.ceil((pw * ph * c) / 4) : pw * ph * c;
  return residuals + storedCount(w, hh) * c;
}

function isRebuilt(x, y, w, h) {
  return ((x & 1) === 1 || x + 1 === w) && ((y & 1) === 1 || y + 1 === h);
}

// Method 2's context models, carried from group to group.
const ACTS = 8;
function bucket(a) {
  return a > 80 ? 7 : a > 40 ? 6 : a > 20 ? 5 : a > 10 ? 4 : a > 5 ? 3 : a > 2 ? 2 : a > 0 ? 1 : 0;
}
const ALPHA = 0;
const GREEN = 1;
const RED_BLUE = 2;
const ORDER = {
  1: [[0], [GREEN]],
  2: [[1, 0], [ALPHA, GREEN]],
  3: [[1, 0, 2], [GREEN, RED_BLUE, RED_BLUE]],
  4: [[3, 1, 0, 2], [ALPHA, GREEN, RED_BLUE, RED_BLUE]],
};

function newModels() {
  return {
    colour: new Models(2 * 2 * 2 * ACTS * SIGNED_BITS),
    alpha: new Models(2 * 2 * ACTS * SIGNED_BITS),
    residual: new Models(3 * 2 * 3 * 3),
  };
}

function wrap(v) {
  return ((v + 128) & 255) - 128;
}

// Decodes one method-2 group of level `level` (w × h) into `out`.
function arithLevel(d, m, hd, level, parent, out, w, h) {
  const C = hd.channels;
  const row = w * C;
  const hasAlpha = C === 2 || C === 4;
  const alphaCh = C - 1;
  const [chans, classes] = ORDER[C];
  const within = hd.within && hasAlpha;
  const near = hd.near;
  const step = 2 * near + 1;
  const lc = level > 0 ? 1 : 0;
  const decorrelate = C >= 3 ? d.even() : 0;
  const pw = parent ? parent.width : 0;
  const pdata = parent ? parent.data : null;
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const at = y * row + x * C;
      const rebuilt = parent !== null && isRebuilt(x, y, w, h);
      const pidx = ((y >> 1) * pw + (x >> 1)) * C;
      let greenErr = 0;
      for (let k = 0; k < C; k++) {
        const ch = chans[k];
        const cls = classes[k];
        const i = at + ch;
        const colour = cls !== ALPHA;
        const lossy = colour && near > 0;
        const pv = pdata ? pdata[pidx + ch] : -1;
        if (pv === 255 && !lossy) {
          out[i] = 255;
          continue;
        }
        const alpha = hasAlpha ? out[at + alphaCh] : 255;
        if (within && colour && alpha === 0) {
          out[i] = 0;
          continue;
        }
        const hi = within && colour ? alpha : 255;
        // Prediction and activity.
        const masked = within && colour;
        // A neighbour sample j is usable unless masked and its pixel's alpha is 0.
        const off = alphaCh - ch;
        const hasW = x > 0 && (!masked || out[i - C + off] > 0);
        const hasN = y > 0 && (!masked || out[i - row + off] > 0);
        const wv = hasW ? out[i - C] : 0;
        const nv = hasN ? out[i - row] : 0;
        const edge = masked && (alpha < 255 || (x > 0 && !hasW) || (y > 0 && !hasN));
        let pred;
        let act = 0;
        if (hasW && hasN) {
          const c = !masked || out[i - row - C + off] > 0 ? out[i - row - C] : (wv + nv) >> 1;
          const ne = x + 1 < w && (!masked || out[i - row + C + off] > 0) ? out[i - row + C] : nv;
          pred = Math.min(Math.max(wv + nv - c, Math.min(wv, nv)), Math.max(wv, nv));
          act = Math.abs(wv - c) + Math.abs(nv - c) + Math.abs(nv - ne);
        } else if (hasW) pred = wv;
        else if (hasN) pred = nv;
        else pred = pv >= 0 ? pv : 0;
        if (pv >= 0 && !rebuilt) act += Math.abs(pred - pv);
        if (pred > hi) pred = hi;
        act = bucket(act);
        if (rebuilt && !lossy) {
          out[i] = rebuiltLossless(d, m, out, x, y, w, h, row, C, ch, cls, pv, pred, act, level);
          continue;
        }
        let model;
        let base;
        if (cls === ALPHA) {
          model = m.alpha;
          base = ((lc * 2 + (pv === 0 ? 1 : 0)) * ACTS + act) * SIGNED_BITS;
        } else {
          model = m.colour;
          base = (((lc * 2 + cls - 1) * 2 + (edge ? 1 : 0)) * ACTS + act) * SIGNED_BITS;
        }
        const gbase = decorrelate && cls === RED_BLUE ? greenErr : 0;
        let v;
        let err;
        if (lossy) {
          let p = pred;
          if (rebuilt) {
            const { others, n: cnt } = blockOthers(out, x, y, w, h, row, C, ch);
            const pvv = pv >= 0 ? pv : 0;
            const lo = cnt * pvv - others;
            const top = cnt * pvv + cnt - 1 - others;
            if (lo <= top) {
              const l0 = Math.max(lo, 0);
              p = Math.min(Math.max(p, l0), Math.max(Math.min(top, hi), l0));
            }
          }
          const coded = d.signed(model, base);
          const q = Math.min(coded + gbase, 0x7fffffff);
          v = Math.min(Math.max(p + q * step, 0), hi);
          err = q;
        } else {
          const coded = d.signed(model, base);
          err = wrap(coded + gbase);
          v = (pred + err) & 255;
        }
        if (cls === GREEN) greenErr = err;
        out[i] = v;
      }
    }
  }
}

// The sum of the other samples of (x, y)'s block and its pixel count, in `block` (no
// allocation per sample).
const block = { others: 0, n: 1 };
function blockOthers(out, x, y, w, h, row, C, ch) {
  const x0 = x & ~1;
  const y0 = y & ~1;
  const twoCols = x0 + 1 < w;
  const twoRows = y0 + 1 < h;
  const base = y0 * row + x0 * C + ch;
  if (twoCols && twoRows) {
    block.others = out[base] + out[base + C] + out[base + row];
    block.n = 4;
  } else if (twoCols || twoRows) {
    block.others = out[base];
    block.n = 2;
  } else {
    block.others = 0;
    block.n = 1;
  }
  return block;
}

function rebuiltLossless(d, m, out, x, y, w, h, row, C, ch, cls, pv, pred, act, level) {
  const p = pv >= 0 ? pv : 0;
  const { others, n } = blockOthers(out, x, y, w, h, row, C, ch);
  if (n === 1) return p;
  const guess = Math.min(Math.max(others + pred - n * p, 0), n - 1);
  const r = m.residual;
  const base = ((cls * 2 + (n === 4 ? 1 : 0)) * 3 + (Math.min(act, 5) >> 1)) * 3;
  let dd;
  if (d.bit(r, base)) dd = 0;
  else if (n === 2 || d.bit(r, base + 1)) dd = 1;
  else dd = d.bit(r, base + 2) ? 3 : 2;
  const eps = (guess + dd) % n;
  const v = n * p + eps - others;
  if (v < 0 || v > 255) {
    throw new PtmError(`PTM level ${level}: damaged residual at (${x}, ${y}) channel ${ch}: ${v}`);
  }
  return v;
}

// Method 0: group 0 is the level's samples; later groups the 2-bit residuals, then the
// stored pixels' samples.
function rawLevel(payload, hd, parent, w, h, level) {
  const C = hd.channels;
  const out = new Uint8Array(w * h * C);
  if (!parent) {
    out.set(payload);
    return out;
  }
  const pw = parent.width;
  const nres = parent.width * parent.height * C;
  let at = Math.ceil(nres / 4);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      if (!isRebuilt(x, y, w, h)) {
        for (let c = 0; c < C; c++) out[(y * w + x) * C + c] = payload[at++];
      }
    }
  }
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      if (!isRebuilt(x, y, w, h)) continue;
      const pidx = ((y >> 1) * pw + (x >> 1)) * C;
      for (let c = 0; c < C; c++) {
        const { others, n } = blockOthers(out, x, y, w, h, w * C, C, c);
        const k = pidx + c;
        const eps = (payload[k >> 2] >> ((k & 3) * 2)) & 3;
        const v = n * parent.data[k] + eps - others;
        if (eps >= n || v < 0 || v > 255) {
          throw new PtmError(`PTM level ${level}: damaged residual at (${x}, ${y}) channel ${c}`);
        }
        out[(y * w + x) * C + c] = v;
      }
    }
  }
  return out;
}

// The streaming decoder: push bytes in any chunks; `levels[g]` is group g's level
// ({ width, height, channels, level, data }).
export class PtmDecoder {
  constructor(limits = DEFAULT_LIMITS) {
    this.limits = limits;
    this.header = null;
    this.pending = [];
    this.buf = new Uint8Array(0);
    this.levels = [];
    this.models = null;
    this.failed = null;
  }

  get done() {
    return this.header !== null && this.levels.length === this.header.levels;
  }

  // The finest decoded level, or null.
  finest() {
    return this.levels.length ? this.levels[this.levels.length - 1] : null;
  }

  // Feeds bytes; returns "done" or "more". Throws PtmError on damage (and stays failed).
  push(bytes) {
    if (this.failed) throw this.failed;
    try {
      return this.pushInner(bytes);
    } catch (e) {
      this.failed = e;
      throw e;
    }
  }

  pushInner(bytes) {
    const joined = new Uint8Array(this.buf.length + bytes.length);
    joined.set(this.buf);
    joined.set(bytes, this.buf.length);
    let at = 0;
    if (!this.header) {
      const h = parseHeader(joined, this.limits);
      if (!h) {
        this.buf = joined;
        return "more";
      }
      this.header = h;
      at = h.headerLen;
    }
    const h = this.header;
    while (this.levels.length < h.levels) {
      const g = this.levels.length;
      const len = h.groupLens[g];
      if (joined.length - at < len) break;
      this.levels.push(this.decodeGroup(g, joined.subarray(at, at + len)));
      at += len;
    }
    if (this.levels.length === h.levels && at < joined.length) {
      throw new PtmError(`PTM: ${joined.length - at} bytes after the last group`);
    }
    this.buf = joined.slice(at);
    return this.levels.length === h.levels ? "done" : "more";
  }

  decodeGroup(g, payload) {
    const h = this.header;
    const level = levelOfGroup(h, g);
    const [w, hh] = levelDims(h.width, h.height, level);
    const parent = g === 0 ? null : this.levels[g - 1];
    let data;
    if (h.method === 2) {
      data = new Uint8Array(w * hh * h.channels);
      if (!this.models) this.models = newModels();
      arithLevel(new RangeDecoder(payload), this.models, h, level, parent, data, w, hh);
    } else {
      data = rawLevel(payload, h, parent, w, hh, level);
    }
    return { width: w, height: hh, channels: h.channels, level, data };
  }
}

// Decodes a whole PTM (every group); throws PtmError on damage or a cut.
export function decodePtm(bytes, limits = DEFAULT_LIMITS) {
  const d = new PtmDecoder(limits);
  if (d.push(bytes) !== "done") throw new PtmError("PTM: cut short");
  return d.levels;
}
