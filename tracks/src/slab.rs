//! Slab depth ranges.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A slab: the radial depth interval `[near, far)` in metres; `far` may be `+inf`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabRange {
    pub near: f64,
    /// `null` in JSON for infinity.
    #[serde(serialize_with = "ser_far", deserialize_with = "de_far")]
    pub far: f64,
}

fn ser_far<S: Serializer>(far: &f64, s: S) -> Result<S::Ok, S::Error> {
    if far.is_finite() {
        s.serialize_f64(*far)
    } else {
        s.serialize_none()
    }
}

fn de_far<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

impl SlabRange {
    /// `None` unless `0 ≤ near < far` (far may be `+inf`) and `near` is finite.
    pub fn new(near: f64, far: f64) -> Option<SlabRange> {
        (near.is_finite() && near >= 0.0 && far > near).then_some(SlabRange { near, far })
    }

    /// Whether a radial depth falls in `[near, far)`.
    pub fn contains(&self, depth: f64) -> bool {
        depth >= self.near && depth < self.far
    }

    /// `near-far` with `inf` for infinity, as on the command line.
    pub fn label(&self) -> String {
        if self.far.is_finite() {
            format!("{}-{}", self.near, self.far)
        } else {
            format!("{}-inf", self.near)
        }
    }

    /// Parse `0-1000,1000-10000,10000-inf`: ranges must be valid, sorted and not overlap.
    pub fn parse_list(text: &str) -> Result<Vec<SlabRange>, String> {
        let mut out: Vec<SlabRange> = Vec::new();
        for (i, part) in text.split(',').enumerate() {
            let part = part.trim();
            let (a, b) = part
                .split_once('-')
                .ok_or_else(|| format!("slab {i} `{part}`: expected NEAR-FAR"))?;
            let num = |s: &str| -> Result<f64, String> {
                let s = s.trim();
                if s.eq_ignore_ascii_case("inf") {
                    Ok(f64::INFINITY)
                } else {
                    s.parse::<f64>()
                        .map_err(|_| format!("slab {i} `{part}`: `{s}` is not a number"))
                }
            };
            let r = SlabRange::new(num(a)?, num(b)?).ok_or_else(|| {
                format!("slab {i} `{part}`: needs 0 <= near < far (far may be inf)")
            })?;
            if let Some(prev) = out.last() {
                if r.near < prev.far {
                    return Err(format!(
                        "slab {i} `{part}` overlaps or precedes the previous slab {}",
                        prev.label()
                    ));
                }
            }
            out.push(r);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_paper_example() {
        let s = SlabRange::parse_list("0-1000,1000-10000,10000-inf").unwrap();
        assert_eq!(s.len(), 3);
        assert_eq!(s[2].far, f64::INFINITY);
        assert!(s[1].contains(1000.0) && !s[1].contains(10000.0));
        assert_eq!(s[2].label(), "10000-inf");
    }

    #[test]
    fn parse_errors_name_the_slab() {
        assert!(SlabRange::parse_list("0-10,5-20")
            .unwrap_err()
            .contains("slab 1"));
        assert!(SlabRange::parse_list("10-5")
            .unwrap_err()
            .contains("slab 0"));
        assert!(SlabRange::parse_list("a-5").unwrap_err().contains("`a`"));
        assert!(SlabRange::parse_list("nan-5").is_err());
    }

    #[test]
    fn json_uses_null_for_infinity() {
        let r = SlabRange::new(2.0, f64::INFINITY).unwrap();
        let j = serde_json::to_string(&r).unwrap();
        assert_eq!(j, r#"{"near":2.0,"far":null}"#);
        let back: SlabRange = serde_json::from_str(&j).unwrap();
        assert_eq!(back, r);
    }
}
