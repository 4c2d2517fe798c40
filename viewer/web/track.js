// Tracks as the manifest carries them (tracks::TrackSet::to_toml): the points, the optional
// centripetal Catmull-Rom smoothing, arc length, and the blend pair of tracks::segment; the
// network of tracks that meet at junctions (tracks::network) and the walker that follows it
// (streamer::client::route: the branch the user chose, else the one nearest the view).

import { MAX_TRACK_POINTS } from "./limits.js";

const SMOOTH_SUBDIVISIONS = 32;

const sub = (a, b) => a.map((x, i) => x - b[i]);
const add = (a, b) => a.map((x, i) => x + b[i]);
const mul = (a, s) => a.map((x) => x * s);
const dist = (a, b) => Math.hypot(...sub(a, b));

// The points and smoothing of a track's TOML (the form `to_toml` writes).
export function parseTrackToml(text) {
  const m = /^points\s*=\s*(\[.*\])\s*$/m.exec(text);
  if (!m) throw new Error("track: no points in the manifest's track");
  const points = JSON.parse(m[1]);
  if (!Array.isArray(points) || points.length < 2 || points.length > MAX_TRACK_POINTS ||
      !points.every((p) => Array.isArray(p) && p.length === 3 && p.every(Number.isFinite))) {
    throw new Error(`track: points must be 2 to ${MAX_TRACK_POINTS} finite [x, y, z]`);
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
  // Unit tangent at s, the direction of travel (tracks::Track::tangent_at).
  tangentAt(s) {
    const h = Math.max(this.length * 1e-4, 1e-9);
    const d = sub(this.positionAt(s + h), this.positionAt(s - h));
    const l = Math.hypot(...d);
    return l === 0 ? [0, 0, 0] : d.map((x) => x / l);
  }
  // Yaw (degrees) along the track at s (viewer::headless::yaw_along).
  yawAlong(s) {
    const d = this.tangentAt(s);
    if (d[0] === 0 && d[2] === 0) return 0;
    return (Math.atan2(d[0], -d[2]) * 180) / Math.PI;
  }
}

// Networks (tracks::network): tracks that share viewpoints. A junction is one viewpoint every
// track through it stops at; its branches are the segments that leave it, each with its
// direction (forward: towards larger arc lengths of its track). Segments are numbered track
// by track: track t's segment k joins its stops k and k + 1.

const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const unit = (d) => {
  const l = Math.hypot(...d);
  return l > 0 && Number.isFinite(l) ? d.map((x) => x / l) : [0, 0, 0];
};

// The level view direction of a yaw in degrees (0 looks along −z, 90 along +x).
export const viewOf = (yawDeg) => {
  const y = (yawDeg * Math.PI) / 180;
  return [Math.sin(y), 0, -Math.cos(y)];
};

export const sameBranch = (a, b) =>
  !!a && !!b && a.track === b.track && a.stop === b.stop && a.forward === b.forward && a.segment === b.segment;

// The junctions the stops make (tracks::network::Network::from_stops): every viewpoint that
// more than one stop names, in id order; per visit (track by track, stop by stop) the segment
// back and the segment on, where there is one.
function junctionsOf(stops, firstSegment) {
  const visits = new Map();
  stops.forEach((st, ti) =>
    st.forEach((x, k) => {
      const v = visits.get(x.viewpoint);
      if (v) v.push([ti, k]);
      else visits.set(x.viewpoint, [[ti, k]]);
    }));
  const out = [];
  for (const [viewpoint, vs] of [...visits].sort((a, b) => a[0] - b[0])) {
    if (vs.length < 2) continue;
    const branches = [];
    for (const [ti, k] of vs) {
      if (k > 0) branches.push({ track: ti, stop: k, forward: false, segment: firstSegment[ti] + k - 1 });
      if (k + 1 < stops[ti].length) branches.push({ track: ti, stop: k, forward: true, segment: firstSegment[ti] + k });
    }
    out.push({ viewpoint, branches });
  }
  return out;
}

const sameJunction = (a, b) =>
  a.viewpoint === b.viewpoint && a.branches.length === b.branches.length &&
  a.branches.every((x, k) => sameBranch(x, b.branches[k]));

// The network of a manifest that passed plan.js checkManifest (db::TopManifest::network): each
// track's curve from its TOML, the viewpoints' positions by id, the stops (each within its
// track), the segments, and the junctions the stops make, which must be the ones listed.
export class Network {
  constructor(manifest) {
    this.viewpoints = manifest.viewpoints.map((v) => v.position);
    this.names = manifest.tracks.map((t) => t.name);
    this.tracks = manifest.tracks.map((t) => new Track(t.track_toml));
    this.stops = manifest.tracks.map((t) => t.stops);
    this.arcs = this.stops.map((st) => st.map((x) => x.s));
    this.firstSegment = [];
    this.segments = [];
    this.stops.forEach((st, ti) => {
      const len = this.tracks[ti].length;
      st.forEach((x, k) => {
        if (!(x.s >= 0 && x.s <= len * (1 + 1e-9) + 1e-6)) {
          throw new Error(`manifest: track ${ti} stop ${k}: arc length ${x.s} is not within 0..${len}`);
        }
      });
      this.firstSegment.push(this.segments.length);
      for (let k = 0; k + 1 < st.length; k++) {
        this.segments.push({ track: ti, index: k, from: st[k].viewpoint, to: st[k + 1].viewpoint, s0: st[k].s, s1: st[k + 1].s });
      }
    });
    this.junctions = junctionsOf(this.stops, this.firstSegment);
    const listed = manifest.junctions ?? [];
    if (listed.length !== this.junctions.length) {
      throw new Error(`manifest: junctions: the manifest lists ${listed.length} but its tracks' stops make ${this.junctions.length}`);
    }
    const odd = listed.findIndex((j, i) => !sameJunction(j, this.junctions[i]));
    if (odd >= 0) throw new Error(`manifest: junctions[${odd}] is not the junction its tracks' stops make there`);
    this.junctionAt = new Map(this.junctions.map((j) => [j.viewpoint, j]));
    // Per track, the positions among its stops of the junctions on it.
    this.junctionStops = this.stops.map((st) => st.flatMap((x, k) => (this.junctionAt.has(x.viewpoint) ? [k] : [])));
  }

  trackIndex(name) {
    return this.names.indexOf(name);
  }

  // Global id of segment k of track t, or null.
  segmentId(t, k) {
    return k >= 0 && k + 1 < this.stops[t].length ? this.firstSegment[t] + k : null;
  }

  // The two viewpoints (ids) around arc length s of track t and the blend weight of the
  // second (tracks::network::Network::blend_pair).
  blendPair(t, s) {
    const [a, b, w] = blendPair(this.arcs[t], s);
    return [this.stops[t][a].viewpoint, this.stops[t][b].viewpoint, w, a, b];
  }

  // The unit direction a branch leaves its junction in: towards the next point of its
  // segment's path, the track's curve between the two stops (Network::branch_heading).
  branchHeading(b) {
    const sg = this.segments[b.segment];
    const t = this.tracks[sg.track];
    const arc = t.arc;
    // First curve vertex past s0 and last before s1.
    let lo = 0;
    let hi = arc.length;
    const key = b.forward ? sg.s0 : sg.s1;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (b.forward ? arc[mid] <= key : arc[mid] < key) lo = mid + 1;
      else hi = mid;
    }
    // A vertex on the junction itself (its arc length a rounding away from the stop's) is
    // passed over.
    const NEAR = 1e-6;
    let to;
    if (b.forward) {
      const from = this.viewpoints[sg.from];
      while (lo < arc.length && arc[lo] < sg.s1 && dist(t.curve[lo], from) < NEAR) lo++;
      to = lo < arc.length && arc[lo] < sg.s1 ? t.curve[lo] : this.viewpoints[sg.to];
      return unit(sub(to, from));
    }
    const from = this.viewpoints[sg.to];
    while (lo > 0 && arc[lo - 1] > sg.s0 && dist(t.curve[lo - 1], from) < NEAR) lo--;
    to = lo > 0 && arc[lo - 1] > sg.s0 ? t.curve[lo - 1] : this.viewpoints[sg.from];
    return unit(sub(to, from));
  }
}

// The ways out of a junction for a walker arriving along segment `arrival` (all of them for
// null): every branch but the one back along it (client::route::ways_out).
export const waysOut = (junction, arrival) => junction.branches.filter((b) => b.segment !== arrival);

// The way nearest the view direction (ties: the first) (client::route::nearest_to_view).
export function nearestToView(net, ways, view) {
  const v = unit(view);
  let best = null;
  for (const b of ways) {
    const d = dot3(net.branchHeading(b), v);
    if (best === null || !(best.d >= d)) best = { d, b };
  }
  return best ? best.b : null;
}

// How likely each way out is, for prefetching (client::route::branch_weights): the view pulls
// (exp(2 cos θ)), the motion less (exp(cos θ)), a chosen way outweighs both (× e³); the
// weights sum to 1.
export function branchWeights(net, ways, view, motion, chosen) {
  const v = unit(view);
  const m = unit(motion);
  const raw = ways.map((b) => {
    const h = net.branchHeading(b);
    let w = Math.exp(2 * dot3(h, v) + dot3(h, m));
    if (sameBranch(chosen, b)) w *= Math.exp(3);
    return [b, w];
  });
  const total = raw.reduce((a, x) => a + x[1], 0);
  if (!(total > 0)) return [];
  return raw.map(([b, w]) => [b, w / total]);
}

// A walker on a network (client::route::Walker): at (track, s), travelling towards larger s
// when `forward`; crossing a junction it takes the branch the user chose (`chosen`, if it is
// a way out there), else the one nearest the view; at the end of a track with no way on it
// stops.
export class Walker {
  constructor(net, track, s, forward = true) {
    this.net = net;
    this.track = track;
    this.s = s;
    this.forward = forward;
    this.chosen = null;
    // The junction just turned at while the walker still stands on it (not crossed twice).
    this.passed = null;
  }

  // The next junction ahead (or at the walker): { stop, junction, dist, arrival }, arrival
  // the segment the walker comes along (null at a track's end).
  nextJunction() {
    const net = this.net;
    const stops = net.stops[this.track];
    const ks = net.junctionStops[this.track];
    if (!stops || !ks) return null;
    for (let i = 0; i < ks.length; i++) {
      const k = this.forward ? ks[i] : ks[ks.length - 1 - i];
      const st = stops[k];
      const ahead = this.forward ? st.s >= this.s : st.s <= this.s;
      if (!ahead || (st.s === this.s && this.passed === st.viewpoint)) continue;
      const arrival = this.forward ? net.segmentId(this.track, k - 1) : net.segmentId(this.track, k);
      return { stop: k, junction: net.junctionAt.get(st.viewpoint), dist: Math.abs(st.s - this.s), arrival };
    }
    return null;
  }

  // The ways out of the next junction (none without one).
  options() {
    const nj = this.nextJunction();
    return nj ? waysOut(nj.junction, nj.arrival) : [];
  }

  // The branch the walker takes at the next junction looking along `view`.
  nextBranch(view) {
    const ways = this.options();
    if (this.chosen && ways.some((w) => sameBranch(w, this.chosen))) return this.chosen;
    return nearestToView(this.net, ways, view);
  }

  // The direction of travel (unit, in the world).
  heading() {
    const t = this.net.tracks[this.track];
    if (!t) return [0, 0, 0];
    const h = t.tangentAt(this.s);
    return this.forward ? h : h.map((x) => -x);
  }

  // The ways out of the next junction left to right as seen along the direction of travel,
  // with the junction (viewer::app::junction::Junctions::ahead); null without one.
  ahead() {
    const nj = this.nextJunction();
    if (!nj) return null;
    const h = this.heading();
    const angle = (b) => {
      const g = this.net.branchHeading(b);
      return Math.atan2(h[0] * g[2] - h[2] * g[0], dot3(h, g));
    };
    const ways = waysOut(nj.junction, nj.arrival)
      .map((b) => [angle(b), b])
      .sort((a, b) => a[0] - b[0])
      .map((x) => x[1]);
    return { ...nj, ways };
  }

  // Moves the choice for the next junction `step` ways to the right (left when negative),
  // round the ways out; from the way the walker would take now.
  choose(step, view) {
    const a = this.ahead();
    if (!a || !a.ways.length) return;
    const next = this.nextBranch(view);
    const at = Math.max(a.ways.findIndex((w) => sameBranch(w, next)), 0);
    const n = a.ways.length;
    this.chosen = a.ways[(((at + step) % n) + n) % n];
  }

  // Moves d metres (≥ 0) on, turning at junctions as nextBranch says; the turns made
  // ({ viewpoint, fromTrack, to }). Stops at the end of a track with no way on.
  advance(d, view) {
    const net = this.net;
    let left = Number.isFinite(d) ? Math.max(d, 0) : 0;
    const turns = [];
    // Each pass reaches a junction or the end (at most one turn per junction passed).
    for (let pass = 0; pass < Math.max(net.viewpoints.length, 1) + 1; pass++) {
      const t = net.tracks[this.track];
      if (!t) return turns;
      const nj = this.nextJunction();
      if (!nj || nj.dist > left) {
        const room = this.forward ? Math.max(t.length - this.s, 0) : Math.max(this.s, 0);
        const step = Math.min(left, room);
        this.s += this.forward ? step : -step;
        if (step > 0) this.passed = null;
        return turns;
      }
      left -= nj.dist;
      const ways = waysOut(nj.junction, nj.arrival);
      const pick = this.chosen && ways.some((w) => sameBranch(w, this.chosen)) ? this.chosen : nearestToView(net, ways, view);
      if (!pick) {
        // A junction with no way on (the end of every track there).
        this.s = net.stops[this.track][nj.stop].s;
        return turns;
      }
      const fromTrack = this.track;
      const wasForward = this.forward;
      this.track = pick.track;
      this.s = net.stops[pick.track][pick.stop].s;
      this.forward = pick.forward;
      this.chosen = null;
      this.passed = nj.junction.viewpoint;
      // Straight on along the same track is no turn.
      if (pick.track !== fromTrack || pick.forward !== wasForward) turns.push({ viewpoint: nj.junction.viewpoint, fromTrack, to: pick });
      // Step off the junction so the next pass looks past it.
      const sg = net.segments[pick.segment];
      const step = Math.min(left, Math.abs(sg.s1 - sg.s0));
      if (step <= 0) return turns;
      this.s += this.forward ? step : -step;
      this.passed = null;
      left -= step;
      if (left <= 0) return turns;
    }
    return turns;
  }
}
