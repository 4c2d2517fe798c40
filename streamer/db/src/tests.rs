//! Database writer/reader/verify tests on a tiny database.

use std::path::{Path, PathBuf};

use glam::DVec3;
use tracks::manifest::*;
use tracks::{Face, SlabRange, TileId};

use super::*;
use codec::mesh::{encode_mesh, MeshCoding, TileMesh};
use codec::ptm::{encode, EncodeOptions, Image};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("railview-db-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

/// Writes a small database: 2 viewpoints, 3 tiles each (one culled), a background each.
fn build(dir: &Path) -> (Manifest, DbWriter) {
    let mut w = DbWriter::create(dir).unwrap();
    let mut viewpoints = Vec::new();
    for v in 0..2usize {
        let mut tiles = Vec::new();
        for t in 0..3u32 {
            let tile = TileId {
                face: Face::ALL[t as usize],
                tx: t,
                ty: 1,
            };
            let kept = t != 2;
            let (ptm, mesh) = if kept {
                let img = Image::from_fn(16, 16, 4, |x, y, c| {
                    (x * 9 + y * 3 + c as u32 * 50 + v as u32 * 7 + t) as u8
                });
                let enc = encode(&img, &EncodeOptions::default()).unwrap();
                let mesh = TileMesh {
                    vertices: vec![
                        [0.5, 0.5, 3.0],
                        [15.5, 0.5, 3.5],
                        [0.5, 15.5, 4.0 + t as f32 * 10.0 + v as f32],
                    ],
                    indices: vec![0, 1, 2],
                };
                (
                    Some(w.put_ptm(&enc, 4).unwrap()),
                    Some(
                        w.put(
                            &encode_mesh(&mesh, &MeshCoding::for_parallax(16, 1.0, 0.05)).unwrap(),
                        )
                        .unwrap(),
                    ),
                )
            } else {
                (None, None)
            };
            tiles.push(TileEntry {
                tile,
                slab: t % 2,
                depth_min: 3.0,
                depth_max: 5.0,
                opaque_pixels: 200,
                kept,
                ptm,
                mesh,
                mesh_range: None,
            });
        }
        let bg = Image::from_fn(16, 16, 4, |x, y, c| (x + y + c as u32 + v as u32) as u8);
        let background = vec![BackgroundTile {
            tile: TileId {
                face: Face::PosY,
                tx: 1,
                ty: 0,
            },
            ptm: w
                .put_ptm(&encode(&bg, &EncodeOptions::default()).unwrap(), 4)
                .unwrap(),
        }];
        viewpoints.push(ViewpointEntry {
            index: v,
            s: v as f64 * 2.0,
            position: DVec3::new(v as f64 * 2.0, 1.7, 0.0),
            background,
            tiles,
        });
    }
    let m = Manifest {
        version: MANIFEST_VERSION,
        scene: "test".into(),
        face_size: 32,
        tile_size: 16,
        slabs: vec![
            SlabRange {
                near: 0.0,
                far: 4.0,
            },
            SlabRange {
                near: 4.0,
                far: f64::INFINITY,
            },
        ],
        cull_alpha: Some(1.0),
        cull_variant: Some("conservative".into()),
        tracks: vec![TrackEntry {
            name: "main".into(),
            track_toml:
                "[[track]]\nname = \"main\"\npoints = [[0, 1.7, 0], [2, 1.7, 0]]\ncount = 2\n"
                    .into(),
            length: 2.0,
            viewpoints,
            segments: vec![SegmentEntry {
                from: 0,
                to: 1,
                ach: vec![],
            }],
        }],
    };
    let packed = w.finish(&m).unwrap();
    (packed, w)
}

fn all_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = vec![];
    for e in fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(all_files(&p));
        } else {
            out.push(p);
        }
    }
    out.sort();
    out
}

#[test]
fn write_open_read_levels() {
    let dir = tmpdir("rw");
    let (m, w) = build(&dir);
    // 4 tile PTMs, 2 background tiles, 4 meshes, 2 packs, 2 viewpoint tables, the ACH
    // object of viewpoint 0 (the one segment starts there) and the index's one chunk, all
    // distinct.
    assert_eq!(w.objects_written, 16);
    drop(w); // a second writer waits for the first to end
    let db = Database::open(&dir).unwrap();
    assert_eq!(db.manifest(), &m);
    let tile = &m.tracks[0].viewpoints[1].tiles[0];
    let p = tile.ptm.as_ref().unwrap();
    let whole = db.read_object(&p.object).unwrap();
    // The tile's ranges lie back to back in the viewpoint's pack, after its mesh.
    let mesh = tile.mesh_range.as_ref().unwrap();
    assert_eq!(mesh.offset + mesh.len, p.levels[0].offset);
    let mesh_bytes = db.read_checked_range(&p.object, mesh).unwrap();
    assert_eq!(
        &whole[mesh.offset as usize..p.levels[0].offset as usize],
        &mesh_bytes[..]
    );
    let mut stream = Vec::new();
    for g in 0..p.levels.len() {
        stream.extend(db.read_level(p, g).unwrap());
    }
    let start = p.levels[0].offset as usize;
    assert_eq!(&stream[..], &whole[start..start + stream.len()]);
    assert_eq!(
        codec::ptm::decode(&stream, codec::ptm::Limits::default())
            .unwrap()
            .width(),
        16
    );
    assert!(db.read_level(p, p.levels.len()).is_err());
    assert!(db.read_range(&p.object, p.object.size - 1, 2).is_err());
    assert!(db.read_range(&p.object, u64::MAX, 2).is_err());
    assert!(db.object_path("../../etc/passwd").is_none());
    // Rebuilding reuses every object (resume).
    let (_, w2) = build(&dir);
    assert_eq!((w2.objects_written, w2.objects_reused), (0, 16));
    let r = verify(&dir).unwrap();
    assert!(r.is_intact(), "{r:?}");
    assert_eq!(
        (
            r.objects_referenced,
            r.files_checked,
            r.level_ranges_checked,
            r.tables_checked
        ),
        // Two packs, two tables, one ACH object, one chunk of the index.
        (2 + 2 + 1 + 1, 16, r.level_ranges_checked, 2)
    );
    // At least one range per background tile, every tile's mesh and one PTM range.
    assert!(r.level_ranges_checked >= 2 + 4 * 2);
    // The tiles' own objects (4 PTMs, 4 meshes, 2 background PTMs) stay for a resumed build:
    // notes, not damage (more than 8: counted in one note).
    assert_eq!(r.notes.len(), 1, "{:?}", r.notes);
    assert!(r.notes[0].what.starts_with("10 objects"), "{:?}", r.notes);
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn prune_removes_only_what_the_manifest_does_not_reference_and_only_when_intact() {
    let dir = tmpdir("prune");
    let (m, mut w) = build(&dir);
    w.finish(&m).unwrap();
    // A writer still holding the directory: nothing is removed under it.
    assert!(prune(&dir).is_err());
    drop(w);
    let before = verify(&dir).unwrap();
    assert_eq!(before.unreferenced.len(), 10, "the tiles' own objects");
    let pruned = prune(&dir).unwrap();
    assert_eq!(pruned.objects, 10);
    assert_eq!(
        pruned.bytes,
        before.unreferenced.iter().map(|u| u.1).sum::<u64>()
    );
    let after = verify(&dir).unwrap();
    assert!(after.is_intact() && after.unreferenced.is_empty() && after.notes.is_empty());
    assert_eq!(after.objects_referenced, before.objects_referenced);
    assert!(Database::open(&dir).is_ok());
    // A database with a missing object is not pruned: an error naming it, nothing removed.
    let stray = dir.join(object_rel_path(&hash_hex(b"stray")).unwrap());
    write_atomic(&stray, b"stray").unwrap();
    let table = dir.join(m_table_path(&dir));
    fs::remove_file(&table).unwrap();
    let err = prune(&dir).unwrap_err().to_string();
    assert!(err.contains("nothing pruned"), "{err}");
    assert!(stray.exists());
    fs::remove_dir_all(&dir).unwrap();
}

/// The path of the first viewpoint's table.
fn m_table_path(dir: &Path) -> PathBuf {
    let db = Database::open(dir).unwrap();
    let v = &db.top().viewpoints[0];
    dir.join(object_rel_path(&v.table.hash).unwrap())
}

#[test]
fn a_flipped_byte_in_any_file_is_caught_and_named() {
    let dir = tmpdir("flip");
    build(&dir);
    let files = all_files(&dir);
    assert_eq!(files.len(), 19);
    assert!(files.contains(&dir.join(MANIFEST_GZ_FILE)));
    for f in &files {
        let orig = fs::read(f).unwrap();
        // Every byte of the small files (the gzip copy's header included), three of the rest.
        let ats: Vec<usize> = if orig.len() <= 128 {
            (0..orig.len()).collect()
        } else {
            vec![0, 5, 9, orig.len() / 2, orig.len() - 1]
        };
        for at in ats {
            let mut bad = orig.clone();
            bad[at] ^= 0x10;
            fs::write(f, &bad).unwrap();
            let r = verify(&dir).unwrap();
            assert!(!r.is_intact(), "{} byte {at}", f.display());
            assert!(
                r.problems.iter().any(|p| &p.path == f),
                "{} byte {at}: {:?}",
                f.display(),
                r.problems
            );
        }
        fs::write(f, &orig).unwrap();
    }
    assert!(verify(&dir).unwrap().is_intact());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn missing_truncated_and_stray_files() {
    let dir = tmpdir("missing");
    let (m, _) = build(&dir);
    let pack = m.tracks[0].viewpoints[1].tiles[0]
        .ptm
        .clone()
        .unwrap()
        .object;
    let mesh_path = dir.join(pack.rel_path().unwrap());
    fs::remove_file(&mesh_path).unwrap();
    let r = verify(&dir).unwrap();
    assert_eq!(r.problems.len(), 1, "{r:?}");
    assert_eq!(r.problems[0].path, mesh_path);
    assert!(r.problems[0].what.contains("missing"));
    // Leftover temporary files (this writer's, the `tempfile` crate's, anywhere in the
    // database) are stray files, an unreferenced object a note; neither is damage.
    let temps = [
        mesh_path.with_file_name(".x.tmp.1"),
        dir.join("objects").join(".tmpAbC123"),
        dir.join(".manifest.json.tmp.77"),
    ];
    for t in &temps {
        fs::write(t, b"partial").unwrap();
    }
    let stray = dir.join(object_rel_path(&hash_hex(b"stray")).unwrap());
    write_atomic(&stray, b"stray").unwrap();
    let r = verify(&dir).unwrap();
    assert_eq!(r.problems.len(), 1);
    assert_eq!(r.notes.len(), 1, "{:?}", r.notes);
    let mut found: Vec<_> = r.stray.iter().map(|p| p.path.clone()).collect();
    found.sort();
    let mut want = temps.to_vec();
    want.sort();
    assert_eq!(found, want);
    // On request they are removed, and only they.
    let opts = VerifyOptions {
        remove_temp: true,
        ..Default::default()
    };
    let r = verify_with(&dir, opts).unwrap();
    assert_eq!(r.removed.len(), 3);
    assert!(temps.iter().all(|t| !t.exists()) && stray.exists());
    assert!(verify(&dir).unwrap().stray.is_empty());
    // Truncating a pack: its hash, size and ranges are all reported on that file.
    let p = m.tracks[0].viewpoints[0].tiles[0].ptm.clone().unwrap();
    let pp = dir.join(p.object.rel_path().unwrap());
    let bytes = fs::read(&pp).unwrap();
    fs::write(&pp, &bytes[..bytes.len() - 3]).unwrap();
    let r = verify(&dir).unwrap();
    assert!(
        r.problems.iter().filter(|x| x.path == pp).count() >= 3,
        "{:?}",
        r.problems
    );
    // No manifest at all.
    fs::remove_file(dir.join(MANIFEST_FILE)).unwrap();
    let r = verify(&dir).unwrap();
    assert!(r.problems.iter().any(|x| x.path == dir.join(MANIFEST_FILE)));
    assert!(Database::open(&dir).is_err());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn manifest_is_compact_and_its_gzip_copy_matches() {
    let dir = tmpdir("gz");
    let (m, _) = build(&dir);
    let json = fs::read(dir.join(MANIFEST_FILE)).unwrap();
    assert!(
        !json[..json.len() - 1].contains(&b'\n'),
        "manifest is not compact"
    );
    assert_eq!(
        fs::read_to_string(dir.join(MANIFEST_HASH_FILE)).unwrap(),
        format!("{}\n", hash_hex(&json))
    );
    let gz = fs::read(dir.join(MANIFEST_GZ_FILE)).unwrap();
    assert!(gz.len() < json.len());
    assert_eq!(gunzip_limited(&gz, json.len() as u64).unwrap(), json);
    assert_eq!(read_manifest(&dir).unwrap(), m);
    // An older database without the copy is intact; verify says it is absent.
    fs::remove_file(dir.join(MANIFEST_GZ_FILE)).unwrap();
    let r = verify(&dir).unwrap();
    assert!(r.is_intact(), "{r:?}");
    assert!(
        r.notes
            .iter()
            .any(|n| n.path == dir.join(MANIFEST_GZ_FILE) && n.what.contains("absent")),
        "{:?}",
        r.notes
    );
    // A copy of another manifest (stale) is damage, named on the .gz.
    let mut other = json.clone();
    other[1] = b' ';
    fs::write(dir.join(MANIFEST_GZ_FILE), gzip(&other).unwrap()).unwrap();
    let r = verify(&dir).unwrap();
    assert_eq!(r.problems.len(), 1, "{r:?}");
    assert_eq!(r.problems[0].path, dir.join(MANIFEST_GZ_FILE));
    assert!(r.problems[0].what.contains("first at byte 1"), "{r:?}");
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn gunzip_is_bounded_and_rejects_garbage() {
    let zeros = vec![0u8; 1 << 20];
    let gz = gzip(&zeros).unwrap();
    assert!(gz.len() < 4096);
    assert_eq!(gunzip_limited(&gz, 1 << 20).unwrap().len(), 1 << 20);
    assert!(matches!(
        gunzip_limited(&gz, (1 << 20) - 1),
        Err(GunzipError::TooLarge { limit }) if limit == (1 << 20) - 1
    ));
    assert!(matches!(
        gunzip_limited(b"{\"not\":\"gzip\"}", 1 << 20),
        Err(GunzipError::Invalid(_))
    ));
    assert!(matches!(
        gunzip_limited(&gz[..gz.len() - 4], 1 << 20),
        Err(GunzipError::Invalid(_))
    ));
    assert_eq!(gunzip_limited(&gzip(b"").unwrap(), 0).unwrap(), b"");
}

#[test]
fn a_missing_or_damaged_table_is_reported_by_viewpoint() {
    let dir = tmpdir("tables");
    build(&dir);
    let top = read_top(&dir).unwrap();
    let v1 = &top.viewpoints[1];
    let path = dir.join(v1.table.rel_path().unwrap());
    let orig = fs::read(&path).unwrap();
    // Damaged: the hash names it, by viewpoint.
    let mut bad = orig.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 1;
    fs::write(&path, &bad).unwrap();
    let r = verify(&dir).unwrap();
    let p = r
        .problems
        .iter()
        .find(|p| p.path == path && p.what.contains("table of viewpoint 1"))
        .unwrap_or_else(|| panic!("{:?}", r.problems));
    assert!(p.what.contains("damaged"), "{}", p.what);
    assert_eq!(r.tables_checked, 1);
    assert!(Database::open(&dir).is_err());
    // A right hash over bytes that are not a table (the object store holds what the top
    // says, but it does not decode): still named.
    fs::remove_file(&path).unwrap();
    let r = verify(&dir).unwrap();
    assert!(
        r.problems.iter().any(|p| p.path == path
            && p.what.contains("viewpoint 1")
            && p.what.contains("missing")),
        "{:?}",
        r.problems
    );
    fs::write(&path, &orig).unwrap();
    assert!(verify(&dir).unwrap().is_intact());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_table_that_does_not_decode_is_reported() {
    let dir = tmpdir("table-decode");
    let (m, _) = build(&dir);
    // Rewrite the top manifest so viewpoint 0's table is a valid object that is no table.
    let mut w = DbWriter::create(&dir).unwrap();
    let junk = w.put(&gzip(b"{\"not\":\"a table\"}").unwrap()).unwrap();
    let (mut top, _) = split::split(&m).unwrap();
    top.viewpoints[0].table = junk.clone();
    write_index(&mut w, &top);
    let r = verify(&dir).unwrap();
    let junk_path = dir.join(junk.rel_path().unwrap());
    assert!(
        r.problems.iter().any(|p| p.path == junk_path
            && p.what.contains("viewpoint 0")
            && p.what.contains("RVTB")),
        "{:?}",
        r.problems
    );
    let err = Database::open(&dir).unwrap_err().to_string();
    assert!(err.contains("viewpoint 0"), "{err}");
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_format_1_manifest_is_refused_with_a_request_to_rebuild() {
    let dir = tmpdir("v1");
    let (m, _) = build(&dir);
    // The old layout: the whole manifest in one file.
    let json = serde_json::to_vec(&m).unwrap();
    write_atomic(&dir.join(MANIFEST_FILE), &json).unwrap();
    fs::remove_file(dir.join(MANIFEST_HASH_FILE)).unwrap();
    let err = Database::open(&dir).unwrap_err().to_string();
    assert!(
        err.contains("manifest format 1") && err.contains("rebuild"),
        "{err}"
    );
    // Format 2 (JSON tables, a PTM object and a mesh object per tile): refused the same way.
    let json = br#"{"version":2,"scene":"x"}"#;
    write_atomic(&dir.join(MANIFEST_FILE), json).unwrap();
    let err = Database::open(&dir).unwrap_err().to_string();
    assert!(
        err.contains("manifest format 2") && err.contains("rebuild"),
        "{err}"
    );
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn split_and_assemble_round_trip_and_partial_tables_leave_tiles_out() {
    let dir = tmpdir("split");
    let (m, _) = build(&dir);
    let (top, bytes) = split::split(&m).unwrap();
    assert_eq!(top.version, TOP_VERSION);
    let tables: Vec<ViewTable> = top
        .viewpoints
        .iter()
        .zip(&bytes)
        .map(|(v, b)| {
            assert_eq!(hash_hex(&b.table), v.table.hash);
            let mut t = split::decode_table(&b.table, v.index).unwrap();
            // The ACH lists come from an object of their own (only 0 starts a segment).
            assert_eq!(b.ach.is_some(), v.index == 0);
            if let (Some(a), Some(r)) = (&b.ach, &v.ach) {
                assert_eq!(hash_hex(a), r.hash);
                t.segments = split::decode_ach(a, v.index).unwrap();
                assert!(split::decode_ach(a, 1).is_err());
                assert!(split::decode_table(a, 0).is_err());
            }
            t
        })
        .collect();
    let all: Vec<Option<&ViewTable>> = tables.iter().map(Some).collect();
    assert_eq!(split::assemble(&top, &all), m);
    // Only viewpoint 1's table: viewpoint 0 has no tiles, the segment (in 0's table) no ACH.
    let part = split::assemble(&top, &[None, Some(&tables[1])]);
    assert!(part.tracks[0].viewpoints[0].tiles.is_empty());
    assert_eq!(
        part.tracks[0].viewpoints[1].tiles,
        m.tracks[0].viewpoints[1].tiles
    );
    assert!(part.tracks[0].segments[0].ach.is_empty());
    // Filled in one viewpoint at a time, in any order, the manifest is what `assemble` makes
    // of the tables so far, also where a viewpoint stops on two tracks (a second track, the
    // first reversed: its segment starts at viewpoint 1, whose table has no ACH for it).
    let mut net = top.clone();
    let mut back = net.tracks[0].clone();
    back.name = "back".into();
    back.stops.reverse();
    net.tracks.push(back);
    let at = split::stops_by_viewpoint(&net);
    assert_eq!(at[1], [(0, 1), (1, 0)]);
    for order in [[0, 1], [1, 0]] {
        let mut m = split::assemble(&net, &[]);
        let mut row: Vec<Option<&ViewTable>> = vec![None; 2];
        for vi in order {
            row[vi] = Some(&tables[vi]);
            split::update_viewpoint(&mut m, &net, vi, &at[vi], row[vi]);
            assert_eq!(m, split::assemble(&net, &row), "order {order:?}");
        }
        split::update_viewpoint(&mut m, &net, 0, &at[0], None);
        assert_eq!(m, split::assemble(&net, &[None, Some(&tables[1])]));
    }
    // A table is never taken for another viewpoint.
    assert!(split::decode_table(&bytes[0].table, 1).is_err());
    assert!(split::decode_table(b"garbage", 0).is_err());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn range_checksums_are_32_64_or_128_bits_and_full_hashes_still_match() {
    let h = hash_hex(b"abc");
    assert_eq!(range_hash32(b"abc"), h[..8]);
    assert!(hash_matches(b"abc", &h[..8]) && !hash_matches(b"abd", &h[..8]));
    assert!(valid_range_hash(&h[..8]) && !valid_range_hash(&h[..7]) && !valid_range_hash(&h[..4]));
    assert_eq!(range_hash64(b"abc"), h[..16]);
    assert!(hash_matches(b"abc", &h[..16]) && !hash_matches(b"abd", &h[..16]));
    assert!(valid_range_hash(&h[..16]) && !valid_range_hash(&h[..15]));
    assert!(hash_matches(b"abc", &h));
    assert!(hash_matches(b"abc", &h[..32]));
    assert_eq!(range_hash(b"abc"), h[..32]);
    assert!(!hash_matches(b"abd", &h[..32]));
    assert!(!hash_matches(b"abc", &h[..31]));
    assert!(!hash_matches(b"abc", ""));
    assert!(valid_range_hash(&h[..32]) && valid_range_hash(&h));
    assert!(!valid_range_hash(&h[..40]) && !valid_range_hash(&h.to_uppercase()));
}

#[test]
fn older_and_newer_formats_are_refused_with_what_to_do() {
    let dir = tmpdir("old-formats");
    let (m, mut w) = build(&dir);
    w.finish(&m).unwrap();
    let db = Database::open(&dir).unwrap();
    assert_eq!(db.top().version, TOP_VERSION);
    assert!(db.top().coarse_levels_premultiplied());
    let write_top = |top: &TopManifest| {
        let json = serde_json::to_vec(top).unwrap();
        write_atomic(&dir.join(MANIFEST_FILE), &json).unwrap();
        write_atomic(
            &dir.join(MANIFEST_HASH_FILE),
            format!("{}\n", hash_hex(&json)).as_bytes(),
        )
        .unwrap();
        let _ = fs::remove_file(dir.join(format!("{MANIFEST_FILE}.gz")));
    };
    // Formats 4 and 5 (PTMs of format 2, uncompressed meshes, a payload in every pack that
    // uses it), 6 (meshes of format 2) and 8 (the whole graph in manifest.json): rebuild.
    let mut top = db.top().clone();
    for old in [4, 5, 6, 8] {
        top.version = old;
        write_top(&top);
        let err = Database::open(&dir).unwrap_err().to_string();
        assert!(
            err.contains(&format!("manifest format {old}")) && err.contains("railview build"),
            "{err}"
        );
    }
    // A format from a newer build is refused, naming both.
    top.version = TOP_VERSION + 1;
    write_top(&top);
    let err = Database::open(&dir).unwrap_err().to_string();
    assert!(
        err.contains(&format!("manifest format {}", TOP_VERSION + 1))
            && err.contains(&format!("reads format {TOP_VERSION}")),
        "{err}"
    );
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn clear_masked_touches_only_texels_without_alpha() {
    let mut px = vec![10, 20, 30, 0, 40, 50, 60, 255, 70, 80, 90, 128, 0, 0, 0, 0];
    clear_masked(&mut px);
    assert_eq!(
        px,
        vec![0, 0, 0, 0, 40, 50, 60, 255, 70, 80, 90, 128, 0, 0, 0, 0]
    );
}

#[test]
fn unpremultiply_leaves_empty_and_opaque_texels_alone() {
    let mut px = vec![
        0, 0, 0, 0, 40, 50, 60, 255, 100, 20, 0, 128, 200, 200, 200, 100,
    ];
    unpremultiply(&mut px);
    // 100·255/128 = 199.2; 200·255/100 = 510 → 255 (more colour than coverage: clamped).
    assert_eq!(
        px,
        vec![0, 0, 0, 0, 40, 50, 60, 255, 199, 40, 0, 128, 255, 255, 255, 100]
    );
}

proptest::proptest! {
    /// A tile cleared under its mask (format 5) and reduced by the PTM pyramid: every coarse
    /// texel, divided by its alpha, is the mean colour of the opaque texels it covers (within
    /// the pyramid's integer rounding), so coarse outlines are neither darkened nor tinted by
    /// what lay under the mask.
    #[test]
    fn coarse_levels_unpremultiplied_are_the_covered_texels_mean_colour(
        seed in proptest::prelude::any::<u64>(),
        fill in 1u32..16,
        junk in proptest::prelude::any::<u8>(),
    ) {
        let n = 16u32;
        let mut state = seed | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        // Binary alpha (as every renderer writes it); colour everywhere, `junk` under the mask.
        let mut px = Vec::new();
        for _ in 0..n * n {
            let r = next();
            let opaque = (r % 16) < u64::from(fill);
            let c = [(r >> 8) as u8, (r >> 16) as u8, (r >> 24) as u8];
            if opaque {
                px.extend_from_slice(&[c[0], c[1], c[2], 255]);
            } else {
                px.extend_from_slice(&[junk, junk, junk, 0]);
            }
        }
        let mut cleared = px.clone();
        clear_masked(&mut cleared);
        let chain = ptm::MipChain::build(&ptm::Image::new(n, n, 4, cleared).unwrap(), 4).unwrap();
        for (level, img) in chain.levels.iter().enumerate().skip(1) {
            let step = 1u32 << level;
            let mut texels = img.data().to_vec();
            unpremultiply(&mut texels);
            for (i, t) in texels.chunks_exact(4).enumerate() {
                let (cx, cy) = (i as u32 % img.width(), i as u32 / img.width());
                let mut sum = [0u32; 3];
                let mut count = 0u32;
                for y in cy * step..(cy + 1) * step {
                    for x in cx * step..(cx + 1) * step {
                        let p = &px[((y * n + x) * 4) as usize..][..4];
                        if p[3] == 255 {
                            count += 1;
                            for k in 0..3 {
                                sum[k] += u32::from(p[k]);
                            }
                        }
                    }
                }
                if count == 0 {
                    proptest::prop_assert_eq!(t, &[0, 0, 0, 0][..]);
                    continue;
                }
                for k in 0..3 {
                    let mean = sum[k] as f64 / count as f64;
                    // The pyramid rounds each level down by up to one unit of the level's
                    // colour; divided by a coverage down to 1/step², that is step² units.
                    let tol = 1.0 + f64::from(step * step) / f64::from(count).max(1.0) * 2.0;
                    proptest::prop_assert!(
                        (f64::from(t[k]) - mean).abs() <= tol,
                        "level {} texel ({}, {}) channel {}: {} against the mean {:.1} of {} texels",
                        level, cx, cy, k, t[k], mean, count
                    );
                }
            }
        }
    }
}

#[test]
fn decoding_finds_colour_left_under_the_mask() {
    // The tiny database's tile images were not cleared under their masks (some texels have
    // alpha 0 and colour): the files are intact, their content breaks format 5's rule.
    let dir = tmpdir("decode-rule");
    let (m, _) = build(&dir);
    assert!(verify(&dir).unwrap().is_intact());
    let r = verify_with(
        &dir,
        VerifyOptions {
            decode: true,
            ..Default::default()
        },
    )
    .unwrap();
    // 4 kept tiles and 2 backgrounds.
    assert_eq!(r.ptms_decoded, 6, "{r:?}");
    let stray: Vec<_> = r
        .problems
        .iter()
        .filter(|p| p.what.contains("with alpha 0 hold colour"))
        .collect();
    assert!(!stray.is_empty(), "{:?}", r.problems);
    assert_eq!(stray.len(), r.problems.len(), "{:?}", r.problems);
    // Named by the pack they are in.
    let packs: Vec<PathBuf> = m.tracks[0]
        .viewpoints
        .iter()
        .filter_map(|v| v.tiles[0].ptm.as_ref())
        .map(|p| dir.join(p.object.rel_path().unwrap()))
        .collect();
    assert!(stray.iter().all(|p| packs.contains(&p.path)), "{stray:?}");
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn colour_under_empty_texels_counts_only_alpha_zero_with_colour() {
    let px = [0, 0, 0, 0, 5, 0, 0, 0, 9, 9, 9, 255, 0, 0, 1, 0, 7, 7, 7, 1];
    assert_eq!(verify::colour_under_empty_texels(&px), 2);
}

/// Regression: a build killed while writing an object left `objects/HH/.HASH.tmp.RANDOM`
/// behind for good. Opening the writer again removes every temporary file; a second writer of
/// the same database, while the first holds it, is refused and removes nothing.
#[test]
fn a_resumed_writer_removes_the_leftovers_of_a_killed_one() {
    let dir = tmpdir("leftovers");
    drop(DbWriter::create(&dir).unwrap());
    let sub = dir.join("objects").join("41");
    fs::create_dir_all(&sub).unwrap();
    let obj = sub.join(format!(".41{}.tmp.Ab3xYz", "a".repeat(62)));
    let top = dir.join(".manifest.json.tmp.QwErTy");
    let foreign = sub.join(".tmpXyZ123");
    for f in [&obj, &top, &foreign] {
        fs::write(f, b"partial").unwrap();
    }
    let w = DbWriter::create(&dir).unwrap();
    let mut want = vec![top.clone(), obj.clone(), foreign.clone()];
    want.sort();
    assert_eq!(w.leftovers_removed, want);
    fs::write(&obj, b"partial").unwrap();
    let second = DbWriter::create(&dir).expect_err("a second writer is refused");
    assert!(second.to_string().contains("another build"), "{second}");
    assert!(obj.exists(), "the refused writer removed nothing");
    // Nor does verify remove a running writer's files.
    let opts = VerifyOptions {
        remove_temp: true,
        ..Default::default()
    };
    let r = verify_with(&dir, opts).unwrap();
    assert!(r.removed.is_empty() && obj.exists(), "{r:?}");
    assert!(
        r.problems
            .iter()
            .any(|p| p.what.contains("not removed") && p.what.contains("another build")),
        "{:?}",
        r.problems
    );
    drop(w);
    assert_eq!(DbWriter::create(&dir).unwrap().leftovers_removed, vec![obj]);
    assert!(is_temp_name(".tmpXyZ123") && is_temp_name(".a.tmp.3") && !is_temp_name("tmp"));
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn verify_checks_the_site_files_beside_a_database() {
    let dir = tmpdir("site-files");
    let (_m, _w) = build(&dir);
    let site: &[(&str, &[u8])] = &[
        ("index.html", b"<!doctype html><title>x</title>"),
        ("main.js", b"export const x = 1;\n"),
    ];
    let opts = VerifyOptions {
        site,
        ..Default::default()
    };
    // Without them: intact, each absent file a note.
    let r = verify_with(&dir, opts).unwrap();
    assert!(r.is_intact(), "{:?}", r.problems);
    assert_eq!(r.site_files_checked, 0);
    let absent: Vec<_> = r
        .notes
        .iter()
        .filter(|n| n.what.starts_with("absent"))
        .collect();
    assert_eq!(absent.len(), 2, "{:?}", r.notes);
    // Written as given: both checked, no note about them.
    for (name, body) in site {
        fs::write(dir.join(name), body).unwrap();
    }
    let r = verify_with(&dir, opts).unwrap();
    assert!(r.is_intact(), "{:?}", r.problems);
    assert_eq!(r.site_files_checked, 2);
    assert!(r.notes.iter().all(|n| !n.path.ends_with("main.js")));
    // One byte changed (same length), then a file of another length: damage, named.
    fs::write(dir.join("main.js"), b"export const x = 2;\n").unwrap();
    let r = verify_with(&dir, opts).unwrap();
    assert_eq!(r.problems.len(), 1, "{:?}", r.problems);
    assert!(r.problems[0].path.ends_with("main.js"));
    assert!(
        r.problems[0].what.contains("differs"),
        "{}",
        r.problems[0].what
    );
    fs::write(dir.join("index.html"), b"<script>alert(1)</script>").unwrap();
    let r = verify_with(&dir, opts).unwrap();
    assert_eq!(r.problems.len(), 2, "{:?}", r.problems);
    // Without a site to check, they are files that are not part of a database.
    let r = verify(&dir).unwrap();
    assert!(r.is_intact());
    assert!(r.notes.iter().any(|n| n.path.ends_with("main.js")));
    let _ = fs::remove_dir_all(&dir);
}

/// Writes `top` as the database's index (its pieces as objects, the root with its checksum
/// file and gzip copy), as [`DbWriter::finish`] does.
pub(crate) fn write_index(w: &mut DbWriter, top: &TopManifest) {
    let (root, pieces) = crate::index::pieces(top, w.cell).unwrap();
    for p in &pieces {
        w.put(p).unwrap();
    }
    let mut json = serde_json::to_vec(&root).unwrap();
    json.push(b'\n');
    let dir = w.root().to_path_buf();
    write_atomic(&dir.join(MANIFEST_FILE), &json).unwrap();
    write_atomic(
        &dir.join(MANIFEST_HASH_FILE),
        format!("{}\n", hash_hex(&json)).as_bytes(),
    )
    .unwrap();
    write_atomic(&dir.join(MANIFEST_GZ_FILE), &gzip(&json).unwrap()).unwrap();
}
