// Byte ranges over HTTP, as the native client asks for them (streamer::client::byteranges):
// a tile's parts as ranges of its pack, neighbouring ranges merged, several per request
// answered as multipart/byteranges; a host that answers one range at a time (or ignores
// Range and sends the whole object) is noticed and served by what it can do. Every answer
// is checked against what was asked before a byte of it is used.

export const MERGE_GAP = 256;       // bytes between two ranges fetched as one
export const MAX_RANGES = 48;       // ranges in one request
export const MAX_OBJECT_BYTES = 1 << 30;

export class FetchError extends Error {
  constructor(message, retry) {
    super(message);
    this.retry = retry;
  }
}

// Merges sorted, possibly overlapping [start, end) ranges that lie within `gap` bytes.
export function mergeRanges(ranges, gap = MERGE_GAP) {
  const sorted = [...ranges].sort((a, b) => a[0] - b[0]);
  const out = [];
  for (const [s, e] of sorted) {
    const last = out[out.length - 1];
    if (last && s <= last[1] + gap) last[1] = Math.max(last[1], e);
    else out.push([s, e]);
  }
  return out;
}

function indexOf(hay, needle, from) {
  outer: for (let i = from; i <= hay.length - needle.length; i++) {
    for (let j = 0; j < needle.length; j++) if (hay[i + j] !== needle[j]) continue outer;
    return i;
  }
  return -1;
}

// Parses a multipart/byteranges body into [{ start, end, bytes }] (end exclusive).
export function parseMultipart(body, boundary, objectSize) {
  const enc = new TextEncoder();
  const delim = enc.encode(`--${boundary}`);
  const parts = [];
  let at = indexOf(body, delim, 0);
  if (at < 0) throw new FetchError("multipart answer without its boundary", false);
  for (;;) {
    at += delim.length;
    if (body[at] === 45 && body[at + 1] === 45) break; // closing "--"
    const headEnd = indexOf(body, enc.encode("\r\n\r\n"), at);
    if (headEnd < 0) throw new FetchError("multipart part without headers", false);
    const head = new TextDecoder().decode(body.subarray(at, headEnd));
    const m = /content-range:\s*bytes\s+(\d+)-(\d+)\/(\d+|\*)/i.exec(head);
    if (!m) throw new FetchError("multipart part without Content-Range", false);
    const start = Number(m[1]);
    const end = Number(m[2]) + 1;
    if (end <= start || end > objectSize) throw new FetchError(`part ${start}-${end} outside the object`, false);
    const dataStart = headEnd + 4;
    if (dataStart + (end - start) > body.length) throw new FetchError("multipart part cut short", true);
    parts.push({ start, end, bytes: body.subarray(dataStart, dataStart + (end - start)) });
    at = indexOf(body, delim, dataStart + (end - start));
    if (at < 0) throw new FetchError("multipart answer cut short", true);
  }
  return parts;
}

// The object store of one database URL. `stats` counts requests and bytes.
export class Store {
  constructor(base) {
    this.base = base;
    this.multi = true;   // until a host shows it answers one range at a time
    this.stats = { requests: 0, bytes: 0, retries: 0, fallbacks: 0 };
  }

  url(hash) {
    return `${this.base}objects/${hash.slice(0, 2)}/${hash}`;
  }

  async get(path, limit) {
    this.stats.requests++;
    let res;
    try {
      res = await fetch(path, { cache: "no-store" });
    } catch (e) {
      throw new FetchError(`${path}: ${e.message}`, true);
    }
    if (!res.ok) throw new FetchError(`${path}: HTTP ${res.status}`, res.status >= 500 || res.status === 429);
    const len = Number(res.headers.get("content-length") ?? 0);
    if (len > limit) throw new FetchError(`${path}: ${len} bytes, more than the limit ${limit}`, false);
    const b = new Uint8Array(await res.arrayBuffer());
    if (b.length > limit) throw new FetchError(`${path}: more than the limit ${limit}`, false);
    this.stats.bytes += b.length;
    return b;
  }

  // Fetches `ranges` ([start, end)) of object `obj` ({ hash, size }); resolves to
  // [{ start, end, bytes }] covering every range asked.
  async ranges(obj, ranges) {
    const merged = mergeRanges(ranges);
    const out = [];
    for (let i = 0; i < merged.length; ) {
      const batch = this.multi ? merged.slice(i, i + MAX_RANGES) : [merged[i]];
      const got = await this.request(obj, batch);
      if (got === null) {
        // One range came back for several asked: this host answers one at a time.
        this.multi = false;
        this.stats.fallbacks++;
        continue;
      }
      out.push(...got);
      i += batch.length;
    }
    return out;
  }

  async request(obj, batch) {
    const header = `bytes=${batch.map(([s, e]) => `${s}-${e - 1}`).join(",")}`;
    this.stats.requests++;
    let res;
    try {
      res = await fetch(this.url(obj.hash), { headers: { Range: header }, cache: "no-store" });
    } catch (e) {
      throw new FetchError(`${obj.hash}: ${e.message}`, true);
    }
    if (res.status === 200) {
      // The whole object: a host that ignores Range, or one that answers several ranges so
      // (nginx beyond its max_ranges). Later requests ask for one range at a time.
      if (batch.length > 1 && this.multi) {
        this.multi = false;
        this.stats.fallbacks++;
      }
      const b = new Uint8Array(await res.arrayBuffer());
      this.stats.bytes += b.length;
      if (b.length !== obj.size) throw new FetchError(`${obj.hash}: ${b.length} bytes, expected ${obj.size}`, true);
      return batch.map(([s, e]) => ({ start: s, end: e, bytes: b.subarray(s, e) }));
    }
    if (res.status !== 206) throw new FetchError(`${obj.hash}: HTTP ${res.status}`, res.status >= 500 || res.status === 404);
    const body = new Uint8Array(await res.arrayBuffer());
    this.stats.bytes += body.length;
    const type = res.headers.get("content-type") ?? "";
    const bm = /multipart\/byteranges;\s*boundary=("?)([^";]+)\1/i.exec(type);
    let parts;
    if (bm) parts = parseMultipart(body, bm[2], obj.size);
    else {
      const m = /bytes\s+(\d+)-(\d+)\/(\d+|\*)/i.exec(res.headers.get("content-range") ?? "");
      if (!m) throw new FetchError(`${obj.hash}: 206 without Content-Range`, false);
      const start = Number(m[1]);
      const end = Number(m[2]) + 1;
      if (end - start !== body.length) throw new FetchError(`${obj.hash}: range cut short`, true);
      parts = [{ start, end, bytes: body }];
    }
    // Every range asked must lie inside one part.
    const res2 = [];
    for (const [s, e] of batch) {
      const p = parts.find((q) => q.start <= s && q.end >= e);
      if (!p) {
        if (batch.length > 1 && parts.length === 1) return null;
        throw new FetchError(`${obj.hash}: the answer lacks bytes ${s}-${e}`, true);
      }
      res2.push({ start: s, end: e, bytes: p.bytes.subarray(s - p.start, e - p.start) });
    }
    return res2;
  }
}
