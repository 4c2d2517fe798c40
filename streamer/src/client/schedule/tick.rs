//! One tick of the scheduler: what to request, what to cancel and what to pin, by the
//! strategy in force, and the dispatch limits of the moment.

use tracks::PerspectiveCamera;

use super::{Actions, DispatchLimits, Piece, Scheduler, Strategy, Want, WantClass};
use crate::client::budget::{plan, LiveCount, Plan, PlanInput, PriorityMode};
use crate::client::http::{FetchKey, KeySet};
use crate::client::items::Part;
use crate::client::route::NetPos;

/// What one tick knows before the strategy's choice.
struct TickState<'a> {
    /// Position along the walker's track.
    s: f64,
    /// Each viewpoint's distance from the walker along the network.
    dist: Vec<f64>,
    camera: &'a PerspectiveCamera,
    /// Keys on the wire.
    running: &'a KeySet,
    /// Parts held per item at the start of the tick.
    have: Vec<usize>,
    /// Items with a part on the wire.
    downloading: Vec<bool>,
    /// The current segment's ACH list, and the background items of the two viewpoints around.
    seg_ach: Vec<(usize, f64)>,
    backgrounds: Vec<usize>,
    /// Whether a visible item lacks its coarsest level.
    holes: bool,
    /// Whether new requests wait after an unreachable server.
    paused: bool,
}

impl Scheduler {
    /// One tick at time `now`: position `s` along the walker's track ([`Scheduler::track`]),
    /// `camera`, the caller's live counts (merged with the CPU estimate) and the keys on the
    /// wire; returns what to request and cancel.
    pub fn tick(
        &mut self,
        now: f64,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
        running: &KeySet,
    ) -> Actions {
        let pos = NetPos {
            track: self.track,
            s,
        };
        self.tick_at(now, pos, camera, live, running)
    }

    /// [`Scheduler::tick`] at a position on the network: a walker on another track than the
    /// last tick's turned at a junction (its motion carries over).
    pub fn tick_at(
        &mut self,
        now: f64,
        pos: NetPos,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
        running: &KeySet,
    ) -> Actions {
        let s = if pos.s.is_finite() { pos.s } else { 0.0 };
        if pos.track != self.track && pos.track < self.net.tracks.len() {
            self.rebase(NetPos {
                track: pos.track,
                s,
            });
            self.prefetch_memo = None;
            self.cpu_counts = None;
        }
        self.now = self.now.max(now);
        if !self.changed.is_empty() {
            // Once for all the tables of the tick (castle 256's 37 tables, each followed by
            // a rebuild of the whole manifest and index, cost 0.66 s in one frame).
            self.tables_changed();
        }
        self.motion.observe(now, s);
        let dist = self.distances(s);
        self.cache.set_distances(dist.clone());
        self.live = self.count(s, camera, live);
        let have = self.held.clone();
        let mut downloading = vec![false; self.table.items.len()];
        for k in running {
            for &(i, _) in self.users.get(k).map_or(&[][..], |v| v.as_slice()) {
                downloading[i] = true;
            }
        }
        let seg_ach: Vec<(usize, f64)> = self
            .segment(s)
            .and_then(|k| self.table.segment_ach.get(k).cloned())
            .unwrap_or_default();
        let backgrounds: Vec<usize> = self
            .pair(s)
            .iter()
            .flat_map(|&(vi, _)| self.table.background_items(vi))
            .collect();
        let holes = self
            .live
            .iter()
            .any(|c| have[c.item] < self.infos[c.item].min_parts());
        let t = TickState {
            s,
            dist,
            camera,
            running,
            have,
            downloading,
            seg_ach,
            backgrounds,
            holes,
            paused: self.paused_until.is_some_and(|u| now < u),
        };
        let mut wants = Vec::new();
        let mut wanted_keys = KeySet::default();
        if !t.paused {
            wants.extend(self.urgent_tables(s, camera, t.holes, running, &t.dist));
        }
        let (tile_wants, mut background_table) = match self.config.strategy {
            Strategy::Naive => {
                self.pin(&[], &[], &t.have);
                if t.paused {
                    (Vec::new(), None)
                } else {
                    let background_table = self.background_table(running, &t.dist);
                    (
                        self.naive_wants(&t.have, running, &mut wanted_keys),
                        background_table,
                    )
                }
            }
            Strategy::Budget { mode, prefetch } => {
                self.budget_tick(&t, mode, prefetch, &mut wanted_keys)
            }
        };
        let naive = self.config.strategy == Strategy::Naive;
        if naive {
            wants.extend(background_table.take().into_iter().flatten());
        }
        wants.extend(tile_wants);
        wants.extend(background_table.into_iter().flatten());
        for w in &wants {
            for p in &w.pieces {
                wanted_keys.insert(p.key.clone());
            }
        }
        // Tables on the wire are always wanted; tile parts no longer wanted are cancelled
        // (naive wants everything).
        let cancel: Vec<FetchKey> = running
            .iter()
            .filter(|_| !naive)
            .filter(|k| {
                !wanted_keys.contains(*k)
                    && !self.table_keys.contains_key(*k)
                    && !self.ach_keys.contains_key(*k)
                    && self.users.contains_key(*k)
            })
            .cloned()
            .collect();
        self.cancelled.extend(cancel.iter().cloned());
        self.update_stats(s, &t.have, &t.seg_ach, &t.backgrounds);
        Actions {
            wants,
            limits: self.limits(t.holes),
            cancel,
        }
    }

    /// The budget strategies' part of a tick: the plan of what to hold, the pins, the keys it
    /// still wants (into `wanted_keys`), and its requests for tile parts and, when the view
    /// has no holes, a background table.
    fn budget_tick(
        &mut self,
        t: &TickState,
        mode: PriorityMode,
        prefetch: bool,
        wanted_keys: &mut KeySet,
    ) -> (Vec<Want>, Option<Vec<Want>>) {
        let (p, pre) = self.budget_plan(t, mode, prefetch);
        let pin: Vec<(usize, usize)> = p.targets.iter().map(|&(i, _, r)| (i, r)).collect();
        let coarse: Vec<usize> = t
            .seg_ach
            .iter()
            .map(|a| a.0)
            .chain(t.backgrounds.iter().copied())
            .collect();
        self.pin(&pin, &coarse, &t.have);
        // What the plan still wants (on the wire: not cancelled).
        for &(i, target, _) in &p.targets {
            for part in self.table.items[i].parts.iter().take(target) {
                wanted_keys.insert(part.key.clone());
            }
        }
        for &(i, _) in &pre {
            let parts = &self.table.items[i].parts;
            let end = self
                .prefetch_need
                .get(&i)
                .map_or(parts.len(), |&l| self.infos[i].parts_for_level(l));
            let end = self.capped(i, end);
            for part in &parts[..end] {
                wanted_keys.insert(part.key.clone());
            }
        }
        if t.paused {
            return (Vec::new(), None);
        }
        let tile_wants = self.plan_wants(&p, t.running);
        let around = self.pair(t.s).iter().all(|w| self.table.has_viewpoint(w.0));
        let background_table = if !t.holes && around {
            self.background_table(t.running, &t.dist)
        } else {
            None
        };
        (tile_wants, background_table)
    }

    /// The PTM budget plan of a tick in priority `mode` (with the prefetch list of the
    /// predicted next segment when `prefetch`), and that list; keeps the resident figures of
    /// [`ViewStats`].
    fn budget_plan(
        &mut self,
        t: &TickState,
        mode: PriorityMode,
        prefetch: bool,
    ) -> (Plan, Vec<(usize, f64)>) {
        let (ach, wide) = self.frustum_ach(t.camera, &t.seg_ach, &t.backgrounds);
        let next = if prefetch {
            self.next_segments(t.s, t.camera)
        } else {
            Vec::new()
        };
        let pre = self.prefetch_lists(t.camera, &next, mode);
        let counts = if matches!(mode, PriorityMode::Ach) {
            Vec::new()
        } else {
            self.live.clone()
        };
        let (memory, dt_max) = self.budget.current(self.motion.still_s());
        let still = self.motion.still_s() >= self.budget.t_static_s;
        let mut seg_all = t.seg_ach.clone();
        let top = t.seg_ach.iter().map(|a| a.1).fold(0.0f64, f64::max);
        let top = if top > 0.0 { top } else { 1.0 };
        seg_all.extend(t.backgrounds.iter().map(|&b| (b, top)));
        let p = plan(&PlanInput {
            items: &self.plan_infos,
            have: &t.have,
            downloading: &t.downloading,
            // Combined: the ACH list broadens (coarsest levels ready for a turn of the head)
            // within the widened frustum while moving, to the whole segment once still (the
            // static budgets apply).
            ach: match mode {
                PriorityMode::Combined { .. } if still => &seg_all,
                PriorityMode::Combined { .. } => &wide,
                _ => &ach,
            },
            live: &counts,
            prefetch: &pre,
            mode,
            memory_bytes: memory,
            dt_max_s: dt_max,
            link: &self.link,
        });
        self.stats.max_resident_bytes = self.stats.max_resident_bytes.max(p.resident_bytes);
        self.stats.over_budget |= p.resident_bytes > memory;
        (p, pre)
    }

    /// The plan's requests as wants: the parts neither on the wire nor asked for by an
    /// earlier request of the plan, prefetched ones only as fine as the predicted view needs.
    fn plan_wants(&self, p: &Plan, running: &KeySet) -> Vec<Want> {
        let mut tile_wants = Vec::new();
        let mut seen = KeySet::default();
        for r in &p.requests {
            let parts = &self.table.items[r.item].parts;
            let mut end = (r.part + r.parts.max(1)).min(parts.len());
            if r.priority < 1.0 {
                if let Some(&l) = self.prefetch_need.get(&r.item) {
                    end = end.min(self.infos[r.item].parts_for_level(l));
                }
            }
            let class = if r.priority < 1.0 {
                WantClass::Prefetch
            } else {
                WantClass::Current
            };
            // A part that failed waits for its retry time (or was given up): the parts after
            // it are of no use without it.
            let todo: Vec<&Part> = parts[r.part..end.max(r.part)]
                .iter()
                .take_while(|p| self.part_ready(&p.key))
                .filter(|p| !running.contains(&p.key) && seen.insert(p.key.clone()))
                .collect();
            push_wants(&mut tile_wants, class, &todo);
        }
        tile_wants
    }

    /// `end` (a count of parts of item `i`) within the level cap.
    fn capped(&self, i: usize, end: usize) -> usize {
        end.min(self.plan_infos[i].parts())
    }

    /// The dispatch limits of the moment (see [`DispatchLimits`]): requests of about one
    /// latency's worth at the estimated bandwidth, two on the link.
    fn limits(&self, holes: bool) -> DispatchLimits {
        let (bps, latency) = self.link.get();
        let bdp = bps / 8.0 * latency.max(0.05);
        let floor = self.config.min_request_bytes.max(1);
        let request_bytes = if bdp.is_finite() && bdp > 0.0 {
            (bdp as u64).clamp(floor, self.config.max_request_bytes.max(floor))
        } else {
            self.config.max_request_bytes.max(floor)
        };
        let naive = self.config.strategy == Strategy::Naive;
        DispatchLimits {
            max_in_flight: self.config.max_in_flight.max(1),
            max_pieces: self.config.max_pieces.max(1),
            request_bytes,
            in_flight_bytes: if naive {
                u64::MAX
            } else {
                request_bytes.saturating_mul(2)
            },
            prefetch_slots: if holes {
                0
            } else {
                (self.config.max_in_flight / 3).max(1)
            },
            one_object: !self.bundles,
        }
    }

    /// Whole tiles in manifest order (by viewpoint, its tiles, then its background) that
    /// are neither held nor on the wire, as many as the request slots can carry.
    fn naive_wants(&self, have: &[usize], running: &KeySet, wanted: &mut KeySet) -> Vec<Want> {
        let items = &self.table.items;
        let mut order: Vec<usize> = (0..items.len())
            .filter(|&i| have[i] < items[i].parts.len())
            .filter(|&i| !items[i].parts.iter().any(|p| running.contains(&p.key)))
            .filter(|&i| items[i].parts.iter().all(|p| self.part_ready(&p.key)))
            .collect();
        order.sort_by_key(|&i| (items[i].viewpoint, items[i].tile.is_none(), i));
        let limit = self.config.max_in_flight.max(1) * self.config.max_pieces.max(1);
        let mut out = Vec::new();
        for i in order.into_iter().take(limit) {
            let parts: Vec<&Part> = items[i].parts.iter().collect();
            for p in &parts {
                wanted.insert(p.key.clone());
            }
            push_wants(&mut out, WantClass::Current, &parts);
        }
        out
    }

    /// Pins what the plan keeps resident (`resident`: item, parts) and the coarsest levels
    /// of `coarse`; a key is pinned once however many items use it, and only the keys that
    /// join or leave the set touch the cache.
    fn pin(&mut self, resident: &[(usize, usize)], coarse: &[usize], have: &[usize]) {
        let mut spec: Vec<(usize, usize)> = resident
            .iter()
            .copied()
            .chain(coarse.iter().map(|&i| (i, self.infos[i].min_parts())))
            .map(|(i, n)| (i, n.min(have[i])))
            .filter(|&(_, n)| n > 0)
            .collect();
        spec.sort_unstable_by_key(|&(i, n)| (i, std::cmp::Reverse(n)));
        spec.dedup_by_key(|a| a.0);
        if spec == self.pin_spec.0 && self.pin_spec.1 {
            return;
        }
        let mut pins = KeySet::default();
        for &(i, n) in &spec {
            for part in &self.table.items[i].parts[..n] {
                pins.insert(part.key.clone());
            }
        }
        for k in self.pinned.iter().filter(|k| !pins.contains(*k)) {
            self.stats.pinned_bytes = self
                .stats
                .pinned_bytes
                .saturating_sub(self.cache.get(k).map_or(0, |b| b.len() as u64));
            self.cache.release(k);
        }
        let cache = &mut self.cache;
        let (mut added, mut complete) = (0, true);
        pins.retain(|k| {
            if self.pinned.contains(k) {
                return true;
            }
            let held = cache.acquire(k);
            if held {
                added += cache.get(k).map_or(0, |b| b.len() as u64);
            }
            complete &= held;
            held
        });
        self.stats.pinned_bytes += added;
        self.pinned = pins;
        self.pin_spec = (spec, complete);
    }
}

/// `parts` (of one item, in order) as wants of `class`, one per run of parts in one object.
fn push_wants(out: &mut Vec<Want>, class: WantClass, parts: &[&Part]) {
    let mut i = 0;
    while i < parts.len() {
        let object = &parts[i].key.object;
        let mut j = i + 1;
        while j < parts.len() && parts[j].key.object == *object {
            j += 1;
        }
        out.push(Want {
            class,
            pieces: parts[i..j]
                .iter()
                .map(|p| Piece {
                    key: p.key.clone(),
                    hash: p.hash.clone(),
                    len: p.bytes,
                })
                .collect(),
        });
        i = j;
    }
}
