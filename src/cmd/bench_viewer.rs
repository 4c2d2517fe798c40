//! `railview bench-viewer`: frame time of the full reconstruction (two reference views, all
//! slabs, blending) against a plain single-panorama draw (one cube map, no slabs, no
//! blending), same size, same run, interleaved frame by frame.

use std::time::Instant;

use anyhow::Context;
use viewer::gpu::{Gpu, GpuRequest, Renderer};
use viewer::headless::{open, parse_size, synth_street, yaw_along};
use viewer::source::LoadOptions;
use viewer::{plan_frame, DrawBudget, MeshParams, RefView};

/// Arguments of `railview bench-viewer`.
#[derive(clap::Args)]
pub struct Args {
    /// Database or prerender directory; default: the synthetic street at `--face` pixels.
    pub db: Option<String>,
    /// Frame size WxH.
    #[arg(long, default_value = "1920x1080")]
    pub size: String,
    /// Face size of the synthetic street.
    #[arg(long, default_value_t = 512)]
    pub face: u32,
    /// Meshes of the synthetic street: `adaptive` (error-bounded Delaunay meshes, 0.5 px of
    /// parallax at the sample spacing, as `railview build` stores in databases) or `grid`
    /// (a vertex every `--mesh-step` pixels).
    #[arg(long, default_value = "adaptive")]
    pub mesh: String,
    /// Mesh grid step (pixels) of the synthetic street with `--mesh grid`.
    #[arg(long, default_value_t = 4)]
    pub mesh_step: u32,
    /// Timed frames per variant.
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Throughput: frames per variant submitted back to back with one wait at the end
    /// (and GPU timestamps where the adapter has them); 0 = skip.
    #[arg(long, default_value_t = 20)]
    pub throughput_frames: usize,
    /// Only the plain panorama, the full frame (with and without tile ids) and the
    /// half-resolution second view: for large sizes such as `--size 3840x2160`.
    #[arg(long)]
    pub core: bool,
    /// Also time a tile arrival: rebuilding and re-uploading the whole layer against
    /// updating the tile's region (`Layer::update_region`, `Renderer::update_layer_region`).
    #[arg(long)]
    pub uploads: bool,
    /// Write the results as JSON here.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
    /// Compare wgpu backends instead (e.g. `vulkan,gl`): the main frame types drawn on a
    /// renderer per backend, interleaved frame by frame in one run; medians per backend and
    /// each backend's ratio to the first.
    #[arg(long, value_delimiter = ',')]
    pub backends: Vec<String>,
    /// Also count the full frame's mesh fragments per view pass on the CPU reference
    /// (`viewer::cpu`, same plan): rasterised, shaded after the depth test in drawing order
    /// (early depth testing), kept by the opacity mask, pixels covered (overdraw).
    #[arg(long)]
    pub fragments: bool,
}

/// One timed configuration: median wall-clock and CPU milliseconds per frame.
#[derive(serde::Serialize)]
struct Variant {
    name: String,
    wall_ms: f64,
    /// CPU time of all threads of this process (llvmpipe renders on its own threads), so a
    /// loaded machine inflates it much less than the wall clock; `None` without
    /// `/proc/self/task`.
    cpu_ms: Option<f64>,
    /// `wall_ms` and `cpu_ms` over the plain panorama's.
    wall_ratio: f64,
    cpu_ratio: Option<f64>,
    /// Throughput (`--throughput-frames` submitted back to back, one wait): wall ms per
    /// frame, frames per second, and the median GPU time of one frame (timestamp queries;
    /// `None` where the adapter has none).
    throughput_ms: Option<f64>,
    throughput_fps: Option<f64>,
    gpu_ms: Option<f64>,
}

#[derive(serde::Serialize)]
struct BenchResult {
    adapter: String,
    width: u32,
    height: u32,
    views: usize,
    slabs: usize,
    triangles: usize,
    /// Triangles drawn at mesh levels 1, 2 (decimated).
    coarse_triangles: Vec<usize>,
    /// Triangles of the half-texel skirts (`viewer::refview::skirt`), drawn besides
    /// `triangles` at every mesh level.
    skirt_triangles: usize,
    /// Load average (1 min) before and after the run.
    load_before: Option<f64>,
    load_after: Option<f64>,
    variants: Vec<Variant>,
    /// With `--uploads`: one tile arriving in slab 0 of the first view.
    uploads: Option<Uploads>,
    /// With `--fragments`: mesh fragments of the full frame's view passes.
    fragments: Vec<Fragments>,
}

/// Mesh fragments of one view pass of the full frame (`viewer::cpu::Fragments`).
#[derive(serde::Serialize)]
struct Fragments {
    view: usize,
    pixels: u64,
    rasterised: u64,
    shaded: u64,
    kept: u64,
    covered: u64,
}

/// Median milliseconds of one tile arrival, whole layer against the tile's region.
#[derive(serde::Serialize)]
struct Uploads {
    face_size: u32,
    /// CPU: `Layer::from_rgba(dilate_masked(..))` of the whole layer.
    layer_rebuild_ms: f64,
    /// CPU: `Layer::update_region` of the tile.
    region_update_ms: f64,
    /// Next frame including the upload: the view re-uploaded whole (`invalidate_view`).
    frame_after_full_upload_ms: f64,
    /// Next frame after `update_layer_region` of the tile's texels.
    frame_after_region_upload_ms: f64,
}

/// Time one tile arrival in slab 0 of view 0 both ways (median of `reps`).
fn time_uploads(
    r: &mut Renderer,
    views: &mut [RefView],
    plan: &viewer::FramePlan,
    reps: usize,
) -> anyhow::Result<Option<Uploads>> {
    use viewer::texture::{dilate_masked, Layer};
    let Some(tile) = views[0].tiles.iter().find(|t| t.slab == 0).map(|t| t.tile) else {
        return Ok(None);
    };
    let grid = tracks::TileGrid::new(views[0].face_size, views[0].tile_size)
        .context("tile grid of view 0")?;
    let rect = tracks::PixelRect::of_tile(grid, tile);
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
        anyhow::ensure!(
            r.update_layer_region(&views[0], 1, &rects),
            "view 0 not uploaded"
        );
        r.draw(plan, views)?;
        t[3].push(c.elapsed().as_secs_f64() * 1e3);
    }
    let [a, b, c, d] = t.map(median);
    Ok(Some(Uploads {
        face_size: views[0].face_size,
        layer_rebuild_ms: a,
        region_update_ms: b,
        frame_after_full_upload_ms: c,
        frame_after_region_upload_ms: d,
    }))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Nanoseconds on CPU of all threads of this process (Linux `schedstat`).
fn cpu_ns() -> Option<u64> {
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

/// Triangles of a view's meshes decimated to mesh level `level`.
fn coarse_triangles(view: &RefView, level: u32) -> usize {
    let Some(grid) = tracks::TileGrid::new(view.face_size, view.tile_size) else {
        return view.triangle_count();
    };
    let cell = viewer::refview::mesh_cell(view.tile_size, level);
    let jump = MeshParams::default().jump;
    view.tiles
        .iter()
        .map(|t| {
            viewer::refview::decimated_indices(
                &t.mesh,
                tracks::PixelRect::of_tile(grid, t.tile),
                cell,
                jump,
            )
            .len()
                / 3
        })
        .sum()
}

fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    super::count("--frames", args.frames, 100_000)?;
    super::count("--throughput-frames", args.throughput_frames, 100_000)?;
    super::face_size("--face", args.face)?;
    super::count("--mesh-step", args.mesh_step as usize, 4096)?;
    let mesh = MeshParams {
        step: args.mesh_step,
        adaptive: match args.mesh.as_str() {
            // The street's samples are 1.5 m apart (its largest baseline).
            "adaptive" => Some(viewer::refview::AdaptiveMesh::database(1.5)),
            "grid" => None,
            other => anyhow::bail!("--mesh {other}: expected `adaptive` or `grid`"),
        },
        ..Default::default()
    };
    let walk = match &args.db {
        Some(db) => open(
            db,
            None,
            LoadOptions {
                mesh,
                ..Default::default()
            },
        )
        .with_context(|| format!("opening {db}"))?,
        None => synth_street(args.face, &viewer::synth::Scene::street_slabs(), mesh)?,
    };
    anyhow::ensure!(
        walk.views.len() >= 2,
        "the benchmark needs two reference views"
    );
    let camera_at = |s: f64| tracks::PerspectiveCamera {
        position: walk.position_at(s),
        yaw_deg: yaw_along(&walk, s),
        pitch_deg: 0.0,
        fov_deg: 90.0,
        width: w,
        height: h,
    };
    let s = 0.5 * (walk.views[0].s + walk.views[1].s);
    let camera = camera_at(s);
    // Near the first sample (2 % into the segment: second weight 1.2e-3), where the second
    // view is drawn only where it is nearer than the first or that has a hole or sky.
    let s_near = walk.views[0].s + 0.02 * (walk.views[1].s - walk.views[0].s);
    let camera_near = camera_at(s_near);
    let at = |name: &str| {
        if name.contains("near a sample") {
            (&camera_near, s_near)
        } else {
            (&camera, s)
        }
    };
    let plan = plan_frame(&walk.views, &camera, s, DrawBudget::default())?;
    let pano = [RefView::panorama(
        usize::MAX,
        walk.views[0].s,
        walk.views[0].position,
        &walk.views[0].flatten(),
    )];
    let pano_plan = plan_frame(&pano, &camera, s, DrawBudget::default())?;
    if !args.backends.is_empty() {
        let cameras = Cameras {
            mid: (&camera, s),
            near: (&camera_near, s_near),
        };
        return compare_backends(&args, &walk.views, &pano, &cameras);
    }
    let mut r = Renderer::new(Gpu::new()?)?;
    // A second renderer without the half-texel mesh skirts (what they cost).
    let mut r_bare = Renderer::new(Gpu::new()?)?;
    r_bare.set_skirts(false);
    // (name, budget, tile ids written); frames without overlays take the fused path (no
    // view targets, no composite pass), feedback frames (tile ids) add a depth + id pass per
    // view at a quarter of the width and height (`FramePlan::id_scale`).
    let variants: Vec<(&str, DrawBudget, bool)> = vec![
        (
            "full (2 views x all slabs, tile ids)",
            DrawBudget::default(),
            true,
        ),
        (
            "full, tile ids at full resolution",
            DrawBudget::default(),
            true,
        ),
        (
            "full, tile ids, composite pass (feedback frames before)",
            DrawBudget::default(),
            true,
        ),
        (
            "full without tile ids (fused)",
            DrawBudget::default(),
            false,
        ),
        (
            "full without tile ids, composite pass",
            DrawBudget::default(),
            false,
        ),
        (
            "full, fused, without mesh skirts",
            DrawBudget::default(),
            false,
        ),
        (
            "full, meshes decimated (level 1)",
            DrawBudget {
                mesh_level: 1,
                ..Default::default()
            },
            true,
        ),
        (
            "full, meshes decimated (level 2)",
            DrawBudget {
                mesh_level: 2,
                ..Default::default()
            },
            true,
        ),
        (
            "1 view, all slabs",
            DrawBudget {
                blend: false,
                ..Default::default()
            },
            true,
        ),
        (
            "2 views, 1 slab",
            DrawBudget {
                max_slabs: 1,
                ..Default::default()
            },
            true,
        ),
        (
            "full, fused, near a sample (t = 0.02)",
            DrawBudget::default(),
            false,
        ),
        (
            "full, second view at half resolution",
            DrawBudget {
                half_res_second: true,
                ..Default::default()
            },
            false,
        ),
        (
            "1 view, all slabs, fused",
            DrawBudget {
                blend: false,
                ..Default::default()
            },
            false,
        ),
        (
            "2 views, 1 slab, fused",
            DrawBudget {
                max_slabs: 1,
                ..Default::default()
            },
            false,
        ),
    ];
    let variants: Vec<(&str, DrawBudget, bool)> = if args.core {
        variants
            .into_iter()
            .filter(|v| {
                v.0.starts_with("full (")
                    || v.0.starts_with("full without tile ids (fused)")
                    || v.0.contains("near a sample")
                    || v.0.contains("half resolution")
                    || v.0.contains("tile ids")
                    || v.0.contains("skirts")
            })
            .collect()
    } else {
        variants
    };
    let composite_variant = variants
        .iter()
        .position(|v| v.0 == "full without tile ids, composite pass");
    // The hole overlay needs no tile ids but the composite pass: the path frames without
    // tile ids took before the fused one (same image where nothing is a hole). The highlight
    // overlay (no tile highlighted: the same image) takes the composite path with
    // full-resolution tile ids, as feedback frames did before the id pass.
    let adjust = |plan: &mut viewer::plan::FramePlan, k: usize, name: &str| {
        plan.overlays.holes = Some(k) == composite_variant;
        plan.overlays.highlight = name.contains("feedback frames before");
        if name.contains("ids at full resolution") {
            plan.id_scale = 1;
        }
    };
    for _ in 0..3 {
        r.draw(&plan, &walk.views)?;
        r_bare.draw(&plan, &walk.views)?;
        r.draw_panorama(&pano_plan, &pano)?;
    }
    let load_before = load_average();
    let mut wall: Vec<Vec<f64>> = vec![Vec::new(); variants.len() + 1];
    let mut cpu: Vec<Vec<f64>> = vec![Vec::new(); variants.len() + 1];
    for _ in 0..args.frames {
        for (k, (name, budget, ids)) in variants.iter().enumerate() {
            let (t, c) = (Instant::now(), cpu_ns());
            let (camera, s) = at(name);
            let mut plan = plan_frame(&walk.views, camera, s, *budget)?;
            plan.tile_ids = *ids;
            adjust(&mut plan, k, name);
            if name.contains("without mesh skirts") {
                r_bare.draw(&plan, &walk.views)?;
            } else {
                r.draw(&plan, &walk.views)?;
            }
            wall[k + 1].push(t.elapsed().as_secs_f64() * 1e3);
            if let (Some(a), Some(b)) = (c, cpu_ns()) {
                cpu[k + 1].push(b.saturating_sub(a) as f64 / 1e6);
            }
        }
        let (t, c) = (Instant::now(), cpu_ns());
        let p = plan_frame(&pano, &camera, s, DrawBudget::default())?;
        r.draw_panorama(&p, &pano)?;
        wall[0].push(t.elapsed().as_secs_f64() * 1e3);
        if let (Some(a), Some(b)) = (c, cpu_ns()) {
            cpu[0].push(b.saturating_sub(a) as f64 / 1e6);
        }
    }
    // Throughput of each variant and the plain panorama (index 0).
    let mut through: Vec<Option<viewer::gpu::Throughput>> = vec![None; variants.len() + 1];
    if args.throughput_frames > 0 {
        let p = plan_frame(&pano, &camera, s, DrawBudget::default())?;
        through[0] = Some(r.throughput_panorama(&p, &pano, args.throughput_frames)?);
        for (k, (name, budget, ids)) in variants.iter().enumerate() {
            let (camera, s) = at(name);
            let mut plan = plan_frame(&walk.views, camera, s, *budget)?;
            plan.tile_ids = *ids;
            adjust(&mut plan, k, name);
            let rr = if name.contains("without mesh skirts") {
                &mut r_bare
            } else {
                &mut r
            };
            through[k + 1] = Some(rr.throughput(&plan, &walk.views, args.throughput_frames)?);
        }
    }
    let names: Vec<&str> = std::iter::once("plain single cube map")
        .chain(variants.iter().map(|v| v.0))
        .collect();
    let med = |v: &Vec<f64>| (!v.is_empty()).then(|| median(v.clone()));
    let (plain_wall, plain_cpu) = (median(wall[0].clone()), med(&cpu[0]));
    let uploads = if args.uploads {
        let mut plan = plan_frame(&walk.views, &camera, s, DrawBudget::default())?;
        plan.tile_ids = false;
        let mut views = walk.views.clone();
        time_uploads(&mut r, &mut views, &plan, 5)?
    } else {
        None
    };
    let fragments: Vec<Fragments> = if args.fragments {
        let plan = plan_frame(&walk.views, &camera, s, DrawBudget::default())?;
        plan.passes
            .iter()
            .take(2)
            .filter_map(|p| {
                let v = walk.views.get(p.view)?;
                let f = viewer::cpu::view_pass(p, v, plan.width, plan.height).fragments;
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
    } else {
        Vec::new()
    };
    for f in &fragments {
        let px = f.pixels.max(1) as f64;
        eprintln!(
            "view {} mesh fragments per frame pixel: rasterised {:.2}, shaded (early depth) {:.2}, kept {:.2}; covered {:.2}",
            f.view,
            f.rasterised as f64 / px,
            f.shaded as f64 / px,
            f.kept as f64 / px,
            f.covered as f64 / px
        );
    }
    let res = BenchResult {
        fragments,
        uploads,
        adapter: format!("{} ({:?})", r.gpu.info.name, r.gpu.info.backend),
        width: w,
        height: h,
        views: plan.passes.len(),
        slabs: walk.views[0].slab_count(),
        triangles: plan
            .passes
            .iter()
            .map(|p| walk.views[p.view].triangle_count())
            .sum(),
        skirt_triangles: plan
            .passes
            .iter()
            .flat_map(|p| viewer::refview::view_skirts(&walk.views[p.view]))
            .map(|(_, i)| i.len() / 3)
            .sum(),
        coarse_triangles: (1..=viewer::refview::MESH_LEVELS)
            .map(|level| {
                plan.passes
                    .iter()
                    .map(|p| coarse_triangles(&walk.views[p.view], level))
                    .sum()
            })
            .collect(),
        load_before,
        load_after: load_average(),
        variants: names
            .iter()
            .zip(wall.iter().zip(&cpu))
            .zip(&through)
            .map(|((name, (wv, cv)), t)| {
                let (wall_ms, cpu_ms) = (median(wv.clone()), med(cv));
                Variant {
                    name: name.to_string(),
                    wall_ms,
                    cpu_ms,
                    wall_ratio: wall_ms / plain_wall,
                    cpu_ratio: cpu_ms.zip(plain_cpu).map(|(a, b)| a / b),
                    throughput_ms: t.map(|t| t.wall_ms),
                    throughput_fps: t.map(|t| 1e3 / t.wall_ms),
                    gpu_ms: t.and_then(|t| t.gpu_ms),
                }
            })
            .collect(),
    };
    let plain_gpu = res.variants.first().and_then(|v| v.gpu_ms);
    for v in &res.variants {
        eprintln!(
            "{:<40} {:>8.1} ms wall ({:>4.2}x)  {:>8.1} ms cpu ({:>4.2}x)  throughput {:>7.2} ms ({:>6.1} fps)  gpu {:>7.3} ms ({:>4.2}x)",
            v.name,
            v.wall_ms,
            v.wall_ratio,
            v.cpu_ms.unwrap_or(f64::NAN),
            v.cpu_ratio.unwrap_or(f64::NAN),
            v.throughput_ms.unwrap_or(f64::NAN),
            v.throughput_fps.unwrap_or(f64::NAN),
            v.gpu_ms.unwrap_or(f64::NAN),
            v.gpu_ms.zip(plain_gpu).map_or(f64::NAN, |(a, b)| a / b),
        );
    }
    if let Some(u) = &res.uploads {
        eprintln!(
            "tile arrival at face {}: layer rebuild {:.1} ms, region update {:.3} ms; next frame with full upload {:.1} ms, with region upload {:.1} ms",
            u.face_size,
            u.layer_rebuild_ms,
            u.region_update_ms,
            u.frame_after_full_upload_ms,
            u.frame_after_region_upload_ms
        );
    }
    eprintln!(
        "triangles {} (+ {} of skirts)",
        res.triangles, res.skirt_triangles
    );
    println!("{}", serde_json::to_string_pretty(&res)?);
    if let Some(path) = &args.json {
        prerender::store::write_json(path, &res)?;
    }
    Ok(())
}

/// The cameras of the benchmark: between the first two samples, and near the first.
struct Cameras<'a> {
    mid: (&'a tracks::PerspectiveCamera, f64),
    near: (&'a tracks::PerspectiveCamera, f64),
}

/// A frame type of `--backends`: budget, tile ids written, near a sample.
type FrameKind = (DrawBudget, bool, bool);

/// One backend of `--backends`: its adapter and, per frame type, median wall ms per frame
/// drawn and waited for, throughput ms per frame, and the ratio of both to the first
/// backend's.
#[derive(serde::Serialize)]
struct BackendResult {
    backend: String,
    adapter: String,
    /// Capabilities the device lacks (fallback paths taken).
    without: String,
    variants: Vec<BackendVariant>,
}

#[derive(serde::Serialize)]
struct BackendVariant {
    name: String,
    wall_ms: f64,
    /// CPU time of all the process's threads while the frame was drawn (only that
    /// backend's renderer works then; steadier than the wall clock on a loaded machine).
    cpu_ms: Option<f64>,
    throughput_ms: Option<f64>,
    wall_ratio: f64,
    cpu_ratio: Option<f64>,
    throughput_ratio: Option<f64>,
}

/// `--backends`: the main frame types on a renderer per backend, frames interleaved across
/// backends (one frame of each backend in turn), so a load change hits all alike.
fn compare_backends(
    args: &Args,
    views: &[RefView],
    pano: &[RefView],
    cameras: &Cameras<'_>,
) -> anyhow::Result<()> {
    let mut renderers = Vec::new();
    for name in &args.backends {
        let request = GpuRequest::for_backend(name)
            .with_context(|| format!("--backends {name}: expected vulkan, gl, metal or dx12"))?;
        let gpu = Gpu::request(&request).with_context(|| format!("--backends {name}"))?;
        renderers.push((name.clone(), Renderer::new(gpu)?));
    }
    // (name, (budget, tile ids, near a sample)); `None`: the plain panorama.
    let kinds: Vec<(&str, Option<FrameKind>)> = vec![
        ("plain single cube map", None),
        (
            "full without tile ids (fused)",
            Some((DrawBudget::default(), false, false)),
        ),
        (
            "full (2 views x all slabs, tile ids)",
            Some((DrawBudget::default(), true, false)),
        ),
        (
            "full, fused, near a sample (t = 0.02)",
            Some((DrawBudget::default(), false, true)),
        ),
        (
            "full, second view at half resolution",
            Some((
                DrawBudget {
                    half_res_second: true,
                    ..Default::default()
                },
                false,
                false,
            )),
        ),
        (
            "1 view, all slabs, fused",
            Some((
                DrawBudget {
                    blend: false,
                    ..Default::default()
                },
                false,
                false,
            )),
        ),
    ];
    let plan_of = |kind: &Option<FrameKind>| -> anyhow::Result<viewer::FramePlan> {
        let (camera, s) = cameras.mid;
        Ok(match kind {
            None => plan_frame(pano, camera, s, DrawBudget::default())?,
            Some((budget, ids, near)) => {
                let (camera, s) = if *near { cameras.near } else { cameras.mid };
                let mut p = plan_frame(views, camera, s, *budget)?;
                p.tile_ids = *ids;
                p
            }
        })
    };
    let plans: Vec<viewer::FramePlan> = kinds
        .iter()
        .map(|(_, k)| plan_of(k))
        .collect::<anyhow::Result<_>>()?;
    let draw = |r: &mut Renderer, k: usize| -> anyhow::Result<()> {
        match kinds[k].1 {
            None => r.draw_panorama(&plans[k], pano)?,
            Some(_) => r.draw(&plans[k], views)?,
        }
        Ok(())
    };
    // Warm-up: uploads, pipelines, first use of every path.
    for (_, r) in &mut renderers {
        for k in 0..kinds.len() {
            for _ in 0..2 {
                draw(r, k)?;
            }
        }
    }
    // wall[frame type][backend], cpu likewise: ms per frame.
    let mut wall = vec![vec![Vec::new(); renderers.len()]; kinds.len()];
    let mut cpu = wall.clone();
    for _ in 0..args.frames {
        for (k, (per_backend, cpu_per_backend)) in wall.iter_mut().zip(&mut cpu).enumerate() {
            for ((_, r), (times, cpu_times)) in renderers
                .iter_mut()
                .zip(per_backend.iter_mut().zip(cpu_per_backend.iter_mut()))
            {
                let (t, c) = (Instant::now(), cpu_ns());
                draw(r, k)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                if let (Some(a), Some(b)) = (c, cpu_ns()) {
                    cpu_times.push(b.saturating_sub(a) as f64 / 1e6);
                }
            }
        }
    }
    let mut through = vec![vec![None; kinds.len()]; renderers.len()];
    if args.throughput_frames > 0 {
        for (k, (plan, (_, kind))) in plans.iter().zip(&kinds).enumerate() {
            for (b, (_, r)) in renderers.iter_mut().enumerate() {
                let t = match kind {
                    None => r.throughput_panorama(plan, pano, args.throughput_frames)?,
                    Some(_) => r.throughput(plan, views, args.throughput_frames)?,
                };
                through[b][k] = Some(t.wall_ms);
            }
        }
    }
    // walls[backend][frame type]: median ms; cpus likewise where measured.
    let walls: Vec<Vec<f64>> = (0..renderers.len())
        .map(|b| wall.iter().map(|per| median(per[b].clone())).collect())
        .collect();
    let cpus: Vec<Vec<Option<f64>>> = (0..renderers.len())
        .map(|b| {
            cpu.iter()
                .map(|per| (!per[b].is_empty()).then(|| median(per[b].clone())))
                .collect()
        })
        .collect();
    let results: Vec<BackendResult> = renderers
        .iter()
        .enumerate()
        .map(|(b, (name, r))| BackendResult {
            backend: name.clone(),
            adapter: r.gpu.describe(),
            without: r.gpu.caps.missing(),
            variants: kinds
                .iter()
                .enumerate()
                .map(|(k, (kind, _))| BackendVariant {
                    name: kind.to_string(),
                    wall_ms: walls[b][k],
                    cpu_ms: cpus[b][k],
                    throughput_ms: through[b][k],
                    wall_ratio: walls[b][k] / walls[0][k],
                    cpu_ratio: cpus[b][k].zip(cpus[0][k]).map(|(a, z)| a / z),
                    throughput_ratio: through[b][k].zip(through[0][k]).map(|(a, z)| a / z),
                })
                .collect(),
        })
        .collect();
    let (w, h) = (cameras.mid.0.width, cameras.mid.0.height);
    eprintln!(
        "{w}x{h}, {} frames per frame type and backend, interleaved; ratios to {}",
        args.frames, results[0].backend
    );
    for res in &results {
        eprintln!(
            "{}: {} (without: {})",
            res.backend, res.adapter, res.without
        );
        for v in &res.variants {
            eprintln!(
                "  {:<40} {:>8.1} ms wall ({:>4.2}x)  {:>8.1} ms cpu ({:>4.2}x)  throughput {:>7.2} ms ({:>4.2}x)",
                v.name,
                v.wall_ms,
                v.wall_ratio,
                v.cpu_ms.unwrap_or(f64::NAN),
                v.cpu_ratio.unwrap_or(f64::NAN),
                v.throughput_ms.unwrap_or(f64::NAN),
                v.throughput_ratio.unwrap_or(f64::NAN),
            );
        }
    }
    println!("{}", serde_json::to_string_pretty(&results)?);
    if let Some(path) = &args.json {
        prerender::store::write_json(path, &results)?;
    }
    Ok(())
}
