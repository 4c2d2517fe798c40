//! Test vectors for the browser viewer's decoders (`viewer/web/`): PTMs, meshes, tables and
//! BLAKE3 digests as the Rust codec writes them, each with what the Rust decoder makes of it
//! whole, cut short and damaged. `node --test viewer/web/test/` decodes the same bytes and
//! must give the same bytes (or fail where the Rust decoder fails).
//!
//! The vectors are committed (`viewer/web/test/vectors.json`) so the JavaScript tests need no
//! Rust; this test fails when the file is not what the codec writes today. To rewrite it
//! after a deliberate format change: `RAILVIEW_BLESS_WEB_VECTORS=1 cargo test -p db --test
//! web_vectors`.

use codec::mesh::TileMesh;
use codec::mesh::{decode_mesh, encode_mesh, MeshCoding};
use codec::ptm::{decode, encode, EncodeOptions, Image, Limits, Method};
use db::table::{decode_table, encode_table};
use db::ViewTable;
use serde_json::{json, Value};
use tracks::manifest::{BackgroundTile, LevelRef, ObjectRef, PackRange, PtmRef, TileEntry};
use tracks::{Face, TileId};

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// A deterministic pseudo-random sequence (no RNG crate needed for a few bytes).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) as u32
    }
}

/// The input variants every vector is decoded in: whole, cut at a few places, damaged.
fn variants(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
    let n = bytes.len();
    let mut out = vec![("whole".to_string(), bytes.to_vec())];
    for cut in [1, 3, n / 2, n.saturating_sub(1)] {
        if cut < n {
            out.push((format!("cut {cut}"), bytes[..cut].to_vec()));
        }
    }
    for at in [1, 4, n / 3, n / 2, n - 1] {
        if at < n {
            let mut b = bytes.to_vec();
            b[at] ^= 0x5a;
            out.push((format!("byte {at} flipped"), b));
        }
    }
    out
}

fn image(w: u32, h: u32, c: u8, seed: u64, masked: bool) -> Image {
    let mut r = Lcg(seed);
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let inside = !masked || (x * 3 + y * 2) % 11 > 3;
            let noise = (r.next() % 9) as u8;
            for k in 0..c as u32 {
                let v = (x * 37 + y * 11 + k * 50) as u8 / 2 + noise;
                data.push(if c == 2 || c == 4 {
                    if k + 1 == c as u32 {
                        if inside {
                            255
                        } else {
                            0
                        }
                    } else if inside {
                        v
                    } else {
                        0
                    }
                } else {
                    v
                });
            }
        }
    }
    Image::new(w, h, c, data).unwrap()
}

fn ptm_vectors() -> Vec<Value> {
    let mut out = Vec::new();
    let cases: [(u32, u32, u8, bool, u8, Method); 8] = [
        (32, 32, 4, true, 0, Method::Arith),
        (33, 17, 4, true, 0, Method::Arith),
        (5, 3, 3, false, 0, Method::Arith),
        (16, 16, 3, false, 4, Method::Arith),
        (13, 9, 4, true, 3, Method::Arith),
        (7, 11, 2, true, 0, Method::Arith),
        (9, 6, 1, false, 0, Method::Arith),
        (10, 7, 4, false, 0, Method::Raw),
    ];
    for (i, &(w, h, c, masked, near, method)) in cases.iter().enumerate() {
        let img = image(w, h, c, i as u64 + 1, masked);
        let opts = EncodeOptions {
            method,
            near,
            ..EncodeOptions::default()
        };
        let enc = encode(&img, &opts).unwrap();
        let runs: Vec<Value> = variants(&enc.bytes)
            .into_iter()
            .map(|(name, b)| match decode(&b, Limits::default()) {
                Ok(img) => json!({"name": name, "input": hex(&b), "ok": hex(img.data())}),
                Err(e) => json!({"name": name, "input": hex(&b), "error": e.to_string()}),
            })
            .collect();
        out.push(json!({
            "what": format!("{w}x{h}x{c} near {near} {method:?}"),
            "runs": runs,
        }));
    }
    out
}

/// A grid mesh with holes and both diagonals, plus pixel quads where `quads`.
fn mesh(seed: u64, side: u32, offset: (f32, f32), quads: bool) -> TileMesh {
    let mut r = Lcg(seed);
    let mut vertices = Vec::new();
    let mut index = vec![vec![u32::MAX; side as usize]; side as usize];
    for y in 0..side {
        for x in 0..side {
            if r.next().is_multiple_of(7) && x % 3 == 1 {
                continue;
            }
            index[y as usize][x as usize] = vertices.len() as u32;
            let depth = 20.0 + x as f32 * 0.3 + y as f32 * 0.1 + (r.next() % 5) as f32 * 0.05;
            vertices.push([x as f32 + offset.0, y as f32 + offset.1, depth]);
        }
    }
    let mut indices = Vec::new();
    for y in 0..side as usize - 1 {
        for x in 0..side as usize - 1 {
            let [a, b, c, d] = [
                index[y][x],
                index[y][x + 1],
                index[y + 1][x],
                index[y + 1][x + 1],
            ];
            if [a, b, c, d].contains(&u32::MAX) {
                continue;
            }
            if r.next().is_multiple_of(2) {
                indices.extend([a, b, d, a, d, c]);
            } else {
                indices.extend([a, b, c, b, d, c]);
            }
        }
    }
    let mut m = TileMesh { vertices, indices };
    if quads {
        for (qx, qy, depth) in [
            (40.0f32, 3.0f32, 7.5f32),
            (41.0, 3.0, 7.9),
            (40.0, 4.0, 7.0),
        ] {
            let base = m.vertices.len() as u32;
            m.vertices.extend([
                [qx, qy, depth],
                [qx + 1.0, qy, depth],
                [qx + 1.0, qy + 1.0, depth],
                [qx, qy + 1.0, depth],
            ]);
            m.indices
                .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
    m
}

fn f32s_hex(m: &TileMesh) -> (String, String) {
    let v: Vec<u8> = m
        .vertices
        .iter()
        .flatten()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let i: Vec<u8> = m.indices.iter().flat_map(|k| k.to_le_bytes()).collect();
    (hex(&v), hex(&i))
}

fn mesh_vectors() -> Vec<Value> {
    let plain = TileMesh {
        vertices: vec![[0.5, 0.5, 3.0], [0.5, 0.5, 4.0], [2.5, 0.5, 3.0]],
        indices: vec![0, 1, 2],
    };
    let cases = [
        ("grid on pixel centres", mesh(1, 9, (64.5, 32.5), false)),
        ("grid with pixel quads", mesh(2, 12, (0.5, 0.5), true)),
        ("grid off pixel centres", mesh(3, 8, (10.25, 20.625), false)),
        ("plain", plain),
    ];
    let coding = MeshCoding::for_parallax(128, 0.5, 0.25);
    cases
        .into_iter()
        .map(|(what, m)| {
            let bytes = encode_mesh(&m, &coding).unwrap();
            let runs: Vec<Value> = variants(&bytes)
                .into_iter()
                .map(|(name, b)| match decode_mesh(&b) {
                    Ok(m) => {
                        let (v, i) = f32s_hex(&m);
                        json!({"name": name, "input": hex(&b), "vertices": v, "indices": i})
                    }
                    Err(e) => json!({"name": name, "input": hex(&b), "error": e.to_string()}),
                })
                .collect();
            json!({"what": what, "runs": runs})
        })
        .collect()
}

fn tile(k: u32, slab: u32, ranges: usize, mesh: bool) -> TileEntry {
    let levels = (0..ranges)
        .map(|l| {
            let level = (ranges - 1 - l) as u32;
            let (w, h) = codec::ptm::level_dims(32, 32, level);
            LevelRef {
                level,
                width: w,
                height: h,
                offset: 0,
                len: 40 + (k as u64 * 7 + l as u64 * 13) % 300,
                hash: format!("{:08x}", k * 0x9e37_79b9 + l as u32),
            }
        })
        .collect();
    TileEntry {
        tile: TileId {
            face: Face::ALL[(k % 6) as usize],
            tx: k % 4,
            ty: (k / 4) % 4,
        },
        slab,
        depth_min: 3.0 + k as f64 * 0.37,
        depth_max: 9.0 + k as f64 * 1.5,
        opaque_pixels: 100 + k * 3,
        kept: !k.is_multiple_of(5),
        ptm: (ranges > 0).then(|| PtmRef {
            object: ObjectRef {
                hash: String::new(),
                size: 0,
            },
            width: 32,
            height: 32,
            channels: 4,
            levels,
        }),
        mesh: None,
        mesh_range: (mesh && ranges > 0).then(|| PackRange {
            offset: 0,
            len: 60 + k as u64 % 90,
            hash: format!("{:08x}", k * 0x85eb_ca6b),
        }),
    }
}

/// A table whose payloads lie back to back in its pack, as `db::pack` lays them out.
fn table(count: u32) -> (ViewTable, ObjectRef) {
    let mut background: Vec<BackgroundTile> = (0..usize::from(count > 3) * 2)
        .map(|k| BackgroundTile {
            tile: TileId {
                face: Face::ALL[k],
                tx: 0,
                ty: 1,
            },
            ptm: tile(k as u32, 0, 3, false).ptm.unwrap(),
        })
        .collect();
    let mut tiles: Vec<TileEntry> = (0..count)
        .map(|k| {
            tile(
                k,
                k % 3,
                (k % 4) as usize + usize::from(k % 7 != 0),
                k % 2 == 0,
            )
        })
        .collect();
    tiles.sort_by_key(|t| (t.slab, t.tile.face, t.tile.ty, t.tile.tx));
    tiles.dedup_by_key(|t| (t.slab, t.tile.face, t.tile.ty, t.tile.tx));
    let mut cursor = 0;
    for p in background.iter_mut().map(|b| &mut b.ptm) {
        for l in &mut p.levels {
            l.offset = cursor;
            cursor += l.len;
        }
    }
    for t in &mut tiles {
        if let Some(m) = &mut t.mesh_range {
            m.offset = cursor;
            cursor += m.len;
        }
        if let Some(p) = &mut t.ptm {
            for l in &mut p.levels {
                l.offset = cursor;
                cursor += l.len;
            }
        }
    }
    let pack = ObjectRef {
        hash: db::hash_hex(format!("pack {count}").as_bytes()),
        size: cursor,
    };
    for p in background
        .iter_mut()
        .map(|b| &mut b.ptm)
        .chain(tiles.iter_mut().filter_map(|t| t.ptm.as_mut()))
    {
        p.object = pack.clone();
    }
    for t in &mut tiles {
        if t.mesh_range.is_some() {
            t.mesh = Some(pack.clone());
        }
    }
    let table = ViewTable {
        viewpoint: 3,
        background,
        tiles,
        segments: Vec::new(),
    };
    (table, pack)
}

/// A decoded table as the browser's decoder returns it.
fn table_json(t: &ViewTable) -> Value {
    let ptm = |p: &PtmRef| {
        json!({
            "width": p.width, "height": p.height, "channels": p.channels,
            "levels": p.levels.iter().map(|l| json!({
                "level": l.level, "width": l.width, "height": l.height,
                "offset": l.offset, "len": l.len, "hash": l.hash,
            })).collect::<Vec<_>>(),
        })
    };
    let face = |f: Face| Face::ALL.iter().position(|&g| g == f).unwrap();
    json!({
        "background": t.background.iter().map(|b| json!({
            "face": face(b.tile.face), "tx": b.tile.tx, "ty": b.tile.ty, "ptm": ptm(&b.ptm),
        })).collect::<Vec<_>>(),
        "tiles": t.tiles.iter().map(|e| json!({
            "face": face(e.tile.face), "tx": e.tile.tx, "ty": e.tile.ty, "slab": e.slab,
            "kept": e.kept, "opaque": e.opaque_pixels,
            "depthMin": e.depth_min, "depthMax": e.depth_max,
            "ptm": e.ptm.as_ref().map(ptm),
            "mesh": e.mesh_range.as_ref().map(|m| json!({"offset": m.offset, "len": m.len, "hash": m.hash})),
        })).collect::<Vec<_>>(),
    })
}

fn table_vectors() -> Vec<Value> {
    [("small, plain body", 1), ("larger, gzipped body", 60)]
        .into_iter()
        .map(|(what, count)| {
            let (t, pack) = table(count);
            let bytes = encode_table(&t, Some(&pack)).unwrap();
            let runs: Vec<Value> = variants(&bytes)
                .into_iter()
                .map(|(name, b)| match decode_table(&b, 3) {
                    Ok(t) => json!({"name": name, "input": hex(&b), "ok": table_json(&t)}),
                    Err(e) => json!({"name": name, "input": hex(&b), "error": e.to_string()}),
                })
                .collect();
            json!({"what": what, "coding": bytes[5], "runs": runs})
        })
        .collect()
}

fn hash_vectors() -> Vec<Value> {
    let data: Vec<u8> = (0..5000u32).map(|i| (i % 251) as u8).collect();
    [0usize, 1, 64, 65, 1023, 1024, 1025, 2048, 3073, 5000]
        .into_iter()
        .map(|n| {
            let b = &data[..n];
            json!({"len": n, "hash": db::hash_hex(b), "range32": db::range_hash32(b)})
        })
        .collect()
}

#[test]
fn web_vectors_are_what_the_codec_writes() {
    let all = json!({
        "about": "written by streamer/db/tests/web_vectors.rs; inputs and outputs in hex",
        "ptm": ptm_vectors(),
        "mesh": mesh_vectors(),
        "table": table_vectors(),
        "blake3": hash_vectors(),
    });
    // Both table codings and damage the decoders notice must be covered.
    assert!(all["table"]
        .as_array()
        .unwrap()
        .iter()
        .any(|t| t["coding"] == 0));
    assert!(all["table"]
        .as_array()
        .unwrap()
        .iter()
        .any(|t| t["coding"] == 1));
    for kind in ["ptm", "mesh", "table"] {
        let errors = all[kind]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|v| v["runs"].as_array().unwrap())
            .filter(|r| r.get("error").is_some())
            .count();
        assert!(errors > 0, "no {kind} vector fails to decode");
    }
    let text = serde_json::to_string_pretty(&all).unwrap() + "\n";
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../viewer/web/test/vectors.json");
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    if std::env::var_os("RAILVIEW_BLESS_WEB_VECTORS").is_some() {
        std::fs::write(&path, &text).unwrap();
    } else {
        assert!(
            on_disk == text,
            "{} is not what the codec writes today; rewrite it with \
             RAILVIEW_BLESS_WEB_VECTORS=1 cargo test -p db --test web_vectors",
            path.display()
        );
    }
}
