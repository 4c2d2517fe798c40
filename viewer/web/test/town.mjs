// The town of client::route's tests as a top manifest of format 9 (shared by the tests).
export const HASH = "ab".repeat(32);
export const X = [1, 0, 0];
export const NEG_X = [-1, 0, 0];
export const Z = [0, 0, 1];
export const NEG_Z = [0, 0, -1];

// The town of client::route's tests: `ew` along x crossing `ns` along z at the origin, `spur`
// leaving `ew`'s east end towards −z; stops every 2.5 m (2 m on `spur`), viewpoints numbered
// track by track, a junction at its first appearance (tracks::network).
export function town() {
  const toml = (name, points) => `[[track]]\nname = "${name}"\npoints = ${JSON.stringify(points)}\nspacing = 2.5\n`;
  const viewpoints = [];
  const vp = (p) => {
    viewpoints.push({ index: viewpoints.length, position: p, table: { hash: HASH, size: 10 } });
    return viewpoints.length - 1;
  };
  const ew = [];
  for (let k = 0; k <= 8; k++) ew.push({ viewpoint: vp([-10 + 2.5 * k, 1.7, 0]), s: 2.5 * k });
  const ns = [];
  for (let k = 0; k <= 8; k++) ns.push({ viewpoint: k === 4 ? 4 : vp([0, 1.7, -10 + 2.5 * k]), s: 2.5 * k });
  const spur = [];
  for (let k = 0; k <= 4; k++) spur.push({ viewpoint: k === 0 ? 8 : vp([10, 1.7, -2 * k]), s: 2 * k });
  return {
    version: 9, scene: "town", face_size: 64, tile_size: 32, slabs: [{ near: 0, far: 20 }, { near: 20, far: null }],
    cull_alpha: null, cull_variant: null, viewpoints,
    tracks: [
      { name: "ew", track_toml: toml("ew", [[-10, 1.7, 0], [0, 1.7, 0], [10, 1.7, 0]]), length: 20, stops: ew },
      { name: "ns", track_toml: toml("ns", [[0, 1.7, -10], [0, 1.7, 10]]), length: 20, stops: ns },
      { name: "spur", track_toml: toml("spur", [[10, 1.7, 0], [10, 1.7, -8]]), length: 8, stops: spur },
    ],
    // Segments: ew 0–7, ns 8–15, spur 16–19.
    junctions: [
      { viewpoint: 4, branches: [
        { track: 0, stop: 4, forward: false, segment: 3 }, { track: 0, stop: 4, forward: true, segment: 4 },
        { track: 1, stop: 4, forward: false, segment: 11 }, { track: 1, stop: 4, forward: true, segment: 12 }] },
      { viewpoint: 8, branches: [{ track: 0, stop: 8, forward: false, segment: 7 }, { track: 2, stop: 0, forward: true, segment: 16 }] },
    ],
  };
}

