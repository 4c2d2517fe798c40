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

/// CPU seconds (user + system) this process has used so far, from `/proc/self/stat`; `None`
/// where that is not available. On a shared machine, CPU time / cores is what the wall time
/// would be with the cores to ourselves.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Run `f` once: (wall seconds, CPU seconds) and its result.
fn timed<T>(f: impl FnOnce() -> T) -> (f64, f64, T) {
    let c0 = cpu_seconds();
    let t = Instant::now();
    let r = black_box(f());
    let wall = t.elapsed().as_secs_f64();
    let cpu = match (c0, cpu_seconds()) {
        (Some(a), Some(b)) => b - a,
        _ => f64::NAN,
    };
    (wall, cpu, r)
}

fn bench(c: &mut Criterion) {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
    println!(
        "cores: {cores}; `cpu` = process CPU seconds, `cpu/cores` = wall time on an idle machine"
    );
    for name in ["castle", "nature"] {
        let b = builtin(name).expect("built-in scene");
        let vps = b.tracks.get("main").expect("track main").viewpoints();
        let pos = vps[vps.len() / 2].position;
        let opts = RenderOptions {
            face_size: 512,
            supersample: 1,
            shadows: true,
        };
        println!(
            "{name}: {} primitives, viewpoint {pos}",
            b.scene.primitive_count()
        );
        let (w, cpu, r) = timed(|| render_cube(&b.scene, pos, opts));
        let idle = cpu / cores;
        println!(
            "{name}: cube 6x512² shadows: wall {w:.3} s, cpu {cpu:.2} s, cpu/cores {idle:.3} s; \
             {:.0} shaded samples/s and {:.0} primary rays/s (at cpu/cores)",
            r.color.as_slice().len() as f64 / idle,
            r.primary_rays as f64 / idle
        );
        let (w2, cpu2, _) = timed(|| {
            render_cube(
                &b.scene,
                pos,
                RenderOptions {
                    shadows: false,
                    ..opts
                },
            )
        });
        println!(
            "{name}: cube 6x512² no shadows: wall {w2:.3} s, cpu/cores {:.3} s",
            cpu2 / cores
        );
        let (w3, cpu3, _) = timed(|| render_depth_lowres(&b.scene, pos, 512));
        println!(
            "{name}: depth only 6x512²: wall {w3:.3} s, cpu/cores {:.3} s ({:.0} rays/s)",
            cpu3 / cores,
            6.0 * 512.0 * 512.0 / (cpu3 / cores)
        );
        let slabs = SlabRange::parse_list("0-8,8-25,25-inf").expect("slab list");
        let (w4, cpu4, layers) = timed(|| render_slabs(&b.scene, pos, &slabs, opts));
        let filled: Vec<usize> = layers
            .iter()
            .map(|l| l.color.as_slice().iter().filter(|c| c[3] == 255).count())
            .collect();
        println!(
            "{name}: 3 slab layers 6x512² shadows: wall {w4:.3} s, cpu/cores {:.3} s ({:.2}x the single layer by cpu), texels per layer {filled:?}",
            cpu4 / cores,
            cpu4 / cpu
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
