//! The split manifest (format 2): a small top-level [`TopManifest`] plus one content-addressed
//! tile table per viewpoint ([`ViewTable`]), so a client needs the top and the tables of the
//! viewpoints around it before its first frame, not the whole database's entries.
//!
//! ```text
//! manifest.json      TopManifest: scene, slabs, tracks, viewpoints (position, background,
//!                    and a reference — hash and size — to the viewpoint's table)
//! objects/HH/HASH    a viewpoint's table: gzip of compact JSON (tiles as arrays, segment ACH
//!                    lists of the segments starting at the viewpoint); an object like the
//!                    tiles (fetched, hash-checked and cached the same way)
//! ```
//!
//! [`split`] turns a full [`Manifest`] into the top and the tables' bytes; [`assemble`] puts
//! a full [`Manifest`] back together from the top and the tables that have arrived
//! (viewpoints without their table have no tiles, segments without theirs no ACH entries).

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::manifest::{
    AchEntry, LevelRef, Manifest, ObjectRef, PtmRef, SegmentEntry, TileEntry, TrackEntry,
    ViewpointEntry,
};
use tracks::{SlabRange, TileId};

/// Version of the split manifest written by this crate.
pub const TOP_VERSION: u32 = 2;

/// Longest decoded table accepted (a table of a face-4096 viewpoint is far below it).
pub const MAX_TABLE_BYTES: u64 = 64 << 20;

/// `manifest.json` of format 2.
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

/// A compact level group: `[level, width, height, offset, len, hash]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct CLevel(u32, u32, u32, u64, u64, String);

/// A compact PTM reference: `[hash, size, width, height, channels, levels]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct CPtm(String, u64, u32, u32, u8, Vec<CLevel>);

/// A compact tile: `[tile, slab, depth_min, depth_max, opaque, kept, mesh, ptm]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct CTile(
    TileId,
    u32,
    f64,
    f64,
    u32,
    bool,
    Option<(String, u64)>,
    Option<CPtm>,
);

/// A compact ACH entry: `[viewpoint, slab, tile, ach]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct CAch(usize, u32, TileId, f64);

/// The JSON inside a table object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct CTable {
    /// Viewpoint index the table belongs to (a table is never used for another one).
    v: usize,
    t: Vec<CTile>,
    /// Segments starting at this viewpoint: `(to, ach list)`.
    a: Vec<(usize, Vec<CAch>)>,
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

/// Why a table could not be decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    #[error("table: {0}")]
    Gzip(#[from] super::GunzipError),
    #[error("table: JSON line {line}: {message}")]
    Json { line: usize, message: String },
    #[error("table is for viewpoint {got}, expected {want}")]
    Viewpoint { got: usize, want: usize },
}

fn c_ptm(p: &PtmRef) -> CPtm {
    CPtm(
        p.object.hash.clone(),
        p.object.size,
        p.width,
        p.height,
        p.channels,
        p.levels
            .iter()
            .map(|l| CLevel(l.level, l.width, l.height, l.offset, l.len, l.hash.clone()))
            .collect(),
    )
}

fn from_c_ptm(c: CPtm) -> PtmRef {
    PtmRef {
        object: ObjectRef {
            hash: c.0,
            size: c.1,
        },
        width: c.2,
        height: c.3,
        channels: c.4,
        levels: c
            .5
            .into_iter()
            .map(|l| LevelRef {
                level: l.0,
                width: l.1,
                height: l.2,
                offset: l.3,
                len: l.4,
                hash: l.5,
            })
            .collect(),
    }
}

/// The bytes of a viewpoint's table object (gzip of its compact JSON).
pub fn encode_table(table: &ViewTable) -> Vec<u8> {
    let c = CTable {
        v: table.viewpoint,
        t: table
            .tiles
            .iter()
            .map(|t| {
                CTile(
                    t.tile,
                    t.slab,
                    t.depth_min,
                    t.depth_max,
                    t.opaque_pixels,
                    t.kept,
                    t.mesh.as_ref().map(|m| (m.hash.clone(), m.size)),
                    t.ptm.as_ref().map(c_ptm),
                )
            })
            .collect(),
        a: table
            .segments
            .iter()
            .map(|s| {
                (
                    s.to,
                    s.ach
                        .iter()
                        .map(|a| CAch(a.viewpoint, a.slab, a.tile, a.ach))
                        .collect(),
                )
            })
            .collect(),
    };
    let json = serde_json::to_vec(&c).expect("a table always serialises");
    super::gzip(&json).expect("gzip into memory cannot fail")
}

/// Decodes a table object's bytes (already checked against its hash) for viewpoint `want`.
pub fn decode_table(bytes: &[u8], want: usize) -> Result<ViewTable, TableError> {
    let json = super::gunzip_limited(bytes, MAX_TABLE_BYTES)?;
    let c: CTable = serde_json::from_slice(&json).map_err(|e| TableError::Json {
        line: e.line(),
        message: e.to_string(),
    })?;
    if c.v != want {
        return Err(TableError::Viewpoint { got: c.v, want });
    }
    Ok(ViewTable {
        viewpoint: c.v,
        tiles: c
            .t
            .into_iter()
            .map(|t| TileEntry {
                tile: t.0,
                slab: t.1,
                depth_min: t.2,
                depth_max: t.3,
                opaque_pixels: t.4,
                kept: t.5,
                mesh: t.6.map(|(hash, size)| ObjectRef { hash, size }),
                ptm: t.7.map(from_c_ptm),
            })
            .collect(),
        segments: c
            .a
            .into_iter()
            .map(|(to, ach)| SegmentEntry {
                from: c.v,
                to,
                ach: ach
                    .into_iter()
                    .map(|a| AchEntry {
                        viewpoint: a.0,
                        slab: a.1,
                        tile: a.2,
                        ach: a.3,
                    })
                    .collect(),
            })
            .collect(),
    })
}

/// Splits a full manifest: the top manifest and, per track and viewpoint, the table's bytes
/// (the top refers to each by hash and size; store them as objects).
pub fn split(m: &Manifest) -> (TopManifest, Vec<Vec<Vec<u8>>>) {
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
                    let b = encode_table(&table);
                    let obj = ObjectRef {
                        hash: super::hash_hex(&b),
                        size: b.len() as u64,
                    };
                    bytes.push(b);
                    TopViewpoint {
                        index: v.index,
                        s: v.s,
                        position: v.position,
                        background: v.background.clone(),
                        table: obj,
                    }
                })
                .collect();
            all.push(bytes);
            TopTrack {
                name: t.name.clone(),
                track_toml: t.track_toml.clone(),
                length: t.length,
                viewpoints,
                segments: t.segments.iter().map(|s| (s.from, s.to)).collect(),
            }
        })
        .collect();
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
    (top, all)
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use tracks::Face;

    fn hex(n: usize, seed: u64) -> String {
        (0..n)
            .map(|i| {
                let d = (seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(i as u64)
                    >> 7)
                    % 16;
                char::from_digit(d as u32, 16).unwrap()
            })
            .collect()
    }

    prop_compose! {
        fn tile()(face in 0usize..6, tx in 0u32..64, ty in 0u32..64, slab in 0u32..4,
                  d0 in 0.0f64..1e4, dd in 0.0f64..1e4, opaque in any::<u32>(), kept in any::<bool>(),
                  seed in any::<u64>(), mesh in any::<bool>(), levels in 0usize..7,
                  sizes in proptest::collection::vec(1u64..5000, 7)) -> TileEntry {
            let mut offset = 0;
            let levels: Vec<LevelRef> = (0..levels).map(|l| {
                let len = sizes[l];
                let r = LevelRef { level: (levels - 1 - l) as u32, width: 1 << l, height: 1 << l,
                    offset, len, hash: hex(if l % 2 == 0 { 32 } else { 64 }, seed ^ l as u64) };
                offset += len;
                r
            }).collect();
            TileEntry {
                tile: TileId { face: Face::ALL[face], tx, ty },
                slab,
                depth_min: d0,
                depth_max: d0 + dd,
                opaque_pixels: opaque,
                kept,
                ptm: (!levels.is_empty()).then(|| PtmRef {
                    object: ObjectRef { hash: hex(64, seed), size: offset },
                    width: 1 << levels.len(),
                    height: 1 << levels.len(),
                    channels: 4,
                    levels,
                }),
                mesh: mesh.then(|| ObjectRef { hash: hex(64, !seed), size: seed % 9000 }),
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        #[test]
        fn tables_round_trip_exactly(viewpoint in 0usize..1000,
                                     tiles in proptest::collection::vec(tile(), 0..20),
                                     ach in proptest::collection::vec((0usize..1000, 0u32..4, 0.0f64..1.0), 0..20)) {
            let segments = vec![SegmentEntry {
                from: viewpoint,
                to: viewpoint + 1,
                ach: ach.iter().zip(&tiles).map(|(&(v, slab, a), t)| AchEntry {
                    viewpoint: v, slab, tile: t.tile, ach: a,
                }).collect(),
            }];
            let table = ViewTable { viewpoint, tiles, segments };
            let bytes = encode_table(&table);
            prop_assert_eq!(decode_table(&bytes, viewpoint).unwrap(), table);
            prop_assert!(decode_table(&bytes, viewpoint + 1).is_err());
        }

        #[test]
        fn damaged_table_bytes_are_rejected_or_decode_cleanly(
            tiles in proptest::collection::vec(tile(), 1..6),
            at in any::<usize>(), bit in 0u8..8) {
            let table = ViewTable { viewpoint: 3, tiles, segments: Vec::new() };
            let mut bytes = encode_table(&table);
            let i = at % bytes.len();
            bytes[i] ^= 1 << bit;
            // gzip's CRC catches a flipped bit in the body; the header's unprotected bytes may
            // still decode — to the same table. Never a panic.
            if let Ok(t) = decode_table(&bytes, 3) {
                prop_assert_eq!(t, table);
            }
        }
    }

    #[test]
    fn a_huge_table_is_refused_within_the_limit() {
        let zeros = vec![b' '; (MAX_TABLE_BYTES + 10) as usize];
        let gz = crate::db::gzip(&zeros).unwrap();
        assert!(matches!(
            decode_table(&gz, 0),
            Err(TableError::Gzip(crate::db::GunzipError::TooLarge { .. }))
        ));
    }
}
