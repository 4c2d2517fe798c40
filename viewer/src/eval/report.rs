//! What an evaluation writes: `eval.json` ([`EvalReport`]), `eval.csv`, `eval.md` and the
//! figures (error against frame time and bytes, PSNR along the track), as values and text;
//! the caller writes the files.

use std::fmt::Write as _;

use charts::{Axis, Chart, Figure, Series};
use serde::{Deserialize, Serialize};

use super::{ConfigSummary, EvalRow, ViewSpec};

/// `eval.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub db: String,
    pub scene: String,
    /// How the ground truth was rendered.
    pub truth: String,
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    /// Cube-map face size of the evaluated walkthrough.
    pub face_size: u32,
    /// Angle of a view pixel over a panorama pixel at their centres (1 = matched).
    pub resolution_ratio: f64,
    pub views: ViewSpec,
    pub adapter: String,
    pub summary: Vec<ConfigSummary>,
    /// The worst views between samples of the first configuration, worst first.
    pub worst: Vec<EvalRow>,
    pub rows: Vec<EvalRow>,
    /// The first configuration's error per pixel class against the sampling bound (when the
    /// prerender directory was at hand).
    #[serde(default)]
    pub classes: Option<super::bound::ClassTally>,
}

/// One line per row.
pub fn csv(rows: &[EvalRow]) -> String {
    let mut s = String::from(
        "config,s_m,segment,yaw_deg,pitch_deg,at_reference,x,y,z,psnr_db,ssim,hole_fraction,filled_fraction,frame_ms,db_bytes\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{:.4},{},{:.2},{:.2},{},{:.4},{:.4},{:.4},{:.3},{:.4},{:.6},{:.6},{:.3},{}",
            r.config,
            r.view.s,
            r.view.segment,
            r.view.yaw_deg,
            r.view.pitch_deg,
            r.view.at_reference,
            r.position[0],
            r.position[1],
            r.position[2],
            r.psnr_db,
            r.ssim,
            r.hole_fraction,
            r.filled_fraction,
            r.frame_ms,
            r.db_bytes
        );
    }
    s
}

fn db(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.2}")
    } else {
        "–".into()
    }
}

/// The Markdown page: settings, a table per configuration, the worst views, the figures.
pub fn markdown(r: &EvalReport, figures: &[(String, String)]) -> String {
    let mut m = format!(
        "# Error against run time: {}\n\nScene `{}`; views {}×{} px, FOV {}°, resolution \
         ratio {:.2} (view pixel over panorama pixel at the centre; faces of {} px); {} \
         positions inside every segment × {} directions × pitches {:?}. Ground truth: {}. \
         Adapter: {}. \"Worst 5 %\" is the PSNR that 95 % of the views meet or beat.\n\n",
        r.db,
        r.scene,
        r.width,
        r.height,
        r.fov_deg,
        r.resolution_ratio,
        r.face_size,
        r.views.per_segment,
        r.views.directions,
        r.views.pitches_deg,
        r.truth,
        r.adapter
    );
    m += "| config | views between | PSNR mean (dB) | PSNR worst 5 % (dB) | PSNR worst (dB) | SSIM mean | SSIM worst 5 % | holes mean % | holes worst 5 % | filled mean % | PSNR at samples (dB) | frame ms | DB bytes |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for s in &r.summary {
        let b = &s.between;
        let filled: Vec<f64> = r
            .rows
            .iter()
            .filter(|x| x.config == s.config && !x.view.at_reference)
            .map(|x| x.filled_fraction)
            .collect();
        let filled = filled.iter().sum::<f64>() / filled.len().max(1) as f64;
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {:.4} | {:.4} | {:.3} | {:.3} | {:.3} | {} | {} | {} |",
            s.config,
            b.views,
            db(b.psnr_mean_db),
            db(b.psnr_worst5_db),
            db(b.psnr_min_db),
            b.ssim_mean,
            b.ssim_worst5,
            b.holes_mean * 100.0,
            b.holes_worst5 * 100.0,
            filled * 100.0,
            db(s.at_samples.psnr_mean_db),
            if s.frame_ms.is_finite() {
                format!("{:.2}", s.frame_ms)
            } else {
                "–".into()
            },
            s.db_bytes
        );
    }
    if r.summary
        .iter()
        .any(|s| s.config == super::bound::EXACT_FILLED)
    {
        m += "\nThe sampling bound (rows `exact warp`): the same two reference panoramas warped \
              exactly into each view between samples with their exact depth, on the CPU \
              (`bound::exact_warp`), holes left black or filled from the farther side; the \
              oracle takes per pixel the better of the two references (unreachable). Where \
              railview is near the filled bound, only more or better samples help.\n";
    }
    if let Some(c) = &r.classes {
        m += "\n## Where the error is (first configuration, by the exact warp's pixel classes)\n\n";
        m += &c.markdown();
    }
    if !r.worst.is_empty() {
        m += "\n## Worst views between samples\n\n| rank | config | s (m) | position (m) | yaw (°) | pitch (°) | PSNR (dB) | SSIM | holes % | picture |\n|---|---|---|---|---|---|---|---|---|---|\n";
        for (i, w) in r.worst.iter().enumerate() {
            let _ = writeln!(
                m,
                "| {} | {} | {:.2} | ({:.2}, {:.2}, {:.2}) | {:.0} | {:.0} | {:.2} | {:.4} | {:.3} | [worst-{}.png](worst-{}.png) |",
                i + 1,
                w.config,
                w.view.s,
                w.position[0],
                w.position[1],
                w.position[2],
                w.view.yaw_deg,
                w.view.pitch_deg,
                w.psnr_db,
                w.ssim,
                w.hole_fraction * 100.0,
                i + 1,
                i + 1
            );
        }
        m += "\n![The worst view: reconstruction, ground truth, |difference| × 4](worst-1.png)\n";
    }
    m.push('\n');
    for (file, title) in figures {
        let _ = writeln!(m, "![{title}]({file})\n");
    }
    m
}

/// The figures, as `(file stem, title, figure)`.
pub fn figures(r: &EvalReport) -> Vec<(String, String, Figure)> {
    let mut out = Vec::new();
    // A colour per configuration; a dot for the mean over the views, a ring for the worst 5 %.
    let per_config = |x: fn(&ConfigSummary) -> f64| -> Vec<Series> {
        let mut v: Vec<Series> = r
            .summary
            .iter()
            .enumerate()
            .filter(|(_, s)| x(s).is_finite())
            .flat_map(|(i, s)| {
                [
                    Series::points(s.config.clone(), vec![(x(s), s.between.psnr_mean_db)]).color(i),
                    Series::front("", vec![(x(s), s.between.psnr_worst5_db)]).color(i),
                ]
            })
            .collect();
        v.push(Series::points("(dot) mean of the views", Vec::new()).color(7));
        v.push(Series::front("(ring) worst 5 % of the views", Vec::new()).color(7));
        v
    };
    let psnr_axis = || Axis::linear("PSNR between samples (dB)");
    let mut by_time = Chart::new("Error against frame time")
        .x(Axis::linear("frame time on this adapter (ms)"))
        .y(psnr_axis());
    for s in per_config(|s| s.frame_ms) {
        by_time = by_time.series(s);
    }
    out.push((
        "psnr_vs_frame_ms".into(),
        "PSNR against frame time".into(),
        Figure::single(by_time),
    ));
    let mut by_bytes = Chart::new("Error against database bytes")
        .x(Axis::auto("bytes read from the database (MB)"))
        .y(psnr_axis());
    for s in per_config(|s| s.db_bytes as f64 / 1e6) {
        by_bytes = by_bytes.series(s);
    }
    out.push((
        "psnr_vs_bytes".into(),
        "PSNR against database bytes".into(),
        Figure::single(by_bytes),
    ));
    if let Some(first) = r.summary.first() {
        let mut along = Chart::new(format!("PSNR along the track ({})", first.config))
            .x(Axis::linear("arc length along the track (m)"))
            .y(Axis::linear("PSNR (dB)"));
        let rows: Vec<&EvalRow> = r.rows.iter().filter(|x| x.config == first.config).collect();
        let mut yaws: Vec<i64> = Vec::new();
        for x in rows.iter().filter(|x| !x.view.at_reference) {
            let rel = relative_yaw(x);
            if !yaws.contains(&rel) {
                yaws.push(rel);
            }
        }
        yaws.sort_unstable();
        for (i, yaw) in yaws.iter().enumerate() {
            let pts = rows
                .iter()
                .filter(|x| !x.view.at_reference && relative_yaw(x) == *yaw)
                .map(|x| (x.view.s, x.psnr_db))
                .collect();
            along = along.series(
                Series::points(format!("between samples, {yaw}° from the track"), pts).color(i),
            );
        }
        let refs: Vec<(f64, f64)> = rows
            .iter()
            .filter(|x| x.view.at_reference)
            .map(|x| (x.view.s, x.psnr_db))
            .collect();
        if !refs.is_empty() {
            along = along.series(Series::points("at the reference samples", refs).color(7));
        }
        out.push((
            "psnr_along_track".into(),
            "PSNR of every view along the track".into(),
            Figure::single(along),
        ));
    }
    out
}

/// A view's direction from the direction of travel, whole degrees.
fn relative_yaw(r: &EvalRow) -> i64 {
    r.view.yaw_from_track_deg.round() as i64
}
