//! The RAM cache: downloaded, checked bytes under a byte budget.
//!
//! Entries are keyed by [`FetchKey`] (content-addressed, so a group shared by several tiles
//! is stored once). Each entry remembers the viewpoints (ids) that use it and counts its
//! current users (`refs`). When room is needed, entries nobody uses are evicted farthest-first
//! from the walker, by the distance along the network the caller gives per viewpoint
//! ([`Cache::set_distances`]: the city paper's eviction by adjacency depth, on a graph of
//! tracks); entries in use are never evicted, and an insert that cannot fit is refused, so the
//! budget is never exceeded.

use bytes::Bytes;

use super::http::{FetchKey, KeyMap};

#[derive(Debug)]
struct Entry {
    data: Bytes,
    /// The viewpoints whose tiles use this entry.
    viewpoints: Vec<usize>,
    refs: u32,
}

impl Entry {
    fn distance(&self, distances: &[f64]) -> f64 {
        self.viewpoints
            .iter()
            .map(|&v| distances.get(v).copied().unwrap_or(f64::INFINITY))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Why an insert was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CacheError {
    #[error("{need} bytes do not fit: budget {budget}, {pinned} bytes in use")]
    NoRoom { need: u64, budget: u64, pinned: u64 },
}

/// Byte-budgeted cache with distance eviction and reference counts.
#[derive(Debug)]
pub struct Cache {
    budget: u64,
    used: u64,
    /// Per viewpoint, its distance from the walker.
    distances: Vec<f64>,
    entries: KeyMap<Entry>,
    evictions: u64,
    /// Keys evicted since the last [`Cache::take_evicted`], when recording.
    evicted: Option<Vec<FetchKey>>,
    /// Moves whenever a key joins or leaves ([`Cache::changes`]).
    changes: u64,
}

impl Cache {
    pub fn new(budget_bytes: u64) -> Cache {
        Cache {
            budget: budget_bytes,
            used: 0,
            distances: Vec::new(),
            entries: KeyMap::default(),
            evictions: 0,
            evicted: None,
            changes: 0,
        }
    }

    /// A count that moves whenever a key joins or leaves the cache (inserted, evicted or
    /// removed): what was looked up under the same count still holds.
    pub fn changes(&self) -> u64 {
        self.changes
    }

    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Bytes held (always ≤ the budget).
    pub fn used(&self) -> u64 {
        self.used
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn evictions(&self) -> u64 {
        self.evictions
    }

    /// Per viewpoint id, its distance from the walker (metres along the network), which
    /// ranks evictions; a viewpoint without one counts as infinitely far.
    pub fn set_distances(&mut self, distances: Vec<f64>) {
        self.distances = distances;
    }

    pub fn contains(&self, key: &FetchKey) -> bool {
        self.entries.contains_key(key)
    }

    pub fn get(&self, key: &FetchKey) -> Option<&Bytes> {
        self.entries.get(key).map(|e| &e.data)
    }

    /// Insert checked bytes used by viewpoint `viewpoint`. A key already present only gains
    /// the viewpoint. Evicts unused entries farthest from the walker until the bytes fit;
    /// refuses when they cannot.
    pub fn insert(
        &mut self,
        key: FetchKey,
        data: Bytes,
        viewpoint: usize,
    ) -> Result<(), CacheError> {
        if let Some(e) = self.entries.get_mut(&key) {
            if !e.viewpoints.contains(&viewpoint) {
                e.viewpoints.push(viewpoint);
            }
            return Ok(());
        }
        let need = data.len() as u64;
        self.make_room(need)?;
        self.used += need;
        self.changes += 1;
        self.entries.insert(
            key,
            Entry {
                data,
                viewpoints: vec![viewpoint],
                refs: 0,
            },
        );
        Ok(())
    }

    fn make_room(&mut self, need: u64) -> Result<(), CacheError> {
        if self.used + need <= self.budget {
            return Ok(());
        }
        let pinned = self.pinned_bytes();
        if pinned + need > self.budget {
            return Err(CacheError::NoRoom {
                need,
                budget: self.budget,
                pinned,
            });
        }
        let distances = &self.distances;
        let mut victims: Vec<(f64, FetchKey)> = self
            .entries
            .iter()
            .filter(|(_, e)| e.refs == 0)
            .map(|(k, e)| (e.distance(distances), k.clone()))
            .collect();
        // Farthest first; ties broken by key so eviction is deterministic.
        victims.sort_by(|a, b| b.0.total_cmp(&a.0).then_with(|| a.1.cmp(&b.1)));
        for (_, k) in victims {
            if self.used + need <= self.budget {
                break;
            }
            if let Some(e) = self.entries.remove(&k) {
                self.used -= e.data.len() as u64;
                self.evictions += 1;
                self.changes += 1;
                if let Some(log) = &mut self.evicted {
                    log.push(k);
                }
            }
        }
        Ok(())
    }

    /// One more user of `key` (it will not be evicted while used). `false` if absent.
    /// From now on, remember the keys evicted to make room, for [`Cache::take_evicted`]
    /// (a caller that keeps its own view of what is held).
    pub fn record_evictions(&mut self) {
        self.evicted.get_or_insert_with(Vec::new);
    }

    /// The keys evicted since the last call (empty unless recording).
    pub fn take_evicted(&mut self) -> Vec<FetchKey> {
        self.evicted
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Bytes of the entries in use (at least one user).
    pub fn pinned_bytes(&self) -> u64 {
        self.entries
            .values()
            .filter(|e| e.refs > 0)
            .map(|e| e.data.len() as u64)
            .sum()
    }

    pub fn acquire(&mut self, key: &FetchKey) -> bool {
        match self.entries.get_mut(key) {
            Some(e) => {
                e.refs += 1;
                true
            }
            None => false,
        }
    }

    /// One user fewer; the entry stays cached (evictable) when the count reaches zero.
    pub fn release(&mut self, key: &FetchKey) {
        if let Some(e) = self.entries.get_mut(key) {
            e.refs = e.refs.saturating_sub(1);
        }
    }

    pub fn refs(&self, key: &FetchKey) -> u32 {
        self.entries.get(key).map_or(0, |e| e.refs)
    }

    /// Drop an entry regardless of users (e.g. the server's database changed).
    pub fn remove(&mut self, key: &FetchKey) -> Option<Bytes> {
        let e = self.entries.remove(key)?;
        self.used -= e.data.len() as u64;
        self.changes += 1;
        Some(e.data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn key(i: u32) -> FetchKey {
        FetchKey {
            object: format!("{i:064x}").into(),
            range: None,
        }
    }

    #[test]
    fn evicts_farthest_from_the_position_first() {
        let mut c = Cache::new(300);
        c.insert(key(1), Bytes::from(vec![0; 100]), 0).unwrap();
        c.insert(key(2), Bytes::from(vec![0; 100]), 1).unwrap();
        c.insert(key(3), Bytes::from(vec![0; 100]), 2).unwrap();
        // Viewpoints at 0, 10, 20 and 18 m along a track, the walker at 18 m.
        c.set_distances(vec![18.0, 8.0, 2.0, 0.0]);
        c.insert(key(4), Bytes::from(vec![0; 100]), 3).unwrap();
        assert!(!c.contains(&key(1)), "the entry farthest behind goes");
        assert!(c.contains(&key(2)) && c.contains(&key(3)) && c.contains(&key(4)));
        assert_eq!(c.used(), 300);
    }

    #[test]
    fn evicted_keys_are_reported_once_when_recording() {
        let fill = |c: &mut Cache| {
            for i in 1..=4 {
                c.insert(key(i), Bytes::from(vec![0; 100]), i as usize)
                    .unwrap();
            }
        };
        let mut quiet = Cache::new(200);
        fill(&mut quiet);
        assert!(quiet.take_evicted().is_empty(), "not recording");
        let mut c = Cache::new(200);
        c.record_evictions();
        c.set_distances((0..5).map(|i| (4 - i) as f64).collect());
        fill(&mut c);
        assert_eq!(c.take_evicted(), vec![key(1), key(2)]);
        assert!(c.take_evicted().is_empty());
        c.remove(&key(3));
        assert!(c.take_evicted().is_empty(), "removals are the caller's own");
    }

    #[test]
    fn entries_in_use_are_never_evicted_and_overflow_is_refused() {
        let mut c = Cache::new(200);
        c.insert(key(1), Bytes::from(vec![0; 100]), 0).unwrap();
        c.insert(key(2), Bytes::from(vec![0; 100]), 0).unwrap();
        assert!(c.acquire(&key(1)));
        assert!(c.acquire(&key(2)));
        let err = c.insert(key(3), Bytes::from(vec![0; 50]), 0).unwrap_err();
        assert!(matches!(err, CacheError::NoRoom { pinned: 200, .. }));
        c.release(&key(2));
        c.insert(key(3), Bytes::from(vec![0; 50]), 0).unwrap();
        assert!(c.contains(&key(1)) && !c.contains(&key(2)));
    }

    #[test]
    fn shared_entries_count_their_users() {
        let mut c = Cache::new(100);
        c.insert(key(1), Bytes::from(vec![0; 60]), 0).unwrap();
        // A second tile at another viewpoint uses the same bytes: stored once.
        c.insert(key(1), Bytes::from(vec![0; 60]), 5).unwrap();
        assert_eq!(c.used(), 60);
        c.acquire(&key(1));
        c.acquire(&key(1));
        c.release(&key(1));
        assert_eq!(c.refs(&key(1)), 1);
        assert!(c.insert(key(2), Bytes::from(vec![0; 60]), 0).is_err());
        c.release(&key(1));
        c.insert(key(2), Bytes::from(vec![0; 60]), 0).unwrap();
    }

    proptest! {
        #[test]
        fn never_exceeds_the_budget(ops in proptest::collection::vec((0u32..20, 1usize..120, 0usize..50, 0u8..4), 1..200)) {
            let mut c = Cache::new(500);
            for (k, len, v, op) in ops {
                match op {
                    0 | 1 => { let _ = c.insert(key(k), Bytes::from(vec![1; len]), v); }
                    2 => { c.acquire(&key(k)); }
                    _ => {
                        c.release(&key(k));
                        c.set_distances((0..50).map(|i| (i as f64 - v as f64).abs()).collect());
                    }
                }
                prop_assert!(c.used() <= c.budget());
                let sum: u64 = (0..20).filter_map(|i| c.get(&key(i))).map(|b| b.len() as u64).sum();
                prop_assert_eq!(sum, c.used());
            }
        }
    }
}
