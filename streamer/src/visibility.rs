//! CPU reference of the viewer's tile-visibility pass: which tiles (and backgrounds) cover the
//! pixels of a camera, how many pixels each covers, and which PTM level those pixels need.
//!
//! [`SceneIndex`] indexes the viewpoints of a manifest (per viewpoint, by id, per slab, a dense
//! tile table). [`SceneIndex::count`] casts one ray per sample of the camera image and, for each
//! given reference viewpoint (the two ends of the current segment, with their blend weights),
//! finds what that viewpoint's layers show along the ray:
//!
//! 1. the ray is marched from the camera in geometric steps (48, out to 1.5× the farthest tile
//!    depth); at each step, the direction viewpoint → step midpoint picks a tile per slab
//!    (front to back), and the tile is hit when the step's range of distances from the
//!    viewpoint overlaps the tile's `[depth_min, depth_max]` — so parallax between camera and
//!    viewpoint is followed and thin depth ranges cannot be stepped over (steps nearer than
//!    every tile look nothing up, and the march stops once a step lies beyond every tile);
//! 2. the first step with a hit wins (lower slab first within a step); no hit means the
//!    sample shows the viewpoint's background tile in the ray's direction (the sky lies at
//!    infinity), or a disocclusion hole where the viewpoint has no background tile;
//! 3. the needed level: a screen pixel spans `α_c = 2·tan(fov/2)/width` radians at distance
//!    `d_c` from the camera, a level-0 texel spans about `α_v = 2/face_size` at distance `d_v`
//!    from the viewpoint; level `l` is enough while `2^l · α_v · d_v ≤ α_c · d_c`, so the
//!    needed level is `floor(log2(α_c·d_c / (α_v·d_v)))`, at least 0 (backgrounds: `d_c = d_v`).
//!
//! Each sample stands for `width·height / samples` screen pixels and counts with the
//! viewpoint's blend weight. The result per tile is a histogram of pixels by needed level, so a
//! client can say exactly which fraction of the needed pixels it holds at their needed level —
//! and use the totals as the live visible-pixel counts of Goss & Yuasa.

use glam::DVec3;
use rayon::prelude::*;
use tracks::cubemap::subpixel_dir;
use tracks::manifest::Manifest;
use tracks::{FaceCoord, PerspectiveCamera, TileGrid};

/// Levels tracked per histogram (level 0 .. `MAX_LEVELS − 1`; coarser needs are clamped).
pub const MAX_LEVELS: usize = 16;

/// What a sample of the camera shows from one viewpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Surface {
    /// Position of the tile in `viewpoints[viewpoint].tiles`.
    Tile { viewpoint: usize, tile: usize },
    /// Position of the tile in `viewpoints[viewpoint].background`.
    Background { viewpoint: usize, tile: usize },
}

/// Visible pixels of one surface, by the level they need.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceCount {
    pub surface: Surface,
    /// Weighted screen pixels needing exactly level `l` at index `l`.
    pub pixels_by_level: [f64; MAX_LEVELS],
}

impl SurfaceCount {
    pub fn pixels(&self) -> f64 {
        self.pixels_by_level.iter().sum()
    }

    /// The finest level any of its pixels needs.
    pub fn finest_needed(&self) -> u32 {
        self.pixels_by_level
            .iter()
            .position(|&p| p > 0.0)
            .unwrap_or(0) as u32
    }

    /// Pixels satisfied when the finest level held is `level` (`None` = nothing held).
    pub fn satisfied(&self, level: Option<u32>) -> f64 {
        match level {
            None => 0.0,
            Some(l) => self.pixels_by_level[(l as usize).min(MAX_LEVELS - 1)..]
                .iter()
                .sum(),
        }
    }
}

struct Layer {
    /// Tile position per `TileGrid::tile_index`, only kept tiles with opaque pixels.
    tiles: Vec<Option<usize>>,
}

struct ViewpointIndex {
    position: DVec3,
    /// Per slab.
    layers: Vec<Layer>,
    /// `(depth_min, depth_max)` per tile position.
    depth: Vec<(f64, f64)>,
    /// Largest finite tile depth.
    far: f64,
    /// Smallest depth of an indexed tile (infinite when there is none).
    near: f64,
    /// Background tile position per `TileGrid::tile_index`.
    background: Vec<Option<usize>>,
    /// Per tile position: unit direction to the tile's centre, its angular radius (radians,
    /// centre to the farthest corner) and its nearest depth (`None` for an unusable tile).
    cones: Vec<Option<(DVec3, f64, f64)>>,
}

/// Steps of the depth-range march along each ray.
const MARCH_STEPS: usize = 48;

/// One track of a manifest, indexed for visibility queries.
pub struct SceneIndex {
    grid: TileGrid,
    slabs: usize,
    viewpoints: Vec<ViewpointIndex>,
}

impl SceneIndex {
    /// Every viewpoint of `m` (each once, by id: a network's junctions are listed by every
    /// track through them). `None` when the manifest's face/tile sizes are not a valid grid.
    pub fn new(m: &Manifest) -> Option<SceneIndex> {
        let grid = TileGrid::new(m.face_size, m.tile_size)?;
        let slabs = m.slabs.len().max(1);
        // By id: a gap in the ids (a manifest that skips one) is a viewpoint without tiles.
        let listed = db::split::unique_viewpoints(m);
        let count = listed.last().map_or(0, |v| v.index + 1);
        if count > tracks::limits::MAX_VIEWPOINTS {
            return None;
        }
        let mut by_id: Vec<Option<&tracks::manifest::ViewpointEntry>> = vec![None; count];
        for v in listed {
            by_id[v.index] = Some(v);
        }
        // A gap in the ids (a viewpoint no track lists) is an empty viewpoint at the origin.
        let viewpoints = by_id
            .iter()
            .map(|v| match v {
                Some(vp) => viewpoint_index(grid, slabs, vp),
                None => empty_viewpoint(DVec3::ZERO),
            })
            .collect();
        Some(SceneIndex {
            grid,
            slabs,
            viewpoints,
        })
    }

    /// Indexes viewpoint `vp.index` again (its table arrived): the cost of that viewpoint,
    /// not of the scene. An id beyond those of the manifest the index was made from is left
    /// out.
    pub fn update(&mut self, vp: &tracks::manifest::ViewpointEntry) {
        let (grid, slabs) = (self.grid, self.slabs);
        if let Some(slot) = self.viewpoints.get_mut(vp.index) {
            *slot = viewpoint_index(grid, slabs, vp);
        }
    }

    /// Whether tile `tile` of viewpoint `viewpoint` can fall inside `camera`'s view frustum —
    /// the frustum culling that precedes the ACH budget sharing (PTM §6.1). Conservative: the
    /// frustum is bounded by the cone through its corners, the tile by the cone through its
    /// corners seen from the viewpoint, widened by the largest parallax between viewpoint and
    /// camera at the tile's nearest depth. Unknown or unusable tiles are never in view.
    pub fn tile_in_frustum(
        &self,
        camera: &PerspectiveCamera,
        viewpoint: usize,
        tile: usize,
    ) -> bool {
        self.tile_in_cone(
            camera.position,
            camera.forward(),
            frustum_half_angle(camera),
            viewpoint,
            tile,
        )
    }

    /// Whether tile `tile` of viewpoint `viewpoint` can be seen from `position` within
    /// `half_angle` radians of `forward` (unit) — [`Self::tile_in_frustum`] with a cone of any
    /// width, e.g. a frustum widened by the turn a walker may make before arriving (prefetch).
    pub fn tile_in_cone(
        &self,
        position: DVec3,
        forward: DVec3,
        half_angle: f64,
        viewpoint: usize,
        tile: usize,
    ) -> bool {
        let Some(vp) = self.viewpoints.get(viewpoint) else {
            return false;
        };
        let Some(&Some((dir, radius, near))) = vp.cones.get(tile) else {
            return false;
        };
        let offset = (position - vp.position).length();
        let parallax = if offset >= near {
            std::f64::consts::PI
        } else {
            (offset / near).asin()
        };
        let angle = dir.dot(forward).clamp(-1.0, 1.0).acos();
        angle <= half_angle + radius + parallax + 1e-9
    }

    /// Index (in a slab's dense tile table) of the tile in direction `dir`.
    fn tile_index_at(&self, dir: DVec3) -> Option<usize> {
        let fc = FaceCoord::from_dir(dir)?;
        let (x, y) = fc.to_pixel(self.grid.face_size);
        Some(self.grid.tile_index(self.grid.tile_of_pixel(fc.face, x, y)))
    }

    /// What viewpoint `vi` shows along the ray `origin + t·dir`: the surface and the hit
    /// point (`None` for a background tile, which lies at infinity: the viewpoint sees it in
    /// the ray's direction). `None` when the ray hits no tile and no background tile lies in
    /// its direction (a disocclusion hole). See the module docs for the march.
    pub fn trace(&self, vi: usize, origin: DVec3, dir: DVec3) -> Option<(Surface, Option<DVec3>)> {
        let vp = self.viewpoints.get(vi)?;
        let dir = dir.try_normalize()?;
        let background = self.tile_index_at(dir).and_then(|ti| {
            let tile = vp.background.get(ti).copied().flatten()?;
            Some((
                Surface::Background {
                    viewpoint: vi,
                    tile,
                },
                None,
            ))
        });
        if vp.far <= 0.0 {
            return background;
        }
        // Geometric steps from close to the camera to beyond the farthest tile.
        let t_far = vp.far * 1.5 + (origin - vp.position).length();
        let t_near = (t_far * 1e-4).max(1e-3);
        let ratio = (t_far / t_near).powf(1.0 / MARCH_STEPS as f64);
        let mut t0 = 0.0;
        let mut r0 = (origin - vp.position).length();
        // The distance from the viewpoint is convex along the ray: from a start within the
        // farthest tile, once a step lies wholly beyond it, so does every later step.
        let starts_within = r0 <= vp.far;
        let mut t1 = t_near;
        for _ in 0..=MARCH_STEPS {
            let p1 = origin + dir * t1;
            let r1 = (p1 - vp.position).length();
            let (lo, hi) = (r0.min(r1), r0.max(r1));
            if starts_within && lo > vp.far {
                break;
            }
            // No tile is that near: nothing to look up in this step.
            if hi < vp.near {
                t0 = t1;
                r0 = r1;
                t1 *= ratio;
                continue;
            }
            let mid = origin + dir * (0.5 * (t0 + t1));
            // One direction for every slab of the step.
            let at = self.tile_index_at(mid - vp.position);
            for tile in at
                .iter()
                .flat_map(|&ti| vp.layers.iter().filter_map(move |l| l.tiles[ti]))
            {
                let (dmin, dmax) = vp.depth[tile];
                if hi >= dmin && lo <= dmax {
                    // Place the hit where the ray's distance from the viewpoint is closest to
                    // the tile's mid depth within this step.
                    let target = (0.5 * (dmin + dmax)).clamp(lo, hi);
                    let f = if hi > lo {
                        ((target - r0) / (r1 - r0)).clamp(0.0, 1.0)
                    } else {
                        0.5
                    };
                    let hit = origin + dir * (t0 + (t1 - t0) * f);
                    return Some((
                        Surface::Tile {
                            viewpoint: vi,
                            tile,
                        },
                        Some(hit),
                    ));
                }
            }
            t0 = t1;
            r0 = r1;
            t1 *= ratio;
        }
        background
    }

    /// Count visible pixels per surface for `camera`, sampling its image with
    /// `samples_x × samples_y` rays, for each `(viewpoint, blend weight)`.
    pub fn count(
        &self,
        camera: &PerspectiveCamera,
        viewpoints: &[(usize, f64)],
        samples_x: u32,
        samples_y: u32,
    ) -> Vec<SurfaceCount> {
        let (sx, sy) = (samples_x.max(1), samples_y.max(1));
        let (w, h) = (camera.width.max(1) as f64, camera.height.max(1) as f64);
        let px_per_sample = w * h / (sx as f64 * sy as f64);
        let alpha_c = 2.0 * (camera.fov_deg.to_radians() * 0.5).tan() / w;
        let alpha_v = 2.0 / self.grid.face_size as f64;
        // Rows traced in parallel, summed in row order (the same sums as one thread).
        let rows: Vec<Vec<(Surface, usize, f64)>> = (0..sy)
            .into_par_iter()
            .map(|j| {
                let mut row = Vec::new();
                for i in 0..sx {
                    let x = (i as f64 + 0.5) * w / sx as f64;
                    let y = (j as f64 + 0.5) * h / sy as f64;
                    let dir = camera.ray_dir(x, y);
                    for &(vi, weight) in viewpoints {
                        if weight <= 0.0 {
                            continue;
                        }
                        let Some((surface, hit)) = self.trace(vi, camera.position, dir) else {
                            continue;
                        };
                        let q = match hit {
                            Some(p) => {
                                let d_c = (p - camera.position).length();
                                let d_v = (p - self.viewpoints[vi].position).length().max(1e-9);
                                alpha_c * d_c / (alpha_v * d_v)
                            }
                            None => alpha_c / alpha_v,
                        };
                        let level = if q > 1.0 {
                            // The epsilon keeps exact powers of two on their level.
                            ((q.log2() + 1e-9).floor() as usize).min(MAX_LEVELS - 1)
                        } else {
                            0
                        };
                        row.push((surface, level, weight * px_per_sample));
                    }
                }
                row
            })
            .collect();
        let mut counts: std::collections::HashMap<Surface, [f64; MAX_LEVELS]> =
            std::collections::HashMap::new();
        for (surface, level, pixels) in rows.into_iter().flatten() {
            counts.entry(surface).or_insert([0.0; MAX_LEVELS])[level] += pixels;
        }
        let mut out: Vec<SurfaceCount> = counts
            .into_iter()
            .map(|(surface, pixels_by_level)| SurfaceCount {
                surface,
                pixels_by_level,
            })
            .collect();
        out.sort_by_key(|a| a.surface);
        out
    }
}

/// Half-angle (radians) of the cone through the corners of `camera`'s view frustum.
pub fn frustum_half_angle(camera: &PerspectiveCamera) -> f64 {
    let half = (camera.fov_deg.to_radians() * 0.5).tan();
    let aspect = camera.height.max(1) as f64 / camera.width.max(1) as f64;
    (half * (1.0 + aspect * aspect).sqrt()).atan()
}

/// Centre direction, angular radius and nearest depth of a tile seen from its viewpoint.
fn tile_cone(grid: TileGrid, t: tracks::TileId, depth_min: f64) -> (DVec3, f64, f64) {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(t);
    let n = grid.face_size;
    let centre = subpixel_dir(t.face, 0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64, n);
    let radius = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
        .iter()
        .map(|&(x, y)| {
            subpixel_dir(t.face, x as f64, y as f64, n)
                .dot(centre)
                .clamp(-1.0, 1.0)
                .acos()
        })
        .fold(0.0, f64::max);
    (centre, radius, depth_min)
}

/// Blend weights of the two viewpoints around arc length `s`: the renderer's rule
/// ([`tracks::segment::blend_weights`], smoothstep across the segment), so the pixels a
/// sample counts for each view are weighted as the renderer blends them.
pub use tracks::segment::blend_weights;

/// A viewpoint's index; one without tiles (its table not in yet) holds no per-tile arrays, so
/// an index over a large network costs what its loaded part does.
fn viewpoint_index(
    grid: TileGrid,
    slabs: usize,
    vp: &tracks::manifest::ViewpointEntry,
) -> ViewpointIndex {
    if vp.tiles.is_empty() && vp.background.is_empty() {
        empty_viewpoint(vp.position)
    } else {
        index_viewpoint(grid, slabs, vp)
    }
}

fn empty_viewpoint(position: DVec3) -> ViewpointIndex {
    ViewpointIndex {
        position,
        layers: Vec::new(),
        depth: Vec::new(),
        far: 0.0,
        near: f64::INFINITY,
        background: Vec::new(),
        cones: Vec::new(),
    }
}

/// The lookup tables of one viewpoint with tiles: its tiles per slab and tile position, their
/// depth bounds and cones, and its background tiles.
fn index_viewpoint(
    grid: TileGrid,
    slabs: usize,
    vp: &tracks::manifest::ViewpointEntry,
) -> ViewpointIndex {
    let mut layers: Vec<Layer> = (0..slabs)
        .map(|_| Layer {
            tiles: vec![None; grid.tile_count()],
        })
        .collect();
    let mut depth = Vec::with_capacity(vp.tiles.len());
    let mut cones = Vec::with_capacity(vp.tiles.len());
    let mut far: f64 = 0.0;
    let mut near = f64::INFINITY;
    for (i, tile) in vp.tiles.iter().enumerate() {
        depth.push((tile.depth_min, tile.depth_max));
        let usable = tile.kept
            && tile.ptm.is_some()
            && tile.opaque_pixels > 0
            && tile.depth_min.is_finite()
            && tile.depth_max.is_finite()
            && tile.depth_min > 0.0
            && tile.depth_max >= tile.depth_min
            && tile.tile.tx < grid.tiles_per_side()
            && tile.tile.ty < grid.tiles_per_side();
        cones.push(usable.then(|| tile_cone(grid, tile.tile, tile.depth_min)));
        if let (true, Some(layer)) = (usable, layers.get_mut(tile.slab as usize)) {
            layer.tiles[grid.tile_index(tile.tile)] = Some(i);
            far = far.max(tile.depth_max);
            near = near.min(tile.depth_min);
        }
    }
    let mut background = vec![None; grid.tile_count()];
    for (i, b) in vp.background.iter().enumerate() {
        if b.tile.tx < grid.tiles_per_side() && b.tile.ty < grid.tiles_per_side() {
            background[grid.tile_index(b.tile)] = Some(i);
        }
    }
    ViewpointIndex {
        position: vp.position,
        layers,
        depth,
        far,
        near,
        background,
        cones,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::manifest::Manifest;

    fn corridor(name: &str) -> (SceneIndex, Manifest) {
        let dir = std::env::temp_dir().join(format!("railview-vis-{name}-{}", std::process::id()));
        let m = crate::walk::synth::write_synthetic(&dir, &Default::default()).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        (SceneIndex::new(&m).unwrap(), m)
    }

    fn cam_at(m: &Manifest, vp: usize, width: u32) -> PerspectiveCamera {
        PerspectiveCamera {
            position: m.tracks[0].viewpoints[vp].position,
            yaw_deg: 90.0,
            pitch_deg: -20.0,
            fov_deg: 90.0,
            width,
            height: width / 2,
        }
    }

    #[test]
    fn every_screen_pixel_is_counted_once_per_unit_of_weight() {
        let (index, m) = corridor("count");
        let cam = cam_at(&m, 1, 320);
        let counts = index.count(&cam, &[(1, 0.25), (2, 0.75)], 40, 20);
        let total: f64 = counts.iter().map(|c| c.pixels()).sum();
        // Samples that hit no tile and no background tile (holes) are not counted.
        let mut holes = 0.0;
        for j in 0..20 {
            for i in 0..40 {
                let dir = cam.ray_dir((i as f64 + 0.5) * 8.0, (j as f64 + 0.5) * 8.0);
                for (vi, w) in [(1, 0.25), (2, 0.75)] {
                    if index.trace(vi, cam.position, dir).is_none() {
                        holes += w * 64.0;
                    }
                }
            }
        }
        assert!(
            (total + holes - 320.0 * 160.0).abs() < 1e-6,
            "{total} + {holes}"
        );
        // Looking at a wall and the floor: tiles, not background, cover the view.
        let tiles: f64 = counts
            .iter()
            .filter(|c| matches!(c.surface, Surface::Tile { .. }))
            .map(|c| c.pixels())
            .sum();
        assert!(tiles > 0.9 * total, "{tiles} of {total}");
    }

    #[test]
    fn an_index_updated_viewpoint_by_viewpoint_sees_what_a_full_one_does() {
        let (full, m) = corridor("update");
        let mut empty = m.clone();
        for v in empty
            .tracks
            .iter_mut()
            .flat_map(|t| t.viewpoints.iter_mut())
        {
            v.tiles.clear();
            v.background.clear();
        }
        let mut index = SceneIndex::new(&empty).unwrap();
        let cam = cam_at(&m, 1, 160);
        let pair = [(1, 0.5), (2, 0.5)];
        assert!(index.count(&cam, &pair, 40, 20).is_empty());
        for v in m.tracks[0].viewpoints.iter().rev() {
            index.update(v);
        }
        assert_eq!(
            index.count(&cam, &pair, 40, 20),
            full.count(&cam, &pair, 40, 20)
        );
        let (mut far, mut near) = (
            m.tracks[0].viewpoints[0].clone(),
            empty.tracks[0].viewpoints[0].clone(),
        );
        far.index = index.viewpoints.len();
        near.index = 0;
        // An id the index does not know is left out; an emptied viewpoint sees nothing.
        index.update(&far);
        index.update(&near);
        assert_eq!(index.viewpoints.len(), full.viewpoints.len());
        assert!(index.trace(0, cam.position, DVec3::X).is_none());
    }

    #[test]
    fn needed_level_follows_screen_resolution_at_the_viewpoint() {
        let (index, m) = corridor("level");
        // At the viewpoint, a screen as fine as the panorama (90° over face_size pixels)
        // needs level 0; one 4× coarser needs level 2.
        for (width, level) in [(m.face_size, 0u32), (m.face_size / 4, 2)] {
            let counts = index.count(&cam_at(&m, 1, width), &[(1, 1.0)], 16, 8);
            for c in counts
                .iter()
                .filter(|c| matches!(c.surface, Surface::Tile { .. }))
            {
                assert_eq!(c.finest_needed(), level, "width {width}: {c:?}");
            }
        }
    }

    #[test]
    fn frustum_keeps_every_visible_tile_and_drops_those_behind() {
        let (index, m) = corridor("frustum");
        let mut cam = cam_at(&m, 1, 320);
        // Between viewpoints 1 and 2: parallax must not lose a tile that is seen.
        cam.position = m.tracks[0].viewpoints[1]
            .position
            .lerp(m.tracks[0].viewpoints[2].position, 0.4);
        for yaw in [0.0, 90.0, 200.0, 300.0] {
            cam.yaw_deg = yaw;
            let counts = index.count(&cam, &[(1, 0.6), (2, 0.4)], 64, 32);
            for c in &counts {
                if let Surface::Tile { viewpoint, tile } = c.surface {
                    assert!(
                        index.tile_in_frustum(&cam, viewpoint, tile),
                        "yaw {yaw}: {c:?}"
                    );
                }
            }
            let tiles = m.tracks[0].viewpoints[1].tiles.len();
            let inside = (0..tiles)
                .filter(|&t| index.tile_in_frustum(&cam, 1, t))
                .count();
            assert!(
                inside > 0 && inside < tiles,
                "yaw {yaw}: {inside} of {tiles}"
            );
        }
        assert!(!index.tile_in_frustum(&cam, 99, 0));
        assert!(!index.tile_in_frustum(&cam, 1, usize::MAX));
    }

    #[test]
    fn blend_weights_follow_the_segment_as_the_renderer_blends() {
        // A quarter along the segment: smoothstep gives the second view 0.15625, not 0.25.
        assert_eq!(
            blend_weights(&[0.0, 4.0, 8.0], 5.0),
            vec![(1, 0.84375), (2, 0.15625)]
        );
        assert_eq!(blend_weights(&[0.0, 4.0], 9.0), vec![(0, 0.0), (1, 1.0)]);
        assert_eq!(blend_weights(&[3.0], 9.0), vec![(0, 1.0)]);
    }
}
