//! Viewpoint tables in the walk: which to ask for when, fetched over HTTP and put on the
//! virtual link like any response.

use super::{first_unreachable, InFlight, Sim, Strategy, WalkError};
use crate::client::{next_segment, segment_at, BundlePiece, Connection, FetchKey, Verdict};
use crate::db::split::{decode_ach, decode_table};
use tracks::manifest::ObjectRef;

impl Sim<'_> {
    /// Requests the tables the walker needs now: the current segment's two viewpoints and,
    /// with prefetch, the next segment's once the view has no holes (nearest first, one
    /// request each, before any tile). Returns the request slots used.
    pub(super) async fn issue_urgent_tables(
        &mut self,
        conn: &mut Connection,
        t: f64,
        free: usize,
    ) -> Result<usize, WalkError> {
        if free == 0 {
            return Ok(0);
        }
        let have = self.have();
        let vp_s = &self.table.vp_s;
        let mut want: Vec<usize> = Vec::new();
        if let Some(seg) = segment_at(vp_s, self.s) {
            want.extend([seg, seg + 1]);
        } else if !vp_s.is_empty() {
            want.push(0);
        }
        // The next segment's tables are prefetched once the view has no holes (the view
        // first).
        let holes = self
            .live
            .iter()
            .any(|c| have[c.item] < self.items[c.item].min_parts())
            || want
                .iter()
                .any(|&v| v < vp_s.len() && !self.table.has_viewpoint(v));
        if let Strategy::Budget { prefetch: true, .. } = self.strategy {
            if let Some(k) = next_segment(&self.motion, vp_s, self.s, self.cfg.prefetch_horizon_s)
                .filter(|_| !holes)
            {
                want.extend([k, k + 1]);
            }
        }
        // Whatever the strategy: the viewpoint after the current segment once the walker
        // would reach it before its table (two transfers and a round trip, to be safe) could
        // arrive — at speed there are always holes, and a table asked for on arrival stalls
        // every segment crossing.
        if let (Some(seg), Some(v)) = (segment_at(vp_s, self.s), self.motion.velocity()) {
            let next = seg + 2;
            if v > 0.0 && next < vp_s.len() && !self.table_requested[next] {
                let (bps, latency) = self.estimate.get();
                let bytes = self.table_objects(next).map(|o| o.size).sum::<u64>() as f64;
                let fetch_s = latency + 2.0 * bytes * 8.0 / bps.max(1.0);
                let reach_s = (vp_s[seg + 1] - self.s).max(0.0) / v;
                // With holes in the view only in the last quarter second (the link estimate
                // of the first seconds is too rough to time it closer).
                if (!holes && reach_s < 2.0 * fetch_s) || reach_s < 0.25 {
                    want.push(next);
                }
            }
        }
        want.retain(|&v| v < vp_s.len() && !self.table_requested[v] && self.table_ready(v, t));
        want.sort_by(|&a, &b| {
            (vp_s[a] - self.s)
                .abs()
                .total_cmp(&(vp_s[b] - self.s).abs())
                .then(a.cmp(&b))
        });
        want.dedup();
        // One request each, nearest first: the link delivers the nearest table first.
        want.truncate(free);
        for &v in &want {
            self.fetch_tables(conn, t, &[v], false).await?;
        }
        Ok(want.len())
    }

    /// One background table (the nearest missing viewpoint) when a slot is free and no
    /// other background table is on its way.
    pub(super) async fn issue_background_table(
        &mut self,
        conn: &mut Connection,
        t: f64,
    ) -> Result<bool, WalkError> {
        if self.in_flight.len() >= self.cfg.max_in_flight.max(1)
            || self.in_flight.iter().any(|f| f.background_table)
        {
            return Ok(false);
        }
        let vp_s = &self.table.vp_s;
        let next = (0..vp_s.len())
            .filter(|&v| !self.table_requested[v] && self.table_ready(v, t))
            .min_by(|&a, &b| {
                (vp_s[a] - self.s)
                    .abs()
                    .total_cmp(&(vp_s[b] - self.s).abs())
                    .then(a.cmp(&b))
            });
        if let Some(v) = next {
            self.fetch_tables(conn, t, &[v], true).await?;
        }
        Ok(next.is_some())
    }

    /// Whether viewpoint `v`'s objects may be asked for at `t` (none failed and waits for its
    /// retry time, or was given up).
    fn table_ready(&self, v: usize, t: f64) -> bool {
        self.table_objects(v).all(|o| {
            self.table_failures.may_request(
                &FetchKey {
                    object: o.hash.as_str().into(),
                    range: None,
                },
                t,
            )
        })
    }

    /// The objects the walk fetches for viewpoint `v`: its table, and its ACH object when the
    /// strategy ranks tiles by ACH.
    fn table_objects(&self, v: usize) -> impl Iterator<Item = &ObjectRef> {
        let (table, ach, _) = &self.scene.tables[v];
        let ach = ach.as_ref().filter(|_| self.strategy.uses_ach());
        std::iter::once(table).chain(ach)
    }

    /// Fetches the tables (and ACH objects, [`Self::table_objects`]) of viewpoints `vps` in
    /// one request (hash-checked, decoded) and puts them on the link.
    async fn fetch_tables(
        &mut self,
        conn: &mut Connection,
        t: f64,
        vps: &[usize],
        background: bool,
    ) -> Result<(), WalkError> {
        let refs: Vec<ObjectRef> = vps
            .iter()
            .flat_map(|&v| self.table_objects(v))
            .cloned()
            .collect();
        let keys: Vec<FetchKey> = refs
            .iter()
            .map(|r| FetchKey {
                object: r.hash.as_str().into(),
                range: None,
            })
            .collect();
        let pieces: Vec<BundlePiece> = refs
            .iter()
            .zip(&keys)
            .map(|(r, key)| BundlePiece {
                key,
                len: r.size,
                hash: &r.hash,
            })
            .collect();
        let data = conn.fetch_pieces(&pieces, None).await;
        self.note_transfer(conn, t);
        if let Some(e) = first_unreachable(&data) {
            return Err(WalkError::Unreachable(e));
        }
        let size: u64 = data
            .iter()
            .filter_map(|d| d.as_ref().ok())
            .map(|b| b.len() as u64)
            .sum();
        let mut data = data.into_iter().zip(&refs).zip(&keys);
        let mut tables = Vec::with_capacity(vps.len());
        for &v in vps {
            let index = self.scene.tables[v].2;
            let with_ach = self.table_objects(v).count() == 2;
            let mut got = Vec::new();
            for _ in 0..1 + usize::from(with_ach) {
                if let Some(((bytes, r), key)) = data.next() {
                    got.push((bytes, r, key));
                }
            }
            // A viewpoint whose table (or ACH object) failed is asked for again later, and
            // given up after repeated faults; a table that arrives intact but does not decode
            // is given up at once (the database itself is broken there).
            let mut vt = None;
            let mut bad: Option<(&FetchKey, String, bool)> = None;
            for (k, (bytes, r, key)) in got.into_iter().enumerate() {
                let bytes = match bytes {
                    Ok(b) => b,
                    Err(e) => {
                        bad.get_or_insert((key, e.to_string(), false));
                        continue;
                    }
                };
                if k == 0 {
                    match decode_table(&bytes, index) {
                        Ok(t) => vt = Some(t),
                        Err(e) => {
                            let what = format!("table {} of viewpoint {index}: {e}", r.hash);
                            bad.get_or_insert((key, what, true));
                        }
                    }
                } else if let Some(t) = vt.as_mut() {
                    match decode_ach(&bytes, index) {
                        Ok(seg) => t.segments = seg,
                        Err(e) => {
                            let what = format!("ACH object {} of viewpoint {index}: {e}", r.hash);
                            bad.get_or_insert((key, what, true));
                        }
                    }
                }
            }
            match (vt, bad) {
                (Some(vt), None) => {
                    tables.push((v, vt));
                    self.table_requested[v] = true;
                }
                (_, bad) => {
                    let (key, what, broken) =
                        bad.unwrap_or((&keys[0], "no bytes".to_string(), false));
                    let mut verdict = self.table_failures.fault(key, t);
                    while broken && verdict != Verdict::GivenUp {
                        verdict = self.table_failures.fault(key, t);
                    }
                    match verdict {
                        Verdict::GivenUp => {
                            tracing::warn!("walk: giving up viewpoint {index}'s table: {what}")
                        }
                        Verdict::RetryAt(_) => tracing::info!("walk: {what}"),
                    }
                }
            }
        }
        let requests = if conn.bundles_supported() {
            1
        } else {
            refs.len() as u64
        };
        self.requests += requests;
        self.table_requests += requests;
        self.bytes += size;
        self.table_bytes += size;
        self.in_flight.push(InFlight {
            prefetch: false,
            tables,
            background_table: background,
            items: Vec::new(),
            keys: Vec::new(),
            issued: t,
            arrives: self.link.schedule_requests(t, size, requests),
            bytes: size,
        });
        Ok(())
    }
}
