//! The split manifest (format 7; older formats are refused with a request to rebuild): a
//! small top-level [`TopManifest`] plus one content-addressed tile table per viewpoint ([`ViewTable`]), so a client needs the top and the tables of the
//! viewpoints around it before its first frame, not the whole database's entries.
//!
//! ```text
//! manifest.json      TopManifest: scene, slabs, viewpoints (position and a reference —
//!                    hash and size — to the viewpoint's table), tracks (their curves and
//!                    stops: viewpoint ids with arc lengths), junctions
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
use tracks::network::{Junction, Network, Stop};
use tracks::{SlabRange, TrackSet};

/// Version of the split manifest written by this crate (3: binary tables, one pack object
/// per viewpoint, 64-bit range checksums; 4: column-wise tables, 32-bit range checksums;
/// 5: the layout of 4, and every PTM's colour is 0 wherever its alpha is 0, see
/// [`super::clear_masked`]; 6: PTMs of format 3 (range-coded levels, a compact header),
/// meshes of format 2 (range-coded, depth within a parallax bound), every payload stored
/// once — a table may name ranges of earlier viewpoints' packs; 7: the layout of 6, meshes of
/// format 4 — pixel quads coded apart, so no mesh of a slab stage falls back to the plain
/// layout; 8: a network — the viewpoints once, each track its stops (viewpoint ids and arc
/// lengths), the junctions where tracks share a viewpoint; 9: the graph of 8 in pieces —
/// `manifest.json` a small root, the viewpoints, stops and junctions in spatial chunks
/// reached through a quadtree of node objects, [`super::index`]).
pub const TOP_VERSION: u32 = 9;

/// The oldest format this crate reads: format 9 keeps the graph in pieces, so older
/// databases are refused with a request to rebuild them.
pub const OLDEST_READ_VERSION: u32 = 9;

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
    /// Every reference viewpoint once, by id (`viewpoints[i].index == i`).
    pub viewpoints: Vec<TopViewpoint>,
    /// The tracks, each with its stops.
    pub tracks: Vec<TopTrack>,
    /// Where tracks share a viewpoint, with the segments that leave it (derived from the
    /// stops; readers check that they agree).
    #[serde(default)]
    pub junctions: Vec<Junction>,
}

impl TopManifest {
    /// Every number that sizes what a reader allocates or loops over, against the stated
    /// limits of [`tracks::limits`]: the grid, slab, track and viewpoint counts, text
    /// lengths, positions, stops. The message names the field (`tracks[0].stops[3].s`) and
    /// the limit. Checked by every reader of a manifest before it uses one.
    pub fn check_limits(&self) -> Result<(), String> {
        use tracks::limits::*;
        check_grid(self.face_size as u64, self.tile_size as u64).map_err(|e| e.to_string())?;
        let count = |name: &str, n: usize, max: usize| {
            check_u64(name, n as u64, 0, max as u64).map_err(|e| e.to_string())
        };
        count("slabs (count)", self.slabs.len(), MAX_SLABS)?;
        count("tracks (count)", self.tracks.len(), MAX_TRACKS)?;
        count("viewpoints (count)", self.viewpoints.len(), MAX_VIEWPOINTS)?;
        count("junctions (count)", self.junctions.len(), MAX_VIEWPOINTS)?;
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
        let cells = grid.saturating_mul(self.viewpoints.len() as u64);
        if cells > MAX_GRID_CELLS {
            return Err(format!(
                "viewpoints: {} viewpoints × {grid} tile cells (faces of {} px in tiles of {} \
                 px, {} slabs) = {cells} cells; at most {MAX_GRID_CELLS}",
                self.viewpoints.len(),
                self.face_size,
                self.tile_size,
                self.slabs.len()
            ));
        }
        for (vi, v) in self.viewpoints.iter().enumerate() {
            if v.index != vi {
                return Err(format!(
                    "viewpoints[{vi}].index = {}: viewpoints are listed by id",
                    v.index
                ));
            }
            let p = v.position;
            if !p.is_finite() || p.abs().max_element() > MAX_COORDINATE_M {
                return Err(format!(
                    "viewpoints[{vi}].position = {p} is out of range: finite and within \
                     ±{MAX_COORDINATE_M} m"
                ));
            }
        }
        for (ti, t) in self.tracks.iter().enumerate() {
            let at = |f: &str| format!("tracks[{ti}].{f}");
            count(&at("stops (count)"), t.stops.len(), MAX_VIEWPOINTS)?;
            count(&at("name (bytes)"), t.name.len(), MAX_TEXT_BYTES)?;
            count(
                &at("track_toml (bytes)"),
                t.track_toml.len(),
                MAX_TEXT_BYTES,
            )?;
            check_f64(&at("length"), t.length, 0.0, MAX_COORDINATE_M).map_err(|e| e.to_string())?;
            let mut last = 0.0;
            for (k, st) in t.stops.iter().enumerate() {
                let at = |f: &str| format!("tracks[{ti}].stops[{k}].{f}");
                if st.viewpoint >= self.viewpoints.len() {
                    return Err(format!(
                        "{} = {} names no viewpoint (there are {})",
                        at("viewpoint"),
                        st.viewpoint,
                        self.viewpoints.len()
                    ));
                }
                check_f64(&at("s"), st.s, last, MAX_COORDINATE_M)
                    .map_err(|e| format!("{e} (stops are in order along the track)"))?;
                last = st.s;
            }
        }
        for (ji, j) in self.junctions.iter().enumerate() {
            count(
                &format!("junctions[{ji}].branches (count)"),
                j.branches.len(),
                MAX_VIEWPOINTS,
            )?;
            if j.viewpoint >= self.viewpoints.len() {
                return Err(format!(
                    "junctions[{ji}].viewpoint = {} names no viewpoint",
                    j.viewpoint
                ));
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

    /// The graph: each track's curve from its TOML, the viewpoints' positions and the stops;
    /// the junctions checked against those the stops make. Call after
    /// [`TopManifest::check_limits`].
    pub fn network(&self) -> Result<Network, String> {
        let net = self.graph()?;
        if net.junctions != self.junctions {
            return Err(format!(
                "junctions: the manifest lists {} but its tracks' stops make {}",
                self.junctions.len(),
                net.junctions.len()
            ));
        }
        Ok(net)
    }

    /// The graph of the tracks' curves, the viewpoints and the stops, its junctions derived
    /// (not checked against the listed ones).
    fn graph(&self) -> Result<Network, String> {
        let tracks = self
            .tracks
            .iter()
            .enumerate()
            .map(|(ti, t)| {
                let set = TrackSet::parse(&t.track_toml, &format!("tracks[{ti}].track_toml"))
                    .map_err(|e| e.to_string())?;
                set.get(&t.name)
                    .or(set.tracks.first())
                    .cloned()
                    .ok_or_else(|| format!("tracks[{ti}].track_toml holds no track"))
            })
            .collect::<Result<Vec<_>, String>>()?;
        Network::from_parts(
            tracks,
            self.viewpoints.iter().map(|v| v.position).collect(),
            self.tracks.iter().map(|t| t.stops.clone()).collect(),
        )
    }
}

/// A track of the top manifest: its curve and where its viewpoints lie along it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopTrack {
    pub name: String,
    /// The track alone, as TOML (`TrackSet::to_toml`).
    pub track_toml: String,
    pub length: f64,
    /// Its viewpoints (ids) in order, with their arc lengths; consecutive stops bound a
    /// segment, whose ACH list is in the first stop's ACH object.
    pub stops: Vec<Stop>,
}

/// A viewpoint of the top manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopViewpoint {
    pub index: usize,
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

/// Per viewpoint (by id), the bytes of its objects.
pub type TableBytes = Vec<ViewBytes>;

/// The viewpoints of `m` once each, by id: the first entry of each id in track order.
pub fn unique_viewpoints(m: &Manifest) -> Vec<&ViewpointEntry> {
    let mut out: Vec<Option<&ViewpointEntry>> = Vec::new();
    for v in m.tracks.iter().flat_map(|t| &t.viewpoints) {
        if out.len() <= v.index {
            out.resize(v.index + 1, None);
        }
        out[v.index].get_or_insert(v);
    }
    out.into_iter().flatten().collect()
}

/// Splits a full manifest: the top manifest and, per viewpoint, the bytes of its table and
/// ACH object (the top refers to each by hash and size; store them as objects). Viewpoint ids
/// must be `0..n`, each the same entry on every track that stops there.
pub fn split(m: &Manifest) -> Result<(TopManifest, TableBytes), TableError> {
    let vps = unique_viewpoints(m);
    if vps.iter().enumerate().any(|(i, v)| v.index != i) {
        return Err(TableError::Layout(
            "viewpoint ids are not 0..n without gaps".into(),
        ));
    }
    let segments: Vec<&SegmentEntry> = m.tracks.iter().flat_map(|t| &t.segments).collect();
    let mut all = Vec::with_capacity(vps.len());
    // Each viewpoint's own pack: the one object its payloads lie in that no earlier
    // viewpoint owns (payloads lie in their viewpoint's pack or an earlier one).
    let mut owned: std::collections::HashSet<&str> = std::collections::HashSet::new();
    let mut viewpoints = Vec::with_capacity(vps.len());
    for v in &vps {
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
            segments: segments
                .iter()
                .filter(|s| s.from == v.index)
                .map(|s| (*s).clone())
                .collect(),
        };
        let named = |e: TableError| TableError::Layout(format!("viewpoint {}: {e}", v.index));
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
        viewpoints.push(TopViewpoint {
            index: v.index,
            position: v.position,
            table: obj(&b),
            ach: ach.as_deref().map(obj),
        });
        all.push(ViewBytes { table: b, ach });
    }
    let tracks: Vec<TopTrack> = m
        .tracks
        .iter()
        .map(|t| TopTrack {
            name: t.name.clone(),
            track_toml: t.track_toml.clone(),
            length: t.length,
            stops: t
                .viewpoints
                .iter()
                .map(|v| Stop {
                    viewpoint: v.index,
                    s: v.s,
                })
                .collect(),
        })
        .collect();
    let mut top = TopManifest {
        version: TOP_VERSION,
        scene: m.scene.clone(),
        face_size: m.face_size,
        tile_size: m.tile_size,
        slabs: m.slabs.clone(),
        cull_alpha: m.cull_alpha,
        cull_variant: m.cull_variant.clone(),
        viewpoints,
        tracks,
        junctions: Vec::new(),
    };
    top.junctions = top
        .graph()
        .map_err(|e| TableError::Layout(format!("the graph of tracks: {e}")))?
        .junctions;
    Ok((top, all))
}

/// Where each viewpoint stops on `top`'s tracks, by viewpoint id: `(track, stop)` pairs in
/// track order (a junction's viewpoint stops on several tracks). What
/// [`update_viewpoint`] needs to find a viewpoint's entries without going over the others.
pub fn stops_by_viewpoint(top: &TopManifest) -> Vec<Vec<(usize, usize)>> {
    let mut out = vec![Vec::new(); top.viewpoints.len()];
    for (t, track) in top.tracks.iter().enumerate() {
        for (k, st) in track.stops.iter().enumerate() {
            if let Some(at) = out.get_mut(st.viewpoint) {
                at.push((t, k));
            }
        }
    }
    out
}

/// Brings viewpoint `vi`'s entries in `m` (a manifest [`assemble`] made from `top`) up to
/// `table`: its tiles and background on every track that stops there and the ACH lists of the
/// segments that start there, as [`assemble`] would give them with that table; `at` is
/// [`stops_by_viewpoint`]`(top)[vi]`. The cost is that of the one table, not of the network.
pub fn update_viewpoint(
    m: &mut Manifest,
    top: &TopManifest,
    vi: usize,
    at: &[(usize, usize)],
    table: Option<&ViewTable>,
) {
    for &(t, k) in at {
        let (Some(track), Some(top_track)) = (m.tracks.get_mut(t), top.tracks.get(t)) else {
            continue;
        };
        if let Some(v) = track.viewpoints.get_mut(k).filter(|v| v.index == vi) {
            v.background = table.map(|tb| tb.background.clone()).unwrap_or_default();
            v.tiles = table.map(|tb| tb.tiles.clone()).unwrap_or_default();
        }
        let Some(to) = top_track.stops.get(k + 1).map(|st| st.viewpoint) else {
            continue;
        };
        if let Some(seg) = track.segments.get_mut(k).filter(|s| s.from == vi) {
            seg.ach = table
                .and_then(|tb| tb.segments.iter().find(|s| s.to == to))
                .map(|s| s.ach.clone())
                .unwrap_or_default();
        }
    }
}

/// The full manifest as far as the tables go: `tables[v]` is viewpoint `v`'s table when it
/// has arrived. Viewpoints without one have no tiles; segments whose `from` table is missing
/// have no ACH entries. Each track lists its viewpoints (the same entry on every track that
/// stops there, with the track's arc length).
pub fn assemble(top: &TopManifest, tables: &[Option<&ViewTable>]) -> Manifest {
    let got = |vi: usize| tables.get(vi).copied().flatten();
    let tracks = top
        .tracks
        .iter()
        .map(|t| {
            let viewpoints = t
                .stops
                .iter()
                .filter_map(|st| {
                    let v = top.viewpoints.get(st.viewpoint)?;
                    Some(ViewpointEntry {
                        index: v.index,
                        s: st.s,
                        position: v.position,
                        background: got(v.index)
                            .map(|tb| tb.background.clone())
                            .unwrap_or_default(),
                        tiles: got(v.index).map(|tb| tb.tiles.clone()).unwrap_or_default(),
                    })
                })
                .collect();
            let segments = t
                .stops
                .windows(2)
                .map(|w| {
                    let (from, to) = (w[0].viewpoint, w[1].viewpoint);
                    let ach = got(from)
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
