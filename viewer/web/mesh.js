// Compact tile meshes (codec::mesh, format 4): lattice occupancy, connectivity grown edge
// by edge with each third vertex ranked among the Delaunay candidates, inverse planar depth
// predicted across triangles, pixel quads; and the plain layout (lattice unit 0). The byte
// layout and every rule are the Rust module's documentation; the connectivity search
// follows `mesh::connect` step by step so that the same candidates are tied.

import { Decoder as RangeDecoder, Models, SIGNED_BITS, UNSIGNED_BITS } from "./entropy.js";

export const MESH_VERSION = 4;
const MAX_SIDE = 2 ** 20;
const MAX_CELLS = 2 ** 24;
const MAX_BOX_SIDE = 2 ** 15;
const MAX_WORK = 2 ** 28;
const MAX_QUADS = MAX_CELLS / 4;

export class MeshError extends Error {}

const fail = (m) => {
  throw new MeshError(m);
};

class Header {
  constructor(b) {
    this.b = b;
    this.at = 2;
  }
  varint(what) {
    let v = 0;
    for (let shift = 0; shift < 64; shift += 7) {
      if (this.at >= this.b.length) fail(`mesh ends inside the header (${what})`);
      const byte = this.b[this.at++];
      if (shift < 56) v += (byte & 0x7f) * 2 ** shift;
      else if (byte & 0x7f) v = Infinity;
      if (!(byte & 0x80)) return v;
    }
    return fail(`mesh ${what}: varint too long`);
  }
}

const unzigzag = (v) => (v % 2 === 0 ? v / 2 : -(v + 1) / 2);

// Sign of a·b − c·d, exactly (BigInt only where doubles could round).
function cmpProducts(a, b, c, d) {
  const x = a * b;
  const y = c * d;
  if (Math.abs(x) < 2 ** 52 && Math.abs(y) < 2 ** 52) return Math.sign(x - y);
  const r = BigInt(a) * BigInt(b) - BigInt(c) * BigInt(d);
  return r > 0n ? 1 : r < 0n ? -1 : 0;
}

const cross = (o, a, b) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
const dot = (o, a, b) => (a[0] - o[0]) * (b[0] - o[0]) + (a[1] - o[1]) * (b[1] - o[1]);

function sideOf(pts, u, v, p) {
  const c = cross(pts[u], pts[v], pts[p]);
  return c === 0 ? null : c > 0;
}

// A side as one number (vertex indices are below 2^24).
const sideKey = (a, b, left) => (a * 16777216 + b) * 2 + (left ? 1 : 0);

function occupancyCtx(cells, w, i) {
  const x = i % w;
  const y = (i - x) / w;
  let c = 0;
  if (x > 0 && cells[i - 1]) c |= 1;
  if (x > 0 && y > 0 && cells[i - w - 1]) c |= 2;
  if (y > 0 && cells[i - w]) c |= 4;
  if (y > 0 && x + 1 < w && cells[i - w + 1]) c |= 8;
  return c;
}

// Connectivity models: seed[3], rank and far (unsigned), exists[6] (bits).
const SEED = 0;
const RANK = 3 * UNSIGNED_BITS;
const FAR = 4 * UNSIGNED_BITS;
const EXISTS = 5 * UNSIGNED_BITS;

class Growth {
  constructor(pts, count) {
    this.pts = pts;
    const height = pts.length ? pts[pts.length - 1][1] + 1 : 0;
    this.rows = new Uint32Array(height + 1);
    for (const p of pts) this.rows[p[1] + 1]++;
    for (let y = 0; y < height; y++) this.rows[y + 1] += this.rows[y];
    this.width = pts.reduce((m, p) => Math.max(m, p[0] + 1), 0);
    this.done = new Set();
    this.queue = [];
    this.head = 0;
    this.out = [];
    this.m = new Models(EXISTS + 6);
    this.cands = [];
    this.count = count;
  }

  add(t) {
    const [a, b, c] = t;
    const pts = this.pts;
    const s1 = sideOf(pts, a, b, c);
    const s2 = sideOf(pts, b, c, a);
    const s3 = sideOf(pts, a, c, b);
    if (s1 === null || s2 === null || s3 === null) fail(`triangle ${t} is degenerate`);
    const sides = [[a, b, s1], [b, c, s2], [a, c, s3]];
    if (sides.some((s) => this.done.has(sideKey(...s)))) fail(`triangle ${t} overlaps another`);
    for (const s of sides) {
      this.done.add(sideKey(...s));
      this.queue.push([s[0], s[1], !s[2]]);
    }
    this.out.push(t);
  }

  lattice() {
    return [0, 0, this.width - 1, this.rows.length - 2];
  }

  scan(s, bx) {
    const [u, v, left] = s;
    const pts = this.pts;
    this.cands = [];
    const lastRow = this.rows.length - 2;
    const ya = Math.max(bx[1], 0);
    const yb = Math.min(bx[3], lastRow);
    for (let y = ya; y <= yb; y++) {
      const first = this.rows[y];
      const end = this.rows[y + 1];
      for (let p = first; p < end; p++) {
        const x = pts[p][0];
        if (x < bx[0] || x > bx[2]) continue;
        if (p !== u && p !== v && sideOf(pts, u, v, p) === left) this.cands.push(p);
      }
    }
  }

  firstBox(s) {
    const a = this.pts[s[0]];
    const b = this.pts[s[1]];
    const reach = Math.max(Math.floor(Math.max(Math.abs(b[0] - a[0]), Math.abs(b[1] - a[1])) / 2), 1);
    return [Math.min(a[0], b[0]) - reach, Math.min(a[1], b[1]) - reach,
      Math.max(a[0], b[0]) + reach, Math.max(a[1], b[1]) + reach];
  }

  nextSide() {
    while (this.head < this.queue.length) {
      const s = this.queue[this.head++];
      if (this.done.has(sideKey(...s))) continue;
      this.scan(s, this.firstBox(s));
      return [s, this.cands.length === 0];
    }
    this.queue = [];
    this.head = 0;
    return null;
  }

  delaunayTies(s) {
    const lattice = this.lattice();
    let bx = this.firstBox(s);
    const pts = this.pts;
    const a = pts[s[0]];
    const b = pts[s[1]];
    const key = (p) => [dot(pts[p], a, b), Math.abs(cross(pts[p], a, b))];
    // k before l: k.0 · l.1 < l.0 · k.1
    const before = (k, l) => cmpProducts(k[0], l[1], l[0], k[1]) < 0;
    for (;;) {
      let best = -1;
      let bk = null;
      for (const p of this.cands) {
        const k = key(p);
        if (best < 0 || before(k, bk)) {
          best = p;
          bk = k;
        }
      }
      if (best < 0) {
        if (contains(bx, lattice)) return;
        bx = grow(bx, lattice);
        this.scan(s, bx);
        continue;
      }
      const reach = clampBox(capBox(a, b, pts[best]), lattice);
      if (contains(bx, reach)) {
        this.cands = this.cands.filter((p) => {
          const k = key(p);
          return cmpProducts(k[0], bk[1], bk[0], k[1]) === 0;
        });
        return;
      }
      bx = union(bx, reach);
      this.scan(s, bx);
    }
  }
}

const contains = (o, i) => o[0] <= i[0] && o[1] <= i[1] && o[2] >= i[2] && o[3] >= i[3];
const clampBox = (b, t) => [Math.max(b[0], t[0]), Math.max(b[1], t[1]), Math.min(b[2], t[2]), Math.min(b[3], t[3])];
const union = (a, b) => [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[2], b[2]), Math.max(a[3], b[3])];
const tdiv = (a, b) => Math.trunc(a / b);

function grow(b, lattice) {
  const dx = tdiv(b[2] - b[0], 2) + 1;
  const dy = tdiv(b[3] - b[1], 2) + 1;
  return clampBox([b[0] - dx, b[1] - dy, b[2] + dx, b[3] + dy], lattice);
}

function capBox(a, b, c) {
  const bx = b[0] - a[0];
  const by = b[1] - a[1];
  const cx = c[0] - a[0];
  const cy = c[1] - a[1];
  const d = 2 * (bx * cy - by * cx);
  const b2 = bx * bx + by * by;
  const c2 = cx * cx + cy * cy;
  const ux = (cy * b2 - by * c2) / d;
  const uy = (bx * c2 - cx * b2) / d;
  const r = Math.sqrt(ux * ux + uy * uy);
  const side = Math.sign(bx * cy - by * cx);
  let loX = Math.min(a[0], b[0]);
  let loY = Math.min(a[1], b[1]);
  let hiX = Math.max(a[0], b[0]);
  let hiY = Math.max(a[1], b[1]);
  for (const [px, py] of [[ux + r, uy], [ux - r, uy], [ux, uy + r], [ux, uy - r]]) {
    if ((bx * py - by * px) * side > -(Math.sqrt(b2) + 1)) {
      const x = a[0] + px;
      const y = a[1] + py;
      loX = Math.min(loX, x);
      loY = Math.min(loY, y);
      hiX = Math.max(hiX, x);
      hiY = Math.max(hiY, y);
    }
  }
  return [Math.floor(loX) - 1, Math.floor(loY) - 1, Math.ceil(hiX) + 1, Math.ceil(hiY) + 1];
}

function decodeConnectivity(d, pts, count) {
  const n = pts.length;
  const g = new Growth(pts, count);
  const m = g.m;
  let prevA = 0;
  while (g.out.length < count) {
    const a = prevA + d.unsigned(m, SEED);
    const b = a + 1 + d.unsigned(m, SEED + UNSIGNED_BITS);
    const c = b + 1 + d.unsigned(m, SEED + 2 * UNSIGNED_BITS);
    if (c >= n) fail(`seed triangle (${a}, ${b}, ${c}) names a vertex beyond the ${n} vertices`);
    prevA = a;
    g.add([a, b, c]);
    while (g.out.length < count) {
      const next = g.nextSide();
      if (!next) break;
      const [s, empty] = next;
      const pa = pts[s[0]];
      const pb = pts[s[1]];
      const dx = Math.abs(pb[0] - pa[0]);
      const dy = Math.abs(pb[1] - pa[1]);
      const shape = dx === 0 || dy === 0 ? 0 : dx === dy ? 1 : 2;
      if (!d.bit(m, EXISTS + shape + 3 * (empty ? 1 : 0))) {
        g.done.add(sideKey(...s));
        continue;
      }
      g.delaunayTies(s);
      const k = d.unsigned(m, RANK);
      let w;
      if (k < g.cands.length) w = g.cands[k];
      else if (k === g.cands.length) {
        w = d.unsigned(m, FAR);
        if (w >= n || sideOf(pts, s[0], s[1], w) !== s[2]) {
          fail(`third vertex ${w} of edge (${s[0]}, ${s[1]}) is not on its side`);
        }
      } else fail(`third vertex ${k} of ${g.cands.length} tied ones`);
      g.add([s[0], s[1], w].sort((p, q) => p - q));
    }
  }
  return g.out;
}

function divRound(num, den) {
  let n = num;
  let dd = den;
  if (dd < 0n) {
    n = -n;
    dd = -dd;
  }
  const x = 2n * n + dd;
  const y = 2n * dd;
  let q = x / y;
  if (x % y !== 0n && x < 0n) q -= 1n;
  return q;
}

// divRound for numbers whose products stay exact (|num| < 2^50, |den| < 2^31).
function divRoundNumber(num, den) {
  let n = num;
  let d = den;
  if (d < 0) {
    n = -n;
    d = -d;
  }
  const x = 2 * n + d;
  const y = 2 * d;
  let q = Math.floor(x / y);
  if (q * y > x) q--;
  else if ((q + 1) * y <= x) q++;
  return q;
}

function adjacency(n, tris) {
  const incident = Array.from({ length: n }, () => []);
  const across = new Map();
  tris.forEach((t, ti) => {
    for (const p of t) incident[p].push(ti);
    for (const [a, b] of [[t[0], t[1]], [t[1], t[2]], [t[0], t[2]]]) {
      const key = Math.min(a, b) * 2 ** 26 + Math.max(a, b);
      const e = across.get(key);
      if (e) e.push(ti);
      else across.set(key, [ti]);
    }
  });
  return { incident, across };
}

// The prediction of vertex v's quantised depth and which predictor made it (0 plane,
// 1 edge, 2 neighbour, 3 previous).
function predict(v, pts, q, tris, adj) {
  let edge = null;
  let neighbour = -1;
  for (const ti of adj.incident[v]) {
    const others = tris[ti].filter((p) => p !== v);
    if (others.length < 2) continue;
    const [a, b] = others;
    const both = a < v && b < v;
    if (neighbour < 0) {
      const f = [a, b].find((p) => p < v);
      if (f !== undefined) neighbour = f;
    }
    if (!both) continue;
    if (edge === null) edge = [a, b];
    const pair = adj.across.get(Math.min(a, b) * 2 ** 26 + Math.max(a, b));
    if (!pair) continue;
    for (const tj of pair.slice(0, 2)) {
      if (tj === ti) continue;
      const c = tris[tj].find((p) => p !== a && p !== b);
      if (c === undefined || c >= v) continue;
      const [pa, pb, pc, pv] = [pts[a], pts[b], pts[c], pts[v]];
      // Lattice coordinates are below 2^15, so each D is exact in a double.
      const D = (o, s, t) => (s[0] - o[0]) * (t[1] - o[1]) - (s[1] - o[1]) * (t[0] - o[0]);
      const den = D(pa, pb, pc);
      if (den === 0) continue;
      const d1 = D(pa, pv, pc);
      const d2 = D(pa, pb, pv);
      const [qa, qb, qc] = [q[a], q[b], q[c]];
      let pred;
      if (Math.abs(qb - qa) * Math.abs(d1) + Math.abs(qc - qa) * Math.abs(d2) < 2 ** 50) {
        pred = qa + divRoundNumber((qb - qa) * d1 + (qc - qa) * d2, den);
      } else {
        const num = BigInt(qb - qa) * BigInt(d1) + BigInt(qc - qa) * BigInt(d2);
        pred = Number(BigInt(qa) + divRound(num, BigInt(den)));
      }
      return [Math.min(Math.max(pred, 1), 2147483647), 0];
    }
  }
  if (edge) return [Math.floor((q[edge[0]] + q[edge[1]] + 1) / 2), 1];
  if (neighbour >= 0) return [q[neighbour], 2];
  return [v > 0 ? q[v - 1] : 0, 3];
}

const f32 = Math.fround;

function planarNorm(x, y, n) {
  const u = (2 * x) / n - 1;
  const v = 1 - (2 * y) / n;
  return Math.sqrt(1 + u * u + v * v);
}

function decodePlain(b) {
  const hd = new Header(b);
  const faceSize = hd.varint("face size");
  const n = hd.varint("vertex count");
  const t = hd.varint("triangle count");
  if (faceSize === 0 || faceSize > MAX_SIDE) fail(`mesh face size ${faceSize}`);
  if (n > MAX_CELLS || t > 2 * MAX_CELLS) fail(`plain mesh of ${n} vertices and ${t} triangles`);
  const body = b.subarray(hd.at);
  if (body.length !== 12 * (n + t)) {
    fail(`${body.length} bytes after the header of a plain mesh of ${n} vertices and ${t} triangles`);
  }
  const dv = new DataView(body.buffer, body.byteOffset, body.byteLength);
  const vertices = new Float32Array(3 * n);
  for (let k = 0; k < 3 * n; k++) vertices[k] = dv.getFloat32(4 * k, true);
  for (let k = 0; k < n; k++) {
    const [x, y, r] = [vertices[3 * k], vertices[3 * k + 1], vertices[3 * k + 2]];
    if (!(Number.isFinite(x) && Number.isFinite(y) && Number.isFinite(r) && r > 0)) {
      fail(`plain mesh vertex ${k}: needs finite x, y and depth > 0`);
    }
  }
  const indices = new Uint32Array(3 * t);
  for (let k = 0; k < 3 * t; k++) {
    indices[k] = dv.getUint32(4 * (3 * n + k), true);
    if (indices[k] >= n) fail(`plain mesh index ${indices[k]} at ${k} of ${n} vertices`);
  }
  return { vertices, indices };
}

function readQuadBox(hd) {
  const count = hd.varint("pixel quad count");
  if (count === 0) return { count, x0: 0, y0: 0, w: 0, h: 0 };
  const qb = {
    count,
    x0: unzigzag(hd.varint("pixel quad x0")),
    y0: unzigzag(hd.varint("pixel quad y0")),
    w: hd.varint("pixel quad box width"),
    h: hd.varint("pixel quad box height"),
  };
  const lim = 2 ** 40;
  if (Math.abs(qb.x0) > lim || Math.abs(qb.y0) > lim) fail("pixel quad box corner out of range");
  if (qb.w === 0 || qb.h === 0 || qb.w > MAX_BOX_SIDE || qb.h > MAX_BOX_SIDE) {
    fail(`a pixel quad box of ${qb.w} × ${qb.h} pixels`);
  }
  if (count > MAX_QUADS || count > qb.w * qb.h) fail(`${count} pixel quads in a box of ${qb.w} × ${qb.h}`);
  return qb;
}

const quantiseR = (r, step) => Math.min(Math.max(Math.round(1 / (r * step)), 1), 2147483647);

function decodeQuads(d, qb, lastR, step) {
  if (qb.count === 0) return [];
  const { w, h, count } = qb;
  const mask = new Uint8Array(w * h);
  const cells = [];
  const ctx = new Models(16);
  for (let i = 0; i < mask.length && cells.length < count; i++) {
    if (d.bit(ctx, occupancyCtx(mask, w, i))) {
      mask[i] = 1;
      cells.push(i);
    }
  }
  if (cells.length < count) fail(`pixel quad mask holds ${cells.length} of ${count} quads`);
  const q = new Float64Array(w * h);
  const models = new Models(4 * SIGNED_BITS);
  let prev = null;
  const out = [];
  cells.forEach((i, k) => {
    let pred;
    let how;
    if (i >= w && mask[i - w]) [pred, how] = [q[i - w], 0];
    else if (i % w !== 0 && mask[i - 1]) [pred, how] = [q[i - 1], 1];
    else if (prev !== null) [pred, how] = [prev, 2];
    else [pred, how] = [lastR === null ? 0 : quantiseR(lastR, step), 3];
    const v = pred + d.signed(models, how * SIGNED_BITS);
    if (v < 1 || v > 2147483647) fail(`pixel quad ${k}: quantised depth ${v} out of range`);
    q[i] = v;
    prev = v;
    out.push([qb.x0 + (i % w), qb.y0 + Math.floor(i / w), f32(1 / (v * step))]);
  });
  return out;
}

// Decodes a mesh into { vertices: Float32Array of x, y, r; indices: Uint32Array }.
// Throws MeshError on damage; every count is checked before allocating.
export function decodeMesh(b) {
  if (b.length < 2) fail(`${b.length} bytes, shorter than any mesh header`);
  if (b[0] !== MESH_VERSION) fail(`mesh format ${b[0]} (this viewer reads format 4; rebuild the database)`);
  if (b[1] === 0) return decodePlain(b);
  if (b[1] !== 1 && b[1] !== 8) fail(`lattice unit ${b[1]} (0, 1 or 8)`);
  const unit = b[1];
  const hd = new Header(b);
  const faceSize = hd.varint("face size");
  const x0 = unzigzag(hd.varint("x0"));
  const y0 = unzigzag(hd.varint("y0"));
  const w = hd.varint("box width");
  const h = hd.varint("box height");
  const n = hd.varint("vertex count");
  const tris = hd.varint("triangle count");
  const qb = readQuadBox(hd);
  if (faceSize === 0 || faceSize > MAX_SIDE) fail(`mesh face size ${faceSize}`);
  if (Math.abs(x0) > 2 ** 40 || Math.abs(y0) > 2 ** 40) fail(`box corner (${x0}, ${y0}) out of range`);
  if (w > MAX_BOX_SIDE || h > MAX_BOX_SIDE || w * h > MAX_CELLS) fail(`a lattice box of ${w} × ${h} cells`);
  if (n > w * h) fail(`${n} vertices in ${w * h} lattice cells`);
  if (tris > 2 * n) fail(`${tris} triangles over ${n} vertices`);
  if (n * tris > MAX_WORK) fail(`${n} vertices × ${tris} triangles exceed ${MAX_WORK}`);
  if (hd.at + 2 > b.length) fail("mesh ends inside the header (depth step)");
  const step = (256 + b[hd.at + 1]) * 2 ** (b[hd.at] - 136);
  if (!(step >= 1e-9 && step <= 1e9)) fail(`depth step ${step}`);
  const d = new RangeDecoder(b.subarray(hd.at + 2));
  const cells = w * h;
  const occupied = new Uint8Array(cells);
  const pts = [];
  const ctx = new Models(16);
  for (let i = 0; i < cells && pts.length < n; i++) {
    if (d.bit(ctx, occupancyCtx(occupied, w, i))) {
      occupied[i] = 1;
      pts.push([i % w, Math.floor(i / w)]);
    }
  }
  if (pts.length < n) fail(`occupancy holds ${pts.length} of ${n} vertices`);
  const grown = decodeConnectivity(d, pts, tris);
  const adj = adjacency(n, grown);
  const q = new Float64Array(n);
  const models = new Models(4 * SIGNED_BITS);
  const nq = qb.count;
  const vertices = new Float32Array(3 * (n + 4 * nq));
  for (let k = 0; k < n; k++) {
    const [pred, how] = predict(k, pts, q, grown, adj);
    const v = pred + d.signed(models, how * SIGNED_BITS);
    if (v < 1 || v > 2147483647) fail(`vertex ${k}: quantised depth ${v} out of range`);
    q[k] = v;
    const x = f32((pts[k][0] + x0) / unit + 0.5);
    const y = f32((pts[k][1] + y0) / unit + 0.5);
    vertices[3 * k] = x;
    vertices[3 * k + 1] = y;
    vertices[3 * k + 2] = planarNorm(x, y, faceSize) / (v * step);
  }
  const lastR = n > 0 ? vertices[3 * n - 1] : null;
  const quads = decodeQuads(d, qb, lastR, step);
  const indices = new Uint32Array(3 * grown.length + 6 * nq);
  grown.forEach((t, i) => indices.set(t, 3 * i));
  quads.forEach(([qx, qy, r], i) => {
    const base = n + 4 * i;
    vertices.set([qx, qy, r, qx + 1, qy, r, qx + 1, qy + 1, r, qx, qy + 1, r], 3 * base);
    indices.set([base, base + 1, base + 2, base, base + 2, base + 3], 3 * grown.length + 6 * i);
  });
  return { vertices, indices };
}
