//! The app's streaming side: the priority strategies offered, one streaming step per
//! frame, and the streaming panel with its figures over time.

use std::collections::VecDeque;

use eframe::egui;
use egui_plot::{Line, Plot, PlotPoints};
use streamer::client::{LiveCount, PriorityMode};

use super::{Source, ViewerApp, HISTORY};

/// The download priority strategies offered in the UI.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    Ach,
    Visibility,
    Both,
}

impl Strategy {
    pub const ALL: [Strategy; 3] = [Strategy::Ach, Strategy::Visibility, Strategy::Both];

    /// `ach`, `visibility` or `both` (`ach+visibility` too).
    pub fn parse(text: &str) -> Option<Strategy> {
        match text {
            "ach" => Some(Strategy::Ach),
            "visibility" => Some(Strategy::Visibility),
            "both" | "ach+visibility" => Some(Strategy::Both),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Strategy::Ach => "ach",
            Strategy::Visibility => "visibility",
            Strategy::Both => "both",
        }
    }

    pub fn mode(self) -> PriorityMode {
        match self {
            Strategy::Ach => PriorityMode::Ach,
            Strategy::Visibility => PriorityMode::Visibility,
            Strategy::Both => PriorityMode::Combined { ach_weight: 0.5 },
        }
    }
}

/// Streaming figures over time, for the plots.
#[derive(Clone, Copy, Debug)]
pub(super) struct StreamSample {
    pub(super) t_s: f64,
    pub(super) bytes_per_s: f64,
    pub(super) quality: f64,
    pub(super) visible: f64,
}

/// Streaming state of the app.
pub(super) struct StreamUi {
    pub(super) strategy: Strategy,
    pub(super) prefetch: bool,
    pub(super) level_cap: usize,
    /// The debug overlay tinting tiles that arrived in the last second: off until asked for
    /// (on a slow link tiles arrive all the time, and the walk would be seen through a tint).
    pub(super) highlight: bool,
    pub(super) live: Option<Vec<LiveCount>>,
    pub(super) history: VecDeque<StreamSample>,
    /// Seconds from start to the first frame with every visible tile at some level.
    pub(super) first_complete_s: Option<f64>,
}

impl ViewerApp {
    /// One streaming step before the frame is drawn: downloads planned for the camera of the
    /// last frame, new levels folded in, changed views re-uploaded.
    pub(super) fn step_stream(&mut self) {
        let [w, h] = self.view_px;
        let camera = self.camera(w, h);
        let s = self.s;
        let live = self.stream.live.take();
        let started = self.started;
        let Source::Stream(st) = &mut self.source else {
            return;
        };
        let report = st.step(s, &camera, live.as_deref());
        if let Some(r) = &mut self.renderer {
            report.apply(r, &st.walk.views);
        }
        let stats = st.session().stats().clone();
        if self.stream.first_complete_s.is_none() && stats.visible_fraction >= 1.0 {
            let secs = started.elapsed().as_secs_f64();
            self.stream.first_complete_s = Some(secs);
            println!(
                "railview view: every visible tile shown after {secs:.2} s ({} bytes fetched, cache {} of {} bytes; manifest of {} bytes took {:.2} s of it)",
                stats.bytes, stats.cache_used, stats.cache_budget, stats.manifest_bytes, stats.manifest_s
            );
        }
        if self.stream.history.len() == HISTORY {
            self.stream.history.pop_front();
        }
        self.stream.history.push_back(StreamSample {
            t_s: stats.t_s,
            bytes_per_s: stats.bytes_per_s,
            quality: stats.quality,
            visible: stats.visible_fraction,
        });
        if let Some(e) = st.errors.last() {
            self.error = Some(e.clone());
        }
    }

    /// The streaming panel: strategy, level cap, and the figures over time.
    pub(super) fn stream_ui(&mut self, ui: &mut egui::Ui) {
        let Source::Stream(st) = &mut self.source else {
            return;
        };
        ui.separator();
        ui.strong("streaming");
        let before = (
            self.stream.strategy,
            self.stream.prefetch,
            self.stream.level_cap,
        );
        egui::ComboBox::from_label("priority")
            .selected_text(self.stream.strategy.name())
            .show_ui(ui, |ui| {
                for s in Strategy::ALL {
                    ui.selectable_value(&mut self.stream.strategy, s, s.name());
                }
            });
        ui.checkbox(&mut self.stream.prefetch, "prefetch the next segment");
        let levels = st
            .session()
            .table()
            .items
            .iter()
            .map(|i| i.info.levels.len())
            .max()
            .unwrap_or(1);
        ui.add(
            egui::Slider::new(&mut self.stream.level_cap, 0..=levels)
                .text("level groups (0 = all)"),
        );
        ui.checkbox(
            &mut self.stream.highlight,
            "highlight tiles loaded in the last second",
        );
        if before
            != (
                self.stream.strategy,
                self.stream.prefetch,
                self.stream.level_cap,
            )
        {
            let session = st.session_mut();
            session.set_mode(self.stream.strategy.mode());
            session.set_prefetch(self.stream.prefetch);
            session.set_level_cap((self.stream.level_cap > 0).then_some(self.stream.level_cap));
        }
        let stats = st.session().stats();
        let m = st.session().manifest();
        ui.label(match (m.cull_alpha, &m.cull_variant) {
            (Some(a), Some(v)) => {
                format!("culled with α = {a} ({v}); culled tiles are not in the database")
            }
            (Some(a), None) => format!("culled with α = {a}; culled tiles are not in the database"),
            _ => "no occlusion culling recorded".to_string(),
        });
        ui.label(format!(
            "{:.1} kB/s · {} requests made · {} parts in flight, {} queued · link {:.2} Mbit/s, {:.0} ms",
            stats.bytes_per_s / 1e3,
            stats.requests,
            stats.in_flight,
            stats.queued,
            stats.link.0 / 1e6,
            stats.link.1 * 1e3
        ));
        let (tables, viewpoints) = st.session().tables_loaded();
        ui.label(format!(
            "viewpoint tables {tables} of {viewpoints} (tiles of the others cannot be asked for yet)"
        ));
        let used = stats.cache_used as f64 / stats.cache_budget.max(1) as f64;
        ui.add(egui::ProgressBar::new(used as f32).text(format!(
            "cache {:.1} / {:.1} MiB (peak {:.1}, pinned {:.1})",
            stats.cache_used as f64 / 1048576.0,
            stats.cache_budget as f64 / 1048576.0,
            stats.cache_peak as f64 / 1048576.0,
            stats.pinned_bytes as f64 / 1048576.0
        )));
        ui.label(format!(
            "decoded views {:.1} / {:.1} MiB ({} laid out)",
            st.decoded_bytes() as f64 / 1048576.0,
            st.decoded_budget_bytes as f64 / 1048576.0,
            st.laid_out_views().len()
        ));
        ui.label(format!(
            "quality {:.2} · visible shown {:.0} % · segment shown {:.0} % · {:.1} MiB fetched",
            stats.quality,
            stats.visible_fraction * 100.0,
            stats.coarse_fraction * 100.0,
            stats.bytes as f64 / 1048576.0
        ));
        if let Some(t) = self.stream.first_complete_s {
            ui.label(format!("every visible tile shown after {t:.2} s"));
        }
        if stats.failed_requests > 0 || stats.checksum_failures > 0 || stats.part_faults > 0 {
            ui.label(format!(
                "{} failed downloads, {} checksum mismatches (re-fetched), {} damaged parts ({} given up)",
                stats.failed_requests,
                stats.checksum_failures,
                stats.part_faults,
                stats.parts_given_up
            ));
        }
        if stats.retries > 0 || stats.longest_stall_s >= 1.0 {
            ui.label(format!(
                "waiting {:.1} s now, {:.1} s at most · {} retries, {} timeouts, server unreachable {:.1} s",
                stats.stalled_s,
                stats.longest_stall_s,
                stats.retries,
                stats.timeouts,
                stats.outage_s
            ));
        }
        if let Some(e) = &stats.last_error {
            ui.colored_label(egui::Color32::YELLOW, format!("server: {e}"));
        }
        let hist = &self.stream.history;
        let series = |f: fn(&StreamSample) -> f64| -> PlotPoints<'_> {
            hist.iter().map(|h| [h.t_s, f(h)]).collect()
        };
        Plot::new("bandwidth").height(90.0).show(ui, |p| {
            p.line(Line::new("kB/s", series(|h| h.bytes_per_s / 1e3)));
        });
        Plot::new("quality")
            .height(90.0)
            .include_y(0.0)
            .include_y(1.0)
            .show(ui, |p| {
                p.line(Line::new("downloading quality", series(|h| h.quality)));
                p.line(Line::new("visible shown", series(|h| h.visible)));
            });
    }
}
