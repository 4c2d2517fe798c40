//! Tile-visibility feedback (Goss & Yuasa §3): visible pixels per tile of each view pass,
//! counted on the GPU ([`crate::gpu::Renderer::feedback`]) or on the CPU ([`cpu_counts`]), and
//! turned into request priorities for tiles whose needed level has not arrived
//! ([`missing_priorities`]).

use crate::cpu;
use crate::plan::FramePlan;
use crate::refview::RefView;

/// Visible pixels of every tile of one view (`pixels[i]` for `view.tiles[i]`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewCounts {
    /// Index into the views slice of the plan.
    pub view: usize,
    pub pixels: Vec<u32>,
}

/// A tile to request: which view and tile, how many pixels show it, and the level it needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileRequest {
    pub view: usize,
    pub tile: usize,
    pub pixels: u32,
    /// Weighted by the view's blend weight (a view at weight 0 only fills holes).
    pub priority: f64,
    pub needed_level: u32,
}

/// The same counts computed by the CPU reference renderer.
pub fn cpu_counts(plan: &FramePlan, views: &[RefView]) -> Vec<ViewCounts> {
    plan.passes
        .iter()
        .take(2)
        .filter_map(|p| {
            let v = views.get(p.view)?;
            let img = cpu::view_pass(p, v, plan.width, plan.height);
            let mut pixels = vec![0u32; v.tiles.len()];
            for &t in &img.tile {
                if t > 0 {
                    if let Some(c) = pixels.get_mut(t as usize - 1) {
                        *c += 1;
                    }
                }
            }
            Some(ViewCounts {
                view: p.view,
                pixels,
            })
        })
        .collect()
}

/// Visible tiles drawn coarser than the frame needs, by descending priority
/// (pixels × (blend weight + 0.1), so hole-filling views still get some bandwidth).
pub fn missing_priorities(
    plan: &FramePlan,
    views: &[RefView],
    counts: &[ViewCounts],
) -> Vec<TileRequest> {
    let mut out = Vec::new();
    for c in counts {
        let Some(pass) = plan.passes.iter().find(|p| p.view == c.view) else {
            continue;
        };
        let Some(view) = views.get(c.view) else {
            continue;
        };
        let needed = pass.uniforms.params[0].max(0.0).floor() as u32;
        for (i, &px) in c.pixels.iter().enumerate() {
            let Some(tile) = view.tiles.get(i) else {
                continue;
            };
            if px > 0 && tile.finest_level > needed {
                out.push(TileRequest {
                    view: c.view,
                    tile: i,
                    pixels: px,
                    priority: px as f64 * (pass.weight + 0.1),
                    needed_level: needed,
                });
            }
        }
    }
    out.sort_by(|a, b| b.priority.total_cmp(&a.priority));
    out
}
