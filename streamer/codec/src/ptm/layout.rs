//! Byte layout of [`Method::Zstd`](super::Method::Zstd) group payloads (format 2).
//!
//! A group payload is one *mode* byte, then one zstd frame. The frame holds the group's coded
//! planes (see `predict.rs`: residual codes, one per parent sample, then the prediction errors
//! of the stored samples) rearranged so that samples with similar statistics sit together:
//!
//! ```text
//! colour part of the residual codes   (np · cc bytes, colour channels interleaved)
//! colour part of the prediction errors (stored · cc bytes, interleaved)
//! alpha residual codes                (np bytes; only with 2 or 4 channels)
//! alpha prediction errors             (stored bytes)
//! ```
//!
//! where `cc` is the number of colour channels (1 for grey and grey+alpha, 3 for RGB and
//! RGBA). Separating the alpha plane (an opacity mask, almost always perfectly predicted)
//! lets zstd code it as long matches instead of one literal per pixel among the colour
//! literals. With mode bit [`MODE_DECORRELATE`] (RGB and RGBA only) the prediction errors of
//! red and blue are stored relative to green's, `(e_R − e_G) mod 256` and `(e_B − e_G) mod 256`:
//! a reversible decorrelation (the decoder adds green back) that removes most of the error
//! shared by the three channels on rendered surfaces. The encoder picks the mode per group.
//!
//! Group 0 (the lowest level, coded as per-channel differences) always has mode 0.

/// Mode bit: red and blue prediction errors are coded relative to green's.
pub(crate) const MODE_DECORRELATE: u8 = 1;
/// Every mode bit this decoder understands.
pub(crate) const KNOWN_MODES: u8 = MODE_DECORRELATE;

/// Number of colour channels of a `c`-channel image (the rest is alpha).
pub(crate) fn colour_channels(c: usize) -> usize {
    if c == 2 || c == 4 {
        c - 1
    } else {
        c
    }
}

/// True when `mode` is meaningful for `c` channels.
pub(crate) fn mode_allowed(mode: u8, c: usize) -> bool {
    mode & !KNOWN_MODES == 0 && (mode & MODE_DECORRELATE == 0 || colour_channels(c) == 3)
}

/// True when [`split`] and [`merge`] are the identity (no alpha plane, no decorrelation).
pub(crate) fn is_identity(mode: u8, c: usize) -> bool {
    mode == 0 && colour_channels(c) == c
}

/// Rearranges a group's interleaved plain bytes (`np · c` residual codes, then the errors of
/// the stored samples) into the coded layout.
pub(crate) fn split(plain: &[u8], np: usize, c: usize, mode: u8) -> Vec<u8> {
    let cc = colour_channels(c);
    let (res, err) = plain.split_at(np * c);
    let mut out = Vec::with_capacity(plain.len());
    for px in res.chunks_exact(c) {
        out.extend_from_slice(&px[..cc]);
    }
    let decorrelate = mode & MODE_DECORRELATE != 0;
    for px in err.chunks_exact(c) {
        if decorrelate {
            let g = px[1];
            out.extend_from_slice(&[px[0].wrapping_sub(g), g, px[2].wrapping_sub(g)]);
        } else {
            out.extend_from_slice(&px[..cc]);
        }
    }
    if cc < c {
        out.extend(res.chunks_exact(c).map(|px| px[cc]));
        out.extend(err.chunks_exact(c).map(|px| px[cc]));
    }
    out
}

/// Inverse of [`split`]: writes the interleaved plain bytes into `out` (cleared first).
/// `coded` holds `(np + stored) · c` bytes (the caller checks the length).
pub(crate) fn merge(coded: &[u8], np: usize, c: usize, mode: u8, out: &mut Vec<u8>) {
    let decorrelate = mode & MODE_DECORRELATE != 0;
    out.clear();
    out.resize(coded.len(), 0);
    match (c, decorrelate) {
        (1, _) | (3, false) => out.copy_from_slice(coded),
        (2, _) => merge_c::<2, 1, false>(coded, np, out),
        (3, true) => merge_c::<3, 3, true>(coded, np, out),
        (4, false) => merge_c::<4, 3, false>(coded, np, out),
        _ => merge_c::<4, 3, true>(coded, np, out),
    }
}

/// [`merge`] for `C` channels of which `CC` are colour: the residual codes, then the errors.
fn merge_c<const C: usize, const CC: usize, const DECORRELATE: bool>(
    coded: &[u8],
    np: usize,
    out: &mut [u8],
) {
    let n = coded.len() / C; // np + stored samples per channel
    let (colour, alpha) = coded.split_at(n * CC);
    let (colour_res, colour_err) = colour.split_at(np * CC);
    let (alpha_res, alpha_err) = alpha.split_at(if CC < C { np } else { 0 });
    let (out_res, out_err) = out.split_at_mut(np * C);
    merge_part::<C, CC, false>(colour_res, alpha_res, out_res);
    merge_part::<C, CC, DECORRELATE>(colour_err, alpha_err, out_err);
}

/// Interleaves `CC` colour samples and (when `CC < C`) one alpha sample per pixel, adding
/// green back to red and blue when `DECORRELATE`. One pass, pixels as fixed-size arrays.
#[inline(always)]
fn merge_part<const C: usize, const CC: usize, const DECORRELATE: bool>(
    colour: &[u8],
    alpha: &[u8],
    out: &mut [u8],
) {
    let pixel = |s: &[u8], a: u8| {
        let mut p = [a; C];
        p[..CC].copy_from_slice(s);
        if DECORRELATE {
            p[0] = p[0].wrapping_add(p[1]);
            p[2] = p[2].wrapping_add(p[1]);
        }
        p
    };
    if CC < C {
        for ((px, s), &a) in out
            .chunks_exact_mut(C)
            .zip(colour.chunks_exact(CC))
            .zip(alpha)
        {
            px.copy_from_slice(&pixel(s, a));
        }
    } else {
        for (px, s) in out.chunks_exact_mut(C).zip(colour.chunks_exact(CC)) {
            px.copy_from_slice(&pixel(s, 0));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_then_merge_is_identity_for_every_mode() {
        for c in 1..=4usize {
            for mode in 0..=KNOWN_MODES {
                if !mode_allowed(mode, c) {
                    continue;
                }
                let (np, stored) = (5, 11);
                let plain: Vec<u8> = (0..(np + stored) * c)
                    .map(|i| (i * 37 % 251) as u8)
                    .collect();
                let coded = split(&plain, np, c, mode);
                assert_eq!(coded.len(), plain.len());
                assert_eq!(coded == plain, is_identity(mode, c), "c {c} mode {mode}");
                let mut back = vec![9; 3];
                merge(&coded, np, c, mode, &mut back);
                assert_eq!(back, plain, "c {c} mode {mode}");
            }
        }
    }

    #[test]
    fn decorrelation_codes_red_and_blue_against_green_and_alpha_last() {
        // One residual pixel, one stored pixel, RGBA.
        let plain = [1, 2, 3, 0, 10, 20, 5, 0];
        let coded = split(&plain, 1, 4, MODE_DECORRELATE);
        assert_eq!(coded, [1, 2, 3, 246, 20, 241, 0, 0]);
        assert!(!mode_allowed(MODE_DECORRELATE, 1));
        assert!(!mode_allowed(MODE_DECORRELATE, 2));
        assert!(mode_allowed(MODE_DECORRELATE, 3));
        assert!(!mode_allowed(2, 4));
    }
}
