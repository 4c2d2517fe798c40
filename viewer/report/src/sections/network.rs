//! The scene's network of tracks: its map (tracks, junctions, reference viewpoints coloured
//! by the later-slab tiles they keep), its culling judged by the oracle, and a walk that turns
//! at every junction beside a straight one.

use std::collections::BTreeMap;

use charts::{Axis, Chart, Figure as ChartFigure, Series};
use occlusion::report::CullReport;
use streamer::walk::WalkReport;

use super::{fmt_num, Ctx};
use crate::doc::{Block, Figure, Table};

/// Colour classes of the map's viewpoints: later-slab tiles kept, by quartile.
const CLASSES: usize = 4;

pub(super) fn network(c: &mut Ctx) {
    c.section("network", "The streets: a network of tracks");
    let root = c.layout.network();
    let db_dir = root.join("db");
    c.push(Block::Command(c.command(
        "network",
        format!(
            "railview build --scene {} --track all --out {}",
            c.log.scene,
            db_dir.display()
        ),
    )));
    let m = match db::read_manifest(&db_dir) {
        Ok(m) => m,
        Err(e) => {
            let why = match c.log.stage("network") {
                Some(s) if s.status != crate::StageStatus::Done => {
                    c.why_missing("network", "manifest.json")
                }
                _ => format!("{e}"),
            };
            c.missing(why);
            return;
        }
    };
    let vps = db::split::unique_viewpoints(&m);
    let mut tracks_at: BTreeMap<usize, Vec<&str>> = BTreeMap::new();
    for t in &m.tracks {
        for v in &t.viewpoints {
            tracks_at.entry(v.index).or_default().push(&t.name);
        }
    }
    let junctions: Vec<(usize, Vec<&str>)> = tracks_at
        .iter()
        .filter(|(_, t)| t.len() > 1)
        .map(|(&v, t)| (v, t.clone()))
        .collect();
    c.push(Block::Para(format!(
        "Every track of `{}` built into one database: {} tracks, {} reference viewpoints, {} \
         junctions. A junction is one viewpoint that every track through it uses, rendered once; \
         a walker passing it goes on along any of its branches without a cut (the frame at a \
         junction is its own view alone, whichever track the camera is on).",
        c.log.scene,
        m.tracks.len(),
        vps.len(),
        junctions.len()
    )));
    // The map, looking down: x right, z down the page (north up is −z).
    let kept = |v: &tracks::manifest::ViewpointEntry| {
        v.tiles.iter().filter(|t| t.slab > 0 && t.kept).count()
    };
    let mut chart = Chart::new("Tracks, junctions and reference viewpoints")
        .x(Axis::linear("x (m)"))
        .y(Axis::linear("−z (m)"));
    for (i, t) in m.tracks.iter().enumerate() {
        let line: Vec<(f64, f64)> = t
            .viewpoints
            .iter()
            .map(|v| (v.position.x, -v.position.z))
            .collect();
        chart = chart.series(Series::line(format!("track {}", t.name), line).color(i));
    }
    let mut counts: Vec<usize> = vps.iter().map(|v| kept(v)).collect();
    counts.sort_unstable();
    let bound = |q: usize| counts.get(q * counts.len() / CLASSES).copied().unwrap_or(0);
    let mut lo = 0;
    for k in 0..CLASSES {
        let hi = if k + 1 == CLASSES {
            usize::MAX
        } else {
            bound(k + 1).saturating_sub(1).max(lo)
        };
        let pts: Vec<(f64, f64)> = vps
            .iter()
            .filter(|v| (lo..=hi).contains(&kept(v)))
            .map(|v| (v.position.x, -v.position.z))
            .collect();
        if !pts.is_empty() {
            let name = if hi == usize::MAX {
                format!("viewpoint keeping {lo}+ later tiles")
            } else {
                format!("viewpoint keeping {lo}–{hi} later tiles")
            };
            chart = chart.series(Series::points(name, pts).color(m.tracks.len() + k));
        }
        if hi == usize::MAX {
            break;
        }
        lo = hi + 1;
    }
    let jpts: Vec<(f64, f64)> = junctions
        .iter()
        .filter_map(|(v, _)| vps.iter().find(|x| x.index == *v))
        .map(|v| (v.position.x, -v.position.z))
        .collect();
    chart = chart.series(Series::points("junction", jpts).color(m.tracks.len() + CLASSES));
    let fig = ChartFigure::single(chart);
    match (charts::svg(&fig), charts::png(&fig)) {
        (Ok(svg), Ok(png)) => {
            let ok = std::fs::write(c.dir.join("network-map.svg"), svg)
                .and_then(|()| std::fs::write(c.dir.join("network-map.png"), png));
            match ok {
                Ok(()) => c.push(Block::Figures(vec![Figure {
                    src: "network-map.png".into(),
                    caption: "The network seen from above: each track, its reference \
                              viewpoints coloured by the later-slab tiles culling kept there, \
                              and the junctions."
                        .into(),
                    checker: false,
                    vector: Some("network-map.svg".into()),
                }])),
                Err(e) => c.missing(format!("writing the map: {e}")),
            }
        }
        (Err(e), _) | (_, Err(e)) => c.missing(format!("drawing the map: {e}")),
    }
    c.push(Block::Table(Table {
        id: "network-junctions".into(),
        caption: "Junctions: the viewpoint and the tracks through it.".into(),
        header: vec!["viewpoint".into(), "position (m)".into(), "tracks".into()],
        rows: junctions
            .iter()
            .map(|(v, t)| {
                let p = vps
                    .iter()
                    .find(|x| x.index == *v)
                    .map_or(String::new(), |x| {
                        format!(
                            "({:.1}, {:.1}, {:.1})",
                            x.position.x, x.position.y, x.position.z
                        )
                    });
                vec![v.to_string(), p, t.join(", ")]
            })
            .collect(),
    }));
    culling(c);
    turns(c);
}

/// The network's culling table: later-slab tiles kept against what the oracle saw, false
/// culls (every segment judged, the junctions' included).
fn culling(c: &mut Ctx) {
    let path = c.layout.network().join("work/prerender/cull.json");
    c.push(Block::Command(c.command(
        "network-cull",
        format!(
                "railview cull {} --oracle",
                path.parent()
                    .map_or(String::new(), |p| p.display().to_string())
            ),
    )));
    let Some((_, rep)) = c.stage_report::<CullReport>(Some(path), "network-cull", "cull.json")
    else {
        return;
    };
    let rows = rep
        .runs
        .iter()
        .map(|r| {
            let later = r.later_slabs();
            vec![
                r.variant.name().to_string(),
                later.tiles_after.to_string(),
                later.visible_tiles.map_or("–".into(), |v| v.to_string()),
                fmt_num(later.kept_per_seen(), 2),
                later.false_culls.map_or("–".into(), |v| v.to_string()),
                format!("{:.1}", r.seconds),
            ]
        })
        .collect();
    c.push(Block::Table(Table {
        id: "network-culling".into(),
        caption: "Culling over the network (α = 1): a viewpoint keeps every tile some point of \
                  any segment through it can see; the oracle samples every segment."
            .into(),
        header: vec![
            "variant".into(),
            "later tiles kept".into(),
            "seen by the oracle".into(),
            "kept ÷ seen".into(),
            "false culls".into(),
            "seconds".into(),
        ],
        rows,
    }));
}

/// The walk with a turn at every junction beside the straight one.
fn turns(c: &mut Ctx) {
    let root = c.layout.network();
    c.push(Block::Command(c.command(
        "network-walk-turns",
        format!("railview walk {} --route …", root.join("db").display()),
    )));
    let mut rows = Vec::new();
    for (stage, dir) in [
        ("network-walk-turns", "walk-turns"),
        ("network-walk-straight", "walk-straight"),
    ] {
        let Some((_, rep)) = c.stage_report::<WalkReport>(
            Some(root.join(dir).join("walk.json")),
            stage,
            "walk.json",
        ) else {
            continue;
        };
        for r in &rep.runs {
            let after: Vec<String> = r.turns.iter().map(|t| t.label(" s")).collect();
            rows.push(vec![
                rep.track.clone(),
                format!("{:.0}", rep.length_m),
                r.strategy.clone(),
                format!("{:.3}", r.mean_needed_fraction),
                fmt_num(r.mean_needed_fraction_at_turns, 3),
                r.stalled_frames_at_turns.to_string(),
                if after.is_empty() {
                    "no turn".into()
                } else {
                    after.join(", ")
                },
            ]);
        }
    }
    if rows.is_empty() {
        return;
    }
    c.push(Block::Table(Table {
        id: "network-turns".into(),
        caption: "Walks over the network at 2 Mbit/s and 50 ms: through every junction of the \
                  route (turning at each) and straight along `main`; the fraction of the needed \
                  pixels present, over the whole walk and in the 4 m after each turn, and the \
                  time from passing a junction to the first complete frame."
            .into(),
        header: vec![
            "route".into(),
            "m".into(),
            "strategy".into(),
            "needed fraction".into(),
            "at turns".into(),
            "stalled frames at turns".into(),
            "first complete after each turn".into(),
        ],
        rows,
    }));
}
