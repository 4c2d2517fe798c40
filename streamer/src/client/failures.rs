//! Failure accounting for a request scheduler, on any clock (the viewer's wall clock, the
//! walk simulator's virtual one): plain data, no I/O.
//!
//! - [`FailureBook`]: per fetch key, the faults of its object (checksum mismatches that
//!   persist, 404, a range outside the file — [`super::ClientError::is_object_fault`]). A
//!   key that failed waits before it is asked for again (doubling from
//!   [`FailurePolicy::first_retry_s`]), and after [`FailurePolicy::max_faults`] faults it
//!   is given up: counted, never asked for again, and the rest goes on without it. One
//!   damaged object is a per-tile failure, never the end of a session or a walk.
//! - [`ProgressClock`]: the time without progress — while requests are outstanding, how
//!   long since the last one arrived — now and at its longest, so an outage shows in what a
//!   session or a walk reports.

use super::http::{FetchKey, KeyMap};

/// When a failed key is asked for again, and when it is given up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FailurePolicy {
    /// Faults of one key before it is given up (at least 1).
    pub max_faults: u32,
    /// Wait after the first fault, seconds; doubled after each further one.
    pub first_retry_s: f64,
    /// Longest wait between tries, seconds.
    pub max_retry_s: f64,
}

impl Default for FailurePolicy {
    fn default() -> Self {
        FailurePolicy {
            max_faults: 3,
            first_retry_s: 1.0,
            max_retry_s: 30.0,
        }
    }
}

/// What happens to a key after a fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Ask again at this time.
    RetryAt(f64),
    /// Never ask again.
    GivenUp,
}

#[derive(Clone, Copy, Debug)]
struct KeyFaults {
    faults: u32,
    retry_at: f64,
    given_up: bool,
}

/// Object faults per key (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct FailureBook {
    policy: FailurePolicy,
    keys: KeyMap<KeyFaults>,
    faults: u64,
    given_up: u64,
}

impl FailureBook {
    pub fn new(policy: FailurePolicy) -> FailureBook {
        FailureBook {
            policy,
            ..FailureBook::default()
        }
    }

    /// `key`'s object failed at time `t`.
    pub fn fault(&mut self, key: &FetchKey, t: f64) -> Verdict {
        let p = self.policy;
        let k = self.keys.entry(key.clone()).or_insert(KeyFaults {
            faults: 0,
            retry_at: t,
            given_up: false,
        });
        if k.given_up {
            return Verdict::GivenUp;
        }
        self.faults += 1;
        k.faults += 1;
        if k.faults >= p.max_faults.max(1) {
            k.given_up = true;
            self.given_up += 1;
            return Verdict::GivenUp;
        }
        let wait = (p.first_retry_s * 2f64.powi(k.faults as i32 - 1)).min(p.max_retry_s);
        k.retry_at = t + wait.max(0.0);
        Verdict::RetryAt(k.retry_at)
    }

    /// Give `key` up at once (its object arrived intact but is unusable).
    pub fn give_up(&mut self, key: &FetchKey) {
        let k = self.keys.entry(key.clone()).or_insert(KeyFaults {
            faults: 0,
            retry_at: 0.0,
            given_up: false,
        });
        if !k.given_up {
            k.given_up = true;
            k.faults += 1;
            self.faults += 1;
            self.given_up += 1;
        }
    }

    /// Whether `key` may be asked for at time `t` (not given up, not waiting).
    pub fn may_request(&self, key: &FetchKey, t: f64) -> bool {
        self.keys
            .get(key)
            .is_none_or(|k| !k.given_up && t >= k.retry_at)
    }

    /// Whether `key` was given up.
    pub fn is_given_up(&self, key: &FetchKey) -> bool {
        self.keys.get(key).is_some_and(|k| k.given_up)
    }

    /// `key` arrived: its faults are forgotten.
    pub fn succeeded(&mut self, key: &FetchKey) {
        if self.keys.get(key).is_some_and(|k| !k.given_up) {
            self.keys.remove(key);
        }
    }

    /// Faults counted in all.
    pub fn faults(&self) -> u64 {
        self.faults
    }

    /// Keys given up.
    pub fn given_up(&self) -> u64 {
        self.given_up
    }
}

/// Time without progress on one clock (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProgressClock {
    /// Since when the client has been waiting with nothing arriving (`None`: not waiting).
    waiting_since: Option<f64>,
    longest_s: f64,
}

impl ProgressClock {
    /// At time `t`: whether requests are outstanding, and whether something arrived.
    pub fn observe(&mut self, t: f64, outstanding: bool, arrived: bool) {
        if let Some(since) = self.waiting_since {
            self.longest_s = self.longest_s.max(t - since);
        }
        self.waiting_since = match (outstanding, arrived) {
            (false, _) => None,
            (true, true) => Some(t),
            (true, false) => Some(self.waiting_since.unwrap_or(t)),
        };
    }

    /// Seconds without progress at time `t` (0 when nothing is outstanding).
    pub fn current_s(&self, t: f64) -> f64 {
        self.waiting_since.map_or(0.0, |s| (t - s).max(0.0))
    }

    /// The longest time without progress so far.
    pub fn longest_s(&self) -> f64 {
        self.longest_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(n: u8) -> FetchKey {
        FetchKey {
            object: format!("{n:02x}").repeat(32).into(),
            range: Some((0, 10)),
        }
    }

    #[test]
    fn a_failing_key_waits_longer_each_time_then_is_given_up() {
        let mut b = FailureBook::new(FailurePolicy::default());
        let (a, other) = (key(1), key(2));
        assert!(b.may_request(&a, 0.0));
        assert_eq!(b.fault(&a, 10.0), Verdict::RetryAt(11.0));
        assert!(!b.may_request(&a, 10.5) && b.may_request(&a, 11.0));
        assert!(b.may_request(&other, 10.5));
        assert_eq!(b.fault(&a, 11.0), Verdict::RetryAt(13.0));
        assert_eq!(b.fault(&a, 13.0), Verdict::GivenUp);
        assert!(!b.may_request(&a, 1e9) && b.is_given_up(&a));
        // Given up stays given up, and counts once.
        assert_eq!(b.fault(&a, 20.0), Verdict::GivenUp);
        b.succeeded(&a);
        assert!(b.is_given_up(&a));
        assert_eq!((b.faults(), b.given_up()), (3, 1));
        // A success forgets earlier faults.
        b.fault(&other, 0.0);
        b.succeeded(&other);
        assert!(b.may_request(&other, 0.0));
    }

    #[test]
    fn progress_clock_measures_waits_with_requests_outstanding() {
        let mut c = ProgressClock::default();
        c.observe(0.0, false, false);
        c.observe(1.0, true, false);
        c.observe(1.5, true, true);
        assert_eq!(c.current_s(1.5), 0.0);
        c.observe(9.5, true, false);
        assert_eq!(c.current_s(10.0), 8.5);
        c.observe(10.0, true, true);
        assert_eq!(c.longest_s(), 8.5);
        // Idle time (nothing outstanding) is not waiting.
        c.observe(20.0, false, false);
        c.observe(40.0, false, false);
        assert_eq!(c.longest_s(), 10.0);
    }
}
