//! The walkthrough database manifest: what a server streams and a viewer draws.
//!
//! A database is a directory of immutable, content-addressed files plus `manifest.json`:
//!
//! ```text
//! DB/manifest.json          the top of the manifest, written last and atomically
//! DB/objects/HH/HASH        every payload (per viewpoint a tile table and a pack of its tiles'
//!                           PTMs and meshes, background maps), named by the lowercase hex
//!                           BLAKE3 hash of its bytes, HH = first two hex digits
//! ```
//!
//! The on-disk form (the split top manifest, binary tables, packs) is the streamer's
//! (`db`); [`Manifest`] here is the assembled in-memory form every crate reads: a
//! tile's PTM names its pack as `object` with level ranges inside it, and its mesh is a
//! [`PackRange`] of the same pack ([`TileEntry::mesh_range`]).
//!
//! Because every payload is named by its hash, any static HTTP server can serve a database
//! (`GET /manifest.json`, `GET /objects/HH/HASH`, `Range:` for one tile part), caches can keep
//! files forever, and `verify` is a hash check per file plus one per range.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{SlabRange, TileId};

/// Manifest format version written by this crate.
pub const MANIFEST_VERSION: u32 = 1;

/// A content-addressed file of the database.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ObjectRef {
    /// Lowercase hex BLAKE3 of the whole file (64 characters).
    pub hash: String,
    /// File size in bytes.
    pub size: u64,
}

impl ObjectRef {
    /// Path of the object relative to the database root: `objects/HH/HASH`.
    /// `None` when the hash is not 64 lowercase hex digits (never build paths from bad ids).
    pub fn rel_path(&self) -> Option<String> {
        object_rel_path(&self.hash)
    }
}

/// `objects/HH/HASH` for a valid hash, else `None`.
pub fn object_rel_path(hash: &str) -> Option<String> {
    let ok = hash.len() == 64
        && hash
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
    ok.then(|| format!("objects/{}/{}", &hash[..2], hash))
}

/// One level group of a PTM file: a byte range inside the tile's object.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelRef {
    /// Level number: 0 is the full resolution, larger is coarser.
    pub level: u32,
    /// Width and height of the image at this level.
    pub width: u32,
    pub height: u32,
    /// Byte offset and length of the group inside the object.
    pub offset: u64,
    pub len: u64,
    /// Lowercase hex BLAKE3 of the group's bytes, so a single range can be checked alone.
    pub hash: String,
}

/// A tile's colour as a progressive texture map.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PtmRef {
    pub object: ObjectRef,
    pub width: u32,
    pub height: u32,
    /// 1 grey, 3 RGB, 4 RGBA (alpha = the slab's opacity mask).
    pub channels: u8,
    /// Groups in stream order: the header + lowest level first, then coarse to fine.
    pub levels: Vec<LevelRef>,
}

/// One slab tile of one reference viewpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileEntry {
    pub tile: TileId,
    /// Slab index, 0 = nearest.
    pub slab: u32,
    /// Radial depth range of the tile's opaque pixels, metres.
    pub depth_min: f64,
    pub depth_max: f64,
    /// Opaque pixels in the tile.
    pub opaque_pixels: u32,
    /// False when occlusion culling dropped the tile (its payload is then absent).
    pub kept: bool,
    pub ptm: Option<PtmRef>,
    /// Depth mesh (compact binary, quantised depth): the object holding it — the whole
    /// object, or with `mesh_range` the range of it — when that is not `ptm.object`.
    pub mesh: Option<ObjectRef>,
    /// Depth mesh packed with other payloads: its byte range and that range's checksum,
    /// inside `mesh` when given, else inside `ptm.object` (the pack that holds the PTM).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_range: Option<PackRange>,
}

impl TileEntry {
    /// Where the tile's mesh lies: the object and, when it is a range of it, the range.
    pub fn mesh_at(&self) -> Option<(&ObjectRef, Option<&PackRange>)> {
        match (&self.mesh, &self.mesh_range, &self.ptm) {
            (Some(o), r, _) => Some((o, r.as_ref())),
            (None, Some(r), Some(p)) => Some((&p.object, Some(r))),
            _ => None,
        }
    }
}

/// A byte range inside a pack object, checked by its own (short) checksum.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PackRange {
    pub offset: u64,
    pub len: u64,
    /// Lowercase hex of the range's truncated BLAKE3.
    pub hash: String,
}

/// Stable key of a tile in a track: `v{viewpoint}-s{slab}-{face}-{tx}-{ty}`.
pub fn tile_key(viewpoint: usize, slab: u32, tile: TileId) -> String {
    format!(
        "v{viewpoint:04}-s{slab}-{}-{}-{}",
        tile.face.short_name(),
        tile.tx,
        tile.ty
    )
}

/// A reference viewpoint with everything drawn from it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewpointEntry {
    pub index: usize,
    /// Arc length along the track, metres.
    pub s: f64,
    pub position: DVec3,
    /// Sky/background layer (no mesh), tile by tile on the same grid as the slabs' tiles:
    /// only the tiles with some sky, each an RGBA PTM with alpha = 255 where sky, so a client
    /// fetches the sky it sees rather than the whole cube.
    #[serde(default)]
    pub background: Vec<BackgroundTile>,
    pub tiles: Vec<TileEntry>,
}

/// One tile of a viewpoint's background.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BackgroundTile {
    pub tile: TileId,
    pub ptm: PtmRef,
}

/// Average coverage hint of one tile for one track segment (PTM §5 adapted to tracks).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AchEntry {
    /// Reference viewpoint owning the tile.
    pub viewpoint: usize,
    pub slab: u32,
    pub tile: TileId,
    /// Fraction of all visible pixels along the segment that this tile covers (sums to ≤ 1).
    pub ach: f64,
}

/// The part of a track between two consecutive reference viewpoints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentEntry {
    pub from: usize,
    pub to: usize,
    /// Tiles seen from this segment, by descending `ach`.
    pub ach: Vec<AchEntry>,
}

/// One track of the database.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackEntry {
    pub name: String,
    /// The track description (TOML, as `TrackSet::to_toml`), so clients can rebuild the curve.
    pub track_toml: String,
    pub length: f64,
    pub viewpoints: Vec<ViewpointEntry>,
    pub segments: Vec<SegmentEntry>,
}

/// The manifest (`manifest.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub version: u32,
    pub scene: String,
    pub face_size: u32,
    pub tile_size: u32,
    pub slabs: Vec<SlabRange>,
    /// α used for occlusion culling, and the variant (`conservative` or `paper`).
    pub cull_alpha: Option<f64>,
    pub cull_variant: Option<String>,
    pub tracks: Vec<TrackEntry>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Face;

    #[test]
    fn object_paths_reject_anything_but_hashes() {
        let h = "ab".repeat(32);
        assert_eq!(object_rel_path(&h).unwrap(), format!("objects/ab/{h}"));
        for bad in [
            "",
            "../etc/passwd",
            &"AB".repeat(32),
            &"ab".repeat(31),
            &format!("{}/x", "a".repeat(62)),
        ] {
            assert!(object_rel_path(bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn tile_keys_are_stable() {
        let t = TileId {
            face: Face::NegZ,
            tx: 3,
            ty: 0,
        };
        assert_eq!(tile_key(7, 2, t), "v0007-s2-nz-3-0");
    }
}
