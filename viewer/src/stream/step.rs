//! One step of a streamed walkthrough: what arrived is taken in, the parts a step may
//! consume are decoded on every core and placed into the views, the texels around each
//! tile that arrived are rebuilt, and the views over the decoded budget are dropped.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use bytes::Bytes;
use rayon::prelude::*;
use streamer::client::{Arrival, LiveCount};
use tracks::{PerspectiveCamera, PixelRect};

use super::items::{decode_parts, item_state, Decoded, ItemState};
use super::redecode::RedecodePlan;
use super::{StepReport, StreamedWalkthrough};
use crate::source::SourceError;

/// An item's parts decoded in a step: the item, its name, its finest level when that became
/// finer.
type DecodedItem = (usize, String, Result<Option<Decoded>, SourceError>);

impl StreamedWalkthrough {
    /// One frame: update the session at `s` / `camera` (with the GPU's counts when given)
    /// and fold what arrived into the views.
    pub fn step(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> StepReport {
        let pos = streamer::client::NetPos {
            track: self.walk.current,
            s,
        };
        let arrived = self.session.update_at(pos, camera, live);
        self.add_new_items();
        let now = Instant::now();
        let mut report = StepReport {
            arrivals: arrived.len(),
            ..Default::default()
        };
        let drawn = self.drawn_views(s, camera);
        let protected = self.protected_views(s, &drawn, now);
        // Views that stopped being drawn before anything of them arrived: the renderer may
        // hold a placeholder upload of them.
        let mut views: BTreeSet<usize> = self
            .protected
            .difference(&protected)
            .filter(|&&v| !self.laid_out(v))
            .filter_map(|&v| self.walk.views.get(v).map(|rv| rv.index))
            .collect();
        let touched = self.take_in(arrived, &protected, now);
        let plan = self.plan_redecode(&touched, &drawn, &protected, s);
        report.redecoded_parts = plan.parts;
        report.redecoded_bytes = plan.bytes;
        report.backlog = plan.backlog;
        let decoded = self.decode_touched(&touched, &plan);
        let rects = self.place_decoded(decoded, now, &mut report);
        report.regions.extend(self.update_regions(rects));
        // Views laid out in this step changed shape: uploaded whole.
        views.extend(
            std::mem::take(&mut self.fresh)
                .into_iter()
                .map(|v| self.walk.views[v].index),
        );
        // Decoded bytes per view, counted once a step (every item of every view).
        let mut per_view: Vec<u64> = (0..self.walk.views.len())
            .map(|v| self.view_decoded_bytes(v))
            .collect();
        for v in self.evict_over_budget(s, &protected, &per_view) {
            let index = self.walk.views[v].index;
            report.evicted.push(index);
            views.insert(index);
            per_view[v] = self.view_decoded_bytes(v);
        }
        report.regions.retain(|r| !report.evicted.contains(&r.0));
        self.protected = protected;
        report.changed_views = views.into_iter().collect();
        report.decoded_bytes = per_view.iter().sum();
        self.decoded_peak = self.decoded_peak.max(report.decoded_bytes);
        self.fade_highlights(now);
        report
    }

    /// Tiles of viewpoint tables that arrived: new items (appended, never renumbered).
    fn add_new_items(&mut self) {
        for i in self.items.len()..self.session.table().items.len() {
            let view = self.session.table().items[i].viewpoint;
            if let Some(list) = self.view_items.get_mut(view) {
                list.push(i);
            }
            match item_state(&self.session, i) {
                Ok(state) => self.items.push(state),
                Err(e) => {
                    self.errors.push(e.to_string());
                    self.items.push(ItemState::failed(view));
                }
            }
        }
    }

    /// Take in the parts that `arrived` (beside their items where their view is needed or
    /// laid out) and return the items with a next part to consume: arrived now or earlier,
    /// or, for the `protected` views, in the session's cache.
    fn take_in(
        &mut self,
        arrived: Vec<Arrival>,
        protected: &BTreeSet<usize>,
        now: Instant,
    ) -> BTreeSet<usize> {
        let mut touched = BTreeSet::new();
        for a in arrived {
            self.walk.bytes += a.data.len() as u64;
            self.arrivals.push_back((now, a.data.len()));
            let Some(it) = self.items.get_mut(a.item) else {
                continue;
            };
            // Parts of a view that is neither laid out nor needed soon stay in the session's
            // cache only (consumed from there when the view is needed).
            let wanted = protected.contains(&it.view)
                || self.dense.get(it.view).is_some_and(|d| !d.is_empty());
            if a.part >= it.next && !it.failed && wanted {
                it.waiting.insert(a.part, a.data);
                touched.insert(a.item);
            }
        }
        // Items of the views needed now whose next part is in the session's cache (e.g. they
        // were evicted here, or arrived while their view was not needed).
        for &v in protected {
            for &i in self.view_items.get(v).map_or(&[][..], |l| &l[..]) {
                let it = &self.items[i];
                if !it.failed
                    && (it.waiting.contains_key(&it.next)
                        || self.session.part_bytes(i, it.next).is_some())
                {
                    touched.insert(i);
                }
            }
        }
        // Parts that arrived in earlier steps and wait for a step with budget left: taken in
        // turn, as they would have been at once, even where their view is no longer needed
        // (a view that received them may stand in later, e.g. with the server gone; the
        // decoded budget evicts what is too far).
        for (i, it) in self.items.iter().enumerate() {
            if !it.failed && it.waiting.contains_key(&it.next) {
                touched.insert(i);
            }
        }
        while self
            .arrivals
            .front()
            .is_some_and(|(t, _)| now.duration_since(*t) > Duration::from_secs(10))
        {
            self.arrivals.pop_front();
        }
        touched
    }

    /// The parts each touched item takes in this step (`plan`), decoded for all items at
    /// once on every core (each item has its own decoder), in item order.
    fn decode_touched(
        &mut self,
        touched: &BTreeSet<usize>,
        plan: &RedecodePlan,
    ) -> Vec<DecodedItem> {
        let work: Vec<(usize, Vec<Bytes>, String)> = touched
            .iter()
            .map(|&item| {
                let count = plan.allowed.get(&item).copied().unwrap_or(0);
                (item, self.take_parts(item, count), self.item_name(item))
            })
            .collect();
        let mut work = work.into_iter().peekable();
        let mut jobs = Vec::new();
        for (i, it) in self.items.iter_mut().enumerate() {
            if let Some((_, parts, what)) = work.next_if(|w| w.0 == i) {
                jobs.push((i, it, parts, what));
            }
        }
        let premultiplied = self.premultiplied;
        let k = self.layout_level;
        jobs.into_par_iter()
            .map(|(i, it, parts, what)| {
                let d = decode_parts(it, parts, &what, premultiplied, k);
                (i, what, d)
            })
            .collect()
    }

    /// Place the levels `decoded` into the views in order; the tile rectangles that changed
    /// as `(view, layer, rectangle)`. An item that fails is marked so and its error kept.
    fn place_decoded(
        &mut self,
        decoded: Vec<DecodedItem>,
        now: Instant,
        report: &mut StepReport,
    ) -> Vec<(usize, usize, PixelRect)> {
        let mut rects = Vec::new();
        for (item, what, d) in decoded {
            match d.and_then(|d| match d {
                Some(d) => self.place(item, d, &what, now),
                None => Ok(None),
            }) {
                Ok(Some((layer, rect))) => {
                    rects.push((self.items[item].view, layer, rect));
                    report.upgraded += 1;
                }
                Ok(None) => {}
                Err(e) => {
                    self.items[item].failed = true;
                    self.errors.push(e.to_string());
                }
            }
        }
        rects
    }

    /// Redo the dilation and mip texels around each tile rectangle that changed only, the
    /// layers that changed in parallel; the texels per mip level that may have changed, as
    /// [`StepReport::regions`] lists them.
    fn update_regions(
        &mut self,
        rects: Vec<(usize, usize, PixelRect)>,
    ) -> Vec<(usize, usize, Vec<PixelRect>)> {
        let mut by_layer: BTreeMap<(usize, usize), Vec<PixelRect>> = BTreeMap::new();
        for (v, layer, rect) in rects {
            by_layer.entry((v, layer)).or_default().push(rect);
        }
        let mut jobs = Vec::new();
        for (v, (view, dense)) in self.walk.views.iter_mut().zip(&self.dense).enumerate() {
            for (l, (layer, map)) in view.layers.iter_mut().zip(dense).enumerate() {
                if let Some(rects) = by_layer.remove(&(v, l)) {
                    jobs.push((view.index, l, layer, map, rects));
                }
            }
        }
        let regions: Vec<Vec<(usize, usize, Vec<PixelRect>)>> = jobs
            .into_par_iter()
            .map(|(index, l, layer, map, rects)| {
                rects
                    .into_iter()
                    .map(|r| (index, l, layer.update_region(map, r)))
                    .filter(|r| !r.2.is_empty())
                    .collect()
            })
            .collect();
        regions.into_iter().flatten().collect()
    }
}
