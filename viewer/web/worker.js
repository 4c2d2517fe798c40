// Decoding off the main thread: a tile's parts are checked against their checksums, then its
// PTM levels (unpremultiplied, alpha-0 texels dilated as viewer::texture::dilate_masked
// does within the tile) and its mesh (triangles unshared, stretched ones flagged as
// viewer::refview::stretch does).
import { PtmDecoder } from "./ptm.js";
import { decodeMesh } from "./mesh.js";
import { hashMatches } from "./blake3.js";

const STRETCH_COS = 0.05;

function unpremultiply(rgba) {
  for (let i = 0; i < rgba.length; i += 4) {
    const a = rgba[i + 3];
    if (a === 0 || a === 255) continue;
    for (let c = 0; c < 3; c++) rgba[i + c] = Math.min(Math.floor((rgba[i + c] * 255 + (a >> 1)) / a), 255);
  }
}

// Alpha-0 texels take the mean colour of their filled 8-neighbours, two passes (alpha kept).
function dilate(rgba, w, h) {
  let filled = new Uint8Array(w * h);
  for (let i = 0; i < w * h; i++) filled[i] = rgba[i * 4 + 3] > 0 ? 1 : 0;
  for (let pass = 0; pass < 2; pass++) {
    const prev = rgba.slice();
    const now = filled.slice();
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        if (filled[y * w + x]) continue;
        let n = 0;
        let r = 0;
        let g = 0;
        let b = 0;
        for (let yy = Math.max(y - 1, 0); yy <= Math.min(y + 1, h - 1); yy++) {
          for (let xx = Math.max(x - 1, 0); xx <= Math.min(x + 1, w - 1); xx++) {
            const k = yy * w + xx;
            if (!filled[k]) continue;
            r += prev[k * 4];
            g += prev[k * 4 + 1];
            b += prev[k * 4 + 2];
            n++;
          }
        }
        if (n) {
          const i = (y * w + x) * 4;
          rgba[i] = Math.floor((r + (n >> 1)) / n);
          rgba[i + 1] = Math.floor((g + (n >> 1)) / n);
          rgba[i + 2] = Math.floor((b + (n >> 1)) / n);
          now[y * w + x] = 1;
        }
      }
    }
    filled = now;
  }
}

function toRgba(level) {
  const { width: w, height: h, channels: c, data } = level;
  if (c === 4) return data.slice();
  const out = new Uint8Array(w * h * 4);
  for (let i = 0; i < w * h; i++) {
    const g = data[i * c];
    out[i * 4] = c >= 3 ? data[i * c] : g;
    out[i * 4 + 1] = c >= 3 ? data[i * c + 1] : g;
    out[i * 4 + 2] = c >= 3 ? data[i * c + 2] : g;
    out[i * 4 + 3] = c === 2 ? data[i * 2 + 1] : 255;
  }
  return out;
}

function decodeLevels(parts) {
  const d = new PtmDecoder();
  for (const p of parts) d.push(p);
  return d.levels.map((l) => {
    const rgba = toRgba(l);
    unpremultiply(rgba);
    dilate(rgba, l.width, l.height);
    return { level: l.level, width: l.width, height: l.height, rgba };
  });
}

const FWD = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]];
const UP = [[0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [0, 1, 0], [0, 1, 0]];

// The point (x, y, r) of a face's mesh relative to the reference viewpoint, into p at k.
function posFromRef(x, y, r, face, n, p, k) {
  const u = (2 * x) / n - 1;
  const v = 1 - (2 * y) / n;
  const f = FWD[face];
  const up = UP[face];
  const s = r / Math.sqrt(u * u + v * v + 1);
  // right = f × up
  const rx = f[1] * up[2] - f[2] * up[1];
  const ry = f[2] * up[0] - f[0] * up[2];
  const rz = f[0] * up[1] - f[1] * up[0];
  p[k] = (f[0] + u * rx + v * up[0]) * s;
  p[k + 1] = (f[1] + u * ry + v * up[1]) * s;
  p[k + 2] = (f[2] + u * rz + v * up[2]) * s;
}

const onCentre = (c) => Math.abs(c - Math.floor(c) - 0.5) < 1e-4;
const half = (x) => (Math.abs(x) < 1e-6 ? 0 : 0.5 * Math.sign(x));

// viewer::refview::skirt: half-texel skirts along the boundary edges on pixel centres of a
// tile's mesh (none along a border shared with a kept neighbour: left, top, right, bottom),
// and corner patches joining them. Returns triangles as [x, y, r] triples.
function skirt(m, n, rect, shared) {
  const { x0, y0, x1, y1 } = rect;
  const v = m.vertices;
  const P = (i) => [v[3 * i], v[3 * i + 1]];
  const isShared = (c, lo, hi, first) => (shared[first] && c === lo + 0.5) || (shared[first + 2] && c === hi + 0.5);
  const edges = new Map();
  const idx = m.indices;
  for (let t = 0; t < idx.length; t += 3) {
    for (let k = 0; k < 3; k++) {
      const a = idx[t + k];
      const b = idx[t + ((k + 1) % 3)];
      const c = idx[t + ((k + 2) % 3)];
      const key = Math.min(a, b) * 2 ** 26 + Math.max(a, b);
      const e = edges.get(key) ?? [0, c, Math.min(a, b), Math.max(a, b)];
      e[0]++;
      e[1] = c;
      edges.set(key, e);
    }
  }
  const boundary = [];
  for (const [count, c, a, b] of edges.values()) {
    if (count !== 1) continue;
    const [pa, pb, pc] = [P(a), P(b), P(c)];
    if (![...pa, ...pb].every(onCentre)) continue;
    const alongX = pa[1] === pb[1] && isShared(pa[1], y0, y1, 1);
    const alongY = pa[0] === pb[0] && isShared(pa[0], x0, x1, 0);
    if (alongX || alongY) continue;
    const d = [pb[0] - pa[0], pb[1] - pa[1]];
    let normal = [d[1], -d[0]];
    if (normal[0] * (pc[0] - pa[0]) + normal[1] * (pc[1] - pa[1]) > 0) normal = [-normal[0], -normal[1]];
    boundary.push([a, b, [half(normal[0]), half(normal[1])]]);
  }
  boundary.sort((p, q) => p[0] - q[0] || p[1] - q[1]);
  const tris = [];
  const at = (i, o) => [Math.min(Math.max(v[3 * i] + o[0], 0), n), Math.min(Math.max(v[3 * i + 1] + o[1], 0), n), v[3 * i + 2]];
  const orig = (i) => [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
  const offsets = new Map();
  for (const [a, b, o] of boundary) {
    const a2 = at(a, o);
    const b2 = at(b, o);
    tris.push([orig(a), orig(b), b2], [orig(a), b2, a2]);
    for (const x of [a, b]) {
      if (!offsets.has(x)) offsets.set(x, []);
      offsets.get(x).push(o);
    }
  }
  for (const vtx of [...offsets.keys()].sort((p, q) => p - q)) {
    const os = offsets.get(vtx);
    for (let i = 0; i < os.length; i++) {
      for (let j = i + 1; j < os.length; j++) {
        const [o1, o2] = [os[i], os[j]];
        if (o1[0] === o2[0] && o1[1] === o2[1]) continue;
        const oc = [half(o1[0] + o2[0]), half(o1[1] + o2[1])];
        const p1 = at(vtx, o1);
        const pc = at(vtx, oc);
        const p2 = at(vtx, o2);
        tris.push([orig(vtx), p1, pc], [orig(vtx), pc, p2]);
      }
    }
  }
  return tris;
}

function meshArrays(bytes, face, faceSize, rect, shared) {
  const m = decodeMesh(bytes);
  const skirts = skirt(m, faceSize, rect, shared);
  const own = m.indices.length / 3;
  const t = own + skirts.length;
  const pos = new Float32Array(9 * t);
  const stretched = new Uint8Array(3 * t);
  skirts.forEach((tri, i) => {
    for (let k = 0; k < 3; k++) pos.set(tri[k], 9 * (own + i) + 3 * k);
  });
  const p = new Float64Array(9);
  for (let i = 0; i < own; i++) {
    for (let k = 0; k < 3; k++) {
      const vi = m.indices[3 * i + k];
      const x = m.vertices[3 * vi];
      const y = m.vertices[3 * vi + 1];
      const r = m.vertices[3 * vi + 2];
      pos[9 * i + 3 * k] = x;
      pos[9 * i + 3 * k + 1] = y;
      pos[9 * i + 3 * k + 2] = r;
      posFromRef(x, y, r, face, faceSize, p, 3 * k);
    }
    // Normal and centroid of the triangle (refview::stretch::is_stretched).
    const e1x = p[3] - p[0], e1y = p[4] - p[1], e1z = p[5] - p[2];
    const e2x = p[6] - p[0], e2y = p[7] - p[1], e2z = p[8] - p[2];
    const nx = e1y * e2z - e1z * e2y, ny = e1z * e2x - e1x * e2z, nz = e1x * e2y - e1y * e2x;
    const cx = (p[0] + p[3] + p[6]) / 3, cy = (p[1] + p[4] + p[7]) / 3, cz = (p[2] + p[5] + p[8]) / 3;
    const nl = Math.sqrt(nx * nx + ny * ny + nz * nz);
    const cl = Math.sqrt(cx * cx + cy * cy + cz * cz);
    if (nl > 0 && cl > 0 && Number.isFinite(nl) && Number.isFinite(cl)) {
      if (Math.abs(nx * cx + ny * cy + nz * cz) / (nl * cl) < STRETCH_COS) stretched.fill(1, 3 * i, 3 * i + 3);
    }
  }
  return { pos, stretched };
}

self.onmessage = (ev) => {
  const { id, kind, parts, hashes, face, faceSize, rect, shared } = ev.data;
  const t0 = performance.now();
  try {
    parts.forEach((p, i) => {
      if (!hashMatches(p, hashes[i])) throw new Error(`checksum mismatch (range ${i})`);
    });
    if (kind === "ptm") {
      const levels = decodeLevels(parts);
      self.postMessage({ id, levels, ms: performance.now() - t0 }, levels.map((l) => l.rgba.buffer));
    } else {
      const mesh = meshArrays(parts[0], face, faceSize, rect, shared);
      self.postMessage({ id, mesh, ms: performance.now() - t0 }, [mesh.pos.buffer, mesh.stretched.buffer]);
    }
  } catch (e) {
    self.postMessage({ id, error: String(e.message ?? e), ms: performance.now() - t0 });
  }
};
