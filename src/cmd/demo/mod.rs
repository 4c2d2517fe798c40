//! `railview demo [--out railview-demo] [--face-size N]`: the whole system on the built-in
//! `castle` scene in one command, then a report.
//!
//! Each stage is the function the ordinary `railview` subcommand calls, run in this process
//! with the same parameters, so the demo shows exactly what a person typing the commands
//! would get; the log records for each the command line that reproduces it. A stage is
//! skipped when `OUT/demo.json` says the same command completed and its outputs are still
//! there; a stage that was killed midway simply runs again and resumes from what it wrote. A
//! stage whose prerequisite did not complete makes its section of the report say "not
//! available".

mod stages;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;

use self::stages::{build_stages, network_stages, use_stages, view_stage, Stage};
use report::{self, Layout, RunLog, StageRecord, StageStatus};

#[derive(clap::Args)]
pub struct Args {
    /// Output directory: the prerender work dir, the database, walks, evaluation, frames and the report.
    #[arg(long, default_value = "railview-demo")]
    pub out: PathBuf,
    /// Cube-map face size of the reference panoramas, pixels (192: castle gets its three
    /// slabs and the whole demo takes a few minutes on two cores).
    #[arg(long, default_value_t = 192)]
    pub face_size: u32,
    /// Built-in scene.
    #[arg(long, default_value = "castle")]
    pub scene: String,
    /// Track of the scene.
    #[arg(long, default_value = "main")]
    pub track: String,
    /// Walking speed of the streaming simulation, m/s (the walk is simulated in virtual
    /// time, but each frame costs a visibility pass, so faster walks finish sooner).
    #[arg(long, default_value_t = 4.0)]
    pub walk_speed: f64,
    /// Never open the viewer window (the headless flythrough is rendered either way).
    #[arg(long)]
    pub no_window: bool,
    /// Only rebuild the report from what is already in OUT.
    #[arg(long)]
    pub report_only: bool,
}

/// `railview a b` with shell quoting where needed, for people to copy.
fn command_line(words: &[String]) -> String {
    let mut s = String::from("railview");
    for a in words {
        s.push(' ');
        let plain = !a.is_empty()
            && a.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_./,:=+@%".contains(c));
        if plain {
            s += a;
        } else {
            s += &format!("'{}'", a.replace('\'', "'\\''"));
        }
    }
    s
}

fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|x| !x.is_empty()))
}

/// Run one stage (or reuse it), record the outcome in the log, and save the log.
fn run_stage(
    layout: &Layout,
    log: &mut RunLog,
    stage: &Stage,
    step: usize,
    steps: usize,
) -> StageStatus {
    let command = command_line(&stage.command);
    if let Some(prev) = log.stage(stage.name) {
        let inputs_unchanged = !stage
            .requires
            .iter()
            .any(|r| log.ran_now.iter().any(|n| n == r));
        // A stage without outputs (the viewer window) is never "reused".
        if prev.status == StageStatus::Done
            && prev.command == command
            && inputs_unchanged
            && !stage.outputs.is_empty()
            && stage.outputs.iter().all(|p| p.exists())
        {
            eprintln!("[{step}/{steps}] {}: reused ({command})", stage.name);
            return StageStatus::Done;
        }
    }
    let mut record = StageRecord {
        name: stage.name.to_string(),
        command: command.clone(),
        status: StageStatus::Unavailable,
        seconds: 0.0,
        cpu_seconds: None,
        message: None,
    };
    let missing: Vec<&str> = stage
        .requires
        .iter()
        .copied()
        .filter(|r| log.stage(r).is_none_or(|s| s.status != StageStatus::Done))
        .collect();
    if !missing.is_empty() {
        record.message = Some(format!("needs `{}` first", missing.join("`, `")));
        eprintln!(
            "[{step}/{steps}] {}: skipped, {}",
            stage.name,
            record.message.as_deref().unwrap_or("")
        );
        return finish(layout, log, record);
    }
    eprintln!("[{step}/{steps}] {}: {command}", stage.name);
    let meter = ::stages::cost::Meter::start();
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (stage.run)()));
    let (cpu, wall) = meter.stop();
    record.seconds = wall;
    record.cpu_seconds = cpu.is_finite().then_some(cpu);
    match outcome {
        Ok(Ok(())) => {
            record.status = StageStatus::Done;
            log.ran_now.push(stage.name.to_string());
            eprintln!(
                "[{step}/{steps}] {}: done in {:.1} s",
                stage.name, record.seconds
            );
        }
        Ok(Err(e)) => {
            record.status = StageStatus::Failed;
            record.message = Some(format!("{e:#}"));
            eprintln!("[{step}/{steps}] {}: failed: {e:#}", stage.name);
        }
        Err(payload) => {
            // A bug, not an error the command reports: keep its message with the stage.
            let what = panic_text(payload.as_ref());
            record.status = StageStatus::Failed;
            record.message = Some(format!("the command panicked: {what}"));
            eprintln!(
                "[{step}/{steps}] {}: failed, it panicked: {what}",
                stage.name
            );
        }
    }
    finish(layout, log, record)
}

/// The message of a panic's payload (`panic!` with a literal or a formatted message).
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".into())
}

fn finish(layout: &Layout, log: &mut RunLog, record: StageRecord) -> StageStatus {
    let status = record.status;
    log.record(record);
    if let Err(e) = log.save(layout) {
        eprintln!("warning: {e:#}");
    }
    status
}

/// Mesa prints "XDG_RUNTIME_DIR is invalid or not set" for every GPU stage when the variable
/// is missing (containers, CI); point it at a private directory before any thread starts.
#[cfg(unix)]
fn set_runtime_dir() {
    use std::os::unix::fs::PermissionsExt;
    if std::env::var_os("XDG_RUNTIME_DIR").is_some() {
        return;
    }
    let dir = std::env::temp_dir().join("railview-xdg");
    let made = std::fs::create_dir_all(&dir)
        .and_then(|()| std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)));
    match made {
        Ok(()) => std::env::set_var("XDG_RUNTIME_DIR", &dir),
        Err(e) => tracing::debug!("{}: {e}", dir.display()),
    }
}

#[cfg(not(unix))]
fn set_runtime_dir() {}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The limits every stage checks (tracks::limits), not a copy of them.
    let max = tracks::limits::MAX_FACE_SIZE;
    anyhow::ensure!(
        (8..=max).contains(&args.face_size),
        "--face-size {} is out of range (8..={max})",
        args.face_size
    );
    let layout = Layout::new(&args.out);
    let mut log = RunLog::load_or_default(&layout, &args.scene, &args.track, args.face_size);
    anyhow::ensure!(
        log.scene == args.scene && log.track == args.track && log.face_size == args.face_size,
        "{} holds a demo of {} / {} at face size {}; use another --out or delete it",
        layout.root().display(),
        log.scene,
        log.track,
        log.face_size
    );
    if args.report_only {
        let written = report::write_report(&layout, &log)?;
        println!(
            "report: {} ({} tables, {} images; not available: {})",
            written.html.display(),
            written.tables.len(),
            written.images.len(),
            if written.unavailable.is_empty() {
                "none".to_string()
            } else {
                written.unavailable.join(", ")
            }
        );
        return Ok(());
    }
    std::fs::create_dir_all(layout.root())
        .with_context(|| format!("creating {}", layout.root().display()))?;
    set_runtime_dir();
    let window = !args.no_window && display_available();
    let start = Instant::now();
    let all: Vec<Stage> = build_stages(&args, &layout)
        .into_iter()
        .chain(use_stages(&args, &layout))
        .chain(network_stages(&args, &layout))
        .collect();
    let steps = all.len();
    for (i, stage) in all.iter().enumerate() {
        run_stage(&layout, &mut log, stage, i + 1, steps);
    }
    let written = report::write_report(&layout, &log).context("writing the report")?;

    println!();
    println!(
        "railview demo: {} / {} (face size {}), {:.1} s",
        args.scene,
        args.track,
        args.face_size,
        start.elapsed().as_secs_f64()
    );
    println!("  prerendered panoramas: {}", layout.prerender().display());
    println!("  database:              {}", layout.db().display());
    println!("  flythrough frames:     {}", layout.frames().display());
    if !window {
        let why = if args.no_window {
            "--no-window"
        } else {
            "no display (DISPLAY/WAYLAND_DISPLAY unset)"
        };
        println!("  no viewer window ({why}): the flythrough frames above were rendered headless");
    }
    println!("  report:                {}", written.html.display());
    println!("                         {}", written.markdown.display());
    if !written.unavailable.is_empty() {
        println!(
            "  not available yet:     {}",
            written.unavailable.join(", ")
        );
    }
    println!("Open the viewer later:");
    println!("  railview view {}", layout.db().display());
    println!(
        "  railview serve {} --addr 127.0.0.1:8080   # then: railview view http://127.0.0.1:8080 (or walk … --out walk)",
        layout.db().display()
    );

    if window
        && log
            .stage("build")
            .is_some_and(|s| s.status == StageStatus::Done)
    {
        view_window(&layout, &mut log)?;
    }
    let failed: Vec<&str> = log
        .stages
        .iter()
        .filter(|s| s.status == StageStatus::Failed)
        .map(|s| s.name.as_str())
        .collect();
    // Which stages could not run and why, each reason once (the GPU stages usually share
    // theirs); everything else was written.
    let mut reasons: Vec<(Vec<&str>, &str)> = Vec::new();
    for s in log
        .stages
        .iter()
        .filter(|s| s.status == StageStatus::Failed)
    {
        let why = s.message.as_deref().unwrap_or("no message");
        match reasons.iter_mut().find(|(_, w)| *w == why) {
            Some((names, _)) => names.push(&s.name),
            None => reasons.push((vec![&s.name], why)),
        }
    }
    for (names, why) in &reasons {
        eprintln!(
            "{} `{}` could not run: {why}",
            if names.len() == 1 { "stage" } else { "stages" },
            names.join("`, `")
        );
    }
    anyhow::ensure!(
        failed.is_empty(),
        "stages failed: {} (details in {} and the report)",
        failed.join(", "),
        layout.log().display()
    );
    Ok(())
}

/// Serve the database on loopback and open the viewer window on it until it is closed.
fn view_window(layout: &Layout, log: &mut RunLog) -> anyhow::Result<()> {
    use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
    let db = ServedDb::open(&layout.db())?;
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .context("binding 127.0.0.1")?;
    let url = format!("http://{}", listener.local_addr()?);
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let task = rt.spawn(server::run(
        listener,
        db,
        ServerConfig::default(),
        std::sync::Arc::new(ServerStats::default()),
        async {
            // A dropped sender also stops the server.
            let _ = stop_rx.await;
        },
    ));
    println!(
        "serving {} on {url}; opening the viewer (close the window to finish)",
        layout.db().display()
    );
    // The window streams from the server just started, as a remote viewer would.
    if run_stage(layout, log, &view_stage(url), 1, 2) != StageStatus::Done {
        // Streaming failed (see the log): the database directory still opens directly.
        println!("opening the viewer on the database directory instead");
        let dir = layout.db().display().to_string();
        run_stage(layout, log, &view_stage(dir), 2, 2);
    }
    drop(stop_tx);
    rt.block_on(task).context("server task")??;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_lines_quote_what_a_shell_would_split() {
        let argv = vec![
            "walk".to_string(),
            "my db".to_string(),
            "--x".into(),
            "it's".into(),
        ];
        assert_eq!(command_line(&argv), "railview walk 'my db' --x 'it'\\''s'");
        assert_eq!(
            command_line(&["cull".into(), "a/b".into(), "1.0,0.9".into()]),
            "railview cull a/b 1.0,0.9"
        );
    }

    #[test]
    fn a_panic_is_recorded_with_its_message() {
        let caught = std::panic::catch_unwind(|| panic!("out of {} apples", 3)).unwrap_err();
        assert_eq!(panic_text(caught.as_ref()), "out of 3 apples");
        let caught = std::panic::catch_unwind(|| std::panic::panic_any(7u8)).unwrap_err();
        assert_eq!(panic_text(caught.as_ref()), "no message");
    }

    /// A stage running `f`, with these outputs and prerequisites.
    fn stage(
        name: &'static str,
        outputs: Vec<PathBuf>,
        requires: Vec<&'static str>,
        f: impl Fn() -> anyhow::Result<()> + 'static,
    ) -> Stage {
        Stage {
            name,
            command: vec![name.to_string()],
            run: Box::new(f),
            outputs,
            requires,
        }
    }

    #[test]
    fn a_stage_whose_prerequisite_is_not_done_is_unavailable_not_failed() {
        let dir = std::env::temp_dir().join(format!("railview-demo-stage-{}", std::process::id()));
        let layout = Layout::new(&dir);
        let mut log = RunLog::load_or_default(&layout, "castle", "main", 16);
        // A stage that fails: recorded as failed, with its message.
        let failing = stage("nothing", vec![], vec![], || anyhow::bail!("no such thing"));
        assert_eq!(
            run_stage(&layout, &mut log, &failing, 1, 1),
            StageStatus::Failed
        );
        let rec = log.stage("nothing").unwrap();
        assert!(rec.message.as_deref().unwrap().contains("no such thing"));
        // A stage whose prerequisite is not done does not run.
        let dependent = stage("after", vec![], vec!["nothing"], || {
            panic!("a stage whose prerequisite failed ran")
        });
        assert_eq!(
            run_stage(&layout, &mut log, &dependent, 1, 1),
            StageStatus::Unavailable
        );
        assert!(log
            .stage("after")
            .unwrap()
            .message
            .as_deref()
            .unwrap()
            .contains("needs `nothing`"));
        // A stage that panics is recorded as failed with the panic's message.
        let panics = stage("bug", vec![], vec![], || panic!("out of {} apples", 3));
        assert_eq!(
            run_stage(&layout, &mut log, &panics, 1, 1),
            StageStatus::Failed
        );
        assert!(log
            .stage("bug")
            .unwrap()
            .message
            .as_deref()
            .unwrap()
            .contains("panicked: out of 3 apples"));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn completed_stages_are_reused_until_a_stage_they_need_runs_again() {
        let dir = std::env::temp_dir().join(format!("railview-demo-reuse-{}", std::process::id()));
        let layout = Layout::new(dir.join("demo"));
        let inner = dir.join("inner");
        // A cheap stage: one output file.
        let cheap = |name: &'static str, requires: Vec<&'static str>| {
            let out = inner.join(name).join("out.txt");
            let made = out.clone();
            stage(name, vec![out], requires, move || {
                std::fs::create_dir_all(made.parent().unwrap())?;
                std::fs::write(&made, b"done")?;
                Ok(())
            })
        };
        let (a, b) = (cheap("a", vec![]), cheap("b", vec!["a"]));
        let mut log = RunLog::load_or_default(&layout, "castle", "main", 16);
        assert_eq!(run_stage(&layout, &mut log, &a, 1, 2), StageStatus::Done);
        assert_eq!(run_stage(&layout, &mut log, &b, 2, 2), StageStatus::Done);
        assert_eq!(log.ran_now, ["a", "b"]);
        // A second run reuses both.
        let mut log = RunLog::load_or_default(&layout, "castle", "main", 16);
        assert_eq!(log.stages.len(), 2);
        run_stage(&layout, &mut log, &a, 1, 2);
        run_stage(&layout, &mut log, &b, 2, 2);
        assert!(log.ran_now.is_empty());
        // Outputs of `a` gone: `a` runs again, and so does `b`, which reads them.
        std::fs::remove_dir_all(inner.join("a")).unwrap();
        let mut log = RunLog::load_or_default(&layout, "castle", "main", 16);
        run_stage(&layout, &mut log, &a, 1, 2);
        run_stage(&layout, &mut log, &b, 2, 2);
        assert_eq!(log.ran_now, ["a", "b"]);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn the_recorded_commands_are_those_a_person_would_type() {
        let args = Args {
            out: PathBuf::from("demo"),
            face_size: 192,
            scene: "castle".into(),
            track: "main".into(),
            walk_speed: 4.0,
            no_window: true,
            report_only: false,
        };
        let layout = Layout::new(&args.out);
        let all: Vec<String> = build_stages(&args, &layout)
            .iter()
            .chain(&use_stages(&args, &layout))
            .map(|s| command_line(&s.command))
            .collect();
        let p = |x: PathBuf| x.display().to_string();
        assert_eq!(
            all[0],
            format!(
                "railview build --scene castle --track main --face-size 192 --out {} --work {}",
                p(layout.db()),
                p(layout.work())
            )
        );
        assert_eq!(
            all[1],
            format!(
                "railview cull {} --alpha 1.0,0.9,0.8 --oracle --oracle-per-segment 8",
                p(layout.prerender())
            )
        );
        assert_eq!(
            all[2],
            format!(
                "railview walk {} --speed 4 --bandwidth 2mbit,unlimited --strategy naive,ach+prefetch,visibility+prefetch --pause 1 --out {}",
                p(layout.db()),
                p(layout.walk())
            )
        );
        assert_eq!(
            all[3],
            format!(
                "railview eval {} --out {} --per-segment 1 --directions 2 --timed-draws 1",
                p(layout.db()),
                p(layout.eval())
            )
        );
        assert_eq!(
            all[4],
            format!(
                "railview tune --scene castle --track main --out {} --face-size 64 --every 2 \
                 --supersamples 2 --slab-counts '' --tile-sizes '' --mesh-errors '' --culls none \
                 --drop-levels 1 --per-segment 1 --directions 2 --truth-supersample 2 \
                 --zstd-level 9 --walk-speed 4 --target-psnr 24",
                p(layout.tune())
            )
        );
        assert_eq!(
            all[5],
            format!(
                "railview flythrough {} -o {} --frames 24 --size 320x180",
                p(layout.db()),
                p(layout.frames())
            )
        );
    }
}
