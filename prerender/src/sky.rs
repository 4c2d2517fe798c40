//! The complete sky of a track: the background in every direction, behind occluders too.
//!
//! The sky lies at infinity, so every viewpoint sees the same sky in a direction, and a
//! view between samples can look at sky that both neighbouring references see only as an
//! occluder (the sky through a gap between trees). Each reference's background therefore
//! needs the sky in every direction, not only where its own panorama shows it.
//!
//! - Built-in scenes and scene files: the tracer renders the sky alone
//!   ([`crate::render::render_sky`]), exactly, into `sky.png` of the prerender directory.
//! - POV-Ray imports: POV-Ray has no switch that hides every object, but a ray that starts
//!   past every object sees only what lies at infinity. The import renders the sky so
//!   ([`crate::pov::PovImport::render_sky`]: rays starting twice as far out as anything the
//!   references see) into `sky.png`, and keeps it only where it matches the panoramas'
//!   own sky (within [`SKY_MATCH`] levels on average where they see it).
//! - Otherwise (a POV-Ray sky that did not match, or an older prerender directory) the sky is
//!   assembled from every reference panorama ([`SkyAccumulator`]): each direction averages, in linear light, the
//!   samples that see sky there away from any silhouette (a sky pixel whose 8 neighbours on
//!   its face are sky too, so anti-aliased edges do not tint it); directions no sample sees
//!   as sky are filled by push-pull over each face (a pyramid of averages, coarse levels
//!   filling the gaps of finer ones), faces with no sky at all by the mean of the rest.
//!   Where a scene has no sky in any panorama (an interior) there is no sky to assemble.

use glam::DVec3;
use tracks::{CubeMap, Face};

use crate::shade::{srgb8_to_linear, to_srgb8};
use crate::store::{self, PrerenderDir, PrerenderReport, StoreError};

/// How far (mean over the directions the panoramas see as clear sky, levels of 255) a sky
/// rendered alone may differ from the panoramas' own to be used.
pub const SKY_MATCH: f64 = 4.0;

/// Mean difference (levels of 255, over the three channels) between `sky` and the
/// panoramas' clear sky gathered in `acc`, over the directions they see; `None` where they
/// see none.
pub fn difference(sky: &CubeMap<[u8; 3]>, acc: &SkyAccumulator) -> Option<f64> {
    let seen = acc.finish()?;
    let n = sky.face_size();
    if seen.face_size() != n {
        return None;
    }
    let (mut sum, mut count) = (0.0, 0u64);
    for f in Face::ALL {
        for y in 0..n {
            for x in 0..n {
                if acc.is_covered(f, x, y) {
                    let (a, b) = (sky.get(f, x, y), seen.get(f, x, y));
                    sum += (0..3)
                        .map(|k| (a[k] as f64 - b[k] as f64).abs())
                        .sum::<f64>()
                        / 3.0;
                    count += 1;
                }
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// Where a track's sky came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SkySource {
    /// `sky.png`, rendered alone by the tracer.
    Rendered,
    /// Assembled from the reference panoramas ([`SkyAccumulator`]).
    Assembled,
    /// No panorama sees any sky.
    None,
}

/// A track's complete sky and where it came from.
pub struct TrackSky {
    /// `None` when no panorama sees any sky.
    pub sky: Option<CubeMap<[u8; 3]>>,
    pub source: SkySource,
}

/// The complete sky of a prerender directory: its `sky.png` when the renderer wrote one (at
/// the report's face size), else assembled from its samples' panoramas.
pub fn load_or_assemble(
    dir: &PrerenderDir,
    report: &PrerenderReport,
) -> Result<TrackSky, StoreError> {
    let path = dir.sky_png();
    if path.is_file() {
        let sky = store::read_rgb_png(&path)?;
        if sky.face_size() == report.face_size {
            return Ok(TrackSky {
                sky: Some(sky),
                source: SkySource::Rendered,
            });
        }
    }
    let mut acc = SkyAccumulator::new(report.face_size);
    for vp in &report.viewpoints {
        let color = store::read_rgb_png(&dir.color_png(vp.index))?;
        let depth = store::read_depth_exr(&dir.depth_exr(vp.index))?;
        acc.add(&color, &depth)
            .map_err(|message| StoreError::Format {
                path: dir.color_png(vp.index),
                message,
            })?;
    }
    Ok(match acc.finish() {
        Some(sky) => TrackSky {
            sky: Some(sky),
            source: SkySource::Assembled,
        },
        None => TrackSky {
            sky: None,
            source: SkySource::None,
        },
    })
}

/// Sum of linear colours and their count per direction, over the panoramas added.
pub struct SkyAccumulator {
    sum: CubeMap<[f32; 4]>,
}

impl SkyAccumulator {
    pub fn new(face_size: u32) -> Self {
        SkyAccumulator {
            sum: CubeMap::filled(face_size, [0.0; 4]),
        }
    }

    /// Add one panorama (sRGB colour, radial depth; infinite depth = sky). Maps of another
    /// face size than the accumulator's are an error.
    pub fn add(&mut self, color: &CubeMap<[u8; 3]>, depth: &CubeMap<f32>) -> Result<(), String> {
        let n = self.sum.face_size();
        if color.face_size() != n || depth.face_size() != n {
            return Err(format!(
                "panorama of {} px (depth {} px) added to a sky of {n} px",
                color.face_size(),
                depth.face_size()
            ));
        }
        let sky = |f: Face, x: i64, y: i64| {
            x < 0
                || y < 0
                || x >= n as i64
                || y >= n as i64
                || !depth.get(f, x as u32, y as u32).is_finite()
        };
        for f in Face::ALL {
            for y in 0..n {
                for x in 0..n {
                    let (xi, yi) = (x as i64, y as i64);
                    let clear = (-1..=1).all(|dy| (-1..=1).all(|dx| sky(f, xi + dx, yi + dy)));
                    if !clear {
                        continue;
                    }
                    let c = color.get(f, x, y);
                    let s = self.sum.get_mut(f, x, y);
                    for k in 0..3 {
                        s[k] += srgb8_to_linear(c[k]);
                    }
                    s[3] += 1.0;
                }
            }
        }
        Ok(())
    }

    /// Whether some panorama saw this direction as clear sky.
    pub fn is_covered(&self, face: Face, x: u32, y: u32) -> bool {
        self.sum.get(face, x, y)[3] > 0.0
    }

    /// Directions some panorama saw as clear sky.
    pub fn covered(&self) -> usize {
        self.sum.as_slice().iter().filter(|s| s[3] > 0.0).count()
    }

    /// The sky in every direction (gaps filled as the module docs say); `None` when no
    /// panorama saw any clear sky.
    pub fn finish(&self) -> Option<CubeMap<[u8; 3]>> {
        let n = self.sum.face_size();
        let mut total = [0.0f64; 4];
        for s in self.sum.as_slice() {
            for k in 0..4 {
                total[k] += s[k] as f64;
            }
        }
        if total[3] == 0.0 {
            return None;
        }
        let mean = [
            (total[0] / total[3]) as f32,
            (total[1] / total[3]) as f32,
            (total[2] / total[3]) as f32,
        ];
        let mut out = CubeMap::filled(n, [0u8; 3]);
        for f in Face::ALL {
            let avg: Vec<[f32; 4]> = self
                .sum
                .face(f)
                .iter()
                .map(|s| {
                    if s[3] > 0.0 {
                        [s[0] / s[3], s[1] / s[3], s[2] / s[3], 1.0]
                    } else {
                        [0.0; 4]
                    }
                })
                .collect();
            let filled = push_pull(&avg, n as usize, mean);
            for (o, c) in out.face_mut(f).iter_mut().zip(filled) {
                *o = to_srgb8(DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64));
            }
        }
        Some(out)
    }
}

/// Fill the texels of weight 0 of an `n × n` image of `[r, g, b, weight]` (colour not
/// premultiplied) from a pyramid of weighted averages; `fallback` where the whole image has
/// weight 0.
fn push_pull(img: &[[f32; 4]], n: usize, fallback: [f32; 3]) -> Vec<[f32; 3]> {
    // Premultiplied levels, each half the size (rounded up) of the one before.
    let mut levels: Vec<(usize, Vec<[f32; 4]>)> = vec![(
        n,
        img.iter()
            .map(|p| [p[0] * p[3], p[1] * p[3], p[2] * p[3], p[3]])
            .collect(),
    )];
    while levels.last().is_some_and(|(m, _)| *m > 1) {
        let (m, prev) = levels.last().expect("a level");
        let h = m.div_ceil(2);
        let mut next = vec![[0.0f32; 4]; h * h];
        for y in 0..*m {
            for x in 0..*m {
                let p = prev[y * m + x];
                let q = &mut next[(y / 2) * h + x / 2];
                for k in 0..4 {
                    q[k] += p[k];
                }
            }
        }
        levels.push((h, next));
    }
    // Pull: each level's empty texels take the colour of the coarser level above them.
    let mut coarse: Vec<[f32; 3]> = {
        let (_, top) = levels.last().expect("a level");
        let t = top[0];
        vec![if t[3] > 0.0 {
            [t[0] / t[3], t[1] / t[3], t[2] / t[3]]
        } else {
            fallback
        }]
    };
    for li in (0..levels.len() - 1).rev() {
        let (m, lvl) = &levels[li];
        let h = m.div_ceil(2);
        coarse = (0..m * m)
            .map(|i| {
                let (x, y) = (i % m, i / m);
                let p = lvl[i];
                if p[3] > 0.0 {
                    [p[0] / p[3], p[1] / p[3], p[2] / p[3]]
                } else {
                    coarse[(y / 2) * h + x / 2]
                }
            })
            .collect();
    }
    coarse
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sky rendered alone is compared with the panoramas' only where they see clear sky:
    /// what it shows behind their occluders does not count, a wrong sky does.
    #[test]
    fn a_sky_rendered_alone_is_judged_where_the_panoramas_see_sky() {
        let n = 8;
        let blue = CubeMap::filled(n, [40u8, 80, 200]);
        let depth = CubeMap::from_fn(n, |_, x, _| if x < 4 { 3.0f32 } else { f32::INFINITY });
        let mut acc = SkyAccumulator::new(n);
        acc.add(&blue, &depth).unwrap();
        // Right where they see sky, anything behind their occluder.
        let alone = CubeMap::from_fn(n, |_, x, _| if x < 4 { [0, 0, 0] } else { [40, 80, 200] });
        assert_eq!(difference(&alone, &acc), Some(0.0));
        let wrong = CubeMap::filled(n, [46u8, 86, 206]);
        assert_eq!(difference(&wrong, &acc), Some(6.0));
        assert!(difference(&wrong, &acc).unwrap() > SKY_MATCH);
        // No sky seen: nothing to judge by.
        let closed = CubeMap::filled(n, 3.0f32);
        let mut none = SkyAccumulator::new(n);
        none.add(&blue, &closed).unwrap();
        assert_eq!(difference(&alone, &none), None);
    }

    #[test]
    fn sky_behind_an_occluder_comes_from_another_panorama() {
        let n = 8;
        let blue = CubeMap::filled(n, [40u8, 80, 200]);
        // Panorama 1: an occluder over the left half of every face.
        let d1 = CubeMap::from_fn(n, |_, x, _| if x < 4 { 3.0f32 } else { f32::INFINITY });
        // Panorama 2: an occluder over the right half.
        let d2 = CubeMap::from_fn(n, |_, x, _| if x >= 4 { 3.0f32 } else { f32::INFINITY });
        let mut acc = SkyAccumulator::new(n);
        acc.add(&blue, &d1).unwrap();
        acc.add(&blue, &d2).unwrap();
        let sky = acc.finish().unwrap();
        // The edge columns next to each occluder are not clear in either panorama; push-pull
        // fills them with the same blue.
        assert!(sky.as_slice().iter().all(|c| *c == [40, 80, 200]));
    }

    #[test]
    fn silhouette_pixels_do_not_tint_the_sky() {
        let n = 8;
        let d = CubeMap::from_fn(n, |_, x, y| {
            if x == 3 && y == 3 {
                2.0f32
            } else {
                f32::INFINITY
            }
        });
        // Colour: anti-aliased red around the occluder pixel.
        let c = CubeMap::from_fn(n, |_, x, y| {
            if (x as i32 - 3).abs() <= 1 && (y as i32 - 3).abs() <= 1 {
                [200u8, 0, 0]
            } else {
                [0u8, 0, 200]
            }
        });
        let mut acc = SkyAccumulator::new(n);
        acc.add(&c, &d).unwrap();
        let sky = acc.finish().unwrap();
        assert!(
            sky.as_slice().iter().all(|p| p[0] == 0),
            "no red leaks into the sky"
        );
    }

    #[test]
    fn no_sky_anywhere_gives_none_and_mismatched_sizes_are_an_error() {
        let mut acc = SkyAccumulator::new(4);
        acc.add(&CubeMap::filled(4, [1u8; 3]), &CubeMap::filled(4, 5.0f32))
            .unwrap();
        assert!(acc.finish().is_none());
        assert!(acc
            .add(&CubeMap::filled(8, [1u8; 3]), &CubeMap::filled(4, 5.0f32))
            .is_err());
    }

    #[test]
    fn a_face_without_sky_takes_the_mean() {
        let n = 4;
        let d = CubeMap::from_fn(n, |f, _, _| {
            if f == Face::ALL[0] {
                1.0f32
            } else {
                f32::INFINITY
            }
        });
        let mut acc = SkyAccumulator::new(n);
        acc.add(&CubeMap::filled(n, [90u8, 90, 90]), &d).unwrap();
        let sky = acc.finish().unwrap();
        assert!(sky.face(Face::ALL[0]).iter().all(|c| *c == [90, 90, 90]));
    }
}
