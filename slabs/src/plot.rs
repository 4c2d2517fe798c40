//! The histogram plot: bars over `log10(depth)`, decade ticks, chosen boundaries in red.

use image::{Rgb, RgbImage};
use tracks::SlabRange;

use crate::histogram::DepthHistogram;

/// Draw `hist` with the boundaries of `slabs` (their finite `near` values above 0) into a
/// `width × height` RGB image: grey bars scaled to the highest bin, black ticks at every
/// power of ten (taller at 1 m), red lines at the boundaries, blue lines at the rejected
/// candidates' depths given in `rejected_m`.
pub fn plot_histogram(
    hist: &DepthHistogram,
    slabs: &[SlabRange],
    rejected_m: &[f64],
    width: u32,
    height: u32,
) -> RgbImage {
    let (w, h) = (width.max(16), height.max(16));
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let margin = 12u32;
    let plot_h = h - 2 * margin;
    let base = h - margin;
    let max = hist.weights.iter().cloned().fold(0.0, f64::max);
    let span = hist.log10_max - hist.log10_min;
    let x_of = |log10: f64| -> Option<u32> {
        let t = (log10 - hist.log10_min) / span;
        (0.0..=1.0)
            .contains(&t)
            .then(|| (t * (w - 1) as f64).round() as u32)
    };
    if max > 0.0 {
        let bins = hist.bins();
        for x in 0..w {
            let b = ((x as f64 / w as f64) * bins as f64) as usize;
            let v = hist.weights[b.min(bins - 1)] / max;
            let top = base - (v * plot_h as f64).round() as u32;
            for y in top..base {
                img.put_pixel(x, y, Rgb([150, 150, 150]));
            }
        }
        // Decade ticks.
        let (lo, hi) = (hist.log10_min.floor() as i32, hist.log10_max.ceil() as i32);
        for e in lo..=hi {
            if let Some(x) = x_of(e as f64) {
                let len = if e == 0 { 10 } else { 6 };
                for y in base..(base + len).min(h) {
                    img.put_pixel(x, y, Rgb([0, 0, 0]));
                }
            }
        }
    }
    for x in 0..w {
        img.put_pixel(x, base.min(h - 1), Rgb([0, 0, 0]));
    }
    let mut vline = |d: f64, c: Rgb<u8>, dashed: bool| {
        if d > 0.0 && d.is_finite() {
            if let Some(x) = x_of(d.log10()) {
                for y in margin..base {
                    if !dashed || (y / 4) % 2 == 0 {
                        img.put_pixel(x, y, c);
                    }
                }
            }
        }
    };
    for &d in rejected_m {
        vline(d, Rgb([60, 90, 220]), true);
    }
    for s in slabs {
        vline(s.near, Rgb([220, 30, 30]), false);
    }
    img
}

/// Encode an RGB image as PNG bytes.
pub fn encode_png(img: &RgbImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    // Encoding into memory cannot fail for a valid RGB8 image.
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracks::{CubeMap, Face};

    #[test]
    fn boundary_line_is_red_and_bars_are_drawn() {
        let m = CubeMap::from_fn(8, |f, _, _| if f == Face::PosX { 2.0 } else { 50.0 });
        let h = DepthHistogram::build(&[m], 64);
        let slabs = SlabRange::parse_list("0-10,10-inf").unwrap();
        let img = plot_histogram(&h, &slabs, &[], 200, 100);
        let t = (10f64.log10() - h.log10_min) / (h.log10_max - h.log10_min);
        let x = (t * 199.0).round() as u32;
        assert_eq!(img.get_pixel(x, 50), &Rgb([220, 30, 30]));
        let grey = img.pixels().filter(|p| p.0 == [150, 150, 150]).count();
        assert!(grey > 50);
        assert!(encode_png(&img).starts_with(b"\x89PNG"));
    }
}
