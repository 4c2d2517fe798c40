//! Viewpoint tables in a live session: asked for through the fetcher (the ones around the
//! walker above every tile, the rest below), decoded and added as they arrive.

use bytes::Bytes;

use super::Arrival;
use super::LiveSession;
use crate::client::budget::PriorityMode;
use crate::client::fetcher::FetchRequest;
use crate::client::http::FetchKey;
use crate::client::predict::{next_segment, segment_at};
use crate::db::split::{assemble, decode_ach, decode_table, ViewTable};
use crate::visibility::{blend_weights, SceneIndex};

impl LiveSession {
    /// Tables of the viewpoints around `s` (and, with prefetch, of the predicted next
    /// segment) at the top priority, every other missing one at the lowest, nearest first;
    /// returns the table keys to keep.
    pub(super) fn request_tables(
        &mut self,
        s: f64,
        t_now: f64,
    ) -> Vec<(FetchRequest, Option<u64>)> {
        let vp_s = &self.table.vp_s;
        let mut urgent: Vec<usize> = blend_weights(vp_s, s).iter().map(|w| w.0).collect();
        if let Some(seg) = segment_at(vp_s, s) {
            urgent.extend([seg, seg + 1]);
        }
        if self.config.prefetch {
            if let Some(k) = next_segment(&self.motion, vp_s, s, self.config.prefetch_horizon_s) {
                urgent.extend([k, k + 1]);
            }
        }
        let t = &self.top.tracks[self.track];
        let mut out = Vec::new();
        let ach_mode = !matches!(self.config.mode, PriorityMode::Visibility);
        for (vi, v) in t.viewpoints.iter().enumerate() {
            // The ACH lists beside the table, when the mode ranks tiles by them.
            let ach = v
                .ach
                .as_ref()
                .filter(|_| ach_mode && self.achs[vi].is_none());
            // Urgent tables before any tile (tile priorities stay far below 1e12); the rest
            // after every tile, nearest first; ACH objects beside their tables.
            let dist = (v.s - s).abs();
            let priority = if urgent.contains(&vi) {
                1e12 - dist
            } else {
                -1.0 - dist
            };
            if let Some(a) = ach {
                let key = FetchKey {
                    object: a.hash.as_str().into(),
                    range: None,
                };
                // One that failed waits for its retry time, or was given up.
                if !self.failures.may_request(&key, t_now) {
                    continue;
                }
                self.ach_keys.insert(key.clone(), vi);
                out.push((
                    FetchRequest {
                        key,
                        expected_hash: a.hash.clone(),
                        priority,
                    },
                    Some(a.size),
                ));
            }
            if self.tables[vi].is_some() {
                continue;
            }
            let key = FetchKey {
                object: v.table.hash.as_str().into(),
                range: None,
            };
            if !self.failures.may_request(&key, t_now) {
                continue;
            }
            self.table_keys.insert(key.clone(), vi);
            out.push((
                FetchRequest {
                    key,
                    expected_hash: v.table.hash.clone(),
                    priority,
                },
                Some(v.table.size),
            ));
        }
        out
    }

    /// A checked table arrived: decoded and added to the item table; the manifest, the
    /// visibility index and the planner's item list are rebuilt once for every table of the
    /// update ([`LiveSession::tables_changed`]). A table that does not decode is dropped
    /// (asked for again). Returns whether it was added.
    pub(super) fn table_arrived(&mut self, vi: usize, data: &Bytes) -> bool {
        let Some(v) = self.top.tracks[self.track].viewpoints.get(vi) else {
            return false;
        };
        let mut vt = match decode_table(data, v.index) {
            Ok(vt) => vt,
            Err(e) => {
                // Intact (its hash matched) but unusable: the database is broken there.
                let key = FetchKey {
                    object: v.table.hash.as_str().into(),
                    range: None,
                };
                self.failures.give_up(&key);
                self.stats.last_error = Some(format!("table of viewpoint {}: {e}", v.index));
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
                self.stats.failed_requests += 1;
                self.stats.last_error = Some(e.to_string());
                return false;
            }
        };
        for i in range.clone() {
            let it = &self.table.items[i];
            self.infos.push(it.info.clone());
            for (p, part) in it.parts.iter().enumerate() {
                self.users.entry(part.key.clone()).or_default().push((i, p));
                // A part identical to one already held (its key shared, see
                // `ItemTable::set_share_parts`) arrives for the new item at once.
                if let Some(data) = self.cache.get(&part.key).cloned() {
                    let _ = self.cache.insert(part.key.clone(), data.clone(), it.s);
                    self.pending.push(Arrival {
                        item: i,
                        part: p,
                        data,
                    });
                }
            }
        }
        self.held.resize(self.table.items.len(), 0);
        for i in range {
            self.extend_held(i);
        }
        self.tables[vi] = Some(vt);
        true
    }

    /// A checked ACH object arrived: its lists join the item table (and the table's entry,
    /// when that is in). One that does not decode is dropped (asked for again). Returns
    /// whether the manifest must be rebuilt ([`LiveSession::tables_changed`]).
    pub(super) fn ach_arrived(&mut self, vi: usize, data: &Bytes) -> bool {
        let Some(v) = self.top.tracks[self.track].viewpoints.get(vi) else {
            return false;
        };
        let segments = match decode_ach(data, v.index) {
            Ok(s) => s,
            Err(e) => {
                if let Some(a) = &v.ach {
                    let key = FetchKey {
                        object: a.hash.as_str().into(),
                        range: None,
                    };
                    self.failures.give_up(&key);
                }
                self.stats.last_error = Some(format!("ACH lists of viewpoint {}: {e}", v.index));
                return false;
            }
        };
        self.table.add_segments(vi, &segments);
        self.achs[vi] = Some(segments.clone());
        if let Some(t) = &mut self.tables[vi] {
            t.segments = segments;
            return true;
        }
        false
    }

    /// After the tables (and ACH lists) of one update were added: the planner's item list,
    /// the full manifest and the visibility index, rebuilt once. (Rebuilt for each table, a
    /// session that received all of castle 256's 37 tables in one update spent 0.66 s on
    /// it, all of them rebuilding the same index over and over.)
    pub(super) fn tables_changed(&mut self) {
        self.refresh_plan_infos();
        self.reassemble();
    }

    /// The full manifest and the visibility index from the tables that have arrived.
    fn reassemble(&mut self) {
        let row: Vec<Option<&ViewTable>> = self.tables.iter().map(|t| t.as_ref()).collect();
        let mut rows: Vec<Vec<Option<&ViewTable>>> = vec![Vec::new(); self.top.tracks.len()];
        rows[self.track] = row;
        self.manifest = assemble(&self.top, &rows);
        self.index = SceneIndex::new(&self.manifest, self.track);
        // New tiles and items: count and pin again.
        self.cpu_counts = None;
        self.pin_spec.1 = false;
    }
}
