//! Motion along a track from recent positions: speed, stillness and the next segment
//! (the city paper's prefetching module, §5.3, with the track as the adjacency graph).

/// Remembers the two most recent distinct positions along the track (the paper's FIFO of
/// two viewpoints) and how long the viewpoint has been still.
#[derive(Clone, Debug, Default)]
pub struct MotionTracker {
    /// `(time_s, s)` of the two most recent distinct positions, oldest first.
    fifo: Vec<(f64, f64)>,
    last_move_t: f64,
    now: f64,
}

/// Positions closer than this (metres) count as the same.
const STILL_EPS_M: f64 = 1e-4;

impl MotionTracker {
    pub fn new() -> MotionTracker {
        MotionTracker::default()
    }

    /// Record the viewpoint at arc length `s` at time `t` (seconds, non-decreasing).
    pub fn observe(&mut self, t: f64, s: f64) {
        if !(t.is_finite() && s.is_finite()) {
            return;
        }
        self.now = t;
        match self.fifo.last() {
            Some(&(_, last)) if (s - last).abs() < STILL_EPS_M => {}
            _ => {
                if self.fifo.len() == 2 {
                    self.fifo.remove(0);
                }
                self.fifo.push((t, s));
                self.last_move_t = t;
            }
        }
    }

    /// The most recent position and its time, `(s, t)`.
    pub fn last(&self) -> Option<(f64, f64)> {
        self.fifo.last().map(|&(t, s)| (s, t))
    }

    /// Forgets every position (the walker went onto another track).
    pub fn clear(&mut self) {
        self.fifo.clear();
    }

    /// Seconds since the viewpoint last moved.
    pub fn still_s(&self) -> f64 {
        if self.fifo.is_empty() {
            0.0
        } else {
            self.now - self.last_move_t
        }
    }

    /// Velocity along the track (m/s, signed) from the two most recent positions; `None`
    /// until two distinct positions are known or once the viewpoint is still.
    pub fn velocity(&self) -> Option<f64> {
        let [(t0, s0), (t1, s1)] = self.fifo[..] else {
            return None;
        };
        if t1 <= t0 || self.still_s() > (t1 - t0).max(0.5) {
            return None;
        }
        Some((s1 - s0) / (t1 - t0))
    }

    /// Predicted arc length `horizon_s` seconds ahead.
    pub fn predict(&self, horizon_s: f64) -> Option<f64> {
        let &(_, s) = self.fifo.last()?;
        Some(s + self.velocity()? * horizon_s.max(0.0))
    }
}

pub use tracks::segment::segment_at;

/// The segment to prefetch: the one the predicted motion enters next within `horizon_s`
/// (forward or backward), if it differs from the current one.
pub fn next_segment(m: &MotionTracker, vp_s: &[f64], s: f64, horizon_s: f64) -> Option<usize> {
    let cur = segment_at(vp_s, s)?;
    let v = m.velocity()?;
    if v == 0.0 {
        return None;
    }
    let ahead = m.predict(horizon_s)?;
    let next = if v > 0.0 {
        (cur + 1 < vp_s.len() - 1).then_some(cur + 1)?
    } else {
        cur.checked_sub(1)?
    };
    let boundary = if v > 0.0 { vp_s[cur + 1] } else { vp_s[cur] };
    let reaches = if v > 0.0 {
        ahead >= boundary
    } else {
        ahead <= boundary
    };
    reaches.then_some(next)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_and_stillness() {
        let mut m = MotionTracker::new();
        assert_eq!(m.velocity(), None);
        m.observe(0.0, 1.0);
        m.observe(0.5, 1.75);
        assert_eq!(m.velocity(), Some(1.5));
        assert_eq!(m.predict(2.0), Some(4.75));
        m.observe(1.0, 1.75);
        m.observe(2.0, 1.75);
        assert!((m.still_s() - 1.5).abs() < 1e-12);
        assert_eq!(m.velocity(), None, "a still viewpoint predicts nothing");
    }

    #[test]
    fn next_segment_follows_the_direction_of_travel() {
        let vp = [0.0, 5.0, 10.0, 15.0];
        assert_eq!(segment_at(&vp, -1.0), Some(0));
        assert_eq!(segment_at(&vp, 7.0), Some(1));
        assert_eq!(segment_at(&vp, 15.0), Some(2));
        assert_eq!(segment_at(&[0.0], 0.0), None);
        let mut m = MotionTracker::new();
        m.observe(0.0, 8.0);
        m.observe(1.0, 9.0);
        assert_eq!(next_segment(&m, &vp, 9.0, 2.0), Some(2));
        assert_eq!(
            next_segment(&m, &vp, 9.0, 0.5),
            None,
            "boundary not reached yet"
        );
        let mut back = MotionTracker::new();
        back.observe(0.0, 6.0);
        back.observe(1.0, 5.5);
        assert_eq!(next_segment(&back, &vp, 5.5, 2.0), Some(0));
        let mut end = MotionTracker::new();
        end.observe(0.0, 13.0);
        end.observe(1.0, 14.0);
        assert_eq!(
            next_segment(&end, &vp, 14.0, 5.0),
            None,
            "no segment past the end"
        );
    }
}
