//! The binary viewpoint table (format 5): what a client needs to know about one viewpoint's
//! tiles, in a few bytes per tile; and the viewpoint's ACH object, the ACH lists of the
//! segments starting there, which only clients that rank tiles by ACH fetch.
//!
//! ```text
//! "RVTB" u8 version=5 u8 coding (0 plain, 1 gzip of the body)    header, never compressed
//! body:
//!   varint viewpoint
//!   u8 has_pack [32 B pack BLAKE3, varint pack size]             the pack, named once
//!   varint k, k × (32 B BLAKE3, varint size)                     earlier packs it points into
//!   u8 checksum bytes (4 or 8), varint grid side n
//!   the background tiles, then the tiles, each list as:
//!   u8 depth coding (0 f32, 1 f16), u8 position coding (0 ascending gaps, 1 explicit),
//!   varint count, then one column after another (each over the whole list):
//!     positions   gaps: varint (index − previous index − 1), index = ((slab·6 + face)·n + ty)·n + tx
//!                 explicit: u8 face, varint tx, varint ty, varint slab
//!     flags       u8 (1 kept, 2 PTM, 4 mesh, 8 PTM levels in the usual shape)
//!     opaque      varint opaque pixels
//!     depths      depth_min rounded down, depth_max rounded up (f16 or f32)
//!     PTM shapes  per PTM tile: varint width, varint height, u8 channels, varint ranges,
//!                 unless flag 8: per range varint level, varint width, varint height
//!     lengths     per tile: varint mesh length, varint length of each PTM range
//!     sources     per tile: varint where its mesh lies, then where its PTM's ranges lie
//!                 (one after another): 0 next in the pack, 1 an earlier range of the pack,
//!                 2 + i the i-th earlier pack
//!     offsets     per payload whose source is not 0: varint offset of its first byte
//!     checksums   per tile: mesh, then each PTM range
//!   (a background tile is a kept PTM without mesh in slab 0 at infinite depth)
//!
//! "RVAC" u8 version=1 u8 coding                                   the ACH object
//! body:
//!   varint viewpoint, varint grid side n, varint segments, per segment: varint to,
//!   varint entries, then per entry varint (index · 4 + whose: 0 this viewpoint, 1 `to`,
//!   2 another, whose number follows as a varint), then per entry f32 ach
//! ```
//!
//! Integers are LEB128 varints, floats little-endian. Columns rather than records: gzip finds
//! the repeats of a column (flags, shapes, depths of neighbouring tiles) where interleaved
//! fields hide them. Offsets are stored only for payloads stored once elsewhere (see
//! [`super::pack`]): a viewpoint's pack holds its background tiles' payloads, then its
//! tiles' (each tile's mesh, then its PTM ranges) in table order, so every other offset is
//! the sum of the lengths before it, and those lengths must add up to the pack's size. The usual shape of a PTM's ranges (flag 8) is ranges of consecutive levels ending at
//! level 0, each `level_dims` of the PTM's size, so neither levels nor sizes are written.
//! Checksums are the first 32 (or 64) bits of the range's BLAKE3 ([`super::range_hash32`]).
//! Depths are stored as f16 when every finite depth of the list stays finite and
//! non-negative that way, always rounded outwards. The ACH lists live in an object of their
//! own because a client that ranks tiles by what it sees never reads them (castle 128: a
//! sixth of the tables' bytes). Bodies are gzipped only when that makes them smaller.
//! Decoding never panics: bad bytes give a [`TableError`] naming the field.

mod ach;
mod decode;
mod encode;
#[cfg(test)]
mod tests;

use tracks::manifest::{BackgroundTile, PtmRef, TileEntry};
use tracks::{Face, TileId};

pub use ach::{decode_ach, encode_ach, ACH_MAGIC, ACH_VERSION};
pub use decode::decode_table;
pub use encode::encode_table;

/// First bytes of every table.
pub const MAGIC: &[u8; 4] = b"RVTB";
/// Table format written and read by this crate (5: payloads may lie in earlier packs).
pub const TABLE_VERSION: u8 = 5;
/// Most earlier packs a table may point into.
pub const MAX_OTHER_PACKS: usize = 1 << 16;
/// Longest decoded table body accepted (a table of a face-4096 viewpoint is far below it).
pub const MAX_TABLE_BYTES: u64 = 64 << 20;

const KEPT: u8 = 1;
const HAS_PTM: u8 = 2;
const HAS_MESH: u8 = 4;
const USUAL_SHAPE: u8 = 8;

impl From<super::GunzipError> for TableError {
    fn from(e: super::GunzipError) -> TableError {
        TableError::Gzip(e)
    }
}

/// Why a table could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    #[error("table: {0}")]
    Gzip(super::GunzipError),
    #[error("table: not a viewpoint table (no RVTB header)")]
    Magic,
    #[error("ACH lists: not an ACH object (no RVAC header)")]
    AchMagic,
    #[error("table: format {got}, this build reads format {TABLE_VERSION}: rebuild the database with `railview build`")]
    Version { got: u8 },
    #[error("table: unknown body coding {0}")]
    Coding(u8),
    #[error("table: ends inside {what} (byte {at})")]
    Truncated { what: &'static str, at: usize },
    #[error("table: {what} at byte {at}: {message}")]
    Invalid {
        what: &'static str,
        at: usize,
        message: String,
    },
    #[error("table: {0} bytes after the end")]
    Trailing(usize),
    #[error("table is for viewpoint {got}, expected {want}")]
    Viewpoint { got: usize, want: usize },
    /// The tiles' payloads do not lie in the pack in table order (encoding) or their lengths
    /// do not add up to the pack's size (decoding).
    #[error("table: {0}")]
    Layout(String),
}

/// The linear index of a tile position in a grid of side `n`, `None` on overflow.
fn tile_index(n: u64, slab: u32, t: TileId) -> Option<u64> {
    let face = Face::ALL.iter().position(|&f| f == t.face).unwrap_or(0) as u64;
    (slab as u64)
        .checked_mul(6)?
        .checked_add(face)?
        .checked_mul(n)?
        .checked_add(t.ty as u64)?
        .checked_mul(n)?
        .checked_add(t.tx as u64)
}

/// Whether a PTM's ranges have the usual shape: consecutive levels ending at level 0, each of
/// `level_dims` of the PTM's size.
fn usual_shape(p: &PtmRef) -> bool {
    let k = p.levels.len();
    p.levels.iter().enumerate().all(|(i, l)| {
        l.level as usize == k - 1 - i
            && codec::ptm::level_dims(p.width, p.height, l.level) == (l.width, l.height)
    })
}

/// A background tile as tables and packs handle it: a kept tile without mesh, depth or slab.
pub(super) fn background_entry(b: &BackgroundTile) -> TileEntry {
    TileEntry {
        tile: b.tile,
        slab: 0,
        depth_min: f64::INFINITY,
        depth_max: f64::INFINITY,
        opaque_pixels: 0,
        kept: true,
        ptm: Some(b.ptm.clone()),
        mesh: None,
        mesh_range: None,
    }
}
