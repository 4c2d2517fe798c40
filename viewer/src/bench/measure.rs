//! What the benchmark measures besides frame times: the process's CPU time and the load,
//! a tile arrival both ways, mesh fragments on the CPU reference, triangle counts.

use std::time::Instant;

use super::{BenchError, Fragments, Uploads};
use crate::gpu::Renderer;
use crate::plan::FramePlan;
use crate::refview::{decimated_indices, mesh_cell, view_skirts, MESH_LEVELS};
use crate::texture::{dilate_masked, Layer};
use crate::{LayerMeshing, RefView};

/// The median (the upper one of an even count); NaN of nothing.
pub(super) fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Nanoseconds on CPU of all threads of this process (Linux `schedstat`).
pub(super) fn cpu_ns() -> Option<u64> {
    let mut total = 0u64;
    for entry in std::fs::read_dir("/proc/self/task").ok()? {
        let path = entry.ok()?.path().join("schedstat");
        // A thread may exit between listing and reading; it then adds nothing.
        if let Ok(text) = std::fs::read_to_string(path) {
            total += text.split_whitespace().next()?.parse::<u64>().ok()?;
        }
    }
    Some(total)
}

/// The load average over the last minute (Linux `/proc/loadavg`).
pub(super) fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Time one tile arrival in slab 0 of view 0 both ways (median of `reps`); `None` where
/// view 0 has no tile in slab 0.
pub(super) fn time_uploads(
    r: &mut Renderer,
    views: &mut [RefView],
    plan: &FramePlan,
    reps: usize,
) -> Result<Option<Uploads>, BenchError> {
    let Some(tile) = views[0].tiles.iter().find(|t| t.slab == 0).map(|t| t.tile) else {
        return Ok(None);
    };
    let grid = tracks::TileGrid::new(views[0].face_size, views[0].tile_size)
        .ok_or(BenchError::TileGrid)?;
    let rect = grid.pixel_rect(tile);
    // Level 0 is the dense map dilated; dilating it again changes nothing.
    let dense = views[0].layers[1].levels[0].clone();
    let index = views[0].index;
    let mut t = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
    for _ in 0..reps {
        let c = Instant::now();
        views[0].layers[1] = Layer::from_rgba(dilate_masked(&dense));
        t[0].push(c.elapsed().as_secs_f64() * 1e3);
        let c = Instant::now();
        r.invalidate_view(index);
        r.draw(plan, views)?;
        t[2].push(c.elapsed().as_secs_f64() * 1e3);
        let c = Instant::now();
        let rects = views[0].layers[1].update_region(&dense, rect);
        t[1].push(c.elapsed().as_secs_f64() * 1e3);
        let c = Instant::now();
        if !r.update_layer_region(&views[0], 1, &rects) {
            return Err(BenchError::NotUploaded);
        }
        r.draw(plan, views)?;
        t[3].push(c.elapsed().as_secs_f64() * 1e3);
    }
    let [a, b, c, d] = t.map(|v| median(&v));
    Ok(Some(Uploads {
        face_size: views[0].face_size,
        layer_rebuild_ms: a,
        region_update_ms: b,
        frame_after_full_upload_ms: c,
        frame_after_region_upload_ms: d,
    }))
}

/// Mesh fragments of the view passes of `plan` on the CPU reference.
pub(super) fn fragments(plan: &FramePlan, views: &[RefView]) -> Vec<Fragments> {
    plan.passes
        .iter()
        .take(2)
        .filter_map(|p| {
            let v = views.get(p.view)?;
            let f = crate::cpu::view_pass(p, v, plan.width, plan.height).fragments;
            Some(Fragments {
                view: p.view,
                pixels: plan.width as u64 * plan.height as u64,
                rasterised: f.rasterised,
                shaded: f.shaded,
                kept: f.kept,
                covered: f.covered,
            })
        })
        .collect()
}

/// Triangles of the meshes of the views `plan` draws.
pub(super) fn triangles(plan: &FramePlan, views: &[RefView]) -> usize {
    plan.passes
        .iter()
        .map(|p| views[p.view].triangle_count())
        .sum()
}

/// Triangles of the half-texel skirts of the views `plan` draws.
pub(super) fn skirt_triangles(plan: &FramePlan, views: &[RefView]) -> usize {
    plan.passes
        .iter()
        .flat_map(|p| view_skirts(&views[p.view]))
        .map(|(_, i)| i.len() / 3)
        .sum()
}

/// Triangles of the views `plan` draws at each decimated mesh level (1, 2, …).
pub(super) fn coarse_triangles(plan: &FramePlan, views: &[RefView]) -> Vec<usize> {
    (1..=MESH_LEVELS)
        .map(|level| {
            plan.passes
                .iter()
                .map(|p| view_coarse_triangles(&views[p.view], level))
                .sum()
        })
        .collect()
}

/// Triangles of a view's meshes decimated to mesh level `level`.
fn view_coarse_triangles(view: &RefView, level: u32) -> usize {
    let Some(grid) = tracks::TileGrid::new(view.face_size, view.tile_size) else {
        return view.triangle_count();
    };
    let cell = mesh_cell(view.tile_size, level);
    let jump = LayerMeshing::default().jump;
    view.tiles
        .iter()
        .map(|t| decimated_indices(&t.mesh, grid.pixel_rect(t.tile), cell, jump).len() / 3)
        .sum()
}
