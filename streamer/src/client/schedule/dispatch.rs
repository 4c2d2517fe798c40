//! When the requests the scheduler wants go out, and what each carries: the one rule both
//! executors follow (the viewer's worker pool on the wall clock, the walk simulator on its
//! virtual link), so they send the same requests in the same order.
//!
//! The scheduler hands over, at every tick, its [`Want`]s in priority order and the
//! [`DispatchLimits`] of the moment; they replace whatever had not gone out yet
//! ([`Dispatcher::replace`]). Whenever a request slot is free the executor asks
//! [`Dispatcher::pop`] for the next [`Batch`] and reports it done with
//! [`Dispatcher::finish`]. A batch is one request: a table (alone), or the next wants in
//! order — each the parts of one item in one object — up to `max_pieces` pieces and about
//! one latency's worth of bytes (`request_bytes`; a batch of prefetch alone a quarter of
//! that), at most `in_flight_bytes` on the link in all, prefetch-only batches on at most
//! `prefetch_slots` slots, background tables one at a time. A server without `/bundle`
//! answers one object per request, so then a batch takes only wants of its first want's
//! object (looking a little further down the queue for them, order kept).

use std::collections::VecDeque;

use crate::client::http::{FetchKey, KeySet};

/// One piece to fetch: a key (an object or a byte range of one), the hash its bytes must
/// have and its exact length.
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub key: FetchKey,
    pub hash: String,
    pub len: u64,
}

/// What a want is for, from first to last in the queue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WantClass {
    /// A table (or ACH object) of the viewpoints around the walker: alone, before any tile.
    Table,
    /// What the current view needs (and, in the combined mode, what its segment broadens to).
    Current,
    /// The predicted next segment's tiles.
    Prefetch,
    /// Another viewpoint's table, nearest first: alone, one at a time.
    BackgroundTable,
}

/// Pieces that travel together (one item's parts in one object, or one table object).
#[derive(Clone, Debug, PartialEq)]
pub struct Want {
    pub class: WantClass,
    pub pieces: Vec<Piece>,
}

impl Want {
    pub fn bytes(&self) -> u64 {
        self.pieces.iter().map(|p| p.len).sum()
    }

    fn object(&self) -> Option<&str> {
        self.pieces.first().map(|p| &*p.key.object)
    }
}

/// Limits in force for the next requests (set at every tick from the link estimate and
/// what the view lacks).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DispatchLimits {
    /// Requests in flight at most.
    pub max_in_flight: usize,
    /// Pieces one request carries at most.
    pub max_pieces: usize,
    /// Bytes one request carries at most (its first want always goes).
    pub request_bytes: u64,
    /// Bytes in flight at most before another tile request goes (tables go regardless).
    pub in_flight_bytes: u64,
    /// Requests carrying only prefetch at most (0 while the view has holes).
    pub prefetch_slots: usize,
    /// One object per request (a server without `/bundle`).
    pub one_object: bool,
}

impl Default for DispatchLimits {
    fn default() -> Self {
        DispatchLimits {
            max_in_flight: 6,
            max_pieces: 64,
            request_bytes: 16 << 10,
            in_flight_bytes: 32 << 10,
            prefetch_slots: 2,
            one_object: false,
        }
    }
}

/// One request to send.
#[derive(Clone, Debug, PartialEq)]
pub struct Batch {
    /// Distinct per dispatcher, from 1, in the order batches were popped.
    pub id: u64,
    pub class: WantClass,
    pub pieces: Vec<Piece>,
}

impl Batch {
    pub fn bytes(&self) -> u64 {
        self.pieces.iter().map(|p| p.len).sum()
    }
}

struct Running {
    id: u64,
    class: WantClass,
    bytes: u64,
    keys: Vec<FetchKey>,
}

/// The queue of wants and the requests in flight (see the module docs).
pub struct Dispatcher {
    queue: VecDeque<Want>,
    limits: DispatchLimits,
    running: Vec<Running>,
    next_id: u64,
}

/// How far down the queue a one-object request looks for more of its object's wants.
const LOOKAHEAD: usize = 256;

impl Default for Dispatcher {
    fn default() -> Self {
        Dispatcher::new()
    }
}

impl Dispatcher {
    pub fn new() -> Dispatcher {
        Dispatcher {
            queue: VecDeque::new(),
            limits: DispatchLimits::default(),
            running: Vec::new(),
            next_id: 1,
        }
    }

    /// The scheduler's new wants (priority order) and limits replace what had not gone out;
    /// pieces already in flight are left out of them.
    pub fn replace(&mut self, wants: Vec<Want>, limits: DispatchLimits) {
        let running: KeySet = self.running_keys();
        self.queue = wants
            .into_iter()
            .filter_map(|mut w| {
                w.pieces.retain(|p| !running.contains(&p.key));
                (!w.pieces.is_empty()).then_some(w)
            })
            .collect();
        self.limits = limits;
    }

    /// Keys of the requests in flight.
    pub fn running_keys(&self) -> KeySet {
        self.running
            .iter()
            .flat_map(|r| r.keys.iter().cloned())
            .collect()
    }

    /// Requests in flight.
    pub fn running(&self) -> usize {
        self.running.len()
    }

    /// Wants not yet sent.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// Nothing queued and nothing in flight.
    pub fn idle(&self) -> bool {
        self.queue.is_empty() && self.running.is_empty()
    }

    /// The request finished (arrived, failed or abandoned): its slot is free.
    pub fn finish(&mut self, id: u64) {
        self.running.retain(|r| r.id != id);
    }

    /// Where the next request would start, if the limits allow one now.
    fn next_index(&self) -> Option<usize> {
        let l = self.limits;
        if self.running.len() >= l.max_in_flight.max(1) {
            return None;
        }
        let background_busy = self
            .running
            .iter()
            .any(|r| r.class == WantClass::BackgroundTable);
        let in_flight: u64 = self.running.iter().map(|r| r.bytes).sum();
        let prefetch_busy = self
            .running
            .iter()
            .filter(|r| r.class == WantClass::Prefetch)
            .count();
        let mut tiles_blocked = false;
        for (i, w) in self.queue.iter().enumerate() {
            let ok = match w.class {
                WantClass::Table => true,
                WantClass::BackgroundTable => !background_busy,
                WantClass::Current | WantClass::Prefetch if tiles_blocked => false,
                WantClass::Current | WantClass::Prefetch => {
                    let ok = in_flight < l.in_flight_bytes
                        && (w.class == WantClass::Current || prefetch_busy < l.prefetch_slots);
                    tiles_blocked = !ok;
                    ok
                }
            };
            if ok {
                return Some(i);
            }
        }
        None
    }

    /// Whether nothing is in flight and nothing may go now (what is queued waits for other
    /// limits, e.g. no prefetch while the view has holes).
    pub fn settled(&self) -> bool {
        self.running.is_empty() && self.next_index().is_none()
    }

    /// The next request to send now, if the limits allow one (see the module docs): the
    /// first want in queue order that may go — tables always, a background table when no
    /// other is on its way, tile wants (in their order, none skipped) while the bytes in
    /// flight and the prefetch slots allow.
    pub fn pop(&mut self) -> Option<Batch> {
        let l = self.limits;
        let at = self.next_index()?;
        let class = self.queue[at].class;
        let pieces = match class {
            WantClass::Table | WantClass::BackgroundTable => self.queue.remove(at)?.pieces,
            WantClass::Current | WantClass::Prefetch => {
                let cap = if class == WantClass::Prefetch {
                    l.request_bytes / 4
                } else {
                    l.request_bytes
                };
                self.take_tiles(at, cap, l.max_pieces.max(1), l.one_object)
            }
        };
        if pieces.is_empty() {
            return None;
        }
        let id = self.next_id;
        self.next_id += 1;
        let batch = Batch { id, class, pieces };
        self.running.push(Running {
            id,
            class,
            bytes: batch.bytes(),
            keys: batch.pieces.iter().map(|p| p.key.clone()).collect(),
        });
        Some(batch)
    }

    /// The pieces of the next tile request: the want at `at`, then the following tile wants in
    /// order while they fit `cap` bytes and `max_pieces` pieces; with `one_object`, only
    /// wants of the head's object, looked for within [`LOOKAHEAD`] wants (the others keep
    /// their places). A table want ends the batch.
    fn take_tiles(
        &mut self,
        at: usize,
        cap: u64,
        max_pieces: usize,
        one_object: bool,
    ) -> Vec<Piece> {
        let Some(head) = self.queue.remove(at) else {
            return Vec::new();
        };
        let object = head.object().map(str::to_string);
        let mut bytes = head.bytes();
        let mut pieces = head.pieces;
        let mut i = at;
        let mut looked = 0;
        while i < self.queue.len() && looked < LOOKAHEAD {
            let w = &self.queue[i];
            if !matches!(w.class, WantClass::Current | WantClass::Prefetch) {
                break;
            }
            let fits = pieces.len() + w.pieces.len() <= max_pieces
                && bytes.saturating_add(w.bytes()) <= cap;
            if one_object && w.object() != object.as_deref() {
                i += 1;
                looked += 1;
                continue;
            }
            if !fits {
                break;
            }
            if let Some(w) = self.queue.remove(i) {
                bytes = bytes.saturating_add(w.bytes());
                pieces.extend(w.pieces);
            }
            looked += 1;
        }
        pieces
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn piece(object: u32, offset: u64, len: u64) -> Piece {
        Piece {
            key: FetchKey {
                object: format!("{object:064x}").into(),
                range: Some((offset, len)),
            },
            hash: "00000000".into(),
            len,
        }
    }

    fn want(class: WantClass, object: u32, offset: u64, len: u64) -> Want {
        Want {
            class,
            pieces: vec![piece(object, offset, len)],
        }
    }

    fn limits() -> DispatchLimits {
        DispatchLimits {
            max_in_flight: 3,
            max_pieces: 4,
            request_bytes: 1000,
            in_flight_bytes: 2500,
            prefetch_slots: 1,
            one_object: false,
        }
    }

    #[test]
    fn tables_go_alone_first_and_tiles_fill_a_request_up_to_its_limits() {
        let mut d = Dispatcher::new();
        let mut wants = vec![Want {
            class: WantClass::Table,
            pieces: vec![piece(9, 0, 500)],
        }];
        wants.extend((0..6).map(|k| want(WantClass::Current, 1, k * 300, 300)));
        let tight = DispatchLimits {
            in_flight_bytes: 1000,
            ..limits()
        };
        d.replace(wants, tight);
        let t = d.pop().unwrap();
        assert_eq!((t.id, t.class, t.pieces.len()), (1, WantClass::Table, 1));
        // 300 + 300 + 300 fit 1000 bytes, a fourth would not.
        let b = d.pop().unwrap();
        assert_eq!(
            (b.class, b.pieces.len(), b.bytes()),
            (WantClass::Current, 3, 900)
        );
        // In flight: 500 + 900 bytes, above 1000: nothing more until one finishes.
        assert!(d.pop().is_none());
        d.finish(t.id);
        let c = d.pop().unwrap();
        assert_eq!(c.pieces.len(), 3);
        assert!(d.pop().is_none() && d.queued() == 0);
        d.finish(b.id);
        d.finish(c.id);
        assert!(d.idle());
    }

    #[test]
    fn a_background_table_waits_for_the_one_on_its_way_without_holding_up_tiles() {
        let mut d = Dispatcher::new();
        let bg = |o| Want {
            class: WantClass::BackgroundTable,
            pieces: vec![piece(o, 0, 100)],
        };
        d.replace(
            vec![bg(7), bg(8), want(WantClass::Current, 1, 0, 100)],
            limits(),
        );
        assert_eq!(d.pop().unwrap().class, WantClass::BackgroundTable);
        assert_eq!(d.pop().unwrap().class, WantClass::Current);
        assert!(d.pop().is_none(), "one background table at a time");
    }

    #[test]
    fn prefetch_waits_for_its_slots_and_goes_in_small_requests() {
        let mut d = Dispatcher::new();
        let wants = (0..4)
            .map(|k| want(WantClass::Prefetch, 1, k * 200, 200))
            .collect();
        d.replace(wants, limits());
        let a = d.pop().unwrap();
        // A quarter of 1000 bytes: one 200-byte want.
        assert_eq!((a.class, a.pieces.len()), (WantClass::Prefetch, 1));
        assert!(d.pop().is_none(), "one prefetch slot");
        d.finish(a.id);
        assert!(d.pop().is_some());
        // No prefetch at all while the view has holes.
        let mut d = Dispatcher::new();
        d.replace(
            vec![want(WantClass::Prefetch, 1, 0, 10)],
            DispatchLimits {
                prefetch_slots: 0,
                ..limits()
            },
        );
        assert!(d.pop().is_none());
    }

    #[test]
    fn one_object_requests_gather_their_object_and_leave_the_rest_in_order() {
        let mut d = Dispatcher::new();
        let wants = vec![
            want(WantClass::Current, 1, 0, 100),
            want(WantClass::Current, 2, 0, 100),
            want(WantClass::Current, 1, 100, 100),
            want(WantClass::Current, 2, 100, 100),
        ];
        d.replace(
            wants,
            DispatchLimits {
                one_object: true,
                ..limits()
            },
        );
        let a = d.pop().unwrap();
        assert!(a
            .pieces
            .iter()
            .all(|p| p.key.object == a.pieces[0].key.object));
        assert_eq!(a.pieces.len(), 2);
        let b = d.pop().unwrap();
        assert_eq!(b.pieces.len(), 2);
        assert_ne!(a.pieces[0].key.object, b.pieces[0].key.object);
    }

    #[test]
    fn wants_already_in_flight_are_not_sent_twice() {
        let mut d = Dispatcher::new();
        let w = vec![want(WantClass::Current, 1, 0, 100)];
        d.replace(w.clone(), limits());
        let a = d.pop().unwrap();
        d.replace(w, limits());
        assert!(d.pop().is_none() && d.queued() == 0);
        d.finish(a.id);
        assert!(d.idle());
    }
}
