//! The sweep around a base configuration ([`SweepSpec::configs`]: each knob varied on its
//! own, the others at the base). One configuration is a [`Knobs`] (`stages::Knobs`, the
//! knobs of `railview build`).

use serde::{Deserialize, Serialize};
use stages::cull::Variant;
pub use stages::knobs::{CullChoice, Knobs, SlabSpec};

use crate::error::{Error, Result};

/// The values each knob takes in a sweep; the base configuration is `base`, and every other
/// value of a list makes one configuration that differs from the base in that knob only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepSpec {
    pub base: Knobs,
    pub every: Vec<u32>,
    pub face_size: Vec<u32>,
    pub supersample: Vec<u32>,
    pub slabs: Vec<SlabSpec>,
    pub tile_size: Vec<u32>,
    pub mesh_error_px: Vec<f64>,
    /// `(variant, α)`.
    pub cull: Vec<(CullChoice, f64)>,
    pub drop_levels: Vec<u32>,
}

impl SweepSpec {
    /// Only the base configuration.
    pub fn base_only(base: Knobs) -> SweepSpec {
        SweepSpec {
            base,
            every: Vec::new(),
            face_size: Vec::new(),
            supersample: Vec::new(),
            slabs: Vec::new(),
            tile_size: Vec::new(),
            mesh_error_px: Vec::new(),
            cull: Vec::new(),
            drop_levels: Vec::new(),
        }
    }

    /// `railview tune`'s lists around `base`: every 2nd viewpoint, faces of three quarters
    /// of the base's (a multiple of 8), 2×2 supersampling, a slab fewer and one more, tiles of
    /// 16 and 64 px, mesh error 2 px, culling `paper` at α 1, `conservative` at α 0.9 and
    /// none, the finest texture level left out.
    pub fn around(base: Knobs) -> SweepSpec {
        SweepSpec {
            every: vec![2],
            face_size: vec![three_quarters(base.face_size)],
            supersample: vec![2],
            slabs: vec![SlabSpec::Auto(-1), SlabSpec::Auto(1)],
            tile_size: vec![16, 64],
            mesh_error_px: vec![2.0],
            cull: vec![
                (CullChoice::Variant(Variant::Paper), 1.0),
                (CullChoice::Variant(Variant::Conservative), 0.9),
                (CullChoice::Off, 1.0),
            ],
            drop_levels: vec![1],
            base,
        }
    }

    /// Every configuration's knobs in range (`pov`: POV-Ray renders the panoramas, at most
    /// [`prerender::pov::MAX_SUPERSAMPLE`] colour rays a pixel along each axis).
    pub fn check(&self, pov: bool) -> Result<()> {
        let bad = |m: String| Err(Error::Parameter(m));
        for k in self.configs() {
            if !(1..=64).contains(&k.every) {
                return bad(format!("--every {}: must be in 1..=64", k.every));
            }
            if !(8..=4096).contains(&k.face_size) {
                return bad(format!("face size {} out of 8..=4096", k.face_size));
            }
            let most = if pov {
                prerender::pov::MAX_SUPERSAMPLE
            } else {
                16
            };
            if !(1..=most).contains(&k.supersample) {
                return bad(format!(
                    "supersampling {} out of range (1 to {most}{})",
                    k.supersample,
                    if pov { " for POV-Ray imports" } else { "" }
                ));
            }
            if !(k.tile_size.is_power_of_two() && (4..=1024).contains(&k.tile_size)) {
                return bad(format!(
                    "tile size {}: a power of two from 4 to 1024",
                    k.tile_size
                ));
            }
            if !(k.mesh_error_px.is_finite() && k.mesh_error_px > 0.0) {
                return bad(format!("mesh error {} must be positive", k.mesh_error_px));
            }
            if k.drop_levels > 8 {
                return bad("at most 8 levels left out".into());
            }
        }
        Ok(())
    }

    /// The base, then one configuration per value that differs from the base, knob by knob in
    /// the order of the fields; no configuration twice.
    pub fn configs(&self) -> Vec<Knobs> {
        let b = &self.base;
        let mut out = vec![b.clone()];
        let mut push = |k: Knobs| {
            if !out.contains(&k) {
                out.push(k);
            }
        };
        for &v in &self.every {
            push(Knobs {
                every: v,
                ..b.clone()
            });
        }
        for &v in &self.face_size {
            push(Knobs {
                face_size: v,
                ..b.clone()
            });
        }
        for &v in &self.supersample {
            push(Knobs {
                supersample: v,
                ..b.clone()
            });
        }
        for v in &self.slabs {
            push(Knobs {
                slabs: v.clone(),
                ..b.clone()
            });
        }
        for &v in &self.tile_size {
            push(Knobs {
                tile_size: v,
                ..b.clone()
            });
        }
        for &v in &self.mesh_error_px {
            push(Knobs {
                mesh_error_px: v,
                ..b.clone()
            });
        }
        for &(cull, alpha) in &self.cull {
            push(Knobs {
                cull,
                alpha,
                ..b.clone()
            });
        }
        for &v in &self.drop_levels {
            push(Knobs {
                drop_levels: v,
                ..b.clone()
            });
        }
        out
    }
}

/// Three quarters of a face size, rounded up to a multiple of 8 (`--face-sizes 3/4`).
pub fn three_quarters(face_size: u32) -> u32 {
    (face_size * 3 / 4).div_ceil(8).max(1) * 8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_knob_at_a_time_around_the_base() {
        let spec = SweepSpec {
            every: vec![1, 2],
            slabs: vec![SlabSpec::Auto(0), SlabSpec::Auto(-1), SlabSpec::Auto(1)],
            drop_levels: vec![0, 1],
            ..SweepSpec::base_only(Knobs::default())
        };
        let c = spec.configs();
        let base = Knobs::default();
        assert_eq!(c.len(), 5);
        assert_eq!(c[0], base);
        for k in &c[1..] {
            assert_eq!(k.differences(&base).len(), 1, "{k:?}");
        }
        assert_eq!(c[1].label(&base), "every 2nd reference viewpoint");
        assert_eq!(c[4].label(&base), "finest texture level left out");
        let both = c[1].merged(&c[4], &base);
        assert_eq!(both.differences(&base).len(), 2);
    }
}
