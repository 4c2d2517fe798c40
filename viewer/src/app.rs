//! The interactive viewer (eframe/egui on the same wgpu device as the renderer): move along
//! the track (W/S or arrow keys, slider, play with a speed; on a network A/D or ←/→ choose the
//! branch at the next junction, shown in the panel), look around by dragging the view,
//! FOV; panels for frame time (plotted over time) and the frame-to-frame interval, GPU memory
//! and the frame-time budget's current choice (slabs, texture level, second view, mesh
//! level), made by a [`BudgetController`] from the view's draw times against the target rate.
//!
//! A [`Source::Stream`] walkthrough is filled from `railview serve` while it is shown (see
//! [`crate::stream`]): each frame steps the streaming session, re-uploads only the views that
//! changed, and every few frames hands the GPU's visible-pixel counts back as live counts.
//! Extra panels: bandwidth, requests and parts in flight, cache used against its budget, downloading
//! quality over time, the priority strategy, a level cap, and the renderer's highlight of
//! tiles that arrived in the last second; toggles for the renderer's other overlays.

use std::collections::VecDeque;
use std::time::Instant;

use eframe::egui;
use egui_plot::{Line, Plot, PlotPoints};
use tracks::PerspectiveCamera;

use crate::gpu::{device_limits, DeviceLimits, Gpu, GpuError, Renderer};
use crate::headless::yaw_along;
use crate::plan::{BudgetController, DrawBudget, Overlays};
use crate::source::Walkthrough;
use crate::stream::StreamedWalkthrough;
use streamer::client::PriorityMode;

mod blit;
mod junction;
mod streaming;

pub use streaming::Strategy;
use streaming::StreamUi;

const HISTORY: usize = 300;
/// Frames between two GPU feedback read-backs while streaming.
const FEEDBACK_EVERY: u64 = 5;

/// Where the app's reference views come from.
pub enum Source {
    /// Decoded up front (a directory or `synth:street`).
    Local(Box<Walkthrough>),
    /// Filled from a server while shown.
    Stream(Box<StreamedWalkthrough>),
}

impl Source {
    pub fn walk(&self) -> &Walkthrough {
        match self {
            Source::Local(w) => w,
            Source::Stream(s) => &s.walk,
        }
    }
}

/// The app state.
pub struct ViewerApp {
    source: Source,
    /// Debug overlays (heat map, slab colours, holes); the streaming highlight is in `stream`.
    overlays: Overlays,
    stream: StreamUi,
    /// Size of the view drawn last (the camera for the next streaming step).
    view_px: [u32; 2],
    /// Size of the rectangle it was shown in (larger where the budget draws it smaller).
    shown_px: [u32; 2],
    started: Instant,
    renderer: Option<Renderer>,
    s: f64,
    speed_mps: f64,
    playing: bool,
    yaw_offset_deg: f64,
    pitch_deg: f64,
    fov_deg: f64,
    budget: DrawBudget,
    /// The frame-time budget: steps the drawing down while frames come slower than the
    /// target rate and back up when there is room, without oscillating.
    controller: BudgetController,
    auto_budget: bool,
    target_fps: f64,
    frame_ms: VecDeque<f64>,
    /// Recent frame-to-frame intervals, seconds.
    interval_s: VecDeque<f64>,
    frames: u64,
    last: Instant,
    /// Every frame-to-frame interval, ms, when the window closes after a set number of
    /// frames (for the summary it prints; an open-ended session keeps none).
    intervals_ms: Vec<f64>,
    error: Option<String>,
    /// An error of the GPU while drawing: the window closes and [`run`] returns it.
    failed: std::sync::Arc<std::sync::Mutex<Option<GpuError>>>,
    /// On a network: the walker that turns at junctions.
    junctions: Option<junction::Junctions>,
    /// Close after this many frames (screenshots and smoke tests).
    pub quit_after: Option<u64>,
    /// Save a screenshot of the window here a few frames before closing.
    pub screenshot: Option<std::path::PathBuf>,
}

impl ViewerApp {
    /// Build from eframe's creation context; the renderer shares eframe's wgpu device (and
    /// reports its errors: wgpu's default would panic). Fails when the renderer cannot be
    /// made on that device.
    pub fn new(cc: &eframe::CreationContext<'_>, source: Source) -> Result<ViewerApp, GpuError> {
        let (renderer, error) = match &cc.wgpu_render_state {
            Some(rs) => {
                let gpu = Gpu::from_device(rs.device.clone(), rs.queue.clone(), &rs.adapter);
                blit::BlitResources::install(rs, gpu.caps.view_formats);
                gpu.check("making the window's copy of the view")?;
                (Some(Renderer::new(gpu)?), None)
            }
            None => (None, Some("eframe started without wgpu".to_string())),
        };
        let slabs = source.walk().views.first().map_or(1, |v| v.slab_count());
        let strategy = match &source {
            Source::Stream(st) => match st.session().mode() {
                Some(PriorityMode::Ach) => Strategy::Ach,
                Some(PriorityMode::Visibility) => Strategy::Visibility,
                Some(PriorityMode::Combined { .. }) | None => Strategy::Both,
            },
            Source::Local(_) => Strategy::Both,
        };
        let prefetch = match &source {
            Source::Stream(st) => st.session().prefetch(),
            Source::Local(_) => true,
        };
        let junctions = junction::Junctions::of(&source);
        Ok(ViewerApp {
            junctions,
            source,
            overlays: Overlays::default(),
            stream: StreamUi {
                strategy,
                prefetch,
                level_cap: 0,
                highlight: false,
                live: None,
                history: VecDeque::new(),
                first_complete_s: None,
            },
            view_px: [640, 360],
            shown_px: [640, 360],
            started: Instant::now(),
            renderer,
            s: 0.0,
            speed_mps: 1.5,
            playing: false,
            yaw_offset_deg: 0.0,
            pitch_deg: 0.0,
            fov_deg: 90.0,
            budget: DrawBudget {
                max_slabs: slabs.max(1),
                ..Default::default()
            },
            controller: BudgetController::new(1000.0 / DEFAULT_TARGET_FPS, slabs),
            auto_budget: true,
            target_fps: DEFAULT_TARGET_FPS,
            frame_ms: VecDeque::new(),
            interval_s: VecDeque::new(),
            frames: 0,
            last: Instant::now(),
            intervals_ms: Vec::new(),
            error,
            failed: Default::default(),
            quit_after: None,
            screenshot: None,
        })
    }

    /// Slabs of the walkthrough's views (at least 1).
    fn slab_count(&self) -> usize {
        self.source
            .walk()
            .views
            .first()
            .map_or(1, |v| v.slab_count())
            .max(1)
    }

    /// What the frame draws: slabs, texture level, views, mesh level, size.
    fn budget_text(&self) -> String {
        let b = self.budget;
        let slabs = self.slab_count();
        let size = if b.render_scale < 1.0 {
            format!(
                ", drawn at {:.0} % of the view's size",
                b.render_scale * 100.0
            )
        } else {
            String::new()
        };
        format!(
            "{} slab(s), texture level +{}, {}, mesh level {}{size}",
            b.max_slabs.min(slabs),
            b.lod_bias,
            match (b.blend, b.half_res_second) {
                (false, _) => "1 view",
                (true, false) => "2 views",
                (true, true) => "2 views (the lighter at half resolution)",
            },
            b.mesh_level
        )
    }

    fn push(q: &mut VecDeque<f64>, v: f64) {
        if q.len() == HISTORY {
            q.pop_front();
        }
        q.push_back(v);
    }

    /// Draw the current view into the renderer's target and show it (copied into the
    /// window's pass by [`blit::BlitCallback`]).
    fn draw_view(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame, size: egui::Vec2) {
        let (rect, response) = ui.allocate_exact_size(size, egui::Sense::drag());
        let d = response.drag_delta();
        self.yaw_offset_deg -= d.x as f64 * self.fov_deg / size.x.max(1.0) as f64;
        self.pitch_deg = (self.pitch_deg + d.y as f64 * self.fov_deg / size.x.max(1.0) as f64)
            .clamp(-90.0, 90.0);
        // At full size the output has the size of the viewport the copy is drawn in: texel
        // for pixel.
        let shown = blit::viewport_px(rect, ui.ctx().pixels_per_point());
        let [w, h] = blit::drawn_px(shown, self.budget.render_scale);
        self.shown_px = shown;
        self.view_px = [w, h];
        let camera = self.camera(w, h);
        let (Some(r), Some(_)) = (&mut self.renderer, frame.wgpu_render_state()) else {
            return;
        };
        let t0 = Instant::now();
        let walk = self.source.walk();
        let feedback =
            matches!(self.source, Source::Stream(_)) && self.frames.is_multiple_of(FEEDBACK_EVERY);
        let streaming = matches!(self.source, Source::Stream(_));
        let overlays = Overlays {
            highlight: streaming && self.stream.highlight,
            ..self.overlays
        };
        let planned = match &self.source {
            // Streaming: where the views around the position have nothing yet, the nearest
            // that have (not a black frame).
            Source::Stream(st) => st.plan(&camera, self.s, self.budget),
            _ => walk.plan(&camera, self.s, self.budget),
        };
        let mut plan = match planned {
            Ok(p) => p,
            Err(e) => {
                self.error = Some(e.to_string());
                return;
            }
        };
        // Tile ids only on the frames whose feedback is read.
        plan.tile_ids = feedback;
        plan.overlays = overlays;
        // An error of the GPU ends the session: the window closes and `run` returns it.
        let fail = |e: GpuError, ctx: &egui::Context| {
            if let Ok(mut f) = self.failed.lock() {
                f.get_or_insert(e);
            }
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        };
        if let Err(e) = r.draw(&plan, &walk.views) {
            fail(e, ui.ctx());
            return;
        }
        if let (true, Source::Stream(st)) = (feedback, &self.source) {
            // The GPU's visible-pixel counts of this frame, for the next streaming step.
            match r.feedback(&plan, &st.walk.views) {
                Ok(counts) => self.stream.live = Some(st.live_counts(&plan, &counts)),
                Err(e) => {
                    fail(e, ui.ctx());
                    return;
                }
            }
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        Self::push(&mut self.frame_ms, ms);
        let Some(srgb) = r.output_view() else {
            return;
        };
        let unorm = r.output_view_unorm();
        ui.painter()
            .add(eframe::egui_wgpu::Callback::new_paint_callback(
                rect,
                blit::BlitCallback {
                    srgb: srgb.clone(),
                    unorm: unorm.cloned(),
                    scaled: [w, h] != shown,
                },
            ));
    }

    /// The view direction in the world, level.
    fn view_dir(&self) -> glam::DVec3 {
        let y = (yaw_along(self.source.walk(), self.s) + self.yaw_offset_deg).to_radians();
        glam::DVec3::new(y.sin(), 0.0, -y.cos())
    }

    /// The camera at the current position and view direction for a `w × h` image.
    fn camera(&self, w: u32, h: u32) -> PerspectiveCamera {
        let walk = self.source.walk();
        PerspectiveCamera {
            position: walk.position_at(self.s),
            yaw_deg: yaw_along(walk, self.s) + self.yaw_offset_deg,
            pitch_deg: self.pitch_deg,
            fov_deg: self.fov_deg,
            width: w,
            height: h,
        }
    }

    fn controls_ui(&mut self, ui: &mut egui::Ui) {
        let walk = self.source.walk();
        let len = walk.track.length();
        ui.heading(&walk.scene);
        ui.label(format!(
            "track {} · {:.1} m · {} views",
            walk.track.name,
            len,
            walk.views.len()
        ));
        ui.add(egui::Slider::new(&mut self.s, 0.0..=len.max(1e-6)).text("position m"));
        if let Some(j) = &self.junctions {
            ui.label(j.describe(self.view_dir()));
        }
        ui.horizontal(|ui| {
            if ui
                .button(if self.playing { "pause" } else { "play" })
                .clicked()
            {
                self.playing = !self.playing;
            }
            ui.add(egui::Slider::new(&mut self.speed_mps, 0.1..=20.0).text("m/s"));
        });
        ui.add(egui::Slider::new(&mut self.fov_deg, 20.0..=150.0).text("FOV °"));
        ui.add(egui::Slider::new(&mut self.pitch_deg, -90.0..=90.0).text("pitch °"));
        ui.add(egui::Slider::new(&mut self.yaw_offset_deg, -180.0..=180.0).text("yaw °"));
        ui.separator();
        ui.horizontal(|ui| {
            ui.checkbox(&mut self.overlays.slab_colors, "slab colours");
            ui.checkbox(&mut self.overlays.heat, "feedback heat map");
            ui.checkbox(&mut self.overlays.holes, "holes");
        });
        ui.separator();
        ui.checkbox(&mut self.auto_budget, "frame-time budget");
        // `--target-fps` may be outside the slider's range (1–1000): kept until edited.
        ui.add(
            egui::Slider::new(&mut self.target_fps, 5.0..=120.0)
                .clamping(egui::SliderClamping::Edits)
                .text("target fps"),
        );
        let slabs = self.slab_count();
        ui.add_enabled(
            !self.auto_budget,
            egui::Slider::new(&mut self.budget.max_slabs, 1..=slabs).text("slabs"),
        );
        ui.add_enabled(
            !self.auto_budget,
            egui::Slider::new(&mut self.budget.lod_bias, 0.0..=4.0).text("texture level +"),
        );
        ui.add_enabled(
            !self.auto_budget,
            egui::Checkbox::new(&mut self.budget.blend, "blend two views"),
        );
        ui.add_enabled(
            !self.auto_budget,
            egui::Slider::new(&mut self.budget.render_scale, 0.5..=1.0)
                .step_by(0.25)
                .text("size drawn"),
        );
        ui.label(format!("drawing: {}", self.budget_text()));
        ui.separator();
        let mean = self.frame_ms.iter().sum::<f64>() / self.frame_ms.len().max(1) as f64;
        let interval =
            1e3 * self.interval_s.iter().sum::<f64>() / self.interval_s.len().max(1) as f64;
        ui.label(format!(
            "frame {mean:.1} ms (GPU draw + wait), every {interval:.1} ms ({:.1} fps)",
            1e3 / interval.max(1e-3)
        ));
        if let Some(r) = &self.renderer {
            ui.label(format!(
                "GPU memory for views: {:.1} MiB · database {:.1} MiB",
                r.uploaded_bytes() as f64 / 1048576.0,
                self.source.walk().bytes as f64 / 1048576.0
            ));
            ui.label(format!("adapter: {}", r.gpu.describe()));
        }
        let pts: PlotPoints<'_> = self
            .frame_ms
            .iter()
            .enumerate()
            .map(|(i, v)| [i as f64, *v])
            .collect();
        Plot::new("frame_ms").height(120.0).show(ui, |p| {
            p.line(Line::new("frame ms", pts));
        });
        if let Some(e) = &self.error {
            ui.colored_label(egui::Color32::RED, e);
        }
    }
}

impl eframe::App for ViewerApp {
    /// The window is cleared to the panels' colour, and the side panel paints no fill of its
    /// own: a clear is a fill of memory, while a painted panel goes through egui's shader for
    /// every pixel (about 6 ms a frame on lavapipe).
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let now = Instant::now();
        let interval = now.duration_since(self.last).as_secs_f64();
        let dt = interval.min(0.25);
        self.last = now;
        // The first frames include start-up (window, adapter, shader compilation).
        if self.quit_after.is_some() && self.frames >= WARM_UP_FRAMES {
            self.intervals_ms.push(interval * 1e3);
        }
        if self.frames >= WARM_UP_FRAMES {
            Self::push(&mut self.interval_s, interval);
        }
        let len = self.source.walk().track.length();
        let (fwd, back, left, right) = ui.ctx().input(|i| {
            (
                i.key_down(egui::Key::W) || i.key_down(egui::Key::ArrowUp),
                i.key_down(egui::Key::S) || i.key_down(egui::Key::ArrowDown),
                i.key_pressed(egui::Key::A) || i.key_pressed(egui::Key::ArrowLeft),
                i.key_pressed(egui::Key::D) || i.key_pressed(egui::Key::ArrowRight),
            )
        });
        let mut ds = 0.0;
        if self.playing || fwd {
            ds += self.speed_mps * dt;
        }
        if back {
            ds -= self.speed_mps * dt;
        }
        if self.junctions.is_some() {
            let view = self.view_dir();
            if let Some(j) = &mut self.junctions {
                if left {
                    j.choose(-1, view);
                }
                if right {
                    j.choose(1, view);
                }
            }
            self.walk_network(ds);
        } else {
            self.s = (self.s + ds).clamp(0.0, len);
        }
        if self.auto_budget {
            // The budget holds what it controls, the view's draw (the last frame's), within
            // the target frame time. The window's own panels and presentation come on top:
            // the panel shows the interval and rate beside it. (Fed the interval, a software
            // rasteriser whose panels alone take most of a 30 fps frame drove the budget to
            // one slab with holes, for no rate gained.)
            self.controller.target_ms = 1000.0 / self.target_fps;
            if let (true, Some(&ms)) = (self.frames >= WARM_UP_FRAMES, self.frame_ms.back()) {
                self.budget = self.controller.push(ms);
            }
        } else {
            // Chosen by hand: the budget starts from that choice when switched back on.
            self.controller.set_budget(self.budget);
        }
        self.step_stream();
        egui::Panel::left("controls")
            .frame(
                egui::Frame::side_top_panel(&ui.ctx().global_style())
                    .fill(egui::Color32::TRANSPARENT),
            )
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| {
                    self.controls_ui(ui);
                    self.stream_ui(ui);
                });
            });
        // No panel fill: the view's image covers the whole panel, and a software rasteriser
        // pays for every pixel painted under it (about 14 ms a frame at 1100×650 on lavapipe).
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| {
                let size = ui.available_size();
                self.draw_view(ui, frame, size);
            });
        self.frames += 1;
        if let (Some(n), Some(path)) = (self.quit_after, &self.screenshot) {
            if self.frames + 5 == n {
                let path = path.clone();
                ui.ctx()
                    .request_screenshot(move |img: std::sync::Arc<egui::ColorImage>| {
                        let rgba: Vec<u8> = img.pixels.iter().flat_map(|c| c.to_array()).collect();
                        let saved = image::RgbaImage::from_raw(
                            img.size[0] as u32,
                            img.size[1] as u32,
                            rgba,
                        )
                        .map(|i| i.save(&path));
                        if !matches!(saved, Some(Ok(()))) {
                            eprintln!("screenshot {}: could not save", path.display());
                        }
                    });
            }
        }
        if self.quit_after.is_some_and(|n| self.frames == n) {
            if let Some(line) = interval_summary(&self.intervals_ms) {
                println!(
                    "railview view: {line}; drawing at the end: {} (target {} fps); view {}x{} px; adapter {}",
                    self.budget_text(),
                    self.target_fps,
                    self.shown_px[0],
                    self.shown_px[1],
                    self.renderer
                        .as_ref()
                        .map_or_else(|| "none".to_string(), |r| r.gpu.describe())
                );
            }
            if let Source::Stream(st) = &self.source {
                let stats = st.session().stats();
                println!(
                    "railview view: {} frames in {:.2} s, {} bytes fetched in {} requests, cache peak {} of {} bytes, decoded views peak {} of {} bytes at PTM level {}, visible shown {:.0} %",
                    self.frames,
                    self.started.elapsed().as_secs_f64(),
                    stats.bytes,
                    stats.requests,
                    stats.cache_peak,
                    stats.cache_budget,
                    st.decoded_peak(),
                    st.decoded_budget_bytes,
                    st.layout_level(),
                    stats.visible_fraction * 100.0
                );
            }
        }
        if self.quit_after.is_some_and(|n| self.frames >= n) {
            ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
        }
        ui.ctx().request_repaint();
    }
}

/// The frame-time budget's target rate at start-up (a slider changes it).
const DEFAULT_TARGET_FPS: f64 = 10.0;

/// Frames left out of the interval summary at the start (window, adapter and shader
/// start-up).
const WARM_UP_FRAMES: u64 = 3;

/// `frame interval median M ms, 95th percentile P ms, longest L ms over N frames` of the
/// frame-to-frame intervals (the smoothness a person sees), or `None` without any.
fn interval_summary(intervals_ms: &[f64]) -> Option<String> {
    if intervals_ms.is_empty() {
        return None;
    }
    let mut v = intervals_ms.to_vec();
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    Some(format!(
        "frame interval median {:.1} ms, 95th percentile {:.1} ms, longest {:.1} ms over {} frame{}",
        at(0.5),
        at(0.95),
        v[v.len() - 1],
        v.len(),
        if v.len() == 1 { "" } else { "s" }
    ))
}

/// How the window runs.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    /// Close after this many frames (smoke tests, screenshots).
    pub quit_after: Option<u64>,
    /// With `quit_after`: save a screenshot of the window here a few frames before closing.
    pub screenshot: Option<std::path::PathBuf>,
    /// Start walking along the track at once.
    pub play: bool,
    /// When the command started (streaming times are reported from here).
    pub started: Instant,
    /// The frame-time budget's target rate (a slider changes it).
    pub target_fps: f64,
}

impl Default for WindowOptions {
    fn default() -> Self {
        WindowOptions {
            quit_after: None,
            screenshot: None,
            play: false,
            started: Instant::now(),
            target_fps: DEFAULT_TARGET_FPS,
        }
    }
}

/// Errors of the window.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WindowError {
    /// No adapter, or the renderer failed on the window's device (before or while drawing).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("viewer window: {0}")]
    Window(String),
}

/// Open a window on `source` (needs a display: X11, e.g. Xvfb). On any wgpu backend (`WGPU_BACKEND`
/// chooses, as for the headless commands); an error of the GPU closes the window and is
/// returned.
pub fn run(source: Source, opts: WindowOptions) -> Result<(), WindowError> {
    let mut wgpu_options = eframe::egui_wgpu::WgpuConfiguration::default();
    if let eframe::egui_wgpu::WgpuSetup::CreateNew(create) = &mut wgpu_options.wgpu_setup {
        // The renderer's limits: eframe asks a GL adapter for WebGL2-class ones (no compute)
        // even where it has more.
        create.device_descriptor = std::sync::Arc::new(|adapter| wgpu::DeviceDescriptor {
            label: Some("railview window"),
            required_limits: device_limits(adapter, DeviceLimits::Best),
            ..Default::default()
        });
    }
    let options = eframe::NativeOptions {
        renderer: eframe::Renderer::Wgpu,
        wgpu_options,
        viewport: egui::ViewportBuilder::default().with_inner_size([1100.0, 650.0]),
        ..Default::default()
    };
    let failed: std::sync::Arc<std::sync::Mutex<Option<GpuError>>> = Default::default();
    let in_app = failed.clone();
    let result = eframe::run_native(
        "railview",
        options,
        Box::new(move |cc| {
            let mut app = ViewerApp::new(cc, source)?;
            app.failed = in_app;
            app.quit_after = opts.quit_after;
            app.screenshot = opts.screenshot;
            app.playing = opts.play;
            app.started = opts.started;
            app.target_fps = opts.target_fps;
            Ok(Box::new(app))
        }),
    );
    if let Some(e) = failed.lock().ok().and_then(|mut f| f.take()) {
        return Err(e.into());
    }
    match result {
        Ok(()) => Ok(()),
        Err(eframe::Error::AppCreation(e)) => match e.downcast::<GpuError>() {
            Ok(e) => Err((*e).into()),
            Err(e) => Err(WindowError::Window(e.to_string())),
        },
        // No driver: no adapter, or no backend could make a surface for the window.
        Err(eframe::Error::Wgpu(
            e @ (eframe::egui_wgpu::WgpuError::RequestAdapterError(_)
            | eframe::egui_wgpu::WgpuError::CreateSurfaceError(_)),
        )) => Err(crate::gpu::no_adapter(
            wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY | wgpu::Backends::GL),
            e.to_string().trim_end_matches(": {}"),
        )
        .into()),
        Err(e) => Err(WindowError::Window(e.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::interval_summary;

    #[test]
    fn interval_summary_reports_median_tail_and_longest() {
        assert_eq!(interval_summary(&[]), None);
        let mut v: Vec<f64> = (1..=100).map(f64::from).collect();
        v.reverse();
        assert_eq!(
            interval_summary(&v).unwrap(),
            "frame interval median 51.0 ms, 95th percentile 95.0 ms, longest 100.0 ms over 100 frames"
        );
        assert_eq!(
            interval_summary(&[7.0]).unwrap(),
            "frame interval median 7.0 ms, 95th percentile 7.0 ms, longest 7.0 ms over 1 frame"
        );
    }
}
