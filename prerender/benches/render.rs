//! Renderer benchmarks on the built-in scenes: a 6×512² cube map with shadows (the goal is
//! < 1 s for `castle` on the 2-core dev machine), 3 slab layers (< 1.5 s), the low-res depth
//! pass and the exact first-hit query used by the culling oracle.
//!
//! `cargo bench -p prerender --bench render`; throughput lines print shaded samples/s
//! (cube-map texels per second) and primary rays/s.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use prerender::render::{render_cube, render_depth_lowres, render_slabs, RenderOptions};
use prerender::scenes::builtin;
use tracks::SlabRange;

fn render_cube_timed(
    scene: &prerender::scene::Scene,
    pos: glam::DVec3,
    opts: RenderOptions,
) -> f64 {
    let t = Instant::now();
    black_box(render_cube(scene, pos, opts));
    t.elapsed().as_secs_f64()
}

fn bench(c: &mut Criterion) {
    for name in ["castle", "nature"] {
        let b = builtin(name).expect("built-in scene");
        let vps = b.tracks.get("main").expect("track main").viewpoints();
        let pos = vps[vps.len() / 2].position;
        let opts = RenderOptions {
            face_size: 512,
            supersample: 1,
            shadows: true,
        };
        // One timed run for the throughput line.
        let t = Instant::now();
        let r = render_cube(&b.scene, pos, opts);
        let s = t.elapsed().as_secs_f64();
        println!(
            "{name}: 6x512² cube map with shadows {s:.3} s, {:.0} shaded samples/s, {:.0} primary rays/s",
            r.color.as_slice().len() as f64 / s,
            r.primary_rays as f64 / s
        );
        let t = Instant::now();
        black_box(render_depth_lowres(&b.scene, pos, 512));
        let sd = t.elapsed().as_secs_f64();
        let no_shadows = render_cube_timed(
            &b.scene,
            pos,
            RenderOptions {
                shadows: false,
                ..opts
            },
        );
        println!(
            "{name}: depth only 6x512² {sd:.3} s ({:.0} rays/s); shaded without shadows {no_shadows:.3} s",
            6.0 * 512.0 * 512.0 / sd
        );
        let slabs = SlabRange::parse_list("0-8,8-25,25-inf").expect("slab list");
        let t = Instant::now();
        let layers = render_slabs(&b.scene, pos, &slabs, opts);
        let s3 = t.elapsed().as_secs_f64();
        let filled: Vec<usize> = layers
            .iter()
            .map(|l| l.color.as_slice().iter().filter(|c| c[3] == 255).count())
            .collect();
        println!(
            "{name}: 3 slab layers 6x512² with shadows {s3:.3} s ({:.2}x the single layer), texels per layer {filled:?}",
            s3 / s
        );
        let mut g = c.benchmark_group(name);
        g.sample_size(10);
        g.bench_function("cube_512_shadows", |bch| {
            bch.iter(|| black_box(render_cube(&b.scene, pos, opts)))
        });
        g.bench_function("slabs3_512_shadows", |bch| {
            bch.iter(|| black_box(render_slabs(&b.scene, pos, &slabs, opts)))
        });
        g.bench_function("lowres_depth_64", |bch| {
            bch.iter(|| black_box(render_depth_lowres(&b.scene, pos, 64)))
        });
        g.bench_function("first_hit_1k_rays", |bch| {
            let dirs: Vec<glam::DVec3> = (0..1000)
                .map(|i| {
                    let a = i as f64 * 0.0061;
                    glam::DVec3::new(a.cos(), (i as f64 * 0.013).sin() * 0.5, a.sin()).normalize()
                })
                .collect();
            bch.iter(|| {
                dirs.iter()
                    .filter_map(|d| b.scene.first_hit(pos, *d, f64::INFINITY))
                    .sum::<f64>()
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
