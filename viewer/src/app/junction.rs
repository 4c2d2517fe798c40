//! Walking the window's camera through a network: W/S (or ↑/↓) move along the track, and at
//! a junction the walk goes on along the branch chosen with A/D (or ←/→), else along the one
//! nearest the view ([`streamer::client::Walker`], the one rule of both native paths). The
//! camera keeps its direction in the world through a turn.

use glam::DVec3;
use streamer::client::route::ways_out;
use streamer::client::Walker;
use tracks::network::{Branch, Network};

use super::{Source, ViewerApp};
use crate::headless::yaw_along;

/// The window's walker on its network.
pub(super) struct Junctions {
    pub net: Network,
    pub walker: Walker,
}

impl Junctions {
    /// The network of `source`, the walker at the start of its current track; `None` for a
    /// source without one (a single track walks as before).
    pub fn of(source: &Source) -> Option<Junctions> {
        let walk = source.walk();
        let net = walk.network().ok()?;
        if net.junctions.is_empty() {
            return None;
        }
        Some(Junctions {
            walker: Walker::new(walk.current, 0.0, true),
            net,
        })
    }

    /// The ways out of the next junction ahead, left to right as seen along the direction of
    /// travel, and how far it is.
    pub fn ahead(&self) -> Option<(Vec<Branch>, f64)> {
        let (_, j, dist, arrival) = self.walker.next_junction(&self.net)?;
        let heading = self.walker.heading(&self.net);
        let mut ways = ways_out(j, arrival);
        // Left to right: by the signed angle from the heading (y up, yaw clockwise).
        let angle = |b: &Branch| {
            let h = self.net.branch_heading(b);
            let cross = heading.x * h.z - heading.z * h.x;
            cross.atan2(heading.dot(h))
        };
        ways.sort_by(|a, b| angle(a).total_cmp(&angle(b)));
        Some((ways, dist))
    }

    /// Moves the choice for the next junction one way to the left (`-1`) or right (`+1`).
    pub fn choose(&mut self, step: i32, view: DVec3) {
        let Some((ways, _)) = self.ahead() else {
            return;
        };
        if ways.is_empty() {
            return;
        }
        let current = self
            .walker
            .next_branch(&self.net, view)
            .and_then(|b| ways.iter().position(|w| *w == b))
            .unwrap_or(0) as i32;
        let k = (current + step).clamp(0, ways.len() as i32 - 1) as usize;
        self.walker.chosen = Some(ways[k]);
    }

    /// A line for the panel: where the next junction is and which way the walk goes there.
    pub fn describe(&self, view: DVec3) -> String {
        let Some((ways, dist)) = self.ahead() else {
            return "no junction ahead".into();
        };
        let next = self.walker.next_branch(&self.net, view);
        let names: Vec<String> = ways
            .iter()
            .map(|b| {
                let name = &self.net.tracks[b.track].name;
                let mark = if Some(*b) == next { "▶" } else { " " };
                let dir = if b.forward { "+" } else { "−" };
                format!("{mark}{name}{dir}")
            })
            .collect();
        let how = if self.walker.chosen.is_some() {
            "chosen (A/D)"
        } else {
            "nearest the view (A/D to choose)"
        };
        format!("junction in {dist:.1} m: {} — {how}", names.join("  "))
    }
}

impl ViewerApp {
    /// Moves the camera `ds` metres (backwards when negative) along the network, turning at
    /// junctions; the walkthrough follows onto the new track and the view keeps its world
    /// direction.
    pub(super) fn walk_network(&mut self, ds: f64) {
        let Some(j) = &mut self.junctions else {
            return;
        };
        if ds == 0.0 {
            return;
        }
        let walk = self.source.walk();
        let yaw_world = yaw_along(walk, self.s) + self.yaw_offset_deg;
        let view = {
            let y = yaw_world.to_radians();
            DVec3::new(y.sin(), 0.0, -y.cos())
        };
        j.walker.pos.s = self.s;
        let forward = j.walker.forward;
        if ds < 0.0 {
            j.walker.forward = !forward;
        }
        j.walker.advance(&j.net, ds.abs(), view);
        if ds < 0.0 {
            j.walker.forward = !j.walker.forward;
        }
        let (track, s) = (j.walker.pos.track, j.walker.pos.s);
        if track != self.source.walk().current {
            match &mut self.source {
                Source::Local(w) => w.set_track(track),
                Source::Stream(st) => st.set_track(track),
            }
        }
        self.s = s;
        // The same world direction along the new track.
        self.yaw_offset_deg = wrap(yaw_world - yaw_along(self.source.walk(), s));
        if let (Source::Stream(st), Some(j)) = (&mut self.source, &self.junctions) {
            st.set_branch(j.walker.chosen);
        }
    }
}

/// An angle in degrees brought into −180..180.
fn wrap(deg: f64) -> f64 {
    let d = (deg + 180.0).rem_euclid(360.0) - 180.0;
    if d.is_finite() {
        d
    } else {
        0.0
    }
}
