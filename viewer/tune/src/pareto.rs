//! Pareto fronts of error against cost, and the cheapest configuration meeting an error target.

use serde::{Deserialize, Serialize};

use crate::record::{Cost, Measured};

/// For each point `(cost, quality)`, whether no other point is at most as costly and at
/// least as good with one of the two strictly better. Points with a non-finite coordinate are
/// never on the front (nor dominate). Equal points are both on the front.
pub fn front(points: &[(f64, f64)]) -> Vec<bool> {
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    points
        .iter()
        .map(|p| {
            finite(p)
                && !points
                    .iter()
                    .any(|q| finite(q) && q.0 <= p.0 && q.1 >= p.1 && (q.0 < p.0 || q.1 > p.1))
        })
        .collect()
}

/// The quality a target is judged on: PSNR of the worst 5 % of views.
pub fn quality(m: &Measured) -> f64 {
    m.error.psnr_worst5_db
}

/// The choice for a PSNR target under one cost.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    pub target_psnr_db: f64,
    pub cost: Cost,
    /// Index of the cheapest configuration whose worst 5 % meets the target (the most
    /// accurate among equally cheap ones); `None` when none does.
    pub chosen: Option<usize>,
    /// Per configuration: meets the target.
    pub meets: Vec<bool>,
    /// Per configuration: on the front of (cost, worst-5 % PSNR).
    pub front: Vec<bool>,
}

/// Choose among `records` the cheapest by `cost` whose worst 5 % of views reach
/// `target_psnr_db`. The choice is always on the front: a configuration cheaper or as cheap
/// and at least as good would also meet the target.
pub fn select(records: &[Measured], target_psnr_db: f64, cost: Cost) -> Selection {
    let points: Vec<(f64, f64)> = records
        .iter()
        .map(|m| (cost.value(m), quality(m)))
        .collect();
    let meets: Vec<bool> = points
        .iter()
        .map(|p| p.0.is_finite() && p.1 >= target_psnr_db)
        .collect();
    let chosen = (0..records.len()).filter(|&i| meets[i]).min_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[b].1.total_cmp(&points[a].1))
    });
    Selection {
        target_psnr_db,
        cost,
        chosen,
        meets,
        front: front(&points),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::knobs::Knobs;
    use crate::record::{Costs, ErrorSummary};
    use proptest::prelude::*;

    fn m(bytes: u64, worst5: f64) -> Measured {
        Measured {
            label: format!("{bytes}"),
            knobs: Knobs::default(),
            samples: 2,
            spacing_m: 1.0,
            slab_count: 1,
            resolution_ratio: 1.0,
            error: ErrorSummary {
                psnr_worst5_db: worst5,
                ..ErrorSummary::default()
            },
            costs: Costs {
                db_bytes: bytes,
                ..Costs::default()
            },
            dir: String::new(),
        }
    }

    #[test]
    fn cheapest_meeting_the_target_is_chosen() {
        let r = vec![
            m(100, 35.0),
            m(50, 31.0),
            m(20, 28.0),
            m(60, 30.0),
            m(50, 32.0),
        ];
        let s = select(&r, 30.0, Cost::DbBytes);
        // 50 bytes twice: the better one (32 dB).
        assert_eq!(s.chosen, Some(4));
        assert_eq!(s.meets, [true, true, false, true, true]);
        assert_eq!(s.front, [true, false, true, false, true]);
        assert!(s.front[s.chosen.unwrap()]);
        assert_eq!(select(&r, 40.0, Cost::DbBytes).chosen, None);
    }

    proptest! {
        #[test]
        fn front_points_are_undominated_and_the_rest_dominated(
            pts in proptest::collection::vec((0.0f64..10.0, 0.0f64..10.0), 1..30)
        ) {
            let f = front(&pts);
            for (i, p) in pts.iter().enumerate() {
                let dominated = pts.iter().any(|q| q.0 <= p.0 && q.1 >= p.1 && (q.0 < p.0 || q.1 > p.1));
                prop_assert_eq!(f[i], !dominated);
            }
            prop_assert!(f.iter().any(|&x| x));
        }

        #[test]
        fn the_choice_is_on_the_front_and_cheapest(
            pts in proptest::collection::vec((1u64..1000, 20.0f64..40.0), 1..30),
            target in 20.0f64..40.0
        ) {
            let r: Vec<Measured> = pts.iter().map(|&(b, q)| m(b, q)).collect();
            let s = select(&r, target, Cost::DbBytes);
            match s.chosen {
                Some(c) => {
                    prop_assert!(s.front[c]);
                    prop_assert!(r[c].error.psnr_worst5_db >= target);
                    for x in r.iter().filter(|x| x.error.psnr_worst5_db >= target) {
                        prop_assert!(x.costs.db_bytes >= r[c].costs.db_bytes);
                    }
                }
                None => prop_assert!(r.iter().all(|x| x.error.psnr_worst5_db < target)),
            }
        }
    }
}
