//! The build's knobs ([`Knobs`]): everything that decides one database of a scene along a
//! track besides the scene and track themselves, with the closed sets as enums
//! ([`SlabSpec`], [`CullChoice`]) that read and write the command line's text.

use std::fmt;
use std::str::FromStr;

use occlusion::Variant;
use serde::{Deserialize, Serialize};
use tracks::SlabRange;

/// Which slab boundaries: the automatic choice moved by a number of boundaries, or ranges.
#[derive(Clone, Debug, PartialEq)]
pub enum SlabSpec {
    /// The automatic choice with `n` boundaries more (`n < 0`: fewer): `auto` (0), `fewer`
    /// (−1), `more` (+1), `auto-N`, `auto+N` (N up to 16).
    Auto(i32),
    /// Slab ranges in metres, e.g. `0-1000,1000-10000,10000-inf`.
    Ranges(Vec<SlabRange>),
}

impl Default for SlabSpec {
    fn default() -> Self {
        SlabSpec::Auto(0)
    }
}

impl fmt::Display for SlabSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SlabSpec::Auto(0) => f.write_str("auto"),
            SlabSpec::Auto(-1) => f.write_str("fewer"),
            SlabSpec::Auto(1) => f.write_str("more"),
            SlabSpec::Auto(d) => write!(f, "auto{d:+}"),
            SlabSpec::Ranges(r) => f.write_str(&crate::prerender::labels(r)),
        }
    }
}

impl FromStr for SlabSpec {
    type Err = String;
    /// `auto`, `fewer`, `more`, `auto-N`, `auto+N` or ranges; the message names `--slabs`.
    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || {
            format!("--slabs `{text}`: expected auto, fewer, more, auto-N, auto+N or ranges like 0-10,10-inf")
        };
        Ok(match text {
            "auto" => SlabSpec::Auto(0),
            "fewer" => SlabSpec::Auto(-1),
            "more" => SlabSpec::Auto(1),
            t if t.starts_with("auto") => {
                let d: i32 = t["auto".len()..].parse().map_err(|_| bad())?;
                if !(-16..=16).contains(&d) {
                    return Err(bad());
                }
                SlabSpec::Auto(d)
            }
            t => SlabSpec::Ranges(SlabRange::parse_list(t).map_err(|e| format!("--slabs: {e}"))?),
        })
    }
}

/// Which culling a database gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CullChoice {
    /// At α = 1 the shrunk variant for scenes whose solids the tracer has (built-in and TOML
    /// scenes) and the rendered one for POV-Ray imports; the conservative one at α < 1.
    #[default]
    Auto,
    /// Keep every non-empty tile.
    Off,
    /// This variant.
    Variant(Variant),
}

impl CullChoice {
    /// The variant that runs: `Auto` resolved for a POV-Ray import (`pov`) or not, at `alpha`;
    /// none for [`CullChoice::Off`].
    pub fn resolve(self, pov: bool, alpha: f64) -> Option<Variant> {
        match self {
            CullChoice::Off => None,
            CullChoice::Auto => Some(match (pov, alpha == 1.0) {
                (false, true) => Variant::Shrunk,
                (true, true) => Variant::Rendered,
                (_, false) => Variant::Conservative,
            }),
            CullChoice::Variant(v) => Some(v),
        }
    }
}

impl fmt::Display for CullChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CullChoice::Auto => "auto",
            CullChoice::Off => "none",
            CullChoice::Variant(v) => v.name(),
        })
    }
}

impl CullChoice {
    /// `VARIANT:ALPHA` (`auto`, `shrunk`, `rendered`, `conservative`, `paper`; α 1 when left
    /// out) or `none`, for a POV-Ray import (`pov`) or not: `auto` resolved, a variant that
    /// cannot run there refused.
    pub fn parse_with_alpha(text: &str, pov: bool) -> Result<(CullChoice, f64), String> {
        if text == "none" {
            return Ok((CullChoice::Off, 1.0));
        }
        let (v, a) = text.split_once(':').unwrap_or((text, "1"));
        let alpha: f64 = a
            .parse()
            .ok()
            .filter(|x: &f64| *x > 0.0 && *x <= 1.0)
            .ok_or("α must be in (0, 1]")?;
        let variant = match v {
            "auto" => CullChoice::Auto
                .resolve(pov, alpha)
                .unwrap_or(Variant::Conservative),
            _ => Variant::parse(v)
                .ok_or("expected auto, shrunk, rendered, conservative, paper or none")?,
        };
        if !variant.takes_alpha() && alpha != 1.0 {
            return Err(format!("the {} variant runs at α = 1 only", variant.name()));
        }
        if variant == Variant::Shrunk && pov {
            return Err("the shrunk variant needs a scene's solids (not --pov)".into());
        }
        Ok((CullChoice::Variant(variant), alpha))
    }
}

impl FromStr for CullChoice {
    type Err = String;
    /// `auto`, `none`, `shrunk`, `rendered`, `conservative` or `paper` (surrounding blanks
    /// ignored).
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(CullChoice::Auto),
            "none" => Ok(CullChoice::Off),
            t => Variant::parse(t).map(CullChoice::Variant).ok_or_else(|| {
                format!("`{t}`: expected auto, shrunk, rendered, conservative, paper or none")
            }),
        }
    }
}

/// Serialises as its text (`"auto"`, `"fewer"`, `"0-10,10-inf"`, `"shrunk"`, `"none"`).
macro_rules! serde_as_text {
    ($t:ty) => {
        impl Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let text = String::deserialize(d)?;
                text.parse().map_err(serde::de::Error::custom)
            }
        }
    };
}
serde_as_text!(SlabSpec);
serde_as_text!(CullChoice);

/// Everything that decides one database of a scene along a track, besides the scene and
/// track themselves. Serialised (a sweep's `sweep.json`) with the knobs a sweep varies; the
/// resampling of the track and the zstd level are not written there (`build.json` writes
/// them, as `encode::BuildConfig`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Knobs {
    /// Keep every n-th reference viewpoint of the track's own sampling (1 = all of them).
    pub every: u32,
    /// Reference viewpoints: exactly N, evenly spread along the track (default: the track's
    /// own sampling).
    #[serde(skip)]
    pub samples: Option<usize>,
    /// Reference viewpoints at most this many metres apart (default: the track's own
    /// sampling).
    #[serde(skip)]
    pub spacing_m: Option<f64>,
    pub face_size: u32,
    /// Rays per pixel along each axis of the panoramas.
    pub supersample: u32,
    pub slabs: SlabSpec,
    pub tile_size: u32,
    pub mesh_error_px: f64,
    #[serde(rename = "cull_variant")]
    pub cull: CullChoice,
    pub alpha: f64,
    /// Finest texture levels left out.
    pub drop_levels: u32,
    /// zstd level of the PTM groups coded with zstd.
    #[serde(skip, default = "default_zstd_level")]
    pub zstd_level: i32,
}

fn default_zstd_level() -> i32 {
    19
}

impl Default for Knobs {
    /// A sweep's base without options: `railview build`'s knobs (faces of 128 pixels) with
    /// the conservative culling variant.
    fn default() -> Self {
        Knobs {
            every: 1,
            samples: None,
            spacing_m: None,
            face_size: 128,
            supersample: 1,
            slabs: SlabSpec::Auto(0),
            tile_size: 32,
            mesh_error_px: 0.5,
            cull: CullChoice::Variant(Variant::Conservative),
            alpha: 1.0,
            drop_levels: 0,
            zstd_level: default_zstd_level(),
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
        if self.cull != base.cull || self.alpha != base.alpha {
            v.push(if self.cull == CullChoice::Off {
                "no culling".to_string()
            } else {
                format!("culling {} α {}", self.cull, self.alpha)
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
        if other.cull != base.cull || other.alpha != base.alpha {
            k.cull = other.cull;
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

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn closed_sets_read_and_write_the_command_line_text() {
        for text in [
            "auto",
            "fewer",
            "more",
            "auto-2",
            "auto+3",
            "0-10,10-inf",
            "0.5-2,2-inf",
        ] {
            let s: SlabSpec = text.parse().unwrap();
            assert_eq!(s.to_string(), text);
            assert_eq!(serde_json::to_string(&s).unwrap(), format!("\"{text}\""));
        }
        assert!("auto+17".parse::<SlabSpec>().is_err());
        let err = |t: &str| t.parse::<SlabSpec>().unwrap_err();
        assert!(err("autox").contains("--slabs `autox`"));
        assert!(err("some").starts_with("--slabs: slab 0"));
        for text in [
            "auto",
            "none",
            "shrunk",
            "rendered",
            "conservative",
            "paper",
        ] {
            let c: CullChoice = text.parse().unwrap();
            assert_eq!(c.to_string(), text);
        }
        let json = serde_json::to_value(Knobs::default()).unwrap();
        assert_eq!(json["cull_variant"], "conservative");
        assert_eq!(json["slabs"], "auto");
        assert!(json.get("zstd_level").is_none() && json.get("samples").is_none());
        let back: Knobs = serde_json::from_value(json).unwrap();
        assert_eq!(back, Knobs::default());
    }
}
