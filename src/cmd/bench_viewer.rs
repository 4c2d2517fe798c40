//! `railview bench-viewer`: frame time of the full reconstruction against a plain
//! single-panorama draw ([`viewer::bench`]); this is its command line.

use anyhow::Context;
use viewer::bench::{backends_summary, Bench, BenchParams};
use viewer::gpu::{Gpu, GpuRequest, Renderer};
use viewer::headless::{open, parse_size, synth_street};
use viewer::source::LoadOptions;
use viewer::LayerMeshing;

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

pub fn run(args: Args) -> anyhow::Result<()> {
    let (width, height) = parse_size(&args.size).map_err(anyhow::Error::msg)?;
    let params = BenchParams {
        width,
        height,
        frames: super::count("--frames", args.frames, 100_000)?,
        // 0 skips the throughput run, as the help says.
        throughput_frames: tracks::limits::check_u64(
            "--throughput-frames",
            args.throughput_frames as u64,
            0,
            100_000,
        )? as usize,
        core: args.core,
        uploads: args.uploads,
        fragments: args.fragments,
    };
    super::face_size("--face", args.face)?;
    super::count("--mesh-step", args.mesh_step as usize, 4096)?;
    let mesh = LayerMeshing {
        step: args.mesh_step,
        adaptive: match args.mesh.as_str() {
            // The street's samples are 1.5 m apart (its largest baseline).
            "adaptive" => Some(viewer::refview::AdaptiveMesh::database(1.5)),
            "grid" => None,
            other => anyhow::bail!("--mesh {other}: expected `adaptive` or `grid`"),
        },
        ..Default::default()
    };
    let opts = LoadOptions {
        mesh,
        ..Default::default()
    };
    let walk = match &args.db {
        Some(db) => open(db, None, opts).with_context(|| format!("opening {db}"))?,
        None => synth_street(args.face, &viewer::synth::Scene::street_slabs(), mesh)?,
    };
    let bench = Bench::new(&walk, params)?;
    if args.backends.is_empty() {
        let res = bench.run()?;
        eprint!("{}", res.summary());
        return write(&res, args.json.as_deref());
    }
    let mut renderers = Vec::new();
    for name in &args.backends {
        let request = GpuRequest::for_backend(name)
            .with_context(|| format!("--backends {name}: expected vulkan, gl, metal or dx12"))?;
        let gpu = Gpu::request(&request).with_context(|| format!("--backends {name}"))?;
        renderers.push((name.clone(), Renderer::new(gpu)?));
    }
    let results = bench.compare_backends(renderers)?;
    eprint!(
        "{}",
        backends_summary(&results, width, height, params.frames)
    );
    write(&results, args.json.as_deref())
}

/// The result as JSON on standard output and, with `--json`, in that file.
fn write(res: &impl serde::Serialize, json: Option<&std::path::Path>) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(res)?);
    if let Some(path) = json {
        prerender::store::write_json(path, res)?;
    }
    Ok(())
}
