//! The quality-over-time plot of a walk (PNG, drawn directly with `image`).

use image::{Rgb, RgbImage};

use super::WalkReport;

const W: u32 = 720;
const PANEL_H: u32 = 180;
const MARGIN: u32 = 12;

const COLOURS: [([u8; 3], &str); 8] = [
    ([200, 40, 40], "red"),
    ([40, 110, 220], "blue"),
    ([30, 150, 60], "green"),
    ([230, 140, 20], "orange"),
    ([140, 60, 180], "purple"),
    ([20, 160, 170], "teal"),
    ([120, 120, 120], "grey"),
    ([0, 0, 0], "black"),
];

fn strategies(r: &WalkReport) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    for run in &r.runs {
        if !v.contains(&run.strategy) {
            v.push(run.strategy.clone());
        }
    }
    v
}

fn bandwidths(r: &WalkReport) -> Vec<Option<u64>> {
    let mut v = Vec::new();
    for run in &r.runs {
        if !v.contains(&run.bandwidth_bps) {
            v.push(run.bandwidth_bps);
        }
    }
    v
}

/// `strategy = colour` pairs, in plot order.
pub fn legend(r: &WalkReport) -> Vec<String> {
    strategies(r)
        .iter()
        .enumerate()
        .map(|(i, s)| format!("{s} = {}", COLOURS[i % COLOURS.len()].1))
        .collect()
}

fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: Rgb<u8>, dotted: bool) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=steps {
        if dotted && (k / 3) % 2 == 1 {
            continue;
        }
        let f = k as f64 / steps as f64;
        let x = a.0 + (b.0 - a.0) * f;
        let y = a.1 + (b.1 - a.1) * f;
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, c);
        }
    }
}

/// One panel per bandwidth (top to bottom in report order), time on x, 0..1 on y; a solid
/// line per strategy for the progressive downloading quality and a dotted one for the
/// needed fraction.
pub fn plot_png(r: &WalkReport) -> Result<Vec<u8>, image::ImageError> {
    let bws = bandwidths(r);
    let names = strategies(r);
    let h = PANEL_H * bws.len().max(1) as u32;
    let mut img = RgbImage::from_pixel(W, h, Rgb([255, 255, 255]));
    let t_max = r
        .runs
        .iter()
        .flat_map(|run| run.frames.last().map(|f| f.t_s))
        .fold(1e-9, f64::max);
    for (p, bw) in bws.iter().enumerate() {
        let top = p as u32 * PANEL_H + MARGIN;
        let bottom = (p as u32 + 1) * PANEL_H - MARGIN;
        let (left, right) = (MARGIN as f64, (W - MARGIN) as f64);
        let grey = Rgb([180, 180, 180]);
        for frac in [0.0, 0.5, 1.0] {
            let y = bottom as f64 - frac * (bottom - top) as f64;
            line(&mut img, (left, y), (right, y), grey, frac == 0.5);
        }
        line(
            &mut img,
            (left, top as f64),
            (left, bottom as f64),
            grey,
            false,
        );
        for run in r.runs.iter().filter(|run| run.bandwidth_bps == *bw) {
            let ci = names.iter().position(|n| *n == run.strategy).unwrap_or(0);
            let c = Rgb(COLOURS[ci % COLOURS.len()].0);
            let to_xy = |t: f64, v: f64| {
                (
                    left + (right - left) * t / t_max,
                    bottom as f64 - v.clamp(0.0, 1.0) * (bottom - top) as f64,
                )
            };
            for w in run.frames.windows(2) {
                line(
                    &mut img,
                    to_xy(w[0].t_s, w[0].quality),
                    to_xy(w[1].t_s, w[1].quality),
                    c,
                    false,
                );
                line(
                    &mut img,
                    to_xy(w[0].t_s, w[0].needed_fraction),
                    to_xy(w[1].t_s, w[1].needed_fraction),
                    c,
                    true,
                );
            }
        }
    }
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}
