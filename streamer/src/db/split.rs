//! The split manifest (format 4): a small top-level [`TopManifest`] plus one content-addressed
//! tile table per viewpoint ([`ViewTable`]), so a client needs the top and the tables of the
//! viewpoints around it before its first frame, not the whole database's entries.
//!
//! ```text
//! manifest.json      TopManifest: scene, slabs, tracks, viewpoints (position, background,
//!                    and a reference — hash and size — to the viewpoint's table)
//! objects/HH/HASH    a viewpoint's table: compact binary ([`super::table`]: tiles, their
//!                    ranges in the viewpoint's pack with 32-bit checksums, the ACH lists of
//!                    the segments starting at the viewpoint); an object like the others
//!                    (fetched, hash-checked and cached the same way)
//! objects/HH/HASH    a viewpoint's pack ([`super::pack`]): its tiles' meshes and PTM level
//!                    groups back to back, in table order, named once by the table
//! ```
//!
//! [`split`] turns a full [`Manifest`] into the top and the tables' bytes; [`assemble`] puts
//! a full [`Manifest`] back together from the top and the tables that have arrived
//! (viewpoints without their table have no tiles, segments without theirs no ACH entries).

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::manifest::{
    Manifest, ObjectRef, PtmRef, SegmentEntry, TileEntry, TrackEntry, ViewpointEntry,
};
use tracks::SlabRange;

/// Version of the split manifest written by this crate (3: binary tables, one pack object
/// per viewpoint, 64-bit range checksums; 4: column-wise tables, 32-bit range checksums).
pub const TOP_VERSION: u32 = 4;

pub use super::table::{decode_table, encode_table, TableError, MAX_TABLE_BYTES};

/// `manifest.json` of format 4.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopManifest {
    pub version: u32,
    pub scene: String,
    pub face_size: u32,
    pub tile_size: u32,
    pub slabs: Vec<SlabRange>,
    pub cull_alpha: Option<f64>,
    pub cull_variant: Option<String>,
    pub tracks: Vec<TopTrack>,
}

/// A track of the top manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopTrack {
    pub name: String,
    pub track_toml: String,
    pub length: f64,
    pub viewpoints: Vec<TopViewpoint>,
    /// `(from, to)` viewpoint indices of each segment; its ACH list is in `from`'s table.
    pub segments: Vec<(usize, usize)>,
}

/// A viewpoint of the top manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopViewpoint {
    pub index: usize,
    pub s: f64,
    pub position: DVec3,
    pub background: Option<PtmRef>,
    /// The viewpoint's table (an object: gzip of its compact JSON).
    pub table: ObjectRef,
}

/// A viewpoint's table, decoded.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewTable {
    /// Viewpoint index (`ViewpointEntry::index`).
    pub viewpoint: usize,
    pub tiles: Vec<TileEntry>,
    /// The segments that start at this viewpoint, with their ACH lists.
    pub segments: Vec<SegmentEntry>,
}

/// Per track and viewpoint, the bytes of its table object.
pub type TableBytes = Vec<Vec<Vec<u8>>>;

/// Splits a full manifest: the top manifest and, per track and viewpoint, the table's bytes
/// (the top refers to each by hash and size; store them as objects).
pub fn split(m: &Manifest) -> Result<(TopManifest, TableBytes), TableError> {
    let mut all = Vec::new();
    let tracks = m
        .tracks
        .iter()
        .map(|t| {
            let mut bytes = Vec::new();
            let viewpoints = t
                .viewpoints
                .iter()
                .map(|v| {
                    let pack = v
                        .tiles
                        .iter()
                        .find_map(|t| t.ptm.as_ref())
                        .map(|p| &p.object);
                    let table = ViewTable {
                        viewpoint: v.index,
                        tiles: v.tiles.clone(),
                        segments: t
                            .segments
                            .iter()
                            .filter(|s| s.from == v.index)
                            .cloned()
                            .collect(),
                    };
                    let b = encode_table(&table, pack).map_err(|e| {
                        TableError::Layout(format!("track `{}` viewpoint {}: {e}", t.name, v.index))
                    })?;
                    let obj = ObjectRef {
                        hash: super::hash_hex(&b),
                        size: b.len() as u64,
                    };
                    bytes.push(b);
                    Ok(TopViewpoint {
                        index: v.index,
                        s: v.s,
                        position: v.position,
                        background: v.background.clone(),
                        table: obj,
                    })
                })
                .collect::<Result<Vec<_>, TableError>>()?;
            all.push(bytes);
            Ok(TopTrack {
                name: t.name.clone(),
                track_toml: t.track_toml.clone(),
                length: t.length,
                viewpoints,
                segments: t.segments.iter().map(|s| (s.from, s.to)).collect(),
            })
        })
        .collect::<Result<Vec<_>, TableError>>()?;
    let top = TopManifest {
        version: TOP_VERSION,
        scene: m.scene.clone(),
        face_size: m.face_size,
        tile_size: m.tile_size,
        slabs: m.slabs.clone(),
        cull_alpha: m.cull_alpha,
        cull_variant: m.cull_variant.clone(),
        tracks,
    };
    Ok((top, all))
}

/// The full manifest as far as the tables go: `tables[t][v]` is track `t`'s viewpoint `v`'s
/// table when it has arrived. Viewpoints without one have no tiles; segments whose `from`
/// table is missing have no ACH entries.
pub fn assemble(top: &TopManifest, tables: &[Vec<Option<&ViewTable>>]) -> Manifest {
    let tracks = top
        .tracks
        .iter()
        .enumerate()
        .map(|(ti, t)| {
            let got = |vi: usize| tables.get(ti).and_then(|v| v.get(vi)).copied().flatten();
            let viewpoints = t
                .viewpoints
                .iter()
                .enumerate()
                .map(|(vi, v)| ViewpointEntry {
                    index: v.index,
                    s: v.s,
                    position: v.position,
                    background: v.background.clone(),
                    tiles: got(vi).map(|tb| tb.tiles.clone()).unwrap_or_default(),
                })
                .collect();
            let segments = t
                .segments
                .iter()
                .map(|&(from, to)| {
                    let ach = t
                        .viewpoints
                        .iter()
                        .position(|v| v.index == from)
                        .and_then(got)
                        .and_then(|tb| tb.segments.iter().find(|s| s.to == to))
                        .map(|s| s.ach.clone())
                        .unwrap_or_default();
                    SegmentEntry { from, to, ach }
                })
                .collect();
            TrackEntry {
                name: t.name.clone(),
                track_toml: t.track_toml.clone(),
                length: t.length,
                viewpoints,
                segments,
            }
        })
        .collect();
    Manifest {
        // The in-memory form is the one manifest of every tile (format 1's shape).
        version: tracks::manifest::MANIFEST_VERSION,
        scene: top.scene.clone(),
        face_size: top.face_size,
        tile_size: top.tile_size,
        slabs: top.slabs.clone(),
        cull_alpha: top.cull_alpha,
        cull_variant: top.cull_variant.clone(),
        tracks,
    }
}
