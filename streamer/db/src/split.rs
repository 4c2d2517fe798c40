//! The split manifest (format 7; older formats are refused with a request to rebuild): a
//! small top-level [`TopManifest`] plus one content-addressed tile table per viewpoint ([`ViewTable`]), so a client needs the top and the tables of the
//! viewpoints around it before its first frame, not the whole database's entries.
//!
//! ```text
//! manifest.json      TopManifest: scene, slabs, tracks, viewpoints (position and a
//!                    reference — hash and size — to the viewpoint's table)
//! objects/HH/HASH    a viewpoint's table: compact binary ([`super::table`]: background tiles
//!                    and tiles, their ranges in the viewpoint's pack, or in an earlier
//!                    viewpoint's, with 32-bit checksums); an object like the others
//!                    (fetched, hash-checked and cached the same way)
//! objects/HH/HASH    a viewpoint's ACH object ([`super::table`]: the ACH lists of the
//!                    segments starting at the viewpoint), fetched only by clients that
//!                    rank tiles by ACH
//! objects/HH/HASH    a viewpoint's pack ([`super::pack`]): its background tiles' PTM level
//!                    groups, then its tiles' meshes and PTM level groups, back to back in
//!                    table order, named once by the table
//! ```
//!
//! [`split`] turns a full [`Manifest`] into the top and the tables' bytes; [`assemble`] puts
//! a full [`Manifest`] back together from the top and the tables that have arrived
//! (viewpoints without their table have no tiles, segments without theirs no ACH entries).

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::manifest::{
    BackgroundTile, Manifest, ObjectRef, SegmentEntry, TileEntry, TrackEntry, ViewpointEntry,
};
use tracks::SlabRange;

/// Version of the split manifest written by this crate (3: binary tables, one pack object
/// per viewpoint, 64-bit range checksums; 4: column-wise tables, 32-bit range checksums;
/// 5: the layout of 4, and every PTM's colour is 0 wherever its alpha is 0, see
/// [`super::clear_masked`]; 6: PTMs of format 3 (range-coded levels, a compact header),
/// meshes of format 2 (range-coded, depth within a parallax bound), every payload stored
/// once — a table may name ranges of earlier viewpoints' packs; 7: the layout of 6, meshes of
/// format 4 — pixel quads coded apart, so no mesh of a slab stage falls back to the plain
/// layout).
pub const TOP_VERSION: u32 = 7;

/// The oldest format this crate reads: the mesh format of format 7 is new, so older
/// databases are refused with a request to rebuild them.
pub const OLDEST_READ_VERSION: u32 = 7;

pub use super::table::{
    decode_ach, decode_table, encode_ach, encode_table, TableError, MAX_TABLE_BYTES,
};

/// `manifest.json` (format [`TOP_VERSION`]).
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

impl TopManifest {
    /// Every number that sizes what a reader allocates or loops over, against the stated
    /// limits of [`tracks::limits`]: the grid, slab, track and viewpoint counts, text
    /// lengths, positions. The message names the field (`tracks[0].viewpoints[3].s`) and the
    /// limit. Checked by every reader of a manifest before it uses one.
    pub fn check_limits(&self) -> Result<(), String> {
        use tracks::limits::*;
        check_grid(self.face_size as u64, self.tile_size as u64).map_err(|e| e.to_string())?;
        let count = |name: &str, n: usize, max: usize| {
            check_u64(name, n as u64, 0, max as u64).map_err(|e| e.to_string())
        };
        count("slabs (count)", self.slabs.len(), MAX_SLABS)?;
        count("tracks (count)", self.tracks.len(), MAX_TRACKS)?;
        count("scene (bytes)", self.scene.len(), MAX_TEXT_BYTES)?;
        for (k, s) in self.slabs.iter().enumerate() {
            if tracks::SlabRange::new(s.near, s.far).is_none() {
                return Err(format!(
                    "slabs[{k}] = {}..{} is not a depth range 0 ≤ near < far",
                    s.near, s.far
                ));
            }
        }
        if let Some(a) = self.cull_alpha {
            check_f64("cull_alpha", a, 0.0, 1.0).map_err(|e| e.to_string())?;
        }
        let per_side = self.face_size.div_ceil(self.tile_size.max(1)) as u64;
        let grid = 6 * per_side * per_side * self.slabs.len().max(1) as u64;
        for (ti, t) in self.tracks.iter().enumerate() {
            let at = |f: &str| format!("tracks[{ti}].{f}");
            count(
                &at("viewpoints (count)"),
                t.viewpoints.len(),
                MAX_VIEWPOINTS,
            )?;
            count(&at("segments (count)"), t.segments.len(), MAX_VIEWPOINTS)?;
            count(&at("name (bytes)"), t.name.len(), MAX_TEXT_BYTES)?;
            count(
                &at("track_toml (bytes)"),
                t.track_toml.len(),
                MAX_TEXT_BYTES,
            )?;
            check_f64(&at("length"), t.length, 0.0, MAX_COORDINATE_M).map_err(|e| e.to_string())?;
            let cells = grid.saturating_mul(t.viewpoints.len() as u64);
            if cells > MAX_GRID_CELLS {
                return Err(format!(
                    "{}: {} viewpoints × {grid} tile cells (faces of {} px in tiles of {} px, \
                     {} slabs) = {cells} cells; at most {MAX_GRID_CELLS}",
                    at("viewpoints"),
                    t.viewpoints.len(),
                    self.face_size,
                    self.tile_size,
                    self.slabs.len()
                ));
            }
            for (vi, v) in t.viewpoints.iter().enumerate() {
                let at = |f: &str| format!("tracks[{ti}].viewpoints[{vi}].{f}");
                check_u64(&at("index"), v.index as u64, 0, MAX_VIEWPOINTS as u64 * 16)
                    .map_err(|e| e.to_string())?;
                check_f64(&at("s"), v.s, 0.0, MAX_COORDINATE_M).map_err(|e| e.to_string())?;
                let p = v.position;
                if !p.is_finite() || p.abs().max_element() > MAX_COORDINATE_M {
                    return Err(format!(
                        "{} = {p} is out of range: finite and within ±{MAX_COORDINATE_M} m",
                        at("position")
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether every PTM's coarse levels hold colour × coverage ([`super::clear_masked`],
    /// format 5 on): then a reader recovers the covered texels' own mean colour with
    /// [`super::unpremultiply`]. In format 4 the colour under alpha 0 was whatever the
    /// renderer left there (black for the built-in renderer, POV-Ray's background for
    /// POV-Ray slab layers), so coarse levels are drawn as they are.
    pub fn coarse_levels_premultiplied(&self) -> bool {
        self.version >= 5
    }
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
    /// The viewpoint's table (an object: [`super::table`]).
    pub table: ObjectRef,
    /// The ACH lists of the segments starting at the viewpoint (an object: [`super::table`]),
    /// absent when none starts there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ach: Option<ObjectRef>,
}

/// A viewpoint's table, decoded.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewTable {
    /// Viewpoint index (`ViewpointEntry::index`).
    pub viewpoint: usize,
    /// Its background tiles (payloads first in the pack).
    pub background: Vec<BackgroundTile>,
    pub tiles: Vec<TileEntry>,
    /// The segments that start at this viewpoint, with their ACH lists (from the viewpoint's
    /// ACH object, not the table; empty until that has been read).
    pub segments: Vec<SegmentEntry>,
}

/// The objects of one viewpoint: its table's bytes and its ACH object's (none when no
/// segment starts there).
#[derive(Clone, Debug, PartialEq)]
pub struct ViewBytes {
    pub table: Vec<u8>,
    pub ach: Option<Vec<u8>>,
}

/// Per track and viewpoint, the bytes of its objects.
pub type TableBytes = Vec<Vec<ViewBytes>>;

/// Splits a full manifest: the top manifest and, per track and viewpoint, the bytes of its
/// table and ACH object (the top refers to each by hash and size; store them as objects).
pub fn split(m: &Manifest) -> Result<(TopManifest, TableBytes), TableError> {
    let mut all = Vec::new();
    let tracks = m
        .tracks
        .iter()
        .map(|t| {
            let mut bytes = Vec::new();
            // Each viewpoint's own pack: the one object its payloads lie in that no earlier
            // viewpoint owns (payloads lie in their viewpoint's pack or an earlier one).
            let mut owned: std::collections::HashSet<&str> = std::collections::HashSet::new();
            let viewpoints = t
                .viewpoints
                .iter()
                .map(|v| {
                    let objects = v
                        .background
                        .iter()
                        .map(|b| &b.ptm.object)
                        .chain(
                            v.tiles
                                .iter()
                                .filter_map(|t| t.ptm.as_ref())
                                .map(|p| &p.object),
                        )
                        .chain(v.tiles.iter().filter_map(|t| t.mesh_at()).map(|(o, _)| o));
                    let mut pack = None;
                    for o in objects {
                        if !owned.contains(o.hash.as_str()) {
                            pack = Some(o);
                            break;
                        }
                    }
                    if let Some(p) = pack {
                        owned.insert(p.hash.as_str());
                    }
                    let table = ViewTable {
                        viewpoint: v.index,
                        background: v.background.clone(),
                        tiles: v.tiles.clone(),
                        segments: t
                            .segments
                            .iter()
                            .filter(|s| s.from == v.index)
                            .cloned()
                            .collect(),
                    };
                    let named = |e: TableError| {
                        TableError::Layout(format!("track `{}` viewpoint {}: {e}", t.name, v.index))
                    };
                    let b = encode_table(&table, pack).map_err(named)?;
                    let ach = if table.segments.is_empty() {
                        None
                    } else {
                        Some(encode_ach(v.index, &table.segments).map_err(named)?)
                    };
                    let obj = |b: &[u8]| ObjectRef {
                        hash: super::hash_hex(b),
                        size: b.len() as u64,
                    };
                    let top = TopViewpoint {
                        index: v.index,
                        s: v.s,
                        position: v.position,
                        table: obj(&b),
                        ach: ach.as_deref().map(obj),
                    };
                    bytes.push(ViewBytes { table: b, ach });
                    Ok(top)
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
                    background: got(vi).map(|tb| tb.background.clone()).unwrap_or_default(),
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
