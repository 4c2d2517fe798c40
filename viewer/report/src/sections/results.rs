//! Sections of what the database does: streaming walks, error against run time, the
//! flythrough, and how to open it all again.

use streamer::walk::WalkReport;
use viewer::eval::report::EvalReport;

use super::{fmt_num, fmt_stat, pngs_in, spread, Ctx};
use crate::doc::{Block, Figure, Table};
use crate::StageStatus;

pub(super) fn streaming(c: &mut Ctx) {
    c.section(
        "streaming",
        "Streaming: quality over time per strategy and bandwidth",
    );
    let dir = c.layout.walk();
    let cmd = c.command(
        "walk",
        format!(
            "railview walk {} --out {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    let Some((_, report)) =
        c.stage_report::<WalkReport>(Some(dir.join("walk.json")), "walk", "walk/walk.json")
    else {
        return;
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "A simulated walk of {} m at {} m/s with {} ms latency, streaming from a server on \
         loopback. Quality is the paper's progressive downloading quality; the needed fraction \
         is the share of visible pixels present at the level they need.",
        fmt_num(Some(report.length_m), 1),
        fmt_num(Some(report.speed_mps), 2),
        fmt_num(Some(report.latency_s * 1000.0), 0)
    )));
    let png = dir.join("walk.png");
    if png.is_file() {
        if let Some(fig) = c.plot(
            &png,
            "walk",
            "quality (solid) and the fraction at the level needed (dashed) over time, one panel per bandwidth",
        ) {
            c.push(Block::Figures(vec![fig]));
        }
    } else {
        c.missing("the walk wrote no walk.png".into());
    }
    let rows = report
        .runs
        .iter()
        .map(|r| {
            vec![
                r.strategy.clone(),
                r.bandwidth_bps
                    .map_or("unlimited".into(), streamer::walk::format_bps),
                r.time_to_first_frame_s
                    .map_or("never".into(), |t| fmt_num(Some(t), 2)),
                fmt_num(Some(r.mean_needed_fraction), 3),
                fmt_num(Some(r.mean_quality), 3),
                r.bytes.to_string(),
                fmt_num(Some(r.bytes_per_m), 0),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "walk".into(),
        caption: "Walk summary per strategy and bandwidth".into(),
        header: [
            "strategy",
            "bandwidth",
            "first frame (s)",
            "needed fraction",
            "quality",
            "bytes",
            "bytes/m",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
}

pub(super) fn evaluation(c: &mut Ctx) {
    c.section("eval", "Error against run time");
    let dir = c.layout.eval();
    let cmd = c.command(
        "eval",
        format!(
            "railview eval {} --out {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    let Some((_, report)) =
        c.stage_report::<EvalReport>(Some(dir.join("eval.json")), "eval", "eval/eval.json")
    else {
        return;
    };
    c.push(Block::Command(cmd));
    let views = &report.views;
    c.push(Block::Para(format!(
        "Reconstructed views against the ground truth from the same camera ({}): {} positions          inside every segment of the track, {} directions each, at {}×{} px and {}° (resolution          ratio {}: a view pixel over a panorama pixel at their centres; 1 is matched). At the          reference samples the error is the resampling floor; between them it adds the          interpolation. \"Worst 5 %\" is the PSNR that 95 % of the views meet or beat.",
        report.truth,
        views.per_segment,
        views.directions,
        report.width,
        report.height,
        fmt_num(Some(report.fov_deg), 0),
        fmt_num(Some(report.resolution_ratio), 2),
    )));
    let rows: Vec<Vec<String>> = report
        .summary
        .iter()
        .map(|s| {
            let b = &s.between;
            vec![
                s.config.clone(),
                b.views.to_string(),
                fmt_stat(b.psnr_mean_db, 2),
                fmt_stat(b.psnr_worst5_db, 2),
                fmt_stat(b.psnr_min_db, 2),
                fmt_stat(b.ssim_mean, 4),
                fmt_stat(b.holes_mean * 100.0, 3),
                fmt_stat(s.at_samples.psnr_mean_db, 2),
                fmt_num(Some(s.frame_ms), 2),
                s.db_bytes.to_string(),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "eval".into(),
        caption: "Per configuration, between the samples (and the floor at them)".into(),
        header: [
            "config",
            "views",
            "PSNR mean (dB)",
            "PSNR worst 5 % (dB)",
            "PSNR worst (dB)",
            "SSIM mean",
            "holes mean %",
            "PSNR at samples (dB)",
            "frame ms",
            "database bytes",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
    let worst: Vec<Vec<String>> = report
        .worst
        .iter()
        .enumerate()
        .map(|(i, w)| {
            let [x, y, z] = w.position.map(|v| fmt_num(Some(v), 1));
            vec![
                (i + 1).to_string(),
                fmt_num(Some(w.view.s), 2),
                format!("({x}, {y}, {z})"),
                fmt_num(Some(w.view.yaw_deg), 0),
                fmt_num(Some(w.view.pitch_deg), 0),
                fmt_stat(w.psnr_db, 2),
            ]
        })
        .collect();
    if !worst.is_empty() {
        c.push(Block::Table(Table {
            id: "eval-worst".into(),
            caption: "Where the worst views between samples are".into(),
            header: [
                "rank",
                "s (m)",
                "position (m)",
                "yaw (°)",
                "pitch (°)",
                "PSNR (dB)",
            ]
            .map(String::from)
            .to_vec(),
            rows: worst,
        }));
    }
    let mut figs = Vec::new();
    for (file, caption) in [
        (
            "worst-1.png",
            "the worst view between samples: reconstruction, ground truth, |difference| × 4",
        ),
        (
            "worst-at-sample.png",
            "the worst view at a reference sample (the floor): reconstruction, truth, difference",
        ),
    ] {
        if dir.join(file).is_file() {
            if let Some(name) = c.copy(&dir.join(file), &format!("eval-{file}")) {
                figs.push(Figure {
                    src: name,
                    caption: caption.into(),
                    checker: false,
                    vector: None,
                });
            }
        }
    }
    for (stem, caption) in [
        ("psnr_along_track", "PSNR of every view along the track"),
        ("psnr_vs_frame_ms", "PSNR against frame time"),
        ("psnr_vs_bytes", "PSNR against the bytes read"),
    ] {
        let png = dir.join(format!("{stem}.png"));
        if png.is_file() {
            if let Some(f) = c.plot(&png, &format!("eval-{stem}"), caption) {
                figs.push(f);
            }
        }
    }
    if figs.is_empty() {
        c.missing("the evaluation wrote no pictures".into());
    } else {
        c.push(Block::Figures(figs));
    }
}

pub(super) fn tuning(c: &mut Ctx) {
    c.section("tune", "Error against cost over the build's knobs");
    let dir = c.layout.tune();
    let cmd = c.command(
        "tune",
        format!(
            "railview tune --scene {} --track {} --out {}",
            c.log.scene,
            c.log.track,
            dir.display()
        ),
    );
    let Some((_, sweep)) = c.stage_report::<tune::report::SweepReport>(
        Some(dir.join("sweep.json")),
        "tune",
        "tune/sweep.json",
    ) else {
        return;
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "A small sweep: the databases of this scene with one build knob changed at a time          around a base configuration ({}), each evaluated on the same views. {} The table          marks which configurations lie on the Pareto front of each cost against the PSNR of          the worst 5 % of views.",
        tune::report::describe(&sweep.base),
        sweep.views
    )));
    let fronts = |label: &str| -> String {
        sweep
            .fronts
            .iter()
            .filter(|(_, l)| l.iter().any(|x| x == label))
            .map(|(c, _)| c.name())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let rows = sweep
        .records
        .iter()
        .map(|m| {
            vec![
                m.label.clone(),
                format!("{} ({:.2} m)", m.samples, m.spacing_m),
                m.slab_count.to_string(),
                format!("{:.2}", m.error.psnr_mean_db),
                format!("{:.2}", m.error.psnr_worst5_db),
                format!("{:.1}", m.costs.prerender_cpu_s),
                format!("{:.1}", m.costs.build_cpu_s),
                format!("{:.3}", m.costs.db_bytes as f64 / 1e6),
                format!("{:.3}", m.costs.walk_bytes as f64 / 1e6),
                format!("{:.1}", m.costs.frame_ms),
                fronts(&m.label),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "tune".into(),
        caption: "Configurations: error between samples and costs".into(),
        header: [
            "configuration",
            "samples (spacing)",
            "slabs",
            "PSNR mean (dB)",
            "PSNR worst 5 % (dB)",
            "prerender CPU (s)",
            "build CPU (s)",
            "database (MB)",
            "walk streams (MB)",
            "frame (ms)",
            "on the front of",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
    for s in &sweep.selections {
        c.push(Block::Para(tune::report::selection_text(&sweep, s)));
    }
    let mut figs = Vec::new();
    for cost in tune::Cost::ALL {
        let stem = format!("pareto_{}", cost.name().replace('-', "_"));
        let png = dir.join(format!("{stem}.png"));
        if png.is_file() {
            if let Some(f) = c.plot(
                &png,
                &format!("tune-{stem}"),
                &format!("PSNR against {}, Pareto front marked", cost.axis()),
            ) {
                figs.push(f);
            }
        }
    }
    if !figs.is_empty() {
        c.push(Block::Figures(figs));
    }
}

pub(super) fn frames(c: &mut Ctx) {
    c.section("frames", "Flythrough");
    let dir = c.layout.frames();
    let all = pngs_in(&dir);
    if all.is_empty() {
        let why = match c.log.stage("view") {
            Some(s) if s.status == StageStatus::Done => {
                "the viewer window was shown instead of a headless flythrough".to_string()
            }
            _ => c.why_missing("flythrough", "frames/*.png"),
        };
        c.missing(why);
        return;
    }
    let cmd = c.command(
        "flythrough",
        format!(
            "railview flythrough {} -o {}",
            c.layout.db().display(),
            dir.display()
        ),
    );
    c.push(Block::Command(cmd));
    let mut figs = Vec::new();
    for i in spread(all.len()) {
        let p = &all[i];
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("frame.png")
            .to_string();
        if let Some(name) = c.copy(p, &format!("frame-{file}")) {
            figs.push(Figure {
                src: name,
                caption: format!("frame {} of {}", i + 1, all.len()),
                checker: false,
                vector: None,
            });
        }
    }
    c.push(Block::Figures(figs));
}

pub(super) fn later(c: &mut Ctx) {
    c.section("later", "Open it again later");
    let db = c.layout.db();
    let root = c.layout.root();
    c.push(Block::Code(format!(
        "railview view {db}                      # the viewer window on the database\n\
         railview serve {db} --addr 127.0.0.1:8080  # or serve it, then: railview walk http://127.0.0.1:8080 --out walk\n\
         railview flythrough {db} -o {frames}\n\
         railview demo --out {root}                # reuses everything built so far",
        db = db.display(),
        frames = c.layout.frames().display(),
        root = root.display()
    )));
}
