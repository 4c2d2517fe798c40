//! The viewer benchmark (`railview bench-viewer`): frame time of the full reconstruction
//! (two reference views, all slabs, blending) against a plain single-panorama draw (one
//! cube map, no slabs, no blending), same size, same run, interleaved frame by frame.
//!
//! The frame types are data: [`FrameKind`] names each, and [`FrameKind::settings`] gives
//! what it draws ([`FrameSettings`]: budget, tile ids, the overlay that takes the composite
//! path, camera, skirts, whether `--core` keeps it). [`Bench::new`] checks the walkthrough
//! and plans the cameras; [`Bench::run`] times every frame type against the panorama
//! ([`BenchResult`]), [`Bench::compare_backends`] the main ones on a renderer per wgpu
//! backend ([`BackendResult`]).
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use viewer::bench::{Bench, BenchParams};
//! let walk = viewer::headless::synth_street(
//!     64,
//!     &viewer::synth::Scene::street_slabs(),
//!     viewer::LayerMeshing::default(),
//! )?;
//! let params = BenchParams { width: 160, height: 90, frames: 3, ..Default::default() };
//! let result = Bench::new(&walk, params)?.run()?;
//! eprint!("{}", result.summary());
//! # Ok(()) }
//! ```

use std::time::Instant;

use crate::gpu::{Gpu, GpuError, Renderer, Throughput};
use crate::headless::yaw_along;
use crate::plan::{FramePlan, Overlays, PlanError};
use crate::source::Walkthrough;
use crate::{plan_frame, DrawBudget, RefView};

mod backends;
mod measure;
mod report;

pub use backends::{backends_summary, BackendResult, BackendVariant};
pub use report::{BenchResult, Fragments, Uploads, VariantTimes};

use measure::{cpu_ns, load_average};

/// What [`Bench::run`] and [`Bench::compare_backends`] measure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BenchParams {
    /// Frame size, pixels.
    pub width: u32,
    pub height: u32,
    /// Timed frames per frame type (at least 1).
    pub frames: usize,
    /// Throughput: frames per frame type submitted back to back with one wait at the end
    /// (and GPU timestamps where the adapter has them); 0 = skip.
    pub throughput_frames: usize,
    /// Only the frame types that [`FrameSettings::core`] marks (for large sizes).
    pub core: bool,
    /// Also time a tile arrival: the whole layer rebuilt and re-uploaded against the
    /// tile's region updated ([`Uploads`]).
    pub uploads: bool,
    /// Also count the full frame's mesh fragments per view pass on the CPU reference
    /// ([`Fragments`]).
    pub fragments: bool,
}

impl Default for BenchParams {
    fn default() -> Self {
        BenchParams {
            width: 1920,
            height: 1080,
            frames: 30,
            throughput_frames: 20,
            core: false,
            uploads: false,
            fragments: false,
        }
    }
}

/// Errors of the benchmark.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BenchError {
    #[error("the benchmark needs two reference views")]
    TwoViewsNeeded,
    #[error("the benchmark needs at least one timed frame")]
    NoFrames,
    /// View 0's face and tile sizes make no tile grid.
    #[error("tile grid of view 0")]
    TileGrid,
    #[error("view 0 not uploaded")]
    NotUploaded,
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// The frame types of the benchmark, in the order they are drawn and reported (after the
/// plain panorama); [`FrameKind::settings`] says what each draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// Two views, all slabs, tile ids (a feedback frame: the fused picture and a depth + id
    /// pass per view at a quarter of the width and height, `FramePlan::id_scale`).
    Full,
    /// The same with the tile ids at full resolution.
    FullIdsFullRes,
    /// The same through the composite pass, as feedback frames were drawn before the id
    /// pass (the highlight overlay with no tile highlighted: the same image).
    FullIdsComposite,
    /// Two views, all slabs, no tile ids: fused (no view targets, no composite pass).
    Fused,
    /// The same through the composite pass, the path frames without tile ids took before
    /// the fused one (the hole overlay: the same image where nothing is a hole).
    FusedComposite,
    /// Fused, on a renderer without the half-texel mesh skirts (what they cost).
    FusedWithoutSkirts,
    /// Meshes decimated to mesh level 1, 2.
    Decimated1,
    Decimated2,
    /// One view, all slabs.
    OneView,
    /// Two views, the front slab only.
    OneSlab,
    /// Fused near the first sample (2 % into the segment: second weight 1.2e-3), where the
    /// second view is drawn only where it is nearer than the first or that has a hole or
    /// sky.
    FusedNearSample,
    /// The lighter view at half resolution.
    HalfResSecond,
    /// One view, all slabs, fused.
    OneViewFused,
    /// Two views, the front slab only, fused.
    OneSlabFused,
}

/// Where a frame type's camera stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraAt {
    /// Half way between the first two samples.
    Mid,
    /// Near the first sample ([`FrameKind::FusedNearSample`]).
    NearSample,
}

/// What a frame type draws.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameSettings {
    /// The name reported (`variants[].name` of the JSON).
    pub name: &'static str,
    pub budget: DrawBudget,
    /// [`FramePlan::tile_ids`].
    pub tile_ids: bool,
    /// Tile ids at full resolution ([`FramePlan::id_scale`] 1) instead of the plan's.
    pub full_res_ids: bool,
    /// The overlays set (each leaves the image as it is, but takes the composite path).
    pub overlays: Overlays,
    pub camera: CameraAt,
    /// Drawn with the half-texel mesh skirts (the renderer's default).
    pub skirts: bool,
    /// Kept by [`BenchParams::core`].
    pub core: bool,
}

impl FrameKind {
    /// Every frame type, in order.
    pub const ALL: [FrameKind; 14] = [
        FrameKind::Full,
        FrameKind::FullIdsFullRes,
        FrameKind::FullIdsComposite,
        FrameKind::Fused,
        FrameKind::FusedComposite,
        FrameKind::FusedWithoutSkirts,
        FrameKind::Decimated1,
        FrameKind::Decimated2,
        FrameKind::OneView,
        FrameKind::OneSlab,
        FrameKind::FusedNearSample,
        FrameKind::HalfResSecond,
        FrameKind::OneViewFused,
        FrameKind::OneSlabFused,
    ];

    /// The frame types compared across backends ([`Bench::compare_backends`], after the
    /// plain panorama).
    pub const BACKENDS: [FrameKind; 5] = [
        FrameKind::Fused,
        FrameKind::Full,
        FrameKind::FusedNearSample,
        FrameKind::HalfResSecond,
        FrameKind::OneViewFused,
    ];

    /// What the frame type draws.
    pub fn settings(self) -> FrameSettings {
        let full = FrameSettings {
            name: "",
            budget: DrawBudget::default(),
            tile_ids: true,
            full_res_ids: false,
            overlays: Overlays::default(),
            camera: CameraAt::Mid,
            skirts: true,
            core: true,
        };
        let fused = FrameSettings {
            tile_ids: false,
            ..full
        };
        let one_view = DrawBudget {
            blend: false,
            ..Default::default()
        };
        let one_slab = DrawBudget {
            max_slabs: 1,
            ..Default::default()
        };
        let mesh_level = |mesh_level| DrawBudget {
            mesh_level,
            ..Default::default()
        };
        match self {
            FrameKind::Full => FrameSettings {
                name: "full (2 views x all slabs, tile ids)",
                ..full
            },
            FrameKind::FullIdsFullRes => FrameSettings {
                name: "full, tile ids at full resolution",
                full_res_ids: true,
                ..full
            },
            FrameKind::FullIdsComposite => FrameSettings {
                name: "full, tile ids, composite pass (feedback frames before)",
                overlays: Overlays {
                    highlight: true,
                    ..Default::default()
                },
                ..full
            },
            FrameKind::Fused => FrameSettings {
                name: "full without tile ids (fused)",
                ..fused
            },
            FrameKind::FusedComposite => FrameSettings {
                name: "full without tile ids, composite pass",
                overlays: Overlays {
                    holes: true,
                    ..Default::default()
                },
                ..fused
            },
            FrameKind::FusedWithoutSkirts => FrameSettings {
                name: "full, fused, without mesh skirts",
                skirts: false,
                ..fused
            },
            FrameKind::Decimated1 => FrameSettings {
                name: "full, meshes decimated (level 1)",
                budget: mesh_level(1),
                core: false,
                ..full
            },
            FrameKind::Decimated2 => FrameSettings {
                name: "full, meshes decimated (level 2)",
                budget: mesh_level(2),
                core: false,
                ..full
            },
            FrameKind::OneView => FrameSettings {
                name: "1 view, all slabs",
                budget: one_view,
                core: false,
                ..full
            },
            FrameKind::OneSlab => FrameSettings {
                name: "2 views, 1 slab",
                budget: one_slab,
                core: false,
                ..full
            },
            FrameKind::FusedNearSample => FrameSettings {
                name: "full, fused, near a sample (t = 0.02)",
                camera: CameraAt::NearSample,
                ..fused
            },
            FrameKind::HalfResSecond => FrameSettings {
                name: "full, second view at half resolution",
                budget: DrawBudget {
                    half_res_second: true,
                    ..Default::default()
                },
                ..fused
            },
            FrameKind::OneViewFused => FrameSettings {
                name: "1 view, all slabs, fused",
                budget: one_view,
                core: false,
                ..fused
            },
            FrameKind::OneSlabFused => FrameSettings {
                name: "2 views, 1 slab, fused",
                budget: one_slab,
                core: false,
                ..fused
            },
        }
    }
}

/// Name of the plain panorama's row.
pub const PLAIN: &str = "plain single cube map";

/// Milliseconds per frame of every frame drawn, per row.
type Samples = Vec<Vec<f64>>;

/// A camera of the benchmark and its arc length.
type Placed = (tracks::PerspectiveCamera, f64);

/// The benchmark on one walkthrough: the cameras and the plans every frame type starts
/// from.
pub struct Bench<'a> {
    views: &'a [RefView],
    params: BenchParams,
    /// Between the first two samples, and near the first.
    mid: Placed,
    near: Placed,
    /// The full frame at `mid`, as [`plan_frame`] makes it.
    plan: FramePlan,
    /// The first view's panorama (its layers flattened into one cube map) and its plan.
    pano: [RefView; 1],
    pano_plan: FramePlan,
}

impl<'a> Bench<'a> {
    /// The benchmark of `walk` (at least two reference views) with `params`.
    pub fn new(walk: &'a Walkthrough, params: BenchParams) -> Result<Bench<'a>, BenchError> {
        if walk.views.len() < 2 {
            return Err(BenchError::TwoViewsNeeded);
        }
        if params.frames == 0 {
            return Err(BenchError::NoFrames);
        }
        let camera_at = |s: f64| {
            let camera = tracks::PerspectiveCamera {
                position: walk.position_at(s),
                yaw_deg: yaw_along(walk, s),
                pitch_deg: 0.0,
                fov_deg: 90.0,
                width: params.width,
                height: params.height,
            };
            (camera, s)
        };
        let (a, b) = (&walk.views[0], &walk.views[1]);
        let mid = camera_at(0.5 * (a.s + b.s));
        // 2 % into the segment: second weight 1.2e-3.
        let near = camera_at(a.s + 0.02 * (b.s - a.s));
        let plan = plan_frame(&walk.views, &mid.0, mid.1, DrawBudget::default())?;
        let pano = [RefView::panorama(usize::MAX, a.s, a.position, &a.flatten())];
        let pano_plan = plan_frame(&pano, &mid.0, mid.1, DrawBudget::default())?;
        Ok(Bench {
            views: &walk.views,
            params,
            mid,
            near,
            plan,
            pano,
            pano_plan,
        })
    }

    /// The frame types timed: all, or those [`FrameSettings::core`] marks.
    fn kinds(&self) -> Vec<FrameKind> {
        FrameKind::ALL
            .into_iter()
            .filter(|k| !self.params.core || k.settings().core)
            .collect()
    }

    /// The plan of frame type `kind`.
    fn plan_of(&self, kind: FrameKind) -> Result<FramePlan, BenchError> {
        let set = kind.settings();
        let (camera, s) = match set.camera {
            CameraAt::Mid => &self.mid,
            CameraAt::NearSample => &self.near,
        };
        let mut plan = plan_frame(self.views, camera, *s, set.budget)?;
        plan.tile_ids = set.tile_ids;
        plan.overlays.holes = set.overlays.holes;
        plan.overlays.highlight = set.overlays.highlight;
        if set.full_res_ids {
            plan.id_scale = 1;
        }
        Ok(plan)
    }

    /// The plain panorama's plan, made anew (as each timed frame does).
    fn plain_plan(&self) -> Result<FramePlan, BenchError> {
        let (camera, s) = &self.mid;
        Ok(plan_frame(&self.pano, camera, *s, DrawBudget::default())?)
    }

    /// Time every frame type against the plain panorama on this machine's default adapter.
    pub fn run(&self) -> Result<BenchResult, BenchError> {
        let mut renderers = Renderers {
            skirts: Renderer::new(Gpu::new()?)?,
            bare: Renderer::new(Gpu::new()?)?,
        };
        // A second renderer without the half-texel mesh skirts (what they cost).
        renderers.bare.set_skirts(false);
        let kinds = self.kinds();
        for _ in 0..3 {
            renderers.skirts.draw(&self.plan, self.views)?;
            renderers.bare.draw(&self.plan, self.views)?;
            renderers
                .skirts
                .draw_panorama(&self.pano_plan, &self.pano)?;
        }
        let load_before = load_average();
        let (wall, cpu) = self.time_frames(&mut renderers, &kinds)?;
        let through = self.time_throughput(&mut renderers, &kinds)?;
        let uploads = if self.params.uploads {
            let mut plan = plan_frame(self.views, &self.mid.0, self.mid.1, DrawBudget::default())?;
            plan.tile_ids = false;
            let mut views = self.views.to_vec();
            measure::time_uploads(&mut renderers.skirts, &mut views, &plan, 5)?
        } else {
            None
        };
        let fragments = if self.params.fragments {
            let plan = plan_frame(self.views, &self.mid.0, self.mid.1, DrawBudget::default())?;
            measure::fragments(&plan, self.views)
        } else {
            Vec::new()
        };
        let names = std::iter::once(PLAIN).chain(kinds.iter().map(|k| k.settings().name));
        let r = &renderers.skirts;
        Ok(BenchResult {
            adapter: format!("{} ({:?})", r.gpu.info.name, r.gpu.info.backend),
            width: self.params.width,
            height: self.params.height,
            views: self.plan.passes.len(),
            slabs: self.views[0].slab_count(),
            triangles: measure::triangles(&self.plan, self.views),
            coarse_triangles: measure::coarse_triangles(&self.plan, self.views),
            skirt_triangles: measure::skirt_triangles(&self.plan, self.views),
            load_before,
            load_after: load_average(),
            variants: report::variant_times(names, &wall, &cpu, &through),
            uploads,
            fragments,
        })
    }

    /// Median-ready samples: per row (the plain panorama, then `kinds`) the wall and CPU
    /// milliseconds of every frame, frame types interleaved frame by frame. A frame's time
    /// includes making its plan.
    fn time_frames(
        &self,
        renderers: &mut Renderers,
        kinds: &[FrameKind],
    ) -> Result<(Samples, Samples), BenchError> {
        let mut wall: Vec<Vec<f64>> = vec![Vec::new(); kinds.len() + 1];
        let mut cpu: Vec<Vec<f64>> = vec![Vec::new(); kinds.len() + 1];
        let mut timed = |row: usize, draw: &mut dyn FnMut() -> Result<(), BenchError>| {
            let (t, c) = (Instant::now(), cpu_ns());
            draw()?;
            wall[row].push(t.elapsed().as_secs_f64() * 1e3);
            if let (Some(a), Some(b)) = (c, cpu_ns()) {
                cpu[row].push(b.saturating_sub(a) as f64 / 1e6);
            }
            Ok::<(), BenchError>(())
        };
        for _ in 0..self.params.frames {
            for (k, &kind) in kinds.iter().enumerate() {
                timed(k + 1, &mut || {
                    let plan = self.plan_of(kind)?;
                    renderers.of(kind).draw(&plan, self.views)?;
                    Ok(())
                })?;
            }
            timed(0, &mut || {
                let p = self.plain_plan()?;
                renderers.skirts.draw_panorama(&p, &self.pano)?;
                Ok(())
            })?;
        }
        Ok((wall, cpu))
    }

    /// Throughput of the plain panorama (row 0) and every frame type; none where
    /// [`BenchParams::throughput_frames`] is 0.
    fn time_throughput(
        &self,
        renderers: &mut Renderers,
        kinds: &[FrameKind],
    ) -> Result<Vec<Option<Throughput>>, BenchError> {
        let n = self.params.throughput_frames;
        let mut through: Vec<Option<Throughput>> = vec![None; kinds.len() + 1];
        if n > 0 {
            let p = self.plain_plan()?;
            through[0] = Some(renderers.skirts.throughput_panorama(&p, &self.pano, n)?);
            for (k, &kind) in kinds.iter().enumerate() {
                let plan = self.plan_of(kind)?;
                through[k + 1] = Some(renderers.of(kind).throughput(&plan, self.views, n)?);
            }
        }
        Ok(through)
    }
}

/// The two renderers of [`Bench::run`]: with the half-texel mesh skirts (everything but
/// [`FrameKind::FusedWithoutSkirts`]) and without.
struct Renderers {
    skirts: Renderer,
    bare: Renderer,
}

impl Renderers {
    fn of(&mut self, kind: FrameKind) -> &mut Renderer {
        if kind.settings().skirts {
            &mut self.skirts
        } else {
            &mut self.bare
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_types_keep_their_names_and_core_set() {
        let names: Vec<&str> = FrameKind::ALL.iter().map(|k| k.settings().name).collect();
        assert_eq!(names.len(), 14);
        let unique: std::collections::BTreeSet<&str> = names.iter().copied().collect();
        assert_eq!(unique.len(), names.len());
        let core: Vec<FrameKind> = FrameKind::ALL
            .into_iter()
            .filter(|k| k.settings().core)
            .collect();
        assert_eq!(
            core,
            [
                FrameKind::Full,
                FrameKind::FullIdsFullRes,
                FrameKind::FullIdsComposite,
                FrameKind::Fused,
                FrameKind::FusedComposite,
                FrameKind::FusedWithoutSkirts,
                FrameKind::FusedNearSample,
                FrameKind::HalfResSecond,
            ]
        );
    }

    #[test]
    fn frame_types_compared_across_backends_are_plain_frames() {
        for k in FrameKind::BACKENDS {
            let s = k.settings();
            assert!(s.skirts && !s.full_res_ids, "{k:?}");
            assert_eq!(s.overlays, Overlays::default(), "{k:?}");
        }
    }
}
