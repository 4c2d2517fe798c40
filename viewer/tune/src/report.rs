//! What a sweep writes: `sweep.json` ([`SweepReport`]), `sweep.csv`, `sweep.md` and one
//! Pareto figure per cost, as values and text; the caller writes the files.

use std::fmt::Write as _;

use charts::{Axis, Chart, Figure, Marker, Series};
use serde::{Deserialize, Serialize};

use crate::knobs::Knobs;
use crate::pareto::{front, quality, Selection};
use crate::record::{Cost, Measured};

/// `sweep.json`: everything measured, in configuration order. Apart from the timing fields
/// (CPU seconds, frame times) a rerun writes the same file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub scene: String,
    pub track: String,
    pub base: Knobs,
    /// How the views were chosen and judged (one line).
    pub views: String,
    pub records: Vec<Measured>,
    /// Per cost, the labels of the configurations on its front.
    pub fronts: Vec<(Cost, Vec<String>)>,
    /// The choices for the targets asked for.
    pub selections: Vec<Selection>,
}

impl SweepReport {
    pub fn new(
        scene: String,
        track: String,
        base: Knobs,
        views: String,
        records: Vec<Measured>,
        selections: Vec<Selection>,
    ) -> SweepReport {
        let fronts = Cost::ALL
            .iter()
            .map(|&c| {
                let pts: Vec<(f64, f64)> =
                    records.iter().map(|m| (c.value(m), quality(m))).collect();
                let f = front(&pts);
                (
                    c,
                    records
                        .iter()
                        .zip(f)
                        .filter(|(_, on)| *on)
                        .map(|(m, _)| m.label.clone())
                        .collect(),
                )
            })
            .collect();
        SweepReport {
            scene,
            track,
            base,
            views,
            records,
            fronts,
            selections,
        }
    }

    fn on_front(&self, cost: Cost, label: &str) -> bool {
        self.fronts
            .iter()
            .any(|(c, l)| *c == cost && l.iter().any(|x| x == label))
    }
}

fn db(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.2}")
    } else {
        "–".into()
    }
}

/// One line per configuration.
pub fn csv(r: &SweepReport) -> String {
    let mut s = String::from(
        "label,every,samples,spacing_m,face_size,supersample,slabs,slab_count,tile_size,mesh_error_px,cull_variant,alpha,drop_levels,psnr_mean_db,psnr_worst5_db,psnr_min_db,ssim_mean,ssim_worst5,holes_mean,holes_worst5,psnr_at_samples_db,prerender_cpu_s,build_cpu_s,db_bytes,walk_bytes,frame_ms\n",
    );
    for m in &r.records {
        let (k, e, c) = (&m.knobs, &m.error, &m.costs);
        let _ = writeln!(
            s,
            "\"{}\",{},{},{:.3},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{:.4},{:.4},{:.6},{:.6},{:.3},{:.2},{:.2},{},{},{:.3}",
            m.label.replace('"', "'"),
            k.every,
            m.samples,
            m.spacing_m,
            k.face_size,
            k.supersample,
            k.slabs,
            m.slab_count,
            k.tile_size,
            k.mesh_error_px,
            k.cull,
            k.alpha,
            k.drop_levels,
            e.psnr_mean_db,
            e.psnr_worst5_db,
            e.psnr_min_db,
            e.ssim_mean,
            e.ssim_worst5,
            e.holes_mean,
            e.holes_worst5,
            e.psnr_at_samples_db,
            c.prerender_cpu_s,
            c.build_cpu_s,
            c.db_bytes,
            c.walk_bytes,
            c.frame_ms
        );
    }
    s
}

/// The letters of the costs whose front a configuration is on.
fn front_marks(r: &SweepReport, label: &str) -> String {
    let letters = [
        (Cost::PrerenderCpu, 'P'),
        (Cost::BuildCpu, 'B'),
        (Cost::DbBytes, 'D'),
        (Cost::WalkBytes, 'W'),
        (Cost::FrameMs, 'F'),
    ];
    letters
        .iter()
        .filter(|(c, _)| r.on_front(*c, label))
        .map(|(_, l)| *l)
        .collect()
}

/// The Pareto table (Markdown): one row per configuration.
pub fn table(r: &SweepReport) -> String {
    let mut m = String::from(
        "| configuration | samples (spacing) | slabs | PSNR mean (dB) | PSNR worst 5 % (dB) | PSNR worst (dB) | SSIM mean | holes mean % | prerender CPU (s) | build CPU (s) | database (MB) | walk streams (MB) | frame (ms) | on the front of |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for x in &r.records {
        let (e, c) = (&x.error, &x.costs);
        let _ = writeln!(
            m,
            "| {} | {} ({:.2} m) | {} | {} | **{}** | {} | {:.4} | {:.3} | {:.1} | {:.1} | {:.2} | {:.2} | {:.1} | {} |",
            x.label,
            x.samples,
            x.spacing_m,
            x.slab_count,
            db(e.psnr_mean_db),
            db(e.psnr_worst5_db),
            db(e.psnr_min_db),
            e.ssim_mean,
            e.holes_mean * 100.0,
            c.prerender_cpu_s,
            c.build_cpu_s,
            c.db_bytes as f64 / 1e6,
            c.walk_bytes as f64 / 1e6,
            c.frame_ms,
            front_marks(r, &x.label)
        );
    }
    m += "\nFronts: P prerender CPU, B build CPU, D database bytes, W bytes a standard walk streams, F frame time — against the PSNR of the worst 5 % of views.\n";
    m
}

/// What a selection chose, what it left out against the base and what that saved.
pub fn selection_text(r: &SweepReport, s: &Selection) -> String {
    let Some(i) = s.chosen else {
        let best = r
            .records
            .iter()
            .max_by(|a, b| quality(a).total_cmp(&quality(b)));
        return format!(
            "No configuration reaches {:.1} dB on its worst 5 % of views; the best is {} at {} dB.",
            s.target_psnr_db,
            best.map_or("–".into(), |b| b.label.clone()),
            best.map_or("–".into(), |b| db(quality(b)))
        );
    };
    let chosen = &r.records[i];
    let base = r.records.iter().find(|m| m.knobs == r.base);
    let mut t = format!(
        "Target {:.1} dB on the worst 5 % of views, cheapest by {}: **{}** ({} dB worst 5 %, {} dB mean).",
        s.target_psnr_db,
        s.cost.name(),
        chosen.label,
        db(chosen.error.psnr_worst5_db),
        db(chosen.error.psnr_mean_db)
    );
    let left = chosen.knobs.differences(&r.base);
    if left.is_empty() {
        t += " It is the base configuration: nothing left out.";
    } else {
        let _ = write!(t, " Against the base it takes {}", left.join(", "));
        if let Some(b) = base {
            if chosen.samples < b.samples {
                let _ = write!(
                    t,
                    " ({} of {} reference viewpoints)",
                    chosen.samples, b.samples
                );
            }
        }
        t.push('.');
    }
    if let Some(b) = base {
        let saved: Vec<String> = [
            Cost::DbBytes,
            Cost::WalkBytes,
            Cost::PrerenderCpu,
            Cost::BuildCpu,
        ]
        .iter()
        .map(|&c| {
            let (vb, vc) = (c.value(b), c.value(chosen));
            let pct = if vb > 0.0 {
                100.0 * (vb - vc) / vb
            } else {
                0.0
            };
            // Not "-0 %".
            let pct = if pct.abs() < 0.5 { 0.0 } else { pct };
            let change = if pct < 0.0 {
                format!("{:.0} % more", -pct)
            } else {
                format!("{pct:.0} % saved")
            };
            format!(
                "{} {} → {} ({change})",
                c.name(),
                c.format(vb),
                c.format(vc)
            )
        })
        .collect();
        let _ = write!(t, " Against the base: {}.", saved.join("; "));
    }
    t
}

/// `sweep.md`: the table, the choices, the figures.
pub fn markdown(r: &SweepReport, figures: &[(String, String)]) -> String {
    let mut m = format!(
        "# Error against cost: {} / {}\n\n{}\n\nBase configuration: {}.\n\n",
        r.scene,
        r.track,
        r.views,
        describe(&r.base)
    );
    m += &table(r);
    for s in &r.selections {
        m.push('\n');
        m += &selection_text(r, s);
        m.push('\n');
    }
    m.push('\n');
    for (file, title) in figures {
        let _ = writeln!(m, "![{title}]({file})\n");
    }
    m
}

/// The knobs in words.
pub fn describe(k: &Knobs) -> String {
    format!(
        "every {} reference viewpoint of the track, faces of {} px at {}×{} rays per pixel, slabs {}, tiles of {} px, mesh error {} px, culling {} α {}, {} finest texture level(s) left out",
        match k.every {
            1 => "".to_string(),
            n => format!("{n}th"),
        },
        k.face_size,
        k.supersample,
        k.supersample,
        k.slabs,
        k.tile_size,
        k.mesh_error_px,
        k.cull,
        k.alpha,
        k.drop_levels
    )
    .replace("every  reference", "every reference")
}

/// One figure per cost: the worst 5 % PSNR (and the mean) of every configuration against the
/// cost, the front marked, the chosen configurations as vertical lines.
pub fn figures(r: &SweepReport) -> Vec<(String, String, Figure)> {
    Cost::ALL
        .iter()
        .map(|&c| {
            let pts: Vec<(f64, f64)> = r
                .records
                .iter()
                .map(|m| (c.plotted(m), quality(m)))
                .collect();
            let f = front(&pts);
            let on: Vec<(f64, f64)> = pts
                .iter()
                .zip(&f)
                .filter(|(_, on)| **on)
                .map(|(p, _)| *p)
                .collect();
            let mut chart = Chart::new(format!("Error against {}", c.axis()))
                .x(Axis::auto(c.axis()))
                .y(Axis::linear("PSNR between samples (dB)"))
                .series(Series::points("worst 5 % of views", pts.clone()).color(0))
                .series(
                    Series::points(
                        "mean of the views",
                        r.records
                            .iter()
                            .map(|m| (c.plotted(m), m.error.psnr_mean_db))
                            .collect(),
                    )
                    .color(7),
                )
                .series(Series::front("Pareto front (worst 5 %)", on).color(1));
            for s in r.selections.iter().filter(|s| s.cost == c) {
                if let Some(i) = s.chosen {
                    chart = chart.marker(Marker {
                        x: c.plotted(&r.records[i]),
                        name: format!("chosen for {:.1} dB", s.target_psnr_db),
                        color: 3,
                        dashed: true,
                    });
                }
            }
            (
                format!("pareto_{}", c.name().replace('-', "_")),
                format!("PSNR against {}", c.axis()),
                Figure::single(chart),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pareto::select;
    use crate::record::{Costs, ErrorSummary};

    fn rec(label: &str, knobs: Knobs, bytes: u64, worst5: f64) -> Measured {
        Measured {
            label: label.into(),
            knobs,
            samples: 10,
            spacing_m: 2.0,
            slab_count: 3,
            resolution_ratio: 1.0,
            error: ErrorSummary {
                psnr_worst5_db: worst5,
                psnr_mean_db: worst5 + 5.0,
                ..ErrorSummary::default()
            },
            costs: Costs {
                db_bytes: bytes,
                walk_bytes: bytes / 2,
                prerender_cpu_s: 10.0,
                build_cpu_s: 5.0,
                frame_ms: 3.0,
            },
            dir: String::new(),
        }
    }

    #[test]
    fn tables_choices_and_figures_say_what_was_left_out() {
        let base = Knobs::default();
        let half = Knobs {
            every: 2,
            ..base.clone()
        };
        let records = vec![
            rec("base", base.clone(), 4_000_000, 31.0),
            rec("every 2nd reference viewpoint", half, 2_500_000, 29.0),
        ];
        let sel = vec![
            select(&records, 28.0, Cost::DbBytes),
            select(&records, 30.0, Cost::DbBytes),
            select(&records, 40.0, Cost::DbBytes),
        ];
        let r = SweepReport::new(
            "castle".into(),
            "main".into(),
            base,
            "views".into(),
            records,
            sel,
        );
        let md = markdown(&r, &[("pareto_db_bytes.svg".into(), "t".into())]);
        assert!(
            md.contains("| every 2nd reference viewpoint | 10 (2.00 m) |"),
            "{md}"
        );
        assert!(md.contains("**every 2nd reference viewpoint**"), "{md}");
        assert!(
            md.contains("db-bytes 4.00 MB → 2.50 MB (38 % saved)"),
            "{md}"
        );
        assert!(md.contains("It is the base configuration"), "{md}");
        assert!(md.contains("No configuration reaches 40.0 dB"), "{md}");
        assert_eq!(csv(&r).lines().count(), 3);
        let figs = figures(&r);
        assert_eq!(figs.len(), 5);
        let svg = charts::svg(&figs[2].2).unwrap();
        assert!(svg.contains("database size (MB)") && svg.contains("chosen for 28.0 dB"));
    }
}
