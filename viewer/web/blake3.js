// BLAKE3 (the hash that names the database's objects and checks its byte ranges): the
// reference algorithm, single-threaded, written from the specification
// (https://github.com/BLAKE3-team/BLAKE3-specs). Browsers have no BLAKE3 and SubtleCrypto's
// SHA family is not what the database uses; a dependency for ~120 lines was not worth it.

const IV = new Uint32Array([
  0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19,
]);
const PERM = [2, 6, 3, 10, 7, 0, 4, 13, 1, 11, 12, 5, 9, 14, 15, 8];
const CHUNK_START = 1;
const CHUNK_END = 2;
const PARENT = 4;
const ROOT = 8;

// Message schedules of the seven rounds.
const SCHEDULE = (() => {
  const out = [];
  let s = [...Array(16).keys()];
  for (let r = 0; r < 7; r++) {
    out.push(s);
    s = PERM.map((p) => s[p]);
  }
  return out;
})();

const st = new Uint32Array(16);

function compress(cv, m, counter, len, flags, out) {
  st.set(cv, 0);
  st.set(IV.subarray(0, 4), 8);
  st[12] = counter >>> 0;
  st[13] = Math.floor(counter / 2 ** 32) >>> 0;
  st[14] = len;
  st[15] = flags;
  for (let r = 0; r < 7; r++) {
    const s = SCHEDULE[r];
    g(0, 4, 8, 12, m[s[0]], m[s[1]]);
    g(1, 5, 9, 13, m[s[2]], m[s[3]]);
    g(2, 6, 10, 14, m[s[4]], m[s[5]]);
    g(3, 7, 11, 15, m[s[6]], m[s[7]]);
    g(0, 5, 10, 15, m[s[8]], m[s[9]]);
    g(1, 6, 11, 12, m[s[10]], m[s[11]]);
    g(2, 7, 8, 13, m[s[12]], m[s[13]]);
    g(3, 4, 9, 14, m[s[14]], m[s[15]]);
  }
  for (let i = 0; i < 8; i++) out[i] = st[i] ^ st[i + 8];
}

function g(a, b, c, d, x, y) {
  st[a] = st[a] + st[b] + x;
  st[d] = rotr(st[d] ^ st[a], 16);
  st[c] = st[c] + st[d];
  st[b] = rotr(st[b] ^ st[c], 12);
  st[a] = st[a] + st[b] + y;
  st[d] = rotr(st[d] ^ st[a], 8);
  st[c] = st[c] + st[d];
  st[b] = rotr(st[b] ^ st[c], 7);
}

const rotr = (x, n) => (x >>> n) | (x << (32 - n));

function words(bytes, at, len, m) {
  m.fill(0);
  for (let i = 0; i < len; i++) m[i >> 2] |= bytes[at + i] << (8 * (i & 3));
}

// The chaining value of chunk `index` (its bytes at `at`, `len` ≤ 1024), or with `root` the
// root output words of a one-chunk input.
function chunkCv(bytes, at, len, index, root) {
  const cv = new Uint32Array(IV);
  const m = new Uint32Array(16);
  const blocks = Math.max(1, Math.ceil(len / 64));
  for (let b = 0; b < blocks; b++) {
    const blen = Math.min(64, len - 64 * b);
    words(bytes, at + 64 * b, blen, m);
    let flags = 0;
    if (b === 0) flags |= CHUNK_START;
    if (b === blocks - 1) flags |= CHUNK_END | (root ? ROOT : 0);
    compress(cv, m, index, blen, flags, cv);
  }
  return cv;
}

function parentCv(left, right, root) {
  const m = new Uint32Array(16);
  m.set(left, 0);
  m.set(right, 8);
  const out = new Uint32Array(8);
  compress(IV, m, 0, 64, PARENT | (root ? ROOT : 0), out);
  return out;
}

// BLAKE3 of `bytes` (32 bytes).
export function blake3(bytes) {
  const chunks = Math.max(1, Math.ceil(bytes.length / 1024));
  let cv;
  if (chunks === 1) cv = chunkCv(bytes, 0, bytes.length, 0, true);
  else {
    // The tree: left subtrees hold the largest power of two of chunks below the total.
    const stack = [];
    for (let i = 0; i < chunks; i++) {
      let c = chunkCv(bytes, 1024 * i, Math.min(1024, bytes.length - 1024 * i), i, false);
      if (i === chunks - 1) {
        while (stack.length > 1) c = parentCv(stack.pop(), c, false);
        cv = parentCv(stack.pop(), c, true);
        break;
      }
      let total = i + 1;
      while ((total & 1) === 0) {
        c = parentCv(stack.pop(), c, false);
        total >>= 1;
      }
      stack.push(c);
    }
  }
  const out = new Uint8Array(32);
  for (let i = 0; i < 32; i++) out[i] = (cv[i >> 2] >>> (8 * (i & 3))) & 255;
  return out;
}

export function blake3Hex(bytes, n = 32) {
  return Array.from(blake3(bytes).subarray(0, n), (b) => b.toString(16).padStart(2, "0")).join("");
}

// Whether `bytes` match a hex checksum: the full hash or its first 4 or 8 bytes (how
// tables check byte ranges, db::hash_matches).
export function hashMatches(bytes, hexHash) {
  return blake3Hex(bytes, hexHash.length / 2) === hexHash;
}
