//! The index in pieces (format 9): `manifest.json` is a small root, and the graph of tracks —
//! the viewpoints with their table and ACH references, each track's stops, the junctions —
//! lies in spatial chunks, content-addressed objects like every other, reached through a
//! quadtree of small node objects. A client reads the root and the chunks around the walker;
//! nothing needs the whole graph up front.
//!
//! ```text
//! manifest.json   RootManifest: scene, grid, slabs, culling; per track its name, curve
//!                 (TOML), length and number of stops; the numbers of viewpoints and
//!                 junctions; the index: origin (x, z), cell size (m), levels L and the
//!                 root node's reference
//! node  (object)  gzip of JSON Node {level, x, z, children: [ref or null; 4]}: level l
//!                 covers cells [x·2^l, (x+1)·2^l) × [z·2^l, (z+1)·2^l); its children
//!                 (2x + i, 2z + j) for i, j in 0..2, in the order (0,0), (1,0), (0,1), (1,1)
//!                 are nodes of level l − 1, or chunks at level 1; a child without
//!                 viewpoints is null. With L = 0 the root reference is the one chunk.
//! chunk (object)  gzip of JSON Chunk {x, z, viewpoints, stops, junctions}: the viewpoints
//!                 whose position lies in cell (x, z) (as the top manifest of format 8
//!                 listed them: id, position, table and ACH references), every stop of any
//!                 track at one of them (track, position k among the track's stops, viewpoint,
//!                 arc length), and the junctions at them
//! ```
//!
//! Cell (x, z) holds the positions with `origin.x + x·cell ≤ p.x < origin.x + (x+1)·cell`
//! and the same along z (y is up). The build chooses the origin at the smallest x and z of
//! any viewpoint, so cells count from 0, and [`DEFAULT_CELL_M`] as the cell size.
//!
//! Readers check every number against [`tracks::limits`] and this module's limits before
//! they allocate for it, every object against its hash, every chunk against its cell (a
//! viewpoint outside it, a stop of a viewpoint it does not hold, an id or stop given twice
//! are refused) and, once assembled ([`Assembly::finish`]), the whole graph as the top
//! manifest of format 8 was checked.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::manifest::ObjectRef;
use tracks::network::{Junction, Stop};
use tracks::SlabRange;

use crate::split::{TopManifest, TopTrack, TopViewpoint, TOP_VERSION};

/// Side of a chunk's cell, metres: about 200 viewpoints' references per chunk on a street
/// grid with a viewpoint a metre (BENCHMARKS.md, "The index in pieces").
pub const DEFAULT_CELL_M: f64 = 64.0;
/// Most levels of the quadtree (2^24 cells a side).
pub const MAX_LEVELS: u32 = 24;
/// Most bytes of a node or chunk object, and of its JSON once decompressed.
pub const MAX_PIECE_BYTES: u64 = 8 << 20;
/// Smallest and largest cell side, metres.
pub const MIN_CELL_M: f64 = 0.01;
pub const MAX_CELL_M: f64 = 1e6;

/// `manifest.json` of format 9.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RootManifest {
    pub version: u32,
    pub scene: String,
    pub face_size: u32,
    pub tile_size: u32,
    pub slabs: Vec<SlabRange>,
    pub cull_alpha: Option<f64>,
    pub cull_variant: Option<String>,
    /// Number of reference viewpoints (ids `0..viewpoints`).
    pub viewpoints: usize,
    /// The tracks: curves and lengths; their stops are in the chunks.
    pub tracks: Vec<RootTrack>,
    /// Number of junctions (each in the chunk of its viewpoint).
    pub junctions: usize,
    pub index: IndexRoot,
}

/// A track of the root: everything but its stops.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RootTrack {
    pub name: String,
    /// The track alone, as TOML (`TrackSet::to_toml`).
    pub track_toml: String,
    pub length: f64,
    /// Number of its stops (spread over the chunks).
    pub stops: usize,
}

/// Where the quadtree starts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IndexRoot {
    /// x and z of cell (0, 0)'s smaller corner, metres.
    pub origin: [f64; 2],
    /// Side of a cell, metres.
    pub cell: f64,
    /// Levels above the chunks: the root node covers 2^levels cells a side.
    pub levels: u32,
    /// The root node (a chunk when `levels` is 0); absent when there is no viewpoint.
    pub root: Option<ObjectRef>,
}

/// A node of the quadtree (an object).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Node {
    pub level: u32,
    pub x: u64,
    pub z: u64,
    pub children: [Option<ObjectRef>; 4],
}

/// A chunk: the graph in one cell (an object).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chunk {
    pub x: u64,
    pub z: u64,
    pub viewpoints: Vec<TopViewpoint>,
    pub stops: Vec<ChunkStop>,
    pub junctions: Vec<Junction>,
}

/// A stop of a track at a viewpoint of the chunk.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChunkStop {
    pub track: usize,
    /// Position among the track's stops.
    pub k: usize,
    pub viewpoint: usize,
    pub s: f64,
}

/// A piece of the index: which object, and what it should be.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct PieceAt {
    pub level: u32,
    pub x: u64,
    pub z: u64,
}

impl IndexRoot {
    /// The tree's top piece and where it lies (a chunk when `levels` is 0); `None` without
    /// viewpoints.
    pub fn root_piece(&self) -> Option<(PieceAt, ObjectRef)> {
        let at = PieceAt {
            level: self.levels,
            x: 0,
            z: 0,
        };
        self.root.clone().map(|r| (at, r))
    }

    /// The cell of a horizontal position (x, z), `None` outside the tree.
    pub fn cell_of(&self, x: f64, z: f64) -> Option<(u64, u64)> {
        let side = 1u64 << self.levels.min(MAX_LEVELS);
        let f = |v: f64, o: f64| {
            let c = ((v - o) / self.cell).floor();
            (c >= 0.0 && c < side as f64).then_some(c as u64)
        };
        Some((f(x, self.origin[0])?, f(z, self.origin[1])?))
    }

    /// The cells whose square comes within `radius` metres of (x, z), nearest first.
    pub fn cells_near(&self, x: f64, z: f64, radius: f64) -> Vec<(u64, u64)> {
        let side = 1u64 << self.levels.min(MAX_LEVELS);
        let (fx, fz) = (
            (x - self.origin[0]) / self.cell,
            (z - self.origin[1]) / self.cell,
        );
        let r = (radius.max(0.0) / self.cell).min(side as f64);
        let lo = |f: f64| (f - r).floor().clamp(0.0, (side - 1) as f64) as u64;
        let hi = |f: f64| (f + r).floor().clamp(0.0, (side - 1) as f64) as u64;
        let mut out = Vec::new();
        for cz in lo(fz)..=hi(fz) {
            for cx in lo(fx)..=hi(fx) {
                let dx = (fx - fx.clamp(cx as f64, cx as f64 + 1.0)) * self.cell;
                let dz = (fz - fz.clamp(cz as f64, cz as f64 + 1.0)) * self.cell;
                let d = dx.hypot(dz);
                if d <= radius {
                    out.push((d, cx, cz));
                }
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
        out.into_iter().map(|(_, x, z)| (x, z)).collect()
    }
}

impl RootManifest {
    /// Every number a reader sizes anything by, against [`tracks::limits`] and this module's
    /// limits; the message names the field.
    pub fn check_limits(&self) -> Result<(), String> {
        use tracks::limits::*;
        check_grid(self.face_size as u64, self.tile_size as u64).map_err(|e| e.to_string())?;
        let count = |name: &str, n: usize, max: usize| {
            check_u64(name, n as u64, 0, max as u64).map_err(|e| e.to_string())
        };
        count("slabs (count)", self.slabs.len(), MAX_SLABS)?;
        count("tracks (count)", self.tracks.len(), MAX_TRACKS)?;
        count("viewpoints", self.viewpoints, MAX_VIEWPOINTS)?;
        count("junctions", self.junctions, MAX_VIEWPOINTS)?;
        count("scene (bytes)", self.scene.len(), MAX_TEXT_BYTES)?;
        for (ti, t) in self.tracks.iter().enumerate() {
            count(&format!("tracks[{ti}].stops"), t.stops, MAX_VIEWPOINTS)?;
            count(
                &format!("tracks[{ti}].track_toml (bytes)"),
                t.track_toml.len(),
                MAX_TEXT_BYTES,
            )?;
        }
        let ix = &self.index;
        check_u64("index.levels", ix.levels as u64, 0, MAX_LEVELS as u64)
            .map_err(|e| e.to_string())?;
        check_f64("index.cell", ix.cell, MIN_CELL_M, MAX_CELL_M).map_err(|e| e.to_string())?;
        for (k, o) in ix.origin.iter().enumerate() {
            check_f64(
                &format!("index.origin[{k}]"),
                *o,
                -MAX_COORDINATE_M,
                MAX_COORDINATE_M,
            )
            .map_err(|e| e.to_string())?;
        }
        if ix.root.is_none() != (self.viewpoints == 0) {
            return Err(format!(
                "index.root: {} for {} viewpoints",
                if ix.root.is_none() { "absent" } else { "given" },
                self.viewpoints
            ));
        }
        Ok(())
    }
}

/// The root and every piece's bytes (nodes and chunks, each to be stored as an object) of a
/// top manifest, with cells of `cell` metres.
pub fn pieces(top: &TopManifest, cell: f64) -> Result<(RootManifest, Vec<Vec<u8>>), String> {
    if !(MIN_CELL_M..=MAX_CELL_M).contains(&cell) {
        return Err(format!(
            "cell size {cell} m: between {MIN_CELL_M} and {MAX_CELL_M}"
        ));
    }
    let (mut min_x, mut min_z) = (f64::INFINITY, f64::INFINITY);
    for v in &top.viewpoints {
        min_x = min_x.min(v.position.x);
        min_z = min_z.min(v.position.z);
    }
    let origin = if top.viewpoints.is_empty() {
        [0.0, 0.0]
    } else {
        [min_x, min_z]
    };
    let cell_xz = |p: DVec3| {
        (
            ((p.x - origin[0]) / cell).floor().max(0.0) as u64,
            ((p.z - origin[1]) / cell).floor().max(0.0) as u64,
        )
    };
    let mut chunks: BTreeMap<(u64, u64), Chunk> = BTreeMap::new();
    for v in &top.viewpoints {
        let (x, z) = cell_xz(v.position);
        chunks
            .entry((x, z))
            .or_insert_with(|| Chunk {
                x,
                z,
                viewpoints: Vec::new(),
                stops: Vec::new(),
                junctions: Vec::new(),
            })
            .viewpoints
            .push(v.clone());
    }
    let at = |vi: usize| cell_xz(top.viewpoints[vi].position);
    for (ti, t) in top.tracks.iter().enumerate() {
        for (k, st) in t.stops.iter().enumerate() {
            if let Some(c) = chunks.get_mut(&at(st.viewpoint)) {
                c.stops.push(ChunkStop {
                    track: ti,
                    k,
                    viewpoint: st.viewpoint,
                    s: st.s,
                });
            }
        }
    }
    for j in &top.junctions {
        if let Some(c) = chunks.get_mut(&at(j.viewpoint)) {
            c.junctions.push(j.clone());
        }
    }
    let side = chunks.keys().map(|&(x, z)| x.max(z) + 1).max().unwrap_or(1);
    let levels = side.next_power_of_two().trailing_zeros();
    if levels > MAX_LEVELS {
        return Err(format!(
            "{side} cells of {cell} m a side: at most 2^{MAX_LEVELS}"
        ));
    }
    let mut objects = Vec::new();
    let mut put = |bytes: Vec<u8>| {
        let r = ObjectRef {
            hash: crate::hash_hex(&bytes),
            size: bytes.len() as u64,
        };
        objects.push(bytes);
        r
    };
    // Level by level from the chunks up: each level's refs by cell.
    let mut refs: BTreeMap<(u64, u64), ObjectRef> = BTreeMap::new();
    for (key, c) in &chunks {
        refs.insert(*key, put(encode_piece(c)?));
    }
    for level in 1..=levels {
        let mut up: BTreeMap<(u64, u64), [Option<ObjectRef>; 4]> = BTreeMap::new();
        for ((x, z), r) in refs {
            let slot = (x % 2 + 2 * (z % 2)) as usize;
            up.entry((x / 2, z / 2)).or_default()[slot] = Some(r);
        }
        refs = BTreeMap::new();
        for ((x, z), children) in up {
            let node = Node {
                level,
                x,
                z,
                children,
            };
            refs.insert((x, z), put(encode_piece(&node)?));
        }
    }
    let root = RootManifest {
        version: TOP_VERSION,
        scene: top.scene.clone(),
        face_size: top.face_size,
        tile_size: top.tile_size,
        slabs: top.slabs.clone(),
        cull_alpha: top.cull_alpha,
        cull_variant: top.cull_variant.clone(),
        viewpoints: top.viewpoints.len(),
        tracks: top
            .tracks
            .iter()
            .map(|t| RootTrack {
                name: t.name.clone(),
                track_toml: t.track_toml.clone(),
                length: t.length,
                stops: t.stops.len(),
            })
            .collect(),
        junctions: top.junctions.len(),
        index: IndexRoot {
            origin,
            cell,
            levels,
            root: refs.into_values().next(),
        },
    };
    Ok((root, objects))
}

/// A piece's bytes: gzip of its compact JSON (deterministic: the same piece, the same bytes).
fn encode_piece<T: Serialize>(piece: &T) -> Result<Vec<u8>, String> {
    let json = serde_json::to_vec(piece).map_err(|e| e.to_string())?;
    crate::gzip(&json).map_err(|e| e.to_string())
}

fn decode_piece<T: for<'de> Deserialize<'de>>(bytes: &[u8]) -> Result<T, String> {
    if bytes.len() as u64 > MAX_PIECE_BYTES {
        return Err(format!(
            "{} bytes; a piece of the index is at most {MAX_PIECE_BYTES}",
            bytes.len()
        ));
    }
    let json = crate::gunzip_limited(bytes, MAX_PIECE_BYTES).map_err(|e| e.to_string())?;
    serde_json::from_slice(&json).map_err(|e| format!("line {}: {e}", e.line()))
}

/// Decodes node bytes expected at `at` (level ≥ 1) and checks them against it.
pub fn decode_node(bytes: &[u8], at: &PieceAt) -> Result<Node, String> {
    let n: Node = decode_piece(bytes)?;
    if (n.level, n.x, n.z) != (at.level, at.x, at.z) {
        return Err(format!(
            "node says level {} ({}, {}) where the tree has level {} ({}, {})",
            n.level, n.x, n.z, at.level, at.x, at.z
        ));
    }
    if n.children.iter().all(Option::is_none) {
        return Err("node has no child (empty nodes are left out)".into());
    }
    Ok(n)
}

impl Node {
    /// The children that are there, with where each lies.
    pub fn children_at(&self) -> impl Iterator<Item = (PieceAt, &ObjectRef)> {
        self.children.iter().enumerate().filter_map(|(i, c)| {
            let r = c.as_ref()?;
            Some((
                PieceAt {
                    level: self.level - 1,
                    x: 2 * self.x + (i as u64 % 2),
                    z: 2 * self.z + (i as u64 / 2),
                },
                r,
            ))
        })
    }
}

/// Decodes chunk bytes expected at cell `at` (level 0) and checks what can be checked alone:
/// its cell, every viewpoint inside it, every stop at one of its viewpoints, every junction at
/// one of them, ids and tracks within the root's counts.
pub fn decode_chunk(bytes: &[u8], at: &PieceAt, root: &RootManifest) -> Result<Chunk, String> {
    let c: Chunk = decode_piece(bytes)?;
    if (at.level, c.x, c.z) != (0, at.x, at.z) {
        return Err(format!(
            "chunk says cell ({}, {}) where the tree has level {} ({}, {})",
            c.x, c.z, at.level, at.x, at.z
        ));
    }
    if c.viewpoints.is_empty() {
        return Err("chunk has no viewpoint (empty chunks are left out)".into());
    }
    let mut here = std::collections::HashSet::new();
    for (k, v) in c.viewpoints.iter().enumerate() {
        if v.index >= root.viewpoints {
            return Err(format!(
                "viewpoints[{k}].index = {}: there are {} viewpoints",
                v.index, root.viewpoints
            ));
        }
        let p = v.position;
        if root.index.cell_of(p.x, p.z) != Some((c.x, c.z)) {
            return Err(format!(
                "viewpoints[{k}] (id {}) at {p} lies outside cell ({}, {})",
                v.index, c.x, c.z
            ));
        }
        if !here.insert(v.index) {
            return Err(format!("viewpoints[{k}]: id {} given twice", v.index));
        }
    }
    for (k, st) in c.stops.iter().enumerate() {
        let Some(t) = root.tracks.get(st.track) else {
            return Err(format!(
                "stops[{k}].track = {}: there are {} tracks",
                st.track,
                root.tracks.len()
            ));
        };
        if st.k >= t.stops {
            return Err(format!(
                "stops[{k}].k = {}: track {} has {} stops",
                st.k, st.track, t.stops
            ));
        }
        if !here.contains(&st.viewpoint) {
            return Err(format!(
                "stops[{k}].viewpoint = {} is not a viewpoint of this chunk",
                st.viewpoint
            ));
        }
    }
    for (k, j) in c.junctions.iter().enumerate() {
        if !here.contains(&j.viewpoint) {
            return Err(format!(
                "junctions[{k}].viewpoint = {} is not a viewpoint of this chunk",
                j.viewpoint
            ));
        }
    }
    Ok(c)
}

/// The top manifest put together from the root and its chunks, as they arrive.
#[derive(Debug)]
pub struct Assembly {
    root: RootManifest,
    viewpoints: Vec<Option<TopViewpoint>>,
    stops: Vec<Vec<Option<Stop>>>,
    junctions: Vec<Junction>,
}

impl Assembly {
    /// An empty assembly for `root` (call after [`RootManifest::check_limits`]: the sizes
    /// here are the root's counts).
    pub fn new(root: RootManifest) -> Assembly {
        Assembly {
            viewpoints: vec![None; root.viewpoints],
            stops: root.tracks.iter().map(|t| vec![None; t.stops]).collect(),
            junctions: Vec::new(),
            root,
        }
    }

    /// Adds a decoded chunk ([`decode_chunk`]); an id or stop some earlier chunk gave is
    /// refused.
    pub fn add(&mut self, c: Chunk) -> Result<(), String> {
        for v in c.viewpoints {
            let slot = &mut self.viewpoints[v.index];
            if slot.is_some() {
                return Err(format!("viewpoint {} is in two chunks", v.index));
            }
            *slot = Some(v);
        }
        for st in c.stops {
            let slot = &mut self.stops[st.track][st.k];
            if slot.is_some() {
                return Err(format!(
                    "stop {} of track {} is in two chunks",
                    st.k, st.track
                ));
            }
            *slot = Some(Stop {
                viewpoint: st.viewpoint,
                s: st.s,
            });
        }
        self.junctions.extend(c.junctions);
        Ok(())
    }

    /// The whole top manifest, once every chunk has been added: every viewpoint, stop and
    /// junction present, then checked as a top manifest of format 8 was (limits, the graph).
    pub fn finish(self) -> Result<TopManifest, String> {
        let r = self.root;
        let viewpoints = self
            .viewpoints
            .into_iter()
            .enumerate()
            .map(|(i, v)| v.ok_or_else(|| format!("viewpoint {i} is in no chunk")))
            .collect::<Result<Vec<_>, _>>()?;
        let mut tracks = Vec::with_capacity(r.tracks.len());
        for ((ti, t), stops) in r.tracks.into_iter().enumerate().zip(self.stops) {
            let stops = stops
                .into_iter()
                .enumerate()
                .map(|(k, s)| s.ok_or_else(|| format!("stop {k} of track {ti} is in no chunk")))
                .collect::<Result<Vec<_>, _>>()?;
            tracks.push(TopTrack {
                name: t.name,
                track_toml: t.track_toml,
                length: t.length,
                stops,
            });
        }
        let mut junctions = self.junctions;
        if junctions.len() != r.junctions {
            return Err(format!(
                "the chunks hold {} junctions, the root says {}",
                junctions.len(),
                r.junctions
            ));
        }
        junctions.sort_by_key(|j| j.viewpoint);
        let top = TopManifest {
            version: r.version,
            scene: r.scene,
            face_size: r.face_size,
            tile_size: r.tile_size,
            slabs: r.slabs,
            cull_alpha: r.cull_alpha,
            cull_variant: r.cull_variant,
            viewpoints,
            tracks,
            junctions,
        };
        top.check_limits()?;
        top.network()
            .map_err(|e| format!("the graph of tracks: {e}"))?;
        Ok(top)
    }
}

/// A walk through the whole index, for a reader that fetches its own way (sync or async):
/// [`TreeWalk::next_batch`] names the pieces to fetch, [`TreeWalk::give`] takes its bytes (checked
/// against its hash by the caller), [`TreeWalk::finish`] gives the top manifest.
#[derive(Debug)]
pub struct TreeWalk {
    todo: Vec<(PieceAt, ObjectRef)>,
    asm: Assembly,
    pieces: usize,
    limit: usize,
}

impl TreeWalk {
    pub fn new(root: RootManifest) -> TreeWalk {
        let todo = root.index.root_piece().into_iter().collect();
        // A tree over at most one chunk per viewpoint has at most as many nodes per level.
        let limit = (MAX_LEVELS as usize + 1) * root.viewpoints.max(1);
        TreeWalk {
            todo,
            asm: Assembly::new(root),
            pieces: 0,
            limit,
        }
    }

    /// The pieces to fetch next (they may be fetched at the same time), none when done.
    pub fn next_batch(&mut self) -> Vec<(PieceAt, ObjectRef)> {
        std::mem::take(&mut self.todo)
    }

    /// The bytes of a piece [`TreeWalk::next_batch`] named; the error names the piece.
    pub fn give(&mut self, at: &PieceAt, r: &ObjectRef, bytes: &[u8]) -> Result<(), String> {
        let name = |e: String| {
            format!(
                "index piece level {} ({}, {}) (object {}): {e}",
                at.level, at.x, at.z, r.hash
            )
        };
        self.pieces += 1;
        if self.pieces > self.limit {
            return Err(name(
                "the index has more pieces than its viewpoints allow".into(),
            ));
        }
        if at.level == 0 {
            let c = decode_chunk(bytes, at, &self.asm.root).map_err(name)?;
            self.asm.add(c).map_err(name)
        } else {
            let node = decode_node(bytes, at).map_err(name)?;
            self.todo
                .extend(node.children_at().map(|(a, c)| (a, c.clone())));
            Ok(())
        }
    }

    /// Pieces given so far.
    pub fn pieces(&self) -> usize {
        self.pieces
    }

    pub fn finish(self) -> Result<TopManifest, String> {
        self.asm.finish()
    }
}

/// Reads the whole index through `fetch` (an object's bytes, hash-checked by the caller):
/// the tree level by level, every chunk, assembled into the top manifest. Errors name the
/// piece.
pub fn read_all<E: std::fmt::Display>(
    root: RootManifest,
    mut fetch: impl FnMut(&ObjectRef) -> Result<Vec<u8>, E>,
) -> Result<TopManifest, String> {
    let mut walk = TreeWalk::new(root);
    loop {
        let batch = walk.next_batch();
        if batch.is_empty() {
            return walk.finish();
        }
        for (at, r) in batch {
            let bytes = fetch(&r).map_err(|e| {
                format!(
                    "index piece level {} ({}, {}) (object {}): {e}",
                    at.level, at.x, at.z, r.hash
                )
            })?;
            walk.give(&at, &r, &bytes)?;
        }
    }
}

/// Parses root bytes (format 9) and checks its limits.
pub fn parse_root(bytes: &[u8]) -> Result<RootManifest, String> {
    let root: RootManifest =
        serde_json::from_slice(bytes).map_err(|e| format!("line {}: {e}", e.line()))?;
    root.check_limits()
        .map_err(|e| format!("{e} (limits of this build)"))?;
    Ok(root)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::network::Network;
    use tracks::TrackSet;

    /// A top manifest of a grid of streets `n` × `n` blocks of `block` metres, viewpoints
    /// every 2 m, with made-up table references.
    fn streets(n: usize, block: f64) -> TopManifest {
        let mut text = String::new();
        for k in 0..=n {
            let c = k as f64 * block;
            let pts = |a: [f64; 2]| {
                (0..=n)
                    .map(|i| {
                        let t = i as f64 * block;
                        let (x, z) = if a[0] < 0.0 { (t, c) } else { (c, t) };
                        format!("[{x}, 1.7, {z}]")
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            text.push_str(&format!(
                "[[track]]\nname = \"ew-{k}\"\npoints = [{}]\nspacing = 2.0\n\
                 [[track]]\nname = \"ns-{k}\"\npoints = [{}]\nspacing = 2.0\n",
                pts([-1.0, 0.0]),
                pts([1.0, 0.0])
            ));
        }
        let set = TrackSet::parse(&text, "grid.toml").unwrap();
        let net = Network::new(set.tracks.clone()).unwrap();
        let obj = |k: usize| ObjectRef {
            hash: crate::hash_hex(&k.to_le_bytes()),
            size: 100 + k as u64,
        };
        let tracks = set
            .tracks
            .iter()
            .zip(&net.stops)
            .map(|(t, stops)| TopTrack {
                name: t.name.clone(),
                track_toml: TrackSet {
                    tracks: vec![t.clone()],
                }
                .to_toml(),
                length: t.length(),
                stops: stops.clone(),
            })
            .collect();
        TopManifest {
            version: TOP_VERSION,
            scene: "grid".into(),
            face_size: 16,
            tile_size: 16,
            slabs: vec![SlabRange::new(0.0, 1e9).unwrap()],
            cull_alpha: None,
            cull_variant: None,
            viewpoints: net
                .viewpoints
                .iter()
                .enumerate()
                .map(|(i, &position)| TopViewpoint {
                    index: i,
                    position,
                    table: obj(2 * i),
                    ach: (i % 3 != 0).then(|| obj(2 * i + 1)),
                })
                .collect(),
            tracks,
            junctions: net.junctions.clone(),
        }
    }

    /// The pieces of `top` as a store by hash.
    fn store(pieces: &[Vec<u8>]) -> std::collections::HashMap<String, Vec<u8>> {
        pieces
            .iter()
            .map(|b| (crate::hash_hex(b), b.clone()))
            .collect()
    }

    #[test]
    fn a_grid_of_streets_comes_back_whole_from_its_pieces() {
        let top = streets(3, 40.0);
        for cell in [8.0, 30.0, 64.0, 1000.0] {
            let (root, pieces) = pieces(&top, cell).unwrap();
            root.check_limits().unwrap();
            let objects = store(&pieces);
            let back = read_all(root.clone(), |r: &ObjectRef| {
                objects.get(&r.hash).cloned().ok_or("missing")
            })
            .unwrap();
            assert_eq!(back, top, "cells of {cell} m");
            // The same top, the same bytes.
            assert_eq!(super::pieces(&top, cell).unwrap(), (root, pieces));
        }
        let (root, _) = pieces(&top, 1000.0).unwrap();
        assert_eq!(root.index.levels, 0);
    }

    #[test]
    fn cells_near_are_the_ones_within_the_radius_nearest_first() {
        let top = streets(3, 40.0);
        let (root, _) = pieces(&top, 30.0).unwrap();
        let ix = &root.index;
        // 0..120 m in cells of 30 m: five a side, in a tree of 8.
        assert_eq!(ix.levels, 3);
        assert_eq!(ix.cell_of(1.0, 1.0), Some((0, 0)));
        assert_eq!(ix.cell_of(-1.0, 1.0), None);
        let near = ix.cells_near(31.0, 1.0, 0.5);
        assert_eq!(near, vec![(1, 0)]);
        let near = ix.cells_near(31.0, 1.0, 2.0);
        assert_eq!(near[0], (1, 0));
        assert!(near.contains(&(0, 0)) && near.len() == 2, "{near:?}");
        assert_eq!(ix.cells_near(45.0, 45.0, 1000.0).len(), 64);
        assert_eq!(ix.cells_near(45.0, 45.0, 1000.0)[0], (1, 1));
    }

    #[test]
    fn a_chunk_that_lies_about_its_cell_or_ids_is_refused() {
        let top = streets(2, 40.0);
        let (root, pieces) = pieces(&top, 30.0).unwrap();
        let objects = store(&pieces);
        // Find a chunk and its place through the tree.
        let mut todo = vec![(
            PieceAt {
                level: root.index.levels,
                x: 0,
                z: 0,
            },
            root.index.root.clone().unwrap(),
        )];
        let (at, bytes) = loop {
            let (at, r) = todo.pop().unwrap();
            let b = objects[&r.hash].clone();
            if at.level == 0 {
                break (at, b);
            }
            let n = decode_node(&b, &at).unwrap();
            todo.extend(n.children_at().map(|(a, c)| (a, c.clone())));
        };
        let good = decode_chunk(&bytes, &at, &root).unwrap();
        let enc = |c: &Chunk| encode_piece(c).unwrap();
        let mut moved = good.clone();
        moved.viewpoints[0].position.x += 1000.0;
        let e = decode_chunk(&enc(&moved), &at, &root).unwrap_err();
        assert!(e.contains("outside cell"), "{e}");
        let mut twice = good.clone();
        twice.viewpoints.push(twice.viewpoints[0].clone());
        let e = decode_chunk(&enc(&twice), &at, &root).unwrap_err();
        assert!(e.contains("twice"), "{e}");
        let mut far = good.clone();
        far.viewpoints[0].index = root.viewpoints;
        let e = decode_chunk(&enc(&far), &at, &root).unwrap_err();
        assert!(e.contains("there are"), "{e}");
        let mut stray = good.clone();
        stray.stops[0].viewpoint = usize::MAX;
        let e = decode_chunk(&enc(&stray), &at, &root).unwrap_err();
        assert!(e.contains("not a viewpoint of this chunk"), "{e}");
        let mut k = good.clone();
        k.stops[0].k = 1 << 40;
        let e = decode_chunk(&enc(&k), &at, &root).unwrap_err();
        assert!(e.contains("stops"), "{e}");
        let e = decode_chunk(&bytes[..bytes.len() / 2], &at, &root).unwrap_err();
        assert!(!e.is_empty());
        let wrong = PieceAt { x: at.x + 1, ..at };
        assert!(decode_chunk(&bytes, &wrong, &root).is_err());
    }

    #[test]
    fn a_missing_chunk_or_a_root_that_oversizes_is_an_error() {
        let top = streets(2, 40.0);
        let (root, pieces) = pieces(&top, 30.0).unwrap();
        let mut objects = store(&pieces);
        // Drop one chunk: the node that names it fails to fetch it, and says where.
        let chunk = pieces
            .iter()
            .find(|b| {
                let j = crate::gunzip_limited(b, MAX_PIECE_BYTES).unwrap();
                j.starts_with(b"{\"x\"")
            })
            .unwrap();
        objects.remove(&crate::hash_hex(chunk));
        let e = read_all(root.clone(), |r: &ObjectRef| {
            objects.get(&r.hash).cloned().ok_or("missing")
        })
        .unwrap_err();
        assert!(e.contains("level 0") && e.contains("missing"), "{e}");
        let mut big = root.clone();
        big.viewpoints = usize::MAX;
        assert!(big.check_limits().unwrap_err().contains("viewpoints"));
        let mut deep = root.clone();
        deep.index.levels = 63;
        assert!(deep.check_limits().unwrap_err().contains("levels"));
        let mut cell = root;
        cell.index.cell = f64::NAN;
        assert!(cell.check_limits().unwrap_err().contains("cell"));
    }

    proptest::proptest! {
        /// Pieces with any byte changed, cut short or made of noise are refused or read as
        /// what they say, never a panic; the tree as a whole then still comes back or fails
        /// with a message.
        #[test]
        fn damaged_pieces_never_panic(
            which in 0usize..64,
            at in 0usize..4096,
            flip in 1u8..=255,
            cut in proptest::prelude::any::<bool>(),
            noise in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..256),
        ) {
            let top = streets(2, 40.0);
            let (root, mut pieces) = pieces(&top, 30.0).unwrap();
            let k = which % pieces.len();
            let p = &mut pieces[k];
            if cut {
                let n = at % p.len();
                p.truncate(n);
            } else {
                let n = at % p.len();
                p[n] ^= flip;
            }
            let plain = PieceAt { level: 0, x: 0, z: 0 };
            let _ = decode_chunk(&pieces[k], &plain, &root);
            let _ = decode_node(&pieces[k], &PieceAt { level: 1, ..plain.clone() });
            let _ = decode_chunk(&noise, &plain, &root);
            let _ = decode_chunk(&crate::gzip(&noise).unwrap(), &plain, &root);
            // The damaged piece served under its original name: the walk names it or reads it.
            let objects: std::collections::HashMap<String, Vec<u8>> = super::pieces(&top, 30.0)
                .unwrap()
                .1
                .iter()
                .map(|b| crate::hash_hex(b))
                .zip(pieces.iter().cloned())
                .collect();
            let _ = read_all(root, |r: &ObjectRef| objects.get(&r.hash).cloned().ok_or("missing"));
        }
    }

    #[test]
    fn an_empty_network_has_no_index_root() {
        let mut top = streets(1, 10.0);
        top.viewpoints.clear();
        top.tracks.clear();
        top.junctions.clear();
        let (root, pieces) = pieces(&top, 64.0).unwrap();
        assert!(pieces.is_empty() && root.index.root.is_none());
        root.check_limits().unwrap();
    }
}
