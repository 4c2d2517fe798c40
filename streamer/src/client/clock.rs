//! The clock a live session reads: the wall clock for the viewer, a hand-set one for tests
//! that replay a recorded walk frame by frame (downloads then take no time on it, as on the
//! walk simulator's unlimited link).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Seconds since some start, non-decreasing.
pub trait Clock: Send + Sync {
    fn now_s(&self) -> f64;
}

/// The wall clock, from when it was made.
#[derive(Debug)]
pub struct WallClock(Instant);

impl WallClock {
    pub fn new() -> WallClock {
        WallClock(Instant::now())
    }
}

impl Default for WallClock {
    fn default() -> Self {
        WallClock::new()
    }
}

impl Clock for WallClock {
    fn now_s(&self) -> f64 {
        self.0.elapsed().as_secs_f64()
    }
}

/// A clock that moves only when told to ([`ManualClock::set`]).
#[derive(Debug, Default)]
pub struct ManualClock(AtomicU64);

impl ManualClock {
    pub fn new(t: f64) -> ManualClock {
        ManualClock(AtomicU64::new(t.to_bits()))
    }

    /// Set the time (seconds; earlier times than the current one are ignored).
    pub fn set(&self, t: f64) {
        if t.is_finite() && t >= self.now_s() {
            self.0.store(t.to_bits(), Ordering::Relaxed);
        }
    }
}

impl Clock for ManualClock {
    fn now_s(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manual_clock_moves_only_forward_when_told() {
        let c = ManualClock::new(1.5);
        assert_eq!(c.now_s(), 1.5);
        c.set(2.0);
        c.set(1.0);
        c.set(f64::NAN);
        assert_eq!(c.now_s(), 2.0);
        assert!(WallClock::new().now_s() >= 0.0);
    }
}
