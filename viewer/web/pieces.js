// The index in pieces (db::index, manifest format 9): manifest.json is a small root; the
// viewpoints (with their table and ACH references), each track's stops and the junctions lie
// in spatial chunks, objects like every other, reached through a quadtree of node objects.
// Each piece is gzip of JSON; a node of level l at (x, z) names its children (2x + i, 2z + j),
// i, j in 0..2, in the order (0,0), (1,0), (0,1), (1,1), nodes of level l − 1 or chunks at
// level 1. A chunk holds the viewpoints whose position lies in its cell. Every count is
// checked before it sizes anything, every piece against its hash and its place.

import { gunzipLimited } from "./table.js";
import { blake3Hex } from "./blake3.js";
import { FetchError } from "./fetch.js";
import { MAX_VIEWPOINTS, MAX_TRACKS } from "./limits.js";

// Largest piece, compressed or not (db::index::MAX_PIECE_BYTES).
export const MAX_PIECE_BYTES = 8 << 20;
// Most levels of the tree (db::index::MAX_LEVELS).
export const MAX_LEVELS = 24;
const MAX_FAULTS = 3;

export class IndexError extends Error {}

const fail = (msg) => {
  throw new IndexError(`manifest: index: ${msg}`);
};
const isCount = (n, max) => Number.isInteger(n) && n >= 0 && n <= max;

// An object's bytes, checked against its reference; a damaged or failed answer is asked for
// again (up to MAX_FAULTS times).
export async function fetchChecked(store, ref, limit) {
  if (!(typeof ref?.hash === "string" && isCount(ref.size, limit))) fail(`bad piece reference`);
  for (let attempt = 0; ; attempt++) {
    try {
      const bytes = await store.get(store.url(ref.hash), limit);
      if (bytes.length !== ref.size || blake3Hex(bytes) !== ref.hash) throw new FetchError(`index piece ${ref.hash}: damaged`, true);
      return bytes;
    } catch (e) {
      if (!e.retry || attempt + 1 >= MAX_FAULTS) throw e;
      store.stats.retries++;
      await new Promise((r) => setTimeout(r, 200 * 2 ** attempt));
    }
  }
}

// The cell of a horizontal position, as db::index::IndexRoot::cell_of computes it.
function cellOf(ix, p) {
  const side = 2 ** ix.levels;
  const c = (v, o) => Math.floor((v - o) / ix.cell);
  const x = c(p[0], ix.origin[0]);
  const z = c(p[2], ix.origin[1]);
  return x >= 0 && x < side && z >= 0 && z < side ? [x, z] : null;
}

function checkRoot(root) {
  if (typeof root !== "object" || root === null) fail("the root is not an object");
  if (!isCount(root.viewpoints, MAX_VIEWPOINTS)) fail(`viewpoints = ${root.viewpoints}`);
  if (!isCount(root.junctions, MAX_VIEWPOINTS)) fail(`junctions = ${root.junctions}`);
  if (!Array.isArray(root.tracks) || root.tracks.length > MAX_TRACKS) fail("tracks");
  root.tracks.forEach((t, ti) => {
    if (!isCount(t?.stops, MAX_VIEWPOINTS)) fail(`tracks[${ti}].stops = ${t?.stops}`);
  });
  const ix = root.index;
  if (!(typeof ix === "object" && ix !== null && isCount(ix.levels, MAX_LEVELS))) fail("levels");
  if (!(Number.isFinite(ix.cell) && ix.cell >= 0.01 && ix.cell <= 1e6)) fail(`cell = ${ix.cell}`);
  if (!(Array.isArray(ix.origin) && ix.origin.length === 2 && ix.origin.every(Number.isFinite))) fail("origin");
  if ((ix.root === null || ix.root === undefined) !== (root.viewpoints === 0)) fail("root node");
}

// Checks a chunk against its place and the root, and adds it to the assembly.
function addChunk(asm, root, at, c) {
  if (c?.x !== at.x || c?.z !== at.z) fail(`chunk says cell (${c?.x}, ${c?.z}) where the tree has (${at.x}, ${at.z})`);
  if (!Array.isArray(c.viewpoints) || c.viewpoints.length < 1) fail(`chunk (${at.x}, ${at.z}) has no viewpoint`);
  if (!Array.isArray(c.stops) || !Array.isArray(c.junctions)) fail(`chunk (${at.x}, ${at.z}): stops, junctions`);
  const here = new Set();
  for (const v of c.viewpoints) {
    if (!isCount(v?.index, root.viewpoints - 1)) fail(`chunk (${at.x}, ${at.z}): viewpoint id ${v?.index}`);
    const p = v.position;
    if (!(Array.isArray(p) && p.length === 3 && p.every(Number.isFinite))) fail(`viewpoint ${v.index}: position`);
    const cell = cellOf(root.index, p);
    if (!cell || cell[0] !== at.x || cell[1] !== at.z) fail(`viewpoint ${v.index} lies outside cell (${at.x}, ${at.z})`);
    if (here.has(v.index) || asm.viewpoints[v.index]) fail(`viewpoint ${v.index} given twice`);
    here.add(v.index);
    asm.viewpoints[v.index] = v;
  }
  for (const st of c.stops) {
    const t = asm.stops[st?.track];
    if (!t || !isCount(st.k, t.length - 1)) fail(`chunk (${at.x}, ${at.z}): stop ${st?.k} of track ${st?.track}`);
    if (!here.has(st.viewpoint)) fail(`chunk (${at.x}, ${at.z}): a stop at viewpoint ${st.viewpoint}, not one of its own`);
    if (t[st.k]) fail(`stop ${st.k} of track ${st.track} given twice`);
    t[st.k] = { viewpoint: st.viewpoint, s: st.s };
  }
  for (const j of c.junctions) {
    if (!here.has(j?.viewpoint)) fail(`chunk (${at.x}, ${at.z}): a junction at viewpoint ${j?.viewpoint}, not one of its own`);
    asm.junctions.push(j);
  }
}

// The whole top manifest (the shape of db::TopManifest, for plan.js checkManifest) from the
// root and every piece, fetched level by level through `fetch(ref)` (hash-checked bytes).
export async function readIndex(root, fetch) {
  checkRoot(root);
  const asm = {
    viewpoints: new Array(root.viewpoints).fill(null),
    stops: root.tracks.map((t) => new Array(t.stops).fill(null)),
    junctions: [],
  };
  const ix = root.index;
  let todo = ix.root ? [{ level: ix.levels, x: 0, z: 0, ref: ix.root }] : [];
  let pieces = 0;
  while (todo.length) {
    pieces += todo.length;
    if (pieces > (MAX_LEVELS + 1) * Math.max(root.viewpoints, 1)) fail("more pieces than its viewpoints allow");
    const got = await Promise.all(
      todo.map(async (p) => {
        const json = await gunzipLimited(await fetch(p.ref), MAX_PIECE_BYTES);
        try {
          return JSON.parse(new TextDecoder().decode(json));
        } catch (e) {
          fail(`piece level ${p.level} (${p.x}, ${p.z}): ${e.message}`);
        }
      }),
    );
    const next = [];
    todo.forEach((p, k) => {
      const piece = got[k];
      if (p.level === 0) return addChunk(asm, root, p, piece);
      if (piece?.level !== p.level || piece.x !== p.x || piece.z !== p.z || !Array.isArray(piece.children) || piece.children.length !== 4) {
        fail(`node at level ${p.level} (${p.x}, ${p.z}) is not that node`);
      }
      piece.children.forEach((ref, i) => {
        if (ref) next.push({ level: p.level - 1, x: 2 * p.x + (i % 2), z: 2 * p.z + Math.floor(i / 2), ref });
      });
    });
    todo = next;
  }
  const missing = asm.viewpoints.findIndex((v) => !v);
  if (missing >= 0) fail(`viewpoint ${missing} is in no chunk`);
  asm.stops.forEach((st, ti) => {
    const k = st.findIndex((x) => !x);
    if (k >= 0) fail(`stop ${k} of track ${ti} is in no chunk`);
  });
  if (asm.junctions.length !== root.junctions) fail(`the chunks hold ${asm.junctions.length} junctions, the root says ${root.junctions}`);
  asm.junctions.sort((a, b) => a.viewpoint - b.viewpoint);
  const { index, ...rest } = root;
  return {
    ...rest,
    viewpoints: asm.viewpoints,
    tracks: root.tracks.map((t, ti) => ({ name: t.name, track_toml: t.track_toml, length: t.length, stops: asm.stops[ti] })),
    junctions: asm.junctions,
    pieces,
    indexCell: index.cell,
  };
}
