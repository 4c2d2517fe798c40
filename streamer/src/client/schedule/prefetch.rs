//! What to prefetch for the next segment.

use std::collections::HashMap;

use tracks::PerspectiveCamera;

use super::{surface_item, Scheduler};
use crate::client::budget::PriorityMode;
use crate::visibility::frustum_half_angle;

impl Scheduler {
    /// What to prefetch for the segments the walker may enter next (`next`: segment and how
    /// likely it is), each list weighted by its likelihood and merged (an item on several
    /// keeps the sum of its weights, and the finest level any needs). Recomputed only when
    /// the segments or the view direction (in 10° steps) change, or tables arrive.
    pub(super) fn prefetch_lists(
        &mut self,
        camera: &PerspectiveCamera,
        next: &[(usize, f64)],
        mode: PriorityMode,
    ) -> Vec<(usize, f64)> {
        if next.is_empty() {
            return Vec::new();
        }
        let memo_key = (
            next.iter()
                .map(|&(e, p)| (e, (p * 1000.0).round() as i64))
                .collect::<Vec<_>>(),
            (camera.yaw_deg / 10.0).round() as i64,
            (camera.pitch_deg / 10.0).round() as i64,
        );
        if let Some((k, list, need)) = &self.prefetch_memo {
            if *k == memo_key {
                let (list, need) = (list.clone(), need.clone());
                self.prefetch_need = need;
                return list;
            }
        }
        let mut weight: HashMap<usize, f64> = HashMap::new();
        let mut need: HashMap<usize, u32> = HashMap::new();
        let mut order: Vec<usize> = Vec::new();
        for &(e, p) in next {
            let list = self.prefetch_list(camera, e, mode);
            for (i, w) in list {
                if !weight.contains_key(&i) {
                    order.push(i);
                }
                *weight.entry(i).or_default() += w * p;
            }
            for (i, l) in std::mem::take(&mut self.prefetch_need) {
                need.entry(i).and_modify(|x| *x = (*x).min(l)).or_insert(l);
            }
        }
        let mut merged: Vec<(usize, f64)> = order.into_iter().map(|i| (i, weight[&i])).collect();
        merged.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        self.prefetch_need = need.clone();
        self.prefetch_memo = Some((memo_key, merged.clone(), need));
        merged
    }

    /// What to prefetch for the next segment `next`: what can be in view on arrival, seen
    /// from the middle of that segment (where both its viewpoints are blended), looking the
    /// way `camera` looks now, within the frustum widened by the turn the walker may make
    /// meanwhile (`prefetch_turn_deg` left and right, half of it up and down). With live
    /// counts (visibility, combined) it is the visibility estimate at that predicted camera,
    /// weighted by visible pixels, cut to the tiles covering `prefetch_coverage` of them
    /// (largest first: slivers at the edge are rarely worth their bytes ahead of time); with
    /// ACH alone it is the segment's ACH list cut to the widened cone. Not the whole ACH list:
    /// tiles behind the walker cost bytes and are rarely shown.
    pub(super) fn prefetch_list(
        &mut self,
        camera: &PerspectiveCamera,
        next: usize,
        mode: PriorityMode,
    ) -> Vec<(usize, f64)> {
        let Some(index) = &self.index else {
            return Vec::new();
        };
        let Some(sg) = self.net.segments.get(next).copied() else {
            return Vec::new();
        };
        let table = &self.table;
        let s_mid = 0.5 * (sg.s0 + sg.s1);
        let position = self.net.tracks[sg.track].position_at(s_mid);
        let turn = self.config.prefetch_turn_deg.max(0.0);
        let list: Vec<(usize, f64)> = if matches!(mode, PriorityMode::Ach) {
            let half = (frustum_half_angle(camera) + turn.to_radians()).min(std::f64::consts::PI);
            table
                .segment_ach
                .get(next)
                .map_or(&[][..], |v| v.as_slice())
                .iter()
                .copied()
                .filter(|&(i, _)| {
                    let it = &table.items[i];
                    it.tile.is_none_or(|tile| {
                        index.tile_in_cone(position, camera.forward(), half, it.viewpoint, tile)
                    })
                })
                .collect()
        } else {
            // Widened by `turn` left and right and by half of it up and down (a walker turns
            // the head sideways more than up or down).
            let tan_v = (camera.fov_deg.to_radians() * 0.5).tan() * camera.height.max(1) as f64
                / camera.width.max(1) as f64;
            let v_half = (tan_v.atan() + 0.5 * turn.to_radians()).min(1.3);
            let fov_deg = (camera.fov_deg + 2.0 * turn).min(150.0);
            let h_tan = (fov_deg.to_radians() * 0.5).tan();
            let ahead = PerspectiveCamera {
                position,
                fov_deg,
                height: ((camera.width as f64 * v_half.tan() / h_tan).round() as u32).max(1),
                ..*camera
            };
            // Half way along the segment both of its viewpoints weigh the same.
            let weights = vec![(sg.from, 0.5), (sg.to, 0.5)];
            let (sx, sy) = self.config.samples;
            let counts = index.count(&ahead, &weights, sx, sy);
            let mut need: HashMap<usize, u32> = HashMap::new();
            let mut px: HashMap<usize, f64> = HashMap::new();
            for c in &counts {
                if let Some(i) = surface_item(table, c) {
                    let l = c.finest_needed();
                    need.entry(i).and_modify(|x| *x = (*x).min(l)).or_insert(l);
                    *px.entry(i).or_default() += c.pixels();
                }
            }
            self.prefetch_need = need;
            let mut seen: Vec<(usize, f64)> = px.into_iter().filter(|x| x.1 > 0.0).collect();
            seen.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            let total: f64 = seen.iter().map(|x| x.1).sum();
            let mut acc = 0.0;
            let keep = seen
                .iter()
                .take_while(|x| {
                    let before = acc;
                    acc += x.1;
                    before < self.config.prefetch_coverage * total
                })
                .count();
            seen.truncate(keep);
            seen
        };
        list
    }
}
