//! Combining per-reference z-buffers into one view: shading, blending, classes, hole filling.

use rayon::prelude::*;

use crate::sample::{self, encode, Linear};
use crate::splat::View;
use crate::{Bound, PixelClass, Reference, WarpOptions};

/// One reference's contribution: its z-buffer (view depth, `+inf` where empty) and weight.
pub(crate) struct Layer<'r, 'a> {
    pub reference: &'r Reference<'a>,
    pub z: &'r [f32],
    pub weight: f64,
}

/// A combined pixel before classification of edges and hole filling.
#[derive(Clone, Copy, Debug)]
struct Pixel {
    color: Linear,
    /// View depth; `+inf` for sky, NaN for a hole.
    z: f32,
    class: PixelClass,
}

const HOLE: Pixel = Pixel {
    color: [0.0; 3],
    z: f32::NAN,
    class: PixelClass::Hole,
};

/// The combined view: every pixel shaded from the layers, classified, holes filled.
pub(crate) fn compose(view: &View, layers: &[Layer], opts: &WarpOptions) -> Bound {
    let pixels: Vec<Pixel> = (0..view.height)
        .into_par_iter()
        .flat_map_iter(|py| (0..view.width).map(move |px| shade(view, layers, opts, px, py)))
        .collect();
    let mut class: Vec<PixelClass> = pixels.iter().map(|p| p.class).collect();
    mark_depth_edges(view, &pixels, &mut class);
    let black: Vec<[u8; 3]> = pixels.iter().map(|p| encode(p.color)).collect();
    let filled = fill_holes(view, &pixels, &black);
    Bound {
        width: view.width as u32,
        height: view.height as u32,
        black,
        filled,
        class,
    }
}

/// The colour of layer `l`'s surface at view depth `z` on the ray through `(px, py)`: the
/// reference colour in the direction of that surface point.
fn surface_color(view: &View, opts: &WarpOptions, l: &Layer, px: usize, py: usize) -> Linear {
    let ray = view.ray(px, py);
    let z = l.z[py * view.width + px] as f64;
    let to_point = view.position + ray * z - l.reference.position;
    let r = l.reference;
    sample::surface_color(r.color, r.depth, to_point, opts.filter, opts.same_surface)
        .or_else(|| sample::color(l.reference.color, ray, opts.filter))
        .unwrap_or([0.0; 3])
}

/// Weighted mean of `(colour, weight)` pairs; equal weights when the weights sum to zero.
fn blend(items: impl Iterator<Item = (Linear, f64)> + Clone) -> Linear {
    let total: f64 = items.clone().map(|(_, w)| w).sum();
    let count = items.clone().count() as f64;
    let mut sum = [0.0f64; 3];
    for (c, w) in items {
        let w = if total > 0.0 { w / total } else { 1.0 / count };
        for k in 0..3 {
            sum[k] += w * c[k] as f64;
        }
    }
    sum.map(|s| s as f32)
}

/// One view pixel: the nearest surface (blended with every layer within `agree` of it), else
/// the sky some reference sees in this direction, else a hole.
fn shade(view: &View, layers: &[Layer], opts: &WarpOptions, px: usize, py: usize) -> Pixel {
    let i = py * view.width + px;
    let nearest = layers.iter().map(|l| l.z[i]).fold(f32::INFINITY, f32::min);
    if nearest.is_finite() {
        let limit = nearest as f64 * (1.0 + opts.agree);
        let agreeing = || layers.iter().filter(move |l| l.z[i] as f64 <= limit);
        let color = blend(agreeing().map(|l| (surface_color(view, opts, l, px, py), l.weight)));
        let class = if agreeing().count() < layers.len() {
            PixelClass::OneView
        } else {
            PixelClass::Interior
        };
        return Pixel {
            color,
            z: nearest,
            class,
        };
    }
    let ray = view.ray(px, py);
    let skies: Vec<(Linear, f64)> = layers
        .iter()
        .filter_map(|l| {
            sample::sky(l.reference.color, l.reference.depth, ray).map(|c| (c, l.weight))
        })
        .collect();
    if skies.is_empty() {
        return HOLE;
    }
    Pixel {
        color: blend(skies.iter().copied()),
        z: f32::INFINITY,
        class: PixelClass::Sky,
    }
}

/// Ratio of the far to the near depth in a 3×3 neighbourhood above which a pixel is on a depth
/// edge (sky counts as infinitely far, holes are skipped).
pub(crate) const EDGE_RATIO: f32 = 1.1;

/// Interior pixels whose 3×3 neighbourhood spans a depth ratio above [`EDGE_RATIO`].
fn mark_depth_edges(view: &View, pixels: &[Pixel], class: &mut [PixelClass]) {
    let (w, h) = (view.width, view.height);
    for py in 0..h {
        for px in 0..w {
            let i = py * w + px;
            if class[i] != PixelClass::Interior {
                continue;
            }
            let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
            for ny in py.saturating_sub(1)..(py + 2).min(h) {
                for nx in px.saturating_sub(1)..(px + 2).min(w) {
                    let z = pixels[ny * w + nx].z;
                    if !z.is_nan() {
                        lo = lo.min(z);
                        hi = hi.max(z);
                    }
                }
            }
            if hi > lo * EDGE_RATIO {
                class[i] = PixelClass::DepthEdge;
            }
        }
    }
}

/// For every pixel, the index of the nearest non-hole pixel in one direction along a line:
/// `lines` yields the pixel indices of each line in scan order.
fn nearest_along(
    n: usize,
    pixels: &[Pixel],
    lines: impl Iterator<Item = Vec<usize>>,
) -> Vec<Option<usize>> {
    let mut out = vec![None; n];
    for line in lines {
        let mut last = None;
        for i in line {
            out[i] = last;
            if pixels[i].class != PixelClass::Hole {
                last = Some(i);
            }
        }
    }
    out
}

/// Holes take the colour of the farthest of the nearest non-hole pixels to their left, right,
/// above and below (sky is farthest of all); a view with no non-hole pixel stays black.
fn fill_holes(view: &View, pixels: &[Pixel], black: &[[u8; 3]]) -> Vec<[u8; 3]> {
    let (w, h) = (view.width, view.height);
    if !pixels.iter().any(|p| p.class == PixelClass::Hole) {
        return black.to_vec();
    }
    let n = w * h;
    let rows = || (0..h).map(move |y| (0..w).map(move |x| y * w + x));
    let cols = || (0..w).map(move |x| (0..h).map(move |y| y * w + x));
    let scans = [
        nearest_along(n, pixels, rows().map(|r| r.collect())),
        nearest_along(n, pixels, rows().map(|r| r.rev().collect())),
        nearest_along(n, pixels, cols().map(|c| c.collect())),
        nearest_along(n, pixels, cols().map(|c| c.rev().collect())),
    ];
    let mut filled = black.to_vec();
    for (i, out) in filled.iter_mut().enumerate() {
        if pixels[i].class != PixelClass::Hole {
            continue;
        }
        let farthest = scans
            .iter()
            .filter_map(|s| s[i])
            .fold(None, |best: Option<usize>, j| match best {
                Some(b) if pixels[b].z >= pixels[j].z => Some(b),
                _ => Some(j),
            });
        if let Some(j) = farthest {
            *out = black[j];
        }
    }
    filled
}
