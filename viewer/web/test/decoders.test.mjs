// The browser viewer's decoders against the vectors the Rust codec writes
// (streamer/db/tests/web_vectors.rs): the same bytes out, or an error where Rust fails —
// whole, cut short and damaged. Run: node --test viewer/web/test/
import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { decodePtm, PtmDecoder } from "../ptm.js";
import { decodeMesh } from "../mesh.js";
import { decodeTable } from "../table.js";
import { blake3Hex } from "../blake3.js";

const vectors = JSON.parse(readFileSync(new URL("./vectors.json", import.meta.url)));
const bytes = (hex) => Uint8Array.from(hex.match(/../g) ?? [], (h) => parseInt(h, 16));
const hexOf = (b) => Array.from(b, (x) => x.toString(16).padStart(2, "0")).join("");
const le = (typed) => hexOf(new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength));

test("the vectors cover damage and both table codings", () => {
  for (const kind of ["ptm", "mesh", "table"]) {
    assert.ok(vectors[kind].length > 0);
    assert.ok(vectors[kind].some((v) => v.runs.some((r) => "error" in r)), kind);
  }
  assert.deepEqual(new Set(vectors.table.map((t) => t.coding)), new Set([0, 1]));
});

for (const v of vectors.ptm) {
  test(`PTM ${v.what}`, () => {
    for (const r of v.runs) {
      const input = bytes(r.input);
      if ("error" in r) {
        assert.throws(() => decodePtm(input), Error, `${r.name}: Rust fails with ${r.error}`);
        continue;
      }
      const levels = decodePtm(input);
      assert.equal(hexOf(levels[levels.length - 1].data), r.ok, r.name);
    }
  });
  test(`PTM ${v.what}: fed byte by byte, every prefix gives the levels so far`, () => {
    const whole = bytes(v.runs[0].input);
    const d = new PtmDecoder();
    let seen = 0;
    for (let i = 0; i < whole.length; i++) {
      const s = d.push(whole.subarray(i, i + 1));
      assert.ok(d.levels.length >= seen);
      seen = d.levels.length;
      assert.equal(s, i + 1 === whole.length ? "done" : "more");
    }
    assert.equal(hexOf(d.finest().data), v.runs[0].ok);
  });
}

for (const v of vectors.mesh) {
  test(`mesh ${v.what}`, () => {
    for (const r of v.runs) {
      const input = bytes(r.input);
      if ("error" in r) {
        assert.throws(() => decodeMesh(input), Error, `${r.name}: Rust fails with ${r.error}`);
        continue;
      }
      const m = decodeMesh(input);
      assert.equal(le(m.vertices), r.vertices, `${r.name}: vertices`);
      assert.equal(le(m.indices), r.indices, `${r.name}: indices`);
    }
  });
}

const shape = (t) => ({
  background: t.background.map((b) => ({ face: b.face, tx: b.tx, ty: b.ty, ptm: ptmShape(b.ptm) })),
  tiles: t.tiles.map((e) => ({
    face: e.face, tx: e.tx, ty: e.ty, slab: e.slab, kept: e.kept, opaque: e.opaque,
    depthMin: e.depthMin, depthMax: e.depthMax,
    ptm: e.ptm && ptmShape(e.ptm),
    mesh: e.mesh && { offset: e.mesh.offset, len: e.mesh.len, hash: e.mesh.hash },
  })),
});
const ptmShape = (p) => ({
  width: p.width, height: p.height, channels: p.channels,
  levels: p.levels.map((l) => ({ level: l.level, width: l.width, height: l.height, offset: l.offset, len: l.len, hash: l.hash })),
});

for (const v of vectors.table) {
  test(`table ${v.what}`, async () => {
    for (const r of v.runs) {
      const input = bytes(r.input);
      if ("error" in r) {
        await assert.rejects(decodeTable(input, 3), Error, `${r.name}: Rust fails with ${r.error}`);
        continue;
      }
      const t = await decodeTable(input, 3);
      assert.deepEqual(shape(t), r.ok, r.name);
    }
  });
}

test("a table for another viewpoint is refused", async () => {
  await assert.rejects(decodeTable(bytes(vectors.table[0].runs[0].input), 4), /viewpoint/);
});

test("BLAKE3 and the 32-bit range checksums", () => {
  const data = Uint8Array.from({ length: 5000 }, (_, i) => i % 251);
  for (const h of vectors.blake3) {
    const b = data.subarray(0, h.len);
    assert.equal(blake3Hex(b), h.hash, `${h.len} bytes`);
    assert.equal(blake3Hex(b, 4), h.range32, `${h.len} bytes, 32 bits`);
  }
});
