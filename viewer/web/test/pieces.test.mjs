// The index in pieces (pieces.js, db::index) without a page: a town split into chunks and
// nodes the way db::index::pieces lays them out, read back whole by readIndex, and refused
// with a message naming what is wrong when a piece lies about its place, leaves a viewpoint
// or stop out, or gives one twice.
// Run: node --test viewer/web/test/
import { test } from "node:test";
import assert from "node:assert/strict";
import { gzipSync } from "node:zlib";
import { readIndex } from "../pieces.js";
import { town } from "./town.mjs";

// The pieces of a top manifest with cells of `cell` metres: a store by fake hash, and the
// root (db::index::pieces: origin at the smallest x and z, chunks per cell, a quadtree).
function split(top, cell, spoil = () => {}) {
  const xs = top.viewpoints.map((v) => v.position[0]);
  const zs = top.viewpoints.map((v) => v.position[2]);
  const origin = [Math.min(...xs), Math.min(...zs)];
  const cellOf = (p) => [Math.floor((p[0] - origin[0]) / cell), Math.floor((p[2] - origin[1]) / cell)];
  const chunks = new Map();
  const chunkAt = (p) => {
    const [x, z] = cellOf(p);
    const key = `${x},${z}`;
    if (!chunks.has(key)) chunks.set(key, { x, z, viewpoints: [], stops: [], junctions: [] });
    return chunks.get(key);
  };
  for (const v of top.viewpoints) chunkAt(v.position).viewpoints.push(v);
  top.tracks.forEach((t, track) =>
    t.stops.forEach((st, k) => chunkAt(top.viewpoints[st.viewpoint].position).stops.push({ track, k, viewpoint: st.viewpoint, s: st.s })),
  );
  for (const j of top.junctions) chunkAt(top.viewpoints[j.viewpoint].position).junctions.push(j);
  spoil(chunks);
  const store = new Map();
  let n = 0;
  const put = (piece) => {
    const bytes = gzipSync(JSON.stringify(piece));
    const hash = (n++).toString(16).padStart(64, "0");
    store.set(hash, bytes);
    return { hash, size: bytes.length };
  };
  let level = new Map([...chunks.values()].map((c) => [`${c.x},${c.z}`, { x: c.x, z: c.z, ref: put(c) }]));
  const side = Math.max(...[...chunks.values()].map((c) => Math.max(c.x, c.z) + 1));
  let levels = 0;
  while (2 ** levels < side) levels++;
  for (let l = 1; l <= levels; l++) {
    const up = new Map();
    for (const { x, z, ref } of level.values()) {
      const key = `${x >> 1},${z >> 1}`;
      if (!up.has(key)) up.set(key, { level: l, x: x >> 1, z: z >> 1, children: [null, null, null, null] });
      up.get(key).children[(x % 2) + 2 * (z % 2)] = ref;
    }
    level = new Map([...up.values()].map((node) => [`${node.x},${node.z}`, { x: node.x, z: node.z, ref: put(node) }]));
  }
  const { viewpoints, tracks, junctions, ...rest } = top;
  const root = {
    ...rest,
    viewpoints: viewpoints.length,
    tracks: tracks.map((t) => ({ name: t.name, track_toml: t.track_toml, length: t.length, stops: t.stops.length })),
    junctions: junctions.length,
    index: { origin, cell, levels, root: [...level.values()][0].ref },
  };
  return { root, fetch: async (ref) => store.get(ref.hash), pieces: store.size };
}

test("a town comes back whole from its pieces, with one chunk or a tree of them", async () => {
  const want = town();
  for (const cell of [1000, 7, 3]) {
    const { root, fetch, pieces } = split(town(), cell);
    const got = await readIndex(root, fetch);
    assert.equal(got.pieces, pieces, `cells of ${cell} m`);
    assert.deepEqual(got.viewpoints, want.viewpoints);
    assert.deepEqual(got.tracks, want.tracks);
    assert.deepEqual(got.junctions, want.junctions);
    assert.equal(got.version, want.version);
    assert.equal(got.face_size, want.face_size);
  }
});

test("a piece that lies about its place or its graph is refused, naming what", async () => {
  const first = (chunks) => [...chunks.values()].find((c) => c.stops.length > 0);
  const cases = [
    ["outside cell", (c) => (first(c).viewpoints[0].position = [50, 1.7, 50])],
    ["given twice", (c) => first(c).viewpoints.push(first(c).viewpoints[0])],
    ["is in no chunk", (c) => c.delete([...c.keys()][0])],
    ["not one of its own", (c) => (first(c).stops[0].viewpoint = 7)],
    ["stop 99", (c) => (first(c).stops[0].k = 99)],
    ["junctions", (c) => [...c.values()].forEach((ch) => (ch.junctions = []))],
  ];
  for (const [what, spoil] of cases) {
    const { root, fetch } = split(town(), 7, spoil);
    await assert.rejects(readIndex(root, fetch), (e) => e.message.includes(what), what);
  }
  const { root, fetch } = split(town(), 7);
  for (const [what, change] of [
    ["viewpoints", (r) => (r.viewpoints = 1e9)],
    ["levels", (r) => (r.index.levels = 40)],
    ["cell", (r) => (r.index.cell = 0)],
    ["root node", (r) => (r.index.root = null)],
  ]) {
    const r = structuredClone(root);
    change(r);
    await assert.rejects(readIndex(r, fetch), (e) => e.message.includes(what), what);
  }
  // A node that names another place.
  const wrong = structuredClone(root);
  wrong.index.levels += 1;
  await assert.rejects(readIndex(wrong, fetch), /is not that node|says cell/);
});
