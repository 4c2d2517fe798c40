//! Decode speed of a database's payloads as a client meets them, against PNG.
//!
//! `RAILVIEW_BENCH_DB=DB cargo bench -p codec --bench codec` — every distinct PTM of the
//! database `DB` (its level groups fed in order to the streaming decoder, as a client
//! does) and every distinct mesh, against PNG decode (the `image` crate) of the same pixels:
//! each PTM's full-resolution image as an RGBA PNG at best compression. The decoders
//! alternate payload by payload and each payload keeps its fastest of `ROUNDS` passes, so a
//! loaded machine only adds noise, not bias. Prints MB/s of coded bytes and of decoded
//! pixels, PTM ÷ PNG time, and whether decoding keeps up with the bytes arriving at
//! 10 Mbit/s. Without `RAILVIEW_BENCH_DB` it says so and measures nothing.

use std::hint::black_box;
use std::io::Cursor;
use std::path::Path;
use std::time::Instant;

use codec::mesh::decode_mesh;
use codec::ptm::{Decoder, Limits};
use db::Database;

const ROUNDS: usize = 5;
/// 10 Mbit/s in bytes per second.
const LINK: f64 = 10e6 / 8.0;

struct Ptm {
    groups: Vec<Vec<u8>>,
    png: Vec<u8>,
    pixels: u64,
}

fn png_rgba(w: u32, h: u32, rgba: Vec<u8>) -> Vec<u8> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        Cursor::new(&mut out),
        image::codecs::png::CompressionType::Best,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(&rgba, w, h, image::ExtendedColorType::Rgba8)
    .expect("png encode");
    out
}

fn decode_ptm(groups: &[Vec<u8>]) {
    let mut d = Decoder::new(Limits::default());
    for g in groups {
        d.push(g).unwrap();
    }
    black_box(d.finest());
}

fn main() {
    let Some(dir) = std::env::var_os("RAILVIEW_BENCH_DB") else {
        println!("codec bench: set RAILVIEW_BENCH_DB to a database built by `railview build`");
        return;
    };
    let db = Database::open(Path::new(&dir)).expect("open the database");
    let m = db.manifest();
    let (mut seen_ptm, mut seen_mesh) = (
        std::collections::HashSet::new(),
        std::collections::HashSet::new(),
    );
    let (mut ptms, mut meshes) = (Vec::new(), Vec::new());
    for v in m.tracks.iter().flat_map(|t| &t.viewpoints) {
        let refs = v.background.iter().map(|b| (&b.ptm, None)).chain(
            v.tiles
                .iter()
                .filter_map(|t| Some((t.ptm.as_ref()?, t.mesh_at()))),
        );
        for (p, mesh) in refs {
            let key = (
                p.object.hash.clone(),
                p.levels.first().map_or(0, |l| l.offset),
            );
            if seen_ptm.insert(key) {
                let groups: Vec<Vec<u8>> = (0..p.levels.len())
                    .map(|g| db.read_level(p, g).unwrap())
                    .collect();
                let mut d = Decoder::new(Limits::default());
                for g in &groups {
                    d.push(g).unwrap();
                }
                let img = d.into_finest().unwrap();
                let (w, h) = (img.width(), img.height());
                ptms.push(Ptm {
                    groups,
                    png: png_rgba(w, h, img.into_data()),
                    pixels: w as u64 * h as u64,
                });
            }
            if let Some((o, Some(r))) = mesh {
                if seen_mesh.insert((o.hash.clone(), r.offset)) {
                    meshes.push(db.read_checked_range(o, r).unwrap());
                }
            }
        }
    }
    let time = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64()
    };
    let mut best_ptm = vec![f64::INFINITY; ptms.len()];
    let mut best_png = vec![f64::INFINITY; ptms.len()];
    let mut best_mesh = vec![f64::INFINITY; meshes.len()];
    for _ in 0..ROUNDS {
        for (i, p) in ptms.iter().enumerate() {
            best_ptm[i] = best_ptm[i].min(time(&mut || decode_ptm(black_box(&p.groups))));
            best_png[i] = best_png[i].min(time(&mut || {
                black_box(
                    image::load_from_memory_with_format(black_box(&p.png), image::ImageFormat::Png)
                        .unwrap(),
                );
            }));
        }
        for (i, b) in meshes.iter().enumerate() {
            best_mesh[i] = best_mesh[i].min(time(&mut || {
                black_box(decode_mesh(black_box(b)).unwrap());
            }));
        }
    }
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    let (t_ptm, t_png, t_mesh) = (sum(&best_ptm), sum(&best_png), sum(&best_mesh));
    let ptm_bytes: u64 = ptms
        .iter()
        .map(|p| p.groups.iter().map(|g| g.len() as u64).sum::<u64>())
        .sum();
    let png_bytes: u64 = ptms.iter().map(|p| p.png.len() as u64).sum();
    let mesh_bytes: u64 = meshes.iter().map(|b| b.len() as u64).sum();
    let pixels: u64 = ptms.iter().map(|p| p.pixels).sum();
    println!(
        "{}: {} PTMs ({ptm_bytes} B; as PNG {png_bytes} B), {} meshes ({mesh_bytes} B); fastest of {ROUNDS}",
        Path::new(&dir).display(),
        ptms.len(),
        meshes.len()
    );
    println!(
        "textures: PTM {:.3} s = {:.2} MB/s coded, {:.1} Mpx/s; PNG {:.3} s = {:.2} MB/s coded, \
         {:.1} Mpx/s; PTM/PNG time {:.2}x",
        t_ptm,
        ptm_bytes as f64 / t_ptm / 1e6,
        pixels as f64 / t_ptm / 1e6,
        t_png,
        png_bytes as f64 / t_png / 1e6,
        pixels as f64 / t_png / 1e6,
        t_ptm / t_png
    );
    println!(
        "meshes: {:.3} s = {:.2} MB/s coded ({:.1} µs a mesh)",
        t_mesh,
        mesh_bytes as f64 / t_mesh / 1e6,
        t_mesh / meshes.len().max(1) as f64 * 1e6
    );
    let arrive = (ptm_bytes + mesh_bytes) as f64 / LINK;
    println!(
        "all payloads: decode {:.3} s, arrival at 10 Mbit/s {:.3} s: decode takes {:.2}x the \
         time the bytes take to arrive (textures {:.2}x, meshes {:.2}x)",
        t_ptm + t_mesh,
        arrive,
        (t_ptm + t_mesh) / arrive,
        t_ptm / (ptm_bytes as f64 / LINK),
        t_mesh / (mesh_bytes as f64 / LINK)
    );
}
