//! Walks over a server that freezes, that serves damaged objects, or that goes away: the
//! outage shows in the report on both clocks, a damaged object is a counted per-tile
//! failure, and a walk that cannot go on keeps what it measured.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use streamer::client::RetryPolicy;
use streamer::client::ServerUrl;
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::{self, synth, Strategy, WalkConfig, WalkEvent};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tracks::manifest::Manifest;

fn temp_db(name: &str) -> (PathBuf, Manifest) {
    let dir = std::env::temp_dir().join(format!("railview-walkfail-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let m = synth::write_synthetic(&dir, &synth::SynthParams::default()).unwrap();
    (dir, m)
}

async fn start(
    dir: &Path,
) -> (
    SocketAddr,
    oneshot::Sender<()>,
    tokio::task::JoinHandle<Result<(), server::ServerError>>,
) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let db = ServedDb::open(dir).unwrap();
    let config = ServerConfig {
        drain_timeout: Duration::from_millis(200),
        ..ServerConfig::default()
    };
    let task = tokio::spawn(server::run(
        listener,
        db,
        config,
        Arc::new(ServerStats::default()),
        async {
            let _ = rx.await;
        },
    ));
    (addr, tx, task)
}

fn url(addr: SocketAddr) -> ServerUrl {
    ServerUrl::parse(&format!("http://{addr}")).unwrap()
}

fn small_walk() -> WalkConfig {
    WalkConfig {
        pause_s: 1.0,
        frame_dt_s: 0.1,
        samples_x: 32,
        samples_y: 18,
        retry: RetryPolicy {
            response_timeout: Duration::from_millis(300),
            stall_timeout: Duration::from_millis(300),
            give_up_after: Duration::from_secs(10),
            ..RetryPolicy::default()
        },
        ..WalkConfig::default()
    }
}

/// A TCP proxy that stops forwarding for `freeze` once `after` bytes have come back from
/// the server (a server frozen with SIGSTOP: connections are accepted, nothing moves).
async fn freezing_proxy(upstream: SocketAddr, after: u64, freeze: Duration) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let down = Arc::new(AtomicU64::new(0));
    let frozen_until: Arc<Mutex<Option<Instant>>> = Arc::new(Mutex::new(None));
    tokio::spawn(async move {
        while let Ok((client, _)) = listener.accept().await {
            let Ok(server) = TcpStream::connect(upstream).await else {
                continue;
            };
            let (cr, cw) = client.into_split();
            let (sr, sw) = server.into_split();
            let (d1, f1) = (down.clone(), frozen_until.clone());
            let (d2, f2) = (down.clone(), frozen_until.clone());
            tokio::spawn(pump(cr, sw, d1, f1, None));
            tokio::spawn(pump(sr, cw, d2, f2, Some((after, freeze))));
        }
    });
    addr
}

async fn pump(
    mut from: impl AsyncReadExt + Unpin,
    mut to: impl AsyncWriteExt + Unpin,
    down: Arc<AtomicU64>,
    frozen_until: Arc<Mutex<Option<Instant>>>,
    freeze: Option<(u64, Duration)>,
) {
    let mut buf = vec![0u8; 16 << 10];
    loop {
        let wait = frozen_until
            .lock()
            .unwrap()
            .map(|u| u.saturating_duration_since(Instant::now()));
        if let Some(w) = wait {
            tokio::time::sleep(w).await;
        }
        let n = match from.read(&mut buf).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        if let Some((after, freeze)) = freeze {
            let total = down.fetch_add(n as u64, Ordering::Relaxed) + n as u64;
            let mut f = frozen_until.lock().unwrap();
            if total >= after && f.is_none() {
                *f = Some(Instant::now() + freeze);
            }
        }
        let wait = frozen_until
            .lock()
            .unwrap()
            .map(|u| u.saturating_duration_since(Instant::now()));
        if let Some(w) = wait {
            tokio::time::sleep(w).await;
        }
        if to.write_all(&buf[..n]).await.is_err() {
            return;
        }
    }
}

/// Regression: a walk over a server frozen for a while used to give the same walk.json as
/// an undisturbed one. The freeze now shows: retries and timeouts, the wall-clock outage,
/// and on the virtual clock a longer wait with nothing arriving.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_outage_shows_in_the_report_on_the_wall_and_virtual_clocks() {
    let (dir, _) = temp_db("freeze");
    let (addr, stop, task) = start(&dir).await;
    let strategies = [Strategy::parse("ach+prefetch").unwrap()];
    let cfg = small_walk();
    let clean = walk::run_walk(&url(addr), &cfg, &strategies, &[None], |_| {})
        .await
        .unwrap();
    let proxy = freezing_proxy(addr, 60_000, Duration::from_millis(1500)).await;
    let frozen = walk::run_walk(&url(proxy), &cfg, &strategies, &[None], |_| {})
        .await
        .unwrap();
    let (a, b) = (&clean.runs[0], &frozen.runs[0]);
    eprintln!("{}", walk::summary_markdown(&frozen));
    assert!(a.completed && b.completed);
    assert_eq!((a.retries, a.outage_s), (0, 0.0));
    assert!(b.retries >= 1 && b.timeouts >= 1, "{b:?}");
    assert!(b.outage_s >= 1.0 && b.longest_outage_s >= 1.0, "{b:?}");
    assert!(
        b.longest_wait_s >= a.longest_wait_s + 1.0,
        "virtual wait {} (undisturbed {})",
        b.longest_wait_s,
        a.longest_wait_s
    );
    assert!(b.wall_s >= 1.5, "{}", b.wall_s);
    let _ = stop.send(());
    task.await.unwrap().unwrap();
    let _ = std::fs::remove_dir_all(dir);
}

/// The viewpoints' packs (objects that tiles are ranges of), largest first.
fn packs(dir: &Path, m: &Manifest) -> Vec<PathBuf> {
    let mut out: Vec<(u64, PathBuf)> = Vec::new();
    for v in &m.tracks[0].viewpoints {
        if let Some(p) = v.tiles.iter().find_map(|t| t.ptm.as_ref()) {
            let path = dir.join(p.object.rel_path().unwrap());
            if !out.iter().any(|(_, q)| *q == path) {
                out.push((p.object.size, path));
            }
        }
    }
    out.sort_by_key(|b| std::cmp::Reverse(b.0));
    out.into_iter().map(|x| x.1).collect()
}

/// Regression: one damaged object ended the whole walk with no walk.json. A flipped byte in
/// one pack, a truncated other pack and a damaged table are now per-tile (per-viewpoint)
/// failures: counted, retried, given up; every run finishes and the report says what
/// failed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn damaged_and_truncated_packs_are_counted_per_tile_and_never_end_the_walk() {
    let (dir, m) = temp_db("damaged");
    let packs = packs(&dir, &m);
    assert!(packs.len() >= 2);
    let mut bytes = std::fs::read(&packs[0]).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&packs[0], &bytes).unwrap();
    let len = std::fs::metadata(&packs[1]).unwrap().len();
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&packs[1])
        .unwrap();
    f.set_len(len / 2).unwrap();
    drop(f);
    let (addr, stop, task) = start(&dir).await;
    // A table damaged after the server opened the database (the server checked it then).
    let top = db::read_top(&dir).unwrap();
    let table = dir.join(top.viewpoints[2].table.rel_path().unwrap());
    let mut bytes = std::fs::read(&table).unwrap();
    bytes[7] ^= 0x01;
    std::fs::write(&table, &bytes).unwrap();
    let strategies: Vec<Strategy> = ["naive", "ach+prefetch"]
        .iter()
        .map(|s| Strategy::parse(s).unwrap())
        .collect();
    let report = walk::run_walk(&url(addr), &small_walk(), &strategies, &[None], |_| {})
        .await
        .expect("damaged objects never end a walk");
    eprintln!("{}", walk::summary_markdown(&report));
    for r in &report.runs {
        assert!(
            r.completed && r.error.is_none(),
            "{}: {:?}",
            r.strategy,
            r.error
        );
        assert!(
            r.part_faults + r.table_faults > 0,
            "{}: no fault counted",
            r.strategy
        );
        assert!(
            r.parts_given_up + r.tables_given_up > 0,
            "{}: nothing given up",
            r.strategy
        );
        assert!(r.mean_needed_fraction > 0.0, "{}", r.strategy);
    }
    assert!(report.runs.iter().any(|r| r.checksum_failures > 0));
    assert!(report.runs.iter().any(|r| r.tables_given_up > 0));
    let out = dir.join("out");
    walk::write_outputs(&report, &out).unwrap();
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
    assert!(json["runs"][0]["parts_given_up"].as_u64().is_some());
    assert!(json["runs"][0]["tables_given_up"].as_u64().is_some());
    let _ = stop.send(());
    task.await.unwrap().unwrap();
    let _ = std::fs::remove_dir_all(dir);
}

/// A server that goes away for good ends the walk after its retry budget, and the report
/// keeps the finished run and what the failed one measured.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_gone_for_good_ends_the_walk_keeping_what_it_measured() {
    let (dir, _) = temp_db("gone");
    let (addr, stop, task) = start(&dir).await;
    let strategies: Vec<Strategy> = ["ach", "visibility"]
        .iter()
        .map(|s| Strategy::parse(s).unwrap())
        .collect();
    let mut cfg = small_walk();
    cfg.retry.give_up_after = Duration::from_secs(1);
    let stop = Mutex::new(Some(stop));
    let t0 = Instant::now();
    let failed = walk::run_walk(&url(addr), &cfg, &strategies, &[None], |e| {
        if let WalkEvent::Finished(_) = e {
            if let Some(s) = stop.lock().unwrap().take() {
                let _ = s.send(());
            }
        }
    })
    .await
    .expect_err("the second run cannot finish");
    assert!(t0.elapsed() < Duration::from_secs(20), "{:?}", t0.elapsed());
    task.await.unwrap().unwrap();
    let r = &failed.report;
    assert_eq!(r.runs.len(), 2);
    assert!(r.runs[0].completed && !r.runs[1].completed);
    assert!(r.runs[1].error.is_some() && r.error.is_some());
    assert!(
        failed.error.to_string().contains("stopped answering"),
        "{}",
        failed.error
    );
    let out = dir.join("out");
    walk::write_outputs(r, &out).unwrap();
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
    assert_eq!(json["runs"].as_array().unwrap().len(), 2);
    assert!(json["error"].is_string());
    let _ = std::fs::remove_dir_all(dir);
}
