// The browser viewer's network code without a page: the top manifest of format 9 (its pieces
// assembled, pieces.test.mjs) against its
// limits (plan.js checkManifest, db::TopManifest::check_limits), the network and its
// junctions (track.js Network, tracks::network), the walker (track.js Walker, the rules of
// streamer/src/client/route.rs and its tests) and the arrows' geometry (plan.js).
// Run: node --test viewer/web/test/
import { test } from "node:test";
import assert from "node:assert/strict";
import { checkManifest, projector, projectPolygon, projectPoint, arrowShape, LIMITS } from "../plan.js";
import { Network, Walker, waysOut, nearestToView, branchWeights, sameBranch, viewOf } from "../track.js";
import { town, HASH, X, NEG_X, Z, NEG_Z } from "./town.mjs";

const net = () => new Network(checkManifest(town()));
const heading = (n, b) => n.branchHeading(b);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const near = (a, b, eps = 1e-9) => Math.abs(a - b) <= eps;

test("format 9 is read and every other format refused with the rebuild message", () => {
  assert.ok(checkManifest(town()));
  for (const version of [7, 8, 10, undefined]) {
    const m = { ...town(), version };
    assert.throws(() => checkManifest(m), /reads format 9 \(rebuild the database with `railview build`\)/);
  }
});

test("the manifest's limits are the Rust ones", () => {
  assert.equal(LIMITS.maxViewpoints, 100000);
  assert.equal(LIMITS.maxFace, 8192);
  assert.equal(LIMITS.maxTracks, 1024);
  assert.equal(LIMITS.maxSlabs, 64);
  const bad = [
    ["face_size", (m) => (m.face_size = 16384)],
    ["tile_size", (m) => (m.tile_size = 3)],
    ["slabs", (m) => (m.slabs = Array(65).fill({ near: 0, far: 1 }))],
    ["slabs\\[0\\]", (m) => (m.slabs[0] = { near: 5, far: 1 })],
    ["tracks", (m) => (m.tracks = Array(1025).fill(m.tracks[0]))],
    ["tracks", (m) => (m.tracks = [])],
    ["viewpoints", (m) => (m.viewpoints = Array.from({ length: 100001 }, (_, i) => ({ index: i, position: [0, 0, 0], table: { hash: HASH, size: 1 } })))],
    ["viewpoints\\[3\\]\\.index", (m) => (m.viewpoints[3].index = 4)],
    ["viewpoints\\[2\\]\\.position", (m) => (m.viewpoints[2].position = [0, 2e7, 0])],
    ["viewpoints\\[2\\]\\.position", (m) => (m.viewpoints[2].position = [0, NaN, 0])],
    ["viewpoints\\[1\\]\\.table", (m) => (m.viewpoints[1].table = { hash: "xyz", size: 1 })],
    ["tracks\\[1\\]\\.stops\\[2\\]\\.viewpoint = 21 names no viewpoint", (m) => (m.tracks[1].stops[2].viewpoint = 21)],
    ["tracks\\[1\\]\\.stops\\[2\\]\\.viewpoint", (m) => (m.tracks[1].stops[2].viewpoint = -1)],
    ["tracks\\[0\\]\\.stops\\[3\\]\\.s", (m) => (m.tracks[0].stops[3].s = 1)],
    ["tracks\\[0\\]\\.stops\\[0\\]\\.s", (m) => (m.tracks[0].stops[0].s = -1)],
    ["tracks\\[0\\]\\.stops", (m) => (m.tracks[0].stops = [])],
    ["tracks\\[2\\]\\.length", (m) => (m.tracks[2].length = 1e8)],
    ["junctions\\[1\\]\\.viewpoint", (m) => (m.junctions[1].viewpoint = 21)],
    ["junctions\\[0\\]\\.branches\\[1\\]", (m) => (m.junctions[0].branches[1].track = 3)],
  ];
  for (const [what, spoil] of bad) {
    const m = town();
    spoil(m);
    assert.throws(() => checkManifest(m), new RegExp(`manifest: ${what}`), what);
  }
  // As tracks::limits::check_grid: a tile larger than the face (faces of 16 px, tiles of
  // 32, as `--scene town-K --face-size 16` builds) is the whole face; smaller faces allow
  // tiles down to their own size.
  for (const [face, tile] of [[16, 32], [16, 16], [3, 4], [2, 2]]) {
    const m = town();
    m.face_size = face;
    m.tile_size = tile;
    assert.doesNotThrow(() => checkManifest(m), `face ${face}, tile ${tile}`);
  }
  const small = town();
  small.face_size = 3;
  small.tile_size = 2;
  assert.throws(() => checkManifest(small), /manifest: tile_size 2/);
});

test("the junctions are those the stops make, else the manifest is refused", () => {
  const n = net();
  assert.equal(n.junctions.length, 2);
  assert.equal(n.segments.length, 8 + 8 + 4);
  const m = town();
  m.junctions[0].branches.pop();
  assert.throws(() => new Network(checkManifest(m)), /junctions\[0\] is not the junction its tracks' stops make there/);
  const none = { ...town(), junctions: [] };
  assert.throws(() => new Network(checkManifest(none)), /lists 0 but its tracks' stops make 2/);
  // A single track, format 8 with no junctions, is a network too.
  const one = town();
  one.tracks = [one.tracks[0]];
  one.junctions = [];
  one.viewpoints = one.viewpoints.slice(0, 9);
  assert.equal(new Network(checkManifest(one)).junctions.length, 0);
  // Stops beyond their track's curve are refused.
  const long = town();
  long.tracks[2].stops[4].s = 9;
  assert.throws(() => new Network(checkManifest(long)), /track 2 stop 4: arc length 9/);
});

test("branches head along their segments, away from the junction", () => {
  const n = net();
  const [ewBack, ewOn, nsBack, nsOn] = n.junctions[0].branches;
  assert.deepEqual(heading(n, ewBack).map(Math.round), [-1, 0, 0]);
  assert.deepEqual(heading(n, ewOn).map(Math.round), [1, 0, 0]);
  assert.deepEqual(heading(n, nsBack).map(Math.round), [0, 0, -1]);
  assert.deepEqual(heading(n, nsOn).map(Math.round), [0, 0, 1]);
  const [, spur] = n.junctions[1].branches;
  assert.deepEqual(heading(n, spur).map(Math.round), [0, 0, -1]);
});

test("a junction is one view from every track through it, drawn alone there", () => {
  const n = net();
  const [a, b, w] = n.blendPair(0, 10);
  assert.equal(w, 0);
  assert.equal(a, 4);
  const [c, , w2] = n.blendPair(1, 10);
  assert.equal(w2, 0);
  assert.equal(c, 4);
  assert.notEqual(b, a);
  // Between samples: the two stops' viewpoints by id.
  const [p, q, wq] = n.blendPair(1, 11.25);
  assert.deepEqual([p, q], [4, 13]);
  assert.ok(near(wq, 0.5));
});

test("at a crossing the walker takes the branch nearest the view", () => {
  const n = net();
  const w = new Walker(n, 0, 5, true);
  // Looking south (−z) as it reaches the crossing at s = 10: it turns onto `ns`, backwards.
  const turns = w.advance(7, NEG_Z);
  assert.equal(turns.length, 1);
  assert.deepEqual([turns[0].viewpoint, turns[0].fromTrack, turns[0].to.track], [4, 0, 1]);
  assert.equal(w.track, 1);
  assert.equal(w.forward, false);
  assert.ok(near(w.s, 8), `${w.s}`);
  // Looking along the track: straight on, no turn.
  const v = new Walker(n, 0, 5, true);
  assert.deepEqual(v.advance(7, X), []);
  assert.deepEqual([v.track, v.s], [0, 12]);
});

test("a chosen branch wins over the view and is used once", () => {
  const n = net();
  const w = new Walker(n, 0, 5, true);
  const options = w.options();
  assert.equal(options.length, 3);
  const north = options.find((b) => dot(heading(n, b), Z) > 0.9);
  w.chosen = north;
  assert.ok(sameBranch(w.nextBranch(X), north));
  w.advance(6, X);
  assert.equal(w.track, 1);
  assert.equal(w.forward, true);
  assert.equal(w.chosen, null);
  // A choice that is no way out of the next junction is passed over.
  const u = new Walker(n, 0, 5, true);
  u.chosen = n.junctions[1].branches[1];
  assert.ok(sameBranch(u.nextBranch(X), n.junctions[0].branches[1]));
});

test("standing on a junction after a turn does not turn again", () => {
  const n = net();
  const w = new Walker(n, 0, 5, true);
  w.advance(5, Z);
  assert.equal(w.track, 1);
  assert.equal(w.passed, 4);
  const at = w.s;
  // Looking back west now: the walker walks on along `ns`, it does not turn onto `ew`.
  w.advance(1, NEG_X);
  assert.equal(w.track, 1);
  assert.ok(near(w.s - at, 1));
});

test("the ways out leave out the way back, and the walk stops at a track's end", () => {
  const n = net();
  const w = new Walker(n, 0, 12, false);
  const nj = w.nextJunction();
  assert.deepEqual([nj.stop, nj.dist, nj.arrival], [4, 2, 4]);
  assert.equal(waysOut(nj.junction, nj.arrival).length, 3);
  assert.equal(waysOut(nj.junction, null).length, 4);
  // Along `spur` to its end: no junction, no way on.
  const s = new Walker(n, 2, 3, true);
  assert.equal(s.nextJunction(), null);
  s.advance(100, NEG_Z);
  assert.deepEqual([s.track, s.s], [2, 8]);
  // Back along `spur` onto `ew`: the only way out at its start is `ew` westwards.
  const b = new Walker(n, 2, 3, false);
  b.advance(4, Z);
  assert.equal(b.track, 0);
  assert.equal(b.forward, false);
  assert.ok(near(b.s, 19));
});

test("branch weights sum to one and follow the view; a chosen way outweighs it", () => {
  const n = net();
  const ways = new Walker(n, 0, 5, true).options();
  const weights = branchWeights(n, ways, Z, X, null);
  assert.ok(near(weights.reduce((a, x) => a + x[1], 0), 1, 1e-12));
  const best = weights.reduce((a, x) => (x[1] > a[1] ? x : a));
  assert.ok(dot(heading(n, best[0]), Z) > 0.9);
  const east = ways.find((b) => dot(heading(n, b), X) > 0.9);
  const chosen = branchWeights(n, ways, Z, X, east);
  const top = chosen.reduce((a, x) => (x[1] > a[1] ? x : a));
  assert.ok(sameBranch(top[0], east));
  assert.ok(sameBranch(nearestToView(n, ways, NEG_Z), ways.find((b) => dot(heading(n, b), NEG_Z) > 0.9)));
});

test("the ways out run left to right and the choice goes round them", () => {
  const n = net();
  // Along +x towards the crossing (yaw 90): −z is on the left, +z on the right.
  const w = new Walker(n, 0, 7, true);
  const a = w.ahead();
  assert.ok(near(a.dist, 3));
  assert.deepEqual(a.ways.map((b) => heading(n, b).map((x) => Math.round(x) + 0)), [[0, 0, -1], [1, 0, 0], [0, 0, 1]]);
  const view = viewOf(90);
  assert.ok(sameBranch(w.nextBranch(view), a.ways[1]));
  w.choose(1, view);
  assert.ok(sameBranch(w.chosen, a.ways[2]));
  w.choose(1, view);
  assert.ok(sameBranch(w.chosen, a.ways[0]));
  w.choose(-1, view);
  assert.ok(sameBranch(w.chosen, a.ways[2]));
});

test("arrows lie on the ground along their branch and are cut at the camera", () => {
  const cam = { position: [0, 1.7, 0], yaw: 0, pitch: 0, fov: 90, width: 480, height: 270 };
  const pr = projector(cam, 480, 270);
  // Straight ahead at the horizon: the middle of the screen.
  const mid = projectPoint(pr, [0, 1.7, -100], 480, 270);
  assert.ok(near(mid[0], 240, 1e-6) && near(mid[1], 135, 1e-6));
  // 45° to the right at fov 90: the right edge; behind: nowhere.
  assert.ok(near(pr.toScreen(pr.toCam([1, 1.7, -1]))[0], 480, 1e-6));
  assert.equal(projectPoint(pr, [0, 1.7, 5], 480, 270), null);
  const ahead = arrowShape([0, 1.7, -6], NEG_Z, 0.2);
  assert.ok(ahead.outline.every((p) => p[1] === 0.2 && near(p[0], 0, 0.5) && p[2] < -6));
  const poly = projectPolygon(pr, ahead.outline);
  assert.equal(poly.length, ahead.outline.length);
  const grab = projectPoint(pr, ahead.grab, 480, 270);
  assert.ok(near(grab[0], 240, 1e-6) && grab[1] > 135);
  // An arrow pointing back past the camera is cut where it passes it; one wholly behind, gone.
  const back = arrowShape([0, 1.7, -3], Z, 0.2);
  const cut = projectPolygon(pr, back.outline);
  assert.ok(cut.length >= 3 && cut.every((p) => Number.isFinite(p[0]) && Number.isFinite(p[1])));
  assert.deepEqual(projectPolygon(pr, arrowShape([0, 1.7, 3], Z, 0.2).outline), []);
  assert.equal(arrowShape([0, 0, 0], [0, 1, 0], 0), null);
});
