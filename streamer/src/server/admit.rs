//! Admission and time limits per connection.
//!
//! Every open connection has a [`ConnState`]: atomics that its I/O wrapper
//! ([`super::guard::Guarded`]) and its response body update as bytes move, and that the
//! accept loop and a sweeper read. Two decisions are made from them, both plain functions of
//! a [`Snapshot`] and the time so they are tested without sockets:
//!
//! - [`timed_out`] (the sweeper, several times a second): an idle connection that sent no
//!   byte of a request for `idle_timeout`; a request head not complete `header_timeout` after
//!   its first byte (counted from that byte: sending slowly does not extend it); writes
//!   blocked by a peer that does not read for `write_timeout`; a response the peer takes at
//!   less than `min_send_rate` once its writes have blocked (a reader that drips).
//! - [`Registry::admit`] (the accept loop): the server never stops accepting. At the
//!   connection limit, or a peer's limit, a new connection takes the place of the one that
//!   does least for anyone ([`pick_victim`]): first an idle connection that has never
//!   completed a request (slow header senders, sockets opened and left), from the peer with
//!   the most connections, longest idle first; then one whose writes have been blocked for
//!   [`STALLED_MS`] (a reader that stopped reading); then an idle keep-alive connection.
//!   Connections younger than [`MIN_AGE_MS`] are not taken, so a client that just
//!   connected always gets to send its request. When nothing can be taken the new
//!   connection is answered `503` and closed.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Notify;
use tokio::time::Instant;

/// A connection idle (or its writes blocked) for less than this is never evicted.
pub const MIN_AGE_MS: u64 = 250;
/// Writes blocked this long without progress make a connection evictable under pressure.
pub const STALLED_MS: u64 = 1000;

/// Milliseconds since the server started, from 1 (0 means "not set" in the atomics).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Clock {
    epoch: Instant,
}

impl Clock {
    pub(crate) fn new() -> Clock {
        Clock {
            epoch: Instant::now(),
        }
    }

    pub(crate) fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64 + 1
    }
}

/// Why the server closed a connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum CloseReason {
    /// No byte of a request within `idle_timeout`.
    IdleTimeout = 1,
    /// A request head not complete within `header_timeout` of its first byte.
    HeaderTimeout,
    /// Writes blocked for `write_timeout` (the peer does not read).
    WriteTimeout,
    /// A response taken at less than `min_send_rate`.
    TooSlow,
    /// Its place was given to a new connection at a limit.
    Evicted,
}

impl CloseReason {
    fn from_u8(v: u8) -> Option<CloseReason> {
        use CloseReason::*;
        [IdleTimeout, HeaderTimeout, WriteTimeout, TooSlow, Evicted]
            .into_iter()
            .find(|r| *r as u8 == v)
    }
}

/// The time limits the sweeper applies, in milliseconds and bytes per second.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TimeLimits {
    pub idle_ms: u64,
    pub header_ms: u64,
    pub write_ms: u64,
    /// Bytes per second; 0 = no rate check.
    pub min_rate: u64,
}

impl TimeLimits {
    pub(crate) fn new(
        idle: Duration,
        header: Duration,
        write: Duration,
        min_rate: u64,
    ) -> TimeLimits {
        let ms = |d: Duration| (d.as_millis() as u64).max(1);
        TimeLimits {
            idle_ms: ms(idle),
            header_ms: ms(header),
            write_ms: ms(write),
            min_rate,
        }
    }
}

/// What one connection is doing, shared by its task, its I/O, the sweeper and admission.
#[derive(Debug)]
pub(crate) struct ConnState {
    pub(crate) peer: IpAddr,
    connected_ms: u64,
    busy: AtomicBool,
    idle_since_ms: AtomicU64,
    /// First byte of a request received while idle (0: none yet).
    head_started_ms: AtomicU64,
    written: AtomicU64,
    /// Since when writes have been refused (0: not blocked).
    blocked_since_ms: AtomicU64,
    /// Where the rate of the current response is measured from: its first blocked write.
    rate_from_ms: AtomicU64,
    rate_from_bytes: AtomicU64,
    responses: AtomicU64,
    close: Notify,
    reason: AtomicU8,
}

/// A copy of a [`ConnState`] at one moment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Snapshot {
    pub busy: bool,
    pub connected_ms: u64,
    pub idle_since_ms: u64,
    pub head_started_ms: u64,
    pub written: u64,
    pub blocked_since_ms: u64,
    pub rate_from_ms: u64,
    pub rate_from_bytes: u64,
    pub responses: u64,
}

impl ConnState {
    pub(crate) fn new(peer: IpAddr, now_ms: u64) -> ConnState {
        ConnState {
            peer,
            connected_ms: now_ms,
            busy: AtomicBool::new(false),
            idle_since_ms: AtomicU64::new(now_ms),
            head_started_ms: AtomicU64::new(0),
            written: AtomicU64::new(0),
            blocked_since_ms: AtomicU64::new(0),
            rate_from_ms: AtomicU64::new(0),
            rate_from_bytes: AtomicU64::new(0),
            responses: AtomicU64::new(0),
            close: Notify::new(),
            reason: AtomicU8::new(0),
        }
    }

    /// Bytes read from the peer.
    pub(crate) fn on_read(&self, n: usize, now_ms: u64) {
        if n > 0 && !self.busy.load(Relaxed) && self.head_started_ms.load(Relaxed) == 0 {
            self.head_started_ms.store(now_ms, Relaxed);
        }
    }

    /// The socket refused a write (its buffer is full: the peer is not reading).
    pub(crate) fn on_write_blocked(&self, now_ms: u64) {
        if self.blocked_since_ms.load(Relaxed) == 0 {
            self.blocked_since_ms.store(now_ms, Relaxed);
        }
        if self.rate_from_ms.load(Relaxed) == 0 {
            self.rate_from_bytes
                .store(self.written.load(Relaxed), Relaxed);
            self.rate_from_ms.store(now_ms, Relaxed);
        }
    }

    /// The socket took `n` bytes.
    pub(crate) fn on_written(&self, n: usize) {
        self.written.fetch_add(n as u64, Relaxed);
        if n > 0 {
            self.blocked_since_ms.store(0, Relaxed);
        }
    }

    /// A request head arrived and its response is being made.
    pub(crate) fn start_response(&self) {
        self.busy.store(true, Relaxed);
        self.head_started_ms.store(0, Relaxed);
        self.rate_from_ms.store(0, Relaxed);
    }

    /// The response's body has been handed to the connection in full (or dropped).
    pub(crate) fn end_response(&self, now_ms: u64) {
        self.responses.fetch_add(1, Relaxed);
        self.idle_since_ms.store(now_ms, Relaxed);
        self.head_started_ms.store(0, Relaxed);
        self.busy.store(false, Relaxed);
    }

    /// Ask the connection's task to close it (the first reason given wins).
    pub(crate) fn close(&self, reason: CloseReason) {
        if self
            .reason
            .compare_exchange(0, reason as u8, Relaxed, Relaxed)
            .is_ok()
        {
            self.close.notify_one();
        }
    }

    /// Why the server closed (or is closing) this connection, if it did.
    pub(crate) fn close_reason(&self) -> Option<CloseReason> {
        CloseReason::from_u8(self.reason.load(Relaxed))
    }

    /// Resolves when [`ConnState::close`] was called.
    pub(crate) async fn closed(&self) -> CloseReason {
        loop {
            if let Some(r) = CloseReason::from_u8(self.reason.load(Relaxed)) {
                return r;
            }
            self.close.notified().await;
        }
    }

    pub(crate) fn snapshot(&self) -> Snapshot {
        Snapshot {
            busy: self.busy.load(Relaxed),
            connected_ms: self.connected_ms,
            idle_since_ms: self.idle_since_ms.load(Relaxed),
            head_started_ms: self.head_started_ms.load(Relaxed),
            written: self.written.load(Relaxed),
            blocked_since_ms: self.blocked_since_ms.load(Relaxed),
            rate_from_ms: self.rate_from_ms.load(Relaxed),
            rate_from_bytes: self.rate_from_bytes.load(Relaxed),
            responses: self.responses.load(Relaxed),
        }
    }
}

/// Whether a connection has run out of time (see the module docs), and why.
pub(crate) fn timed_out(s: &Snapshot, now: u64, l: &TimeLimits) -> Option<CloseReason> {
    let since = |t: u64| now.saturating_sub(t);
    if s.blocked_since_ms != 0 && since(s.blocked_since_ms) > l.write_ms {
        return Some(CloseReason::WriteTimeout);
    }
    // The rate of a response whose writes have blocked, once it had `write_ms` to show it;
    // only while something is left to send (busy, or still blocked on the last bytes).
    if l.min_rate > 0
        && s.rate_from_ms != 0
        && (s.busy || s.blocked_since_ms != 0)
        && since(s.rate_from_ms) >= l.write_ms
    {
        let sent = s.written.saturating_sub(s.rate_from_bytes);
        if sent.saturating_mul(1000) < l.min_rate.saturating_mul(since(s.rate_from_ms)) {
            return Some(CloseReason::TooSlow);
        }
    }
    if !s.busy {
        if s.head_started_ms != 0 {
            if since(s.head_started_ms) > l.header_ms {
                return Some(CloseReason::HeaderTimeout);
            }
        } else if s.blocked_since_ms == 0 && since(s.idle_since_ms) > l.idle_ms {
            return Some(CloseReason::IdleTimeout);
        }
    }
    None
}

/// A candidate for eviction: its id, how many connections its peer holds, and its state.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Candidate {
    pub id: u64,
    pub peer_connections: usize,
    pub state: Snapshot,
}

/// The connection to close so that a new one can take its place (see the module docs), or
/// `None` when every connection is doing something worth keeping.
pub(crate) fn pick_victim(cands: impl IntoIterator<Item = Candidate>, now: u64) -> Option<u64> {
    // (class, ordering key) — smaller is evicted first.
    let rank = |c: &Candidate| -> Option<(u8, u64, u64)> {
        let s = &c.state;
        let idle_for = now.saturating_sub(s.idle_since_ms.max(s.connected_ms));
        let idle = !s.busy && s.blocked_since_ms == 0;
        if idle && s.responses == 0 && idle_for >= MIN_AGE_MS {
            // Most connections of one peer first, then the longest idle.
            return Some((0, u64::MAX - c.peer_connections as u64, u64::MAX - idle_for));
        }
        if s.blocked_since_ms != 0 && now.saturating_sub(s.blocked_since_ms) >= STALLED_MS {
            return Some((1, s.blocked_since_ms, 0));
        }
        if idle && idle_for >= MIN_AGE_MS {
            return Some((2, u64::MAX - idle_for, 0));
        }
        None
    };
    cands
        .into_iter()
        .filter_map(|c| rank(&c).map(|r| (r, c.id)))
        .min()
        .map(|(_, id)| id)
}

/// What the accept loop does with a new connection.
pub(crate) enum Admission {
    /// Serve it; close `evicted` (already removed from the registry) to make room.
    Admit {
        id: u64,
        state: Arc<ConnState>,
        evicted: Option<Arc<ConnState>>,
    },
    /// No room: answer 503 and close it.
    Refuse,
}

/// The open connections, per peer too.
#[derive(Default)]
pub(crate) struct Registry {
    conns: HashMap<u64, Arc<ConnState>>,
    per_peer: HashMap<IpAddr, usize>,
    next_id: u64,
}

impl Registry {
    pub(crate) fn len(&self) -> usize {
        self.conns.len()
    }

    /// Admit a connection from `peer` within `max` connections and `max_per_peer` per peer.
    pub(crate) fn admit(
        &mut self,
        peer: IpAddr,
        now: u64,
        max: usize,
        max_per_peer: usize,
    ) -> Admission {
        let peer_count = self.per_peer.get(&peer).copied().unwrap_or(0);
        let mut evicted = None;
        if peer_count >= max_per_peer.max(1) || self.conns.len() >= max.max(1) {
            // At the peer's limit its own connections make room; at the server's, anyone's.
            let own_only = peer_count >= max_per_peer.max(1);
            let cands = self
                .conns
                .iter()
                .filter(|(_, c)| !own_only || c.peer == peer)
                .map(|(&id, c)| Candidate {
                    id,
                    peer_connections: self.per_peer.get(&c.peer).copied().unwrap_or(0),
                    state: c.snapshot(),
                });
            match pick_victim(cands, now) {
                Some(id) => evicted = self.remove(id),
                None => return Admission::Refuse,
            }
        }
        self.next_id += 1;
        let id = self.next_id;
        let state = Arc::new(ConnState::new(peer, now));
        self.conns.insert(id, state.clone());
        *self.per_peer.entry(peer).or_default() += 1;
        Admission::Admit { id, state, evicted }
    }

    /// Forget connection `id` (closed, or evicted); its state when it was still here.
    pub(crate) fn remove(&mut self, id: u64) -> Option<Arc<ConnState>> {
        let c = self.conns.remove(&id)?;
        if let Some(n) = self.per_peer.get_mut(&c.peer) {
            *n -= 1;
            if *n == 0 {
                self.per_peer.remove(&c.peer);
            }
        }
        Some(c)
    }

    /// Remove and return the connections that ran out of time, with the reason.
    pub(crate) fn sweep(
        &mut self,
        now: u64,
        limits: &TimeLimits,
    ) -> Vec<(Arc<ConnState>, CloseReason)> {
        let expired: Vec<(u64, CloseReason)> = self
            .conns
            .iter()
            .filter_map(|(&id, c)| timed_out(&c.snapshot(), now, limits).map(|r| (id, r)))
            .collect();
        expired
            .into_iter()
            .filter_map(|(id, r)| self.remove(id).map(|c| (c, r)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const L: TimeLimits = TimeLimits {
        idle_ms: 30_000,
        header_ms: 5_000,
        write_ms: 10_000,
        min_rate: 1024,
    };

    fn idle(since: u64) -> Snapshot {
        Snapshot {
            connected_ms: since,
            idle_since_ms: since,
            ..Snapshot::default()
        }
    }

    #[test]
    fn a_slow_head_is_cut_off_from_its_first_byte_however_it_drips() {
        let mut s = idle(1);
        s.head_started_ms = 100;
        assert_eq!(timed_out(&s, 5_000, &L), None);
        assert_eq!(timed_out(&s, 5_101, &L), Some(CloseReason::HeaderTimeout));
        // Without a byte, the idle timeout applies.
        let s = idle(1);
        assert_eq!(timed_out(&s, 29_000, &L), None);
        assert_eq!(timed_out(&s, 30_002, &L), Some(CloseReason::IdleTimeout));
    }

    #[test]
    fn blocked_writes_and_dripping_readers_time_out() {
        let mut s = idle(1);
        s.busy = true;
        s.blocked_since_ms = 1_000;
        s.rate_from_ms = 1_000;
        s.written = 100_000;
        s.rate_from_bytes = 100_000;
        assert_eq!(timed_out(&s, 10_999, &L), None);
        assert_eq!(timed_out(&s, 11_001, &L), Some(CloseReason::WriteTimeout));
        // A reader taking 500 bytes a second: progress, but below the minimum rate.
        s.blocked_since_ms = 10_900;
        s.written = 100_000 + 5_000;
        assert_eq!(timed_out(&s, 11_000, &L), Some(CloseReason::TooSlow));
        // 20 kB/s is fine; so is a response that finished and sent everything.
        s.written = 100_000 + 200_000;
        assert_eq!(timed_out(&s, 11_000, &L), None);
        s.written = 100_000 + 5_000;
        s.busy = false;
        s.blocked_since_ms = 0;
        s.idle_since_ms = 10_950;
        assert_eq!(timed_out(&s, 11_000, &L), None);
    }

    fn cand(id: u64, peer_connections: usize, state: Snapshot) -> Candidate {
        Candidate {
            id,
            peer_connections,
            state,
        }
    }

    #[test]
    fn victims_are_idle_strangers_first_then_stalled_readers_then_keep_alives() {
        let now = 10_000;
        let mut served = idle(1_000);
        served.responses = 5;
        let mut stalled = idle(500);
        stalled.busy = true;
        stalled.blocked_since_ms = 8_000;
        let mut working = idle(100);
        working.busy = true;
        let young = idle(now - 10);
        // Nothing evictable: working, young, or blocked only briefly.
        let mut brief = working;
        brief.blocked_since_ms = now - 100;
        assert_eq!(
            pick_victim(
                [cand(1, 1, working), cand(2, 1, young), cand(3, 1, brief)],
                now
            ),
            None
        );
        let all = [
            cand(1, 1, served),
            cand(2, 1, stalled),
            cand(3, 1, working),
            cand(4, 1, idle(9_000)),
            cand(5, 1, idle(2_000)),
        ];
        assert_eq!(pick_victim(all, now), Some(5));
        assert_eq!(pick_victim(all[..3].iter().copied(), now), Some(2));
        assert_eq!(pick_victim([all[0], all[2]], now), Some(1));
        // Among idle strangers, the peer holding the most connections gives way first.
        assert_eq!(
            pick_victim([cand(1, 2, idle(2_000)), cand(2, 9, idle(9_000))], now),
            Some(2)
        );
    }

    #[test]
    fn admission_evicts_at_the_limits_and_refuses_when_nothing_can_go() {
        let a: IpAddr = "127.0.0.2".parse().unwrap();
        let b: IpAddr = "127.0.0.3".parse().unwrap();
        let mut r = Registry::default();
        for _ in 0..3 {
            assert!(matches!(
                r.admit(a, 1, 4, 3),
                Admission::Admit { evicted: None, .. }
            ));
        }
        // Peer a is at its limit: its own idle connection makes room (old enough).
        match r.admit(a, 1_000, 4, 3) {
            Admission::Admit { evicted, .. } => assert_eq!(evicted.unwrap().peer, a),
            Admission::Refuse => panic!("refused"),
        }
        assert_eq!(r.len(), 3);
        assert!(matches!(
            r.admit(b, 1_000, 4, 3),
            Admission::Admit { evicted: None, .. }
        ));
        // At the server's limit with only young connections: refused.
        assert_eq!(r.len(), 4);
        let young: Vec<u64> = r.conns.keys().copied().collect();
        for id in young {
            r.conns[&id].idle_since_ms.store(1_000, Relaxed);
        }
        assert!(matches!(r.admit(b, 1_100, 4, 3), Admission::Refuse));
        // Later, a's idle connections give way first (a holds the most).
        match r.admit(b, 2_000, 4, 3) {
            Admission::Admit { evicted, .. } => assert_eq!(evicted.unwrap().peer, a),
            Admission::Refuse => panic!("refused"),
        }
    }
}
