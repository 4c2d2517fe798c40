//! The scheduler on a network of tracks: the pair of viewpoints around the walker, its
//! segment, distances along the network, and the segments it may enter next — every way out
//! of a junction ahead, weighted by how likely it is.

use tracks::network::{Branch, Network};
use tracks::PerspectiveCamera;

use super::Scheduler;
use crate::client::route::{branch_weights, ways_out, NetPos};

impl Scheduler {
    /// The network the manifest describes.
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The branch the user chose for the next junction (`None`: the one nearest the view),
    /// which the prefetch weighs most.
    pub fn set_branch(&mut self, branch: Option<Branch>) {
        if self.chosen != branch {
            self.chosen = branch;
            self.prefetch_memo = None;
        }
    }

    /// The blend weights at arc length `s` of the current track, by viewpoint id.
    pub(super) fn pair(&self, s: f64) -> Vec<(usize, f64)> {
        self.net.blend_weights(self.track, s)
    }

    /// The segment (global id) of the current track that holds `s`.
    pub(super) fn segment(&self, s: f64) -> Option<usize> {
        self.net.segment_at(self.track, s)
    }

    /// Distance along the network from the walker (arc length `s` of the current track) to
    /// every viewpoint; the shortest paths from the segment's two ends are kept while the
    /// walker stays on it.
    pub(super) fn distances(&mut self, s: f64) -> Vec<f64> {
        let Some(seg) = self.segment(s) else {
            return self.net.distances_from_position(self.track, s);
        };
        let sg = self.net.segments[seg];
        if self.dist_memo.as_ref().is_none_or(|m| m.0 != seg) {
            let a = self.net.distances_from(&[(sg.from, 0.0)]);
            let b = self.net.distances_from(&[(sg.to, 0.0)]);
            self.dist_memo = Some((seg, a, b));
        }
        let Some((_, a, b)) = &self.dist_memo else {
            return Vec::new();
        };
        let s = s.clamp(sg.s0, sg.s1);
        a.iter()
            .zip(b)
            .map(|(da, db)| (da + (s - sg.s0)).min(db + (sg.s1 - s)))
            .collect()
    }

    /// The segments the walker may enter next within the prefetch horizon, with how likely
    /// each is: along the track the next one; at a junction every way out but the way back,
    /// weighted by the view, the motion and the user's choice ([`branch_weights`]).
    pub(super) fn next_segments(&self, s: f64, camera: &PerspectiveCamera) -> Vec<(usize, f64)> {
        let Some(stops) = self.net.stops.get(self.track) else {
            return Vec::new();
        };
        let arcs: Vec<f64> = stops.iter().map(|x| x.s).collect();
        let (Some(k), Some(v), Some(ahead)) = (
            tracks::segment::segment_at(&arcs, s),
            self.motion.velocity(),
            self.motion.predict(self.config.prefetch_horizon_s),
        ) else {
            return Vec::new();
        };
        if v == 0.0 {
            return Vec::new();
        }
        let (boundary, stop) = if v > 0.0 {
            (arcs[k + 1], k + 1)
        } else {
            (arcs[k], k)
        };
        let reaches = if v > 0.0 {
            ahead >= boundary
        } else {
            ahead <= boundary
        };
        if !reaches {
            return Vec::new();
        }
        let cur = self.net.segment_id(self.track, k);
        if let Some(j) = self.net.junction_at(stops[stop].viewpoint) {
            let ways = ways_out(j, cur);
            let t = &self.net.tracks[self.track];
            let motion = t.tangent_at(s) * v.signum();
            return branch_weights(
                &self.net,
                &ways,
                camera.forward(),
                motion,
                self.chosen.as_ref(),
            )
            .into_iter()
            .map(|(b, w)| (b.segment, w))
            .collect();
        }
        let next = if v > 0.0 {
            self.net.segment_id(self.track, k + 1)
        } else {
            k.checked_sub(1)
                .and_then(|p| self.net.segment_id(self.track, p))
        };
        next.map(|e| vec![(e, 1.0)]).unwrap_or_default()
    }

    /// A walker now on another track: the motion so far restated along it, through the
    /// junction the two tracks share (the one nearest both positions), so speed and
    /// direction carry over the turn.
    pub(super) fn rebase(&mut self, pos: NetPos) {
        let old = self.track;
        let Some((prev_s, prev_t)) = self.motion.last() else {
            self.track = pos.track;
            return;
        };
        let shared = self.net.stops.get(old).and_then(|a| {
            let b = self.net.stops.get(pos.track)?;
            a.iter()
                .filter_map(|sa| {
                    let sb = b.iter().find(|sb| sb.viewpoint == sa.viewpoint)?;
                    Some((sa.s, sb.s))
                })
                .min_by(|x, y| {
                    ((x.0 - prev_s).abs() + (x.1 - pos.s).abs())
                        .total_cmp(&((y.0 - prev_s).abs() + (y.1 - pos.s).abs()))
                })
        });
        self.motion.clear();
        if let Some((ja, jb)) = shared {
            let back = (prev_s - ja).abs();
            let dir = (pos.s - jb).signum();
            if dir != 0.0 {
                self.motion.observe(prev_t, jb - dir * back);
            }
        }
        self.track = pos.track;
    }
}
