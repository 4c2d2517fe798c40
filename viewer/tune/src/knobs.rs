//! The sweep around a base configuration ([`SweepSpec::configs`]: each knob varied on its
//! own, the others at the base). One configuration is a [`Knobs`] (`stages::Knobs`, the
//! knobs of `railview build`).

use serde::{Deserialize, Serialize};
pub use stages::knobs::{CullChoice, Knobs, SlabSpec};

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
