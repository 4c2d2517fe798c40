//! Which tiles and levels to hold and download: the PTM budget rules (§6.1–6.2), live
//! visible-pixel counts (Goss & Yuasa §3) and prefetch, as plain functions without I/O.
//!
//! A streamable *item* (a tile or a background) is a list of *parts* downloaded in order: the
//! depth mesh (if any), then the PTM level groups from coarsest to finest. Holding the first
//! `k` parts costs `S(k)` bytes of texture memory ([`ItemInfo::mem`]).
//!
//! The caller frustum-culls the ACH list first (PTM §6.1: only what can be in view shares the
//! budget; [`crate::visibility::SceneIndex::tile_in_frustum`]), so `M` is not spread over the
//! tiles behind the camera. One request carries an item's mesh together with its coarsest
//! level; a later one as many further level groups as the link estimate delivers within
//! `δt_max` ([`PartRequest::parts`]), so a tile does not pay one round trip per part; the caller may
//! bundle the requests of many items into one HTTP request
//! ([`crate::client::Connection::fetch_checked_bundle`]).
//!
//! [`plan`] shares the memory budget `M` among the candidate items in descending order of
//! their weight (the segment's ACH, the live pixel count, or a blend): each item in turn gets
//! `weight / (remaining weight) · (remaining budget)`, takes the finest level whose `S` fits
//! (at least its coarsest level while any budget remains), and returns what it did not use.
//! Then, per item: levels up to the target that are downloaded become resident (add), those
//! beyond it are dropped from residency (remove), and if the next part is missing and no
//! download for that item is running, it is requested — only when the running link estimate
//! says it arrives within `δt_max` (coarsest parts are always requested: nothing can be shown
//! without them). Prefetched items (the next segment's tiles) rank below every current request,
//! as the city paper's prefetching module asks: priorities are, from first to last, coarsest
//! parts of items in view (3 + w), coarsest parts of the combined mode's ACH-only items
//! (2 + w), current refinements (1 + w), prefetched coarsest parts (0.5 + w/2), prefetched
//! refinements (w/2), with `w` ∈ [0, 1) the item's normalised weight.
//! So prefetch only uses request slots the current view leaves idle.

/// Download sizes and memory costs of one item's parts.
#[derive(Clone, Debug, PartialEq)]
pub struct ItemInfo {
    /// Bytes to download for each part, in order.
    pub part_bytes: Vec<u64>,
    /// Memory each part adds once resident (decoded texels for PTM levels).
    pub part_mem: Vec<u64>,
    /// Index of the first PTM level group among the parts (1 when a mesh comes first).
    pub first_level_part: usize,
    /// Level number (0 = finest) of each PTM group, coarse to fine.
    pub levels: Vec<u32>,
}

impl ItemInfo {
    pub fn parts(&self) -> usize {
        self.part_bytes.len()
    }

    /// `S(k)`: memory for the first `k` parts.
    pub fn mem(&self, k: usize) -> u64 {
        self.part_mem.iter().take(k).sum()
    }

    /// Parts needed before anything can be shown (mesh and coarsest level).
    pub fn min_parts(&self) -> usize {
        (self.first_level_part + 1).min(self.parts())
    }

    /// Parts needed to show `level` (or the finest available when `level` is finer).
    pub fn parts_for_level(&self, level: u32) -> usize {
        let groups = self
            .levels
            .iter()
            .position(|&l| l <= level)
            .map_or(self.levels.len(), |i| i + 1);
        (self.first_level_part + groups).min(self.parts())
    }

    /// The finest level shown with `k` parts, `None` when no level is complete.
    pub fn level_with(&self, k: usize) -> Option<u32> {
        let groups = k.checked_sub(self.first_level_part)?;
        groups
            .checked_sub(1)
            .and_then(|g| self.levels.get(g))
            .copied()
    }
}

/// Running estimate of the link: `time = latency + bytes · 8 / bandwidth`, fitted by least
/// squares over the most recent downloads.
#[derive(Clone, Debug)]
pub struct LinkEstimate {
    samples: Vec<(f64, f64)>,
    window: usize,
    prior_bps: f64,
    prior_latency_s: f64,
}

impl LinkEstimate {
    /// Start from a guess (used until two distinct-size samples exist).
    pub fn new(prior_bps: f64, prior_latency_s: f64) -> LinkEstimate {
        LinkEstimate {
            samples: Vec::new(),
            window: 32,
            prior_bps: prior_bps.max(1.0),
            prior_latency_s: prior_latency_s.max(0.0),
        }
    }

    /// Record one download of `bytes` that took `elapsed_s` from request to last byte.
    pub fn observe(&mut self, bytes: u64, elapsed_s: f64) {
        if !(elapsed_s.is_finite() && elapsed_s >= 0.0) {
            return;
        }
        if self.samples.len() == self.window {
            self.samples.remove(0);
        }
        self.samples.push((bytes as f64, elapsed_s));
    }

    /// `(bandwidth_bps, latency_s)`.
    pub fn get(&self) -> (f64, f64) {
        let n = self.samples.len() as f64;
        if self.samples.len() < 2 {
            return match self.samples.first() {
                Some(&(b, t)) if t > self.prior_latency_s => {
                    (b * 8.0 / (t - self.prior_latency_s), self.prior_latency_s)
                }
                _ => (self.prior_bps, self.prior_latency_s),
            };
        }
        let mx = self.samples.iter().map(|s| s.0).sum::<f64>() / n;
        let my = self.samples.iter().map(|s| s.1).sum::<f64>() / n;
        let sxx: f64 = self.samples.iter().map(|s| (s.0 - mx).powi(2)).sum();
        let sxy: f64 = self.samples.iter().map(|s| (s.0 - mx) * (s.1 - my)).sum();
        let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        if slope <= 1e-12 {
            // All sizes alike (or no size effect): attribute the mean time to bandwidth.
            let bps = if my > 0.0 {
                mx * 8.0 / my
            } else {
                f64::INFINITY
            };
            return (bps.max(1.0), 0.0);
        }
        let latency = (my - slope * mx).max(0.0);
        (8.0 / slope, latency)
    }

    /// Estimated seconds to download `bytes`.
    pub fn time_for(&self, bytes: u64) -> f64 {
        let (bps, lat) = self.get();
        lat + bytes as f64 * 8.0 / bps
    }
}

/// Memory and time budgets (PTM §6.2); the static pair applies once the viewpoint has not
/// moved for `t_static_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BudgetParams {
    pub memory_bytes: u64,
    pub dt_max_s: f64,
    pub memory_static_bytes: u64,
    pub dt_static_s: f64,
    pub t_static_s: f64,
}

impl Default for BudgetParams {
    /// The paper's example values: 4 MB and 0.5 s moving, 16 MB and 20 s static.
    fn default() -> Self {
        BudgetParams {
            memory_bytes: 4 << 20,
            dt_max_s: 0.5,
            memory_static_bytes: 16 << 20,
            dt_static_s: 20.0,
            t_static_s: 1.0,
        }
    }
}

impl BudgetParams {
    /// These budgets raised to fit the database (the paper's values by default): `M` is at least the texture memory of
    /// the largest segment's ACH list with every tile at full resolution (all parts), and
    /// `M_static` at least twice that. A segment's ACH list is every tile some viewpoint on
    /// the segment can see, so however the head turns within a segment the budget never
    /// forces what is in view to a coarser level than the database holds (the needed level of
    /// the walk's screen is level 0 on these faces), while it stays a segment's worth — far
    /// below the database (castle face 192: 2.9 MiB of 36 segments' 105 MiB). Fixed paper
    /// values do not scale: tiles grow with the square of the face size.
    pub fn scaled_to(self, items: &[ItemInfo], segment_ach: &[Vec<(usize, f64)>]) -> BudgetParams {
        let largest = segment_ach
            .iter()
            .map(|seg| {
                seg.iter()
                    .filter_map(|&(i, _)| items.get(i))
                    .map(|it| it.mem(it.parts()))
                    .sum::<u64>()
            })
            .max()
            .unwrap_or(0);
        BudgetParams {
            memory_bytes: self.memory_bytes.max(largest),
            memory_static_bytes: self.memory_static_bytes.max(largest.saturating_mul(2)),
            ..self
        }
    }

    /// `(M, δt_max)` for a viewpoint that has been still for `still_s` seconds.
    pub fn current(&self, still_s: f64) -> (u64, f64) {
        if still_s >= self.t_static_s {
            (self.memory_static_bytes, self.dt_static_s)
        } else {
            (self.memory_bytes, self.dt_max_s)
        }
    }
}

/// Where download priorities come from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PriorityMode {
    /// The current segment's ACH (PTM §6.1).
    Ach,
    /// Live visible-pixel counts per missing tile (Goss & Yuasa).
    Visibility,
    /// Weight `w · ACH/ΣACH + (1 − w) · px/Σpx`; tiles only in the ACH list are held at
    /// their coarsest level, visible tiles up to the level their pixels need.
    Combined { ach_weight: f64 },
}

/// A live count for one item: visible pixels and the finest level they need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LiveCount {
    pub item: usize,
    pub pixels: f64,
    pub needed_level: u32,
}

/// Everything [`plan`] looks at.
#[derive(Clone, Debug)]
pub struct PlanInput<'a> {
    pub items: &'a [ItemInfo],
    /// Parts downloaded per item (a prefix).
    pub have: &'a [usize],
    /// Whether a download for the item is running.
    pub downloading: &'a [bool],
    /// The current segment's ACH list `(item, ach)`.
    pub ach: &'a [(usize, f64)],
    /// Live counts for the current view.
    pub live: &'a [LiveCount],
    /// The predicted next segment's ACH list, to prefetch (empty = no prefetch).
    pub prefetch: &'a [(usize, f64)],
    pub mode: PriorityMode,
    pub memory_bytes: u64,
    pub dt_max_s: f64,
    pub link: &'a LinkEstimate,
}

/// One download decided by [`plan`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartRequest {
    pub item: usize,
    /// First part to download.
    pub part: usize,
    /// Consecutive parts to download in one request (≥ 1): PTM level groups of one object,
    /// as many towards the target as the link estimate delivers within `δt_max`.
    pub parts: usize,
    /// Larger is sooner (see the module docs for the four bands).
    pub priority: f64,
}

/// The outcome: resident parts per item (`S` of them sums to at most `M`) and downloads.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// `(item, target parts, resident parts)` in allocation order.
    pub targets: Vec<(usize, usize, usize)>,
    pub requests: Vec<PartRequest>,
    /// Memory the resident parts take.
    pub resident_bytes: u64,
}

/// Share `memory` among `(item, weight, cap)` in descending weight; returns target parts.
pub fn allocate(
    items: &[ItemInfo],
    cands: &[(usize, f64, usize)],
    memory: u64,
) -> Vec<(usize, usize)> {
    let mut order: Vec<&(usize, f64, usize)> = cands.iter().filter(|c| c.0 < items.len()).collect();
    order.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut remaining = memory;
    let mut weight_left: f64 = order.iter().map(|c| c.1.max(0.0)).sum();
    let mut out = Vec::with_capacity(order.len());
    for &&(item, w, cap) in &order {
        let info = &items[item];
        let w = w.max(0.0);
        let share = if weight_left > 0.0 {
            (remaining as f64 * w / weight_left).floor() as u64
        } else {
            remaining / (order.len() as u64).max(1)
        };
        weight_left -= w;
        let cap = cap.min(info.parts());
        let min = info.min_parts().min(cap);
        let mut k = (min..=cap)
            .rev()
            .find(|&k| info.mem(k) <= share)
            .unwrap_or(0);
        if k == 0 && info.mem(min) <= remaining {
            k = min;
        }
        remaining -= info.mem(k);
        out.push((item, k));
    }
    out
}

/// How many parts from `have` towards `target` one request takes. With `coarse_first` (the
/// view has many holes) an item not yet shown gets exactly what it needs to be shown — its
/// mesh and coarsest level, in one request — so the first complete frame does not wait for
/// refinements. Otherwise (and for items already shown) the run goes on with further PTM
/// level groups while it still arrives within `dt_max`, so a tile that comes into view costs
/// one round trip, not one per part. Always at least one part, and never less than
/// mesh + coarsest level for an item not yet shown.
fn run_len(
    info: &ItemInfo,
    have: usize,
    target: usize,
    link: &LinkEstimate,
    dt_max: f64,
    coarse_first: bool,
) -> usize {
    let end = target.min(info.parts());
    if have >= end {
        return 1;
    }
    let mut n = info.min_parts().saturating_sub(have).clamp(1, end - have);
    if coarse_first && have < info.min_parts() {
        return n;
    }
    let mut bytes: u64 = info.part_bytes[have..have + n].iter().sum();
    while have + n < end {
        let more = bytes + info.part_bytes[have + n];
        if link.time_for(more) > dt_max {
            break;
        }
        bytes = more;
        n += 1;
    }
    n
}

/// Decide residency and downloads for one frame (see the module docs).
pub fn plan(inp: &PlanInput) -> Plan {
    let n = inp.items.len();
    let sum_ach: f64 = inp.ach.iter().map(|a| a.1.max(0.0)).sum();
    let sum_px: f64 = inp.live.iter().map(|c| c.pixels.max(0.0)).sum();
    let mut weight = vec![0.0f64; n];
    let mut cap = vec![0usize; n];
    let mut is_cand = vec![false; n];
    let use_ach = !matches!(inp.mode, PriorityMode::Visibility);
    let use_live = !matches!(inp.mode, PriorityMode::Ach);
    let ach_w = match inp.mode {
        PriorityMode::Ach => 1.0,
        PriorityMode::Visibility => 0.0,
        PriorityMode::Combined { ach_weight } => ach_weight.clamp(0.0, 1.0),
    };
    if use_ach {
        for &(i, a) in inp.ach.iter().filter(|a| a.0 < n) {
            weight[i] += ach_w * a.max(0.0) / sum_ach.max(f64::MIN_POSITIVE);
            // Combined: ACH broadens (every tile of the segment gets its coarsest level, ready
            // for a turn of the head), live counts sharpen (visible tiles up to their need).
            cap[i] = if use_live {
                inp.items[i].min_parts()
            } else {
                inp.items[i].parts()
            };
            is_cand[i] = true;
        }
    }
    if use_live {
        for c in inp.live.iter().filter(|c| c.item < n) {
            weight[c.item] += (1.0 - ach_w) * c.pixels.max(0.0) / sum_px.max(f64::MIN_POSITIVE);
            let need = inp.items[c.item].parts_for_level(c.needed_level);
            cap[c.item] = cap[c.item].max(need);
            is_cand[c.item] = true;
        }
    }
    let cands: Vec<(usize, f64, usize)> = (0..n)
        .filter(|&i| is_cand[i])
        .map(|i| (i, weight[i], cap[i]))
        .collect();
    // In view now: every candidate for the ACH alone; with live counts, those with pixels
    // (the combined mode's ACH-only tiles get their coarsest level after those in view).
    let mut in_view = vec![!use_live; n];
    for c in inp.live.iter().filter(|c| c.item < n && c.pixels > 0.0) {
        in_view[c.item] = true;
    }
    let targets = allocate(inp.items, &cands, inp.memory_bytes);
    // Holes: bytes still missing before every candidate can be shown at all. When they take
    // more than half of δt_max, not-yet-shown items get their coarsest level alone first.
    let holes: u64 = targets
        .iter()
        .map(|&(i, target)| {
            let info = &inp.items[i];
            let have = inp.have.get(i).copied().unwrap_or(0).min(info.parts());
            let min = info.min_parts().min(target);
            info.part_bytes[have.min(min)..min].iter().sum::<u64>()
        })
        .sum();
    let coarse_first = holes > 0 && inp.link.time_for(holes) > 0.5 * inp.dt_max_s;
    let mut out = Plan::default();
    for &(i, target) in &targets {
        let info = &inp.items[i];
        let have = inp.have.get(i).copied().unwrap_or(0).min(info.parts());
        let resident = have.min(target);
        out.resident_bytes += info.mem(resident);
        out.targets.push((i, target, resident));
        if have < target && !inp.downloading.get(i).copied().unwrap_or(false) {
            let essential = have < info.min_parts();
            let fast_enough = inp.link.time_for(info.part_bytes[have]) <= inp.dt_max_s;
            if essential || fast_enough {
                out.requests.push(PartRequest {
                    item: i,
                    part: have,
                    parts: run_len(info, have, target, inp.link, inp.dt_max_s, coarse_first),
                    priority: match (essential, in_view[i]) {
                        (true, true) => 3.0,
                        (true, false) => 2.0,
                        (false, _) => 1.0,
                    } + weight[i].min(1.0) * 0.999,
                });
            }
        }
    }
    if !inp.prefetch.is_empty() {
        let sum: f64 = inp.prefetch.iter().map(|a| a.1.max(0.0)).sum();
        let pre: Vec<(usize, f64, usize)> = inp
            .prefetch
            .iter()
            .filter(|a| a.0 < n && !is_cand[a.0])
            .map(|&(i, a)| {
                (
                    i,
                    a.max(0.0) / sum.max(f64::MIN_POSITIVE),
                    inp.items[i].parts(),
                )
            })
            .collect();
        for (i, target) in allocate(inp.items, &pre, inp.memory_bytes) {
            let info = &inp.items[i];
            let have = inp.have.get(i).copied().unwrap_or(0).min(info.parts());
            if have < target && !inp.downloading.get(i).copied().unwrap_or(false) {
                let essential = have < info.min_parts();
                if essential || inp.link.time_for(info.part_bytes[have]) <= inp.dt_max_s {
                    let w = pre.iter().find(|p| p.0 == i).map_or(0.0, |p| p.1);
                    out.requests.push(PartRequest {
                        item: i,
                        part: have,
                        parts: run_len(info, have, target, inp.link, inp.dt_max_s, coarse_first),
                        priority: if essential { 0.5 } else { 0.0 } + w.min(1.0) * 0.499,
                    });
                }
            }
        }
    }
    out.requests
        .sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.item.cmp(&b.item)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4-level tile: mesh of 100 B, groups coarse → fine.
    fn tile() -> ItemInfo {
        ItemInfo {
            part_bytes: vec![100, 20, 60, 240, 960],
            part_mem: vec![100, 16, 64, 256, 1024],
            first_level_part: 1,
            levels: vec![3, 2, 1, 0],
        }
    }

    #[test]
    fn item_levels() {
        let t = tile();
        assert_eq!(t.min_parts(), 2);
        assert_eq!(t.parts_for_level(0), 5);
        assert_eq!(t.parts_for_level(2), 3);
        assert_eq!(t.parts_for_level(9), 2);
        assert_eq!(t.level_with(1), None);
        assert_eq!(t.level_with(2), Some(3));
        assert_eq!(t.level_with(5), Some(0));
        assert_eq!(t.mem(3), 180);
    }

    #[test]
    fn budget_goes_to_higher_ach_first_and_never_overflows() {
        let items = vec![tile(), tile(), tile()];
        // 1500 B: the first tile (ACH 0.6) gets 900 → level 1 (436 B); the rest is shared.
        let t = allocate(&items, &[(0, 0.6, 5), (1, 0.3, 5), (2, 0.1, 5)], 1500);
        assert_eq!(t[0], (0, 4));
        let used: u64 = t.iter().map(|&(i, k)| items[i].mem(k)).sum();
        assert!(used <= 1500);
        assert!(t[1].1 >= t[2].1);
        // Less memory than one coarsest level: nobody gets anything.
        let t = allocate(&items, &[(0, 0.6, 5), (1, 0.4, 5)], 50);
        assert!(t.iter().all(|&(_, k)| k == 0));
    }

    #[test]
    fn slow_links_skip_fine_levels_but_not_the_coarsest() {
        let items = vec![tile()];
        let slow = LinkEstimate::new(1000.0, 0.05); // 1 kbit/s
        let inp = PlanInput {
            items: &items,
            have: &[2],
            downloading: &[false],
            ach: &[(0, 1.0)],
            live: &[],
            prefetch: &[],
            mode: PriorityMode::Ach,
            memory_bytes: 1 << 20,
            dt_max_s: 0.5,
            link: &slow,
        };
        assert!(
            plan(&inp).requests.is_empty(),
            "60 B at 1 kbit/s takes 0.5 s + latency"
        );
        let none = [0];
        let p = plan(&PlanInput {
            have: &none,
            ..inp.clone()
        });
        assert_eq!(p.requests.len(), 1);
        assert_eq!(p.requests[0].part, 0);
        let fast = LinkEstimate::new(1e7, 0.05);
        let p = plan(&PlanInput { link: &fast, ..inp });
        assert_eq!(p.requests[0].part, 2);
    }

    #[test]
    fn visibility_caps_at_the_needed_level_and_prefetch_ranks_last() {
        let items = vec![tile(), tile(), tile()];
        let link = LinkEstimate::new(1e9, 0.0);
        let live = [LiveCount {
            item: 1,
            pixels: 500.0,
            needed_level: 2,
        }];
        let inp = PlanInput {
            items: &items,
            have: &[0, 3, 0],
            downloading: &[false; 3],
            ach: &[(0, 1.0)],
            live: &live,
            prefetch: &[(2, 1.0)],
            mode: PriorityMode::Visibility,
            memory_bytes: 1 << 20,
            dt_max_s: 1.0,
            link: &link,
        };
        let p = plan(&inp);
        // Tile 1 already has level 2: nothing to download; tile 0 is not visible.
        assert_eq!(p.targets, vec![(1, 3, 3)]);
        assert_eq!(p.requests.len(), 1);
        assert_eq!(p.requests[0].item, 2);
        assert!(p.requests[0].priority < 1.0);
        let p = plan(&PlanInput {
            mode: PriorityMode::Combined { ach_weight: 0.5 },
            ..inp.clone()
        });
        assert_eq!(p.requests.first().map(|r| r.item), Some(0));
        let pre = p.requests.iter().find(|r| r.item == 2).unwrap();
        assert!(pre.priority < p.requests[0].priority);
        // Combined: a tile only in the ACH list stops at its coarsest level.
        let have = [2, 3, 2];
        let p = plan(&PlanInput {
            have: &have,
            mode: PriorityMode::Combined { ach_weight: 0.5 },
            ..inp.clone()
        });
        assert!(p.requests.iter().all(|r| r.item != 0));
        // A prefetched refinement ranks below a current refinement.
        let p = plan(&PlanInput {
            have: &have,
            mode: PriorityMode::Ach,
            ..inp
        });
        let cur = p.requests.iter().find(|r| r.item == 0).unwrap();
        let pre = p.requests.iter().find(|r| r.item == 2).unwrap();
        assert!(pre.priority < 1.0 && cur.priority >= 1.0);
    }

    proptest::proptest! {
        #[test]
        fn allocation_never_exceeds_the_budget(
            weights in proptest::collection::vec((0.0f64..1.0, 0usize..6), 1..40),
            memory in 0u64..20_000,
        ) {
            let items: Vec<ItemInfo> = weights.iter().map(|_| tile()).collect();
            let cands: Vec<(usize, f64, usize)> =
                weights.iter().enumerate().map(|(i, &(w, cap))| (i, w, cap)).collect();
            let t = allocate(&items, &cands, memory);
            let used: u64 = t.iter().map(|&(i, k)| items[i].mem(k)).sum();
            proptest::prop_assert!(used <= memory);
            for &(i, k) in &t {
                proptest::prop_assert!(k <= cands[i].2.min(5));
            }
        }
    }

    #[test]
    fn one_request_carries_as_many_levels_as_arrive_within_dt_max() {
        let t = tile();
        let fast = LinkEstimate::new(1e9, 0.05);
        // The mesh travels with the levels: everything up to the target in one run; with
        // holes in the view, the mesh and the coarsest level alone.
        assert_eq!(run_len(&t, 0, 5, &fast, 0.5, false), 5);
        assert_eq!(run_len(&t, 0, 5, &fast, 0.5, true), 2);
        assert_eq!(
            run_len(&t, 1, 5, &fast, 0.5, true),
            1,
            "mesh held: the coarsest alone"
        );
        assert_eq!(
            run_len(&t, 2, 5, &fast, 0.5, true),
            3,
            "shown: refinements in one run"
        );
        assert_eq!(run_len(&t, 2, 4, &fast, 0.5, false), 2);
        assert_eq!(run_len(&t, 4, 5, &fast, 0.5, false), 1);
        // 10 kbit/s, 50 ms: 60+240 B = 240 ms + 50 ms fits 0.4 s, adding 960 B does not.
        let slow = LinkEstimate::new(1e4, 0.05);
        assert_eq!(run_len(&t, 2, 5, &slow, 0.4, false), 2);
        // Too slow for even one group: still one (the caller decides whether to send it),
        // and never less than mesh + coarsest level for an item not yet shown.
        assert_eq!(run_len(&t, 2, 5, &slow, 0.0, false), 1);
        assert_eq!(run_len(&t, 0, 5, &slow, 0.0, false), 2);
        let items = vec![t];
        let p = plan(&PlanInput {
            items: &items,
            have: &[2],
            downloading: &[false],
            ach: &[(0, 1.0)],
            live: &[],
            prefetch: &[],
            mode: PriorityMode::Ach,
            memory_bytes: 1 << 20,
            dt_max_s: 0.5,
            link: &fast,
        });
        assert_eq!((p.requests[0].part, p.requests[0].parts), (2, 3));
        // One tile coming into view: mesh and every level in one request.
        let p = plan(&PlanInput {
            items: &items,
            have: &[0],
            downloading: &[false],
            ach: &[(0, 1.0)],
            live: &[],
            prefetch: &[],
            mode: PriorityMode::Ach,
            memory_bytes: 1 << 20,
            dt_max_s: 0.5,
            link: &fast,
        });
        assert_eq!((p.requests[0].part, p.requests[0].parts), (0, 5));
        // A view full of holes (400 tiles, 48 kB before anything shows: 0.43 s at 1 Mbit/s
        // > δt_max / 2): every tile gets its mesh and coarsest level alone first.
        let many = vec![tile(); 400];
        let ach: Vec<(usize, f64)> = (0..400).map(|i| (i, 1.0)).collect();
        let link = LinkEstimate::new(1e6, 0.05);
        let p = plan(&PlanInput {
            items: &many,
            have: &[0; 400],
            downloading: &[false; 400],
            ach: &ach,
            live: &[],
            prefetch: &[],
            mode: PriorityMode::Ach,
            memory_bytes: 1 << 30,
            dt_max_s: 0.5,
            link: &link,
        });
        assert_eq!(p.requests.len(), 400);
        assert!(p.requests.iter().all(|r| (r.part, r.parts) == (0, 2)));
    }

    #[test]
    fn combined_shows_what_is_in_view_before_broadening() {
        let items = vec![tile(), tile()];
        let link = LinkEstimate::new(1e9, 0.0);
        // Tile 0: high ACH, not in view; tile 1: low ACH, a few pixels in view.
        let live = [LiveCount {
            item: 1,
            pixels: 10.0,
            needed_level: 0,
        }];
        let p = plan(&PlanInput {
            items: &items,
            have: &[0, 0],
            downloading: &[false; 2],
            ach: &[(0, 0.9), (1, 0.1)],
            live: &live,
            prefetch: &[],
            mode: PriorityMode::Combined { ach_weight: 0.5 },
            memory_bytes: 1 << 20,
            dt_max_s: 1.0,
            link: &link,
        });
        let order: Vec<usize> = p.requests.iter().map(|r| r.item).collect();
        assert_eq!(order, vec![1, 0]);
        assert!(p.requests[0].priority >= 3.0 && p.requests[1].priority < 3.0);
    }

    #[test]
    fn link_estimate_recovers_bandwidth_and_latency() {
        let mut e = LinkEstimate::new(1e6, 0.1);
        for b in [1000u64, 5000, 20000, 80000] {
            e.observe(b, 0.05 + b as f64 * 8.0 / 2e6);
        }
        let (bps, lat) = e.get();
        assert!((bps - 2e6).abs() < 1e3, "{bps}");
        assert!((lat - 0.05).abs() < 1e-6, "{lat}");
        assert!((e.time_for(2e6 as u64 / 8) - 1.05).abs() < 1e-3);
    }

    #[test]
    fn scaled_budgets_hold_the_largest_segment_at_full_resolution() {
        let items = vec![tile(); 4];
        let full = tile().mem(5);
        // Small database: the paper's values stand.
        let b =
            BudgetParams::default().scaled_to(&items, &[vec![(0, 1.0), (1, 1.0)], vec![(2, 1.0)]]);
        assert_eq!(b, BudgetParams::default());
        // A database whose segments outgrow 4 MiB: M follows the largest segment.
        let big = ItemInfo {
            part_mem: tile().part_mem.iter().map(|m| m * 4096).collect(),
            ..tile()
        };
        let items = vec![big.clone(), big.clone(), big];
        let segs = vec![vec![(0, 1.0)], vec![(1, 0.5), (2, 0.5), (9, 1.0)]];
        let b = BudgetParams::default().scaled_to(&items, &segs);
        assert_eq!(b.memory_bytes, 2 * full * 4096);
        assert_eq!(b.memory_static_bytes, (16 << 20).max(4 * full * 4096));
        assert_eq!(b.dt_max_s, 0.5);
    }

    #[test]
    fn static_viewpoints_get_the_static_budget() {
        let b = BudgetParams::default();
        assert_eq!(b.current(0.2), (4 << 20, 0.5));
        assert_eq!(b.current(1.5), (16 << 20, 20.0));
    }
}
