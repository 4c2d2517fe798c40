// Stated limits on numbers that come from a database (tracks::limits and db's, the same names
// and values: a test of viewer::web reads this file and compares each constant with Rust's,
// so the two cannot drift apart). Each is checked before it sizes an allocation or a loop.

// Largest cube-map face, pixels per side.
export const MAX_FACE_SIZE = 8192;
// Smallest tile, pixels per side.
export const MIN_TILE_SIZE = 4;
// Most tiles along one side of a face.
export const MAX_TILES_PER_SIDE = 512;
// Most reference viewpoints on one track.
export const MAX_VIEWPOINTS = 100000;
// Most control points of one track.
export const MAX_TRACK_POINTS = 100000;
// Most tracks in one manifest.
export const MAX_TRACKS = 1024;
// Most depth slabs.
export const MAX_SLABS = 64;
// Longest text field of a manifest (a track's TOML, a name), UTF-8 bytes.
export const MAX_TEXT_BYTES = 1 << 20;
// Most cells of a track's tile grids: tiles per face grid × slabs × viewpoints.
export const MAX_GRID_CELLS = 2 ** 26;
// Largest manifest.json read, bytes.
export const MAX_MANIFEST_BYTES = 256 << 20;
// Largest coordinate or arc length, metres.
export const MAX_COORDINATE_M = 1e7;
// Longest decoded body of a viewpoint table (db::table::MAX_TABLE_BYTES); a table object is
// its 6-byte header and that body, gzipped only where that is smaller.
export const MAX_TABLE_BYTES = 64 << 20;
