//! The interactive viewer (eframe/egui on the same wgpu device as the renderer): move along
//! the track (W/S or arrow keys, slider, play with a speed), look around by dragging the view,
//! FOV; panels for frame time (plotted over time), GPU memory and the frame-time budget's
//! current choice (texture level, slabs, second view).

use std::collections::VecDeque;
use std::time::Instant;

use eframe::egui;
use egui_plot::{Line, Plot, PlotPoints};
use tracks::PerspectiveCamera;

use crate::gpu::{Gpu, Renderer};
use crate::headless::yaw_along;
use crate::plan::{adjust_budget, plan_frame, DrawBudget};
use crate::source::Walkthrough;

const HISTORY: usize = 300;

/// The app state.
pub struct ViewerApp {
    walk: Walkthrough,
    renderer: Option<Renderer>,
    texture: Option<(egui::TextureId, [u32; 2])>,
    s: f64,
    speed_mps: f64,
    playing: bool,
    yaw_offset_deg: f64,
    pitch_deg: f64,
    fov_deg: f64,
    budget: DrawBudget,
    auto_budget: bool,
    target_fps: f64,
    frame_ms: VecDeque<f64>,
    frames: u64,
    last: Instant,
    error: Option<String>,
    /// Close after this many frames (screenshots and smoke tests).
    pub quit_after: Option<u64>,
    /// Save a screenshot of the window here a few frames before closing.
    pub screenshot: Option<std::path::PathBuf>,
}

impl ViewerApp {
    /// Build from eframe's creation context; the renderer shares eframe's wgpu device.
    pub fn new(cc: &eframe::CreationContext<'_>, walk: Walkthrough) -> ViewerApp {
        let (renderer, error) = match &cc.wgpu_render_state {
            Some(rs) => (
                Some(Renderer::new(Gpu {
                    device: rs.device.clone(),
                    queue: rs.queue.clone(),
                    info: rs.adapter.get_info(),
                })),
                None,
            ),
            None => (None, Some("eframe started without wgpu".to_string())),
        };
        let slabs = walk.views.first().map_or(1, |v| v.slab_count());
        ViewerApp {
            walk,
            renderer,
            texture: None,
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
            auto_budget: true,
            target_fps: 10.0,
            frame_ms: VecDeque::new(),
            frames: 0,
            last: Instant::now(),
            error,
            quit_after: None,
            screenshot: None,
        }
    }

    fn push(q: &mut VecDeque<f64>, v: f64) {
        if q.len() == HISTORY {
            q.pop_front();
        }
        q.push_back(v);
    }

    /// Draw the current view into the renderer's target and show it as an egui texture.
    fn draw_view(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame, size: egui::Vec2) {
        let (Some(r), Some(rs)) = (&mut self.renderer, frame.wgpu_render_state()) else {
            return;
        };
        let ppp = ui.ctx().pixels_per_point();
        let w = ((size.x * ppp) as u32).max(1);
        let h = ((size.y * ppp) as u32).max(1);
        let camera = PerspectiveCamera {
            position: self.walk.position_at(self.s),
            yaw_deg: yaw_along(&self.walk, self.s) + self.yaw_offset_deg,
            pitch_deg: self.pitch_deg,
            fov_deg: self.fov_deg,
            width: w,
            height: h,
        };
        let t0 = Instant::now();
        let result = plan_frame(&self.walk.views, &camera, self.s, self.budget)
            .map_err(|e| e.to_string())
            .and_then(|plan| r.draw(&plan, &self.walk.views).map_err(|e| e.to_string()));
        if let Err(e) = result {
            self.error = Some(e);
            return;
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        Self::push(&mut self.frame_ms, ms);
        let Some(view) = r.output_view_unorm() else {
            return;
        };
        let mut egui_renderer = rs.renderer.write();
        let id = match self.texture {
            Some((id, dims)) if dims == [w, h] => {
                egui_renderer.update_egui_texture_from_wgpu_texture(
                    &rs.device,
                    view,
                    wgpu::FilterMode::Linear,
                    id,
                );
                id
            }
            Some((id, _)) => {
                egui_renderer.update_egui_texture_from_wgpu_texture(
                    &rs.device,
                    view,
                    wgpu::FilterMode::Linear,
                    id,
                );
                self.texture = Some((id, [w, h]));
                id
            }
            None => {
                let id = egui_renderer.register_native_texture(
                    &rs.device,
                    view,
                    wgpu::FilterMode::Linear,
                );
                self.texture = Some((id, [w, h]));
                id
            }
        };
        drop(egui_renderer);
        let response = ui.add(
            egui::Image::from_texture(egui::load::SizedTexture::new(id, size))
                .sense(egui::Sense::drag()),
        );
        let d = response.drag_delta();
        self.yaw_offset_deg -= d.x as f64 * self.fov_deg / size.x.max(1.0) as f64;
        self.pitch_deg = (self.pitch_deg + d.y as f64 * self.fov_deg / size.x.max(1.0) as f64)
            .clamp(-90.0, 90.0);
    }

    fn controls_ui(&mut self, ui: &mut egui::Ui) {
        let len = self.walk.track.length();
        ui.heading(&self.walk.scene);
        ui.label(format!(
            "track {} · {:.1} m · {} views",
            self.walk.track.name,
            len,
            self.walk.views.len()
        ));
        ui.add(egui::Slider::new(&mut self.s, 0.0..=len.max(1e-6)).text("position m"));
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
        ui.checkbox(&mut self.auto_budget, "frame-time budget");
        ui.add(egui::Slider::new(&mut self.target_fps, 5.0..=120.0).text("target fps"));
        let slabs = self.walk.views.first().map_or(1, |v| v.slab_count()).max(1);
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
        ui.label(format!(
            "drawing: {} slab(s), texture level +{}, {} view(s); mesh density fixed (one mesh per tile)",
            self.budget.max_slabs.min(slabs),
            self.budget.lod_bias,
            if self.budget.blend { 2 } else { 1 }
        ));
        ui.separator();
        let mean = self.frame_ms.iter().sum::<f64>() / self.frame_ms.len().max(1) as f64;
        ui.label(format!("frame {mean:.1} ms (GPU draw + wait)"));
        if let Some(r) = &self.renderer {
            ui.label(format!(
                "GPU memory for views: {:.1} MiB · database {:.1} MiB",
                r.uploaded_bytes() as f64 / 1048576.0,
                self.walk.bytes as f64 / 1048576.0
            ));
            ui.label(format!("adapter: {}", r.gpu.info.name));
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
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let now = Instant::now();
        let dt = now.duration_since(self.last).as_secs_f64().min(0.25);
        self.last = now;
        let len = self.walk.track.length();
        let (fwd, back) = ui.ctx().input(|i| {
            (
                i.key_down(egui::Key::W) || i.key_down(egui::Key::ArrowUp),
                i.key_down(egui::Key::S) || i.key_down(egui::Key::ArrowDown),
            )
        });
        let mut ds = 0.0;
        if self.playing || fwd {
            ds += self.speed_mps * dt;
        }
        if back {
            ds -= self.speed_mps * dt;
        }
        self.s = (self.s + ds).clamp(0.0, len);
        if self.auto_budget {
            let recent: Vec<f64> = self.frame_ms.iter().rev().take(10).copied().collect();
            if self.frames.is_multiple_of(10) {
                let slabs = self.walk.views.first().map_or(1, |v| v.slab_count());
                self.budget = adjust_budget(self.budget, &recent, 1000.0 / self.target_fps, slabs);
            }
        }
        egui::Panel::left("controls")
            .resizable(true)
            .show(ui, |ui| self.controls_ui(ui));
        egui::CentralPanel::default().show(ui, |ui| {
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
        if self.quit_after.is_some_and(|n| self.frames >= n) {
            ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
        }
        ui.ctx().request_repaint();
    }
}

/// Open a window on `walk` (needs a display: X11, e.g. Xvfb).
pub fn run(
    walk: Walkthrough,
    quit_after: Option<u64>,
    screenshot: Option<std::path::PathBuf>,
    play: bool,
) -> Result<(), eframe::Error> {
    let options = eframe::NativeOptions {
        renderer: eframe::Renderer::Wgpu,
        viewport: egui::ViewportBuilder::default().with_inner_size([1100.0, 650.0]),
        ..Default::default()
    };
    eframe::run_native(
        "railview",
        options,
        Box::new(move |cc| {
            let mut app = ViewerApp::new(cc, walk);
            app.quit_after = quit_after;
            app.screenshot = screenshot;
            app.playing = play;
            Ok(Box::new(app))
        }),
    )
}
