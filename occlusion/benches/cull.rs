//! Culling time for a 20-sample track with 6 × 1024² faces and 3 slabs (goal: < 3 s on two
//! cores; the shrunk variant within 3× the conservative one), and the oracle's cost per
//! position, on the synthetic courtyard.
//!
//! `cargo bench -p occlusion --bench cull`

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use occlusion::synth::{render_layers, BoxScene};
use occlusion::{
    cull_viewpoint, cull_viewpoint_shrunk, mark_visible, Cell, CullParams, MatchRule, SceneSolids,
    Variant, Visibility,
};
use tracks::{SlabRange, TileGrid};

const SAMPLES: usize = 20;

fn bench(c: &mut Criterion) {
    let scene = BoxScene::courtyard(DVec3::ZERO);
    let grid = TileGrid::new(1024, 32).expect("valid grid");
    let ranges = SlabRange::parse_list("0-5,5-11,11-inf").expect("valid ranges");
    let track: Vec<DVec3> = (0..SAMPLES)
        .map(|i| DVec3::new(0.4 * i as f64, 1.7, 0.0))
        .collect();
    // The layers of the middle viewpoint stand in for every viewpoint's (the inputs are
    // read from disk one viewpoint at a time in the real command; loading is not timed).
    let layers = render_layers(&scene, track[SAMPLES / 2], &grid, &ranges).expect("layers");
    let mut g = c.benchmark_group("cull");
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    let solids = SceneSolids::boxes(&scene);
    for variant in [Variant::Shrunk, Variant::Conservative, Variant::Paper] {
        let p = CullParams::new(1.0, variant).expect("valid alpha");
        g.bench_function(format!("track20_1024_3slabs_{}", variant.name()), |b| {
            b.iter(|| {
                let mut kept = 0;
                for i in 0..SAMPLES {
                    let mut cell = Cell::straight(&track, i);
                    // Same relative geometry as the viewpoint the layers were rendered at.
                    let shift = track[SAMPLES / 2] - track[i];
                    cell.viewpoint += shift;
                    for path in &mut cell.paths {
                        for x in path {
                            *x += shift;
                        }
                    }
                    let r = match variant {
                        Variant::Shrunk => {
                            cull_viewpoint_shrunk(&cell, &grid, &layers, &p.shrunk, &solids)
                                .expect("cull")
                                .0
                        }
                        _ => cull_viewpoint(&cell, &grid, &layers, &p).expect("cull"),
                    };
                    kept += r.slabs.iter().map(|s| s.kept.len()).sum::<usize>();
                }
                kept
            })
        });
    }
    // Oracle: one position's 256² ray-cast depth, reprojected into one 1024² reference.
    let v = track[SAMPLES / 2];
    let x = v + DVec3::new(0.2, 0.0, 0.0);
    g.bench_function("oracle_position_256_into_1024", |b| {
        b.iter(|| {
            let d = occlusion::oracle::depth_from_geometry(&scene, x, 256);
            let vis = Visibility::new(1024, layers.len());
            mark_visible(x, &d, v, &layers, &MatchRule::default(), &vis);
            vis.visible_pixels(1)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
