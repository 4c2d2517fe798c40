// The page preloads exactly the modules main.js imports, directly or not, so that they are
// fetched at once and not one import level after another. The workers' modules are not
// among them: a worker loads its own.
import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";

const dir = new URL("../", import.meta.url);
const read = (name) => readFileSync(new URL(name, dir), "utf8");

function imported(entry) {
  const seen = new Set();
  const todo = [entry];
  while (todo.length) {
    const name = todo.pop();
    if (seen.has(name)) continue;
    seen.add(name);
    for (const m of read(name).matchAll(/^import[^;]*?from\s+"\.\/([\w.-]+\.js)";/gms)) todo.push(m[1]);
  }
  return seen;
}

test("index.html preloads every module of the page and no other", () => {
  const html = read("index.html");
  const preloaded = new Set([...html.matchAll(/<link rel="modulepreload" href="([^"]+)">/g)].map((m) => m[1]));
  const wanted = imported("main.js");
  assert.ok(wanted.size > 5, `main.js's imports were not found: ${[...wanted]}`);
  assert.deepEqual([...preloaded].sort(), [...wanted].sort());
  assert.ok(!preloaded.has("worker.js"));
});
