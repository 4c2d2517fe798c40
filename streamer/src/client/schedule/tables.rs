//! Viewpoint tables in the scheduler: which to ask for when, and what happens when they
//! arrive (decoded, their items added, their viewpoints' entries in the manifest and the
//! visibility index updated once per tick's worth of tables).

use bytes::Bytes;

use super::{whole, whole_piece, Scheduler, Want, WantClass};
use crate::client::http::KeySet;
use crate::client::schedule::Arrival;
use db::split::{decode_ach, decode_table, update_viewpoint};

impl Scheduler {
    /// The objects to fetch for viewpoint `v` that are neither in nor on the wire: its table,
    /// and its ACH object when the strategy ranks tiles by ACH.
    fn table_wants(&self, v: usize, class: WantClass, running: &KeySet) -> Vec<Want> {
        let Some(vp) = self.top.viewpoints.get(v) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        // One that failed waits for its retry time, or was given up.
        let ready = |hash: &str| self.table_failures.may_request(&whole(hash), self.now);
        if self.tables[v].is_none()
            && !running.contains(&whole(&vp.table.hash))
            && ready(&vp.table.hash)
        {
            out.push(Want {
                class,
                pieces: vec![whole_piece(&vp.table.hash, vp.table.size)],
            });
        }
        if let Some(a) = vp.ach.as_ref().filter(|_| self.config.strategy.uses_ach()) {
            if self.achs[v].is_none() && !running.contains(&whole(&a.hash)) && ready(&a.hash) {
                out.push(Want {
                    class,
                    pieces: vec![whole_piece(&a.hash, a.size)],
                });
            }
        }
        out
    }

    /// Whether viewpoint `v` needs nothing more (its table in or on the wire).
    fn table_requested(&self, v: usize, running: &KeySet) -> bool {
        self.tables[v].is_some()
            || self
                .top
                .viewpoints
                .get(v)
                .is_some_and(|vp| running.contains(&whole(&vp.table.hash)))
    }

    /// The tables the walker needs now, nearest first, one request each: the current
    /// segment's two viewpoints; with prefetch, those of the segments it may enter next (every
    /// way out of a junction ahead) once the view has no holes; and, whatever the strategy,
    /// the viewpoint after the current segment once the walker would reach it before its table
    /// (two transfers and a round trip, to be safe) could arrive — at speed there are always
    /// holes, and a table asked for on arrival stalls every segment crossing. `dist`: each
    /// viewpoint's distance along the network.
    pub(super) fn urgent_tables(
        &self,
        s: f64,
        camera: &tracks::PerspectiveCamera,
        holes: bool,
        running: &KeySet,
        dist: &[f64],
    ) -> Vec<Want> {
        let net = &self.net;
        let n = self.tables.len();
        let mut want: Vec<usize> = self.pair(s).into_iter().map(|w| w.0).collect();
        let holes = holes || want.iter().any(|&v| v < n && !self.table.has_viewpoint(v));
        let next = self.next_segments(s, camera);
        if self.config.strategy.prefetches() && !holes {
            for &(e, _) in &next {
                let sg = net.segments[e];
                want.extend([sg.from, sg.to]);
            }
        }
        if let (Some(seg), Some(v)) = (self.segment(s), self.motion.velocity()) {
            // The viewpoints at the far ends of the segments after the current one in the
            // direction of travel (past a junction: of every way out).
            let sg = net.segments[seg];
            let (end, end_s) = if v > 0.0 {
                (sg.to, sg.s1)
            } else {
                (sg.from, sg.s0)
            };
            let far: Vec<usize> = net
                .incident(end)
                .iter()
                .filter(|&&e| e != seg)
                .map(|&e| {
                    let o = net.segments[e];
                    if o.from == end {
                        o.to
                    } else {
                        o.from
                    }
                })
                .collect();
            let (bps, latency) = self.link.get();
            let reach_s = (end_s - s).abs() / v.abs().max(1e-9);
            for next in far {
                if next >= n || self.table_requested(next, running) {
                    continue;
                }
                let bytes = self
                    .table_wants(next, WantClass::Table, running)
                    .iter()
                    .map(Want::bytes)
                    .sum::<u64>() as f64;
                let fetch_s = latency + 2.0 * bytes * 8.0 / bps.max(1.0);
                // With holes in the view only in the last quarter second (the link estimate
                // of the first seconds is too rough to time it closer).
                if (!holes && reach_s < 2.0 * fetch_s) || reach_s < 0.25 {
                    want.push(next);
                }
            }
        }
        want.retain(|&v| v < n);
        let d = |v: usize| dist.get(v).copied().unwrap_or(f64::INFINITY);
        want.sort_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)));
        want.dedup();
        want.iter()
            .flat_map(|&v| self.table_wants(v, WantClass::Table, running))
            .collect()
    }

    /// The nearest viewpoint (along the network) whose table is neither in nor on the wire,
    /// within [`SchedulerConfig::background_table_radius_m`](super::SchedulerConfig), as
    /// background wants (one goes at a time).
    pub(super) fn background_table(&self, running: &KeySet, dist: &[f64]) -> Option<Vec<Want>> {
        let d = |v: usize| dist.get(v).copied().unwrap_or(f64::INFINITY);
        let radius = self.config.background_table_radius_m;
        let v = (0..self.tables.len())
            .filter(|&v| d(v) <= radius)
            .filter(|&v| !self.table_requested(v, running))
            .filter(|&v| {
                !self
                    .table_wants(v, WantClass::BackgroundTable, running)
                    .is_empty()
            })
            .min_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)))?;
        Some(self.table_wants(v, WantClass::BackgroundTable, running))
    }

    /// A checked table arrived: decoded and added to the item table. A table that does not
    /// decode is dropped (asked for again). Returns whether it was added.
    pub(super) fn table_arrived(&mut self, vi: usize, data: &Bytes) -> bool {
        let Some(v) = self.top.viewpoints.get(vi) else {
            return false;
        };
        let mut vt = match decode_table(data, v.index) {
            Ok(vt) => vt,
            Err(e) => {
                // Intact (its hash matched) but unusable: the database is broken there.
                let (key, index) = (whole(&v.table.hash), v.index);
                self.table_failures.give_up(&key);
                self.fault_stats();
                self.stats.last_error = Some(format!("table of viewpoint {index}: {e}"));
                return false;
            }
        };
        vt.segments = self.achs[vi].clone().unwrap_or_default();
        let range = match self
            .table
            .add_viewpoint(vi, &vt.background, &vt.tiles, &vt.segments)
        {
            Ok(r) => r,
            Err(e) => {
                self.stats.failed += 1;
                self.stats.last_error = Some(e.to_string());
                return false;
            }
        };
        for i in range.clone() {
            let it = &self.table.items[i];
            self.infos.push(it.info.clone());
            for (p, part) in it.parts.iter().enumerate() {
                self.users.entry(part.key.clone()).or_default().push((i, p));
                // A part identical to one already held (its key shared) arrives for the new
                // item at once.
                if let Some(data) = self.cache.get(&part.key).cloned() {
                    let _ = self
                        .cache
                        .insert(part.key.clone(), data.clone(), it.viewpoint);
                    self.arrivals.push(Arrival {
                        item: i,
                        part: p,
                        data,
                    });
                }
            }
        }
        self.held.resize(self.table.items.len(), 0);
        for i in range {
            self.held[i] = super::held_from(&self.table.items[i].parts, 0, &self.cache);
        }
        self.tables[vi] = Some(vt);
        true
    }

    /// A checked ACH object arrived: its lists join the item table. One that does not decode
    /// is dropped (asked for again). Returns whether it was added.
    pub(super) fn ach_arrived(&mut self, vi: usize, data: &Bytes) -> bool {
        let Some(v) = self.top.viewpoints.get(vi) else {
            return false;
        };
        let segments = match decode_ach(data, v.index) {
            Ok(s) => s,
            Err(e) => {
                let (key, index) = (v.ach.as_ref().map(|a| whole(&a.hash)), v.index);
                if let Some(key) = key {
                    self.table_failures.give_up(&key);
                    self.fault_stats();
                }
                self.stats.last_error = Some(format!("ACH lists of viewpoint {index}: {e}"));
                return false;
            }
        };
        self.table.add_segments(vi, &segments);
        self.achs[vi] = Some(segments.clone());
        if let Some(t) = &mut self.tables[vi] {
            t.segments = segments;
        }
        true
    }

    /// After a table (or ACH lists) was added: the planner's item list, the budget, the full
    /// manifest and the visibility index.
    pub(super) fn tables_changed(&mut self) {
        self.refresh_plan_infos();
        if self.config.scale_budget {
            let scaled = self
                .config
                .budget
                .scaled_to(&self.infos, &self.table.segment_ach);
            self.budget.memory_bytes = self.budget.memory_bytes.max(scaled.memory_bytes);
            self.budget.memory_static_bytes = self
                .budget
                .memory_static_bytes
                .max(scaled.memory_static_bytes);
        }
        // Only the viewpoints whose table or ACH lists came: a rebuild of the whole manifest
        // and index cost (and held twice) what every table so far does.
        let mut changed = std::mem::take(&mut self.changed);
        changed.sort_unstable();
        changed.dedup();
        for vi in changed {
            let at = self.stops.get(vi).map_or(&[][..], Vec::as_slice);
            let table = self.tables.get(vi).and_then(Option::as_ref);
            update_viewpoint(&mut self.manifest, &self.top, vi, at, table);
            let entry = at
                .first()
                .and_then(|&(t, k)| self.manifest.tracks.get(t)?.viewpoints.get(k));
            if let (Some(index), Some(entry)) = (&mut self.index, entry) {
                index.update(entry);
            }
        }
        // New tiles and items: count, prefetch and pin again.
        self.cpu_counts = None;
        self.prefetch_memo = None;
        self.pin_spec.1 = false;
    }
}
