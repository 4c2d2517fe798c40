//! Reference views: what the renderer draws from one reference viewpoint.
//!
//! A [`RefView`] holds, for one viewpoint, a stack of cube-map texture layers (layer 0 is the
//! sky/background, layer `k + 1` is slab `k`) and the kept tiles of every slab, each with a
//! small depth mesh ([`TileMesh`]: vertices in face-pixel coordinates plus radial depth, placed
//! in 3D along the viewpoint's rays) and the finest texture level that has arrived
//! ([`ViewTile::finest_level`]; coarser levels stand in for missing finer ones).
//!
//! [`RefView::from_layers`] builds a view from dense per-slab layers (colour with a binary
//! opacity mask and radial depth), e.g. a prerender directory's `slab_K` files.

use glam::DVec3;
use tracks::cubemap::{subpixel_dir, Face, FaceCoord};
use tracks::{CubeMap, PixelRect, TileGrid, TileId};

use crate::texture::{dilate_masked, Layer};

mod skirt;
pub mod stretch;
pub use skirt::{skirt, view_skirts};

/// Errors building a reference view from layers.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ViewError {
    #[error("layer {layer}: face size {got} differs from the view's {expected}")]
    FaceSize {
        layer: usize,
        got: u32,
        expected: u32,
    },
    #[error("tile size {0} is not a power of two")]
    TileSize(u32),
    #[error("mesh step {0} must be between 1 and the tile size")]
    MeshStep(u32),
    #[error("view position is not finite: {0:?}")]
    Position(DVec3),
}

pub use tracks::mesh::{pos_from_ref, pos_in_face};
pub use tracks::TileMesh;

/// One kept slab tile of a reference view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewTile {
    pub tile: TileId,
    pub slab: u32,
    pub mesh: TileMesh,
    /// Finest texture level present (0 = full resolution); finer levels are not sampled.
    pub finest_level: u32,
    /// Bounding sphere of the mesh relative to the reference viewpoint.
    pub bound_center: DVec3,
    pub bound_radius: f64,
    /// Debug highlight, 0..1 (0 = none): the streaming side sets it to 1 when the tile or a
    /// finer level of it arrives and lets it decay per frame; with
    /// [`crate::plan::Overlays::highlight`] on, the renderer tints the tile by it. Read every
    /// frame, so changing it needs no re-upload.
    pub highlight: f32,
}

/// Everything drawn from one reference viewpoint.
#[derive(Clone, Debug)]
pub struct RefView {
    /// Viewpoint index along the track.
    pub index: usize,
    /// Arc length, metres.
    pub s: f64,
    pub position: DVec3,
    pub face_size: u32,
    pub tile_size: u32,
    /// Layer 0: background (alpha 255 where sky); layer `k + 1`: slab `k` (alpha = mask).
    pub layers: Vec<Layer>,
    /// Kept tiles, sorted by slab then tile index.
    pub tiles: Vec<ViewTile>,
}

/// How a directory's dense slab layers are turned into tile meshes for drawing (the slab
/// stage's own mesh builder takes [`slabs::mesh::MeshParams`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerMeshing {
    /// Grid step in pixels (1 = a vertex at every pixel corner).
    pub step: u32,
    /// Two neighbouring depths `a < b` belong to different surfaces when `b > a·(1 + jump)`.
    pub jump: f64,
    /// Error-bounded adaptive meshes (`slabs::mesh`, what `railview build` stores in a
    /// database) instead of the grid; `step` and `jump` are then unused.
    pub adaptive: Option<AdaptiveMesh>,
}

impl Default for LayerMeshing {
    fn default() -> Self {
        LayerMeshing {
            step: 2,
            jump: 0.08,
            adaptive: None,
        }
    }
}

/// Parameters of the adaptive (Delaunay, error-bounded) tile meshes of `slabs::mesh`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveMesh {
    /// Bound on the depth error, parallax pixels at `baseline_m` (databases use 0.5).
    pub max_error_px: f64,
    /// The track's largest baseline (sample spacing), metres.
    pub baseline_m: f64,
}

impl AdaptiveMesh {
    /// The bound `railview build` uses (0.5 px of parallax) at sample spacing `baseline_m`.
    pub fn database(baseline_m: f64) -> AdaptiveMesh {
        AdaptiveMesh {
            max_error_px: 0.5,
            baseline_m,
        }
    }
}

/// The adaptive mesh of one tile of a slab layer (`depth` = +inf outside the slab), as
/// `slabs::mesh` builds it for databases (vertices on pixel centres, neighbouring tiles of a
/// face joined without cracks), or `None` when it has no triangle.
pub fn adaptive_tile_mesh(
    depth: &CubeMap<f32>,
    mask: &CubeMap<bool>,
    grid: &TileGrid,
    tile: TileId,
    params: AdaptiveMesh,
) -> Option<TileMesh> {
    let p = slabs::mesh::MeshParams {
        max_error_px: params.max_error_px,
        baseline_m: params.baseline_m,
        ..Default::default()
    };
    let m = slabs::mesh::mesh_tile(
        depth,
        mask,
        *grid,
        tile,
        &p,
        Some(slabs::tiles::MeshKind::Adaptive),
    )
    .adaptive;
    (!m.indices.is_empty()).then_some(m)
}

/// One dense slab layer: colour (alpha is the binary opacity mask) and radial depth
/// (`+inf` where the slab holds nothing).
pub struct DenseLayer<'a> {
    pub color: &'a CubeMap<[u8; 4]>,
    pub depth: &'a CubeMap<f32>,
}

impl RefView {
    /// A view with nothing to draw (1×1 transparent layers, no tiles): a viewpoint of a track
    /// that was not loaded.
    pub fn empty(index: usize, s: f64, position: DVec3, tile_size: u32) -> RefView {
        RefView {
            index,
            s,
            position,
            face_size: 1,
            tile_size,
            layers: vec![crate::texture::Layer::from_rgba(CubeMap::filled(
                1, [0u8; 4],
            ))],
            tiles: Vec::new(),
        }
    }

    /// Build a view from a background cube map (alpha 255 where sky) and dense slab layers.
    pub fn from_layers(
        index: usize,
        s: f64,
        position: DVec3,
        tile_size: u32,
        params: LayerMeshing,
        background: &CubeMap<[u8; 4]>,
        slabs: &[DenseLayer<'_>],
    ) -> Result<RefView, ViewError> {
        if !position.is_finite() {
            return Err(ViewError::Position(position));
        }
        let n = background.face_size();
        let grid = TileGrid::new(n, tile_size).ok_or(ViewError::TileSize(tile_size))?;
        if params.step == 0 || params.step > tile_size {
            return Err(ViewError::MeshStep(params.step));
        }
        for (i, l) in slabs.iter().enumerate() {
            for got in [l.color.face_size(), l.depth.face_size()] {
                if got != n {
                    return Err(ViewError::FaceSize {
                        layer: i + 1,
                        got,
                        expected: n,
                    });
                }
            }
        }
        let mut layers = vec![Layer::from_rgba(dilate_masked(background))];
        let mut tiles = Vec::new();
        for (k, l) in slabs.iter().enumerate() {
            // A pixel is part of the slab when its mask is set and its depth is usable.
            let depth = CubeMap::from_fn(n, |f, x, y| {
                let d = *l.depth.get(f, x, y);
                let opaque = l.color.get(f, x, y)[3] >= 128 && d.is_finite() && d > 0.0;
                if opaque {
                    d
                } else {
                    f32::INFINITY
                }
            });
            let color = CubeMap::from_fn(n, |f, x, y| {
                let c = *l.color.get(f, x, y);
                let a = if depth.get(f, x, y).is_finite() {
                    255
                } else {
                    0
                };
                [c[0], c[1], c[2], a]
            });
            layers.push(Layer::from_rgba(dilate_masked(&color)));
            let mask = params.adaptive.map(|_| depth.map(|d| d.is_finite()));
            for tile in grid.tiles() {
                let mesh = match (params.adaptive, &mask) {
                    (Some(a), Some(mask)) => adaptive_tile_mesh(&depth, mask, &grid, tile, a),
                    _ => tile_mesh(&depth, &grid, tile, params),
                };
                if let Some(mesh) = mesh {
                    tiles.push(ViewTile::new(tile, k as u32, mesh, n));
                }
            }
        }
        Ok(RefView {
            index,
            s,
            position,
            face_size: n,
            tile_size,
            layers,
            tiles,
        })
    }

    /// A plain panorama: the whole colour cube map as the only (background) layer, no tiles.
    /// What an ordinary panorama viewer draws; the baseline of the viewer benchmark.
    pub fn panorama(index: usize, s: f64, position: DVec3, color: &CubeMap<[u8; 4]>) -> RefView {
        let opaque = color.map(|c| [c[0], c[1], c[2], 255]);
        RefView {
            index,
            s,
            position,
            face_size: color.face_size(),
            tile_size: color.face_size().next_power_of_two(),
            layers: vec![Layer::from_rgba(opaque)],
            tiles: Vec::new(),
        }
    }

    /// The nearest layer's colour per texel (first slab whose mask is set, else the
    /// background): the single panorama an ordinary viewer would show from here.
    pub fn flatten(&self) -> CubeMap<[u8; 4]> {
        let n = self.face_size;
        CubeMap::from_fn(n, |f, x, y| {
            let front = self.layers[1..]
                .iter()
                .chain(self.layers.first())
                .map(|l| *l.levels[0].get(f, x, y))
                .find(|c| c[3] >= 128);
            front.unwrap_or([0, 0, 0, 0])
        })
    }

    /// Number of slabs (layers beyond the background).
    pub fn slab_count(&self) -> usize {
        self.layers.len().saturating_sub(1)
    }

    /// Triangles over all tiles.
    pub fn triangle_count(&self) -> usize {
        self.tiles.iter().map(|t| t.mesh.indices.len() / 3).sum()
    }
}

impl ViewTile {
    /// A tile with all levels present and its bounding sphere computed from the mesh.
    pub fn new(tile: TileId, slab: u32, mesh: TileMesh, face_size: u32) -> ViewTile {
        let pts: Vec<DVec3> = mesh
            .vertices
            .iter()
            .map(|v| pos_from_ref(*v, tile.face, face_size))
            .collect();
        let (lo, hi) = pts.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        let center = if pts.is_empty() {
            DVec3::ZERO
        } else {
            (lo + hi) * 0.5
        };
        let radius = pts
            .iter()
            .map(|p| p.distance(center))
            .fold(0.0f64, f64::max);
        ViewTile {
            tile,
            slab,
            mesh,
            finest_level: 0,
            bound_center: center,
            bound_radius: radius,
            highlight: 0.0,
        }
    }
}

/// Depth of the slab layer at pixel `(x, y)` of `face`, where `(x, y)` may lie one pixel outside
/// the face: such pixels are looked up on the neighbouring face through their direction.
fn depth_around(depth: &CubeMap<f32>, face: Face, x: i64, y: i64) -> f32 {
    let n = depth.face_size() as i64;
    if (0..n).contains(&x) && (0..n).contains(&y) {
        return *depth.get(face, x as u32, y as u32);
    }
    let dir = subpixel_dir(face, x as f64 + 0.5, y as f64 + 0.5, n as u32);
    match FaceCoord::from_dir(dir) {
        Some(c) => {
            let (px, py) = c.to_pixel(n as u32);
            *depth.get(c.face, px, py)
        }
        None => f32::INFINITY,
    }
}

/// Depth of a shared mesh corner: the nearest surface among the (up to four) pixels around it,
/// averaged over the pixels of that surface. A function of the corner's direction only (the
/// canonical face is the one `FaceCoord::from_dir` picks), so tiles and faces that share a
/// corner agree exactly and no crack opens between continuous neighbours.
fn corner_depth(depth: &CubeMap<f32>, face: Face, cx: u32, cy: u32, jump: f64) -> Option<f32> {
    let n = depth.face_size();
    let dir = subpixel_dir(face, cx as f64, cy as f64, n);
    let (face, cx, cy) = match FaceCoord::from_dir(dir) {
        Some(c) => {
            let (x, y) = c.to_pixel_f(n);
            (c.face, x.round() as i64, y.round() as i64)
        }
        None => (face, cx as i64, cy as i64),
    };
    let ds = [
        depth_around(depth, face, cx - 1, cy - 1),
        depth_around(depth, face, cx, cy - 1),
        depth_around(depth, face, cx - 1, cy),
        depth_around(depth, face, cx, cy),
    ];
    let front = ds.iter().copied().fold(f32::INFINITY, f32::min);
    if !front.is_finite() {
        return None;
    }
    let limit = front as f64 * (1.0 + jump);
    let (sum, count) = ds
        .iter()
        .filter(|d| d.is_finite() && (**d as f64) <= limit)
        .fold((0.0f64, 0u32), |(s, c), d| (s + *d as f64, c + 1));
    Some((sum / count as f64) as f32)
}

fn same_surface(a: f32, b: f32, jump: f64) -> bool {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    (hi as f64) <= lo as f64 * (1.0 + jump)
}

/// The depth mesh of one tile of a slab layer (`depth` = +inf outside the slab), or `None`
/// when the tile holds no slab pixel.
///
/// A grid of cells `step` pixels wide. A cell whose corner pixels all agree with the shared
/// corner depths is continuous and uses the shared corner vertices; a cell across a depth
/// jump gets its own four vertices at its own pixels' depths, so it neither stretches a
/// "rubber sheet" over the jump nor moves at the reference viewpoint. Cells without any slab
/// pixel are left out (the opacity mask cuts partial cells exactly).
pub fn tile_mesh(
    depth: &CubeMap<f32>,
    grid: &TileGrid,
    tile: TileId,
    params: LayerMeshing,
) -> Option<TileMesh> {
    let tracks::PixelRect { x0, y0, x1, y1, .. } = grid.pixel_rect(tile);
    let face = tile.face;
    let step = params.step.max(1);
    let xs: Vec<u32> = (x0..x1).step_by(step as usize).chain([x1]).collect();
    let ys: Vec<u32> = (y0..y1).step_by(step as usize).chain([y1]).collect();
    let (nx, ny) = (xs.len(), ys.len());
    let corners: Vec<Option<f32>> = ys
        .iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .map(|(x, y)| corner_depth(depth, face, x, y, params.jump))
        .collect();
    let mut mesh = TileMesh::default();
    let mut shared: Vec<Option<u32>> = vec![None; nx * ny];
    let vertex = |mesh: &mut TileMesh, x: u32, y: u32, d: f32| -> u32 {
        mesh.vertices.push([x as f32, y as f32, d]);
        (mesh.vertices.len() - 1) as u32
    };
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let (cx0, cx1, cy0, cy1) = (xs[i], xs[i + 1], ys[j], ys[j + 1]);
            // Slab pixels of the cell; empty cells are not drawn.
            let mut cell: Vec<f32> = Vec::new();
            for y in cy0..cy1 {
                for x in cx0..cx1 {
                    let d = *depth.get(face, x, y);
                    if d.is_finite() {
                        cell.push(d);
                    }
                }
            }
            if cell.is_empty() {
                continue;
            }
            // The cell pixel touching each corner (clamped inside the cell).
            let own = [
                (cx0, cy0),
                (cx1 - 1, cy0),
                (cx0, cy1 - 1),
                (cx1 - 1, cy1 - 1),
            ]
            .map(|(x, y)| *depth.get(face, x, y));
            let ids = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
            let continuous = ids.iter().zip(own).all(|(&(ci, cj), o)| {
                matches!(corners[cj * nx + ci], Some(c) if o.is_finite() && same_surface(c, o, params.jump))
            });
            let v: [u32; 4] = if continuous {
                ids.map(|(ci, cj)| {
                    let k = cj * nx + ci;
                    *shared[k].get_or_insert_with(|| {
                        vertex(
                            &mut mesh,
                            xs[ci],
                            ys[cj],
                            corners[k].unwrap_or(f32::INFINITY),
                        )
                    })
                })
            } else {
                cell.sort_by(f32::total_cmp);
                let median = cell[cell.len() / 2];
                let pos = [(cx0, cy0), (cx1, cy0), (cx0, cy1), (cx1, cy1)];
                let mut out = [0u32; 4];
                for c in 0..4 {
                    let d = if own[c].is_finite() { own[c] } else { median };
                    out[c] = vertex(&mut mesh, pos[c].0, pos[c].1, d);
                }
                out
            };
            // Two triangles, split along the diagonal whose ends are closer in depth.
            let dd = |a: u32, b: u32| {
                (mesh.vertices[a as usize][2] - mesh.vertices[b as usize][2]).abs()
            };
            if dd(v[0], v[3]) <= dd(v[1], v[2]) {
                mesh.indices.extend([v[0], v[2], v[3], v[0], v[3], v[1]]);
            } else {
                mesh.indices.extend([v[0], v[2], v[1], v[1], v[2], v[3]]);
            }
        }
    }
    (!mesh.indices.is_empty()).then_some(mesh)
}

/// Coarser meshes for the frame-time budget: how many extra levels the renderer builds
/// ([`decimated_indices`] with cells of `tile_size >> (MESH_LEVELS - level)` pixels).
pub const MESH_LEVELS: u32 = 2;

/// Decimation cell (pixels) of mesh level `level ≥ 1` for tiles `tile_size` wide: half a
/// tile, then a whole tile.
pub fn mesh_cell(tile_size: u32, level: u32) -> u32 {
    (tile_size >> MESH_LEVELS.saturating_sub(level)).max(1)
}

/// A coarser triangulation of `mesh` by vertex clustering, as indices into the *same*
/// vertices (so a renderer keeps one vertex buffer and adds an index buffer per level).
///
/// The tile's pixels `rect` are cut into square cells `cell` pixels
/// wide; the inner vertices of one cell that lie on one surface (same depth bucket, buckets a
/// factor `1 + jump` apart) merge into the one nearest the cell centre, and triangles that
/// lose a corner vanish. Vertices on the mesh's border (edges of a single triangle: the tile
/// outline, the outline of the covered area, depth-jump cells) are kept, so neighbouring
/// tiles still share their edge vertices (no crack opens) and the covered area keeps its
/// outline. (Were a tile-edge vertex not on the border, it would merge only along its edge,
/// in cells aligned to the edge: symmetric when the tile size is a multiple of `cell`.)
/// Every kept vertex is an original one, so the reference viewpoint still sees the exact
/// depths there.
pub fn decimated_indices(mesh: &TileMesh, rect: PixelRect, cell: u32, jump: f64) -> Vec<u32> {
    let (x0, y0, x1, y1) = (
        rect.x0 as f32,
        rect.y0 as f32,
        rect.x1 as f32,
        rect.y1 as f32,
    );
    let c = cell.max(1) as f32;
    let log_step = (1.0 + jump.max(1e-6)).ln();
    // Cluster key: kind (0 interior, 1..=4 edges, 5 own), two cell coordinates, depth bucket.
    let key_of = |i: usize, v: &[f32; 3]| -> (u8, i64, i64, i64) {
        let [x, y, _] = *v;
        let d = v[2];
        if !(d.is_finite() && d > 0.0) {
            return (5, i as i64, 0, 0);
        }
        let bucket = ((d as f64).ln() / log_step).floor() as i64;
        let on_x = x <= x0 || x >= x1;
        let on_y = y <= y0 || y >= y1;
        let cx = ((x - x0) / c).floor() as i64;
        let cy = ((y - y0) / c).floor() as i64;
        match (on_x, on_y) {
            (true, true) => (5, i as i64, 0, 0),
            (true, false) => (if x <= x0 { 1 } else { 2 }, cy, 0, bucket),
            (false, true) => (if y <= y0 { 3 } else { 4 }, cx, 0, bucket),
            (false, false) => (0, cx, cy, bucket),
        }
    };
    // Distance of a vertex to the centre of its cell (along the edge for edge clusters).
    let centre_dist = |key: (u8, i64, i64, i64), v: &[f32; 3]| -> f32 {
        let [x, y, _] = *v;
        let mid = |k: i64, o: f32| o + (k as f32 + 0.5) * c;
        match key.0 {
            0 => (x - mid(key.1, x0)).abs().max((y - mid(key.2, y0)).abs()),
            1 | 2 => (y - mid(key.1, y0)).abs(),
            3 | 4 => (x - mid(key.1, x0)).abs(),
            _ => 0.0,
        }
    };
    // Vertices on the mesh's own border (an edge of one triangle only: the outline of the
    // covered area, depth-jump cells, the tile edge) stay, so the covered area and the
    // surfaces' silhouettes keep their shape; only the inside of continuous surfaces thins.
    let mut edges: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
    for tri in mesh.indices.chunks_exact(3) {
        for (a, b) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])] {
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    let mut border = vec![false; mesh.vertices.len()];
    for (&(a, b), &n) in &edges {
        if n == 1 {
            for v in [a, b] {
                if let Some(f) = border.get_mut(v as usize) {
                    *f = true;
                }
            }
        }
    }
    let mut best: std::collections::HashMap<(u8, i64, i64, i64), usize> =
        std::collections::HashMap::new();
    let keys: Vec<_> = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| {
            if border[i] {
                (5, i as i64, 0, 0)
            } else {
                key_of(i, v)
            }
        })
        .collect();
    for (i, v) in mesh.vertices.iter().enumerate() {
        let k = keys[i];
        let better = |j: usize| {
            let w = &mesh.vertices[j];
            let (a, b) = (centre_dist(k, v), centre_dist(k, w));
            // Ties: the nearer surface, then the position (independent of vertex order).
            (a, v[2], v[0], v[1])
                .partial_cmp(&(b, w[2], w[0], w[1]))
                .is_some_and(|o| o.is_lt())
        };
        match best.get(&k) {
            Some(&j) if !better(j) => {}
            _ => {
                best.insert(k, i);
            }
        }
    }
    let rep: Vec<u32> = keys.iter().map(|k| best[k] as u32).collect();
    let mut out = Vec::with_capacity(mesh.indices.len() / 2);
    for tri in mesh.indices.chunks_exact(3) {
        let t = [
            rep[tri[0] as usize],
            rep[tri[1] as usize],
            rep[tri[2] as usize],
        ];
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            out.extend(t);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere_depth(n: u32, r: f32) -> CubeMap<f32> {
        CubeMap::filled(n, r)
    }

    #[test]
    fn constant_depth_gives_one_watertight_mesh_per_tile() {
        let n = 8;
        let d = sphere_depth(n, 5.0);
        let grid = TileGrid::new(n, 4).unwrap();
        let p = LayerMeshing {
            step: 2,
            jump: 0.1,
            adaptive: None,
        };
        for t in grid.tiles() {
            let m = tile_mesh(&d, &grid, t, p).unwrap();
            // 2x2 cells, shared corners: 9 vertices, 8 triangles.
            assert_eq!(m.vertices.len(), 9, "{t:?}");
            assert_eq!(m.indices.len(), 24);
            assert!(m.vertices.iter().all(|v| v[2] == 5.0));
        }
    }

    #[test]
    fn corners_shared_across_faces_get_identical_depth() {
        // Depth varies with direction, so any asymmetry across faces would show.
        let n = 8;
        let d = CubeMap::from_fn(n, |f, x, y| {
            let dir = tracks::cubemap::pixel_dir(f, x, y, n);
            (3.0 + dir.x + 0.5 * dir.y) as f32
        });
        for f in Face::ALL {
            for (cx, cy) in [(0, 0), (n, 0), (0, 3), (n, 5), (4, n)] {
                let a = corner_depth(&d, f, cx, cy, 0.5).unwrap();
                let dir = subpixel_dir(f, cx as f64, cy as f64, n);
                // The same corner seen from every face that holds it.
                for g in Face::ALL {
                    if let Some((u, v)) = g.uv_from_dir(dir) {
                        if u.abs() <= 1.0 + 1e-9 && v.abs() <= 1.0 + 1e-9 {
                            let (x, y) = ((u + 1.0) * 0.5 * n as f64, (1.0 - v) * 0.5 * n as f64);
                            let b = corner_depth(&d, g, x.round() as u32, y.round() as u32, 0.5)
                                .unwrap();
                            assert_eq!(a, b, "{f:?} {cx},{cy} vs {g:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn depth_jump_cells_do_not_stretch() {
        let n = 8;
        // Left half of +z at 2 m, right half at 20 m.
        let d = CubeMap::from_fn(
            n,
            |f, x, _| {
                if f == Face::PosZ && x < 4 {
                    2.0
                } else {
                    20.0
                }
            },
        );
        let grid = TileGrid::new(n, 8).unwrap();
        let t = TileId {
            face: Face::PosZ,
            tx: 0,
            ty: 0,
        };
        let m = tile_mesh(
            &d,
            &grid,
            t,
            LayerMeshing {
                step: 2,
                jump: 0.1,
                adaptive: None,
            },
        )
        .unwrap();
        for tri in m.indices.chunks(3) {
            let ds: Vec<f32> = tri.iter().map(|&i| m.vertices[i as usize][2]).collect();
            let (lo, hi) = ds
                .iter()
                .fold((f32::MAX, 0f32), |(a, b), &d| (a.min(d), b.max(d)));
            assert!(hi <= lo * 1.1, "stretched triangle {ds:?}");
        }
    }

    #[test]
    fn empty_tiles_have_no_mesh() {
        let d = CubeMap::filled(8, f32::INFINITY);
        let grid = TileGrid::new(8, 4).unwrap();
        for t in grid.tiles() {
            assert!(tile_mesh(&d, &grid, t, LayerMeshing::default()).is_none());
        }
    }

    #[test]
    fn decimation_keeps_tile_edges_and_cuts_triangles() {
        let n = 32;
        let d = CubeMap::from_fn(n, |f, x, y| {
            let dir = tracks::cubemap::pixel_dir(f, x, y, n);
            (4.0 + dir.x) as f32
        });
        let grid = TileGrid::new(n, 16).unwrap();
        let p = LayerMeshing {
            step: 2,
            jump: 0.5,
            adaptive: None,
        };
        for t in grid.tiles() {
            let m = tile_mesh(&d, &grid, t, p).unwrap();
            let rect = grid.pixel_rect(t);
            let edge_vertices = |idx: &[u32]| {
                let mut e: Vec<[u32; 2]> = idx
                    .iter()
                    .map(|&i| pos_in_face(m.vertices[i as usize]))
                    .filter(|v| {
                        v[0] == rect.x0 as f32
                            || v[0] == rect.x1 as f32
                            || v[1] == rect.y0 as f32
                            || v[1] == rect.y1 as f32
                    })
                    .map(|v| [v[0] as u32, v[1] as u32])
                    .collect();
                e.sort();
                e.dedup();
                e
            };
            let mut prev = m.indices.len();
            for level in 1..=MESH_LEVELS {
                let idx = decimated_indices(&m, grid.pixel_rect(t), mesh_cell(16, level), p.jump);
                assert!(idx.len() < prev, "{t:?} level {level}");
                assert!(idx.iter().all(|&i| (i as usize) < m.vertices.len()));
                prev = idx.len();
                // Corners always stay; a coarser level keeps edge vertices of the finer one
                // only (never invents any), so neighbours agree.
                let e = edge_vertices(&idx);
                for corner in [
                    [rect.x0, rect.y0],
                    [rect.x1, rect.y0],
                    [rect.x0, rect.y1],
                    [rect.x1, rect.y1],
                ] {
                    assert!(e.contains(&corner), "{t:?} lost corner {corner:?}");
                }
            }
        }
    }

    #[test]
    fn neighbouring_tiles_keep_the_same_shared_edge_vertices() {
        let n = 32;
        let d = CubeMap::filled(n, 6.0f32);
        let grid = TileGrid::new(n, 16).unwrap();
        let p = LayerMeshing {
            step: 2,
            jump: 0.1,
            adaptive: None,
        };
        let a = TileId {
            face: Face::PosZ,
            tx: 0,
            ty: 0,
        };
        let b = TileId {
            face: Face::PosZ,
            tx: 1,
            ty: 0,
        };
        let shared = |t: TileId, level: u32| {
            let m = tile_mesh(&d, &grid, t, p).unwrap();
            let idx = decimated_indices(&m, grid.pixel_rect(t), mesh_cell(16, level), p.jump);
            let mut e: Vec<u32> = idx
                .iter()
                .map(|&i| pos_in_face(m.vertices[i as usize]))
                .filter(|v| v[0] == 16.0)
                .map(|v| v[1] as u32)
                .collect();
            e.sort();
            e.dedup();
            e
        };
        for level in 1..=MESH_LEVELS {
            assert_eq!(shared(a, level), shared(b, level), "level {level}");
        }
    }

    #[test]
    fn decimation_does_not_merge_across_a_depth_jump() {
        let n = 16;
        let d = CubeMap::from_fn(
            n,
            |f, x, _| {
                if f == Face::PosZ && x < 8 {
                    2.0
                } else {
                    20.0
                }
            },
        );
        let grid = TileGrid::new(n, 16).unwrap();
        let t = TileId {
            face: Face::PosZ,
            tx: 0,
            ty: 0,
        };
        let m = tile_mesh(
            &d,
            &grid,
            t,
            LayerMeshing {
                step: 2,
                jump: 0.1,
                adaptive: None,
            },
        )
        .unwrap();
        let idx = decimated_indices(&m, grid.pixel_rect(t), 16, 0.1);
        for tri in idx.chunks(3) {
            let ds: Vec<f32> = tri.iter().map(|&i| m.vertices[i as usize][2]).collect();
            let (lo, hi) = ds
                .iter()
                .fold((f32::MAX, 0f32), |(a, b), &d| (a.min(d), b.max(d)));
            assert!(hi <= lo * 1.1, "stretched triangle {ds:?}");
        }
    }
}
