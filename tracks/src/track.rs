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

use crate::limits::{MAX_COORDINATE_M, MAX_TRACKS, MAX_TRACK_POINTS, MAX_VIEWPOINTS};

/// Subdivisions per polyline segment when a track is smoothed.
const SMOOTH_SUBDIVISIONS: usize = 32;

/// Errors in a track description. Each names the source, the field and, for TOML syntax, the
/// line.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum TrackError {
    /// `line` is 1-based; 0 when the TOML parser gave no position.
    #[error("{}: {message}", at(source_name, *line))]
    Syntax {
        source_name: String,
        line: usize,
        message: String,
    },
    /// `line` is the line of the track's `[[track]]` table; 0 for a track built in code.
    #[error("{}: track `{track}`: field `{field}`: {message}", at(source_name, *line))]
    Invalid {
        source_name: String,
        line: usize,
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

/// `source:line`, or the source alone when the line is not known (0).
fn at(source_name: &str, line: usize) -> String {
    if line > 0 {
        format!("{source_name}:{line}")
    } else {
        source_name.to_string()
    }
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
#[derive(Clone, Debug, Serialize, Deserialize)]
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
    /// Where the track was read (for messages that name the file and line); not part of what
    /// the track is.
    #[serde(skip)]
    origin: Origin,
}

/// Where a track was read: the source's name and the line of its `[[track]]` table (0 for a
/// track built in code).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Origin {
    pub source_name: String,
    pub line: usize,
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&at(&self.source_name, self.line))
    }
}

impl PartialEq for Track {
    /// Two tracks are equal when their names, points, smoothing and sampling are; where they
    /// were read does not matter.
    fn eq(&self, o: &Track) -> bool {
        self.name == o.name
            && self.points == o.points
            && self.smooth == o.smooth
            && self.sampling == o.sampling
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrackFile {
    #[serde(default)]
    track: Vec<toml::Spanned<TrackToml>>,
}

/// The `[[track]]` tables of a file that holds other tables too (a scene file).
#[derive(Deserialize)]
struct TracksIn {
    #[serde(default)]
    track: Vec<toml::Spanned<TrackToml>>,
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
        Track::new_at(name, points, smooth, sampling, source_name, 0)
    }

    /// [`Track::new`] for a track whose `[[track]]` table starts at `line` of the source.
    fn new_at(
        name: &str,
        points: Vec<DVec3>,
        smooth: Smoothing,
        sampling: Sampling,
        source_name: &str,
        line: usize,
    ) -> Result<Track, TrackError> {
        let invalid = |field: &'static str, message: String| TrackError::Invalid {
            source_name: source_name.to_string(),
            line,
            track: name.to_string(),
            field,
            message,
        };
        if points.len() > MAX_TRACK_POINTS {
            return Err(invalid(
                "points",
                format!(
                    "{} points; at most {MAX_TRACK_POINTS} are read",
                    points.len()
                ),
            ));
        }
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
            if !p.is_finite() || p.abs().max_element() > MAX_COORDINATE_M {
                return Err(invalid(
                    "points",
                    format!(
                        "point {i} is {p}: coordinates must be finite and within ±{MAX_COORDINATE_M} m"
                    ),
                ));
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
            Sampling::Count(n) if n == 0 || n > MAX_VIEWPOINTS => {
                return Err(invalid(
                    "count",
                    format!("{n} viewpoints; it must be from 1 to {MAX_VIEWPOINTS}"),
                ));
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
        if let Sampling::Spacing(d) = sampling {
            let count = viewpoint_count(s, d);
            if count > MAX_VIEWPOINTS as f64 {
                return Err(invalid(
                    "spacing",
                    format!(
                        "{d} m on a track of {s:.3} m gives {count:.3e} viewpoints; at most \
                         {MAX_VIEWPOINTS} (a spacing of at least {:.3e} m)",
                        s / (MAX_VIEWPOINTS - 1) as f64
                    ),
                ));
            }
        }
        Ok(Track {
            name: name.to_string(),
            points,
            smooth,
            sampling,
            curve,
            arc,
            origin: Origin {
                source_name: source_name.to_string(),
                line,
            },
        })
    }

    /// Where the track was read.
    pub fn origin(&self) -> &Origin {
        &self.origin
    }

    /// Cumulative arc length at each vertex of [`Track::curve`].
    pub fn curve_arcs(&self) -> &[f64] {
        &self.arc
    }

    /// Arc length of control point `i` along the curve (control points lie on the curve:
    /// vertex `i` unsmoothed, vertex `i × 32` when smoothed).
    pub fn point_arc(&self, i: usize) -> f64 {
        let v = match self.smooth {
            Smoothing::None => i,
            Smoothing::CatmullRom => i * SMOOTH_SUBDIVISIONS,
        };
        self.arc.get(v).copied().unwrap_or_else(|| self.length())
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
            Sampling::Spacing(d) => viewpoint_count(len, d) as usize,
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

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn syntax(text: &str, source_name: &str, e: &toml::de::Error) -> TrackError {
    TrackError::Syntax {
        source_name: source_name.to_string(),
        line: e.span().map_or(0, |r| line_of(text, r.start)),
        message: e.message().to_string(),
    }
}

/// Viewpoints that `spacing` puts on a track of `len` metres (both ends included), as a
/// float so that absurd spacings can be compared with the limit before anything is sized.
pub(crate) fn viewpoint_count(len: f64, spacing: f64) -> f64 {
    (len / spacing - 1e-9).ceil().max(1.0) + 1.0
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
        let file: TrackFile = toml::from_str(text).map_err(|e| syntax(text, source_name, &e))?;
        TrackSet::from_tables(text, source_name, file.track)
    }

    /// The `[[track]]` tables of a TOML file that also holds other tables (a scene file):
    /// `None` when it has none. Errors name the lines of the whole file.
    pub fn parse_within(text: &str, source_name: &str) -> Result<Option<TrackSet>, TrackError> {
        let file: TracksIn = toml::from_str(text).map_err(|e| syntax(text, source_name, &e))?;
        if file.track.is_empty() {
            return Ok(None);
        }
        TrackSet::from_tables(text, source_name, file.track).map(Some)
    }

    fn from_tables(
        text: &str,
        source_name: &str,
        tables: Vec<toml::Spanned<TrackToml>>,
    ) -> Result<TrackSet, TrackError> {
        let file = TracksIn { track: tables };
        let line_of = |offset: usize| line_of(text, offset);
        if file.track.is_empty() {
            return Err(TrackError::File {
                source_name: source_name.to_string(),
                message: "no [[track]] tables: a track file needs at least one track".into(),
            });
        }
        if file.track.len() > MAX_TRACKS {
            return Err(TrackError::File {
                source_name: source_name.to_string(),
                message: format!("{} tracks; at most {MAX_TRACKS} are read", file.track.len()),
            });
        }
        let mut tracks: Vec<Track> = Vec::new();
        for spanned in file.track {
            let line = line_of(spanned.span().start);
            let t = spanned.into_inner();
            if t.name == "all" {
                return Err(TrackError::Invalid {
                    source_name: source_name.to_string(),
                    line,
                    track: t.name,
                    field: "name",
                    message: "`all` names every track of a file (a network); give the track \
                              another name"
                        .into(),
                });
            }
            if tracks.iter().any(|o| o.name == t.name) {
                return Err(TrackError::Invalid {
                    source_name: source_name.to_string(),
                    line,
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
                        line,
                        track: t.name,
                        field: "spacing",
                        message: "give either `spacing` (metres) or `count`".into(),
                    })
                }
                (Some(_), Some(_)) => {
                    return Err(TrackError::Invalid {
                        source_name: source_name.to_string(),
                        line,
                        track: t.name,
                        field: "count",
                        message: "give either `spacing` or `count`, not both".into(),
                    })
                }
            };
            let points = t.points.iter().map(|p| DVec3::from_array(*p)).collect();
            tracks.push(Track::new_at(
                &t.name,
                points,
                t.smooth,
                sampling,
                source_name,
                line,
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
            // Absurd numbers are refused before anything is sized by them.
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[72,0,0]]\nspacing=1e-9",
                "spacing",
            ),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\ncount=100001",
                "count",
            ),
            (
                "[[track]]\nname='a'\npoints=[[0,0,0],[1e300,0,0]]\ncount=2",
                "points",
            ),
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
    fn errors_name_the_line_of_their_track() {
        let text = "[[track]]\nname='a'\npoints=[[0,0,0],[1,0,0]]\ncount=2\n\n[[track]]\nname='b'\npoints=[[0,0,0],[72,0,0]]\nspacing=1e-9\n";
        let err = TrackSet::parse(text, "f.toml").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with("f.toml:6: track `b`: field `spacing`"),
            "{msg}"
        );
        assert!(msg.contains("100000"), "{msg}");
        // Built in code: no line to name, and no `:0`.
        let err = Track::new(
            "c",
            vec![DVec3::ZERO, DVec3::X],
            Smoothing::None,
            Sampling::Count(0),
            "code",
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("code: track `c`"), "{err}");
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
