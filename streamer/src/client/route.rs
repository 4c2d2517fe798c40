//! Walking a network of tracks: where a walker is ([`NetPos`]), which way out of a junction it
//! takes ([`Walker`]: the branch the user chose, else the one nearest the view direction), how
//! likely each way is for prefetching ([`branch_weights`]), and a route through named tracks
//! ([`Route`], `railview walk --route A,B,C`). The one rule for both native paths (the walk
//! simulator and the viewer) and the reference for the browser's.

use glam::DVec3;
use tracks::network::{Branch, Junction, Network};

/// A position on a network: a track and an arc length along it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NetPos {
    pub track: usize,
    pub s: f64,
}

/// A turn the walker made at a junction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turn {
    /// The junction's viewpoint.
    pub viewpoint: usize,
    pub from_track: usize,
    pub to: Branch,
}

/// How strongly the view direction and the motion pull towards a branch, and how much a
/// branch the user chose outweighs them (weights `exp(k · cos angle)`).
const VIEW_PULL: f64 = 2.0;
const MOTION_PULL: f64 = 1.0;
const CHOSEN_PULL: f64 = 3.0;

/// The ways out of `junction` for a walker arriving along segment `arrival` (all of them
/// when `None`): every branch but the one back along `arrival`.
pub fn ways_out(junction: &Junction, arrival: Option<usize>) -> Vec<Branch> {
    junction
        .branches
        .iter()
        .copied()
        .filter(|b| Some(b.segment) != arrival)
        .collect()
}

/// The branch nearest the view direction `view` (ties: the first), among `ways`.
pub fn nearest_to_view(net: &Network, ways: &[Branch], view: DVec3) -> Option<Branch> {
    let view = view.normalize_or_zero();
    ways.iter()
        .copied()
        .map(|b| (net.branch_heading(&b).dot(view), b))
        .fold(None, |best: Option<(f64, Branch)>, (d, b)| match best {
            Some((bd, _)) if bd >= d => best,
            _ => Some((d, b)),
        })
        .map(|x| x.1)
}

/// How likely each way out of a junction is, for prefetching: the view direction pulls
/// (`exp(2 cos θ_view)`), the direction of motion pulls less (`exp(cos θ_motion)`), and a
/// branch the user chose outweighs both (`× e³`). The weights sum to 1.
pub fn branch_weights(
    net: &Network,
    ways: &[Branch],
    view: DVec3,
    motion: DVec3,
    chosen: Option<&Branch>,
) -> Vec<(Branch, f64)> {
    let (view, motion) = (view.normalize_or_zero(), motion.normalize_or_zero());
    let raw: Vec<(Branch, f64)> = ways
        .iter()
        .map(|b| {
            let h = net.branch_heading(b);
            let mut w = (VIEW_PULL * h.dot(view) + MOTION_PULL * h.dot(motion)).exp();
            if chosen == Some(b) {
                w *= CHOSEN_PULL.exp();
            }
            (*b, w)
        })
        .collect();
    let total: f64 = raw.iter().map(|x| x.1).sum();
    if total.is_nan() || total <= 0.0 {
        return Vec::new();
    }
    raw.into_iter().map(|(b, w)| (b, w / total)).collect()
}

/// A walker on a network: it moves along its track in its direction of travel; crossing a
/// junction it takes the branch the user chose ([`Walker::chosen`], if it is a way out there),
/// else the one nearest the view direction; at the end of a track with no way on it stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Walker {
    pub pos: NetPos,
    /// Travelling towards larger arc lengths.
    pub forward: bool,
    /// The branch to take at the next junction, when the user chose one.
    pub chosen: Option<Branch>,
    /// The junction the walker has just turned at while it still stands on it (so it is not
    /// crossed twice).
    passed: Option<usize>,
}

impl Walker {
    pub fn new(track: usize, s: f64, forward: bool) -> Walker {
        Walker {
            pos: NetPos { track, s },
            forward,
            chosen: None,
            passed: None,
        }
    }

    /// The next junction ahead (or at the walker): its stop on the track, the junction, the
    /// distance to it and the segment the walker arrives along.
    pub fn next_junction<'n>(
        &self,
        net: &'n Network,
    ) -> Option<(usize, &'n Junction, f64, Option<usize>)> {
        let stops = net.stops.get(self.pos.track)?;
        let order: Vec<usize> = if self.forward {
            (0..stops.len()).collect()
        } else {
            (0..stops.len()).rev().collect()
        };
        for k in order {
            let st = stops[k];
            let ahead = if self.forward {
                st.s >= self.pos.s
            } else {
                st.s <= self.pos.s
            };
            if !ahead || (st.s == self.pos.s && self.passed == Some(st.viewpoint)) {
                continue;
            }
            if let Some(j) = net.junction_at(st.viewpoint) {
                let arrival = if self.forward {
                    k.checked_sub(1)
                        .and_then(|p| net.segment_id(self.pos.track, p))
                } else {
                    net.segment_id(self.pos.track, k)
                };
                return Some((k, j, (st.s - self.pos.s).abs(), arrival));
            }
        }
        None
    }

    /// The ways out of the next junction (none without one).
    pub fn options(&self, net: &Network) -> Vec<Branch> {
        self.next_junction(net)
            .map(|(_, j, _, arrival)| ways_out(j, arrival))
            .unwrap_or_default()
    }

    /// The branch the walker will take at the next junction looking along `view`.
    pub fn next_branch(&self, net: &Network, view: DVec3) -> Option<Branch> {
        let ways = self.options(net);
        match self.chosen {
            Some(c) if ways.contains(&c) => Some(c),
            _ => nearest_to_view(net, &ways, view),
        }
    }

    /// The direction of travel (unit, in the world).
    pub fn heading(&self, net: &Network) -> DVec3 {
        let Some(t) = net.tracks.get(self.pos.track) else {
            return DVec3::ZERO;
        };
        let h = t.tangent_at(self.pos.s);
        if self.forward {
            h
        } else {
            -h
        }
    }

    /// Moves `d` metres (≥ 0) on, turning at junctions as [`Walker::next_branch`] says;
    /// the turns made. Stops at the end of a track with no way on.
    pub fn advance(&mut self, net: &Network, d: f64, view: DVec3) -> Vec<Turn> {
        let mut left = if d.is_finite() { d.max(0.0) } else { 0.0 };
        let mut turns = Vec::new();
        // Each pass reaches a junction or the end (at most one turn per junction passed).
        for _ in 0..net.viewpoints.len().max(1) + 1 {
            let Some(t) = net.tracks.get(self.pos.track) else {
                return turns;
            };
            let end = if self.forward { t.length() } else { 0.0 };
            let next = self
                .next_junction(net)
                .filter(|(_, _, dist, _)| *dist <= left);
            let Some((k, j, dist, arrival)) = next else {
                let room = (end - self.pos.s).abs();
                let step = left.min(room);
                self.pos.s += if self.forward { step } else { -step };
                if step > 0.0 {
                    self.passed = None;
                }
                return turns;
            };
            left -= dist;
            let ways = ways_out(j, arrival);
            let pick = match self.chosen {
                Some(c) if ways.contains(&c) => Some(c),
                _ => nearest_to_view(net, &ways, view),
            };
            let Some(b) = pick else {
                // A junction with no way on (the end of every track there).
                self.pos.s = net.stops[self.pos.track][k].s;
                return turns;
            };
            let (from_track, was_forward) = (self.pos.track, self.forward);
            self.pos = NetPos {
                track: b.track,
                s: net.stops[b.track][b.stop].s,
            };
            self.forward = b.forward;
            self.chosen = None;
            self.passed = Some(j.viewpoint);
            // Straight on along the same track is no turn.
            if b.track != from_track || b.forward != was_forward {
                turns.push(Turn {
                    viewpoint: j.viewpoint,
                    from_track,
                    to: b,
                });
            }
            // Step off the junction so the next pass looks past it.
            let step = left.min((net.segments[b.segment].s1 - net.segments[b.segment].s0).abs());
            if step <= 0.0 {
                return turns;
            }
            self.pos.s += if self.forward { step } else { -step };
            self.passed = None;
            left -= step;
            if left <= 0.0 {
                return turns;
            }
        }
        turns
    }
}

/// A walk through named tracks: along the first from its end farther from the second into the
/// second at their junction, and so on, to the far end of the last.
#[derive(Clone, Debug, PartialEq)]
pub struct Route {
    /// Per leg: the track and the arc lengths it runs from and to.
    pub legs: Vec<(usize, f64, f64)>,
    /// The junction viewpoints between legs.
    pub turns: Vec<usize>,
}

impl Route {
    /// The route through `names` (track names of `net`). Errors name the track that is not
    /// there, or the two consecutive tracks that do not meet.
    pub fn new(net: &Network, names: &[&str]) -> Result<Route, String> {
        let ids: Vec<usize> = names
            .iter()
            .map(|n| {
                net.track_index(n).ok_or_else(|| {
                    let all: Vec<&str> = net.tracks.iter().map(|t| t.name.as_str()).collect();
                    format!("no track `{n}` (tracks: {})", all.join(", "))
                })
            })
            .collect::<Result<_, _>>()?;
        if ids.is_empty() {
            return Err("a route needs at least one track".into());
        }
        // Where each consecutive pair meets: the shared viewpoint and its arc on each.
        let mut meets = Vec::new();
        for w in ids.windows(2) {
            let (a, b) = (w[0], w[1]);
            let shared: Vec<(usize, f64, f64)> = net.stops[a]
                .iter()
                .filter_map(|sa| {
                    let sb = net.stops[b]
                        .iter()
                        .find(|sb| sb.viewpoint == sa.viewpoint)?;
                    Some((sa.viewpoint, sa.s, sb.s))
                })
                .collect();
            let Some(&m) = shared.first() else {
                return Err(format!(
                    "tracks `{}` and `{}` do not meet: a route goes from one track into the \
                     next at a junction they share",
                    net.tracks[a].name, net.tracks[b].name
                ));
            };
            meets.push(m);
        }
        let mut legs = Vec::new();
        // The first leg starts at the end of its track farther from where it leaves it.
        let first_len = net.tracks[ids[0]].length();
        let mut start = match meets.first() {
            Some(&(_, sa, _)) if sa < 0.5 * first_len => first_len,
            _ => 0.0,
        };
        for (i, &t) in ids.iter().enumerate() {
            let len = net.tracks[t].length();
            let to = match meets.get(i) {
                Some(&(_, sa, _)) => sa,
                // The last leg runs to the end farther from where it was entered.
                None if start > 0.5 * len => 0.0,
                None => len,
            };
            legs.push((t, start, to));
            if let Some(&(_, _, sb)) = meets.get(i) {
                start = sb;
            }
        }
        Ok(Route {
            legs,
            turns: meets.iter().map(|m| m.0).collect(),
        })
    }

    /// Its length, metres.
    pub fn length(&self) -> f64 {
        self.legs.iter().map(|&(_, a, b)| (b - a).abs()).sum()
    }

    /// Where the walker is `d` metres along the route, and whether it travels forward there.
    pub fn at(&self, d: f64) -> (NetPos, bool) {
        let mut left = d.max(0.0);
        for (i, &(t, a, b)) in self.legs.iter().enumerate() {
            let len = (b - a).abs();
            if left <= len || i + 1 == self.legs.len() {
                let step = left.min(len);
                let s = if b >= a { a + step } else { a - step };
                return (NetPos { track: t, s }, b >= a);
            }
            left -= len;
        }
        (NetPos { track: 0, s: 0.0 }, true)
    }

    /// Distances along the route at which it turns (the ends of all legs but the last).
    pub fn turn_distances(&self) -> Vec<f64> {
        let mut acc = 0.0;
        let mut out = Vec::new();
        for &(_, a, b) in &self.legs[..self.legs.len().saturating_sub(1)] {
            acc += (b - a).abs();
            out.push(acc);
        }
        out
    }
}

#[cfg(test)]
mod tests;
