//! The build knobs one configuration sets ([`Knobs`]) and the sweep around a base
//! configuration ([`SweepSpec::configs`]: each knob varied on its own, the others at the base).

use serde::{Deserialize, Serialize};

/// Everything `railview build` needs to make one database of a scene along a track, besides
/// the scene and track themselves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Knobs {
    /// Keep every n-th reference viewpoint of the track's own sampling (1 = all of them).
    pub every: u32,
    pub face_size: u32,
    /// Rays per pixel along each axis of the panoramas.
    pub supersample: u32,
    /// `auto`, `fewer`, `more` (or anything `railview slabs --slabs` takes).
    pub slabs: String,
    pub tile_size: u32,
    pub mesh_error_px: f64,
    /// `conservative`, `paper` or `none`.
    pub cull_variant: String,
    pub alpha: f64,
    /// Finest texture levels left out.
    pub drop_levels: u32,
}

impl Default for Knobs {
    /// What `railview build` does without options (faces of 128 pixels).
    fn default() -> Self {
        Knobs {
            every: 1,
            face_size: 128,
            supersample: 1,
            slabs: "auto".into(),
            tile_size: 32,
            mesh_error_px: 0.5,
            cull_variant: "conservative".into(),
            alpha: 1.0,
            drop_levels: 0,
        }
    }
}

impl Knobs {
    /// Reference viewpoints kept of a track sampled with `base_samples`: the first, every
    /// `every`-th after it, and the last (evenly spread again when `every` does not divide the
    /// segments).
    pub fn samples(&self, base_samples: usize) -> usize {
        if base_samples <= 1 || self.every <= 1 {
            return base_samples;
        }
        let segments = base_samples - 1;
        segments.div_ceil(self.every as usize) + 1
    }

    /// What differs from `base`, one phrase per knob, in knob order.
    pub fn differences(&self, base: &Knobs) -> Vec<String> {
        let mut v = Vec::new();
        if self.every != base.every {
            v.push(format!("every {} reference viewpoint", ordinal(self.every)));
        }
        if self.face_size != base.face_size {
            v.push(format!("faces of {} px", self.face_size));
        }
        if self.supersample != base.supersample {
            v.push(format!(
                "{}×{} rays per panorama pixel",
                self.supersample, self.supersample
            ));
        }
        if self.slabs != base.slabs {
            v.push(format!("slabs {}", self.slabs));
        }
        if self.tile_size != base.tile_size {
            v.push(format!("tiles of {} px", self.tile_size));
        }
        if self.mesh_error_px != base.mesh_error_px {
            v.push(format!("mesh error {} px", self.mesh_error_px));
        }
        if self.cull_variant != base.cull_variant || self.alpha != base.alpha {
            v.push(if self.cull_variant == "none" {
                "no culling".to_string()
            } else {
                format!("culling {} α {}", self.cull_variant, self.alpha)
            });
        }
        if self.drop_levels != base.drop_levels {
            v.push(match self.drop_levels {
                0 => "every texture level".to_string(),
                1 => "finest texture level left out".to_string(),
                n => format!("{n} finest texture levels left out"),
            });
        }
        v
    }

    /// A short name: `base`, or the differences from `base`.
    pub fn label(&self, base: &Knobs) -> String {
        let d = self.differences(base);
        if d.is_empty() {
            "base".into()
        } else {
            d.join(", ")
        }
    }

    /// `self` with every knob in which `other` differs from `base` taken from `other`.
    pub fn merged(&self, other: &Knobs, base: &Knobs) -> Knobs {
        let mut k = self.clone();
        if other.every != base.every {
            k.every = other.every;
        }
        if other.face_size != base.face_size {
            k.face_size = other.face_size;
        }
        if other.supersample != base.supersample {
            k.supersample = other.supersample;
        }
        if other.slabs != base.slabs {
            k.slabs = other.slabs.clone();
        }
        if other.tile_size != base.tile_size {
            k.tile_size = other.tile_size;
        }
        if other.mesh_error_px != base.mesh_error_px {
            k.mesh_error_px = other.mesh_error_px;
        }
        if other.cull_variant != base.cull_variant || other.alpha != base.alpha {
            k.cull_variant = other.cull_variant.clone();
            k.alpha = other.alpha;
        }
        if other.drop_levels != base.drop_levels {
            k.drop_levels = other.drop_levels;
        }
        k
    }
}

fn ordinal(n: u32) -> String {
    match n {
        1 => String::new(),
        2 => "2nd".into(),
        3 => "3rd".into(),
        n => format!("{n}th"),
    }
}

/// The values each knob takes in a sweep; the base configuration is `base`, and every other
/// value of a list makes one configuration that differs from the base in that knob only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepSpec {
    pub base: Knobs,
    pub every: Vec<u32>,
    pub face_size: Vec<u32>,
    pub supersample: Vec<u32>,
    pub slabs: Vec<String>,
    pub tile_size: Vec<u32>,
    pub mesh_error_px: Vec<f64>,
    /// `(variant, α)`.
    pub cull: Vec<(String, f64)>,
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
        for (variant, alpha) in &self.cull {
            push(Knobs {
                cull_variant: variant.clone(),
                alpha: *alpha,
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
            slabs: vec!["auto".into(), "fewer".into(), "more".into()],
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

    #[test]
    fn every_nth_sample_keeps_both_ends() {
        let k = |every| Knobs {
            every,
            ..Knobs::default()
        };
        assert_eq!(k(1).samples(37), 37);
        assert_eq!(k(2).samples(37), 19);
        assert_eq!(k(3).samples(37), 13);
        assert_eq!(k(5).samples(37), 9);
        assert_eq!(k(2).samples(1), 1);
        assert_eq!(k(4).samples(2), 2);
    }
}
