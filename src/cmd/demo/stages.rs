//! The stages the demo runs: each a function call with its parameters, and the command line
//! a person would type to reproduce it (built from the same values, for the log and the
//! report; never parsed).

use std::path::{Path, PathBuf};

use db::ach::AchParams;
use stages::build::{BuildParams, BuildScene};
use stages::cull::{CullParams, OracleParams, Variants};
use streamer::client::PriorityMode;
use streamer::walk::stage::{rate_arg, WalkParams, WalkSource};
use streamer::walk::{Strategy, WalkConfig};
use tune::sweep::ViewParams;
use tune::{Cost, CullChoice, Knobs, SweepParams, SweepSpec};
use viewer::eval::stage::EvalParams;
use viewer::eval::ViewSpec;
use viewer::flythrough::FlythroughParams;

use super::Args;
use crate::cmd::{eval, flythrough, view, walk};
use report::Layout;

/// One stage the demo runs.
pub struct Stage {
    pub name: &'static str,
    /// The words of the command line (after `railview`) that reproduces it; for the log
    /// and the report, never parsed.
    pub command: Vec<String>,
    /// The stage itself.
    pub run: Box<dyn Fn() -> anyhow::Result<()>>,
    /// Files whose presence (with a completed log record) proves the stage done.
    pub outputs: Vec<PathBuf>,
    /// Stages that must be done first.
    pub requires: Vec<&'static str>,
}

fn path_arg(p: &Path) -> String {
    p.display().to_string()
}

/// The stages that make the database, in order: the build runs prerender → slabs → cull
/// (shrunk, α = 1) → encode → ACH, each resuming; then culling runs again over every α and
/// every variant with the oracle, for the report's tables (it rewrites the same decisions
/// for the run the build used).
pub fn build_stages(args: &Args, layout: &Layout) -> Vec<Stage> {
    let db = layout.db();
    let build = BuildParams {
        work: Some(layout.work()),
        knobs: Knobs {
            face_size: args.face_size,
            cull: CullChoice::Auto,
            ..Knobs::default()
        },
        ..BuildParams::new(BuildScene::Tracer(args.scene.clone()), &args.track, &db)
    };
    let cull = CullParams {
        dir: layout.prerender(),
        alphas: vec![1.0, 0.9, 0.8],
        variants: Variants::All,
        oracle: Some(OracleParams {
            per_segment: 8,
            face_size: None,
        }),
        renders_per_segment: None,
    };
    let mut cull_command = vec![
        "cull".into(),
        path_arg(&cull.dir),
        "--alpha".into(),
        cull.alphas
            .iter()
            .map(|a| format!("{a:?}"))
            .collect::<Vec<_>>()
            .join(","),
    ];
    if let Some(o) = cull.oracle {
        cull_command.extend([
            "--oracle".into(),
            "--oracle-per-segment".into(),
            o.per_segment.to_string(),
        ]);
    }
    vec![
        Stage {
            name: "build",
            command: vec![
                "build".into(),
                "--scene".into(),
                args.scene.clone(),
                "--track".into(),
                build.track.clone(),
                "--face-size".into(),
                build.knobs.face_size.to_string(),
                "--out".into(),
                path_arg(&build.out),
                "--work".into(),
                path_arg(&build.work_dir()),
            ],
            outputs: vec![db.join("manifest.json"), layout.work().join("build.json")],
            requires: vec![],
            run: Box::new(move || {
                stages::build::run(&build, &crate::progress::terminal())?;
                Ok(())
            }),
        },
        Stage {
            name: "cull",
            command: cull_command,
            outputs: vec![layout.prerender().join("cull.json")],
            requires: vec!["build"],
            run: Box::new(move || {
                stages::cull::run(&cull, &crate::progress::terminal())?;
                Ok(())
            }),
        },
    ]
}

/// Face size of the demo's network of tracks (every street of the scene: more viewpoints than
/// its main track, so smaller faces).
pub const NETWORK_FACE: u32 = 64;

/// The route through the castle's network the demo walks: a turn at every junction it passes.
pub const NETWORK_ROUTE: &[&str] = &["north", "main", "cross", "west", "south"];

/// The stages on the scene's network of tracks (every track: `--track all`): its database at
/// faces of [`NETWORK_FACE`] px, its culling judged by the oracle (the junctions included),
/// and a walk with a turn at every junction beside a straight one along `main`.
pub fn network_stages(args: &Args, layout: &Layout) -> Vec<Stage> {
    let root = layout.network();
    let db = root.join("db");
    let work = root.join("work");
    let face = args.face_size.min(NETWORK_FACE);
    let build = BuildParams {
        work: Some(work.clone()),
        knobs: Knobs {
            face_size: face,
            cull: CullChoice::Auto,
            ..Knobs::default()
        },
        ..BuildParams::new(BuildScene::Tracer(args.scene.clone()), "all", &db)
    };
    let cull = CullParams {
        dir: work.join("prerender"),
        alphas: vec![1.0],
        variants: Variants::These(vec![
            stages::cull::Variant::Shrunk,
            stages::cull::Variant::Rendered,
        ]),
        oracle: Some(OracleParams {
            per_segment: 16,
            face_size: None,
        }),
        renders_per_segment: None,
    };
    let walk_of = |route: &[&str], out: PathBuf| {
        let base = WalkParams::new(
            WalkSource::Dir(db.clone()),
            out,
            vec![Strategy::Budget {
                mode: PriorityMode::Visibility,
                prefetch: true,
            }],
            vec![Some(2_000_000)],
        );
        WalkParams {
            config: WalkConfig {
                speed_mps: args.walk_speed,
                pause_s: 1.0,
                route: Some(route.iter().map(|t| t.to_string()).collect()),
                ..base.config
            },
            ..base
        }
    };
    let walks = [
        walk_of(NETWORK_ROUTE, root.join("walk-turns")),
        walk_of(&["main"], root.join("walk-straight")),
    ];
    let walk_stage = |name: &'static str, w: WalkParams| {
        let mut command = vec!["walk".into(), w.source.name()];
        if let Some(route) = &w.config.route {
            command.extend(["--route".into(), route.join(",")]);
        }
        walk_command(&mut command, &w);
        Stage {
            name,
            command,
            outputs: vec![w.out.join("walk.json")],
            requires: vec!["network"],
            run: Box::new(move || walk::run_stage(&w)),
        }
    };
    let [turns, straight] = walks;
    vec![
        Stage {
            name: "network",
            command: vec![
                "build".into(),
                "--scene".into(),
                args.scene.clone(),
                "--track".into(),
                "all".into(),
                "--face-size".into(),
                face.to_string(),
                "--out".into(),
                path_arg(&db),
                "--work".into(),
                path_arg(&work),
            ],
            outputs: vec![db.join("manifest.json"), work.join("build.json")],
            requires: vec![],
            run: Box::new(move || {
                stages::build::run(&build, &crate::progress::terminal())?;
                Ok(())
            }),
        },
        Stage {
            name: "network-cull",
            command: cull.command_line(),
            outputs: vec![cull.dir.join("cull.json")],
            requires: vec!["network"],
            run: Box::new(move || {
                stages::cull::run(&cull, &crate::progress::terminal())?;
                Ok(())
            }),
        },
        walk_stage("network-walk-turns", turns),
        walk_stage("network-walk-straight", straight),
    ]
}

/// The PSNR (worst 5 % of views) the demo's small sweep chooses the smallest database for.
const TUNE_TARGET_DB: f64 = 24.0;

/// The stages that use the database. The flythrough always runs (the report shows its
/// frames); with a display the viewer window comes after the report.
pub fn use_stages(args: &Args, layout: &Layout) -> Vec<Stage> {
    vec![
        walk_stage(args, layout),
        eval_stage(layout),
        tune_stage(args, layout),
        flythrough_stage(layout),
    ]
}

/// The options of a walk's command line after its source (and route): speed, bandwidths,
/// strategies, pause and the output directory.
fn walk_command(command: &mut Vec<String>, w: &WalkParams) {
    let list = |v: Vec<String>| v.join(",");
    command.extend([
        "--speed".into(),
        w.config.speed_mps.to_string(),
        "--bandwidth".into(),
        list(w.bandwidths.iter().map(|b| rate_arg(*b)).collect()),
        "--strategy".into(),
        list(w.strategies.iter().map(Strategy::name).collect()),
        "--pause".into(),
        w.config.pause_s.to_string(),
        "--out".into(),
        path_arg(&w.out),
    ]);
}

fn walk_stage(args: &Args, layout: &Layout) -> Stage {
    let prefetch = |mode| Strategy::Budget {
        mode,
        prefetch: true,
    };
    let base = WalkParams::new(
        WalkSource::Dir(layout.db()),
        layout.walk(),
        vec![
            Strategy::Naive,
            prefetch(PriorityMode::Ach),
            prefetch(PriorityMode::Visibility),
        ],
        vec![Some(2_000_000), None],
    );
    let w = WalkParams {
        config: WalkConfig {
            speed_mps: args.walk_speed,
            pause_s: 1.0,
            ..base.config
        },
        ..base
    };
    let mut command = vec!["walk".into(), w.source.name()];
    walk_command(&mut command, &w);
    Stage {
        name: "walk",
        command,
        outputs: vec![layout.walk().join("walk.json")],
        requires: vec!["build"],
        run: Box::new(move || walk::run_stage(&w)),
    }
}

fn eval_stage(layout: &Layout) -> Stage {
    let e = EvalParams {
        views: ViewSpec {
            per_segment: 1,
            directions: 2,
            ..ViewSpec::default()
        },
        timed_draws: 1,
        ..EvalParams::new(path_arg(&layout.db()), layout.eval())
    };
    Stage {
        name: "eval",
        command: vec![
            "eval".into(),
            e.db.clone(),
            "--out".into(),
            path_arg(&e.out),
            "--per-segment".into(),
            e.views.per_segment.to_string(),
            "--directions".into(),
            e.views.directions.to_string(),
            "--timed-draws".into(),
            e.timed_draws.to_string(),
        ],
        outputs: vec![layout.eval().join("eval.json")],
        requires: vec!["build"],
        run: Box::new(move || eval::run_stage(&e)),
    }
}

/// A small sweep over the build's knobs at faces of at most 64 px (the full-size one is
/// `railview tune`, as long as a build per configuration): error against cost, Pareto
/// fronts and the choice for a target.
fn tune_stage(args: &Args, layout: &Layout) -> Stage {
    let face = args.face_size.min(64);
    let base = Knobs {
        face_size: face,
        zstd_level: 9,
        ..Knobs::default()
    };
    let spec = SweepSpec {
        every: vec![2],
        face_size: vec![tune::knobs::three_quarters(face)],
        supersample: vec![2],
        cull: vec![(CullChoice::Off, 1.0)],
        drop_levels: vec![1],
        ..SweepSpec::base_only(base)
    };
    let params = SweepParams {
        scene: BuildScene::Tracer(args.scene.clone()),
        track: args.track.clone(),
        out: layout.tune(),
        spec,
        targets: vec![TUNE_TARGET_DB],
        cost: Cost::DbBytes,
        combine: false,
        views: ViewParams {
            per_segment: 1,
            directions: 2,
            truth_supersample: 2,
            ..ViewParams::default()
        },
        walk_speed: args.walk_speed,
        zstd_level: 9,
        ach: AchParams::default(),
        lowres_face_size: None,
    };
    let list = |v: Vec<String>| v.join(",");
    let s = &params.spec;
    let culls = s.cull.iter().map(|(c, a)| match c {
        CullChoice::Off => "none".to_string(),
        c => format!("{c}:{a}"),
    });
    let options = [
        ("--scene", args.scene.clone()),
        ("--track", params.track.clone()),
        ("--out", path_arg(&params.out)),
        ("--face-size", s.base.face_size.to_string()),
        (
            "--every",
            list(s.every.iter().map(u32::to_string).collect()),
        ),
        (
            "--supersamples",
            list(s.supersample.iter().map(u32::to_string).collect()),
        ),
        (
            "--slab-counts",
            list(s.slabs.iter().map(|x| x.to_string()).collect()),
        ),
        (
            "--tile-sizes",
            list(s.tile_size.iter().map(u32::to_string).collect()),
        ),
        (
            "--mesh-errors",
            list(s.mesh_error_px.iter().map(f64::to_string).collect()),
        ),
        ("--culls", list(culls.collect())),
        (
            "--drop-levels",
            list(s.drop_levels.iter().map(u32::to_string).collect()),
        ),
        ("--per-segment", params.views.per_segment.to_string()),
        ("--directions", params.views.directions.to_string()),
        (
            "--truth-supersample",
            params.views.truth_supersample.to_string(),
        ),
        ("--zstd-level", params.zstd_level.to_string()),
        ("--walk-speed", params.walk_speed.to_string()),
        (
            "--target-psnr",
            list(params.targets.iter().map(f64::to_string).collect()),
        ),
    ];
    Stage {
        name: "tune",
        command: std::iter::once("tune".to_string())
            .chain(options.into_iter().flat_map(|(k, v)| [k.to_string(), v]))
            .collect(),
        outputs: vec![layout.tune().join("sweep.json")],
        requires: vec![],
        run: Box::new(move || super::super::tune::sweep(params.clone())),
    }
}

fn flythrough_stage(layout: &Layout) -> Stage {
    let f = FlythroughParams {
        frames: 24,
        size: (320, 180),
        ..FlythroughParams::new(path_arg(&layout.db()), layout.frames())
    };
    Stage {
        name: "flythrough",
        command: vec![
            "flythrough".into(),
            f.db.clone(),
            "-o".into(),
            path_arg(&f.out),
            "--frames".into(),
            f.frames.to_string(),
            "--size".into(),
            format!("{}x{}", f.size.0, f.size.1),
        ],
        outputs: vec![layout.frames().join("flythrough.json")],
        requires: vec!["build"],
        run: Box::new(move || flythrough::run_stage(&f)),
    }
}

/// The viewer window on `source` (a URL or the database directory), playing the track.
pub fn view_stage(source: String) -> Stage {
    let v = view::Args {
        db: source,
        track: None,
        frames: None,
        screenshot: None,
        play: true,
        strategy: "both".into(),
        no_prefetch: false,
        memory_mib: 512.0,
        requests: 6,
        target_fps: 10.0,
    };
    Stage {
        name: "view",
        command: vec!["view".into(), v.db.clone(), "--play".into()],
        outputs: vec![],
        requires: vec!["build"],
        run: Box::new(move || view::run(v.clone())),
    }
}
