//! Image error metrics for evaluation: PSNR, SSIM and the fraction of hole pixels, plus the
//! resampling floor (the ground-truth cube map resampled straight into the camera).

use tracks::{CubeMap, PerspectiveCamera};

use crate::texture::{linear_to_srgb, Layer};

/// PSNR in dB over RGB of two equally sized sRGB images (`f64::INFINITY` when identical).
pub fn psnr(a: &[[u8; 3]], b: &[[u8; 3]]) -> f64 {
    let n = a.len().min(b.len()).max(1);
    let se: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] as f64 - q[k] as f64).powi(2)))
        .sum();
    let mse = se / (3 * n) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

fn luma(p: [u8; 3]) -> f64 {
    0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
}

/// Mean SSIM on luma over 7×7 windows with stride 1 (Wang et al. constants, L = 255);
/// images smaller than a window are compared as one window.
pub fn ssim(a: &[[u8; 3]], b: &[[u8; 3]], width: u32, height: u32) -> f64 {
    let (w, h) = (width as usize, height as usize);
    if a.len() < w * h || b.len() < w * h || w * h == 0 {
        return 0.0;
    }
    let la: Vec<f64> = a.iter().map(|p| luma(*p)).collect();
    let lb: Vec<f64> = b.iter().map(|p| luma(*p)).collect();
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let win = 7.min(w).min(h);
    let mut total = 0.0;
    let mut count = 0usize;
    for y0 in 0..=h - win {
        for x0 in 0..=w - win {
            let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for y in y0..y0 + win {
                for x in x0..x0 + win {
                    let (p, q) = (la[y * w + x], lb[y * w + x]);
                    sa += p;
                    sb += q;
                    saa += p * p;
                    sbb += q * q;
                    sab += p * q;
                }
            }
            let n = (win * win) as f64;
            let (ma, mb) = (sa / n, sb / n);
            let va = (saa / n - ma * ma).max(0.0);
            let vb = (sbb / n - mb * mb).max(0.0);
            let cov = sab / n - ma * mb;
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
        }
    }
    total / count.max(1) as f64
}

/// RGB of an RGBA frame (holes stay black) and its hole fraction.
pub fn split_rgba(rgba: &[u8]) -> (Vec<[u8; 3]>, f64) {
    let rgb: Vec<[u8; 3]> = rgba.chunks_exact(4).map(|p| [p[0], p[1], p[2]]).collect();
    let holes = rgba.chunks_exact(4).filter(|p| p[3] == 0).count();
    let fraction = holes as f64 / rgb.len().max(1) as f64;
    (rgb, fraction)
}

/// The fraction of an RGBA frame's pixels filled from the farther side (alpha strictly
/// between 0 and 255: `FILLED_ALPHA` of `render.wgsl`).
pub fn filled_fraction(rgba: &[u8]) -> f64 {
    let n = rgba.len() / 4;
    let filled = rgba
        .chunks_exact(4)
        .filter(|p| p[3] > 0 && p[3] < 255)
        .count();
    filled as f64 / n.max(1) as f64
}

/// The resampling floor: a full cube map (e.g. the reference colour) bilinearly resampled
/// into `camera` with no geometry — what any image-based view at that position can at best
/// reach against a ray-traced ground truth at this cube-map resolution.
pub fn resample_cube(cube: &CubeMap<[u8; 4]>, camera: &PerspectiveCamera) -> Vec<[u8; 3]> {
    let layer = Layer {
        levels: vec![cube.clone()],
    };
    let n = cube.face_size();
    let (w, h) = (camera.width.max(1), camera.height.max(1));
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let d = camera.pixel_dir(x, y);
            match tracks::FaceCoord::from_dir(d) {
                Some(c) => {
                    let (px, py) = c.to_pixel_f(n);
                    let s = layer.sample(0.0, c.face, px, py);
                    [
                        linear_to_srgb(s[0]),
                        linear_to_srgb(s[1]),
                        linear_to_srgb(s[2]),
                    ]
                }
                None => [0, 0, 0],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_are_perfect() {
        let a: Vec<[u8; 3]> = (0..64).map(|i| [i as u8 * 3, 10, 200]).collect();
        assert_eq!(psnr(&a, &a), f64::INFINITY);
        assert!((ssim(&a, &a, 8, 8) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn psnr_of_a_known_error() {
        let a = vec![[100u8, 100, 100]; 16];
        let b = vec![[110u8, 110, 110]; 16];
        assert!((psnr(&a, &b) - 10.0 * (65025.0f64 / 100.0).log10()).abs() < 1e-9);
        assert!(ssim(&a, &b, 4, 4) < 1.0);
    }

    #[test]
    fn holes_are_counted() {
        let (rgb, f) = split_rgba(&[1, 2, 3, 255, 0, 0, 0, 0]);
        assert_eq!(rgb, vec![[1, 2, 3], [0, 0, 0]]);
        assert_eq!(f, 0.5);
    }
}
