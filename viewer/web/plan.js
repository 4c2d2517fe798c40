// What a frame needs: the manifest checked against stated limits before anything is sized
// by it (db::TopManifest::check_limits), and the tiles of a view that reach into the
// camera's frustum (viewer::plan::frustum_tiles, with a tile's bounding sphere from its
// corners at its depth bounds).

import * as L from "./limits.js";

export const LIMITS = {
  maxFace: L.MAX_FACE_SIZE, minTile: L.MIN_TILE_SIZE, maxTilesPerSide: L.MAX_TILES_PER_SIDE, maxSlabs: L.MAX_SLABS,
  maxTracks: L.MAX_TRACKS, maxViewpoints: L.MAX_VIEWPOINTS, maxTextBytes: L.MAX_TEXT_BYTES,
  maxGridCells: L.MAX_GRID_CELLS, maxCoord: L.MAX_COORDINATE_M,
};
export const FORMAT = 9;
const NEAR_M = 0.01;

const fail = (m) => {
  throw new Error(`manifest: ${m}`);
};
const isIndex = (v, n) => Number.isInteger(v) && v >= 0 && v < n;
const isRef = (r) => typeof r === "object" && r !== null && /^[0-9a-f]{64}$/.test(r.hash) && Number.isInteger(r.size) && r.size >= 0;
// A text's length in UTF-8 bytes, as Rust counts it.
const textBytes = (t) => new TextEncoder().encode(t).length;

// The top manifest (format 8: the viewpoints once by id, each track's stops, the junctions)
// against the limits of db::TopManifest::check_limits, before anything is sized by it; other
// formats are refused with a request to rebuild.
export function checkManifest(m) {
  if (typeof m !== "object" || m === null) fail("not an object");
  if (m.version !== FORMAT) fail(`format ${m.version}; this viewer reads format ${FORMAT} (rebuild the database with \`railview build\`)`);
  const pow2 = (v) => Number.isInteger(v) && v > 0 && (v & (v - 1)) === 0;
  if (!Number.isInteger(m.face_size) || m.face_size < 1 || m.face_size > LIMITS.maxFace) fail(`face_size ${m.face_size}`);
  // tracks::limits::check_grid: a power of two from MIN_TILE_SIZE (or the face's size rounded
  // up to one, when smaller); a tile larger than the face is the whole face (faces of 16 px
  // with tiles of 32, as the towns are built).
  if (!pow2(m.tile_size) || m.tile_size < Math.min(LIMITS.minTile, 2 ** Math.ceil(Math.log2(m.face_size)))) fail(`tile_size ${m.tile_size}`);
  const perSide = Math.ceil(m.face_size / m.tile_size);
  if (perSide > LIMITS.maxTilesPerSide) fail(`face_size / tile_size = ${perSide} tiles per side; at most ${LIMITS.maxTilesPerSide}`);
  if (!Array.isArray(m.slabs) || m.slabs.length > LIMITS.maxSlabs) fail("slabs");
  m.slabs.forEach((sl, k) => {
    // far: null for infinity.
    const far = sl?.far === null ? Infinity : sl?.far;
    if (!(typeof sl === "object" && sl !== null && Number.isFinite(sl.near) && typeof far === "number" && sl.near >= 0 && sl.near < far)) fail(`slabs[${k}] is not a depth range 0 ≤ near < far`);
  });
  const vps = m.viewpoints;
  if (!Array.isArray(vps) || vps.length < 1 || vps.length > LIMITS.maxViewpoints) fail(`viewpoints: ${vps?.length} (1 to ${LIMITS.maxViewpoints})`);
  const cells = 6 * perSide * perSide * Math.max(m.slabs.length, 1) * vps.length;
  if (cells > LIMITS.maxGridCells) fail(`viewpoints: ${cells} tile cells; at most ${LIMITS.maxGridCells}`);
  vps.forEach((v, i) => {
    if (typeof v !== "object" || v === null || v.index !== i) fail(`viewpoints[${i}].index = ${v?.index}: viewpoints are listed by id`);
    const p = v.position;
    if (!Array.isArray(p) || p.length !== 3 || !p.every((x) => Number.isFinite(x) && Math.abs(x) <= LIMITS.maxCoord)) fail(`viewpoints[${i}].position`);
    if (!isRef(v.table)) fail(`viewpoints[${i}].table`);
  });
  if (!Array.isArray(m.tracks) || m.tracks.length < 1 || m.tracks.length > LIMITS.maxTracks) fail(`tracks: ${m.tracks?.length} (1 to ${LIMITS.maxTracks})`);
  m.tracks.forEach((t, ti) => {
    if (typeof t !== "object" || t === null) fail(`tracks[${ti}]`);
    if (typeof t.name !== "string" || textBytes(t.name) > LIMITS.maxTextBytes) fail(`tracks[${ti}].name`);
    if (typeof t.track_toml !== "string" || textBytes(t.track_toml) > LIMITS.maxTextBytes) fail(`tracks[${ti}].track_toml`);
    if (!(Number.isFinite(t.length) && t.length >= 0 && t.length <= LIMITS.maxCoord)) fail(`tracks[${ti}].length = ${t.length}`);
    if (!Array.isArray(t.stops) || t.stops.length < 1 || t.stops.length > LIMITS.maxViewpoints) fail(`tracks[${ti}].stops: ${t.stops?.length} (1 to ${LIMITS.maxViewpoints})`);
    let last = 0;
    t.stops.forEach((st, k) => {
      if (typeof st !== "object" || st === null || !isIndex(st.viewpoint, vps.length)) fail(`tracks[${ti}].stops[${k}].viewpoint = ${st?.viewpoint} names no viewpoint (there are ${vps.length})`);
      if (!(Number.isFinite(st.s) && st.s >= last && st.s <= LIMITS.maxCoord)) fail(`tracks[${ti}].stops[${k}].s = ${st.s} (stops are in order along the track)`);
      last = st.s;
    });
  });
  const js = m.junctions ?? [];
  if (!Array.isArray(js) || js.length > LIMITS.maxViewpoints) fail("junctions");
  js.forEach((j, ji) => {
    if (typeof j !== "object" || j === null || !isIndex(j.viewpoint, vps.length)) fail(`junctions[${ji}].viewpoint = ${j?.viewpoint} names no viewpoint`);
    if (!Array.isArray(j.branches) || j.branches.length > LIMITS.maxViewpoints) fail(`junctions[${ji}].branches`);
    j.branches.forEach((b, bi) => {
      const ok = typeof b === "object" && b !== null && isIndex(b.track, m.tracks.length) && isIndex(b.stop, m.tracks[b.track].stops.length) &&
        typeof b.forward === "boolean" && Number.isInteger(b.segment) && b.segment >= 0;
      if (!ok) fail(`junctions[${ji}].branches[${bi}]`);
    });
  });
  return m;
}

export const tileKey = (e) => `${e.background ? "b" : e.slab}/${e.face}/${e.tx}/${e.ty}`;

const FWD = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]];
const UP = [[0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [0, 1, 0], [0, 1, 0]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

function dirOf(face, x, y, n) {
  const u = (2 * x) / n - 1;
  const v = 1 - (2 * y) / n;
  const f = FWD[face];
  const up = UP[face];
  const r = cross(f, up);
  const d = [0, 1, 2].map((k) => f[k] + u * r[k] + v * up[k]);
  const l = Math.hypot(...d);
  return d.map((c) => c / l);
}

// The entries of a view whose bounding spheres reach into the camera's frustum.
export function visibleTiles(manifest, refPos, cam, entries) {
  const n = manifest.face_size;
  const T = manifest.tile_size;
  const yaw = (cam.yaw * Math.PI) / 180;
  const pitch = (cam.pitch * Math.PI) / 180;
  const f = [Math.sin(yaw) * Math.cos(pitch), Math.sin(pitch), -Math.cos(yaw) * Math.cos(pitch)];
  const r = [Math.cos(yaw), 0, Math.sin(yaw)];
  const u = cross(r, f);
  const t = Math.tan((cam.fov * Math.PI) / 360);
  const ty = (t * cam.height) / cam.width;
  const side = (a, b, c) => {
    const l = Math.hypot(a, b, c);
    return [a / l, b / l, c / l];
  };
  const planes = [side(-1, 0, -t), side(1, 0, -t), side(0, -1, -ty), side(0, 1, -ty)];
  const rel = [0, 1, 2].map((k) => refPos[k] - cam.position[k]);
  return entries.filter((e) => {
    const x0 = e.tx * T;
    const y0 = e.ty * T;
    const x1 = Math.min(x0 + T, n);
    const y1 = Math.min(y0 + T, n);
    const near = e.background || !Number.isFinite(e.depthMin) ? 1e4 : Math.max(e.depthMin, 1e-3);
    const far = e.background || !Number.isFinite(e.depthMax) ? 1e4 : Math.max(e.depthMax, near);
    const pts = [];
    for (const [x, y] of [[x0, y0], [x1, y0], [x0, y1], [x1, y1], [(x0 + x1) / 2, (y0 + y1) / 2]]) {
      const d = dirOf(e.face, x, y, n);
      for (const depth of [near, far]) pts.push(d.map((c) => c * depth));
    }
    const c = [0, 1, 2].map((k) => pts.reduce((a, p) => a + p[k], 0) / pts.length);
    const rad = Math.max(...pts.map((p) => Math.hypot(p[0] - c[0], p[1] - c[1], p[2] - c[2]))) * (1 + 1e-6) + 1e-6;
    const cc = [0, 1, 2].map((k) => c[k] + rel[k]);
    const cv = [dot(cc, r), dot(cc, u), -dot(cc, f)];
    if (-cv[2] + rad < NEAR_M) return false;
    return planes.every((p) => dot(p, cv) >= -rad);
  });
}

// Where points of the world land on a `width × height` screen seen by `cam` (the camera of
// visibleTiles; clip_from_cam of render.js): toCam gives (right, up, forward) metres from the
// camera, toScreen the pixel of such a point (y down) in front of it.
export function projector(cam, width, height) {
  const yaw = (cam.yaw * Math.PI) / 180;
  const pitch = (cam.pitch * Math.PI) / 180;
  const f = [Math.sin(yaw) * Math.cos(pitch), Math.sin(pitch), -Math.cos(yaw) * Math.cos(pitch)];
  const r = [Math.cos(yaw), 0, Math.sin(yaw)];
  const u = cross(r, f);
  const t = Math.tan((cam.fov * Math.PI) / 360);
  const sx = 1 / t;
  const sy = width / (height * t);
  return {
    toCam: (p) => {
      const d = [0, 1, 2].map((k) => p[k] - cam.position[k]);
      return [dot(d, r), dot(d, u), dot(d, f)];
    },
    toScreen: ([x, y, z]) => [((1 + (sx * x) / z) * width) / 2, ((1 - (sy * y) / z) * height) / 2],
  };
}

// Points this close in front of the camera, or nearer, are cut off an outline.
const CLIP_M = 0.05;

// A polygon of world points as screen points, cut where it comes nearer than CLIP_M in front
// of the camera; [] when none of it lies beyond.
export function projectPolygon(pr, points) {
  const c = points.map(pr.toCam);
  const out = [];
  for (let i = 0; i < c.length; i++) {
    const a = c[i];
    const b = c[(i + 1) % c.length];
    const ina = a[2] >= CLIP_M;
    if (ina) out.push(a);
    if (ina !== b[2] >= CLIP_M) {
      const t = (CLIP_M - a[2]) / (b[2] - a[2]);
      out.push(a.map((x, k) => x + (b[k] - x) * t));
    }
  }
  return out.length >= 3 ? out.map(pr.toScreen) : [];
}

// A screen point of a world point, or null behind the camera or off the screen.
export function projectPoint(pr, p, width, height) {
  const c = pr.toCam(p);
  if (c[2] < CLIP_M) return null;
  const [x, y] = pr.toScreen(c);
  return x >= 0 && x < width && y >= 0 && y < height ? [x, y] : null;
}

// An arrow on the ground plane y = groundY, pointing from `center` along `heading` (its level
// part): a shaft from `from` metres out, then a head; metres.
export const ARROW = { from: 2.0, shaft: 0.9, head: 0.8, halfShaft: 0.16, halfHead: 0.45 };

// The arrow's outline (world points), the point where it is grabbed (inside its head) and
// where its label goes (past its tip); null for a vertical heading.
export function arrowShape(center, heading, groundY) {
  const l = Math.hypot(heading[0], heading[2]);
  if (!(l > 1e-9)) return null;
  const h = [heading[0] / l, heading[2] / l];
  const at = (a, c) => [center[0] + h[0] * a - h[1] * c, groundY, center[2] + h[1] * a + h[0] * c];
  const { from, shaft, head, halfShaft, halfHead } = ARROW;
  const neck = from + shaft;
  return {
    outline: [at(from, -halfShaft), at(neck, -halfShaft), at(neck, -halfHead), at(neck + head, 0), at(neck, halfHead), at(neck, halfShaft), at(from, halfShaft)],
    grab: at(neck + 0.3 * head, 0),
    label: at(neck + head + 0.5, 0),
  };
}
