//! What the scheduler sees of the view: the visibility estimate merged with the caller's
//! counts, the current segment's ACH list cut to the frustum, and the figures of a tick.

use std::collections::HashMap;

use tracks::PerspectiveCamera;

use super::{surface_item, CpuCounts, Scheduler};
use crate::client::budget::{ItemInfo, LiveCount};
use crate::visibility::frustum_half_angle;

/// `(item, weight)` lists.
type Weighted = Vec<(usize, f64)>;

impl Scheduler {
    /// The current segment's ACH list cut to the view frustum, and to the frustum widened
    /// by the prefetch turn; both with the backgrounds of the two viewpoints around, ranked
    /// with the strongest tile (they fill everything no tile covers).
    pub(super) fn frustum_ach(
        &self,
        camera: &PerspectiveCamera,
        seg_ach: &[(usize, f64)],
        backgrounds: &[usize],
    ) -> (Weighted, Weighted) {
        let half = frustum_half_angle(camera);
        let wide =
            (half + self.config.prefetch_turn_deg.max(0.0).to_radians()).min(std::f64::consts::PI);
        let in_cone = |i: usize, h: f64| {
            let it = &self.table.items[i];
            match (&self.index, it.tile) {
                (_, None) => true,
                (Some(index), Some(tile)) => {
                    index.tile_in_cone(camera.position, camera.forward(), h, it.viewpoint, tile)
                }
                (None, Some(_)) => true,
            }
        };
        let mut view: Vec<(usize, f64)> = seg_ach
            .iter()
            .copied()
            .filter(|&(i, _)| in_cone(i, half))
            .collect();
        let mut widened: Vec<(usize, f64)> = seg_ach
            .iter()
            .copied()
            .filter(|&(i, _)| in_cone(i, wide))
            .collect();
        let top = seg_ach.iter().map(|a| a.1).fold(0.0f64, f64::max);
        let top = if top > 0.0 { top } else { 1.0 };
        view.extend(backgrounds.iter().map(|&b| (b, top)));
        widened.extend(backgrounds.iter().map(|&b| (b, top)));
        (view, widened)
    }

    /// CPU visibility counts at `camera` (counted again only when the camera or the blend
    /// weights changed), merged with the caller's per item: the larger count and the finer
    /// need (a tile drawn from a coarse level may show fewer pixels than it will, one the
    /// CPU march missed may show more).
    pub(super) fn count(
        &mut self,
        s: f64,
        camera: &PerspectiveCamera,
        live: Option<&[LiveCount]>,
    ) -> Vec<LiveCount> {
        let mut by_item: HashMap<usize, LiveCount> = HashMap::new();
        if let Some(index) = &self.index {
            let weights = self.pair(s);
            let same = self
                .cpu_counts
                .as_ref()
                .is_some_and(|c| c.camera == *camera && c.weights == weights);
            if !same {
                let (sx, sy) = self.config.samples;
                let counts = index
                    .count(camera, &weights, sx, sy)
                    .iter()
                    .filter_map(|c| {
                        Some(LiveCount {
                            item: surface_item(&self.table, c)?,
                            pixels: c.pixels(),
                            needed_level: c.finest_needed(),
                        })
                    })
                    .collect();
                self.cpu_counts = Some(CpuCounts {
                    camera: *camera,
                    weights,
                    counts,
                });
            }
            for c in self.cpu_counts.iter().flat_map(|c| &c.counts) {
                by_item
                    .entry(c.item)
                    .and_modify(|e| {
                        e.pixels += c.pixels;
                        e.needed_level = e.needed_level.min(c.needed_level);
                    })
                    .or_insert(*c);
            }
        }
        for c in live.unwrap_or(&[]) {
            if c.item >= self.table.items.len() || !c.pixels.is_finite() {
                continue;
            }
            by_item
                .entry(c.item)
                .and_modify(|e| {
                    e.pixels = e.pixels.max(c.pixels);
                    e.needed_level = e.needed_level.min(c.needed_level);
                })
                .or_insert(*c);
        }
        let mut out: Vec<LiveCount> = by_item.into_values().filter(|c| c.pixels > 0.0).collect();
        out.sort_by_key(|c| c.item);
        out
    }

    pub(super) fn update_stats(
        &mut self,
        s: f64,
        have: &[usize],
        seg_ach: &[(usize, f64)],
        bgs: &[usize],
    ) {
        let quality = if seg_ach.is_empty() {
            0.0
        } else {
            seg_ach
                .iter()
                .map(|&(i, _)| {
                    let info = &self.infos[i];
                    let groups = info.levels.len().max(1) as f64;
                    have[i].saturating_sub(info.first_level_part) as f64 / groups
                })
                .sum::<f64>()
                / seg_ach.len() as f64
        };
        // A viewpoint of the segment whose table has not arrived counts as one item not
        // showable (its tiles are not even known yet).
        let tables_missing = self
            .pair(s)
            .iter()
            .filter(|w| !self.table.has_viewpoint(w.0))
            .count();
        let showable: Vec<bool> = seg_ach
            .iter()
            .map(|a| a.0)
            .chain(bgs.iter().copied())
            .map(|i| have[i] >= self.infos[i].min_parts())
            .chain(std::iter::repeat_n(false, tables_missing))
            .collect();
        self.stats.quality = quality;
        self.stats.coarse_fraction = if showable.is_empty() {
            1.0
        } else {
            showable.iter().filter(|&&b| b).count() as f64 / showable.len() as f64
        };
        self.stats.visible_fraction = visible_fraction(&self.live, have, &self.infos);
        self.stats.memory_budget_bytes = self.budget.memory_bytes;
    }
}

/// Fraction of the counted pixels whose item holds at least its coarsest level. With no
/// pixel counted, 0: the tables of the viewpoints around are not known yet, so nothing can
/// be shown (every pixel counts for some item once they are: backgrounds fill what no tile
/// covers).
fn visible_fraction(counts: &[LiveCount], have: &[usize], infos: &[ItemInfo]) -> f64 {
    let total: f64 = counts.iter().map(|c| c.pixels).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let shown: f64 = counts
        .iter()
        .filter(|c| have.get(c.item).copied().unwrap_or(0) >= infos[c.item].min_parts())
        .map(|c| c.pixels)
        .sum();
    shown / total
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info() -> ItemInfo {
        ItemInfo {
            part_bytes: vec![100, 200, 400],
            part_mem: vec![0, 300, 1200],
            first_level_part: 1,
            levels: vec![1, 0],
        }
    }

    #[test]
    fn nothing_counted_is_nothing_shown() {
        assert_eq!(visible_fraction(&[], &[], &[info()]), 0.0);
        let zero = LiveCount {
            item: 0,
            pixels: 0.0,
            needed_level: 0,
        };
        assert_eq!(visible_fraction(&[zero], &[3], &[info()]), 0.0);
    }

    #[test]
    fn the_fraction_weighs_items_by_their_pixels_and_needs_the_coarsest_level() {
        let counts = [
            LiveCount {
                item: 0,
                pixels: 30.0,
                needed_level: 0,
            },
            LiveCount {
                item: 1,
                pixels: 10.0,
                needed_level: 0,
            },
        ];
        let infos = [info(), info()];
        assert_eq!(visible_fraction(&counts, &[2, 1], &infos), 0.75);
        assert_eq!(visible_fraction(&counts, &[3, 2], &infos), 1.0);
        assert_eq!(visible_fraction(&counts, &[0, 0], &infos), 0.0);
    }
}
