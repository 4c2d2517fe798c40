use tracks::manifest::{
    AchEntry, BackgroundTile, LevelRef, ObjectRef, PackRange, PtmRef, SegmentEntry, TileEntry,
};
use tracks::{Face, TileId};

use super::encode::{f16_bound, f32_bound};
use super::*;
use crate::split::ViewTable;
use proptest::prelude::*;

fn hex(n: usize, seed: u64) -> String {
    (0..n)
        .map(|i| {
            let d = (seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(i as u64 * 0x9e37_79b9)
                >> 11)
                % 16;
            char::from_digit(d as u32, 16).unwrap()
        })
        .collect()
}

prop_compose! {
    /// A tile before its place in the pack is known (offsets 0; see `lay_out`).
    fn tile()(face in 0usize..6, tx in 0u32..300, ty in 0u32..300, slab in 0u32..4,
              d0 in 0.0f64..1e4, dd in 0.0f64..1e4, opaque in any::<u32>(), kept in any::<bool>(),
              seed in any::<u64>(), mesh in any::<bool>(), levels in 0usize..7,
              sizes in proptest::collection::vec(1u64..50_000, 8)) -> TileEntry {
        let levels: Vec<LevelRef> = (0..levels).map(|l| LevelRef {
            level: (levels - 1 - l) as u32, width: 1 << l, height: 1 << l,
            offset: 0, len: sizes[l], hash: hex(16, seed ^ l as u64),
        }).collect();
        let has_ptm = !levels.is_empty();
        TileEntry {
            tile: TileId { face: Face::ALL[face], tx, ty },
            slab,
            depth_min: d0,
            depth_max: d0 + dd,
            opaque_pixels: opaque,
            kept,
            ptm: has_ptm.then(|| PtmRef {
                object: ObjectRef { hash: String::new(), size: 0 },
                width: 1 << levels.len(),
                height: 1 << levels.len(),
                channels: 4,
                levels,
            }),
            mesh: None,
            mesh_range: (mesh && has_ptm).then(|| PackRange {
                offset: 0, len: sizes[7], hash: hex(16, !seed),
            }),
        }
    }
}

/// Places the tiles' payloads back to back and names the pack.
fn lay_out(tiles: &mut [TileEntry], seed: u64) -> Option<ObjectRef> {
    let mut cursor = 0;
    for t in tiles.iter_mut() {
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
    let pack = tiles.iter().any(|t| t.ptm.is_some()).then(|| ObjectRef {
        hash: hex(64, seed),
        size: cursor,
    });
    for t in tiles.iter_mut() {
        if let Some(p) = &mut t.ptm {
            p.object = pack.clone().unwrap();
        }
    }
    pack
}

/// [`lay_out`] with some payloads elsewhere: by `choices` per tile (mesh, then PTM) in the
/// pack in order, pointing back at the pack's first bytes, or in one of two earlier packs.
/// A mesh names its object only when the PTM's object is another one.
fn lay_out_shared(tiles: &mut [TileEntry], choices: &[u8], seed: u64) -> Option<ObjectRef> {
    let others = [1u64, 2].map(|k| ObjectRef {
        hash: hex(64, seed.wrapping_add(k)),
        size: 1 << 30,
    });
    let own = ObjectRef {
        hash: hex(64, seed),
        size: 0,
    };
    let mut cursor = 0;
    let mut place = |len: u64, c: u8| -> (ObjectRef, u64) {
        match c % 4 {
            2 => (others[0].clone(), u64::from(c) * 1000),
            3 if len <= cursor => (own.clone(), 0),
            3 => (others[1].clone(), 7),
            _ => {
                cursor += len;
                (own.clone(), cursor - len)
            }
        }
    };
    for (t, &c) in tiles.iter_mut().zip(choices.iter().cycle()) {
        let mut mesh_obj = None;
        if let Some(m) = &mut t.mesh_range {
            let (o, at) = place(m.len, c);
            m.offset = at;
            mesh_obj = Some(o);
        }
        if let Some(p) = &mut t.ptm {
            let len: u64 = p.levels.iter().map(|l| l.len).sum();
            let (o, mut at) = place(len, c / 4);
            for l in &mut p.levels {
                l.offset = at;
                at += l.len;
            }
            p.object = o;
        }
        t.mesh = mesh_obj.filter(|o| Some(o) != t.ptm.as_ref().map(|p| &p.object));
    }
    let used = tiles.iter().any(|t| {
        t.ptm.as_ref().is_some_and(|p| p.object == own)
            || t.mesh_at().is_some_and(|(o, _)| *o == own)
    });
    let pack = used.then(|| ObjectRef {
        hash: own.hash.clone(),
        size: cursor,
    });
    for t in tiles.iter_mut() {
        for o in t
            .ptm
            .as_mut()
            .map(|p| &mut p.object)
            .into_iter()
            .chain(t.mesh.as_mut())
        {
            if *o == own {
                *o = pack.clone().unwrap();
            }
        }
    }
    pack
}

/// What a table keeps of a tile: depths as f16 bounds when all fit, else f32; ACH as f32.
fn as_stored(mut t: ViewTable) -> ViewTable {
    let f16 = |x: f64, up: bool| f16_bound(x, up).map(|b| half::f16::from_bits(b).to_f64());
    let all16 = t
        .tiles
        .iter()
        .all(|d| f16(d.depth_min, false).is_some() && f16(d.depth_max, true).is_some());
    for tile in &mut t.tiles {
        if all16 {
            tile.depth_min = f16(tile.depth_min, false).unwrap();
            tile.depth_max = f16(tile.depth_max, true).unwrap();
        } else {
            tile.depth_min = f32_bound(tile.depth_min, false) as f64;
            tile.depth_max = f32_bound(tile.depth_max, true) as f64;
        }
    }
    // The ACH lists travel in an object of their own.
    t.segments.clear();
    t
}

/// What an ACH object keeps of the lists: values as f32.
fn ach_as_stored(mut segments: Vec<SegmentEntry>) -> Vec<SegmentEntry> {
    for s in &mut segments {
        for a in &mut s.ach {
            a.ach = a.ach as f32 as f64;
        }
    }
    segments
}

fn sample(viewpoint: usize, tiles: Vec<TileEntry>, seed: u64) -> (ViewTable, Option<ObjectRef>) {
    // Every third tile with a PTM lends it to a background tile too (payloads first).
    let mut all: Vec<TileEntry> = tiles
        .iter()
        .filter(|t| t.ptm.is_some())
        .step_by(3)
        .map(|t| {
            background_entry(&BackgroundTile {
                tile: t.tile,
                ptm: t.ptm.clone().unwrap(),
            })
        })
        .collect();
    let nb = all.len();
    all.extend(tiles);
    let pack = lay_out(&mut all, seed);
    let tiles = all.split_off(nb);
    let background = all
        .into_iter()
        .map(|t| BackgroundTile {
            tile: t.tile,
            ptm: t.ptm.unwrap(),
        })
        .collect();
    let ach = tiles
        .iter()
        .enumerate()
        .map(|(i, t)| AchEntry {
            viewpoint: viewpoint + i % 3,
            slab: t.slab,
            tile: t.tile,
            ach: 1.0 / (i as f64 + 1.5),
        })
        .collect();
    let segments = vec![SegmentEntry {
        from: viewpoint,
        to: viewpoint + 1,
        ach,
    }];
    (
        ViewTable {
            viewpoint,
            background,
            tiles,
            segments,
        },
        pack,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn tables_round_trip(viewpoint in 0usize..100_000,
                         tiles in proptest::collection::vec(tile(), 0..40), seed in any::<u64>()) {
        let (table, pack) = sample(viewpoint, tiles, seed);
        let bytes = encode_table(&table, pack.as_ref()).unwrap();
        let got = decode_table(&bytes, viewpoint).unwrap();
        prop_assert_eq!(&got, &as_stored(table.clone()));
        // Depth bounds never shrink.
        for (g, t) in got.tiles.iter().zip(&table.tiles) {
            prop_assert!(g.depth_min <= t.depth_min && g.depth_max >= t.depth_max);
        }
        let other = matches!(decode_table(&bytes, viewpoint + 1),
                             Err(TableError::Viewpoint { .. }));
        prop_assert!(other);
        // The ACH object: the same lists (f32 values), never taken for another viewpoint
        // or for a table.
        let ach = encode_ach(viewpoint, &table.segments).unwrap();
        prop_assert_eq!(decode_ach(&ach, viewpoint).unwrap(),
                        ach_as_stored(table.segments.clone()));
        let other = matches!(decode_ach(&ach, viewpoint + 1),
                             Err(TableError::Viewpoint { .. }));
        prop_assert!(other);
        prop_assert!(matches!(decode_table(&ach, viewpoint), Err(TableError::Magic)));
        prop_assert!(matches!(decode_ach(&bytes, viewpoint), Err(TableError::AchMagic)));
    }

    /// Payloads stored once: some in earlier packs at any offset, some pointing back at an
    /// earlier range of the pack; the rest in the pack in table order.
    #[test]
    fn payloads_stored_elsewhere_round_trip(tiles in proptest::collection::vec(tile(), 0..30),
                                             choices in proptest::collection::vec(0u8..16, 30),
                                             seed in any::<u64>()) {
        let (mut table, _) = sample(9, tiles, seed);
        let pack = lay_out_shared(&mut table.tiles, &choices, seed);
        // Background tiles stay in the pack, first.
        let mut all: Vec<TileEntry> = table.background.iter().map(background_entry).collect();
        let mut cursor = 0;
        for t in &mut all {
            let p = t.ptm.as_mut().unwrap();
            for l in &mut p.levels {
                l.offset = cursor;
                cursor += l.len;
            }
        }
        // Shift the tiles' own-pack payloads past the background.
        let own = pack.as_ref().map(|p| p.hash.clone());
        let mut size = pack.as_ref().map_or(0, |p| p.size) + cursor;
        let any_background = !all.is_empty();
        if own.is_none() && any_background {
            size = cursor;
        }
        let pack = (own.is_some() || any_background).then(|| ObjectRef {
            hash: own.clone().unwrap_or_else(|| hex(64, seed.wrapping_add(7))),
            size,
        });
        for t in &mut table.tiles {
            let in_pack = |o: &ObjectRef| Some(&o.hash) == own.as_ref();
            if let Some(p) = &mut t.ptm {
                if in_pack(&p.object) {
                    for l in &mut p.levels {
                        l.offset += cursor;
                    }
                }
            }
            let mesh_in_pack = t.mesh_at().is_some_and(|(o, _)| in_pack(o));
            if let (true, Some(m)) = (mesh_in_pack, &mut t.mesh_range) {
                m.offset += cursor;
            }
            let objects = t.ptm.as_mut().map(|p| &mut p.object).into_iter().chain(t.mesh.as_mut());
            for o in objects {
                if in_pack(o) {
                    *o = pack.clone().unwrap();
                }
            }
        }
        table.background = all
            .into_iter()
            .map(|t| BackgroundTile {
                tile: t.tile,
                ptm: PtmRef {
                    object: pack.clone().unwrap(),
                    ..t.ptm.unwrap()
                },
            })
            .collect();
        let bytes = encode_table(&table, pack.as_ref()).unwrap();
        let got = decode_table(&bytes, 9).unwrap();
        prop_assert_eq!(&got, &as_stored(table.clone()));
    }

    /// Tiles in grid order (as `railview build` writes them) take the gap coding of
    /// positions; checksums of 32 bits; depths beyond f16 fall back to f32.
    #[test]
    fn sorted_tables_round_trip(tiles in proptest::collection::vec(tile(), 0..40),
                                far in any::<bool>(), seed in any::<u64>()) {
        let mut tiles = tiles;
        tiles.sort_by_key(|t| tile_index(301, t.slab, t.tile));
        tiles.dedup_by_key(|t| tile_index(301, t.slab, t.tile));
        for t in &mut tiles {
            if let Some(m) = &mut t.mesh_range {
                m.hash.truncate(8);
            }
            for l in t.ptm.iter_mut().flat_map(|p| p.levels.iter_mut()) {
                l.hash.truncate(8);
            }
            if far {
                t.depth_max *= 100.0;
            }
        }
        let (table, pack) = sample(11, tiles, seed);
        let bytes = encode_table(&table, pack.as_ref()).unwrap();
        let got = decode_table(&bytes, 11).unwrap();
        prop_assert_eq!(&got, &as_stored(table.clone()));
        for (g, t) in got.tiles.iter().zip(&table.tiles) {
            prop_assert!(g.depth_min <= t.depth_min && g.depth_max >= t.depth_max);
        }
    }

    #[test]
    fn damaged_or_cut_tables_never_panic(tiles in proptest::collection::vec(tile(), 1..12),
                                         at in any::<usize>(), bit in 0u8..8, cut in any::<usize>()) {
        let (table, pack) = sample(3, tiles, 7);
        let bytes = encode_table(&table, pack.as_ref()).unwrap();
        let mut flipped = bytes.clone();
        let i = at % flipped.len();
        flipped[i] ^= 1 << bit;
        let _ = decode_table(&flipped, 3);
        let _ = decode_table(&bytes[..cut % bytes.len()], 3);
    }

    #[test]
    fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode_table(&bytes, 0);
        let mut with_header = b"RVTB\x05\x00".to_vec();
        with_header.extend_from_slice(&bytes);
        let _ = decode_table(&with_header, 0);
        let _ = decode_ach(&bytes, 0);
        let mut with_header = b"RVAC\x01\x00".to_vec();
        with_header.extend_from_slice(&bytes);
        let _ = decode_ach(&with_header, 0);
    }

    #[test]
    fn damaged_or_cut_ach_objects_never_panic(tiles in proptest::collection::vec(tile(), 1..12),
                                              at in any::<usize>(), bit in 0u8..8, cut in any::<usize>()) {
        let (table, _) = sample(3, tiles, 7);
        let bytes = encode_ach(3, &table.segments).unwrap();
        let mut flipped = bytes.clone();
        let i = at % flipped.len();
        flipped[i] ^= 1 << bit;
        let _ = decode_ach(&flipped, 3);
        let _ = decode_ach(&bytes[..cut % bytes.len()], 3);
    }
}

fn one_tile_table() -> Vec<u8> {
    let tile = TileEntry {
        tile: TileId {
            face: Face::ALL[2],
            tx: 1,
            ty: 2,
        },
        slab: 1,
        depth_min: 1.0,
        depth_max: 2.0,
        opaque_pixels: 9,
        kept: true,
        ptm: Some(PtmRef {
            object: ObjectRef {
                hash: String::new(),
                size: 0,
            },
            width: 8,
            height: 8,
            channels: 4,
            levels: vec![LevelRef {
                level: 0,
                width: 8,
                height: 8,
                offset: 0,
                len: 100,
                hash: hex(16, 1),
            }],
        }),
        mesh: None,
        mesh_range: None,
    };
    let (table, pack) = sample(5, vec![tile], 9);
    encode_table(&table, pack.as_ref()).unwrap()
}

/// The long fuzz run of the table decoder (tables whose payloads lie in the pack, earlier
/// in it, or in earlier packs; damaged, cut or garbage):
/// `TABLE_FUZZ_CASES=1000000 cargo test --release -p db --lib table_long_fuzz -- --ignored`.
#[test]
#[ignore = "long fuzz run; set TABLE_FUZZ_CASES"]
fn table_long_fuzz() {
    use proptest::test_runner::{Config, TestRunner};
    let cases = std::env::var("TABLE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000);
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    });
    let strategy = (
        proptest::collection::vec(tile(), 0..10),
        proptest::collection::vec(0u8..16, 10),
        any::<u64>(),
        proptest::collection::vec((any::<usize>(), any::<u8>()), 0..4),
        any::<usize>(),
        proptest::collection::vec(any::<u8>(), 0..64),
    );
    runner
        .run(&strategy, |(tiles, choices, seed, flips, cut, junk)| {
            let (mut table, _) = sample(4, tiles, seed);
            table.background.clear();
            let pack = lay_out_shared(&mut table.tiles, &choices, seed);
            let bytes = encode_table(&table, pack.as_ref()).unwrap();
            prop_assert_eq!(decode_table(&bytes, 4).unwrap(), as_stored(table));
            let mut damaged = bytes.clone();
            for (at, x) in flips {
                let i = at % damaged.len();
                damaged[i] ^= x.max(1);
            }
            damaged.truncate(cut % (damaged.len() + 1));
            let _ = decode_table(&damaged, 4);
            let mut garbage = b"RVTB\x05\x00".to_vec();
            garbage.extend_from_slice(&junk);
            let _ = decode_table(&garbage, 0);
            Ok(())
        })
        .unwrap();
}

#[test]
fn named_bad_inputs_give_named_errors() {
    assert!(matches!(decode_table(b"", 0), Err(TableError::Magic)));
    assert!(matches!(
        decode_table(b"{\"v\":0}", 0),
        Err(TableError::Magic)
    ));
    assert!(matches!(
        decode_table(b"RVTB\x02\x00", 0),
        Err(TableError::Version { got: 2 })
    ));
    assert!(matches!(
        decode_table(b"RVTB\x05\x07xx", 0),
        Err(TableError::Coding(7))
    ));
    assert!(matches!(
        decode_table(b"RVTB\x05\x00", 0),
        Err(TableError::Truncated { .. })
    ));
    // A varint that never ends.
    assert!(matches!(
        decode_table(
            b"RVTB\x05\x00\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff",
            0
        ),
        Err(TableError::Invalid {
            what: "viewpoint",
            ..
        })
    ));
    // A tile count far beyond the bytes that follow: refused before any allocation.
    let mut b = b"RVTB\x05\x00\x00\x00\x00\x04\x00\x00\x00".to_vec();
    b.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0x0f]);
    assert!(matches!(
        decode_table(&b, 0),
        Err(TableError::Invalid {
            what: "tile count",
            ..
        })
    ));
    // Trailing bytes after a good body.
    let good = one_tile_table();
    let mut plain = good[..6].to_vec();
    plain[5] = 0;
    let body = if good[5] == 1 {
        crate::gunzip_limited(&good[6..], MAX_TABLE_BYTES).unwrap()
    } else {
        good[6..].to_vec()
    };
    plain.extend_from_slice(&body);
    assert_eq!(decode_table(&plain, 5).unwrap().tiles.len(), 1);
    plain.push(0);
    assert!(matches!(
        decode_table(&plain, 5),
        Err(TableError::Trailing(1))
    ));
}

#[test]
fn lengths_must_add_up_to_the_pack() {
    let (mut table, pack) = sample(1, Vec::new(), 0);
    assert!(pack.is_none());
    let bytes = encode_table(&table, None).unwrap();
    assert!(decode_table(&bytes, 1).unwrap().tiles.is_empty());
    // A pack bigger than the tiles' payloads is refused on both sides.
    let big = ObjectRef {
        hash: hex(64, 3),
        size: 10,
    };
    assert!(matches!(
        encode_table(&table, Some(&big)),
        Err(TableError::Layout(_))
    ));
    // A tile whose PTM is not in the pack, or whose mesh is an object of its own.
    let bytes = one_tile_table();
    let mut t = decode_table(&bytes, 5).unwrap();
    let pack = t.tiles[0].ptm.as_ref().unwrap().object.clone();
    t.tiles[0].mesh = Some(pack.clone());
    assert!(matches!(
        encode_table(&t, Some(&pack)),
        Err(TableError::Layout(_))
    ));
    table.viewpoint = 5;
    table.tiles = t.tiles.clone();
    table.tiles[0].mesh = None;
    let other = ObjectRef {
        hash: hex(64, 4),
        size: 100,
    };
    assert!(matches!(
        encode_table(&table, Some(&other)),
        Err(TableError::Layout(_))
    ));
}

#[test]
fn a_huge_table_is_refused_within_the_limit() {
    let zeros = vec![0u8; (MAX_TABLE_BYTES + 10) as usize];
    let mut b = b"RVTB\x05\x01".to_vec();
    b.extend_from_slice(&crate::gzip(&zeros).unwrap());
    assert!(matches!(
        decode_table(&b, 0),
        Err(TableError::Gzip(crate::GunzipError::TooLarge { .. }))
    ));
}
