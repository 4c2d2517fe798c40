//! Sections of what the database does: streaming walks, error against run time, the
//! flythrough, and how to open it all again.

use serde_json::Value;

use super::{fmt_int, fmt_num, num, pngs_in, spread, Ctx};
use crate::report::doc::{Block, Figure, Table};
use crate::report::StageStatus;

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
    let Some((_, report)) = c.stage_report(Some(dir.join("walk.json")), "walk", "walk/walk.json")
    else {
        return;
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "A simulated walk of {} m at {} m/s with {} ms latency, streaming from a server on \
         loopback. Quality is the paper's progressive downloading quality; the needed fraction \
         is the share of visible pixels present at the level they need.",
        fmt_num(num(&report, "length_m"), 1),
        fmt_num(num(&report, "speed_mps"), 2),
        fmt_num(num(&report, "latency_s").map(|s| s * 1000.0), 0)
    )));
    let png = dir.join("walk.png");
    if png.is_file() {
        if let Some(name) = c.copy(&png, "walk.png") {
            c.push(Block::Figures(vec![Figure {
                src: name,
                caption: "quality (solid) and needed fraction (dotted) over time, one panel per bandwidth".into(),
                checker: false,
            }]));
        }
    } else {
        c.missing("the walk wrote no walk.png".into());
    }
    let rows = report
        .get("runs")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .map(|r| {
            let bw = match r.get("bandwidth_bps") {
                Some(Value::Null) | None => "unlimited".to_string(),
                Some(v) => v.as_u64().map_or("?".into(), streamer::walk::format_bps),
            };
            vec![
                r.get("strategy")
                    .and_then(Value::as_str)
                    .unwrap_or("?")
                    .to_string(),
                bw,
                match r.get("time_to_first_frame_s") {
                    Some(Value::Null) => "never".into(),
                    v => fmt_num(v.and_then(Value::as_f64), 2),
                },
                fmt_num(num(r, "mean_needed_fraction"), 3),
                fmt_num(num(r, "mean_quality"), 3),
                fmt_int(num(r, "bytes")),
                fmt_num(num(r, "bytes_per_m"), 0),
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
    let Some((_, report)) = c.stage_report(Some(dir.join("eval.json")), "eval", "eval/eval.json")
    else {
        return;
    };
    c.push(Block::Command(cmd));
    c.push(Block::Para(
        "Reconstructed views compared with the ray tracer's ground truth from the same camera. \
         At the reference samples the error is the resampling floor; between them it adds the \
         interpolation error."
            .into(),
    ));
    let mut figs = Vec::new();
    for p in pngs_in(&dir).into_iter().take(8) {
        let file = p
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("eval.png")
            .to_string();
        if let Some(name) = c.copy(&p, &format!("eval-{file}")) {
            figs.push(Figure {
                src: name,
                caption: file,
                checker: false,
            });
        }
    }
    if figs.is_empty() {
        c.missing("the evaluation wrote no plots".into());
    } else {
        c.push(Block::Figures(figs));
    }
    // Mean per configuration, the reference samples apart from the rest.
    let mut groups: Vec<(String, [Acc; 2])> = Vec::new();
    for row in report
        .get("rows")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        let config = match row.get("config") {
            Some(Value::String(s)) => s.clone(),
            Some(v) => v.to_string(),
            None => "?".into(),
        };
        let at_ref = row
            .get("at_reference")
            .and_then(Value::as_bool)
            .unwrap_or(false);
        let g = match groups.iter().position(|(k, _)| *k == config) {
            Some(i) => i,
            None => {
                groups.push((config, [Acc::default(), Acc::default()]));
                groups.len() - 1
            }
        };
        groups[g].1[usize::from(!at_ref)].add(row);
    }
    let rows = groups
        .iter()
        .map(|(config, [at, between])| {
            vec![
                config.clone(),
                between.n.to_string(),
                at.mean(0),
                between.mean(0),
                between.mean(1),
                between.mean(2),
                between.mean(3),
                between.mean(4),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "eval".into(),
        caption: "Mean per configuration (PSNR at the reference samples = resampling floor)".into(),
        header: [
            "config",
            "views between",
            "PSNR at refs (dB)",
            "PSNR between (dB)",
            "SSIM between",
            "hole fraction between",
            "frame ms",
            "database bytes",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
}

/// Sums of `psnr_db`, `ssim`, `hole_fraction`, `frame_ms`, `db_bytes`.
#[derive(Default)]
struct Acc {
    n: usize,
    sums: [f64; 5],
    counts: [usize; 5],
}

impl Acc {
    fn add(&mut self, row: &Value) {
        self.n += 1;
        for (i, key) in ["psnr_db", "ssim", "hole_fraction", "frame_ms", "db_bytes"]
            .iter()
            .enumerate()
        {
            if let Some(x) = num(row, key).filter(|x| x.is_finite()) {
                self.sums[i] += x;
                self.counts[i] += 1;
            }
        }
    }
    fn mean(&self, i: usize) -> String {
        if self.counts[i] == 0 {
            "–".into()
        } else if i == 4 {
            // Bytes: the same for every row of a configuration.
            format!("{:.0}", self.sums[i] / self.counts[i] as f64)
        } else {
            format!("{:.3}", self.sums[i] / self.counts[i] as f64)
        }
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
