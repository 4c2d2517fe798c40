//! Depth histogram of a whole track in log-depth space, weighted by pixel solid angle.

use serde::{Deserialize, Serialize};
use tracks::cubemap::pixel_solid_angle;
use tracks::{CubeMap, Face};

/// A histogram of radial depth over every pixel of every viewpoint, binned uniformly in
/// `log10(depth)` so near and far structure both show. Each pixel adds its solid angle
/// divided by the number of viewpoints, so the weights of one viewpoint sum to 4π and a bin
/// reads "steradians of the average panorama at this depth". Sky (`+inf`) and zero or
/// invalid depths go to separate totals, never into a bin.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthHistogram {
    /// `log10` of the lower edge of bin 0.
    pub log10_min: f64,
    /// `log10` of the upper edge of the last bin.
    pub log10_max: f64,
    /// Weight per bin (steradians per viewpoint).
    pub weights: Vec<f64>,
    /// Solid angle per viewpoint that saw sky (`+inf`).
    pub sky_sr: f64,
    /// Solid angle per viewpoint with depth 0, NaN or negative (not binned).
    pub invalid_sr: f64,
    /// Nearest and farthest finite positive depth seen, metres (`None` when all sky).
    pub depth_min_m: Option<f64>,
    pub depth_max_m: Option<f64>,
}

/// The nearest and farthest finite positive depth of `m`: `(INFINITY, 0)` when it has none.
pub fn depth_range(m: &CubeMap<f32>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for &d in m.as_slice() {
        let d = d as f64;
        if d.is_finite() && d > 0.0 {
            lo = lo.min(d);
            hi = hi.max(d);
        }
    }
    (lo, hi)
}

impl DepthHistogram {
    /// Bin the finite positive depths of `maps` (all must share one face size; an empty
    /// slice gives an empty histogram) into `bins` bins (at least 1).
    pub fn build(maps: &[CubeMap<f32>], bins: usize) -> DepthHistogram {
        let (lo, hi) = maps
            .iter()
            .map(depth_range)
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), (a, b)| {
                (lo.min(a), hi.max(b))
            });
        let views = maps.len().max(1) as f64;
        let mut h = DepthHistogram::over(lo, hi, bins);
        for m in maps {
            h.add(m, views);
        }
        h
    }

    /// An empty histogram of `bins` bins (at least 1) over the depths `lo..=hi` (the fold of
    /// every map's [`depth_range`]; `hi` of 0 when there is no finite depth): what
    /// [`DepthHistogram::build`] starts from, for maps read one at a time.
    pub fn over(lo: f64, hi: f64, bins: usize) -> DepthHistogram {
        let mut h = DepthHistogram {
            log10_min: 0.0,
            log10_max: 1.0,
            weights: vec![0.0; bins.max(1)],
            sky_sr: 0.0,
            invalid_sr: 0.0,
            depth_min_m: None,
            depth_max_m: None,
        };
        if hi > 0.0 {
            // Pad so that both extremes fall strictly inside; a constant depth still gets a
            // range of non-zero width.
            let (a, b) = (lo.log10(), hi.log10());
            let pad = ((b - a) * 1e-3).max(1e-3);
            h.log10_min = a - pad;
            h.log10_max = b + pad;
            h.depth_min_m = Some(lo);
            h.depth_max_m = Some(hi);
        }
        h
    }

    /// Adds map `m`, one of `views` viewpoints (its pixels weigh their solid angle ÷ `views`).
    pub fn add(&mut self, m: &CubeMap<f32>, views: f64) {
        let n = m.face_size();
        // Solid angles of one face, shared by the six faces.
        let sa: Vec<f64> = (0..n * n)
            .map(|i| pixel_solid_angle(i % n, i / n, n))
            .collect();
        for face in Face::ALL {
            for (i, &d) in m.face(face).iter().enumerate() {
                let w = sa[i] / views;
                let d = d as f64;
                if d == f64::INFINITY {
                    self.sky_sr += w;
                } else if d.is_finite() && d > 0.0 {
                    let b = self.bin_of(d);
                    self.weights[b] += w;
                } else {
                    self.invalid_sr += w;
                }
            }
        }
    }

    pub fn bins(&self) -> usize {
        self.weights.len()
    }

    fn bin_width(&self) -> f64 {
        (self.log10_max - self.log10_min) / self.bins() as f64
    }

    /// Bin index of a positive finite depth (clamped into range).
    pub fn bin_of(&self, depth_m: f64) -> usize {
        let t = (depth_m.log10() - self.log10_min) / self.bin_width();
        (t.floor().max(0.0) as usize).min(self.bins() - 1)
    }

    /// Depth at the lower edge of bin `i` (`i == bins` gives the upper edge of the last).
    pub fn edge_m(&self, i: usize) -> f64 {
        10f64.powf(self.log10_min + i as f64 * self.bin_width())
    }

    /// Depth at the centre of bin `i` (geometric mean of its edges).
    pub fn centre_m(&self, i: usize) -> f64 {
        10f64.powf(self.log10_min + (i as f64 + 0.5) * self.bin_width())
    }

    /// Total binned weight (finite depth), steradians per viewpoint.
    pub fn total(&self) -> f64 {
        self.weights.iter().sum()
    }

    /// The weights smoothed by a `[1 2 1]/4` kernel applied `passes` times (edges clamped).
    pub fn smoothed(&self, passes: usize) -> Vec<f64> {
        let mut w = self.weights.clone();
        let n = w.len();
        for _ in 0..passes {
            let prev = w.clone();
            for i in 0..n {
                let l = prev[i.saturating_sub(1)];
                let r = prev[(i + 1).min(n - 1)];
                w[i] = 0.25 * l + 0.5 * prev[i] + 0.25 * r;
            }
        }
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_sum_to_sphere_and_sky_is_separate() {
        let m = CubeMap::from_fn(8, |f, x, _| {
            if f == Face::PosY {
                f32::INFINITY
            } else {
                1.0 + x as f32
            }
        });
        let h = DepthHistogram::build(&[m.clone(), m], 32);
        let four_pi = 4.0 * std::f64::consts::PI;
        assert!((h.total() + h.sky_sr - four_pi).abs() < 1e-9);
        assert!((h.sky_sr - four_pi / 6.0).abs() < 1e-9);
        assert_eq!(h.depth_min_m, Some(1.0));
        assert_eq!(h.depth_max_m, Some(8.0));
        assert_eq!(h.bin_of(1.0), 0);
        assert_eq!(h.bin_of(8.0), 31);
    }

    #[test]
    fn all_sky_has_no_range() {
        let h = DepthHistogram::build(&[CubeMap::filled(4, f32::INFINITY)], 16);
        assert_eq!(h.total(), 0.0);
        assert!(h.depth_min_m.is_none());
    }
}
