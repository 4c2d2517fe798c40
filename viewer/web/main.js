// The browser viewer: the manifest, the two reference views around the camera, their tiles
// streamed as byte ranges of the packs (visible tiles first, coarse levels before fine
// ones, then the next segment's as prefetch, or near a junction every way out's), decoded in
// workers, drawn with the blend rule. On a network of tracks the walk turns at junctions onto
// the branch chosen ([ ] or q e, or a click on its arrow on the ground), else the one nearest
// the view; views are held by viewpoint id, so a junction's is one view whatever the track.
// URL contract: ?track=T&at=S&yaw=Y&pitch=P&fov=F opens that view (track by name, the first
// by default), and the URL follows the walk; when every tile the view needs has arrived and
// been drawn, document.title becomes "railview: ready".
import { Renderer } from "./render.js";
import { Network, Walker, viewOf, sameBranch, branchWeights } from "./track.js";
import { Store, FetchError } from "./fetch.js";
import { decodeTable } from "./table.js";
import { readIndex, fetchChecked, MAX_PIECE_BYTES } from "./pieces.js";
import { blake3Hex } from "./blake3.js";
import { checkManifest, visibleTiles, tileKey, projector, projectPolygon, projectPoint, arrowShape } from "./plan.js";
import { MAX_MANIFEST_BYTES, MAX_TABLE_BYTES } from "./limits.js";
import { Workers } from "./pool.js";

const MAX_FAULTS = 3;
const IN_FLIGHT = 4;
// Arrows show the ways out of the next junction once it is this near (metres along the track).
const ARROW_RANGE_M = 6;
// The ground the arrows lie on, below the camera (metres).
const EYE_ABOVE_GROUND_M = 1.5;
// A click on an arrow walks onto its branch this far past the junction (metres).
const CLICK_STEP_M = 1;
// The walk's direction of travel turns round when the camera is turned further than this
// from it (the cosine of about 100°), so that W walks the way the camera looks.
const TURN_ROUND_COS = -0.17;
// The URL follows the walk at most this often (ms).
const URL_EVERY_MS = 250;
// Before the first complete view, a partial frame is drawn at most this often (ms).
const FIRST_PARTIAL_MS = 1000;
const SVG = "http://www.w3.org/2000/svg";
// Decoded bytes kept (textures and meshes; views beyond the drawn pair and the next are
// evicted, least recently wanted first): `?budget=MB`, 512 MB by default.

const q = new URLSearchParams(location.search);
const num = (k, d) => (q.has(k) && Number.isFinite(Number(q.get(k))) ? Number(q.get(k)) : d);
const MEMORY_BUDGET = Math.min(Math.max(num("budget", 512), 1), 16384) * 1e6;
const canvas = document.getElementById("view");
const arrowLayer = document.getElementById("arrows");
const statusText = document.getElementById("status-text");
const bar = document.getElementById("bar");

function showError(e) {
  const el = document.getElementById("error");
  el.classList.add("shown");
  el.textContent = String(e.message ?? e);
  console.error(e);
}

// A tile mesh's bytes: positions and depths (f32) and the info word per vertex on the GPU,
// the positions and stretch flags kept to rebuild the info words as finer levels arrive.
const meshBytes = (t) => (t.pos ? t.pos.length * 8 + (t.pos.length / 3) * 4 + t.stretched.length : 0);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
// An angle in degrees brought into −180..180 (180 stays 180).
const wrap = (deg) => {
  const d = Number.isFinite(deg) ? ((((deg + 180) % 360) + 360) % 360) - 180 : 0;
  return d === -180 ? 180 : d;
};

class App {
  constructor() {
    this.base = new URL(".", location.href).href;
    this.store = new Store(this.base);
    this.views = new Map();
    this.queue = [];
    this.inFlight = 0;
    this.dirty = true;
    this.stats = { missing: 0, faults: 0 };
    this.frameMs = [];
    this.arrows = [];
  }

  // The track the walker is on.
  get track() {
    return this.net.tracks[this.walker.track];
  }

  get trackName() {
    return this.net.names[this.walker.track];
  }

  // The first time each stage was reached (ms since the page was opened), for measurements.
  mark(name) {
    this.marks ??= {};
    this.marks[name] ??= Math.round(performance.now());
  }

  async start() {
    this.mark("start");
    // The manifest is asked for first: the workers' modules and the renderer (a WebGL
    // context, 0.15–0.3 s of the main thread under SwiftShader) are made while it travels.
    const asked = this.store.get(`${this.base}manifest.json`, MAX_MANIFEST_BYTES);
    asked.catch(() => {}); // awaited below; a renderer that fails first is the error shown
    // At least two workers: one decodes while the other's result is uploaded.
    this.workers = new Workers(Math.max(2, Math.min(4, (navigator.hardwareConcurrency || 2) - 1)));
    this.renderer = new Renderer(canvas);
    this.mark("renderer");
    const bytes = await asked;
    const root = JSON.parse(new TextDecoder().decode(bytes));
    this.manifest = checkManifest(await readIndex(root, (ref) => fetchChecked(this.store, ref, MAX_PIECE_BYTES)));
    this.net = new Network(this.manifest);
    const name = q.get("track");
    let t = name === null ? 0 : this.net.trackIndex(name);
    if (t < 0) {
      console.warn("no track of that name here; the first one is shown");
      t = 0;
    }
    this.cam = { yaw: 0, pitch: num("pitch", 0), fov: num("fov", 90) };
    const yaw = num("yaw", NaN);
    this.go(t, num("at", 0), Number.isFinite(yaw) ? yaw : undefined);
    this.mark("manifest");
    this.shownAt = performance.now();
    this.bindInput();
    this.update();
    requestAnimationFrame(() => this.frame());
  }

  // Puts the walker on track t at arc length s (clamped to the track) looking along `yaw`
  // (along the track when undefined); it travels the way the camera looks.
  go(t, s, yaw) {
    const track = this.net.tracks[t];
    s = Math.min(Math.max(Number.isFinite(s) ? s : 0, 0), track.length);
    this.cam.yaw = yaw ?? track.yawAlong(s);
    this.walker = new Walker(this.net, t, s, dot(viewOf(this.cam.yaw), track.tangentAt(s)) >= 0);
  }

  // The pair around the camera on the walker's track, the views to prefetch, and the tiles
  // each view needs.
  update() {
    const w = this.walker;
    const [a, b, wb, ka] = this.net.blendPair(w.track, w.s);
    // At a sample (the other weight 0) its own view alone, as the native renderer draws it.
    this.pair = b !== a && wb > 0 ? [[a, 1 - wb], [b, wb]] : [[a, 1]];
    for (const v of this.views.values()) v.rank = 2;
    for (const [vi, rank] of this.prefetch(ka, wb)) this.want(vi, rank);
    for (const [vi] of this.pair) this.want(vi, 0);
    this.evict();
    this.requeue();
    this.placeArrows();
    this.followUrl();
    // Not ready until the new view has been drawn (the next frame's status says what it is).
    document.title = "railview: moving";
    this.dirty = true;
  }

  // The views to prefetch, with their ranks (1: kept like the pair; up to 2: fetched after,
  // evicted first): the next view ahead on the track, the way the walker travels; near a
  // junction (ARROW_RANGE_M) also the junction's and the far end of every way out's first
  // segment, the likeliest way first (client::route::branch_weights). Where the junction is
  // the next view or the drawn one, the likeliest way's first segment is the next segment,
  // kept like it.
  prefetch(ka, wb) {
    const w = this.walker;
    const net = this.net;
    const stops = net.stops[w.track];
    const arcs = net.arcs[w.track];
    let k;
    if (w.forward) {
      k = ka;
      while (k < arcs.length && arcs[k] <= w.s) k++;
      if (wb > 0) k++;
    } else {
      k = Math.min(ka + 1, arcs.length - 1);
      while (k >= 0 && arcs[k] >= w.s) k--;
      if (wb > 0) k--;
    }
    const nj = w.nextJunction();
    const near = nj && nj.dist <= ARROW_RANGE_M ? nj : null;
    const out = [];
    // Standing on a junction, the next view is a way out's, ranked with them.
    if (k >= 0 && k < stops.length && !(near && near.dist === 0)) out.push([stops[k].viewpoint, 1]);
    if (near) {
      const next = near.dist === 0 || near.stop === k;
      out.push([near.junction.viewpoint, next ? 1 : 1.1]);
      const view = viewOf(this.cam.yaw);
      const ways = branchWeights(net, w.options(), view, w.heading(), w.chosen).sort((x, y) => y[1] - x[1]);
      ways.forEach(([br], i) => {
        const far = net.stops[br.track][br.stop + (br.forward ? 1 : -1)];
        if (far) out.push([far.viewpoint, next && i === 0 ? 1 : 1.2 + (0.7 * i) / ways.length]);
      });
    }
    return out;
  }

  want(vi, rank) {
    let v = this.views.get(vi);
    if (!v) {
      v = { vi, rank, table: null, tiles: new Map(), tex: null, bytes: 0, loading: null, used: 0 };
      this.views.set(vi, v);
    }
    v.rank = Math.min(v.rank, rank);
    v.used = performance.now();
    if (!v.table && !v.loading) v.loading = this.loadTable(v).catch((e) => showError(e));
  }

  async loadTable(v) {
    const ref = this.manifest.viewpoints[v.vi].table;
    let bytes;
    for (let attempt = 0; ; attempt++) {
      try {
        bytes = await this.store.get(this.store.url(ref.hash), MAX_TABLE_BYTES + 6);
        if (bytes.length !== ref.size || blake3Hex(bytes) !== ref.hash) throw new FetchError(`table of viewpoint ${v.vi}: damaged`, true);
        break;
      } catch (e) {
        if (!e.retry || attempt + 1 >= MAX_FAULTS) throw e;
        this.store.stats.retries++;
        await new Promise((r) => setTimeout(r, 200 * 2 ** attempt));
      }
    }
    const table = await decodeTable(bytes, v.vi);
    if (this.views.get(v.vi) !== v) return;
    this.mark("table");
    v.table = table;
    const m = this.manifest;
    // A tile's levels: a tile larger than the face is cut to it (PTM levels of the face's size).
    v.levels = Math.round(Math.log2(Math.min(m.tile_size, 2 ** Math.ceil(Math.log2(m.face_size))))) + 1;
    v.tex = this.renderer.createLayers(m.face_size, m.slabs.length + 1, v.levels);
    this.mark("texture");
    v.bytes = (m.face_size * 6 * m.face_size * 4 * (m.slabs.length + 1) * 4) / 3;
    const entries = [...v.table.background.map((t) => ({ ...t, background: true })), ...v.table.tiles.filter((t) => t.kept && t.ptm)];
    for (const e of entries) {
      v.tiles.set(tileKey(e), {
        e, layer: e.background ? 0 : e.slab + 1, parts: new Map(), have: 0, decoded: 0, mesh: null,
        meshDone: !e.mesh, state: "idle", faults: 0, minLevel: 15, stretched: null, pos: null,
      });
    }
    this.evict();
    this.requeue();
    this.changed(v);
  }

  // Priorities: the drawn pair's visible tiles (the heavier view first), coarse ranges
  // first; then the rest of the pair's tiles in view of the track ahead; then prefetch.
  requeue() {
    const parts = [];
    const cam = this.camera();
    for (const v of this.views.values()) {
      if (!v.table) continue;
      const pairRank = this.pair.findIndex(([vi]) => vi === v.vi);
      if (v.rank >= 2) continue;
      const visible = new Set(visibleTiles(this.manifest, this.manifest.viewpoints[v.vi].position, cam, [...v.tiles.values()].map((t) => t.e)).map(tileKey));
      for (const [key, t] of v.tiles) {
        const inView = visible.has(key);
        t.needed = pairRank >= 0 && inView;
        if (t.state === "missing" || t.state === "done") continue;
        const base = pairRank >= 0 ? (inView ? 0 : 2) + (pairRank === 0 && this.pair[0][1] >= 0.5 ? 0 : 0.5) : 4 + v.rank;
        const ranges = t.e.ptm.levels;
        if (t.e.mesh && !t.parts.has("mesh") && !t.pending?.has("mesh")) {
          parts.push({ v, t, k: "mesh", obj: t.e.mesh.object, start: t.e.mesh.offset, end: t.e.mesh.offset + t.e.mesh.len, pri: base });
        }
        ranges.forEach((l, i) => {
          if (t.parts.has(i) || t.pending?.has(i)) return;
          parts.push({ v, t, k: i, obj: t.e.ptm.object, start: l.offset, end: l.offset + l.len, pri: base + (i === 0 ? 0 : 1) });
        });
      }
    }
    parts.sort((a, b) => a.pri - b.pri);
    this.queue = parts;
    this.pump();
  }

  pump() {
    while (this.inFlight < IN_FLIGHT && this.queue.length) {
      // Finer levels, the rest of the pair and the prefetch wait while the coarsest levels
      // and meshes of the view's own tiles travel (a complete view first, then detail); on
      // opening the page, until that first complete view has been drawn.
      if (this.queue[0].pri >= 1 && (this.urgentInFlight > 0 || !this.firstView)) break;
      const first = this.queue.shift();
      const batch = [first];
      // Parts of the same pack at the same priority travel in one request.
      this.queue = this.queue.filter((p) => {
        if (batch.length < 256 && p.obj.hash === first.obj.hash && Math.floor(p.pri) === Math.floor(first.pri)) {
          batch.push(p);
          return false;
        }
        return true;
      });
      for (const p of batch) (p.t.pending ??= new Set()).add(p.k);
      this.inFlight++;
      const urgent = first.pri < 1;
      if (urgent) this.urgentInFlight = (this.urgentInFlight ?? 0) + 1;
      this.mark("ranges asked");
      this.store.ranges(first.obj, batch.map((p) => [p.start, p.end]))
        .then((got) => {
          this.mark("ranges arrived");
          this.marks["last ranges arrived"] = Math.round(performance.now());
          for (const p of batch) {
            const g = got.find((r) => r.start <= p.start && r.end >= p.end);
            p.t.pending.delete(p.k);
            p.t.parts.set(p.k, g.bytes.slice(p.start - g.start, p.end - g.start));
          }
          // Each tile once, with every part of it this answer brought.
          for (const t of new Set(batch.map((p) => p.t))) this.arrived(batch.find((p) => p.t === t).v, t);
        })
        .catch((e) => {
          for (const p of batch) {
            p.t.pending.delete(p.k);
            this.fault(p.v, p.t, e);
          }
        })
        .finally(() => {
          this.inFlight--;
          if (urgent) this.urgentInFlight--;
          this.pump();
          if (!this.queue.length && this.inFlight === 0) this.requeue();
        });
    }
  }

  fault(v, t, e) {
    t.faults++;
    this.stats.faults++;
    t.parts.clear();
    t.decoded = 0;
    if (t.faults >= MAX_FAULTS) {
      t.state = "missing";
      this.stats.missing++;
      console.warn(`tile ${tileKey(t.e)} of viewpoint ${v.vi} is missing: ${e.message ?? e}`);
    } else {
      // Asked for again after a wait that doubles with each fault.
      setTimeout(() => this.requeue(), 100 * 2 ** t.faults);
    }
    this.dirty = true;
  }

  arrived(v, t) {
    const m = this.manifest;
    if (t.parts.has("mesh") && !t.meshBusy && !t.mesh) {
      t.meshBusy = true;
      this.mark("mesh job");
      const T = m.tile_size;
      const rect = { x0: t.e.tx * T, y0: t.e.ty * T, x1: Math.min((t.e.tx + 1) * T, m.face_size), y1: Math.min((t.e.ty + 1) * T, m.face_size) };
      const kept = (dx, dy) => v.tiles.has(tileKey({ slab: t.e.slab, face: t.e.face, tx: t.e.tx + dx, ty: t.e.ty + dy }));
      const shared = [kept(-1, 0), kept(0, -1), kept(1, 0), kept(0, 1)];
      this.workers.run({ kind: "mesh", parts: [t.parts.get("mesh")], hashes: [t.e.mesh.hash], face: t.e.face, faceSize: m.face_size, rect, shared }, t.needed ? 0 : 1 + v.rank)
        .then((r) => this.timed(() => {
          t.meshBusy = false;
          this.mark("mesh result");
          this.marks["last mesh result"] = Math.round(performance.now());
          if (r.error) return this.fault(v, t, new Error(r.error));
          if (!v.tex) return;
          t.pos = r.mesh.pos;
          t.stretched = r.mesh.stretched;
          t.mesh = this.renderer.createMesh(t.pos, this.info(t));
          this.mark("mesh");
          t.meshDone = true;
          this.settle(v, t);
        }));
    }
    // The PTM's ranges arrived so far, in order.
    let n = 0;
    while (t.parts.has(n)) n++;
    if (n > t.decoded && !t.ptmBusy) {
      t.ptmBusy = true;
      const parts = Array.from({ length: n }, (_, i) => t.parts.get(i));
      const hashes = t.e.ptm.levels.slice(0, n).map((l) => l.hash);
      this.workers.run({ kind: "ptm", parts, hashes }, (t.needed ? 0 : 1 + v.rank) + (t.decoded ? 0.5 : 0)).then((r) => this.timed(() => {
        t.ptmBusy = false;
        if (r.error) return this.fault(v, t, new Error(r.error));
        if (!v.tex) return;
        const T = m.tile_size;
        for (const l of r.levels) {
          if (l.level >= v.levels) continue;
          const x = (t.e.tx * T) >> l.level;
          const y = (t.e.face * m.face_size + t.e.ty * T) >> l.level;
          this.renderer.upload(v.tex, t.layer, l.level, x, y, l.width, l.height, l.rgba);
          t.minLevel = Math.min(t.minLevel, l.level);
        }
        this.mark("ptm");
        this.marks["last ptm"] = Math.round(performance.now());
        t.decoded = n;
        if (t.pos && t.meshLevel !== t.minLevel) {
          if (t.mesh) this.renderer.deleteMesh(t.mesh);
          t.mesh = this.renderer.createMesh(t.pos, this.info(t));
        }
        this.settle(v, t);
        this.arrived(v, t);
      }));
    }
  }

  // Runs an arrival's main-thread work (uploads, buffers) and keeps the longest such stall.
  timed(f) {
    const t0 = performance.now();
    f();
    const ms = performance.now() - t0;
    this.mainMaxMs = Math.max(this.mainMaxMs ?? 0, ms);
    this.mainTotalMs = (this.mainTotalMs ?? 0) + ms;
  }

  info(t) {
    t.meshLevel = t.minLevel;
    const n = t.pos.length / 3;
    const out = new Uint32Array(n);
    const base = t.e.face | (t.layer << 3) | (Math.min(t.minLevel, 15) << 8);
    for (let i = 0; i < n; i++) out[i] = base | (t.stretched[i] << 12);
    return out;
  }

  settle(v, t) {
    if (t.meshDone && t.decoded === t.e.ptm.levels.length) t.state = "done";
    this.evict();
    this.changed(v);
  }

  // Something of view v changed: drawn again when it is one of the drawn pair; a prefetched
  // view's change shows nowhere but in the status, brought up to date without a frame.
  changed(v) {
    if (this.pair.some(([vi]) => vi === v.vi)) this.dirty = true;
    else this.stale = true;
  }

  // Views beyond the pair and the next (rank over 1) go back to nothing when over the memory
  // budget, least recently wanted first.
  evict() {
    const bytes = (v) => v.bytes + [...v.tiles.values()].reduce((a, t) => a + meshBytes(t), 0);
    let total = [...this.views.values()].reduce((a, v) => a + bytes(v), 0);
    const byAge = [...this.views.values()].filter((v) => v.rank > 1).sort((a, b) => a.used - b.used);
    for (const v of byAge) {
      if (total <= MEMORY_BUDGET) break;
      total -= bytes(v);
      this.dropView(v);
    }
  }

  dropView(v) {
    if (v.tex) this.renderer.deleteTexture(v.tex);
    v.tex = null;
    for (const t of v.tiles.values()) {
      if (t.mesh) this.renderer.deleteMesh(t.mesh);
      t.mesh = null;
      t.pos = null;
    }
    this.views.delete(v.vi);
  }

  // Decoded bytes held: the views' textures (with their mip chains) and mesh buffers
  // (12 bytes of position and depth, 4 of tile info, per vertex; the stretch flags).
  memoryBytes() {
    let b = 0;
    for (const v of this.views.values()) {
      b += v.bytes;
      for (const t of v.tiles.values()) b += meshBytes(t);
    }
    return b;
  }

  camera() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr));
    const h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    return { position: this.track.positionAt(this.walker.s), yaw: this.cam.yaw, pitch: this.cam.pitch, fov: this.cam.fov, width: w, height: h };
  }

  frame() {
    requestAnimationFrame(() => this.frame());
    const cam = this.camera();
    if (canvas.width !== cam.width || canvas.height !== cam.height) {
      canvas.width = cam.width;
      canvas.height = cam.height;
      this.placeArrows();
      this.dirty = true;
    }
    if (!this.dirty) {
      if (this.stale) this.status(cam);
      this.stale = false;
      return;
    }
    // Until the first complete view a frame is drawn only when every tile it needs can be
    // (or at most every FIRST_PARTIAL_MS): partial frames would take the decoders' CPU.
    const now = performance.now();
    if (!this.firstView && !this.moved && now - (this.lastDrawEnd ?? this.shownAt) < FIRST_PARTIAL_MS && !this.coarseComplete()) return;
    // The frame-time budget: at most half the time drawing, so that a slow rasteriser
    // (SwiftShader: a third of a second at 1280×720) leaves the decoders the rest while
    // tiles arrive; a moving camera is drawn at once.
    const last = this.frameMs[this.frameMs.length - 1] ?? 0;
    if (!this.moved && now - (this.lastDrawEnd ?? 0) < last) return;
    this.moved = false;
    this.dirty = false;
    this.stale = false;
    this.render(cam);
    this.lastDrawEnd = performance.now();
  }

  render(cam) {
    const views = [];
    for (const [vi, weight] of this.pair) {
      const v = this.views.get(vi);
      if (!v || !v.tex) continue;
      const meshes = [...v.tiles.values()].filter((t) => t.mesh).sort((a, b) => a.layer - b.layer).map((t) => t.mesh);
      views.push({ weight, position: this.manifest.viewpoints[vi].position, faceSize: this.manifest.face_size, levels: v.levels, tex: v.tex, meshes });
    }
    if (!views.length) return this.status(cam);
    if (views.length === 1) views[0].weight = 1;
    const t0 = performance.now();
    this.mark("first draw");
    try {
      this.renderer.draw(cam, views);
    } catch (e) {
      showError(e);
      return;
    }
    this.frameMs.push(performance.now() - t0);
    this.framesDrawn = (this.framesDrawn ?? 0) + 1;
    this.mark("first draw done");
    if (this.frameMs.length > 200) this.frameMs.splice(0, 100);
    this.status(cam);
  }

  // Whether every tile the drawn pair needs has its mesh and a level (or is missing).
  coarseComplete() {
    for (const [vi] of this.pair) {
      const v = this.views.get(vi);
      if (!v || !v.table) return false;
      for (const t of v.tiles.values()) if (t.needed && !(t.decoded > 0 && t.meshDone) && t.state !== "missing") return false;
    }
    return true;
  }

  status() {
    let need = 0;
    let have = 0;
    let coarse = 0;
    let missing = 0;
    let pairLoaded = true;
    for (const [vi] of this.pair) {
      const v = this.views.get(vi);
      if (!v || !v.table) {
        pairLoaded = false;
        continue;
      }
      for (const t of v.tiles.values()) {
        if (!t.needed && t.state !== "done") continue;
        if (t.needed === false) continue;
        need++;
        if (t.state === "done") have++;
        if (t.decoded > 0 && t.meshDone) coarse++;
        if (t.state === "missing") missing++;
      }
    }
    const pct = need ? Math.floor((100 * have) / need) : pairLoaded ? 100 : 0;
    const st = this.store.stats;
    // Track names come from the database: text only, never markup.
    statusText.textContent = `${this.trackName} · s ${this.walker.s.toFixed(2)} m${this.junctionText()} · detail ${pct}% (${have}/${need} tiles${missing ? `, ${missing} missing` : ""}) · ${(st.bytes / 1e6).toFixed(2)} MB in ${st.requests} requests`;
    bar.style.width = `${pct}%`;
    window.railview = { need, have, missing, memory: this.memoryBytes(), budget: MEMORY_BUDGET, stats: st, faults: this.stats.faults, decodeMaxMs: this.workers.maxMs, decodeTotalMs: this.workers.totalMs, decodes: this.workers.count, mainMaxMs: this.mainMaxMs ?? 0, mainTotalMs: this.mainTotalMs ?? 0, frameMs: this.frameMs.slice(-50), framesDrawn: this.framesDrawn ?? 0 };
    const w = this.walker;
    window.railview.walker = { track: this.trackName, s: w.s, forward: w.forward, chosen: w.chosen ? this.net.names[w.chosen.track] : null };
    window.railview.arrows = this.arrows.map(({ branch, name, chosen, x, y }) => ({ ...branch, name, chosen, x, y }));
    // Times since the page was opened: every needed tile drawn at some level (what the
    // native walk counts as a complete frame), and at every level.
    if (pairLoaded && coarse === need && this.completeMs === undefined) this.completeMs = performance.now();
    // Drawn with every tile it needs (or given up): now the rest is asked for.
    if (pairLoaded && coarse + missing === need && !this.firstView && this.frameMs.length) {
      this.firstView = true;
      this.mark("first complete view");
      this.pump();
    }
    if (pairLoaded && have === need && this.readyMs === undefined) this.readyMs = performance.now();
    window.railview.completeMs = this.completeMs;
    window.railview.marks = this.marks;
    window.railview.readyMs = this.readyMs;
    if (pairLoaded && have === need) document.title = "railview: ready";
    else if (pairLoaded && have + missing === need) document.title = `railview: ${missing} tiles missing`;
    else document.title = `railview: ${pct}%`;
  }

  // The next junction's ways out, left to right, the one the walk takes marked.
  junctionText() {
    const a = this.walker.ahead();
    if (!a || !a.ways.length) return "";
    const next = this.walker.nextBranch(viewOf(this.cam.yaw));
    const ways = a.ways.map((b) => `${sameBranch(b, next) ? "▶" : ""}${this.net.names[b.track]}${b.forward ? "+" : "−"}`);
    const where = a.dist < 0.005 ? "here" : `in ${a.dist.toFixed(1)} m`;
    return ` · junction ${where}: ${ways.join(" ")} (${this.walker.chosen ? "chosen" : "nearest the view"}; [ ] to choose)`;
  }

  // Moves ds metres along the network: forward the way the walker travels, backward (ds < 0)
  // the other way, where a junction is crossed along the way nearest the motion.
  move(ds) {
    this.moved = true;
    const w = this.walker;
    const view = viewOf(this.cam.yaw);
    if (ds >= 0) {
      w.advance(ds, view);
    } else {
      const chosen = w.chosen;
      w.chosen = null;
      w.forward = !w.forward;
      w.advance(-ds, view.map((x) => -x));
      w.forward = !w.forward;
      w.chosen = chosen;
    }
    this.update();
  }

  // Moves the choice at the next junction `step` ways to the right (left when negative).
  choose(step) {
    this.walker.choose(step, viewOf(this.cam.yaw));
    this.update();
  }

  // Takes branch b at the next junction: walks onto it CLICK_STEP_M past the junction.
  take(b) {
    const w = this.walker;
    const nj = w.nextJunction();
    if (!nj) return;
    w.chosen = b;
    this.moved = true;
    w.advance(nj.dist + CLICK_STEP_M, viewOf(this.cam.yaw));
    this.update();
  }

  // The arrows on the ground at the next junction when it is within ARROW_RANGE_M: one per
  // way out along its heading, the way the walk takes highlighted; SVG over the canvas, so a
  // click or tap on one takes its branch.
  placeArrows() {
    const w = this.walker;
    const a = w.ahead();
    const width = canvas.clientWidth;
    const height = canvas.clientHeight;
    const shown = [];
    if (a && a.dist <= ARROW_RANGE_M && a.ways.length && width > 0 && height > 0) {
      const cam = this.camera();
      const pr = projector(cam, width, height);
      const center = this.net.viewpoints[a.junction.viewpoint];
      const ground = cam.position[1] - EYE_ABOVE_GROUND_M;
      const next = w.nextBranch(viewOf(this.cam.yaw));
      const box = canvas.getBoundingClientRect();
      for (const b of a.ways) {
        const shape = arrowShape(center, this.net.branchHeading(b), ground);
        if (!shape) continue;
        const outline = projectPolygon(pr, shape.outline);
        const grab = projectPoint(pr, shape.grab, width, height);
        const label = projectPoint(pr, shape.label, width, height);
        shown.push({ branch: b, name: this.net.names[b.track], chosen: sameBranch(b, next), outline, label,
          x: grab ? grab[0] + box.left : null, y: grab ? grab[1] + box.top : null });
      }
    }
    this.arrows = shown;
    const nodes = [];
    for (const ar of shown) {
      if (!ar.outline.length) continue;
      const g = document.createElementNS(SVG, "g");
      const poly = document.createElementNS(SVG, "polygon");
      poly.setAttribute("points", ar.outline.map((p) => `${p[0].toFixed(1)},${p[1].toFixed(1)}`).join(" "));
      poly.classList.add("arrow");
      if (ar.chosen) poly.classList.add("chosen");
      poly.addEventListener("click", (e) => {
        e.stopPropagation();
        this.take(ar.branch);
      });
      g.append(poly);
      if (ar.label) {
        const text = document.createElementNS(SVG, "text");
        text.setAttribute("x", ar.label[0].toFixed(1));
        text.setAttribute("y", ar.label[1].toFixed(1));
        text.textContent = ar.name;
        text.classList.add("arrow-label");
        g.append(text);
      }
      nodes.push(g);
    }
    arrowLayer.replaceChildren(...nodes);
  }

  // The URL follows the walk (history.replaceState, at most every URL_EVERY_MS, the latest
  // state), keeping the other parameters.
  followUrl() {
    if (this.urlTimer) return;
    const wait = Math.max(0, (this.urlAt ?? -Infinity) + URL_EVERY_MS - performance.now());
    this.urlTimer = setTimeout(() => {
      this.urlTimer = null;
      this.urlAt = performance.now();
      const p = new URLSearchParams(location.search);
      p.set("track", this.trackName);
      p.set("at", String(Number(this.walker.s.toFixed(3))));
      p.set("yaw", String(Number(wrap(this.cam.yaw).toFixed(2))));
      p.set("pitch", String(Number(this.cam.pitch.toFixed(2))));
      p.set("fov", String(Number(this.cam.fov.toFixed(2))));
      history.replaceState(history.state, "", `${location.pathname}?${p}${location.hash}`);
    }, wait);
  }

  bindInput() {
    const step = 0.25;
    addEventListener("keydown", (e) => {
      const k = e.key;
      if (k === "ArrowUp" || k === "w") this.move(step);
      else if (k === "ArrowDown" || k === "s") this.move(-step);
      else if (k === "ArrowLeft" || k === "a") this.look(-5, 0);
      else if (k === "ArrowRight" || k === "d") this.look(5, 0);
      else if (k === "PageUp") this.look(0, 5);
      else if (k === "PageDown") this.look(0, -5);
      else if (k === "[" || k === "q") this.choose(-1);
      else if (k === "]" || k === "e") this.choose(1);
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.move(-Math.sign(e.deltaY) * step);
    }, { passive: false });
    let last = null;
    canvas.addEventListener("pointerdown", (e) => {
      last = e.isPrimary ? [e.clientX, e.clientY] : null;
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointerup", () => (last = null));
    canvas.addEventListener("pointermove", (e) => {
      if (!last || !e.isPrimary) return;
      const deg = this.cam.fov / canvas.clientWidth;
      this.look(-(e.clientX - last[0]) * deg, (e.clientY - last[1]) * deg);
      last = [e.clientX, e.clientY];
    });
    // Two fingers move along the track by their vertical travel (a second one stops the look above).
    let pinch = null;
    canvas.addEventListener("touchstart", (e) => {
      if (e.touches.length === 2) pinch = (e.touches[0].clientY + e.touches[1].clientY) / 2;
    });
    canvas.addEventListener("touchmove", (e) => {
      if (e.touches.length !== 2 || pinch === null) return;
      const y = (e.touches[0].clientY + e.touches[1].clientY) / 2;
      this.move((y - pinch) * 0.02);
      pinch = y;
    });
    canvas.addEventListener("touchend", () => (pinch = null));
  }

  // Turns the camera; the walk's direction of travel turns round with it once the camera
  // looks more than about 100° away from it.
  look(dyaw, dpitch) {
    this.moved = true;
    this.cam.yaw += dyaw;
    this.cam.pitch = Math.min(Math.max(this.cam.pitch + dpitch, -89), 89);
    const w = this.walker;
    if (dot(viewOf(this.cam.yaw), w.heading()) < TURN_ROUND_COS) w.forward = !w.forward;
    this.update();
  }
}

// Test hooks: errors seen, and the canvas's pixels (RGBA rows top to bottom, base64).
window.railviewErrors = [];
addEventListener("error", (e) => window.railviewErrors.push(String(e.message)));
addEventListener("unhandledrejection", (e) => window.railviewErrors.push(String(e.reason?.message ?? e.reason)));
const consoleError = console.error.bind(console);
console.error = (...a) => {
  window.railviewErrors.push(a.map(String).join(" "));
  consoleError(...a);
};
window.railviewPixels = () => {
  const gl = canvas.getContext("webgl2");
  const w = canvas.width;
  const h = canvas.height;
  const px = new Uint8Array(w * h * 4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let s = "";
  for (let y = h - 1; y >= 0; y--) {
    const row = px.subarray(y * w * 4, (y + 1) * w * 4);
    for (let i = 0; i < row.length; i += 0x8000) s += String.fromCharCode(...row.subarray(i, i + 0x8000));
  }
  return { width: w, height: h, rgba: btoa(s) };
};

try {
  const app = new App();
  window.railviewApp = app;
  app.start().catch(showError);
  // Draws the current view n times, each waited for (a pixel read back: gl.finish alone
  // returns before Chromium's GPU process has drawn), and returns the draw times in ms.
  window.railviewFrameTimes = (n) => {
    const gl = canvas.getContext("webgl2");
    const px = new Uint8Array(4);
    const out = [];
    for (let i = 0; i < n; i++) {
      const t0 = performance.now();
      app.render(app.camera());
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      out.push(performance.now() - t0);
    }
    return out;
  };
  // Moves the camera to arc length s of the current track or of the track named `track`,
  // looking along `yaw` (kept when undefined); returns the track's length.
  window.railviewGo = (s, yaw, track) => {
    const t = track === undefined ? app.walker.track : app.net.trackIndex(track);
    if (t < 0) throw new Error(`no track ${track}`);
    app.go(t, s, yaw ?? app.cam.yaw);
    app.update();
    return app.track.length;
  };
} catch (e) {
  showError(e);
}
