//! [`Bench::compare_backends`]: the main frame types on a renderer per wgpu backend,
//! frames interleaved across backends (one frame of each backend in turn), so a load change
//! hits all alike.

use std::time::Instant;

use super::measure::{cpu_ns, median};
use super::{Bench, BenchError, FrameKind, PLAIN};
use crate::gpu::Renderer;
use crate::plan::FramePlan;

/// One backend: its adapter and, per frame type, median wall ms per frame drawn and waited
/// for, throughput ms per frame, and the ratio of both to the first backend's.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BackendResult {
    pub backend: String,
    pub adapter: String,
    /// Capabilities the device lacks (fallback paths taken).
    pub without: String,
    pub variants: Vec<BackendVariant>,
}

/// One frame type on one backend.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BackendVariant {
    pub name: String,
    pub wall_ms: f64,
    /// CPU time of all the process's threads while the frame was drawn (only that
    /// backend's renderer works then; steadier than the wall clock on a loaded machine).
    pub cpu_ms: Option<f64>,
    pub throughput_ms: Option<f64>,
    pub wall_ratio: f64,
    pub cpu_ratio: Option<f64>,
    pub throughput_ratio: Option<f64>,
}

/// A row of the comparison: the plain panorama (`None`) or a frame type.
type Row = Option<FrameKind>;

/// Samples per row and backend: `[row][backend]` milliseconds per frame.
type Samples = Vec<Vec<Vec<f64>>>;

impl Bench<'_> {
    /// Time the plain panorama and [`FrameKind::BACKENDS`] on each of `renderers` (a name
    /// and a renderer per backend, the first the reference of the ratios).
    pub fn compare_backends(
        &self,
        mut renderers: Vec<(String, Renderer)>,
    ) -> Result<Vec<BackendResult>, BenchError> {
        let rows: Vec<Row> = std::iter::once(None)
            .chain(FrameKind::BACKENDS.map(Some))
            .collect();
        let plans: Vec<FramePlan> = rows
            .iter()
            .map(|row| match row {
                None => self.plain_plan(),
                Some(kind) => self.plan_of(*kind),
            })
            .collect::<Result<_, _>>()?;
        let draw = |r: &mut Renderer, k: usize| -> Result<(), BenchError> {
            match rows[k] {
                None => r.draw_panorama(&plans[k], &self.pano)?,
                Some(_) => r.draw(&plans[k], self.views)?,
            }
            Ok(())
        };
        // Warm-up: uploads, pipelines, first use of every path.
        for (_, r) in &mut renderers {
            for k in 0..rows.len() {
                for _ in 0..2 {
                    draw(r, k)?;
                }
            }
        }
        let (wall, cpu) = self.time_interleaved(&mut renderers, rows.len(), draw)?;
        // through[backend][row]: throughput ms per frame.
        let mut through = vec![vec![None; rows.len()]; renderers.len()];
        let n = self.params.throughput_frames;
        if n > 0 {
            for (k, (plan, row)) in plans.iter().zip(&rows).enumerate() {
                for (b, (_, r)) in renderers.iter_mut().enumerate() {
                    let t = match row {
                        None => r.throughput_panorama(plan, &self.pano, n)?,
                        Some(_) => r.throughput(plan, self.views, n)?,
                    };
                    through[b][k] = Some(t.wall_ms);
                }
            }
        }
        Ok(results(&renderers, &rows, &wall, &cpu, &through))
    }

    /// `frames` rounds of one frame of every row on every backend in turn: the wall and CPU
    /// samples, `[row][backend]`.
    fn time_interleaved(
        &self,
        renderers: &mut [(String, Renderer)],
        rows: usize,
        draw: impl Fn(&mut Renderer, usize) -> Result<(), BenchError>,
    ) -> Result<(Samples, Samples), BenchError> {
        let mut wall = vec![vec![Vec::new(); renderers.len()]; rows];
        let mut cpu = wall.clone();
        for _ in 0..self.params.frames {
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
        Ok((wall, cpu))
    }
}

/// Medians per backend and row, and their ratios to the first backend's.
fn results(
    renderers: &[(String, Renderer)],
    rows: &[Row],
    wall: &Samples,
    cpu: &Samples,
    through: &[Vec<Option<f64>>],
) -> Vec<BackendResult> {
    // walls[backend][row]: median ms; cpus likewise where measured.
    let walls: Vec<Vec<f64>> = (0..renderers.len())
        .map(|b| wall.iter().map(|per| median(&per[b])).collect())
        .collect();
    let cpus: Vec<Vec<Option<f64>>> = (0..renderers.len())
        .map(|b| {
            cpu.iter()
                .map(|per| (!per[b].is_empty()).then(|| median(&per[b])))
                .collect()
        })
        .collect();
    renderers
        .iter()
        .enumerate()
        .map(|(b, (name, r))| BackendResult {
            backend: name.clone(),
            adapter: r.gpu.describe(),
            without: r.gpu.caps.missing(),
            variants: rows
                .iter()
                .enumerate()
                .map(|(k, row)| BackendVariant {
                    name: row.map_or(PLAIN, |kind| kind.settings().name).to_string(),
                    wall_ms: walls[b][k],
                    cpu_ms: cpus[b][k],
                    throughput_ms: through[b][k],
                    wall_ratio: walls[b][k] / walls[0][k],
                    cpu_ratio: cpus[b][k].zip(cpus[0][k]).map(|(a, z)| a / z),
                    throughput_ratio: through[b][k].zip(through[0][k]).map(|(a, z)| a / z),
                })
                .collect(),
        })
        .collect()
}

/// The human-readable lines of a comparison, each ending in a newline: the frame and the
/// reference backend, then per backend its adapter and a row per frame type.
pub fn backends_summary(
    results: &[BackendResult],
    width: u32,
    height: u32,
    frames: usize,
) -> String {
    let mut lines = Vec::new();
    lines.push(format!(
        "{width}x{height}, {frames} frames per frame type and backend, interleaved; ratios to {}",
        results.first().map_or("", |r| r.backend.as_str())
    ));
    for res in results {
        lines.push(format!(
            "{}: {} (without: {})",
            res.backend, res.adapter, res.without
        ));
        for v in &res.variants {
            lines.push(format!(
                "  {:<40} {:>8.1} ms wall ({:>4.2}x)  {:>8.1} ms cpu ({:>4.2}x)  throughput {:>7.2} ms ({:>4.2}x)",
                v.name,
                v.wall_ms,
                v.wall_ratio,
                v.cpu_ms.unwrap_or(f64::NAN),
                v.cpu_ratio.unwrap_or(f64::NAN),
                v.throughput_ms.unwrap_or(f64::NAN),
                v.throughput_ratio.unwrap_or(f64::NAN),
            ));
        }
    }
    lines.iter().map(|l| format!("{l}\n")).collect()
}
