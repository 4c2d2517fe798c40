//! A small synthetic database for tests and benchmarks of streaming: a straight corridor
//! (walls at `x = ±half_width`, a floor at `y = 0`, far buildings beyond `far_m`, sky
//! above) seen from viewpoints along a track, with PTM-shaped objects of pseudo-random bytes
//! (incompressible, so byte counts are honest) and ACH from the CPU visibility reference;
//! optionally ([`SynthParams::backgrounds`]) a background tile wherever a tile sees sky.
//! It writes only the manifest and the objects — what a server needs.

use std::io;
use std::path::Path;

use glam::DVec3;
use tracks::cubemap::subpixel_dir;
use tracks::manifest::{
    object_rel_path, AchEntry, BackgroundTile, LevelRef, Manifest, ObjectRef, PtmRef, SegmentEntry,
    TileEntry, TrackEntry, ViewpointEntry, MANIFEST_VERSION,
};
use tracks::{PerspectiveCamera, SlabRange, TileGrid, TrackSet};

use crate::visibility::{blend_weights, SceneIndex, Surface};

/// Shape of the synthetic database.
#[derive(Clone, Debug)]
pub struct SynthParams {
    pub length_m: f64,
    pub spacing_m: f64,
    pub face_size: u32,
    pub tile_size: u32,
    /// Coarsest PTM level is `tile_size >> (levels − 1)` pixels wide.
    pub levels: u32,
    pub half_width_m: f64,
    /// Slab boundary: surfaces nearer are slab 0.
    pub slab_split_m: f64,
    /// Stored bytes per decoded texel (a stand-in for the codec's ratio).
    pub bytes_per_texel: f64,
    pub seed: u64,
    /// Give every tile that sees some sky a background tile (a PTM of the same shape).
    pub backgrounds: bool,
}

impl SynthParams {
    /// The default database at faces of `face_size` px along `length_m`: tiles of a quarter
    /// face (a power of two), as many PTM levels as that allows (1 to 4).
    pub fn for_face(face_size: u32, length_m: f64) -> SynthParams {
        let quarter = (face_size / 4).max(1);
        SynthParams {
            face_size,
            tile_size: 1 << quarter.ilog2(),
            levels: quarter.ilog2().saturating_sub(1).clamp(1, 4),
            length_m,
            ..SynthParams::default()
        }
    }
}

impl Default for SynthParams {
    fn default() -> Self {
        SynthParams {
            length_m: 12.0,
            spacing_m: 4.0,
            face_size: 64,
            tile_size: 16,
            levels: 3,
            half_width_m: 3.0,
            slab_split_m: 8.0,
            bytes_per_texel: 1.5,
            seed: 7,
            backgrounds: false,
        }
    }
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| (self.next() >> 32) as u8).collect()
    }
}

fn put(root: &Path, data: &[u8]) -> io::Result<ObjectRef> {
    let hash = blake3::hash(data).to_hex().to_string();
    let rel = object_rel_path(&hash).ok_or_else(|| io::Error::other("bad hash"))?;
    let path = root.join(rel);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&path, data)?;
    Ok(ObjectRef {
        hash,
        size: data.len() as u64,
    })
}

/// Distance from `o` along unit `d` to the corridor (walls, floor, far buildings), if any.
fn corridor_hit(o: DVec3, d: DVec3, half_width: f64) -> Option<f64> {
    let mut best = f64::INFINITY;
    if d.x.abs() > 1e-9 {
        let t = ((half_width * d.x.signum()) - o.x) / d.x;
        // Walls are 6 m high; above them buildings stand 30 m away.
        if t > 0.0 && o.y + t * d.y <= 6.0 {
            best = best.min(t);
        }
    }
    if d.y < -1e-9 {
        best = best.min(-o.y / d.y);
    }
    if d.y < 0.6 && best.is_infinite() {
        best = 30.0 / d.y.abs().clamp(0.3, 1.0);
    }
    best.is_finite().then_some(best)
}

/// A PTM-shaped object of pseudo-random bytes for a `side × side` tile: a header, then the
/// levels coarse to fine at `p.bytes_per_texel`; the object and its level references.
fn ptm_blob(rng: &mut Rng, side: u32, p: &SynthParams) -> (Vec<u8>, Vec<LevelRef>) {
    let mut levels = Vec::new();
    let mut blob = rng.bytes(16); // header
    for l in (0..p.levels).rev() {
        let w = (side >> l).max(1);
        let n = ((w * w * 4) as f64 * p.bytes_per_texel / 4.0)
            .ceil()
            .max(1.0) as usize;
        let offset = if levels.is_empty() {
            0
        } else {
            blob.len() as u64
        };
        blob.extend(rng.bytes(n));
        let len = blob.len() as u64 - offset;
        let hash = blake3::hash(&blob[offset as usize..]).to_hex().to_string();
        levels.push(LevelRef {
            level: l,
            width: w,
            height: w,
            offset,
            len,
            hash,
        });
    }
    (blob, levels)
}

/// Write a synthetic database to `root` (created) and return its manifest.
pub fn write_synthetic(root: &Path, p: &SynthParams) -> io::Result<Manifest> {
    let bad = |m: String| io::Error::new(io::ErrorKind::InvalidInput, m);
    let grid = TileGrid::new(p.face_size, p.tile_size)
        .ok_or_else(|| bad("tile size must be a power of two".into()))?;
    let toml = format!(
        "[[track]]\nname = \"corridor\"\npoints = [[0, 1.7, 0], [0, 1.7, {}]]\nspacing = {}\n",
        -p.length_m, p.spacing_m
    );
    let set = TrackSet::parse(&toml, "synthetic").map_err(|e| bad(e.to_string()))?;
    let track = set.tracks[0].clone();
    let mut rng = Rng(p.seed.max(1));
    std::fs::create_dir_all(root)?;
    let mut viewpoints = Vec::new();
    for vp in track.viewpoints() {
        let mut tiles = Vec::new();
        let mut background = Vec::new();
        for tile in grid.tiles() {
            let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
            // Depth range from a 3×3 probe of the tile.
            let mut dmin = f64::INFINITY;
            let mut dmax: f64 = 0.0;
            let mut hits = 0u32;
            for a in 0..3 {
                for b in 0..3 {
                    let x = x0 as f64 + (x1 - x0) as f64 * (a as f64 + 0.5) / 3.0;
                    let y = y0 as f64 + (y1 - y0) as f64 * (b as f64 + 0.5) / 3.0;
                    let d = subpixel_dir(tile.face, x, y, p.face_size);
                    if let Some(t) = corridor_hit(vp.position, d, p.half_width_m) {
                        dmin = dmin.min(t);
                        dmax = dmax.max(t);
                        hits += 1;
                    }
                }
            }
            let side = x1 - x0;
            if p.backgrounds && hits < 9 {
                let (blob, levels) = ptm_blob(&mut rng, side, p);
                background.push(BackgroundTile {
                    tile,
                    ptm: PtmRef {
                        object: put(root, &blob)?,
                        width: side,
                        height: side,
                        channels: 4,
                        levels,
                    },
                });
            }
            if hits == 0 {
                continue;
            }
            let slab = u32::from(dmin >= p.slab_split_m);
            let (blob, levels) = ptm_blob(&mut rng, side, p);
            let object = put(root, &blob)?;
            let mesh_len = 48 + (rng.next() % 32) as usize;
            let mesh = put(root, &rng.bytes(mesh_len))?;
            let opaque = (side * side) * hits / 9;
            tiles.push(TileEntry {
                tile,
                slab,
                depth_min: dmin,
                depth_max: dmax,
                opaque_pixels: opaque,
                kept: true,
                ptm: Some(PtmRef {
                    object,
                    width: side,
                    height: side,
                    channels: 4,
                    levels,
                }),
                mesh: Some(mesh),
                mesh_range: None,
            });
        }
        viewpoints.push(ViewpointEntry {
            index: vp.index,
            s: vp.s,
            position: vp.position,
            background,
            tiles,
        });
    }
    let mut manifest = Manifest {
        version: MANIFEST_VERSION,
        scene: "synthetic-corridor".into(),
        face_size: p.face_size,
        tile_size: p.tile_size,
        slabs: vec![
            SlabRange::new(0.0, p.slab_split_m).ok_or_else(|| bad("slab split".into()))?,
            SlabRange::new(p.slab_split_m, f64::INFINITY).ok_or_else(|| bad("slab".into()))?,
        ],
        cull_alpha: None,
        cull_variant: None,
        tracks: vec![TrackEntry {
            name: track.name.clone(),
            track_toml: set.to_toml(),
            length: track.length(),
            viewpoints,
            segments: Vec::new(),
        }],
    };
    manifest.tracks[0].segments = synthetic_ach(&manifest, &track);
    // The database writer's manifest files (compact JSON, checksum, gzip copy), so a
    // synthetic database streams like a built one.
    // The tiles are packed per viewpoint: what comes back is the manifest a reader sees.
    db::DbWriter::create(root)
        .and_then(|mut w| w.finish(&manifest))
        .map_err(io::Error::other)
}

/// ACH per segment: pixels per tile over the six 90° cameras of the rendering box at five
/// positions along the segment (ends included), normalised to sum to 1, descending.
fn synthetic_ach(m: &Manifest, track: &tracks::Track) -> Vec<SegmentEntry> {
    let Some(index) = SceneIndex::new(m) else {
        return Vec::new();
    };
    let t = &m.tracks[0];
    let vp_s: Vec<f64> = t.viewpoints.iter().map(|v| v.s).collect();
    let mut out = Vec::new();
    for i in 0..t.viewpoints.len().saturating_sub(1) {
        let mut px: std::collections::HashMap<usize, (usize, f64)> = Default::default();
        for k in 0..=4 {
            let s = vp_s[i] + (vp_s[i + 1] - vp_s[i]) * k as f64 / 4.0;
            let weights = blend_weights(&vp_s, s);
            for (yaw, pitch) in [
                (0.0, 0.0),
                (90.0, 0.0),
                (180.0, 0.0),
                (270.0, 0.0),
                (0.0, 89.9),
                (0.0, -89.9),
            ] {
                let cam = PerspectiveCamera {
                    position: track.position_at(s),
                    yaw_deg: yaw,
                    pitch_deg: pitch,
                    fov_deg: 90.0,
                    width: 32,
                    height: 32,
                };
                for c in index.count(&cam, &weights, 32, 32) {
                    if let Surface::Tile { viewpoint, tile } = c.surface {
                        let e = px
                            .entry(viewpoint * 1_000_000 + tile)
                            .or_insert((viewpoint, 0.0));
                        e.0 = viewpoint;
                        e.1 += c.pixels();
                    }
                }
            }
        }
        let total: f64 = px.values().map(|v| v.1).sum();
        let mut ach: Vec<AchEntry> = px
            .iter()
            .map(|(&key, &(vi, n))| {
                let tile = &t.viewpoints[vi].tiles[key % 1_000_000];
                AchEntry {
                    viewpoint: t.viewpoints[vi].index,
                    slab: tile.slab,
                    tile: tile.tile,
                    ach: n / total.max(f64::MIN_POSITIVE),
                }
            })
            .collect();
        ach.sort_by(|a, b| {
            b.ach
                .total_cmp(&a.ach)
                .then_with(|| (a.viewpoint, a.slab, a.tile).cmp(&(b.viewpoint, b.slab, b.tile)))
        });
        out.push(SegmentEntry {
            from: t.viewpoints[i].index,
            to: t.viewpoints[i + 1].index,
            ach,
        });
    }
    out
}
