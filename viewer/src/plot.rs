//! Minimal scatter plots for the evaluation report (PNG, no text: axes and ranges are given
//! in the Markdown next to the picture, one colour per series in [`SERIES_COLORS`] order).

use image::{Rgb, RgbImage};

/// Series colours, in order, with their names for the legend.
pub const SERIES_COLORS: [([u8; 3], &str); 10] = [
    ([31, 119, 180], "blue"),
    ([255, 127, 14], "orange"),
    ([44, 160, 44], "green"),
    ([214, 39, 40], "red"),
    ([148, 103, 189], "purple"),
    ([140, 86, 75], "brown"),
    ([227, 119, 194], "pink"),
    ([127, 127, 127], "grey"),
    ([188, 189, 34], "olive"),
    ([23, 190, 207], "cyan"),
];

/// Axis ranges `(x_min, x_max, y_min, y_max)` of the finite points (padded 5 %).
pub fn ranges(series: &[Vec<(f64, f64)>]) -> (f64, f64, f64, f64) {
    let pts = series
        .iter()
        .flatten()
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        return (0.0, 1.0, 0.0, 1.0);
    }
    let pad = |a: f64, b: f64| {
        let d = ((b - a) * 0.05).max(1e-9);
        (a - d, b + d)
    };
    let (x0, x1) = pad(x0, x1);
    let (y0, y1) = pad(y0, y1);
    (x0, x1, y0, y1)
}

/// A 480×320 scatter plot of the series.
pub fn scatter(series: &[Vec<(f64, f64)>]) -> RgbImage {
    let (w, h) = (480u32, 320u32);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let (x0, x1, y0, y1) = ranges(series);
    let (l, r, t, b) = (30.0, w as f64 - 10.0, 10.0, h as f64 - 30.0);
    for x in l as u32..=r as u32 {
        img.put_pixel(x, b as u32, Rgb([0, 0, 0]));
    }
    for y in t as u32..=b as u32 {
        img.put_pixel(l as u32, y, Rgb([0, 0, 0]));
    }
    for (i, s) in series.iter().enumerate() {
        let c = SERIES_COLORS[i % SERIES_COLORS.len()].0;
        for &(x, y) in s {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let px = l + (x - x0) / (x1 - x0) * (r - l);
            let py = b - (y - y0) / (y1 - y0) * (b - t);
            for dy in -2i32..=2 {
                for dx in -2i32..=2 {
                    let (qx, qy) = (px as i32 + dx, py as i32 + dy);
                    if qx >= 0 && qy >= 0 && (qx as u32) < w && (qy as u32) < h {
                        img.put_pixel(qx as u32, qy as u32, Rgb(c));
                    }
                }
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_land_inside_the_axes() {
        let img = scatter(&[vec![(0.0, 0.0), (1.0, 1.0)], vec![(0.5, f64::NAN)]]);
        let blue = Rgb(SERIES_COLORS[0].0);
        let count = img.pixels().filter(|p| **p == blue).count();
        assert_eq!(count, 50);
    }
}
