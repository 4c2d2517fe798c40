//! [`PovImport`]: the passes of one sample, in order, written through [`crate::store`].

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use tracks::{CubeMap, ReferenceViewpoint, SlabRange};

use super::decode::{self, FogDepth, FogScales};
use super::frame::{self, MeshLayout, NEAR_NAME};
use super::runner::{OutputFormat, PovRay, RenderJob, RenderStats};
use super::sdl::{self, names, PassKind, SceneInfo};
use super::{PovError, PovOptions};
use crate::runlog::{RunEvent, RunLog, SampleTiming};
use crate::store::{self, PrerenderDir, SampleMeta};

mod depths;
mod layers;
mod radiosity;
mod sky;
mod views;

pub use depths::{DepthRequest, MAX_PARALLEL_RUNS};
pub use radiosity::radiosity_file;

/// One finished POV-Ray render, for progress and the report.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RenderRecord {
    pub sample: usize,
    /// `lowres-fog`, `lowres-depth`, `depth`, `fog`, `color`, `slab2-depth`, …
    pub pass: String,
    /// Cube-map face size the mesh camera rendered (2× the output with `--aa` colour).
    pub face_size: u32,
    /// Pixels POV-Ray traced (primary rays, including the two dummy rows).
    pub pixels: u64,
    pub stats: RenderStats,
    /// For depth passes: what the decoded image held.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<DepthSummary>,
}

/// Summary of a decoded depth pass (distances along the rays, from their origins).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthSummary {
    pub hits: usize,
    pub sky: usize,
    /// Hits whose channels disagree (no fog: ray started inside a solid, wrong gamma).
    pub inconsistent: usize,
    pub zero: usize,
    /// Pixels whose channels all clipped on the scene's own fog (decoded as misses).
    pub clipped: usize,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub fog_scales: FogScales,
}

impl DepthSummary {
    fn of(d: &FogDepth, scales: &FogScales) -> DepthSummary {
        let (min, max) = finite_range(&d.t);
        DepthSummary {
            hits: d.hits,
            sky: d.t.len() - d.hits,
            inconsistent: d.inconsistent,
            zero: d.zero,
            clipped: d.clipped,
            min: min.is_finite().then_some(min),
            max: max.is_finite().then_some(max),
            fog_scales: *scales,
        }
    }
}

/// Most colour rays per pixel along each axis (16 a pixel).
pub const MAX_SUPERSAMPLE: u32 = 4;

/// A colour cube map as the import decodes it.
type Colour = CubeMap<[u8; 3]>;

/// Called after every finished render.
type ProgressFn = Box<dyn FnMut(&RenderRecord)>;

/// A POV-Ray scene prepared for import. See the module docs of [`super`].
pub struct PovImport {
    scene: PathBuf,
    scene_sdl: String,
    info: SceneInfo,
    pub(super) opts: PovOptions,
    pub(super) povray: PovRay,
    version: String,
    records: Vec<RenderRecord>,
    progress: Option<ProgressFn>,
    /// Where every render, sample and layer set is logged with its time (`runs/`).
    log: Option<Arc<RunLog>>,
    /// Whether the scene's own fog shows at a viewpoint (decided by a low-res fog-only pass).
    has_fog: HashMap<usize, bool>,
    /// Perspective views rendered so far (names their temporary files).
    truth_renders: u64,
    /// Depth renders from free positions so far (names their temporary files).
    pub(super) depth_renders: u64,
    /// The track's shared radiosity samples, loaded by every colour render ([`radiosity`]).
    radiosity: Option<PathBuf>,
}

/// Camera position and ray range of one mesh-camera render.
#[derive(Clone, Copy)]
pub(super) struct View {
    pub pov: DVec3,
    pub near: f64,
    /// `far − near`, or 0 for no limit.
    pub range: f64,
}

impl PovImport {
    /// Check the scene and the `povray` binary, create the work directory.
    pub fn new(scene: impl AsRef<Path>, opts: PovOptions) -> Result<PovImport, PovError> {
        let scene_arg = scene.as_ref();
        let scene_err = |source| PovError::Scene {
            path: scene_arg.to_path_buf(),
            source,
        };
        let text = fs::read(scene_arg).map_err(scene_err)?;
        let scene = fs::canonicalize(scene_arg).map_err(scene_err)?;
        if opts.face_size == 0 || opts.lowres_face_size == 0 {
            return Err(PovError::Parameter {
                name: "face-size",
                message: "face sizes must be at least 1".into(),
            });
        }
        if let Some(g) = opts.file_gamma {
            if !(g.is_finite() && g > 0.0) {
                return Err(PovError::Parameter {
                    name: "gamma",
                    message: format!("must be a positive number, found {g}"),
                });
            }
        }
        let scene_sdl = sdl::sdl_string(&scene).ok_or_else(|| PovError::Parameter {
            name: "scene",
            message: format!(
                "{}: the path cannot be written in an SDL #include (quote, backslash or non-UTF-8)",
                scene.display()
            ),
        })?;
        let info = SceneInfo::from_text(&String::from_utf8_lossy(&text));
        store::ensure_writable_dir(&opts.work_dir)?;
        let povray = PovRay {
            binary: opts.povray.clone(),
            threads: opts.threads.max(1),
            timeout: opts.timeout,
        };
        let version = povray.version()?;
        Ok(PovImport {
            scene,
            scene_sdl,
            info,
            opts,
            povray,
            version,
            records: Vec::new(),
            progress: None,
            log: None,
            has_fog: HashMap::new(),
            truth_renders: 0,
            depth_renders: 0,
            radiosity: None,
        })
    }

    /// The import that wrote the prerender directory `dir` (report `pre`), re-created from
    /// what `import-pov` recorded in `prerender.json` (scene path, up axis, face sizes,
    /// anti-aliasing, gamma, binary, threads and timeout, the shared radiosity samples),
    /// with generated files in `work_dir`.
    pub fn from_report(
        dir: &PrerenderDir,
        pre: &store::PrerenderReport,
        work_dir: &Path,
    ) -> Result<PovImport, PovError> {
        let report = dir.report_json();
        let bad = |field: &str, message: String| PovError::Parameter {
            name: "prerender.json",
            message: format!("{}: extra.{field} {message}", report.display()),
        };
        let field = |name: &str| {
            let v = &pre.extra[name];
            (!v.is_null()).then_some(v)
        };
        let up = match field("up").map(|v| v.as_str()) {
            None => frame::UpAxis::Y,
            Some(Some(s)) => s.parse().map_err(|e| bad("up", format!("`{s}`: {e}")))?,
            Some(None) => return Err(bad("up", "is not a string".into())),
        };
        let mut opts = PovOptions::new(pre.face_size, work_dir);
        opts.lowres_face_size = pre.lowres_face_size;
        opts.up = up;
        // Older prerender directories record only whether colour was anti-aliased (2×2).
        opts.supersample = match field("supersample").and_then(|v| v.as_u64()) {
            Some(s) => (s as u32).clamp(1, MAX_SUPERSAMPLE),
            None => 1 + u32::from(field("antialias").and_then(|v| v.as_bool()) == Some(true)),
        };
        if let Some(p) = field("povray").and_then(|v| v.as_str()) {
            opts.povray = PathBuf::from(p);
        }
        if let Some(t) = field("threads").and_then(|v| v.as_u64()) {
            opts.threads = (t as usize).max(1);
        }
        if let Some(t) = field("timeout_secs").and_then(|v| v.as_f64()) {
            if !(t.is_finite() && t > 0.0) {
                return Err(bad("timeout_secs", format!("{t} is not a positive number")));
            }
            opts.timeout = Some(std::time::Duration::from_secs_f64(t));
        }
        opts.file_gamma = field("gamma")
            .or_else(|| field("file_gamma"))
            .and_then(|v| v.as_f64());
        let mut import = PovImport::new(&pre.scene, opts)?;
        // Colour renders after the import (slab layers) load the track's shared radiosity.
        let file = radiosity::radiosity_file(dir);
        if import.info.radiosity && file.is_file() {
            import.radiosity = Some(file);
        }
        Ok(import)
    }

    /// Call `f` after every finished POV-Ray render.
    /// Log every render, and each sample's and layer set's time, to `log` (the content
    /// files hold no timing).
    pub fn set_run_log(&mut self, log: Arc<RunLog>) {
        self.log = Some(log);
    }

    fn log(&self, event: RunEvent) -> Result<(), PovError> {
        match &self.log {
            Some(l) => Ok(l.log(&event)?),
            None => Ok(()),
        }
    }

    pub fn set_progress(&mut self, f: impl FnMut(&RenderRecord) + 'static) {
        self.progress = Some(Box::new(f));
    }

    pub fn scene(&self) -> &Path {
        &self.scene
    }
    pub fn scene_info(&self) -> &SceneInfo {
        &self.info
    }
    pub fn options(&self) -> &PovOptions {
        &self.opts
    }
    /// POV-Ray's version line.
    pub fn povray_version(&self) -> &str {
        &self.version
    }
    /// Every render so far, in order.
    pub fn records(&self) -> &[RenderRecord] {
        &self.records
    }

    /// POV-Ray timings summed over all renders so far.
    pub fn total_stats(&self) -> RenderStats {
        let mut t = RenderStats::default();
        for r in &self.records {
            t.add(&r.stats);
        }
        t
    }

    pub(super) fn file_gamma(&self) -> f64 {
        self.opts.file_gamma.unwrap_or(self.info.assumed_gamma)
    }

    /// Generate (once) the mesh-camera include for `face_size`.
    fn mesh_include(&self, face_size: u32) -> Result<PathBuf, PovError> {
        let path = self.opts.work_dir.join(format!(
            "meshcam_{}_{face_size}_b{}.inc",
            self.opts.up.name(),
            frame::BLOCK
        ));
        if !path.exists() {
            let text = frame::write_mesh_camera(&MeshLayout::new(face_size), self.opts.up);
            store::write_atomic(&path, text.as_bytes())?;
        }
        Ok(path)
    }

    /// Write the wrapper of a pass kind at a face size; returns its path.
    fn wrapper(&self, kind: PassKind, face_size: u32) -> Result<PathBuf, PovError> {
        let mesh = self.mesh_include(face_size)?;
        let mesh_sdl = sdl::sdl_string(&mesh).ok_or_else(|| PovError::Parameter {
            name: "out",
            message: format!(
                "{}: the output path cannot be written in an SDL #include",
                mesh.display()
            ),
        })?;
        let name = match kind {
            PassKind::Color => "color",
            PassKind::Depth => "depth",
            PassKind::FogOnly => "fog",
        };
        let path = self.opts.work_dir.join(format!(
            "wrap_{name}_{}_{face_size}.pov",
            self.opts.up.name()
        ));
        let text = sdl::mesh_wrapper(kind, &self.scene_sdl, &mesh_sdl, &self.info);
        store::write_atomic(&path, text.as_bytes())?;
        Ok(path)
    }

    /// Run one mesh-camera render; returns the path of the image it wrote.
    fn render(
        &mut self,
        sample: usize,
        pass: &str,
        kind: PassKind,
        face_size: u32,
        view: View,
        fog: Option<&FogScales>,
    ) -> Result<PathBuf, PovError> {
        let mut job = self.job(&format!("s{sample:04}_{pass}"), kind, face_size, view, fog)?;
        job.name = format!("sample {sample} {pass} ({})", self.scene.display());
        let stats = self.povray.run(&job)?;
        self.record(sample, pass, face_size, &job, stats)?;
        Ok(job.output)
    }

    /// The POV-Ray job of one mesh-camera render, its files named after `stem` (its
    /// wrapper written if it is not yet).
    pub(super) fn job(
        &mut self,
        stem: &str,
        kind: PassKind,
        face_size: u32,
        view: View,
        fog: Option<&FogScales>,
    ) -> Result<RenderJob, PovError> {
        let wrapper = self.wrapper(kind, face_size)?;
        let (width, height) = MeshLayout::new(face_size).image_size();
        let declares = vec![
            (names::CAM_X, view.pov.x),
            (names::CAM_Y, view.pov.y),
            (names::CAM_Z, view.pov.z),
            (NEAR_NAME, view.near),
            (names::RANGE, view.range),
        ];
        Ok(self.render_job(stem, kind, wrapper, (width, height), declares, fog))
    }

    /// A job rendering `wrapper` into `STEM.png` of `size` pixels with `declares` (and the
    /// fog's, for a fog pass), in the output format and with the arguments of `kind`.
    fn render_job(
        &self,
        stem: &str,
        kind: PassKind,
        wrapper: PathBuf,
        (width, height): (u32, u32),
        mut declares: Vec<(&'static str, f64)>,
        fog: Option<&FogScales>,
    ) -> RenderJob {
        if let Some(f) = fog {
            declares.extend([
                (names::D1, f.d[0]),
                (names::D2, f.d[1]),
                (names::D3, f.d[2]),
                (names::K, f.k),
            ]);
        }
        let format = match kind {
            PassKind::Color => OutputFormat::Png8,
            PassKind::Depth | PassKind::FogOnly => OutputFormat::Png16 {
                file_gamma: self.file_gamma(),
            },
        };
        RenderJob {
            name: format!("{stem} ({})", self.scene.display()),
            wrapper,
            output: self.opts.work_dir.join(format!("{stem}.png")),
            log: self.opts.work_dir.join("logs").join(format!("{stem}.log")),
            width,
            height,
            format,
            block_size: frame::BLOCK,
            library_dirs: self
                .scene
                .parent()
                .map(Path::to_path_buf)
                .into_iter()
                .collect(),
            declares,
            extra: match kind {
                PassKind::Color => self.radiosity_args(),
                PassKind::Depth | PassKind::FogOnly => Vec::new(),
            },
        }
    }

    /// Generate (once) the meshes of [`frame::BlockLayout`] renders at `face_size`.
    fn block_include(&self, face_size: u32) -> Result<PathBuf, PovError> {
        let path = self.opts.work_dir.join(format!(
            "meshcam_block_{}_{face_size}_b{}.inc",
            self.opts.up.name(),
            frame::BLOCK
        ));
        if !path.exists() {
            let text = frame::write_block_meshes(face_size, self.opts.up);
            store::write_atomic(&path, text.as_bytes())?;
        }
        Ok(path)
    }

    /// A render of the scene from every one of `positions` (POV-Ray frame) at once, laid out
    /// as [`frame::BlockLayout`], with no near or far limit; its wrapper is written to
    /// `STEM_wrap.pov`, for the caller to remove with the image.
    pub(super) fn block_job(
        &mut self,
        stem: &str,
        kind: PassKind,
        face_size: u32,
        positions: &[DVec3],
        fog: Option<&FogScales>,
    ) -> Result<RenderJob, PovError> {
        let mesh = self.block_include(face_size)?;
        let mesh_sdl = sdl::sdl_string(&mesh).ok_or_else(|| PovError::Parameter {
            name: "out",
            message: format!(
                "{}: the output path cannot be written in an SDL #include",
                mesh.display()
            ),
        })?;
        let wrapper = self.opts.work_dir.join(format!("{stem}_wrap.pov"));
        let text = sdl::block_wrapper(kind, &self.scene_sdl, &mesh_sdl, &self.info, positions);
        store::write_atomic(&wrapper, text.as_bytes())?;
        let layout = frame::BlockLayout::new(face_size, positions.len() as u32);
        let declares = vec![(NEAR_NAME, 0.0), (names::RANGE, 0.0)];
        Ok(self.render_job(stem, kind, wrapper, layout.image_size(), declares, fog))
    }

    /// Record a finished render: progress, run log, the import's records.
    pub(super) fn record(
        &mut self,
        sample: usize,
        pass: &str,
        face_size: u32,
        job: &RenderJob,
        stats: RenderStats,
    ) -> Result<(), PovError> {
        let record = RenderRecord {
            sample,
            pass: pass.to_string(),
            face_size,
            pixels: job.width as u64 * job.height as u64,
            stats,
            depth: None,
        };
        if let Some(p) = self.progress.as_mut() {
            p(&record);
        }
        self.log(RunEvent::Povray(record.clone()))?;
        self.records.push(record);
        Ok(())
    }

    /// Render and decode a fog-trick depth pass (with the fog-only pass when `fog`) and, with
    /// `colour`, the colour pass through the same camera (supersampled `supersample`² and
    /// box-filtered): independent renders, run at once ([`PovImport::run_parallel`]).
    fn depth_pass(
        &mut self,
        sample: usize,
        (pass, face_size): (&str, u32),
        view: View,
        scales: &FogScales,
        fog: bool,
        colour: Option<&str>,
    ) -> Result<(FogDepth, Option<Colour>), PovError> {
        let ss = self.opts.supersample.clamp(1, MAX_SUPERSAMPLE);
        let fine = ss * self.opts.face_size;
        let mut passes = Vec::new();
        if fog {
            passes.push((format!("{pass}-fog"), PassKind::FogOnly, face_size));
        }
        passes.push((pass.to_string(), PassKind::Depth, face_size));
        if let Some(c) = colour {
            passes.push((c.to_string(), PassKind::Color, fine));
        }
        let mut jobs = Vec::with_capacity(passes.len());
        for (name, kind, size) in &passes {
            let f = (*kind == PassKind::Depth).then_some(scales);
            let mut job = self.job(&format!("s{sample:04}_{name}"), *kind, *size, view, f)?;
            job.name = format!("sample {sample} {name} ({})", self.scene.display());
            jobs.push(job);
        }
        let stats = self.run_parallel(&jobs)?;
        let (mut p0, mut decoded, mut map) = (None, None, None);
        for ((name, kind, size), (job, st)) in passes.iter().zip(jobs.iter().zip(stats)) {
            self.record(sample, name, *size, job, st)?;
            match kind {
                PassKind::FogOnly => {
                    p0 = Some(decode::read_mesh_png16(
                        &job.output,
                        &MeshLayout::new(*size),
                    )?)
                }
                PassKind::Depth => {
                    let p1 = decode::read_mesh_png16(&job.output, &MeshLayout::new(*size))?;
                    let d = decode::decode_fog(&p1, p0.as_deref(), scales);
                    if let Some(last) = self.records.last_mut() {
                        last.depth = Some(DepthSummary::of(&d, scales));
                    }
                    decoded = Some(d);
                }
                PassKind::Color => {
                    let m = decode::read_mesh_png8(&job.output, &MeshLayout::new(*size))?;
                    map = Some(if ss > 1 {
                        decode::downsample(&m, ss)
                    } else {
                        m
                    });
                }
            }
            remove(&job.output)?;
        }
        let decoded = decoded.ok_or_else(|| PovError::Output {
            path: self.opts.work_dir.clone(),
            message: format!("sample {sample}: the {pass} pass gave no image"),
        })?;
        Ok((decoded, map))
    }

    /// Whether the scene's own fog shows at this viewpoint (a cheap low-res fog-only pass).
    pub fn scene_fog(&mut self, vp: &ReferenceViewpoint) -> Result<bool, PovError> {
        if let Some(f) = self.has_fog.get(&vp.index) {
            return Ok(*f);
        }
        let view = View {
            pov: self.opts.up.pov_from_railview(vp.position),
            near: 0.0,
            range: 0.0,
        };
        let n = self.opts.lowres_face_size;
        let path = self.render(vp.index, "lowres-fog", PassKind::FogOnly, n, view, None)?;
        let px = decode::read_mesh_png16(&path, &MeshLayout::new(n))?;
        remove(&path)?;
        let fog = px.iter().any(|p| p.iter().any(|&c| c > 0));
        self.has_fog.insert(vp.index, fog);
        Ok(fog)
    }

    fn viewpoint_error(&self, vp: &ReferenceViewpoint, message: String) -> PovError {
        PovError::Viewpoint {
            index: vp.index,
            position_railview: vp.position,
            position_pov: self.opts.up.pov_from_railview(vp.position),
            message,
        }
    }

    /// Reject a base depth pass that is not a valid fog code (camera inside a solid, wrong
    /// gamma, scene fog leaking through).
    fn check_depth(
        &self,
        vp: &ReferenceViewpoint,
        pass: &str,
        d: &FogDepth,
    ) -> Result<(), PovError> {
        let total = d.t.len().max(1);
        let pct = |k: usize| 100.0 * k as f64 / total as f64;
        if d.inconsistent * 20 > d.hits.max(1) {
            return Err(self.viewpoint_error(
                vp,
                format!(
                    "{pass} pass: {:.1}% of pixels are not a valid depth code. Most likely the \
                     camera is inside a solid object (rays starting inside a non-hollow object \
                     get no fog); otherwise check --up and the depth gamma (File_Gamma {} from \
                     the scene's assumed_gamma)",
                    pct(d.inconsistent),
                    self.file_gamma()
                ),
            ));
        }
        if d.zero * 2 > total {
            return Err(self.viewpoint_error(
                vp,
                format!(
                    "{pass} pass: {:.1}% of pixels have depth 0; the camera is inside or on a \
                     solid object",
                    pct(d.zero)
                ),
            ));
        }
        Ok(())
    }

    /// Whether a sample's base pass is complete for these options: its marker exists and
    /// matches the face sizes and position (what resuming after a kill checks).
    pub fn base_done(&self, dir: &PrerenderDir, vp: &ReferenceViewpoint) -> bool {
        dir.sample_meta(vp.index).is_some_and(|m| {
            m.face_size == self.opts.face_size
                && m.lowres_face_size == self.opts.lowres_face_size
                && m.position == vp.position
        })
    }

    /// Whether a sample's slab layers are complete for exactly these slabs.
    pub fn slabs_done(
        &self,
        dir: &PrerenderDir,
        vp: &ReferenceViewpoint,
        slabs: &[SlabRange],
    ) -> bool {
        self.base_done(dir, vp) && dir.layers_meta(vp.index).is_some_and(|m| m.slabs == slabs)
    }

    /// Render a sample's colour, depth and low-resolution depth and write them with the
    /// sample marker last. An existing marker is removed first, so a failed or killed run
    /// never leaves a sample that looks complete.
    pub fn render_base(
        &mut self,
        vp: &ReferenceViewpoint,
        dir: &PrerenderDir,
    ) -> Result<SampleMeta, PovError> {
        let start = Instant::now();
        let first_record = self.records.len();
        remove(&dir.sample_json(vp.index))?;
        store::ensure_writable_dir(&dir.sample_dir(vp.index))?;
        store::remove_temporaries(&dir.sample_dir(vp.index))?;
        let view = View {
            pov: self.opts.up.pov_from_railview(vp.position),
            near: 0.0,
            range: 0.0,
        };
        let fog = self.scene_fog(vp)?;
        let k = if fog { 0.5 } else { 1.0 };
        let (n, nl) = (self.opts.face_size, self.opts.lowres_face_size);

        let wide = FogScales::wide(k);
        let (low, _) = self.depth_pass(vp.index, ("lowres-depth", nl), view, &wide, fog, None)?;
        self.check_depth(vp, "low-resolution depth", &low)?;
        let (min, max) = finite_range(&low.t);
        let scales = FogScales::for_range(min, max, k);
        let (full, color) =
            self.depth_pass(vp.index, ("depth", n), view, &scales, fog, Some("color"))?;
        self.check_depth(vp, "depth", &full)?;
        let color = color.ok_or_else(|| PovError::Output {
            path: dir.color_png(vp.index),
            message: "the colour pass gave no image".into(),
        })?;

        let lowres = to_cube(nl, &low.t, |t| t)?;
        let depth = to_cube(n, &full.t, |t| t)?;
        store::write_atomic(&dir.color_png(vp.index), &store::encode_rgb_png(&color))?;
        store::write_depth_exr(&dir.depth_exr(vp.index), &depth)?;
        store::write_depth_exr(&dir.lowres_depth_exr(vp.index), &lowres)?;
        let meta = SampleMeta {
            index: vp.index,
            s: vp.s,
            position: vp.position,
            face_size: n,
            lowres_face_size: nl,
            primary_rays: self.records[first_record..].iter().map(|r| r.pixels).sum(),
        };
        store::write_json(&dir.sample_json(vp.index), &meta)?;
        self.log(RunEvent::Sample(SampleTiming {
            index: vp.index,
            face_size: n,
            lowres_face_size: nl,
            seconds: start.elapsed().as_secs_f64(),
            primary_rays: meta.primary_rays,
        }))?;
        Ok(meta)
    }

    /// Delete the generated mesh includes (tens of MB at large face sizes); logs and
    /// wrappers stay for inspection.
    pub fn remove_mesh_includes(&self) -> Result<(), PovError> {
        let entries = fs::read_dir(&self.opts.work_dir).map_err(|source| PovError::Io {
            path: self.opts.work_dir.clone(),
            source,
        })?;
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if name.starts_with("meshcam_") && name.ends_with(".inc") {
                remove(&e.path())?;
            }
        }
        Ok(())
    }
}

/// Remove a file if it exists.
fn remove(path: &Path) -> Result<(), PovError> {
    match fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(source) => Err(PovError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Smallest positive and largest finite value (`(inf, inf)` if none).
fn finite_range(t: &[f64]) -> (f64, f64) {
    t.iter()
        .filter(|x| x.is_finite() && **x > 0.0)
        .fold((f64::INFINITY, f64::INFINITY), |(lo, hi), &x| {
            (lo.min(x), if hi.is_finite() { hi.max(x) } else { x })
        })
}

pub(super) fn to_cube(n: u32, t: &[f64], f: impl Fn(f64) -> f64) -> Result<CubeMap<f32>, PovError> {
    CubeMap::from_vec(n, t.iter().map(|&x| f(x) as f32).collect()).ok_or_else(|| PovError::Output {
        path: PathBuf::from(format!("depth pass of face size {n}")),
        message: format!("{} pixels do not form a cube map", t.len()),
    })
}
