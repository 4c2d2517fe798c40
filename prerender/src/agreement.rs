//! How two reference panoramas agree on the surfaces both see: the colour difference of the
//! same surface point seen from two viewpoints.
//!
//! Every pixel of `a` on a smooth surface (no neighbour in its face more than 8 % nearer or
//! farther) is taken to its surface point; where `b` sees that point too — the four pixels
//! around its direction in `b` are on a smooth surface and their depth, interpolated there,
//! is within 1 % of its distance from `b` — its colour is compared with `b`'s, interpolated
//! the same way. Lighting computed per render (such
//! as POV-Ray's radiosity, sampled anew in each) shows in the difference; so do shading that
//! depends on the view (highlights, reflections) and texture detail finer than a pixel,
//! which set a floor that a scene without either reaches.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use tracks::cubemap::pixel_dir;
use tracks::{CubeMap, Face, FaceCoord};

/// One reference panorama: where it was taken, its colour and its radial depth.
#[derive(Clone, Copy, Debug)]
pub struct Panorama<'a> {
    pub position: DVec3,
    pub colour: &'a CubeMap<[u8; 3]>,
    pub depth: &'a CubeMap<f32>,
}

/// Colour differences over the surface points two panoramas share, in levels of 255
/// (mean over the three channels of each point).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Agreement {
    /// Points compared.
    pub pixels: u64,
    pub mean: f64,
    /// 95th percentile.
    pub p95: f64,
}

/// Largest relative depth step to a neighbour of a smooth-surface pixel.
const SMOOTH: f64 = 0.08;
/// Largest relative difference between a point's distance and the depth seen towards it.
const SAME: f64 = 0.01;

/// How `a` and `b` agree on the surface points both see ([`Agreement`]); the two maps of a
/// panorama must have one face size.
pub fn agreement(a: &Panorama, b: &Panorama) -> Agreement {
    let n = a.depth.face_size();
    let mut diffs: Vec<f64> = Vec::new();
    if a.colour.face_size() != n || b.colour.face_size() != b.depth.face_size() {
        return Agreement::default();
    }
    for face in Face::ALL {
        for y in 0..n {
            for x in 0..n {
                let d = *a.depth.get(face, x, y) as f64;
                if !(d.is_finite() && d > 0.0 && smooth(a.depth, face, x, y)) {
                    continue;
                }
                let p = a.position + d * pixel_dir(face, x, y, n);
                if let Some(c) = sample(b, p) {
                    let ca = a.colour.get(face, x, y);
                    let diff = (0..3).map(|i| (ca[i] as f64 - c[i]).abs()).sum::<f64>() / 3.0;
                    diffs.push(diff);
                }
            }
        }
    }
    if diffs.is_empty() {
        return Agreement::default();
    }
    let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
    let k = ((diffs.len() as f64 * 0.95) as usize).min(diffs.len() - 1);
    let pixels = diffs.len() as u64;
    let (_, p95, _) = diffs.select_nth_unstable_by(k, f64::total_cmp);
    Agreement {
        pixels,
        mean,
        p95: *p95,
    }
}

/// No neighbour in the face (those that exist) farther or nearer by more than [`SMOOTH`].
fn smooth(depth: &CubeMap<f32>, face: Face, x: u32, y: u32) -> bool {
    let n = depth.face_size();
    let d = *depth.get(face, x, y) as f64;
    [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
        .iter()
        .filter_map(|&(dx, dy)| {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            (nx >= 0 && ny >= 0 && nx < n as i64 && ny < n as i64)
                .then(|| *depth.get(face, nx as u32, ny as u32) as f64)
        })
        .all(|e| (e - d).abs() <= SMOOTH * d)
}

/// `b`'s colour towards the point `p`, bilinear between the four pixel centres around its
/// direction, where all four see `p`'s surface; `None` otherwise (or across a face edge).
fn sample(b: &Panorama, p: DVec3) -> Option<[f64; 3]> {
    let n = b.depth.face_size();
    let v = p - b.position;
    let dist = v.length();
    let c = FaceCoord::from_dir(v)?;
    let (fx, fy) = c.to_pixel_f(n);
    let (x0, y0) = ((fx - 0.5).floor(), (fy - 0.5).floor());
    if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= n as f64 || y0 + 1.0 >= n as f64 {
        return None;
    }
    let (tx, ty) = (fx - 0.5 - x0, fy - 0.5 - y0);
    let (x0, y0) = (x0 as u32, y0 as u32);
    let mut out = [0.0; 3];
    let (mut depth, mut lo, mut hi) = (0.0, f64::INFINITY, 0.0f64);
    for (dx, dy, w) in [
        (0, 0, (1.0 - tx) * (1.0 - ty)),
        (1, 0, tx * (1.0 - ty)),
        (0, 1, (1.0 - tx) * ty),
        (1, 1, tx * ty),
    ] {
        let (x, y) = (x0 + dx, y0 + dy);
        let d = *b.depth.get(c.face, x, y) as f64;
        if !d.is_finite() {
            return None;
        }
        (depth, lo, hi) = (depth + w * d, lo.min(d), hi.max(d));
        let col = b.colour.get(c.face, x, y);
        for i in 0..3 {
            out[i] += w * col[i] as f64;
        }
    }
    (hi <= lo * (1.0 + SMOOTH) && (depth - dist).abs() <= SAME * dist).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A room of grey walls lit the same from everywhere: two panoramas agree exactly; one
    /// lit brighter by 6 levels differs by 6.
    #[test]
    fn a_uniform_room_agrees_and_a_brighter_one_does_not() {
        let n = 32;
        let room = |pos: DVec3| {
            // Inside the box [-4, 4]³: distance to the wall along each pixel's direction.
            CubeMap::from_fn(n, |f, x, y| {
                let d = pixel_dir(f, x, y, n);
                let t = [d.x, d.y, d.z]
                    .iter()
                    .zip([pos.x, pos.y, pos.z])
                    .map(|(&c, p)| {
                        if c > 0.0 {
                            (4.0 - p) / c
                        } else {
                            (-4.0 - p) / c
                        }
                    })
                    .fold(f64::INFINITY, f64::min);
                t as f32
            })
        };
        let (pa, pb) = (DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.6, 0.1, -0.3));
        let (da, db) = (room(pa), room(pb));
        let grey = CubeMap::filled(n, [120u8, 120, 120]);
        let brighter = CubeMap::filled(n, [126u8, 126, 126]);
        let a = Panorama {
            position: pa,
            colour: &grey,
            depth: &da,
        };
        let b = Panorama {
            position: pb,
            colour: &grey,
            depth: &db,
        };
        let same = agreement(&a, &b);
        assert!(same.pixels > 1000, "{same:?}");
        assert!(same.mean < 1e-9 && same.p95 < 1e-9, "{same:?}");
        let b2 = Panorama {
            colour: &brighter,
            ..b
        };
        let off = agreement(&a, &b2);
        assert_eq!(off.pixels, same.pixels);
        assert!((off.mean - 6.0).abs() < 1e-9, "{off:?}");
    }
}
