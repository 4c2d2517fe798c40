//! Tracks: named 3D polylines along which reference viewpoints are sampled.
//!
//! TOML form (one file may hold several tracks):
//!
//! ```toml
//! [[track]]
//! name = "main"
//! points = [[0, 1.7, 0], [20, 1.7, 0], [20, 1.7, -15]]
//! smooth = "catmull-rom"   # or "none" (default)
//! spacing = 2.0            # metres between reference viewpoints, or:
//! # count = 12             # number of reference viewpoints
//! ```
//!
//! Viewpoints are spread evenly by arc length and always include both ends (with `count = 1`,
//! the single viewpoint is the first point). Consecutive viewpoints bound a segment.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Subdivisions per polyline segment when a track is smoothed.
const SMOOTH_SUBDIVISIONS: usize = 32;

/// Errors in a track description. Each names the source, the field and, for TOML syntax, the
/// line.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum TrackError {
    #[error("{source_name}:{line}: {message}")]
    Syntax {
        source_name: String,
        line: usize,
        message: String,
    },
    #[error("{source_name}: track `{track}`: field `{field}`: {message}")]
    Invalid {
        source_name: String,
        track: String,
        field: &'static str,
        message: String,
    },
    #[error("{source_name}: {message}")]
    File {
        source_name: String,
        message: String,
    },
}

/// How a track's control points become a curve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Smoothing {
    /// Straight segments between the points.
    #[default]
    None,
    /// Centripetal Catmull-Rom through the points (no cusps or self-intersections within a
    /// segment).
    CatmullRom,
}

/// How reference viewpoints are placed along a track.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sampling {
    /// At most this many metres apart, evenly spread.
    Spacing(f64),
    /// Exactly this many viewpoints, evenly spread.
    Count(usize),
}

/// A reference viewpoint: where one panorama is rendered.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceViewpoint {
    /// Index along the track, 0-based.
    pub index: usize,
    /// Arc length from the start of the track, metres.
    pub s: f64,
    /// World position, metres.
    pub position: DVec3,
}

/// A named track: the curve (as a dense polyline) and its sampling.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Track {
    pub name: String,
    /// Control points as given.
    pub points: Vec<DVec3>,
    pub smooth: Smoothing,
    pub sampling: Sampling,
    /// The curve as a polyline (equals `points` when not smoothed).
    curve: Vec<DVec3>,
    /// Cumulative arc length at each curve vertex.
    arc: Vec<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrackFile {
    #[serde(default)]
    track: Vec<TrackToml>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrackToml {
    name: String,
    points: Vec<[f64; 3]>,
    #[serde(default)]
    smooth: Smoothing,
    spacing: Option<f64>,
    count: Option<usize>,
}

impl Track {
    /// Build and validate a track. `source_name` only labels errors.
    pub fn new(
        name: &str,
        points: Vec<DVec3>,
        smooth: Smoothing,
        sampling: Sampling,
        source_name: &str,
    ) -> Result<Track, TrackError> {
        let invalid = |field: &'static str, message: String| TrackError::Invalid {
            source_name: source_name.to_string(),
            track: name.to_string(),
            field,
            message,
        };
        if name.trim().is_empty() {
            return Err(invalid("name", "must not be empty".into()));
        }
        if points.len() < 2 {
            return Err(invalid(
                "points",
                format!("needs at least 2 points, found {}", points.len()),
            ));
        }
        for (i, p) in points.iter().enumerate() {
            if !p.is_finite() {
                return Err(invalid("points", format!("point {i} is not finite: {p}")));
            }
        }
        for (i, w) in points.windows(2).enumerate() {
            if w[0] == w[1] {
                return Err(invalid(
                    "points",
                    format!("points {i} and {} are the same point {}", i + 1, w[0]),
                ));
            }
        }
        match sampling {
            Sampling::Spacing(s) if !(s.is_finite() && s > 0.0) => {
                return Err(invalid(
                    "spacing",
                    format!("must be a positive number of metres, found {s}"),
                ));
            }
            Sampling::Count(0) => {
                return Err(invalid("count", "must be at least 1".into()));
            }
            _ => {}
        }
        let curve = match smooth {
            Smoothing::None => points.clone(),
            Smoothing::CatmullRom => catmull_rom(&points),
        };
        let arc = crate::segment::arc_lengths(&curve);
        let s = arc.last().copied().unwrap_or(0.0);
        if !(s > 0.0 && s.is_finite()) {
            return Err(invalid("points", format!("track length is {s} m")));
        }
        Ok(Track {
            name: name.to_string(),
            points,
            smooth,
            sampling,
            curve,
            arc,
        })
    }

    /// Total arc length, metres.
    pub fn length(&self) -> f64 {
        *self.arc.last().unwrap_or(&0.0)
    }

    /// The curve as a polyline.
    pub fn curve(&self) -> &[DVec3] {
        &self.curve
    }

    /// Position at arc length `s` (clamped to the track; [`crate::segment::point_at`]).
    pub fn position_at(&self, s: f64) -> DVec3 {
        crate::segment::point_at(&self.curve, &self.arc, s)
    }

    /// Unit tangent at arc length `s` (direction of travel).
    pub fn tangent_at(&self, s: f64) -> DVec3 {
        let h = (self.length() * 1e-4).max(1e-9);
        let a = self.position_at(s - h);
        let b = self.position_at(s + h);
        (b - a).normalize_or_zero()
    }

    /// Arc lengths of the reference viewpoints.
    pub fn sample_arcs(&self) -> Vec<f64> {
        let len = self.length();
        let count = match self.sampling {
            Sampling::Count(n) => n,
            Sampling::Spacing(d) => (len / d - 1e-9).ceil().max(1.0) as usize + 1,
        };
        if count == 1 {
            return vec![0.0];
        }
        (0..count)
            .map(|i| {
                if i + 1 == count {
                    len
                } else {
                    len * i as f64 / (count - 1) as f64
                }
            })
            .collect()
    }

    /// The reference viewpoints, in order along the track.
    pub fn viewpoints(&self) -> Vec<ReferenceViewpoint> {
        self.sample_arcs()
            .into_iter()
            .enumerate()
            .map(|(index, s)| ReferenceViewpoint {
                index,
                s,
                position: self.position_at(s),
            })
            .collect()
    }
}

/// Centripetal Catmull-Rom through `p`, densified; the ends are extended by reflection.
fn catmull_rom(p: &[DVec3]) -> Vec<DVec3> {
    let n = p.len();
    let get = |i: isize| -> DVec3 {
        if i < 0 {
            2.0 * p[0] - p[1]
        } else if i as usize >= n {
            2.0 * p[n - 1] - p[n - 2]
        } else {
            p[i as usize]
        }
    };
    let mut out = vec![p[0]];
    for i in 0..n - 1 {
        let (p0, p1, p2, p3) = (
            get(i as isize - 1),
            get(i as isize),
            get(i as isize + 1),
            get(i as isize + 2),
        );
        let knot = |a: DVec3, b: DVec3, t: f64| t + a.distance(b).sqrt().max(1e-12);
        let t0 = 0.0;
        let t1 = knot(p0, p1, t0);
        let t2 = knot(p1, p2, t1);
        let t3 = knot(p2, p3, t2);
        for k in 1..=SMOOTH_SUBDIVISIONS {
            let t = t1 + (t2 - t1) * k as f64 / SMOOTH_SUBDIVISIONS as f64;
            let a1 = p0 * ((t1 - t) / (t1 - t0)) + p1 * ((t - t0) / (t1 - t0));
            let a2 = p1 * ((t2 - t) / (t2 - t1)) + p2 * ((t - t1) / (t2 - t1));
            let a3 = p2 * ((t3 - t) / (t3 - t2)) + p3 * ((t - t2) / (t3 - t2));
            let b1 = a1 * ((t2 - t) / (t2 - t0)) + a2 * ((t - t0) / (t2 - t0));
            let b2 = a2 * ((t3 - t) / (t3 - t1)) + a3 * ((t - t1) / (t3 - t1));
            let c = b1 * ((t2 - t) / (t2 - t1)) + b2 * ((t - t1) / (t2 - t1));
            out.push(if k == SMOOTH_SUBDIVISIONS { p2 } else { c });
        }
    }
    out
}

/// The tracks of one scene.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackSet {
    pub tracks: Vec<Track>,
}

impl TrackSet {
    /// Parse TOML text; `source_name` (usually the file path) labels every error.
    pub fn parse(text: &str, source_name: &str) -> Result<TrackSet, TrackError> {
        let file: TrackFile = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|r| text[..r.start.min(text.len())].lines().count().max(1))
                .unwrap_or(0);
            TrackError::Syntax {
                source_name: source_name.to_string(),
                line,
                message: e.message().to_string(),
            }
        })?;
        if file.track.is_empty() {
            return Err(TrackError::File {
                source_name: source_name.to_string(),
                message: "no [[track]] tables: a track file needs at least one track".into(),
            });
        }
        let mut tracks: Vec<Track> = Vec::new();
        for t in file.track {
            if tracks.iter().any(|o| o.name == t.name) {
                return Err(TrackError::Invalid {
                    source_name: source_name.to_string(),
                    track: t.name,
                    field: "name",
                    message: "another track has the same name".into(),
                });
            }
            let sampling = match (t.spacing, t.count) {
                (Some(s), None) => Sampling::Spacing(s),
                (None, Some(c)) => Sampling::Count(c),
                (None, None) => {
                    return Err(TrackError::Invalid {
                        source_name: source_name.to_string(),
                        track: t.name,
                        field: "spacing",
                        message: "give either `spacing` (metres) or `count`".into(),
                    })
                }
                (Some(_), Some(_)) => {
                    return Err(TrackError::Invalid {
                        source_name: source_name.to_string(),
                        track: t.name,
                        field: "count",
                        message: "give either `spacing` or `count`, not both".into(),
                    })
                }
            };
            let points = t.points.iter().map(|p| DVec3::from_array(*p)).collect();
            tracks.push(Track::new(
                &t.name,
                points,
                t.smooth,
                sampling,
                source_name,
            )?);
        }
        Ok(TrackSet { tracks })
    }

    /// Render back to TOML (round-trips through [`TrackSet::parse`]).
    pub fn to_toml(&self) -> String {
        let mut s = String::new();
        for t in &self.tracks {
            s.push_str("[[track]]\n");
            s.push_str(&format!("name = {:?}\n", t.name));
            let pts: Vec<String> = t
                .points
                .iter()
                .map(|p| format!("[{:?}, {:?}, {:?}]", p.x, p.y, p.z))
                .collect();
            s.push_str(&format!("points = [{}]\n", pts.join(", ")));
            if t.smooth == Smoothing::CatmullRom {
                s.push_str("smooth = \"catmull-rom\"\n");
            }
            match t.sampling {
                Sampling::Spacing(d) => s.push_str(&format!("spacing = {d:?}\n")),
                Sampling::Count(c) => s.push_str(&format!("count = {c}\n")),
            }
            s.push('\n');
        }
        s
    }

    pub fn get(&self, name: &str) -> Option<&Track> {
        self.tracks.iter().find(|t| t.name == name)
    }

    /// Track names, in file order.
    pub fn names(&self) -> Vec<&str> {
        self.tracks.iter().map(|t| t.name.as_str()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(points: &[[f64; 3]], sampling: Sampling) -> Track {
        let pts = points.iter().map(|p| DVec3::from_array(*p)).collect();
        Track::new("t", pts, Smoothing::None, sampling, "test").unwrap()
    }

    #[test]
    fn spacing_includes_both_ends() {
        let t = line(&[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]], Sampling::Spacing(3.0));
        let s = t.sample_arcs();
        assert_eq!(s.len(), 5);
        assert_eq!(s[0], 0.0);
        assert_eq!(*s.last().unwrap(), 10.0);
        assert!(s.windows(2).all(|w| w[1] - w[0] <= 3.0 + 1e-12));
        // Exact multiples do not add a sample.
        let t = line(&[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]], Sampling::Spacing(2.5));
        assert_eq!(t.sample_arcs().len(), 5);
    }

    #[test]
    fn count_one_is_a_single_viewpoint() {
        let t = line(&[[0.0, 1.0, 0.0], [4.0, 1.0, 0.0]], Sampling::Count(1));
        let v = t.viewpoints();
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].position, DVec3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn position_follows_polyline() {
        let t = line(
            &[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 4.0, 0.0]],
            Sampling::Count(3),
        );
        assert_eq!(t.length(), 7.0);
        assert_eq!(t.position_at(5.0), DVec3::new(3.0, 2.0, 0.0));
        assert_eq!(t.position_at(-1.0), DVec3::ZERO);
        assert_eq!(t.position_at(99.0), DVec3::new(3.0, 4.0, 0.0));
        assert!((t.tangent_at(1.0) - DVec3::X).length() < 1e-9);
    }

    #[test]
    fn catmull_rom_passes_through_points() {
        let pts = vec![
            DVec3::ZERO,
            DVec3::new(5.0, 0.0, 0.0),
            DVec3::new(5.0, 0.0, 5.0),
            DVec3::new(0.0, 0.0, 9.0),
        ];
        let t = Track::new(
            "c",
            pts.clone(),
            Smoothing::CatmullRom,
            Sampling::Count(4),
            "x",
        )
        .unwrap();
        for p in &pts {
            assert!(t.curve().iter().any(|c| c.distance(*p) < 1e-12));
        }
        assert!(t.length() > 14.0);
    }

    #[test]
    fn parse_reports_line_of_syntax_error() {
        let text = "[[track]]\nname = \"a\"\npoints = [[0,0,0], [1,0,0]\nspacing = 1\n";
        match TrackSet::parse(text, "bad.toml") {
            Err(TrackError::Syntax {
                line, source_name, ..
            }) => {
                assert_eq!(source_name, "bad.toml");
                assert!((3..=4).contains(&line), "line {line}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn parse_rejects_bad_tracks_naming_the_field() {
        let cases = [
            ("[[track]]\nname='a'\npoints=[]\nspacing=1", "points"),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[0,0,0]]\nspacing=1",
                "points",
            ),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\nspacing=-1",
                "spacing",
            ),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\nspacing=nan",
                "spacing",
            ),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\ncount=0",
                "count",
            ),
            ("[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]", "spacing"),
        ];
        for (text, field) in cases {
            match TrackSet::parse(text, "f.toml") {
                Err(TrackError::Invalid { field: f, .. }) => assert_eq!(f, field, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
        let err = TrackSet::parse(
            "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\nspeed=1\ncount=2",
            "f.toml",
        )
        .unwrap_err();
        assert!(err.to_string().contains("speed"), "{err}");
        assert!(matches!(
            TrackSet::parse("", "e.toml"),
            Err(TrackError::File { .. })
        ));
    }

    #[test]
    fn toml_round_trip() {
        let text = "[[track]]\nname = 'a'\npoints = [[0,0,0],[1,0.5,0],[2,0,1]]\nsmooth = 'catmull-rom'\ncount = 3\n\n[[track]]\nname='b'\npoints=[[0,0,0],[0,0,-4]]\nspacing=0.5\n";
        let set = TrackSet::parse(text, "rt.toml").unwrap();
        assert_eq!(set.names(), vec!["a", "b"]);
        let again = TrackSet::parse(&set.to_toml(), "rt2.toml").unwrap();
        assert_eq!(set, again);
    }
}
