//! The README's Slurm commands, as written, on a real Slurm cluster: one node started here
//! (munged, slurmctld and slurmd with a generated configuration, `proctrack/linuxproc`,
//! `task/none`, private ports and state directory). The README's submit block runs
//! `deploy/slurm-prerender.sbatch` as a 4-task array and `deploy/slurm-merge.sbatch` after
//! it; one task is killed while it renders; the merge then fails naming the missing samples;
//! the README's rerun block renders that shard again and merges; the database must equal,
//! file for file and byte for byte, the one a single machine builds from the same inputs.
//! The daemons are stopped afterwards, also when the test fails.
//!
//! Needs root and Debian's `slurm-wlm` and `munge` (`scripts/test.sh` installs them). Without
//! them it fails, saying so; set `RAILVIEW_SKIP_SLURM_TESTS=1` to mark it ignored instead.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{assert_same_files, files_under, is_content, railview, scratch_dir, stderr};

/// Whole test, cluster start to comparison: a bound, not a measurement.
const TEST_LIMIT: Duration = Duration::from_secs(480);
const SHARDS: usize = 4;
const FACE: &str = "128";
const SLABS: &str = "0-12,12-inf";
/// 16 viewpoints: four per shard.
const TRACK: &str =
    "[[track]]\nname = \"gate\"\npoints = [[0, 1.7, 42], [0, 1.7, 30]]\ncount = 16\n";

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin".into(), "/sbin".into()])
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// The fenced `sh` block after `<!-- cli_slurm: NAME -->` in the README.
fn readme_block(name: &str) -> String {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let marker = format!("<!-- cli_slurm: {name} -->");
    let at = readme
        .find(&marker)
        .unwrap_or_else(|| panic!("README.md has no `{marker}`"));
    let rest = &readme[at + marker.len()..];
    let start = rest
        .find("```sh\n")
        .expect("a ```sh block after the marker")
        + 6;
    let end = rest[start..].find("```").expect("the block's end") + start;
    rest[start..end].to_string()
}

/// A single-node Slurm cluster in `dir`; dropping it cancels every job and stops the daemons.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    daemons: Vec<(&'static str, Child)>,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let root = Command::new("id")
            .arg("-u")
            .output()
            .is_ok_and(|o| o.stdout.trim_ascii() == b"0");
        assert!(
            root,
            "the Slurm test starts slurmctld, slurmd and munged and needs root (run \
             scripts/test.sh as root), or set RAILVIEW_SKIP_SLURM_TESTS=1 to mark it ignored"
        );
        let missing: Vec<&str> = [
            "munged",
            "slurmctld",
            "slurmd",
            "sbatch",
            "squeue",
            "scontrol",
            "scancel",
            "sinfo",
        ]
        .into_iter()
        .filter(|b| which(b).is_none())
        .collect();
        assert!(
            missing.is_empty(),
            "Slurm is not installed (missing {}): `apt-get install slurm-wlm munge` \
             (scripts/test.sh does it as root), or set RAILVIEW_SKIP_SLURM_TESTS=1 to mark \
             this test ignored",
            missing.join(", ")
        );
        let munge = dir.join("munge");
        std::fs::create_dir_all(&munge).unwrap();
        let mut key = [0u8; 1024];
        std::io::Read::read_exact(&mut std::fs::File::open("/dev/urandom").unwrap(), &mut key)
            .unwrap();
        std::fs::write(munge.join("key"), key).unwrap();
        let chmod = |p: &Path, mode: &str| {
            assert!(Command::new("chmod")
                .args([mode, p.to_str().unwrap()])
                .status()
                .unwrap()
                .success());
        };
        chmod(&munge, "700");
        chmod(&munge.join("key"), "600");
        let socket = munge.join("socket");
        // Two free ports, both held until both are known: a port released and asked for
        // again at once can come back the same, and slurmd would then take slurmctld's.
        let listeners: Vec<std::net::TcpListener> = (0..2)
            .map(|_| std::net::TcpListener::bind("127.0.0.1:0").unwrap())
            .collect();
        let ports: Vec<u16> = listeners
            .iter()
            .map(|l| l.local_addr().unwrap().port())
            .collect();
        drop(listeners);
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .unwrap()
            .trim()
            .split('.')
            .next()
            .unwrap()
            .to_string();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mem_mb = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|m| {
                m.lines()
                    .find(|l| l.starts_with("MemTotal:"))
                    .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
            })
            .map_or(2048, |kb| kb / 1024 / 2);
        let state = dir.join("state");
        let spool = dir.join("spool");
        std::fs::create_dir_all(&state).unwrap();
        std::fs::create_dir_all(&spool).unwrap();
        let d = |name: &str| dir.join(name).display().to_string();
        let conf = dir.join("slurm.conf");
        std::fs::write(
            &conf,
            format!(
                "ClusterName=railview\n\
                 SlurmctldHost={host}(127.0.0.1)\n\
                 SlurmUser=root\nSlurmdUser=root\n\
                 SlurmctldPort={}\nSlurmdPort={}\n\
                 AuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={}\n\
                 StateSaveLocation={}\nSlurmdSpoolDir={}\n\
                 SlurmctldPidFile={}\nSlurmdPidFile={}\n\
                 SlurmctldLogFile={}\nSlurmdLogFile={}\n\
                 ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n\
                 SwitchType=switch/none\nMpiDefault=none\n\
                 SchedulerType=sched/backfill\nSelectType=select/cons_tres\n\
                 SelectTypeParameters=CR_Core_Memory\nReturnToService=2\n\
                 JobAcctGatherType=jobacct_gather/none\n\
                 AccountingStorageType=accounting_storage/none\n\
                 MinJobAge=3600\nMailProg=/bin/true\n\
                 NodeName=railview-node NodeHostname={host} NodeAddr=127.0.0.1 CPUs={cpus} \
                 RealMemory={mem_mb} State=UNKNOWN\n\
                 PartitionName=railview Nodes=railview-node Default=YES MaxTime=INFINITE State=UP\n",
                ports[0],
                ports[1],
                socket.display(),
                state.display(),
                spool.display(),
                d("slurmctld.pid"),
                d("slurmd.pid"),
                d("slurmctld.log"),
                d("slurmd.log"),
            ),
        )
        .unwrap();
        let mut cluster = Cluster {
            dir: dir.to_path_buf(),
            conf: conf.clone(),
            daemons: Vec::new(),
        };
        let spawn = |name: &'static str, args: &[String]| -> (&'static str, Child) {
            let log = std::fs::File::create(dir.join(format!("{name}.out"))).unwrap();
            let child = Command::new(which(name).unwrap())
                .args(args)
                .stdout(log.try_clone().unwrap())
                .stderr(log)
                .stdin(Stdio::null())
                .spawn()
                .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
            (name, child)
        };
        let m = |p: &Path| p.display().to_string();
        cluster.daemons.push(spawn(
            "munged",
            &[
                "--foreground".into(),
                "--force".into(),
                format!("--key-file={}", m(&munge.join("key"))),
                format!("--socket={}", m(&socket)),
                format!("--log-file={}", m(&munge.join("log"))),
                format!("--pid-file={}", m(&munge.join("pid"))),
                format!("--seed-file={}", m(&munge.join("seed"))),
            ],
        ));
        wait_for(Duration::from_secs(20), "munged's socket", || {
            socket.exists()
        });
        cluster.daemons.push(spawn(
            "slurmctld",
            &["-D".into(), "-i".into(), "-f".into(), m(&conf)],
        ));
        cluster.daemons.push(spawn(
            "slurmd",
            &[
                "-D".into(),
                "-f".into(),
                m(&conf),
                "-N".into(),
                "railview-node".into(),
            ],
        ));
        let ready = wait_until(Duration::from_secs(60), || {
            let o = cluster.client("sinfo", &["-h", "-o", "%T"]);
            o.status.success() && String::from_utf8_lossy(&o.stdout).trim() == "idle"
        });
        if !ready {
            panic!("the Slurm node did not come up:\n{}", cluster.logs());
        }
        cluster
    }

    fn client(&self, bin: &str, args: &[&str]) -> Output {
        let mut c = Command::new(which(bin).unwrap());
        clean_env(&mut c);
        c.env("SLURM_CONF", &self.conf).args(args).output().unwrap()
    }

    /// `JobState=…` of a job or array task (`123`, `123_1`), from slurmctld.
    fn state(&self, job: &str) -> String {
        let o = self.client("scontrol", &["show", "job", "-o", job]);
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        text.split_whitespace()
            .find_map(|f| f.strip_prefix("JobState="))
            .unwrap_or("UNKNOWN")
            .to_string()
    }

    /// Wait until the job has ended; its final state.
    fn wait_end(&self, job: &str, limit: Duration) -> String {
        let mut last = String::new();
        let ended = wait_until(limit, || {
            last = self.state(job);
            !matches!(
                last.as_str(),
                "PENDING" | "RUNNING" | "CONFIGURING" | "COMPLETING" | "REQUEUED" | "SUSPENDED"
            )
        });
        if !ended {
            panic!("job {job} still {last} after {limit:?}:\n{}", self.logs());
        }
        last
    }

    /// Tails of the daemons' logs and the jobs' output, for failure messages.
    fn logs(&self) -> String {
        let mut s = String::new();
        let q = self.client("squeue", &["-a", "-o", "%i %T %R"]);
        s += &format!("squeue:\n{}\n", String::from_utf8_lossy(&q.stdout));
        let mut files: Vec<PathBuf> = std::fs::read_dir(&self.dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "log" || x == "out"))
            .collect();
        files.sort();
        for f in files {
            let text = std::fs::read_to_string(&f).unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            let tail = lines[lines.len().saturating_sub(15)..].join("\n");
            s += &format!("== {}\n{tail}\n", f.display());
        }
        s
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // Jobs first (their steps run under slurmstepd, not under our daemons), then the
        // daemons, newest first.
        self.client("scancel", &["--partition=railview"]);
        wait_until(Duration::from_secs(30), || {
            let o = self.client("squeue", &["-h", "-p", "railview"]);
            o.status.success() && o.stdout.trim_ascii().is_empty()
        });
        for (name, mut child) in self.daemons.drain(..).rev() {
            // SIGTERM by the child's own pid: slurmctld and slurmd save their state and exit.
            Command::new("kill")
                .arg(child.id().to_string())
                .status()
                .ok();
            let stopped = wait_until(Duration::from_secs(15), || {
                child.try_wait().ok().flatten().is_some()
            });
            if !stopped {
                eprintln!("{name} did not stop on SIGTERM; killing it");
                child.kill().ok();
                child.wait().ok();
            }
        }
    }
}

/// Leave out the Slurm variables of any job the test itself runs in, so commands talk to the
/// cluster started here.
fn clean_env(c: &mut Command) {
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("SLURM") {
            c.env_remove(k);
        }
    }
}

fn wait_until(limit: Duration, mut done: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + limit;
    loop {
        if done() {
            return true;
        }
        if Instant::now() > deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn wait_for(limit: Duration, what: &str, done: impl FnMut() -> bool) {
    assert!(wait_until(limit, done), "timed out waiting for {what}");
}

/// Run the README block `name` in bash, from `cwd`, after `settings`, and return the values of
/// `vars` it set.
fn run_block(
    cluster: &Cluster,
    cwd: &Path,
    settings: &str,
    name: &str,
    vars: &[&str],
) -> Vec<String> {
    let echo: String = vars
        .iter()
        .map(|v| format!("echo \"{v}=${v}\"\n"))
        .collect();
    let script = format!(
        "set -euo pipefail\n{settings}\n# README: {name}\n{}\n{echo}",
        readme_block(name)
    );
    let mut c = Command::new("bash");
    clean_env(&mut c);
    let o = c
        .arg("-c")
        .arg(&script)
        .current_dir(cwd)
        .env("SLURM_CONF", &cluster.conf)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "README block `{name}` failed:\n{script}\nstdout:\n{out}\nstderr:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    vars.iter()
        .map(|v| {
            out.lines()
                .find_map(|l| l.strip_prefix(&format!("{v}=")))
                .filter(|x| !x.is_empty())
                .unwrap_or_else(|| panic!("block `{name}` set no `{v}`:\n{out}"))
                .to_string()
        })
        .collect()
}

#[test]
#[cfg_attr(
    railview_skip_slurm,
    ignore = "RAILVIEW_SKIP_SLURM_TESTS=1: the Slurm cluster test is switched off"
)]
fn readme_slurm_jobs_survive_a_killed_shard_and_match_one_machine() {
    let started = Instant::now();
    let dir = scratch_dir("cli-slurm", "cluster");
    let cluster = Cluster::start(&dir);
    // Submit from a directory of our own, like a user's project directory: job logs land
    // there, and `deploy/` is the project's.
    let submit = dir.join("submit");
    std::fs::create_dir_all(&submit).unwrap();
    std::os::unix::fs::symlink(repo().join("deploy"), submit.join("deploy")).unwrap();
    let track = dir.join("gate.toml");
    std::fs::write(&track, TRACK).unwrap();
    let work = dir.join("cluster.work");
    let db = dir.join("cluster-db");
    // The README's settings block, with small values for this machine.
    let settings = format!(
        "export RAILVIEW={} SCENE=castle TRACK={} FACE_SIZE={FACE} SLABS={SLABS}\n\
         export WORK={} DB={} BUILD_ARGS='--zstd-level 3'\n\
         SHARDS={SHARDS} CPUS=1 MEM=500M\n",
        env!("CARGO_BIN_EXE_railview"),
        track.display(),
        work.display(),
        db.display(),
    );
    let ids = run_block(&cluster, &submit, &settings, "submit", &["jid", "mid"]);
    let (jid, mid) = (&ids[0], &ids[1]);

    // Kill shard 1 once it has finished its first sample (1; it renders 1, 5, 9, 13 and their
    // slab layers after them), while it works on the rest.
    let victim = format!("{jid}_1");
    let first = work.join("prerender/samples/0001/sample.json");
    if !wait_until(Duration::from_secs(120), || first.exists()) {
        panic!("shard 1 rendered nothing:\n{}", cluster.logs());
    }
    let o = cluster.client("scancel", &[&victim]);
    assert!(o.status.success(), "scancel: {}", stderr(&o));
    let state = cluster.wait_end(&victim, Duration::from_secs(60));
    assert_eq!(
        state, "CANCELLED",
        "shard 1 was to be killed while rendering; it ended {state}"
    );

    // The merge runs after the other tasks although one failed, and names what is missing.
    let state = cluster.wait_end(mid, Duration::from_secs(180));
    let merge_log = std::fs::read_to_string(submit.join(format!("railview-merge-{mid}.log")))
        .unwrap_or_default();
    assert_eq!(state, "FAILED", "merge with a shard missing:\n{merge_log}");
    assert!(
        merge_log.contains("shard 1/4") && merge_log.contains("--array=1"),
        "the merge must name the shard to run again:\n{merge_log}"
    );
    assert!(!db.join("manifest.json").exists());
    for k in [0, 2, 3] {
        assert_eq!(cluster.state(&format!("{jid}_{k}")), "COMPLETED");
    }

    // The README's rerun block, for the shard the merge named; then the merge succeeds.
    let ids = run_block(
        &cluster,
        &submit,
        &format!("{settings}K=1\n"),
        "rerun",
        &["rid", "mid"],
    );
    let (rid, mid2) = (&ids[0], &ids[1]);
    let state = cluster.wait_end(mid2, Duration::from_secs(300));
    let merge_log = std::fs::read_to_string(submit.join(format!("railview-merge-{mid2}.log")))
        .unwrap_or_default();
    assert_eq!(
        state,
        "COMPLETED",
        "merge after the rerun:\n{merge_log}\n{}",
        cluster.logs()
    );
    let rerun_log =
        std::fs::read_to_string(submit.join(format!("railview-prerender-{rid}_1.log"))).unwrap();
    assert!(rerun_log.contains("shard 1/4"), "{rerun_log}");
    assert!(db.join("manifest.json").is_file());

    // One machine, the same inputs: the same panoramas, layers, tiles, decisions and database.
    let one = dir.join("one.work");
    let one_db = dir.join("one-db");
    let t = track.to_str().unwrap();
    let o = railview(&[
        "prerender",
        "--scene",
        "castle",
        "--track",
        t,
        "--face-size",
        FACE,
        "--slabs",
        SLABS,
        "--out",
        one.join("prerender").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = railview(&[
        "build",
        "--scene",
        "castle",
        "--track",
        t,
        "--face-size",
        FACE,
        "--work",
        one.to_str().unwrap(),
        "--out",
        one_db.to_str().unwrap(),
        "--zstd-level",
        "3",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_same_files(
        "database: cluster against one machine",
        &files_under(&db, &|_| true),
        &files_under(&one_db, &|_| true),
    );
    assert_same_files(
        "work directory: cluster against one machine",
        &files_under(&work, &|rel| is_content(rel)),
        &files_under(&one, &|rel| is_content(rel)),
    );
    // The merged report knows the shards: every sample once, the rerun's included.
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(work.join("prerender/prerender.json")).unwrap())
            .unwrap();
    let shards = report["shards"].as_array().unwrap();
    assert_eq!(shards.len(), SHARDS, "{report}");
    let mut samples: Vec<u64> = shards
        .iter()
        .flat_map(|s| s["samples"].as_array().unwrap().iter())
        .map(|v| v.as_u64().unwrap())
        .collect();
    samples.sort_unstable();
    assert_eq!(samples, (0..16).collect::<Vec<u64>>());
    for s in shards {
        let (k, n) = (
            s["shard"][0].as_u64().unwrap(),
            s["shard"][1].as_u64().unwrap(),
        );
        assert_eq!(n, SHARDS as u64);
        assert!(s["samples"]
            .as_array()
            .unwrap()
            .iter()
            .all(|i| i.as_u64().unwrap() % n == k));
    }
    let summed: f64 = shards
        .iter()
        .map(|s| s["render_seconds"].as_f64().unwrap())
        .sum();
    assert!(summed > 0.0 && report["seconds"].as_f64().unwrap() >= summed - 1e-9);
    drop(cluster);
    assert!(
        started.elapsed() < TEST_LIMIT,
        "the Slurm test took {:?}, more than its bound {TEST_LIMIT:?}",
        started.elapsed()
    );
    std::fs::remove_dir_all(&dir).ok();
}
