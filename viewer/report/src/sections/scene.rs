//! Sections about the pictures: the viewpoints, the depth histogram and slab boundaries, and
//! the slab layers of one viewpoint.

use std::path::Path;

use prerender::store::PrerenderReport;
use serde_json::Value;
use slabs::report::SlabsReport;
use tracks::Face;

use super::{fmt_depth, fmt_num, read_json, reduction, spread, Ctx};
use crate::doc::{Block, Figure, Table};
use crate::images;

pub(super) fn viewpoints(c: &mut Ctx) -> Option<PrerenderReport> {
    c.section("viewpoints", "The scene from a few reference viewpoints");
    let work = c.layout.prerender();
    let cmd = c.command(
        "prerender",
        format!(
            "railview prerender --scene {} --track {} --face-size {} --out {}",
            c.log.scene,
            c.log.track,
            c.log.face_size,
            c.path_arg(work.clone())
        ),
    );
    let (path, report): (_, PrerenderReport) = c.stage_report(
        c.layout.find("prerender.json"),
        "prerender",
        "prerender.json",
    )?;
    c.push(Block::Command(cmd));
    c.push(Block::Table(Table {
        id: "prerender".into(),
        caption: format!("Prerender ({})", path.display()),
        header: [
            "samples",
            "face size",
            "low-res face",
            "seconds",
            "primary rays/s",
        ]
        .map(String::from)
        .to_vec(),
        rows: vec![vec![
            report.samples.to_string(),
            report.face_size.to_string(),
            report.lowres_face_size.to_string(),
            fmt_num(Some(report.seconds), 2),
            fmt_num(Some(report.rays_per_second), 0),
        ]],
    }));
    let pre_dir = prerender::store::PrerenderDir::new(path.parent().unwrap_or(Path::new(".")));
    let n = report.samples;
    let mut figs = Vec::new();
    for i in spread(n) {
        let src = pre_dir.color_png(i);
        let at = pre_dir
            .sample_meta(i)
            .map(|m| format!(" at s = {:.2} m", m.s))
            .unwrap_or_default();
        if let Some(name) = c.strip(&src, &format!("view-{i:04}.png")) {
            figs.push(Figure {
                src: name,
                caption: format!("viewpoint {i}{at}: +x, +z, −x, −z faces (360° around)"),
                checker: false,
                vector: None,
            });
        }
    }
    if figs.is_empty() {
        c.missing(format!(
            "no colour cube maps under {}",
            pre_dir.root().display()
        ));
    } else {
        c.push(Block::Figures(figs));
    }
    Some(report)
}

pub(super) fn histogram(c: &mut Ctx) -> Option<SlabsReport> {
    c.section("slabs", "Depth histogram and slab boundaries");
    let cmd = c.command(
        "slabs",
        format!("railview slabs {}", c.path_arg(c.layout.prerender())),
    );
    let (path, report): (_, SlabsReport) =
        c.stage_report(c.layout.find("slabs.json"), "slabs", "slabs.json")?;
    c.push(Block::Command(cmd));
    if let Some(hist) = path
        .parent()
        .map(|d| d.join("histogram.png"))
        .filter(|p| p.is_file())
    {
        if let Some(fig) = c.plot(
            &hist,
            "histogram",
            "depth histogram of the whole track with the chosen slab boundaries",
        ) {
            c.push(Block::Figures(vec![fig]));
        }
    } else {
        c.missing("the slab stage wrote no histogram.png".into());
    }
    let rows = report
        .slabs
        .iter()
        .enumerate()
        .map(|(k, s)| {
            vec![
                k.to_string(),
                fmt_depth(s.near),
                fmt_depth(s.far),
                s.tiles_before.to_string(),
                s.tiles_after.to_string(),
                reduction(s.tiles_before as f64, s.tiles_after as f64),
                s.opaque_pixels.to_string(),
                s.texture_bytes.to_string(),
                s.mesh_bytes.to_string(),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "slab-table".into(),
        caption: "Slabs, nearest first: tiles before and after empty-tile removal".into(),
        header: [
            "slab",
            "near (m)",
            "far (m)",
            "tiles",
            "non-empty tiles",
            "removed",
            "opaque pixels",
            "texture bytes",
            "mesh bytes",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }));
    // The criterion's numbers, each under its name in `slabs.json`.
    let mut crit = Vec::new();
    match serde_json::to_value(&report.criterion) {
        Ok(v) => flatten("criterion", &v, &mut crit),
        Err(e) => c.missing(format!("the slab-count criterion: {e}")),
    }
    if !crit.is_empty() {
        c.push(Block::Table(Table {
            id: "slab-criterion".into(),
            caption: "Why this many slabs: the numbers of the slab-count criterion".into(),
            header: vec!["quantity".into(), "value".into()],
            rows: crit.into_iter().map(|(k, v)| vec![k, v]).collect(),
        }));
    }
    Some(report)
}

/// Scalars of a JSON object as `a.b` = value rows (arrays of scalars joined, big arrays and
/// arrays of objects skipped), in the order of their names.
pub(super) fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, String)>) {
    match v {
        Value::Number(n) => out.push((prefix.into(), format_number(n))),
        Value::String(s) => out.push((prefix.into(), s.clone())),
        Value::Bool(b) => out.push((prefix.into(), b.to_string())),
        Value::Null => out.push((prefix.into(), "∞ / none".into())),
        Value::Object(o) if out.len() < 40 => {
            for (k, v) in o {
                flatten(&format!("{prefix}.{k}"), v, out);
            }
        }
        Value::Array(a) if a.len() <= 16 && a.iter().all(|x| !x.is_object() && !x.is_array()) => {
            let items: Vec<String> = a
                .iter()
                .map(|x| match x {
                    Value::Number(n) => format_number(n),
                    Value::Null => "∞".into(),
                    other => other.to_string().trim_matches('"').to_string(),
                })
                .collect();
            out.push((prefix.into(), items.join(", ")));
        }
        _ => {}
    }
}

fn format_number(n: &serde_json::Number) -> String {
    match (n.as_i64(), n.as_f64()) {
        (Some(i), _) => i.to_string(),
        (None, Some(f)) if f.abs() >= 1e-3 && f.abs() < 1e7 => format!("{f:.4}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string(),
        (None, Some(f)) => format!("{f:.4e}"),
        _ => n.to_string(),
    }
}

pub(super) fn layers(c: &mut Ctx) {
    c.section("layers", "Slab layers of one viewpoint");
    let Some(path) = c.layout.find("prerender.json") else {
        let why = c.why_missing("prerender", "prerender.json");
        c.missing(why);
        return;
    };
    let pre_dir = prerender::store::PrerenderDir::new(path.parent().unwrap_or(Path::new(".")));
    let n = read_json::<PrerenderReport>(&path).map_or(0, |r| r.samples);
    let i = n / 2;
    let Some(meta) = pre_dir.layers_meta(i) else {
        c.missing(format!(
            "viewpoint {i} has no slab layers yet ({} is missing)",
            pre_dir.layers_json(i).display()
        ));
        return;
    };
    let cmd = c.command(
        "slabs",
        format!("railview slabs {}", pre_dir.root().display()),
    );
    c.push(Block::Command(cmd));
    c.push(Block::Para(format!(
        "Viewpoint {i}: each slab layer holds the first surface whose distance lies in the \
         slab's range (nearer surfaces removed); transparent pixels (checkerboard) are outside \
         the slab. The full view is first."
    )));
    let mut figs = Vec::new();
    if let Some(name) = c.strip(&pre_dir.color_png(i), &format!("layer-{i:04}-all.png")) {
        figs.push(Figure {
            src: name,
            caption: "all slabs (the panorama)".into(),
            checker: false,
            vector: None,
        });
    }
    for (k, range) in meta.slabs.iter().enumerate() {
        let src = pre_dir.slab_color_png(i, k);
        if let Some(name) = c.strip(&src, &format!("layer-{i:04}-slab{k}.png")) {
            let far = if range.far.is_finite() {
                format!("{:.1} m", range.far)
            } else {
                "∞".into()
            };
            figs.push(Figure {
                src: name,
                caption: format!("slab {k}: [{:.1} m, {far})", range.near),
                checker: true,
                vector: None,
            });
        }
    }
    c.push(Block::Figures(figs));
    // One face, side by side across the slabs: the face where the farthest slab shows most.
    let last = meta.slabs.len().saturating_sub(1);
    let face = images::busiest_face(&pre_dir.slab_color_png(i, last)).unwrap_or(Face::PosX);
    let mut row = Vec::new();
    for (k, _) in meta.slabs.iter().enumerate() {
        let name = format!("layer-{i:04}-slab{k}-{}.png", face.short_name());
        let made = images::cube_face(&pre_dir.slab_color_png(i, k), face)
            .and_then(|img| images::save_png(&img, &c.dir.join(&name)));
        match made {
            Ok(()) => row.push(Figure {
                src: name,
                caption: format!("slab {k}, face {}", face.short_name()),
                checker: true,
                vector: None,
            }),
            Err(e) => c.missing(format!("{e:#}")),
        }
    }
    if !row.is_empty() {
        c.push(Block::Para(format!(
            "The same viewpoint's {} face, slab by slab:",
            face.short_name()
        )));
        c.push(Block::Figures(row));
    }
}
