//! Codec tests: bit-exact round trips, extreme images, streaming equivalence, progressive
//! quality, hostile input (a short fuzz run here; `PTM_FUZZ_CASES=N` runs a long one).

use proptest::prelude::*;

use super::*;

fn opts(method: Method) -> EncodeOptions {
    EncodeOptions {
        method,
        zstd_level: 3,
        levels: None,
        near: 0,
    }
}

const METHODS: [Method; 3] = [Method::Raw, Method::Zstd, Method::Arith];

fn roundtrip(img: &Image, o: &EncodeOptions) {
    let enc = encode(img, o).unwrap();
    let back = decode(&enc.bytes, Limits::default()).unwrap();
    assert_eq!(&back, img, "{img:?} {o:?}");
}

/// A smooth-with-texture deterministic image (what tiles look like).
fn textured(w: u32, h: u32, c: u8, seed: u32) -> Image {
    Image::from_fn(w, h, c, |x, y, k| {
        let mut v = x.wrapping_mul(3) ^ y.wrapping_mul(5) ^ (k as u32 * 77) ^ seed;
        v = v.wrapping_mul(2_654_435_761) >> 30; // noise 0..=3
        ((x * 2 + y + k as u32 * 40 + v) & 0xff) as u8
    })
}

fn image_strategy(max: u32) -> impl Strategy<Value = Image> {
    (1..=max, 1..=max, 1u8..=4, any::<u64>(), 0u8..5).prop_map(|(w, h, c, seed, kind)| {
        let mut s = seed | 1;
        let mut img = Image::from_fn(w, h, c, |x, y, k| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            match kind {
                0 => s as u8,                                                             // noise
                1 | 3 => ((x + 2 * y + k as u32 * 30) as u8).wrapping_add((s & 3) as u8), // smooth
                _ => {
                    if (s >> 60) & 1 == 1 {
                        255
                    } else {
                        0
                    }
                } // binary, like alpha
            }
        });
        if kind >= 3 && (c == 2 || c == 4) {
            // A slab tile: a binary opacity mask (a disc, or blotches) and the colour cleared
            // under it, as databases store.
            let c = c as usize;
            let (cx, cy, r) = (w as i64 / 2, h as i64 / 2, (w.min(h) as i64 / 2).max(1));
            for (i, px) in img.data.chunks_exact_mut(c).enumerate() {
                let (x, y) = ((i % w as usize) as i64, (i / w as usize) as i64);
                let inside = if kind == 3 {
                    (x - cx).pow(2) + (y - cy).pow(2) <= r * r
                } else {
                    px[c - 1] == 255
                };
                px[c - 1] = if inside { 255 } else { 0 };
                if !inside {
                    px[..c - 1].fill(0);
                }
            }
        }
        img
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn roundtrip_is_bit_exact_for_any_size_and_channels(img in image_strategy(300), m in 0usize..3) {
        roundtrip(&img, &opts(METHODS[m]));
    }

    /// The lossy mode: every colour sample of every level within `near` of the lossless
    /// pyramid's, alpha exact; every level decodes on its own.
    #[test]
    fn lossy_levels_stay_within_near(img in image_strategy(70), near in 1u8..=8) {
        let o = EncodeOptions { near, ..opts(Method::Arith) };
        let enc = encode(&img, &o).unwrap();
        let chain = MipChain::build(&img, max_levels(img.width(), img.height())).unwrap();
        let mut dec = Decoder::new(Limits::default());
        dec.push(&enc.bytes).unwrap();
        let c = img.channels() as usize;
        let alpha = (c == 2 || c == 4).then_some(c - 1);
        for (n, want) in chain.levels.iter().enumerate() {
            let got = dec.level(n as u32).unwrap();
            for (i, (a, b)) in want.data().iter().zip(got.data()).enumerate() {
                let err = (*a as i32 - *b as i32).abs();
                if Some(i % c) == alpha {
                    prop_assert_eq!(err, 0, "alpha at level {}", n);
                } else {
                    prop_assert!(err <= near as i32, "level {} sample {}: {} vs {}", n, i, a, b);
                }
            }
        }
    }

    /// Every group mode, forced, round-trips (the encoder alone may never pick some of them
    /// on random content).
    #[test]
    fn every_group_mode_round_trips(img in image_strategy(80), mode in 0u8..=1) {
        let enc = super::encode::encode_with_modes(&img, &opts(Method::Zstd), Some(mode)).unwrap();
        prop_assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), img);
    }

    #[test]
    fn fewer_levels_round_trip(img in image_strategy(40), keep in 1u8..8, m in 1usize..3) {
        let levels = keep.min(max_levels(img.width(), img.height()));
        let o = EncodeOptions { levels: Some(levels), ..opts(METHODS[m]) };
        let enc = encode(&img, &o).unwrap();
        prop_assert_eq!(enc.groups.len(), levels as usize);
        prop_assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), img);
    }

    /// Whole, byte by byte, or in arbitrary pieces: the same levels come out.
    #[test]
    fn decoding_is_independent_of_chunking(img in image_strategy(24), cuts in proptest::collection::vec(any::<usize>(), 0..12), m in 1usize..3) {
        let enc = encode(&img, &opts(METHODS[m])).unwrap();
        let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c % (enc.bytes.len() + 1)).collect();
        cuts.push(0);
        cuts.push(enc.bytes.len());
        cuts.sort_unstable();
        let mut dec = Decoder::new(Limits::default());
        let mut status = Status::NeedMore;
        for w in cuts.windows(2) {
            status = dec.push(&enc.bytes[w[0]..w[1]]).unwrap();
        }
        prop_assert_eq!(status, Status::Done);
        prop_assert_eq!(dec.finest().unwrap(), &img);
        let mut one = Decoder::new(Limits::default());
        for b in &enc.bytes {
            one.push(std::slice::from_ref(b)).unwrap();
        }
        prop_assert_eq!(one.into_levels(), dec.into_levels());
    }

    /// Short fuzz run: arbitrary bytes never panic and never decode to something inconsistent.
    #[test]
    fn arbitrary_bytes_are_rejected_cleanly(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        check_hostile(&bytes);
    }

    #[test]
    fn mutated_files_are_rejected_cleanly(img in image_strategy(20), m in 0usize..3, near in prop_oneof![Just(0u8), 1u8..5], flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..4), cut in any::<usize>()) {
        let near = if METHODS[m] == Method::Arith { near } else { 0 };
        let enc = encode(&img, &EncodeOptions { near, ..opts(METHODS[m]) }).unwrap();
        let mut bytes = enc.bytes.clone();
        for (at, x) in flips {
            let at = at % bytes.len();
            bytes[at] ^= x.max(1);
        }
        bytes.truncate(1 + cut % bytes.len());
        check_hostile(&bytes);
    }
}

/// Feeds hostile bytes whole and in two pieces; any outcome but a panic or an inconsistent
/// result is fine.
fn check_hostile(bytes: &[u8]) {
    let limits = Limits {
        max_side: 4096,
        max_decoded_bytes: 1 << 24,
    };
    let whole = decode(bytes, limits);
    if let Ok(img) = &whole {
        assert_eq!(
            img.data().len(),
            img.width() as usize * img.height() as usize * img.channels() as usize
        );
    }
    let mut dec = Decoder::new(limits);
    let half = bytes.len() / 2;
    let split = dec
        .push(&bytes[..half])
        .and_then(|_| dec.push(&bytes[half..]));
    match (&whole, split) {
        (Ok(a), Ok(Status::Done)) => assert_eq!(Some(a), dec.finest()),
        (Err(PtmError::Truncated { .. }), Ok(Status::NeedMore)) => {}
        (Err(_), Err(_)) => {}
        (w, s) => panic!("whole {w:?} vs split {s:?}"),
    }
}

/// The long fuzz run: `PTM_FUZZ_CASES=1000000 cargo test --release -p codec --lib long_fuzz -- --ignored`.
#[test]
#[ignore = "long fuzz run; set PTM_FUZZ_CASES"]
fn long_fuzz() {
    let cases: u32 = std::env::var("PTM_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let strat = (
        image_strategy(48),
        0usize..4,
        proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
        any::<usize>(),
        proptest::collection::vec(any::<u8>(), 0..64),
    );
    runner
        .run(&strat, |(img, m, flips, cut, junk)| {
            // Method 2 lossless and lossy, raw, and zstd groups in the mode the encoder picks
            // or decorrelated wherever it applies.
            let (method, near) = match m {
                0 => (Method::Raw, 0),
                1 => (Method::Zstd, 0),
                2 => (Method::Arith, 0),
                _ => (Method::Arith, 1 + (cut % 6) as u8),
            };
            let o = EncodeOptions {
                near,
                ..opts(method)
            };
            let mode = (cut % 7 == 0).then_some(1);
            let enc = super::encode::encode_with_modes(&img, &o, mode).unwrap();
            if flips.is_empty() && near == 0 {
                prop_assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), img);
                return Ok(());
            }
            let mut bytes = enc.bytes.clone();
            for (at, x) in flips {
                let at = at % bytes.len();
                bytes[at] ^= x.max(1);
            }
            if cut.is_multiple_of(3) {
                bytes.truncate(cut % (bytes.len() + 1));
            }
            if cut % 5 == 1 {
                bytes.extend_from_slice(&junk);
            }
            check_hostile(&bytes);
            check_hostile(&junk);
            Ok(())
        })
        .unwrap();
}

#[test]
fn extreme_images_round_trip() {
    for &(w, h) in &[
        (1, 1),
        (1, 2),
        (2, 1),
        (1, 7),
        (7, 1),
        (2, 2),
        (3, 3),
        (5, 4),
        (257, 3),
        (64, 64),
    ] {
        for c in 1..=4u8 {
            for method in METHODS {
                let o = opts(method);
                roundtrip(&Image::from_fn(w, h, c, |_, _, _| 0), &o);
                roundtrip(&Image::from_fn(w, h, c, |_, _, _| 255), &o);
                roundtrip(
                    &Image::from_fn(
                        w,
                        h,
                        c,
                        |x, y, _| if (x + y).is_multiple_of(2) { 0 } else { 255 },
                    ),
                    &o,
                );
                roundtrip(
                    &Image::from_fn(w, h, c, |x, _, k| {
                        if (x + k as u32).is_multiple_of(2) {
                            255
                        } else {
                            0
                        }
                    }),
                    &o,
                );
                roundtrip(
                    &Image::from_fn(w, h, c, |_, y, _| if y.is_multiple_of(2) { 255 } else { 0 }),
                    &o,
                );
            }
        }
    }
}

#[test]
fn raw_method_is_the_papers_layout_with_residual_overhead() {
    // 1024² RGB, the paper's example. The partial levels together hold exactly as many samples
    // as level 0 (3/4 · (1 + 1/4 + …) = 1); the 2-bit residuals add 1/4 byte per sample of
    // every level above 0: 1/4 · (1/4 + 1/16 + …) = 1/12 ≈ 8.3 %. The paper's "+6 %" is the
    // finest level's residuals alone (1/4 · 1/4 = 6.25 %).
    let img = textured(1024, 1024, 3, 1);
    let enc = encode(&img, &opts(Method::Raw)).unwrap();
    let base = img.data().len() as f64;
    let overhead = enc.bytes.len() as f64 / base - 1.0;
    assert!((0.0833..0.0834).contains(&overhead), "overhead {overhead}");
    assert_eq!(enc.bytes[0], FORMAT_VERSION);
    // Group 1 (level L−2 = 2×2 from 1×1): residual byte(s) then three stored pixels.
    let g1 = &enc.groups[1];
    assert_eq!((g1.width, g1.height, g1.level), (2, 2, 9));
    assert_eq!(g1.len, 1 + 3 * 3);
}

#[test]
fn chunk_table_matches_header_and_allows_range_requests() {
    let img = textured(37, 21, 4, 2);
    let enc = encode(&img, &EncodeOptions::default()).unwrap();
    let mut dec = Decoder::new(Limits::default());
    let first = &enc.groups[0];
    assert_eq!(first.offset, 0);
    dec.push(&enc.bytes[..first.len as usize]).unwrap();
    let header = dec.header().unwrap().clone();
    assert_eq!(header.file_len(), enc.bytes.len() as u64);
    for (g, span) in enc.groups.iter().enumerate() {
        let r = header.chunk_range(g).unwrap();
        assert_eq!((r.start, r.end - r.start), (span.offset, span.len));
        assert_eq!(
            (span.width, span.height),
            level_dims(37, 21, span.level),
            "group {g}"
        );
        if g > 0 {
            // A client holding the earlier chunks fetches exactly this byte range.
            let status = dec
                .push(&enc.bytes[r.start as usize..r.end as usize])
                .unwrap();
            assert_eq!(dec.finest_level(), Some(span.level));
            assert_eq!(status == Status::Done, span.level == 0);
        }
    }
    assert!(header.chunk_range(enc.groups.len()).is_none());
    assert_eq!(dec.level(0).unwrap(), &img);
    assert_eq!(dec.level(99), None);
}

/// Mean squared error of `coarse` upsampled (nearest) to `img`'s size.
fn mse_upsampled(img: &Image, coarse: &Image, level: u32) -> f64 {
    let mut sum = 0.0;
    for y in 0..img.height() {
        for x in 0..img.width() {
            for k in 0..img.channels() {
                let a = img.get(x, y, k).unwrap() as f64;
                let b = coarse.get(x >> level, y >> level, k).unwrap() as f64;
                sum += (a - b) * (a - b);
            }
        }
    }
    sum / img.data().len() as f64
}

#[test]
fn every_prefix_decodes_and_quality_never_drops() {
    for (seed, (w, h, c)) in [(64, 64, 4), (45, 30, 3), (17, 33, 1), (128, 96, 3)]
        .into_iter()
        .enumerate()
    {
        let img = textured(w, h, c, seed as u32);
        let enc = encode(&img, &EncodeOptions::default()).unwrap();
        let mut dec = Decoder::new(Limits::default());
        let mut last = f64::INFINITY;
        for span in &enc.groups {
            dec.push(&enc.bytes[span.offset as usize..(span.offset + span.len) as usize])
                .unwrap();
            let level = dec.finest_level().unwrap();
            assert_eq!(level, span.level);
            let err = mse_upsampled(&img, dec.finest().unwrap(), level);
            assert!(
                err <= last,
                "{w}×{h}: level {level} error {err} after {last}"
            );
            last = err;
        }
        assert_eq!(last, 0.0);
    }
}

fn header_bytes(method: u8, c: u8, levels: u8, w: u32, h: u32, lens: &[u32]) -> Vec<u8> {
    let mut b = vec![FORMAT_VERSION, method, c, levels, 0];
    let mut var = |mut v: u64| {
        while v >= 0x80 {
            b.push((v as u8) | 0x80);
            v >>= 7;
        }
        b.push(v as u8);
    };
    var(w as u64);
    var(h as u64);
    for &l in lens {
        var(l as u64);
    }
    b
}

#[test]
fn hostile_headers_give_typed_errors() {
    let l = Limits::default();
    let e = |b: &[u8]| decode(b, l).unwrap_err();
    assert_eq!(e(b"JUNKJUNKJUNKJUNK"), PtmError::UnsupportedVersion(b'J'));
    let mut v = header_bytes(1, 3, 1, 1, 1, &[10]);
    v[0] = 9;
    assert_eq!(e(&v), PtmError::UnsupportedVersion(9));
    assert_eq!(
        e(&header_bytes(7, 3, 1, 1, 1, &[10])),
        PtmError::UnknownMethod(7)
    );
    for c in [0, 5] {
        assert!(matches!(
            e(&header_bytes(1, c, 1, 1, 1, &[1])),
            PtmError::BadHeader {
                field: "channels",
                ..
            }
        ));
    }
    // Unknown flags, the alpha flag without alpha or without method 2, near out of place.
    for (m, c) in [(2, 0x23), (2, 0x13), (1, 0x14)] {
        assert!(matches!(
            e(&header_bytes(m, c, 1, 1, 1, &[1])),
            PtmError::BadHeader { field: "flags", .. }
        ));
    }
    for (m, near) in [(1, 1), (2, 33)] {
        let mut b = header_bytes(m, 4, 1, 1, 1, &[4]);
        b[4] = near;
        assert!(matches!(e(&b), PtmError::BadHeader { field: "near", .. }));
    }
    assert!(matches!(
        e(&header_bytes(1, 3, 1, 0, 1, &[1])),
        PtmError::BadHeader { field: "width", .. }
    ));
    assert!(matches!(
        e(&header_bytes(1, 3, 1, 4, 0, &[1])),
        PtmError::BadHeader {
            field: "height",
            ..
        }
    ));
    // A varint longer than 32 bits.
    let mut b = vec![FORMAT_VERSION, 1, 3, 1, 0];
    b.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0x7f]);
    assert!(matches!(e(&b), PtmError::BadHeader { field: "size", .. }));
    b.truncate(5);
    b.extend_from_slice(&[0x80; 6]);
    assert!(matches!(e(&b), PtmError::BadHeader { field: "size", .. }));
    // Wrong level counts: zero, and more than halving down to 1×1 allows.
    assert!(matches!(
        e(&header_bytes(1, 3, 0, 4, 4, &[])),
        PtmError::BadHeader {
            field: "levels",
            ..
        }
    ));
    assert!(matches!(
        e(&header_bytes(1, 3, 4, 4, 4, &[1, 1, 1, 1])),
        PtmError::BadHeader {
            field: "levels",
            ..
        }
    ));
    // Sizes that overflow naive arithmetic are stopped by the limits before any allocation.
    assert!(matches!(
        e(&header_bytes(1, 4, 33, u32::MAX, u32::MAX, &[])),
        PtmError::LimitsExceeded { what: "width", .. }
    ));
    let tight = Limits {
        max_side: 16_384,
        max_decoded_bytes: 1000,
    };
    assert!(matches!(
        decode(&header_bytes(1, 4, 1, 16_384, 16_384, &[1]), tight).unwrap_err(),
        PtmError::LimitsExceeded {
            what: "decoded bytes",
            ..
        }
    ));
    // Group lengths that cannot hold their level.
    assert!(matches!(
        e(&header_bytes(0, 1, 1, 2, 2, &[5])),
        PtmError::GroupLength { group: 0, .. }
    ));
    assert!(matches!(
        e(&header_bytes(1, 1, 2, 2, 2, &[9, u32::MAX])),
        PtmError::GroupLength { group: 1, .. }
    ));
    assert!(matches!(
        e(&header_bytes(1, 1, 2, 2, 2, &[0, 9])),
        PtmError::GroupLength { group: 0, .. }
    ));
    assert!(matches!(
        e(&header_bytes(2, 1, 2, 2, 2, &[0, 1 << 20])),
        PtmError::GroupLength { group: 1, .. }
    ));
}

#[test]
fn truncation_is_need_more_then_truncated() {
    let img = textured(9, 7, 3, 3);
    let enc = encode(&img, &EncodeOptions::default()).unwrap();
    for cut in 0..enc.bytes.len() {
        let mut dec = Decoder::new(Limits::default());
        assert_eq!(dec.push(&enc.bytes[..cut]).unwrap(), Status::NeedMore);
        assert!(matches!(
            decode(&enc.bytes[..cut], Limits::default()),
            Err(PtmError::Truncated { .. })
        ));
    }
}

#[test]
fn trailing_bytes_and_reuse_after_error_are_errors() {
    let img = textured(4, 4, 1, 4);
    let mut bytes = encode(&img, &EncodeOptions::default()).unwrap().bytes;
    bytes.push(0);
    assert_eq!(
        decode(&bytes, Limits::default()),
        Err(PtmError::TrailingBytes(1))
    );
    let mut dec = Decoder::new(Limits::default());
    assert!(dec.push(&[FORMAT_VERSION, 2, 4, 1]).is_ok());
    assert!(dec.push(&[99]).is_err()); // near 99

    assert_eq!(dec.push(b""), Err(PtmError::Poisoned));
}

#[test]
fn bad_residuals_are_caught_in_raw_groups() {
    // 2×2 grey, all 255 → parent 255, residual 3; the rebuilt pixel would be > 255 if any
    // stored pixel dropped below… here we make the residual impossible instead.
    let img = Image::from_fn(2, 2, 1, |_, _, _| 255);
    let mut bytes = encode(&img, &opts(Method::Raw)).unwrap().bytes;
    // Layout: header (5 + 4 varints) | group 0: 1 byte | group 1: 1 residual byte, 3 pixels.
    assert_eq!(bytes.len(), 9 + 1 + 4);
    bytes[10] = 3; // residual 3 with parent 255 and three stored 255s → 4·255 + 3 − 765 = 258
    assert!(matches!(
        decode(&bytes, Limits::default()),
        Err(PtmError::BadResidual {
            level: 0,
            x: 1,
            y: 1,
            channel: 0,
            value: 258
        })
    ));
    // A 2×1 image: its one block has two pixels, so residuals above 1 are impossible.
    let img = Image::from_fn(2, 1, 1, |x, _, _| x as u8);
    let mut bytes = encode(&img, &opts(Method::Raw)).unwrap().bytes;
    bytes[10] = 2;
    assert!(matches!(
        decode(&bytes, Limits::default()),
        Err(PtmError::BadResidual { value: 2, .. })
    ));
    // Non-zero padding bits after the last residual.
    bytes[10] = 0b0100_0001;
    assert!(matches!(
        decode(&bytes, Limits::default()),
        Err(PtmError::BadResidual { .. })
    ));
}

#[test]
fn encoder_rejects_inconsistent_input() {
    assert!(Image::new(0, 4, 1, vec![]).is_err());
    assert!(Image::new(2, 2, 5, vec![0; 20]).is_err());
    assert!(Image::new(2, 2, 3, vec![0; 11]).is_err());
    let img = textured(4, 4, 1, 0);
    let o = EncodeOptions {
        levels: Some(4),
        ..EncodeOptions::default()
    };
    assert!(encode(&img, &o).is_err());
    let o = EncodeOptions {
        levels: Some(0),
        ..EncodeOptions::default()
    };
    assert!(encode(&img, &o).is_err());
}

#[test]
fn prediction_compresses_textured_tiles_well() {
    let img = textured(256, 256, 4, 5);
    let raw = encode(&img, &opts(Method::Raw)).unwrap().bytes.len();
    let z = encode(&img, &opts(Method::Zstd)).unwrap().bytes.len();
    let a = encode(&img, &EncodeOptions::default()).unwrap().bytes.len();
    assert!(z * 2 < raw, "zstd {z} vs raw {raw}");
    assert!(a < z, "method 2 {a} vs zstd {z}");
}

#[test]
fn masked_tiles_cost_little_for_what_is_empty_or_opaque() {
    // A 32² RGBA tile: a textured disc, the colour cleared outside it.
    let img = Image::from_fn(32, 32, 4, |x, y, k| {
        let inside = (x as i32 - 16).pow(2) + (y as i32 - 16).pow(2) <= 144;
        match (inside, k) {
            (false, _) => 0,
            (true, 3) => 255,
            (true, _) => (x * 3 + y * 2 + k as u32 * 50) as u8,
        }
    });
    let enc = encode(&img, &EncodeOptions::default()).unwrap();
    assert_eq!(enc.bytes[2], 4 | FLAG_COLOUR_WITHIN_ALPHA);
    let zstd = encode(&img, &opts(Method::Zstd)).unwrap().bytes.len();
    assert!(
        enc.bytes.len() * 2 < zstd,
        "{} vs zstd {zstd}",
        enc.bytes.len()
    );
    assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), img);
    // Colour left under the mask: still exact, without the flag.
    let mut stray = img.clone();
    stray.data[0] = 7;
    let enc = encode(&stray, &EncodeOptions::default()).unwrap();
    assert_eq!(enc.bytes[2], 4);
    assert_eq!(decode(&enc.bytes, Limits::default()).unwrap(), stray);
}

#[test]
fn older_formats_are_refused_with_a_typed_error() {
    let img = textured(6, 5, 4, 1);
    let mut bytes = encode(&img, &EncodeOptions::default()).unwrap().bytes;
    bytes[0] = 2;
    let e = decode(&bytes, Limits::default()).unwrap_err();
    assert_eq!(e, PtmError::UnsupportedVersion(2));
    assert!(e.to_string().contains("rebuild"), "{e}");
    // Format 2 began with the magic "RPTM".
    assert_eq!(
        decode(b"RPTM\x02\x01\x04\x01", Limits::default()),
        Err(PtmError::UnsupportedVersion(b'R'))
    );
}

#[test]
fn lossy_mode_needs_method_2_and_a_small_near() {
    let img = textured(8, 8, 3, 1);
    let o = |method, near| EncodeOptions {
        near,
        ..opts(method)
    };
    assert!(encode(&img, &o(Method::Zstd, 1)).is_err());
    assert!(encode(&img, &o(Method::Arith, MAX_NEAR + 1)).is_err());
    let lossy = encode(&img, &o(Method::Arith, 4)).unwrap();
    let exact = encode(&img, &o(Method::Arith, 0)).unwrap();
    assert!(lossy.bytes.len() < exact.bytes.len());
    assert_eq!(lossy.bytes[4], 4);
}

/// Byte offset of chunk `g`'s first payload byte (its mode byte for zstd groups).
fn group_start(enc: &Encoded, g: usize) -> usize {
    let h = {
        let mut d = Decoder::new(Limits::default());
        d.push(&enc.bytes[..FIXED_HEADER_LEN]).unwrap();
        d.push(&enc.bytes[FIXED_HEADER_LEN..enc.groups[0].len as usize])
            .unwrap();
        d.header().unwrap().clone()
    };
    assert_eq!(h.method, Method::Zstd);
    if g == 0 {
        h.len()
    } else {
        enc.groups[g].offset as usize
    }
}

#[test]
fn group_modes_are_checked() {
    // Colour errors shared by the three channels: the encoder decorrelates the finest group.
    let img = Image::from_fn(64, 64, 3, |x, y, k| {
        let noise = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) >> 27;
        (x + y + noise + 20 * k as u32) as u8
    });
    let enc = encode(&img, &opts(Method::Zstd)).unwrap();
    let last = enc.groups.len() - 1;
    assert_eq!(
        enc.bytes[group_start(&enc, last)],
        1,
        "finest group decorrelated"
    );
    assert_eq!(
        enc.bytes[group_start(&enc, 0)],
        0,
        "lowest level has mode 0"
    );
    for (g, bad) in [(last, 0x80u8), (last, 2), (0, 1)] {
        let mut bytes = enc.bytes.clone();
        bytes[group_start(&enc, g)] = bad;
        assert!(
            matches!(
                decode(&bytes, Limits::default()),
                Err(PtmError::UnknownGroupMode { group, mode, .. }) if group == g && mode == bad
            ),
            "group {g} mode {bad}"
        );
    }
    // Decorrelation needs three colour channels.
    let grey = textured(8, 8, 2, 3);
    let enc = encode(&grey, &opts(Method::Zstd)).unwrap();
    let mut bytes = enc.bytes.clone();
    bytes[group_start(&enc, 1)] = 1;
    assert!(matches!(
        decode(&bytes, Limits::default()),
        Err(PtmError::UnknownGroupMode { group: 1, .. })
    ));
}

#[test]
fn decode_up_to_reads_only_the_groups_it_needs() {
    for (w, h, c) in [(37, 21, 4), (8, 8, 3), (1, 1, 1), (5, 1, 2)] {
        let img = textured(w, h, c, w ^ h);
        let levels = max_levels(w, h);
        let chain = MipChain::build(&img, levels).unwrap();
        let enc = encode(&img, &EncodeOptions::default()).unwrap();
        for (g, span) in enc.groups.iter().enumerate() {
            // Only the chunks up to this level are present.
            let prefix = &enc.bytes[..(span.offset + span.len) as usize];
            let got = decode_up_to(prefix, span.level, Limits::default()).unwrap();
            assert_eq!(
                got, chain.levels[span.level as usize],
                "{w}×{h}×{c} group {g}"
            );
            assert!(matches!(
                decode_up_to(&prefix[..prefix.len() - 1], span.level, Limits::default()),
                Err(PtmError::Truncated { .. })
            ));
        }
        let lowest = decode_up_to(&enc.bytes, levels as u32 + 5, Limits::default()).unwrap();
        assert_eq!(lowest, chain.levels[levels as usize - 1]);
    }
    assert!(matches!(
        decode_up_to(&[FORMAT_VERSION, 2, 4], 0, Limits::default()),
        Err(PtmError::Truncated { .. })
    ));
    assert!(matches!(
        decode_up_to(b"JUNKJUNKJUNKJUNK", 0, Limits::default()),
        Err(PtmError::UnsupportedVersion(_))
    ));
}
