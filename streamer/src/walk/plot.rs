//! The quality-over-time figure of a walk, drawn with [`charts`]: one panel per bandwidth,
//! time on x, a solid line per strategy for the progressive downloading quality and a dashed
//! one in the same colour for the needed fraction.

use charts::{Axis, Chart, Figure, Series};

use super::{format_bps, WalkReport};

fn strategies(r: &WalkReport) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    for run in &r.runs {
        if !v.contains(&run.strategy) {
            v.push(run.strategy.clone());
        }
    }
    v
}

fn bandwidths(r: &WalkReport) -> Vec<Option<u64>> {
    let mut v = Vec::new();
    for run in &r.runs {
        if !v.contains(&run.bandwidth_bps) {
            v.push(run.bandwidth_bps);
        }
    }
    v
}

/// One panel per bandwidth, in report order.
pub fn figure(r: &WalkReport) -> Figure {
    let names = strategies(r);
    let panels = bandwidths(r)
        .into_iter()
        .map(|bw| {
            let label = bw.map_or("unlimited bandwidth".to_string(), format_bps);
            let mut chart = Chart::new(format!("{} / {}: streaming at {label}", r.scene, r.track))
                .x(Axis::linear("time since the walk started (s)"))
                .y(Axis::linear("fraction of visible pixels").range(0.0, 1.02));
            for run in r.runs.iter().filter(|run| run.bandwidth_bps == bw) {
                let ci = names.iter().position(|n| *n == run.strategy).unwrap_or(0);
                let q = run.frames.iter().map(|f| (f.t_s, f.quality)).collect();
                let n = run
                    .frames
                    .iter()
                    .map(|f| (f.t_s, f.needed_fraction))
                    .collect();
                chart = chart
                    .series(Series::line(format!("{}: quality", run.strategy), q).color(ci))
                    .series(
                        Series::dashed(format!("{}: at the level needed", run.strategy), n)
                            .color(ci),
                    );
            }
            chart
        })
        .collect();
    Figure::stacked(panels, 360)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::walk::{FrameRecord, RunReport};

    #[test]
    fn a_panel_per_bandwidth_and_two_lines_per_strategy() {
        let frames = |q: f64| {
            (0..5)
                .map(|i| FrameRecord {
                    t_s: i as f64,
                    s_m: i as f64,
                    track: 0,
                    d_m: i as f64,
                    quality: q * i as f64 / 4.0,
                    needed_fraction: 0.5,
                    complete: true,
                    bytes: 0,
                    cache_bytes: 0,
                })
                .collect::<Vec<_>>()
        };
        let run = |strategy: &str, bw: Option<u64>| RunReport {
            strategy: strategy.into(),
            bandwidth_bps: bw,
            time_to_first_frame_s: None,
            manifest_bytes: 0,
            manifest_s: 0.0,
            table_bytes: 0,
            table_requests: 0,
            background_bytes: 0,
            first_frame_bytes: None,
            first_frame_table_bytes: None,
            mean_needed_fraction: 0.5,
            mean_quality: 0.5,
            bytes: 0,
            bytes_per_m: 0.0,
            requests: 0,
            requests_per_m: 0.0,
            checksum_failures: 0,
            cache_budget_bytes: None,
            max_cache_bytes: 0,
            max_resident_bytes: 0,
            resident_within_budget: true,
            memory_budget_bytes: 0,
            wall_s: 0.0,
            retries: 0,
            timeouts: 0,
            outage_s: 0.0,
            longest_outage_s: 0.0,
            longest_wait_s: 0.0,
            part_faults: 0,
            parts_given_up: 0,
            table_faults: 0,
            tables_given_up: 0,
            completed: true,
            error: None,
            frames: frames(1.0),
            request_log: Vec::new(),
            ..RunReport::default()
        };
        let r = WalkReport {
            scene: "castle".into(),
            track: "main".into(),
            length_m: 10.0,
            speed_mps: 1.0,
            latency_s: 0.05,
            runs: vec![
                run("naive", Some(56_000)),
                run("ach", Some(56_000)),
                run("naive", None),
            ],
            error: None,
        };
        let fig = figure(&r);
        assert_eq!(fig.panels.len(), 2);
        assert_eq!(fig.panels[0].series.len(), 4);
        assert_eq!(fig.panels[1].series.len(), 2);
        // A strategy keeps its colour in every panel and for both of its lines.
        assert_eq!(fig.panels[0].series[0].color, fig.panels[1].series[0].color);
        assert_eq!(fig.panels[0].series[2].color, fig.panels[0].series[3].color);
        let svg = charts::svg(&fig).unwrap();
        assert!(svg.contains("56 kbit/s") && svg.contains("naive: quality"));
    }
}
