//! Networks of tracks that meet at junctions: the graph a walker follows through a scene.
//!
//! Tracks join where they share a point: a control point of one track that lies within
//! [`JOIN_TOLERANCE_M`] (1 mm) of another track's curve — its end, or anywhere along it — is a
//! junction of the two. A junction is one reference viewpoint that every track through it
//! uses, so it is rendered once. Each track's viewpoints are spread evenly between its ends and
//! its junctions (its `spacing`, or its `count` shared out by length), so a track without
//! junctions is sampled exactly as it is alone. A track whose last point is its first is a
//! loop: both ends are the same viewpoint.
//!
//! What looks like a junction but is not one is refused, naming the file, the line and the
//! distance: a control point within [`NEAR_MISS_M`] of another track that is not on it, and
//! two tracks that pass within [`NEAR_MISS_M`] of each other (or cross) farther than
//! [`JUNCTION_CLEARANCE_M`] from every point they share.
//!
//! Viewpoints get global ids: track by track in file order, each track's stops in order of arc
//! length, a junction at its first appearance. A network of one track numbers its viewpoints
//! as [`crate::Track::viewpoints`] does.
//!
//! ```
//! use tracks::{network::Network, TrackSet};
//! let set = TrackSet::parse(r#"
//!     [[track]]
//!     name = "east-west"
//!     points = [[-10, 1.7, 0], [10, 1.7, 0]]
//!     spacing = 2.5
//!     [[track]]
//!     name = "north"
//!     points = [[0, 1.7, 0], [0, 1.7, -10], [0, 1.7, -20]]
//!     spacing = 2.5
//! "#, "streets.toml").unwrap();
//! let net = Network::new(set.tracks).unwrap();
//! // `north` starts on `east-west`: one junction, three branches.
//! assert_eq!(net.junctions.len(), 1);
//! let j = &net.junctions[0];
//! assert_eq!(net.viewpoints[j.viewpoint], glam::DVec3::new(0.0, 1.7, 0.0));
//! assert_eq!(j.branches.len(), 3);
//! assert_eq!(net.viewpoints.len(), 9 + 8);
//! ```

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::limits::MAX_VIEWPOINTS;
use crate::track::{Sampling, Track, TrackError};

/// Two tracks share a point where a control point of one lies this close to the other's curve.
pub const JOIN_TOLERANCE_M: f64 = 1e-3;
/// Tracks that come this close without sharing a point are refused (a junction missed by a
/// typo, or a crossing with no shared point).
pub const NEAR_MISS_M: f64 = 0.25;
/// Near a shared point tracks may run close together (a branch leaving at a shallow angle):
/// the near-miss rule applies only this far from every junction.
pub const JUNCTION_CLEARANCE_M: f64 = 2.0;

/// A reference viewpoint on a track: its global id and its arc length along the track.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stop {
    pub viewpoint: usize,
    pub s: f64,
}

/// The part of a track between two consecutive stops.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    pub track: usize,
    /// Position among the track's segments (segment `k` joins stops `k` and `k + 1`).
    pub index: usize,
    /// Global viewpoint ids of its ends, in track order.
    pub from: usize,
    pub to: usize,
    /// Arc lengths of its ends along the track.
    pub s0: f64,
    pub s1: f64,
}

/// One way out of a junction: a segment that starts there, and which way along its track.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Branch {
    pub track: usize,
    /// Position of the junction among the track's stops.
    pub stop: usize,
    /// True when the branch leaves towards larger arc lengths.
    pub forward: bool,
    /// Global id of the segment it leaves along.
    pub segment: usize,
}

/// A viewpoint that several tracks share (or both ends of a loop).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Junction {
    pub viewpoint: usize,
    /// Every segment that touches it, each with its direction away from it.
    pub branches: Vec<Branch>,
}

/// Tracks, their viewpoints and the segments and junctions between them.
#[derive(Clone, Debug)]
pub struct Network {
    pub tracks: Vec<Track>,
    /// Position of every reference viewpoint, by global id.
    pub viewpoints: Vec<DVec3>,
    /// Per track, its stops in order of arc length.
    pub stops: Vec<Vec<Stop>>,
    /// Every segment, track by track.
    pub segments: Vec<Segment>,
    /// In order of viewpoint id (read it; [`Network::junction_at`] looks it up by an index
    /// made with it).
    pub junctions: Vec<Junction>,
    /// Per viewpoint, the segments that touch it.
    incident: Vec<Vec<usize>>,
    /// Per track, the id of its first segment.
    first_segment: Vec<usize>,
    /// Per viewpoint, its index in `junctions` if it is one.
    junction_of: Vec<Option<usize>>,
}

/// A point two or more tracks share: where it is and at which arc length of each track.
#[derive(Clone, Debug)]
struct Shared {
    position: DVec3,
    at: Vec<(usize, f64)>,
}

impl Network {
    /// The network of `tracks` (see the module docs). Errors name the file, line and
    /// distance of a near miss, and the two tracks.
    pub fn new(tracks: Vec<Track>) -> Result<Network, TrackError> {
        let shared = shared_points(&tracks)?;
        check_near_misses(&tracks, &shared)?;
        let mut viewpoints: Vec<DVec3> = Vec::new();
        // Global id of each shared point, once it has one.
        let mut shared_id: Vec<Option<usize>> = vec![None; shared.len()];
        let mut stops = Vec::with_capacity(tracks.len());
        for (ti, t) in tracks.iter().enumerate() {
            // Arc lengths where the track must have a viewpoint, with the shared point there.
            let mut fixed: Vec<(f64, Option<usize>)> = vec![(0.0, None), (t.length(), None)];
            for (k, sh) in shared.iter().enumerate() {
                for &(tt, s) in &sh.at {
                    if tt == ti {
                        fixed.push((s, Some(k)));
                    }
                }
            }
            fixed.sort_by(|a, b| a.0.total_cmp(&b.0));
            // Stops within the join tolerance of each other are one stop; a shared point wins.
            let mut merged: Vec<(f64, Option<usize>)> = Vec::new();
            for (s, k) in fixed {
                match merged.last_mut() {
                    Some(last) if s - last.0 <= JOIN_TOLERANCE_M => {
                        if last.1.is_none() {
                            *last = (if k.is_some() { s } else { last.0 }, k);
                        }
                    }
                    _ => merged.push((s, k)),
                }
            }
            // The ends stay at 0 and at the length.
            if let Some(first) = merged.first_mut() {
                first.0 = 0.0;
            }
            if merged.len() > 1 {
                if let Some(last) = merged.last_mut() {
                    last.0 = t.length();
                }
            }
            let arcs = sample_pieces(t, &merged.iter().map(|m| m.0).collect::<Vec<_>>())?;
            let mut track_stops = Vec::with_capacity(arcs.len());
            for s in arcs {
                let at_shared = merged
                    .iter()
                    .find(|m| m.0 == s)
                    .and_then(|m| m.1)
                    .map(|k| (k, shared[k].position));
                let viewpoint = match at_shared {
                    Some((k, _)) if shared_id[k].is_some() => shared_id[k].unwrap_or(0),
                    Some((k, p)) => {
                        viewpoints.push(p);
                        shared_id[k] = Some(viewpoints.len() - 1);
                        viewpoints.len() - 1
                    }
                    None => {
                        viewpoints.push(t.position_at(s));
                        viewpoints.len() - 1
                    }
                };
                track_stops.push(Stop { viewpoint, s });
            }
            stops.push(track_stops);
            if viewpoints.len() > MAX_VIEWPOINTS {
                return Err(TrackError::Invalid {
                    source_name: t.origin().source_name.clone(),
                    line: t.origin().line,
                    track: t.name.clone(),
                    field: "spacing",
                    message: format!(
                        "the network has {} viewpoints by this track; at most {MAX_VIEWPOINTS}",
                        viewpoints.len()
                    ),
                });
            }
        }
        Ok(Network::from_stops(tracks, viewpoints, stops))
    }

    /// The network of tracks whose viewpoints are already placed: `viewpoints` by global id,
    /// and per track its stops (ids and arc lengths, non-decreasing). The stops are checked
    /// (ids in range, arc lengths finite, not decreasing, within the track); the message names
    /// the first that is not.
    pub fn from_parts(
        tracks: Vec<Track>,
        viewpoints: Vec<DVec3>,
        stops: Vec<Vec<Stop>>,
    ) -> Result<Network, String> {
        if stops.len() != tracks.len() {
            return Err(format!(
                "{} tracks but stops for {}",
                tracks.len(),
                stops.len()
            ));
        }
        for (t, st) in tracks.iter().zip(&stops) {
            if st.is_empty() {
                return Err(format!("track `{}`: no stops", t.name));
            }
            let mut last = f64::NEG_INFINITY;
            for (k, x) in st.iter().enumerate() {
                if x.viewpoint >= viewpoints.len() {
                    return Err(format!(
                        "track `{}` stop {k}: viewpoint {} of {}",
                        t.name,
                        x.viewpoint,
                        viewpoints.len()
                    ));
                }
                let len = t.length();
                if !(x.s.is_finite()
                    && x.s >= last
                    && x.s >= 0.0
                    && x.s <= len * (1.0 + 1e-9) + 1e-6)
                {
                    return Err(format!(
                        "track `{}` stop {k}: arc length {} is not in order within 0..{len}",
                        t.name, x.s
                    ));
                }
                last = x.s;
            }
        }
        if let Some(p) = viewpoints.iter().find(|p| !p.is_finite()) {
            return Err(format!("viewpoint at {p} is not a finite position"));
        }
        Ok(Network::from_stops(tracks, viewpoints, stops))
    }

    /// A network of one track `name`: straight pieces through `positions` (at least two,
    /// consecutive ones distinct), a viewpoint at each.
    pub fn polyline(name: &str, positions: &[DVec3]) -> Result<Network, TrackError> {
        let track = Track::new(
            name,
            positions.to_vec(),
            crate::track::Smoothing::None,
            Sampling::Count(positions.len()),
            "viewpoints",
        )?;
        let stops = positions
            .iter()
            .enumerate()
            .map(|(i, _)| Stop {
                viewpoint: i,
                s: track.point_arc(i),
            })
            .collect();
        Ok(Network::from_stops(
            vec![track],
            positions.to_vec(),
            vec![stops],
        ))
    }

    fn from_stops(tracks: Vec<Track>, viewpoints: Vec<DVec3>, stops: Vec<Vec<Stop>>) -> Network {
        let mut segments = Vec::new();
        let mut first_segment = Vec::with_capacity(tracks.len());
        for (ti, st) in stops.iter().enumerate() {
            first_segment.push(segments.len());
            for (k, w) in st.windows(2).enumerate() {
                segments.push(Segment {
                    track: ti,
                    index: k,
                    from: w[0].viewpoint,
                    to: w[1].viewpoint,
                    s0: w[0].s,
                    s1: w[1].s,
                });
            }
        }
        let mut incident = vec![Vec::new(); viewpoints.len()];
        for (id, sg) in segments.iter().enumerate() {
            incident[sg.from].push(id);
            if sg.to != sg.from {
                incident[sg.to].push(id);
            }
        }
        // A junction: a viewpoint more than one track stops at, or one a track stops at twice.
        // Every stop's (track, position) listed under its viewpoint, tracks and stops in order.
        let mut visits_of: Vec<Vec<(usize, usize)>> = vec![Vec::new(); viewpoints.len()];
        for (ti, st) in stops.iter().enumerate() {
            for (k, x) in st.iter().enumerate() {
                if let Some(v) = visits_of.get_mut(x.viewpoint) {
                    v.push((ti, k));
                }
            }
        }
        let mut junctions = Vec::new();
        let mut junction_of = vec![None; viewpoints.len()];
        for (v, visits) in visits_of.iter().enumerate() {
            if visits.len() < 2 {
                continue;
            }
            let mut branches = Vec::new();
            for &(ti, k) in visits {
                let first = first_segment[ti];
                if k > 0 {
                    branches.push(Branch {
                        track: ti,
                        stop: k,
                        forward: false,
                        segment: first + k - 1,
                    });
                }
                if k + 1 < stops[ti].len() {
                    branches.push(Branch {
                        track: ti,
                        stop: k,
                        forward: true,
                        segment: first + k,
                    });
                }
            }
            junction_of[v] = Some(junctions.len());
            junctions.push(Junction {
                viewpoint: v,
                branches,
            });
        }
        Network {
            tracks,
            viewpoints,
            stops,
            segments,
            junctions,
            incident,
            first_segment,
            junction_of,
        }
    }

    /// Index of the track named `name`.
    pub fn track_index(&self, name: &str) -> Option<usize> {
        self.tracks.iter().position(|t| t.name == name)
    }

    /// The segments of track `t`, in order.
    pub fn track_segments(&self, t: usize) -> &[Segment] {
        let a = self.first_segment.get(t).copied().unwrap_or(0);
        let b = self
            .first_segment
            .get(t + 1)
            .copied()
            .unwrap_or(self.segments.len());
        &self.segments[a.min(b)..b]
    }

    /// Global id of segment `k` of track `t`.
    pub fn segment_id(&self, t: usize, k: usize) -> Option<usize> {
        (k < self.track_segments(t).len()).then(|| self.first_segment[t] + k)
    }

    /// The segments that touch viewpoint `v`.
    pub fn incident(&self, v: usize) -> &[usize] {
        self.incident.get(v).map_or(&[], |x| x.as_slice())
    }

    /// The junction at viewpoint `v`, if it is one.
    pub fn junction_at(&self, v: usize) -> Option<&Junction> {
        let k = self.junction_of.get(v).copied().flatten()?;
        self.junctions.get(k).filter(|j| j.viewpoint == v)
    }

    /// The neighbours of viewpoint `v` along the network's segments.
    pub fn neighbours(&self, v: usize) -> Vec<usize> {
        let mut out: Vec<usize> = self
            .incident(v)
            .iter()
            .map(|&e| {
                let sg = &self.segments[e];
                if sg.from == v {
                    sg.to
                } else {
                    sg.from
                }
            })
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The curve of segment `e` as a polyline from its `from` viewpoint to its `to`
    /// viewpoint, both included (the track's curve vertices between them in order).
    pub fn segment_path(&self, e: usize) -> Vec<DVec3> {
        let sg = &self.segments[e];
        let t = &self.tracks[sg.track];
        let mut out = vec![self.viewpoints[sg.from]];
        out.extend(
            t.curve()
                .iter()
                .zip(t.curve_arcs())
                .filter(|(_, &s)| s > sg.s0 && s < sg.s1)
                .map(|(p, _)| *p),
        );
        out.push(self.viewpoints[sg.to]);
        out
    }

    /// The paths of viewpoint `v`'s cell: per segment that touches it, the polyline from `v`
    /// along the segment to the viewpoint at its other end, without `v` itself (the form of
    /// the culling's cell).
    pub fn cell_paths(&self, v: usize) -> Vec<Vec<DVec3>> {
        let mut out = Vec::new();
        for &e in self.incident(v) {
            let sg = &self.segments[e];
            let mut path = self.segment_path(e);
            if sg.from == v {
                path.remove(0);
                out.push(path.clone());
            }
            if sg.to == v {
                let mut back = self.segment_path(e);
                back.reverse();
                back.remove(0);
                out.push(back);
            }
        }
        out
    }

    /// Arc lengths of track `t`'s stops.
    pub fn stop_arcs(&self, t: usize) -> Vec<f64> {
        self.stops
            .get(t)
            .map(|st| st.iter().map(|x| x.s).collect())
            .unwrap_or_default()
    }

    /// The two viewpoints around arc length `s` of track `t` and the blend weight of the
    /// second ([`crate::segment::blend_pair`] in global ids).
    pub fn blend_pair(&self, t: usize, s: f64) -> Option<(usize, usize, f64)> {
        let st = self.stops.get(t)?;
        let arcs: Vec<f64> = st.iter().map(|x| x.s).collect();
        let (a, b, w) = crate::segment::blend_pair(&arcs, s)?;
        Some((st[a].viewpoint, st[b].viewpoint, w))
    }

    /// The blend weights at arc length `s` of track `t` ([`crate::segment::blend_weights`] in
    /// global ids).
    pub fn blend_weights(&self, t: usize, s: f64) -> Vec<(usize, f64)> {
        let Some(st) = self.stops.get(t) else {
            return Vec::new();
        };
        let arcs: Vec<f64> = st.iter().map(|x| x.s).collect();
        crate::segment::blend_weights(&arcs, s)
            .into_iter()
            .map(|(k, w)| (st[k].viewpoint, w))
            .collect()
    }

    /// Global id of the segment of track `t` that holds arc length `s`.
    pub fn segment_at(&self, t: usize, s: f64) -> Option<usize> {
        let k = crate::segment::segment_at(&self.stop_arcs(t), s)?;
        self.segment_id(t, k)
    }

    /// Where viewpoint `v` lies on track `t` (its arc lengths there; two for a loop's ends).
    pub fn arcs_of(&self, t: usize, v: usize) -> Vec<f64> {
        self.stops
            .get(t)
            .map(|st| {
                st.iter()
                    .filter(|x| x.viewpoint == v)
                    .map(|x| x.s)
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Distance along the network from the nearest of `sources` (viewpoint id and its
    /// distance) to every viewpoint: shortest paths over the segments, each as long as its
    /// arc length; `INFINITY` where none reaches.
    pub fn distances_from(&self, sources: &[(usize, f64)]) -> Vec<f64> {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let mut dist = vec![f64::INFINITY; self.viewpoints.len()];
        // Ordered by distance through its bits (distances are finite and non-negative).
        let mut heap: BinaryHeap<Reverse<(u64, usize)>> = BinaryHeap::new();
        for &(v, d) in sources {
            if v < dist.len() && d.is_finite() && d >= 0.0 && d < dist[v] {
                dist[v] = d;
                heap.push(Reverse((d.to_bits(), v)));
            }
        }
        while let Some(Reverse((bits, v))) = heap.pop() {
            let d = f64::from_bits(bits);
            if d > dist[v] {
                continue;
            }
            for &e in self.incident(v) {
                let sg = &self.segments[e];
                let w = if sg.from == v { sg.to } else { sg.from };
                let nd = d + (sg.s1 - sg.s0).abs();
                if nd < dist[w] {
                    dist[w] = nd;
                    heap.push(Reverse((nd.to_bits(), w)));
                }
            }
        }
        dist
    }

    /// Distance along the network from arc length `s` of track `t` to every viewpoint.
    pub fn distances_from_position(&self, t: usize, s: f64) -> Vec<f64> {
        let Some(st) = self.stops.get(t) else {
            return vec![f64::INFINITY; self.viewpoints.len()];
        };
        let arcs: Vec<f64> = st.iter().map(|x| x.s).collect();
        match crate::segment::locate(&arcs, s) {
            Some(p) => {
                let (a, b) = (&st[p.index], &st[p.index + 1]);
                let s = s.clamp(a.s, b.s);
                self.distances_from(&[(a.viewpoint, s - a.s), (b.viewpoint, b.s - s)])
            }
            None => self.distances_from(&[(st[0].viewpoint, 0.0)]),
        }
    }

    /// The direction (unit, in the world) a walker leaving along `branch` starts in.
    pub fn branch_heading(&self, branch: &Branch) -> DVec3 {
        let path = self.segment_path(branch.segment);
        let (a, b) = if branch.forward {
            (path[0], path[1])
        } else {
            (path[path.len() - 1], path[path.len() - 2])
        };
        (b - a).normalize_or_zero()
    }
}

/// The arc lengths of a track's viewpoints: every fixed arc length (its ends and junctions,
/// sorted, distinct) and, between each two, viewpoints spread evenly by the track's sampling.
fn sample_pieces(t: &Track, fixed: &[f64]) -> Result<Vec<f64>, TrackError> {
    let len = t.length();
    let invalid = |field: &'static str, message: String| TrackError::Invalid {
        source_name: t.origin().source_name.clone(),
        line: t.origin().line,
        track: t.name.clone(),
        field,
        message,
    };
    if fixed.len() <= 2 {
        return Ok(t.sample_arcs());
    }
    let pieces: Vec<(f64, f64)> = fixed.windows(2).map(|w| (w[0], w[1])).collect();
    let counts: Vec<usize> = match t.sampling {
        Sampling::Spacing(d) => pieces
            .iter()
            .map(|(a, b)| ((b - a) / d - 1e-9).ceil().max(1.0) as usize)
            .collect(),
        Sampling::Count(c) => {
            let total = c.saturating_sub(1);
            if total < pieces.len() {
                return Err(invalid(
                    "count",
                    format!(
                        "{c} viewpoints cannot hold its {} junctions and ends ({} needed); give \
                         a larger count or a spacing",
                        fixed.len() - 2,
                        fixed.len()
                    ),
                ));
            }
            // One piece each, the rest shared by length (largest remainder).
            let spare = (total - pieces.len()) as f64;
            let shares: Vec<f64> = pieces.iter().map(|(a, b)| spare * (b - a) / len).collect();
            let mut n: Vec<usize> = shares.iter().map(|x| 1 + x.floor() as usize).collect();
            let mut left = total - n.iter().sum::<usize>();
            let mut order: Vec<usize> = (0..pieces.len()).collect();
            order.sort_by(|&i, &j| {
                let (ri, rj) = (shares[i].fract(), shares[j].fract());
                rj.total_cmp(&ri).then(i.cmp(&j))
            });
            for &i in order.iter().cycle().take(pieces.len() * 2) {
                if left == 0 {
                    break;
                }
                n[i] += 1;
                left -= 1;
            }
            n
        }
    };
    let mut out = vec![fixed[0]];
    for (&(a, b), &n) in pieces.iter().zip(&counts) {
        for i in 1..=n {
            out.push(if i == n {
                b
            } else {
                a + (b - a) * i as f64 / n as f64
            });
        }
    }
    Ok(out)
}

mod joins;
#[cfg(test)]
use joins::closest_between_segments;
use joins::{check_near_misses, shared_points};

#[cfg(test)]
mod tests;
