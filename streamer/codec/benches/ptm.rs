//! PTM codec benchmark on 256×256 RGBA tiles.
//!
//! Tiles: the six faces of the built-in `castle` rendered at 256 px from the first reference
//! viewpoint of track `main` (alpha = 255 on geometry, 0 on sky, as a near slab's mask), plus
//! one deterministic synthetic texture for comparison. Measures encode and decode throughput
//! (MB/s of RGBA pixels), PNG decode of the same tile with the `image` crate, and prints sizes:
//! PTM (method 2, range-coded, the default; and method 1, zstd) against PNG of the base level
//! and against the raw mip chain, then a decode ratio that holds on a loaded machine (PTM and
//! PNG alternate tile by tile over the six castle tiles, each keeps its fastest pass), with
//! the zstd method and partial decodes. Database tiles (32² slab tiles with masks) and meshes
//! are measured by the `codec` bench.
//!
//! `cargo bench -p codec --bench ptm` (sizes and ratio only: `… -- nomatch`)

use std::hint::black_box;
use std::io::Cursor;
use std::time::Instant;

use codec::ptm::{decode, decode_up_to, encode, EncodeOptions, Image, Limits, Method};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use prerender::render::{render_cube, RenderOptions};
use tracks::Face;

const N: u32 = 256;

fn castle_tiles() -> Vec<(String, Image)> {
    let built = prerender::scenes::builtin("castle").expect("castle is built in");
    let track = built.tracks.get("main").expect("castle has track main");
    let vp = &track.viewpoints()[0];
    let cube = render_cube(
        &built.scene,
        vp.position,
        RenderOptions {
            face_size: N,
            supersample: 1,
            shadows: true,
        },
    );
    Face::ALL
        .iter()
        .map(|&f| {
            let (c, d) = (cube.color.face(f), cube.depth.face(f));
            let img = Image::from_fn(N, N, 4, |x, y, k| {
                let i = (y * N + x) as usize;
                if k == 3 {
                    if d[i].is_finite() {
                        255
                    } else {
                        0
                    }
                } else {
                    c[i][k as usize]
                }
            });
            (format!("castle-{}", f.short_name()), img)
        })
        .collect()
}

fn synthetic_tile() -> Image {
    Image::from_fn(N, N, 4, |x, y, k| {
        let (fx, fy) = (x as f64 / 17.0, y as f64 / 23.0);
        let v =
            128.0 + 60.0 * (fx + k as f64).sin() * (fy * 1.3).cos() + ((x * 7 + y * 13) % 9) as f64;
        if k == 3 {
            255
        } else {
            v as u8
        }
    })
}

fn png_bytes(img: &Image) -> Vec<u8> {
    let mut out = Vec::new();
    image::RgbaImage::from_raw(img.width(), img.height(), img.data().to_vec())
        .expect("size matches")
        .write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
        .expect("png encode");
    out
}

fn raw_mip_chain_bytes(img: &Image) -> u64 {
    let mut total = 0u64;
    let (mut w, mut h) = (img.width(), img.height());
    loop {
        total += w as u64 * h as u64 * img.channels() as u64;
        if w == 1 && h == 1 {
            return total;
        }
        (w, h) = (w.div_ceil(2), h.div_ceil(2));
    }
}

fn bench(c: &mut Criterion) {
    let mut tiles = castle_tiles();
    tiles.push(("synthetic".into(), synthetic_tile()));
    let opts = EncodeOptions::default();
    let raw_opts = EncodeOptions {
        method: Method::Raw,
        ..opts
    };
    let zstd_opts = EncodeOptions {
        method: Method::Zstd,
        ..opts
    };
    println!(
        "\n{:<12} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8}",
        "tile", "rgba", "mipchain", "ptm-raw", "png", "ptm-zstd", "ptm", "vs png", "vs mips"
    );
    let mut sum = [0u64; 5];
    for (name, img) in &tiles {
        let png = png_bytes(img).len() as u64;
        let ptm = encode(img, &opts).unwrap().bytes.len() as u64;
        let zstd = encode(img, &zstd_opts).unwrap().bytes.len() as u64;
        let raw = encode(img, &raw_opts).unwrap().bytes.len() as u64;
        let mips = raw_mip_chain_bytes(img);
        if name.starts_with("castle") {
            for (s, v) in sum.iter_mut().zip([png, ptm, mips, raw, zstd]) {
                *s += v;
            }
        }
        println!(
            "{name:<12} {:>9} {mips:>9} {raw:>9} {png:>9} {zstd:>9} {ptm:>9} {:>8.3} {:>8.3}",
            img.data().len(),
            ptm as f64 / png as f64,
            ptm as f64 / mips as f64
        );
    }
    let [png, ptm, mips, raw, zstd] = sum.map(|v| v as f64);
    println!(
        "castle total: ptm/png {:.3} (zstd method {:.3}), ptm/mipchain {:.3}, ptm-raw/base {:.4}, \
         mipchain/ptm {:.2}:1\n",
        ptm / png,
        zstd / png,
        ptm / mips,
        raw / (6 * N * N * 4) as f64,
        mips / ptm
    );

    decode_ratio(&tiles[..6], &opts, &zstd_opts);

    let mut g = c.benchmark_group("ptm-256-rgba");
    g.throughput(Throughput::Bytes((N * N * 4) as u64));
    let (name, img) = &tiles[Face::PosX.index()];
    let enc = encode(img, &opts).unwrap().bytes;
    let png = png_bytes(img);
    g.bench_function(format!("encode/{name}"), |b| {
        b.iter(|| encode(black_box(img), &opts).unwrap())
    });
    g.bench_function(format!("decode/{name}"), |b| {
        b.iter(|| decode(black_box(&enc), Limits::default()).unwrap())
    });
    g.bench_function(format!("png-decode/{name}"), |b| {
        b.iter(|| {
            image::load_from_memory_with_format(black_box(&png), image::ImageFormat::Png).unwrap()
        })
    });
    let raw = encode(img, &raw_opts).unwrap().bytes;
    g.bench_function(format!("decode-raw-method/{name}"), |b| {
        b.iter(|| decode(black_box(&raw), Limits::default()).unwrap())
    });
    g.finish();
}

/// Decode time of PTM against PNG over the castle tiles, robust to the load of a shared
/// machine: the decoders alternate tile by tile, and each keeps its fastest of `ROUNDS`
/// passes (load only ever adds time). Also the time to decode only the coarser levels (what a
/// client asking for level 1 or 2 pays) and the zstd method's.
fn decode_ratio(tiles: &[(String, Image)], opts: &EncodeOptions, zstd_opts: &EncodeOptions) {
    const ROUNDS: usize = 40;
    let encoded: Vec<Vec<u8>> = tiles
        .iter()
        .map(|(_, img)| encode(img, opts).unwrap().bytes)
        .collect();
    let zstd: Vec<Vec<u8>> = tiles
        .iter()
        .map(|(_, img)| encode(img, zstd_opts).unwrap().bytes)
        .collect();
    let pngs: Vec<Vec<u8>> = tiles.iter().map(|(_, img)| png_bytes(img)).collect();
    let time = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64()
    };
    let mut best = [[f64::INFINITY; 5]; 6];
    for _ in 0..ROUNDS {
        for (i, ((ptm, png), z)) in encoded.iter().zip(&pngs).zip(&zstd).enumerate() {
            let b = &mut best[i];
            b[0] = b[0].min(time(&mut || {
                black_box(decode(black_box(ptm), Limits::default()).unwrap());
            }));
            b[1] = b[1].min(time(&mut || {
                black_box(
                    image::load_from_memory_with_format(black_box(png), image::ImageFormat::Png)
                        .unwrap(),
                );
            }));
            b[4] = b[4].min(time(&mut || {
                black_box(decode(black_box(z), Limits::default()).unwrap());
            }));
            for (slot, level) in [(2, 1), (3, 2)] {
                b[slot] = b[slot].min(time(&mut || {
                    black_box(decode_up_to(black_box(ptm), level, Limits::default()).unwrap());
                }));
            }
        }
    }
    for ((name, _), b) in tiles.iter().zip(&best) {
        println!(
            "  {name:<10} decode ms: ptm {:.3}, png {:.3}, zstd method {:.3}",
            b[0] * 1e3,
            b[1] * 1e3,
            b[4] * 1e3
        );
    }
    let sum = |k: usize| best.iter().map(|b| b[k]).sum::<f64>() * 1e3;
    let (ptm, png, l1, l2, zs) = (sum(0), sum(1), sum(2), sum(3), sum(4));
    let bytes: usize = encoded.iter().map(Vec::len).sum();
    println!(
        "decode, 6 castle tiles, fastest of {ROUNDS} (ms): ptm {ptm:.3} ({:.1} MB/s of its bytes), \
         png {png:.3}, ptm/png {:.2}x the time; up to level 1 {l1:.3} ({:.2}x png), level 2 \
         {l2:.3} ({:.2}x png); zstd method {zs:.3} ({:.2}x png)\n",
        bytes as f64 / ptm / 1e3,
        ptm / png,
        l1 / png,
        l2 / png,
        zs / png
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
