//! Decoding a budget per step, parts that arrived and parts from the session's cache alike
//! (see the parent module's docs): which parts a step takes, in which order.

use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap, HashMap};

use super::{StreamedWalkthrough, REDECODE_PART_BYTES};

/// What [`StreamedWalkthrough::plan_redecode`] allows one step to consume.
#[derive(Debug, Default)]
pub(super) struct RedecodePlan {
    /// Parts per item.
    pub(super) allowed: HashMap<usize, usize>,
    pub(super) parts: usize,
    pub(super) bytes: u64,
    /// Items with parts left over (arrived or cached).
    pub(super) backlog: usize,
}

/// An item's next part to consume, in the order parts are taken: `(rank of its
/// view, level position, distance bits, item, part)` (see
/// [`StreamedWalkthrough::plan_redecode`]).
type QueueKey = (u8, usize, u64, usize, usize);

/// Take parts off `queue` (one entry per item: its next part) in order while
/// their `cost` fits `budget` (the first always does), queueing each item's following part
/// (`next` of an item and the part just taken).
fn schedule(
    queue: Vec<QueueKey>,
    budget: u64,
    cost: impl Fn(usize, usize) -> u64,
    next: impl Fn(usize, usize) -> Option<QueueKey>,
) -> RedecodePlan {
    // A heap: building it is linear in the items waiting, which may be many while views
    // are re-filled, and a step takes only the first few.
    let mut queue: BinaryHeap<Reverse<QueueKey>> = queue.into_iter().map(Reverse).collect();
    let mut plan = RedecodePlan::default();
    while let Some(&Reverse((_, _, _, item, part))) = queue.peek() {
        let c = cost(item, part);
        if plan.parts > 0 && plan.bytes.saturating_add(c) > budget {
            break;
        }
        queue.pop();
        plan.parts += 1;
        plan.bytes = plan.bytes.saturating_add(c);
        *plan.allowed.entry(item).or_insert(0) += 1;
        if let Some(k) = next(item, part) {
            queue.push(Reverse(k));
        }
    }
    plan.backlog = queue.len();
    plan
}

impl StreamedWalkthrough {
    /// Decoded bytes (plus [`REDECODE_PART_BYTES`] per part) of the parts a step consumes,
    /// arrived or from the session's cache (default [`super::DEFAULT_REDECODE_BUDGET`]).
    pub fn redecode_budget(&self) -> u64 {
        self.redecode_budget
    }

    /// Consume parts (arrived, or from the session's cache) worth at most `bytes` per step
    /// (decoded bytes plus [`REDECODE_PART_BYTES`] each; always at least one part, so a step
    /// makes progress whatever the budget); what is left is consumed in later steps (see the
    /// module docs). `u64::MAX`: everything at once.
    pub fn set_redecode_budget(&mut self, bytes: u64) {
        self.redecode_budget = bytes;
    }

    /// Which parts to consume in this step, within [`StreamedWalkthrough::redecode_budget`]:
    /// among the items about to be consumed (their next part arrived or is in the session's
    /// cache), those of the pair of views drawn first, then the other protected views, then
    /// the rest; within those, by how far along its parts an item is (each item's mesh and
    /// coarsest level before any item's finer levels), then the view nearest to `s`, then
    /// item order.
    pub(super) fn plan_redecode(
        &self,
        touched: &BTreeSet<usize>,
        drawn: &BTreeSet<usize>,
        protected: &BTreeSet<usize>,
        s: f64,
    ) -> RedecodePlan {
        let table = &self.session.table().items;
        // Part `part` of `item`, if it arrived or is held in the cache.
        let available = |item: usize, part: usize| -> Option<usize> {
            (self.items[item].waiting.contains_key(&part)
                || self.session.part_bytes(item, part).is_some())
            .then_some(part)
        };
        let key = |item: usize, part: usize| {
            let it = &self.items[item];
            let rank = if drawn.contains(&it.view) {
                0u8
            } else if protected.contains(&it.view) {
                1
            } else {
                2
            };
            let d = self
                .walk
                .views
                .get(it.view)
                .map_or(f64::MAX, |v| (v.s - s).abs());
            let d = if d.is_finite() { d } else { f64::MAX };
            let level = part.saturating_sub(it.first_level_part);
            // Non-negative floats order as their bits do.
            (rank, level, d.to_bits(), item, part)
        };
        let queue: Vec<QueueKey> = touched
            .iter()
            .filter(|&&i| !self.items[i].failed)
            .filter_map(|&i| available(i, self.items[i].next).map(|p| key(i, p)))
            .collect();
        let cost = |item: usize, part: usize| {
            table
                .get(item)
                .and_then(|t| t.info.part_mem.get(part).copied())
                .or_else(|| {
                    let it = &self.items[item];
                    it.waiting
                        .get(&part)
                        .or_else(|| self.session.part_bytes(item, part))
                        .map(|b| b.len() as u64)
                })
                .unwrap_or(0)
                .saturating_add(REDECODE_PART_BYTES)
        };
        let next = |item: usize, part: usize| available(item, part + 1).map(|p| key(item, p));
        schedule(queue, self.redecode_budget, cost, next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A test item: rank of its view, distance, first level part, decoded bytes per part.
    type TestItem = (u8, u64, usize, Vec<u64>);

    /// Steps of [`schedule`] over `items` (all parts in the cache) until none is left; each
    /// step's plan and the `(item, part)` it took in order of the queue.
    fn schedule_all(items: &[TestItem], budget: u64) -> Vec<(RedecodePlan, Vec<(usize, usize)>)> {
        let key = |i: usize, p: usize| {
            let (rank, d, first, ref costs) = items[i];
            (p < costs.len()).then_some((rank, p.saturating_sub(first), d, i, p))
        };
        let mut next = vec![0; items.len()];
        let mut steps = Vec::new();
        loop {
            let queue: Vec<QueueKey> = (0..items.len()).filter_map(|i| key(i, next[i])).collect();
            if queue.is_empty() {
                return steps;
            }
            let taken = std::cell::RefCell::new(Vec::new());
            let plan = schedule(
                queue,
                budget,
                |i, p| {
                    taken.borrow_mut().push((i, p));
                    items[i].3[p]
                },
                |i, p| key(i, p + 1),
            );
            let mut taken = taken.into_inner();
            // `cost` is also asked of the part that did not fit.
            taken.truncate(plan.parts);
            for (&i, &n) in &plan.allowed {
                next[i] += n;
            }
            steps.push((plan, taken));
            assert!(steps.len() <= 1000, "no progress");
        }
    }

    #[test]
    fn every_items_coarse_levels_come_before_any_finer_level() {
        // Mesh, then levels 2, 1, 0 of three tiles of one view.
        let tile = |d| (0, d, 1, vec![10, 16, 64, 256]);
        let steps = schedule_all(&[tile(2), tile(1), tile(2)], 100);
        let (plan, taken) = &steps[0];
        assert_eq!(
            taken,
            &[(1, 0), (1, 1), (0, 0), (0, 1), (2, 0), (2, 1)],
            "meshes and coarsest levels first, the nearest view's tile first"
        );
        assert_eq!((plan.parts, plan.bytes, plan.backlog), (6, 78, 3));
        // Then one part per step (two do not fit): every level 1, then every level 0.
        let rest: Vec<(usize, usize)> = steps[1..].iter().flat_map(|s| s.1.clone()).collect();
        assert_eq!(rest, [(1, 2), (0, 2), (2, 2), (1, 3), (0, 3), (2, 3)]);
        assert!(steps[1..].iter().all(|(p, _)| p.parts == 1));
    }

    #[test]
    fn views_drawn_come_before_the_others() {
        let drawn = (0, 5, 1, vec![10, 20, 30]);
        let prefetched = (1, 0, 1, vec![10, 20, 30]);
        let steps = schedule_all(&[prefetched, drawn], u64::MAX);
        assert_eq!(steps.len(), 1);
        assert_eq!(steps[0].1, [(1, 0), (1, 1), (1, 2), (0, 0), (0, 1), (0, 2)]);
        assert_eq!(steps[0].0.backlog, 0);
    }

    #[test]
    fn a_step_takes_one_part_larger_than_the_budget() {
        let steps = schedule_all(&[(0, 0, 0, vec![500, 500])], 0);
        assert_eq!(steps.len(), 2);
        for (plan, _) in &steps {
            assert_eq!((plan.parts, plan.bytes), (1, 500));
        }
    }

    proptest::proptest! {
        #[test]
        fn every_part_is_taken_once_within_the_budget(
            items in proptest::collection::vec(
                (0u8..3, 0u64..4, 0usize..2, proptest::collection::vec(0u64..1000, 1..6)),
                1..8,
            ),
            budget in 0u64..3000,
        ) {
            let steps = schedule_all(&items, budget);
            let mut seen = Vec::new();
            for (plan, taken) in &steps {
                proptest::prop_assert!(plan.parts >= 1);
                proptest::prop_assert!(plan.parts == 1 || plan.bytes <= budget);
                let bytes: u64 = taken.iter().map(|&(i, p)| items[i].3[p]).sum();
                proptest::prop_assert_eq!(bytes, plan.bytes);
                seen.extend(taken.iter().copied());
            }
            // Each item's parts once, in order.
            let total: usize = items.iter().map(|it| it.3.len()).sum();
            proptest::prop_assert_eq!(seen.len(), total);
            for (i, it) in items.iter().enumerate() {
                let parts: Vec<usize> =
                    seen.iter().filter(|t| t.0 == i).map(|t| t.1).collect();
                proptest::prop_assert_eq!(parts, (0..it.3.len()).collect::<Vec<_>>());
            }
        }
    }
}
