//! Splitting + tiling + meshing one 6 × 1024² viewpoint into 3 slabs (goal < 0.3 s on 2 cores).
//!
//! The viewpoint is synthetic: a 20 m box room with a ring of columns at 3–5 m and rolling
//! relief on the walls, so every slab has curved surfaces, edges and empty tiles.

use criterion::{criterion_group, criterion_main, Criterion};
use slabs::mesh::MeshParams;
use slabs::tiles::{mask_from_depth, split_depth, tile_sample, LayerInput, MeshKind, TileParams};
use tracks::cubemap::pixel_dir;
use tracks::{CubeMap, SlabRange};

fn viewpoint(n: u32) -> CubeMap<f32> {
    CubeMap::from_fn(n, |f, x, y| {
        let d = pixel_dir(f, x, y, n);
        let wall = 20.0 / d.abs().max_element();
        let relief = 1.0 + 0.05 * (7.0 * d.x).sin() * (5.0 * d.z).cos();
        let az = d.z.atan2(d.x);
        let column = (az * 6.0).sin() > 0.9 && d.y.abs() < 0.6;
        let r = if column {
            3.0 + 2.0 * ((az * 3.0).cos() * 0.5 + 0.5)
        } else if d.y < -0.3 {
            1.7 / -d.y // floor
        } else {
            wall * relief
        };
        r.min(wall) as f32
    })
}

fn bench(c: &mut Criterion) {
    let n = 1024;
    let depth = viewpoint(n);
    let slabs = SlabRange::parse_list("0-6,6-15,15-inf").expect("valid list");
    for (name, keep, both) in [
        ("grid", MeshKind::Grid, false),
        ("adaptive", MeshKind::Adaptive, false),
        ("both-measured", MeshKind::Adaptive, true),
    ] {
        let params = TileParams {
            tile_size: 32,
            mesh: MeshParams {
                step: 4,
                max_error_px: 0.5,
                baseline_m: 2.0,
                discontinuity_px: 1.0,
            },
            keep,
            measure_both: both,
        };
        let mut g = c.benchmark_group("split_tile_mesh_6x1024_3slabs");
        g.sample_size(10);
        g.bench_function(name, |b| {
            b.iter(|| {
                let layers = split_depth(&depth, &slabs);
                let masks: Vec<_> = layers.iter().map(mask_from_depth).collect();
                let inputs: Vec<LayerInput> = layers
                    .iter()
                    .zip(&masks)
                    .map(|(depth, mask)| LayerInput { depth, mask })
                    .collect();
                tile_sample(0, &inputs, &params).expect("valid parameters")
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
