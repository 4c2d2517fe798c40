// Tracks as the manifest carries them (tracks::TrackSet::to_toml): the points, the optional
// centripetal Catmull-Rom smoothing, arc length, and the blend pair of tracks::segment.

const SMOOTH_SUBDIVISIONS = 32;
const MAX_POINTS = 1 << 16;

const sub = (a, b) => a.map((x, i) => x - b[i]);
const add = (a, b) => a.map((x, i) => x + b[i]);
const mul = (a, s) => a.map((x) => x * s);
const dist = (a, b) => Math.hypot(...sub(a, b));

// The points and smoothing of a track's TOML (the form `to_toml` writes).
export function parseTrackToml(text) {
  const m = /^points\s*=\s*(\[.*\])\s*$/m.exec(text);
  if (!m) throw new Error("track: no points in the manifest's track");
  const points = JSON.parse(m[1]);
  if (!Array.isArray(points) || points.length < 2 || points.length > MAX_POINTS ||
      !points.every((p) => Array.isArray(p) && p.length === 3 && p.every(Number.isFinite))) {
    throw new Error("track: points must be 2 to 65536 finite [x, y, z]");
  }
  const smooth = /^smooth\s*=\s*["']catmull-rom["']/m.test(text);
  return { points, smooth };
}

function catmullRom(p) {
  const n = p.length;
  const get = (i) => (i < 0 ? sub(mul(p[0], 2), p[1]) : i >= n ? sub(mul(p[n - 1], 2), p[n - 2]) : p[i]);
  const out = [p[0]];
  for (let i = 0; i < n - 1; i++) {
    const [p0, p1, p2, p3] = [get(i - 1), get(i), get(i + 1), get(i + 2)];
    const knot = (a, b, t) => t + Math.max(Math.sqrt(dist(a, b)), 1e-12);
    const t0 = 0;
    const t1 = knot(p0, p1, t0);
    const t2 = knot(p1, p2, t1);
    const t3 = knot(p2, p3, t2);
    for (let k = 1; k <= SMOOTH_SUBDIVISIONS; k++) {
      const t = t1 + ((t2 - t1) * k) / SMOOTH_SUBDIVISIONS;
      const a1 = add(mul(p0, (t1 - t) / (t1 - t0)), mul(p1, (t - t0) / (t1 - t0)));
      const a2 = add(mul(p1, (t2 - t) / (t2 - t1)), mul(p2, (t - t1) / (t2 - t1)));
      const a3 = add(mul(p2, (t3 - t) / (t3 - t2)), mul(p3, (t - t2) / (t3 - t2)));
      const b1 = add(mul(a1, (t2 - t) / (t2 - t0)), mul(a2, (t - t0) / (t2 - t0)));
      const b2 = add(mul(a2, (t3 - t) / (t3 - t1)), mul(a3, (t - t1) / (t3 - t1)));
      const c = add(mul(b1, (t2 - t) / (t2 - t1)), mul(b2, (t - t1) / (t2 - t1)));
      out.push(k === SMOOTH_SUBDIVISIONS ? p2 : c);
    }
  }
  return out;
}

// tracks::segment::locate
export function locate(arcs, s) {
  const n = arcs.length;
  if (n < 2) return null;
  if (Number.isNaN(s)) s = arcs[0];
  let lo = 0;
  while (lo < n && arcs[lo] <= s) lo++;
  const index = Math.min(Math.max(lo - 1, 0), n - 2);
  const a0 = arcs[index];
  const a1 = arcs[index + 1];
  const t = a1 > a0 ? Math.min(Math.max((s - a0) / (a1 - a0), 0), 1) : 0;
  return { index, t };
}

export const smoothWeight = (t) => {
  t = Number.isNaN(t) ? 0 : Math.min(Math.max(t, 0), 1);
  return t * t * (3 - 2 * t);
};

// tracks::segment::blend_pair: [a, b, w_b].
export function blendPair(arcs, s) {
  if (arcs.length === 0) return null;
  if (arcs.length === 1) return [0, 0, 0];
  const p = locate(arcs, s);
  return p.t >= 1 ? [p.index + 1, p.index, 0] : [p.index, p.index + 1, smoothWeight(p.t)];
}

export class Track {
  constructor(toml) {
    const { points, smooth } = parseTrackToml(toml);
    this.curve = smooth ? catmullRom(points) : points;
    this.arc = [0];
    for (let i = 1; i < this.curve.length; i++) this.arc.push(this.arc[i - 1] + dist(this.curve[i - 1], this.curve[i]));
  }
  get length() {
    return this.arc[this.arc.length - 1];
  }
  positionAt(s) {
    const p = locate(this.arc, s);
    if (!p) return this.curve[0];
    const a = this.curve[p.index];
    const b = this.curve[p.index + 1];
    return add(a, mul(sub(b, a), p.t));
  }
  // Yaw (degrees) along the track at s (viewer::headless::yaw_along).
  yawAlong(s) {
    const h = Math.max(this.length * 1e-4, 1e-9);
    const d = sub(this.positionAt(s + h), this.positionAt(s - h));
    const l = Math.hypot(...d);
    if (l === 0 || (d[0] === 0 && d[2] === 0)) return 0;
    return (Math.atan2(d[0] / l, -d[2] / l) * 180) / Math.PI;
  }
}
