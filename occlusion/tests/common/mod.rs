//! Shared by the culling tests: a scene's layers along a track as the pipeline makes them
//! (slab boundaries chosen by `slabs`, layers rendered by the built-in tracer), the oracle's
//! marks, and every variant run against them.

#![allow(dead_code)]

use glam::DVec3;
use occlusion::{
    cull_from_segments, cull_viewpoint, cull_viewpoint_shrunk, hidden_from_segment, oracle_track,
    raw_rgba_bytes, score, BallDepth, Cell, CullParams, MatchRule, RayCast, RenderedParams,
    RenderedStats, SegmentEnd, ShrunkStats, SlabLayer, Variant, ViewpointCull, Visibility,
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
    let verdicts = if variant == Variant::Rendered {
        rendered_verdicts(p, scene, &params.rendered).0
    } else {
        Vec::new()
    };
    for i in 0..p.positions.len() {
        let cell = Cell::straight(&p.positions, i);
        let c = match variant {
            Variant::Rendered => rendered_cull(p, &verdicts, i),
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

/// Per segment of the track (one for a track of one viewpoint), which later tiles of its two
/// ends the rendered variant hides from it (depth renders by rays through the scene at the
/// layers' face size); the stats summed.
pub fn rendered_verdicts(
    p: &Prepared,
    scene: &Scene,
    params: &RenderedParams,
) -> (Vec<Vec<Vec<Vec<bool>>>>, RenderedStats) {
    let render = |cs: &[DVec3]| {
        Ok::<_, ()>(
            cs.iter()
                .map(|_| Some(BallDepth::Rays(scene as &dyn occlusion::Geometry)))
                .collect(),
        )
    };
    let end = |i: usize| SegmentEnd {
        viewpoint: p.positions[i],
        grid: &p.grid,
        layers: &p.layers[i],
    };
    let mut stats = RenderedStats::default();
    let pieces: Vec<(Vec<DVec3>, Vec<usize>)> = if p.positions.len() == 1 {
        vec![(p.positions.clone(), vec![0])]
    } else {
        (0..p.positions.len() - 1)
            .map(|i| (p.positions[i..i + 2].to_vec(), vec![i, i + 1]))
            .collect()
    };
    let verdicts = pieces
        .iter()
        .map(|(path, ends)| {
            let ends: Vec<SegmentEnd> = ends.iter().map(|&i| end(i)).collect();
            let v = hidden_from_segment(path, &ends, params, render)
                .unwrap()
                .unwrap();
            stats.add(&v.stats);
            v.hidden
        })
        .collect();
    (verdicts, stats)
}

/// Viewpoint `i`'s decisions from the verdicts of its segments ([`rendered_verdicts`]).
pub fn rendered_cull(p: &Prepared, verdicts: &[Vec<Vec<Vec<bool>>>], i: usize) -> ViewpointCull {
    let mut hidden: Vec<&[Vec<bool>]> = Vec::new();
    if p.positions.len() == 1 {
        hidden.push(&verdicts[0][0]);
    } else {
        if i > 0 {
            hidden.push(&verdicts[i - 1][1]);
        }
        if i + 1 < p.positions.len() {
            hidden.push(&verdicts[i][0]);
        }
    }
    cull_from_segments(&p.layers[i], &hidden).unwrap()
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
