//! Shared by the culling tests: a scene's layers along a track as the pipeline makes them
//! (slab boundaries chosen by `slabs`, layers rendered by the built-in tracer), the oracle's
//! marks, and every variant run against them.

#![allow(dead_code)]

use glam::DVec3;
use occlusion::oracle::depth_from_geometry;
use occlusion::{
    cull_viewpoint, cull_viewpoint_rendered, cull_viewpoint_shrunk, oracle_track, raw_rgba_bytes,
    render_balls, score, BallView, Cell, CullParams, MatchRule, RayCast, RenderedParams,
    ShrunkStats, SlabLayer, Variant, ViewpointCull, Visibility,
};
use prerender::scene::Scene;
use tracks::{SlabRange, TileGrid};

pub struct Prepared {
    pub positions: Vec<DVec3>,
    pub grid: TileGrid,
    pub ranges: Vec<SlabRange>,
    pub layers: Vec<Vec<SlabLayer>>,
    pub vis: Vec<Visibility>,
}

/// Layers at `positions` with slab boundaries chosen as `railview slabs` does (or given),
/// and the oracle with `per_segment` offset positions per segment.
pub fn prepare(
    scene: &Scene,
    positions: &[DVec3],
    face: u32,
    tile: u32,
    ranges: Option<&str>,
    per_segment: usize,
) -> Prepared {
    prepare_with(scene, positions, face, tile, ranges, per_segment, face)
}

/// [`prepare`] with the oracle casting `oracle_face` rays per face side.
pub fn prepare_with(
    scene: &Scene,
    positions: &[DVec3],
    face: u32,
    tile: u32,
    ranges: Option<&str>,
    per_segment: usize,
    oracle_face: u32,
) -> Prepared {
    let grid = TileGrid::new(face, tile).unwrap();
    let ranges = match ranges {
        Some(r) => SlabRange::parse_list(r).unwrap(),
        None => {
            let lows: Vec<_> = positions
                .iter()
                .map(|p| prerender::render::render_depth_lowres(scene, *p, 32))
                .collect();
            let spacing = positions
                .windows(2)
                .map(|w| w[0].distance(w[1]))
                .fold(0.0, f64::max);
            slabs::boundaries::choose(&lows, spacing, face, &Default::default()).slabs
        }
    };
    let opts = prerender::render::RenderOptions {
        face_size: face,
        supersample: 1,
        shadows: false,
    };
    let layers: Vec<Vec<SlabLayer>> = positions
        .iter()
        .map(|p| {
            prerender::render::render_slabs(scene, *p, &ranges, opts)
                .into_iter()
                .map(|l| {
                    let alpha = l.color.map(|c| c[3]);
                    SlabLayer::from_maps(l.range, alpha, l.depth, &grid, raw_rgba_bytes).unwrap()
                })
                .collect()
        })
        .collect();
    let refs: Vec<(DVec3, &[SlabLayer])> = positions
        .iter()
        .zip(&layers)
        .map(|(p, l)| (*p, l.as_slice()))
        .collect();
    let between: Vec<Vec<DVec3>> = positions.windows(2).map(|w| w.to_vec()).collect();
    let src = RayCast {
        geometry: scene,
        face_size: oracle_face,
    };
    let vis = oracle_track(&refs, &between, &src, per_segment, &MatchRule::default()).unwrap();
    Prepared {
        positions: positions.to_vec(),
        grid,
        ranges,
        layers,
        vis,
    }
}

/// Per slab: tiles before, kept, false culls, tiles the oracle saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rows(pub Vec<(u64, u64, u64, u64)>);

impl Rows {
    pub fn false_culls(&self) -> u64 {
        self.0.iter().map(|r| r.2).sum()
    }
    /// Kept ÷ oracle-visible over the later slabs.
    pub fn later_ratio(&self) -> f64 {
        let kept: u64 = self.0[1..].iter().map(|r| r.1).sum();
        let seen: u64 = self.0[1..].iter().map(|r| r.3).sum();
        kept as f64 / seen.max(1) as f64
    }
}

/// Run a variant on every viewpoint and score it.
pub fn run(
    p: &Prepared,
    scene: &Scene,
    variant: Variant,
) -> (Rows, Vec<ViewpointCull>, ShrunkStats) {
    run_with(p, scene, &CullParams::new(1.0, variant).unwrap())
}

/// [`run`] with given parameters.
pub fn run_with(
    p: &Prepared,
    scene: &Scene,
    params: &CullParams,
) -> (Rows, Vec<ViewpointCull>, ShrunkStats) {
    let variant = params.variant;
    let mut rows = vec![(0, 0, 0, 0); p.ranges.len()];
    let mut culls = Vec::new();
    let mut stats = ShrunkStats::default();
    let solids = occlusion::SceneSolids::new(scene);
    let views = if variant == Variant::Rendered {
        rendered_views(p, scene, &params.rendered)
    } else {
        Vec::new()
    };
    for i in 0..p.positions.len() {
        let cell = Cell::straight(&p.positions, i);
        let c = match variant {
            Variant::Rendered => {
                let near = views_of(&views, i);
                cull_viewpoint_rendered(&cell, &p.grid, &p.layers[i], &near, &params.rendered)
                    .unwrap()
                    .0
            }
            Variant::Shrunk => {
                let (c, s) =
                    cull_viewpoint_shrunk(&cell, &p.grid, &p.layers[i], &params.shrunk, &solids)
                        .unwrap();
                stats.add(&s);
                c
            }
            _ => cull_viewpoint(&cell, &p.grid, &p.layers[i], params).unwrap(),
        };
        for s in score(&c, &p.grid, &p.vis[i]) {
            let r = &mut rows[s.slab];
            r.0 += s.kept + s.culled;
            r.1 += s.kept;
            r.2 += s.false_culls;
            r.3 += s.visible_tiles;
        }
        culls.push(c);
    }
    (Rows(rows), culls, stats)
}

/// Per segment of the track, its balls and their depth renders (rays through the scene at
/// the layers' face size), for the rendered variant.
pub fn rendered_views(p: &Prepared, scene: &Scene, params: &RenderedParams) -> Vec<Vec<BallView>> {
    let n = p.grid.face_size;
    if p.positions.len() == 1 {
        let one = render_balls(&p.positions, params, |c| {
            Ok::<_, ()>(depth_from_geometry(scene, c, n))
        });
        return vec![one.unwrap()];
    }
    p.positions
        .windows(2)
        .map(|w| {
            render_balls(w, params, |c| Ok::<_, ()>(depth_from_geometry(scene, c, n))).unwrap()
        })
        .collect()
}

/// The views whose balls cover the cell of viewpoint `i` (its two segments).
pub fn views_of(views: &[Vec<BallView>], i: usize) -> Vec<&BallView> {
    let mut out: Vec<&BallView> = Vec::new();
    if i > 0 {
        out.extend(views[i - 1].iter());
    }
    if let Some(v) = views.get(i) {
        out.extend(v.iter());
    }
    out
}

/// The reference viewpoints of a built-in scene's main track.
pub fn builtin(name: &str) -> (Scene, Vec<DVec3>) {
    let b = prerender::scenes::builtin(name).unwrap();
    let positions = b
        .tracks
        .get("main")
        .unwrap()
        .viewpoints()
        .iter()
        .map(|v| v.position)
        .collect();
    (b.scene, positions)
}

/// A scene of `shapes`, all of one grey solid material, named `name`.
pub fn grey_scene(shapes: Vec<prerender::scene::Shape>, name: &str) -> Scene {
    use prerender::scene::{Material, Object, SceneDesc, Texture};
    Scene::new(
        SceneDesc {
            materials: vec![Material {
                name: "m".into(),
                color: DVec3::splat(0.6),
                texture: Texture::Solid,
            }],
            objects: shapes
                .into_iter()
                .map(|shape| Object { shape, material: 0 })
                .collect(),
            ..Default::default()
        },
        name,
    )
    .unwrap()
}
