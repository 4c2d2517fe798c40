// Viewpoint tables (db::table, format 5): what a client needs to know about one viewpoint's
// tiles — positions, flags, depth bounds, PTM shapes, and where each payload lies (a byte
// range of this viewpoint's pack or of an earlier one) with its 32-bit checksum. The layout
// is the Rust module's documentation. Decoding never trusts a count: each is checked
// against the bytes left before anything is sized by it.

import { MAX_TABLE_BYTES } from "./limits.js";

export const TABLE_VERSION = 5;
const MAX_OTHER_PACKS = 1 << 16;
const KEPT = 1;
const HAS_PTM = 2;
const HAS_MESH = 4;
const USUAL_SHAPE = 8;

export class TableError extends Error {}

// gunzip with a limit on the output (DecompressionStream: Chromium and Node both have it).
export async function gunzipLimited(bytes, limit) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
  const reader = stream.getReader();
  const parts = [];
  let total = 0;
  for (;;) {
    let r;
    try {
      r = await reader.read();
    } catch (e) {
      throw new TableError(`table: gzip: ${e.message}`);
    }
    if (r.done) break;
    total += r.value.length;
    if (total > limit) {
      await reader.cancel();
      throw new TableError(`table: gzip body larger than ${limit} bytes`);
    }
    parts.push(r.value);
  }
  const out = new Uint8Array(total);
  let at = 0;
  for (const p of parts) {
    out.set(p, at);
    at += p.length;
  }
  return out;
}

const hex = (s) => Array.from(s, (b) => b.toString(16).padStart(2, "0")).join("");

function halfToFloat(h) {
  const s = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 0x1f;
  const f = h & 0x3ff;
  if (e === 0) return s * f * 2 ** -24;
  if (e === 31) return f ? NaN : s * Infinity;
  return s * (1 + f / 1024) * 2 ** (e - 15);
}

class Reader {
  constructor(b) {
    this.b = b;
    this.at = 0;
    this.dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
  }
  invalid(what, at, message) {
    return new TableError(`table: ${what} at byte ${at}: ${message}`);
  }
  take(n, what) {
    if (this.at + n > this.b.length) throw new TableError(`table: ends inside ${what} (byte ${this.at})`);
    const s = this.b.subarray(this.at, this.at + n);
    this.at += n;
    return s;
  }
  u8(what) {
    return this.take(1, what)[0];
  }
  f32(what) {
    this.take(4, what);
    return this.dv.getFloat32(this.at - 4, true);
  }
  f16(what) {
    this.take(2, what);
    return halfToFloat(this.dv.getUint16(this.at - 2, true));
  }
  // A varint as a Number; values beyond 2^53 are refused (no table holds one).
  varint(what) {
    const start = this.at;
    let v = 0;
    for (let shift = 0; shift < 64; shift += 7) {
      const byte = this.u8(what);
      v += (byte & 0x7f) * 2 ** shift;
      if (!(byte & 0x80)) {
        if (v > Number.MAX_SAFE_INTEGER) throw this.invalid(what, start, `${v} is too large`);
        return v;
      }
    }
    throw this.invalid(what, start, "varint longer than 64 bits");
  }
  u32(what) {
    const start = this.at;
    const v = this.varint(what);
    if (v > 0xffffffff) throw this.invalid(what, start, `${v} exceeds 32 bits`);
    return v;
  }
  count(what, minBytes) {
    const start = this.at;
    const n = this.varint(what);
    const left = this.b.length - this.at;
    if (n > Math.floor(left / Math.max(minBytes, 1))) {
      throw this.invalid(what, start, `${n} records cannot fit in the ${left} bytes left`);
    }
    return n;
  }
  hex(n, what) {
    return hex(this.take(n, what));
  }
}

function levelDims(w, h, level) {
  for (let i = 0; i < level; i++) {
    w = Math.ceil(w / 2);
    h = Math.ceil(h / 2);
  }
  return [w, h];
}

// One list (background tiles or tiles). `st` carries the grid side, the packs and the
// cursor in this viewpoint's pack.
function readTiles(r, st) {
  const depthCoding = r.u8("depth coding");
  if (depthCoding > 1) throw r.invalid("depth coding", r.at - 1, `${depthCoding} (0 or 1)`);
  const posCoding = r.u8("position coding");
  if (posCoding > 1) throw r.invalid("position coding", r.at - 1, `${posCoding} (0 or 1)`);
  const count = r.count("tile count", 7);
  const tiles = [];
  let next = 0;
  for (let i = 0; i < count; i++) {
    let face, tx, ty, slab;
    if (posCoding === 1) {
      const at = r.at;
      face = r.u8("tile face");
      if (face > 5) throw r.invalid("tile face", at, `face ${face} (0–5)`);
      tx = r.u32("tile x");
      ty = r.u32("tile y");
      slab = r.u32("slab");
    } else {
      const at = r.at;
      const index = next + r.varint("tile position");
      next = index + 1;
      const n = st.n;
      if (n === 0 || index > Number.MAX_SAFE_INTEGER) throw r.invalid("tile position", at, `${index} outside the grid`);
      tx = index % n;
      ty = Math.floor(index / n) % n;
      const fs = Math.floor(index / n / n);
      face = fs % 6;
      slab = Math.floor(fs / 6);
      if (slab > 0xffffffff) throw r.invalid("tile position", at, `${index} outside the grid`);
    }
    tiles.push({ face, tx, ty, slab, kept: false, opaque: 0, depthMin: 0, depthMax: 0, ptm: null, mesh: null });
  }
  const flags = [];
  for (const t of tiles) {
    const at = r.at;
    const f = r.u8("tile flags");
    if (f & ~(KEPT | HAS_PTM | HAS_MESH | USUAL_SHAPE) || (f & (HAS_MESH | USUAL_SHAPE) && !(f & HAS_PTM))) {
      throw r.invalid("tile flags", at, `0x${f.toString(16)}`);
    }
    if (f & HAS_PTM && !st.pack && st.others.length === 0) {
      throw r.invalid("tile flags", at, "a tile with a PTM in a table that names no pack");
    }
    t.kept = (f & KEPT) !== 0;
    flags.push(f);
  }
  for (const t of tiles) t.opaque = r.u32("opaque_pixels");
  for (const t of tiles) {
    if (depthCoding === 1) {
      t.depthMin = r.f16("depth_min");
      t.depthMax = r.f16("depth_max");
    } else {
      t.depthMin = r.f32("depth_min");
      t.depthMax = r.f32("depth_max");
    }
  }
  tiles.forEach((t, i) => {
    const f = flags[i];
    if (!(f & HAS_PTM)) return;
    const width = r.u32("PTM width");
    const height = r.u32("PTM height");
    const channels = r.u8("PTM channels");
    const at = r.at;
    const ranges = r.count("PTM range count", 2);
    const levels = [];
    for (let k = 0; k < ranges; k++) {
      let level, w, h;
      if (f & USUAL_SHAPE) {
        level = ranges - 1 - k;
        if (level >= 32) throw r.invalid("PTM range count", at, `${ranges} levels`);
        [w, h] = levelDims(width, height, level);
      } else {
        level = r.u32("PTM level");
        w = r.u32("PTM level width");
        h = r.u32("PTM level height");
      }
      levels.push({ level, width: w, height: h, offset: 0, len: 0, hash: "" });
    }
    t.ptm = { object: null, width, height, channels, levels };
  });
  tiles.forEach((t, i) => {
    if (flags[i] & HAS_MESH) t.mesh = { object: null, offset: 0, len: r.varint("mesh length"), hash: "" };
    if (t.ptm) for (const l of t.ptm.levels) l.len = r.varint("PTM range length");
  });
  const sources = [];
  for (const t of tiles) {
    const k = (t.mesh ? 1 : 0) + (t.ptm ? 1 : 0);
    for (let j = 0; j < k; j++) {
      const at = r.at;
      const code = r.varint("payload source");
      if (code >= 2 + st.others.length || (code < 2 && !st.pack)) {
        throw r.invalid("payload source", at, `${code}, but the table names ${st.others.length} earlier packs`);
      }
      sources.push(code);
    }
  }
  let si = 0;
  for (const t of tiles) {
    if (t.mesh) {
      const [obj, off] = place(r, st, sources[si++], t.mesh.len, "mesh");
      t.mesh.object = obj;
      t.mesh.offset = off;
    }
    if (t.ptm) {
      const len = t.ptm.levels.reduce((a, l) => a + l.len, 0);
      const [obj, off] = place(r, st, sources[si++], len, "PTM");
      let o = off;
      for (const l of t.ptm.levels) {
        l.offset = o;
        o += l.len;
      }
      t.ptm.object = obj;
    }
  }
  for (const t of tiles) {
    if (t.mesh) t.mesh.hash = r.hex(st.hashBytes, "mesh checksum");
    if (t.ptm) for (const l of t.ptm.levels) l.hash = r.hex(st.hashBytes, "PTM range checksum");
  }
  return tiles;
}

function place(r, st, code, len, what) {
  if (code === 0) {
    const offset = st.cursor;
    st.cursor += len;
    return [st.pack, offset];
  }
  const at = r.at;
  const offset = r.varint("payload offset");
  const end = offset + len;
  if (code === 1) {
    if (end > st.cursor) {
      throw r.invalid("payload offset", at, `${what} at ${offset}+${len}, beyond the ${st.cursor} bytes of the pack before it`);
    }
    return [st.pack, offset];
  }
  const o = st.others[code - 2];
  if (end > o.size) throw r.invalid("payload offset", at, `${what} at ${offset}+${len}, outside an earlier pack of ${o.size} bytes`);
  return [o, offset];
}

// The table's body: the header checked, gunzipped within the limit.
async function body(bytes) {
  if (bytes.length < 6 || String.fromCharCode(...bytes.subarray(0, 4)) !== "RVTB") {
    throw new TableError("table: not a viewpoint table (no RVTB header)");
  }
  if (bytes[4] !== TABLE_VERSION) {
    throw new TableError(`table: format ${bytes[4]}, this viewer reads format ${TABLE_VERSION}: rebuild the database with \`railview build\``);
  }
  if (bytes[5] === 0) {
    if (bytes.length - 6 > MAX_TABLE_BYTES) throw new TableError("table: body too large");
    return bytes.subarray(6);
  }
  if (bytes[5] === 1) return gunzipLimited(bytes.subarray(6), MAX_TABLE_BYTES);
  throw new TableError(`table: unknown body coding ${bytes[5]}`);
}

// Decodes viewpoint `want`'s table: { viewpoint, pack, others, background, tiles }.
export async function decodeTable(bytes, want) {
  const r = new Reader(await body(bytes));
  const viewpoint = r.varint("viewpoint");
  if (viewpoint !== want) throw new TableError(`table is for viewpoint ${viewpoint}, expected ${want}`);
  let pack = null;
  const pf = r.u8("pack flag");
  if (pf === 1) pack = { hash: r.hex(32, "pack hash"), size: r.varint("pack size") };
  else if (pf !== 0) throw r.invalid("pack flag", r.at - 1, `${pf} (0 or 1)`);
  const count = r.count("earlier pack count", 33);
  if (count > MAX_OTHER_PACKS) throw r.invalid("earlier pack count", r.at, `${count} (at most ${MAX_OTHER_PACKS})`);
  const others = [];
  for (let i = 0; i < count; i++) others.push({ hash: r.hex(32, "earlier pack hash"), size: r.varint("earlier pack size") });
  const hashBytes = r.u8("checksum bytes");
  if (hashBytes !== 4 && hashBytes !== 8) throw r.invalid("checksum bytes", r.at - 1, `${hashBytes} (4 or 8)`);
  const n = r.varint("grid side");
  const st = { n, hashBytes, pack, others, cursor: 0 };
  const at = r.at;
  const background = readTiles(r, st);
  for (const t of background) {
    if (!(t.ptm && t.kept && !t.mesh && t.slab === 0)) {
      throw r.invalid("background tiles", at, "a background tile is a kept PTM without mesh in slab 0");
    }
  }
  const tiles = readTiles(r, st);
  const packSize = pack ? pack.size : 0;
  if (st.cursor !== packSize) {
    throw new TableError(`table: the tiles' lengths add up to ${st.cursor} bytes, the pack has ${packSize}`);
  }
  if (r.at !== r.b.length) throw new TableError(`table: ${r.b.length - r.at} bytes after the end`);
  return { viewpoint, pack, others, gridSide: n, background, tiles };
}
