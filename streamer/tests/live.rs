//! The real-time session against a real server on loopback: tiles arrive checked, the cache
//! stays within its budget, a killed and restarted server is survived, corrupted responses
//! never reach the caller.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use streamer::client::{Arrival, LiveConfig, LiveSession};
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::synth;
use tokio::sync::oneshot;
use tracks::{PerspectiveCamera, TrackSet};

/// Every part the session holds was handed out (as an arrival) for every item that uses it.
fn assert_every_held_part_handed_out(session: &LiveSession, arrivals: &[Arrival]) {
    assert_eq!(
        session.held(),
        &session.have()[..],
        "held parts kept by the session"
    );
    let got: std::collections::HashSet<(usize, usize)> =
        arrivals.iter().map(|a| (a.item, a.part)).collect();
    for (i, it) in session.table().items.iter().enumerate() {
        for p in 0..it.parts.len() {
            if session.part_bytes(i, p).is_some() {
                assert!(
                    got.contains(&(i, p)),
                    "item {i} part {p} held but never handed out"
                );
            }
        }
    }
}

/// The synthetic database with the last viewpoint's tiles replaced by the first's: the same
/// payloads in two packs, at the two ends of the track.
fn repeating_db(name: &str) -> PathBuf {
    let src = temp_db(&format!("{name}-src"));
    let mut m = db::Database::open(&src).unwrap().manifest().clone();
    for t in &mut m.tracks {
        let last = t.viewpoints.len() - 1;
        t.viewpoints[last].tiles = t.viewpoints[0].tiles.clone();
    }
    let dir = std::env::temp_dir().join(format!("railview-live-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut w = db::DbWriter::create(&dir)
        .unwrap()
        .with_stage(&src)
        .unwrap();
    w.finish(&m).unwrap();
    let _ = std::fs::remove_dir_all(&src);
    dir
}

fn temp_db(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("railview-live-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    synth::write_synthetic(&dir, &synth::SynthParams::default()).expect("synthetic database");
    dir
}

/// A server on its own runtime thread.
struct Server {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    fn start(dir: &Path, config: ServerConfig, addr: &str) -> Server {
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        let (stop_tx, stop_rx) = oneshot::channel::<()>();
        let dir = dir.to_path_buf();
        let addr = addr.to_string();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async move {
                let listener = tokio::net::TcpListener::bind(&addr).await.unwrap();
                addr_tx.send(listener.local_addr().unwrap()).unwrap();
                let db = ServedDb::open(&dir).unwrap();
                let stats = Arc::new(ServerStats::default());
                server::run(listener, db, config, stats, async {
                    let _ = stop_rx.await;
                })
                .await
                .unwrap();
            });
        });
        Server {
            addr: addr_rx.recv().unwrap(),
            stop: Some(stop_tx),
            thread: Some(thread),
        }
    }

    fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            t.join().unwrap();
        }
    }
}

fn camera(session: &LiveSession, s: f64, yaw: f64) -> PerspectiveCamera {
    let t = &session.manifest().tracks[session.track()];
    let track = TrackSet::parse(&t.track_toml, "manifest").unwrap().tracks[0].clone();
    PerspectiveCamera {
        position: track.position_at(s),
        yaw_deg: yaw,
        pitch_deg: 0.0,
        fov_deg: 90.0,
        width: 320,
        height: 180,
    }
}

/// Every arrival carries exactly the bytes the manifest's hash names.
fn check(session: &LiveSession, arrivals: &[Arrival]) {
    for a in arrivals {
        let part = &session.table().items[a.item].parts[a.part];
        assert!(
            db::hash_matches(&a.data, &part.hash),
            "item {} part {}",
            a.item,
            a.part
        );
    }
}

/// Update at `s` until `done` holds or `timeout` passes; returns the arrivals.
fn run_until(
    session: &mut LiveSession,
    s: f64,
    timeout: Duration,
    mut done: impl FnMut(&LiveSession) -> bool,
) -> Vec<Arrival> {
    let cam = camera(session, s, 0.0);
    let start = Instant::now();
    let mut all = Vec::new();
    while start.elapsed() < timeout {
        let a = session.update(s, &cam, None);
        check(session, &a);
        assert!(session.cache().used() <= session.cache().budget());
        all.extend(a);
        if done(session) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    all
}

/// Bytes of every part of track 0 of the database in `dir` (all tables included).
fn total_bytes(dir: &Path) -> u64 {
    let db = db::Database::open(dir).unwrap();
    streamer::client::ItemTable::new(db.manifest())
        .unwrap()
        .items
        .iter()
        .flat_map(|it| it.parts.iter().map(|p| p.bytes))
        .sum()
}

#[test]
fn a_session_receives_the_current_segment_and_stays_within_its_budget() {
    let dir = temp_db("receive");
    let srv = Server::start(&dir, ServerConfig::default(), "127.0.0.1:0");
    // A cache a third the size of the whole track: eviction and refusals must happen.
    let budget = total_bytes(&dir) / 3;
    let mut session =
        LiveSession::connect(&srv.url(), None, LiveConfig::with_cache(budget)).unwrap();
    let arrivals = run_until(&mut session, 1.0, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    assert!(!arrivals.is_empty());
    assert_eq!(
        session.stats().coarse_fraction,
        1.0,
        "{:?}",
        session.stats()
    );
    // Walk to the far end: the cache moves along, never above its budget.
    let len = session.manifest().tracks[0].length;
    let mut s = 1.0;
    while s < len {
        s += 0.5;
        run_until(&mut session, s, Duration::from_millis(100), |_| false);
        // The session's pins, kept from frame to frame by what joins and leaves, are
        // exactly what the cache holds in use.
        assert_eq!(
            session.stats().pinned_bytes,
            session.cache().pinned_bytes(),
            "at s = {s}"
        );
        // So are the held parts, kept by arrivals and evictions.
        assert_eq!(session.held(), &session.have()[..], "at s = {s}");
    }
    run_until(&mut session, len, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    let st = session.stats().clone();
    assert_eq!(st.coarse_fraction, 1.0, "{st:?}");
    assert!(st.cache_peak <= budget, "{st:?}");
    assert!(st.bytes > 0 && st.requests > 0);
    assert!(st.quality > 0.0);
    assert!(
        session.cache().evictions() > 0,
        "the walk made the cache evict"
    );
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_session_survives_the_server_going_away_and_coming_back() {
    let dir = temp_db("restart");
    let srv = Server::start(&dir, ServerConfig::default(), "127.0.0.1:0");
    let addr = srv.addr;
    let mut session =
        LiveSession::connect(&srv.url(), None, LiveConfig::with_cache(64 << 20)).unwrap();
    run_until(&mut session, 0.0, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    let held = session.cache().used();
    assert!(held > 0);
    srv.stop();
    // Server gone: keep updating (moving into the next segment); nothing panics, nothing
    // cached is lost.
    let len = session.manifest().tracks[0].length;
    run_until(&mut session, len * 0.6, Duration::from_millis(800), |_| {
        false
    });
    assert!(session.cache().used() >= held);
    let srv = Server::start(&dir, ServerConfig::default(), &addr.to_string());
    let arrivals = run_until(&mut session, len * 0.6, Duration::from_secs(30), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    assert!(!arrivals.is_empty(), "nothing arrived after the restart");
    assert_eq!(session.stats().coarse_fraction, 1.0);
    assert!(session.stats().reconnects > 1);
    // The outage shows: time without progress, and requests that failed or were retried.
    let st = session.stats();
    assert!(st.longest_stall_s >= 0.5, "{st:?}");
    assert!(st.retries + st.failed_requests > 0, "{st:?}");
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

/// A pack damaged on the server (after it opened the database) is a fault of the parts in
/// it: counted, asked for again, given up; everything else keeps arriving.
#[test]
fn a_damaged_pack_is_given_up_part_by_part_and_the_rest_streams_on() {
    let dir = temp_db("damaged");
    let srv = Server::start(&dir, ServerConfig::default(), "127.0.0.1:0");
    let db = db::Database::open(&dir).unwrap();
    let pack = db.manifest().tracks[0].viewpoints[0]
        .tiles
        .iter()
        .find_map(|t| t.ptm.as_ref())
        .unwrap()
        .object
        .clone();
    let path = dir.join(pack.rel_path().unwrap());
    let mut bytes = std::fs::read(&path).unwrap();
    for b in bytes.iter_mut().step_by(97) {
        *b ^= 0x20;
    }
    std::fs::write(&path, &bytes).unwrap();
    let mut config = LiveConfig::with_cache(64 << 20);
    config.schedule.failures.first_retry_s = 0.2;
    let mut session = LiveSession::connect(&srv.url(), None, config).unwrap();
    let arrivals = run_until(&mut session, 0.0, Duration::from_secs(20), |s| {
        s.stats().parts_given_up > 0
    });
    let st = session.stats().clone();
    assert!(st.part_faults >= 3 && st.parts_given_up >= 1, "{st:?}");
    assert!(st.checksum_failures > 0, "{st:?}");
    assert!(!arrivals.is_empty(), "nothing else arrived");
    assert_eq!(
        st.failed_requests, 0,
        "an object's fault is not the server's: {st:?}"
    );
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn corrupted_responses_never_reach_the_caller() {
    let dir = temp_db("corrupt");
    let config = ServerConfig {
        corrupt_every: Some(3),
        ..Default::default()
    };
    let srv = Server::start(&dir, config, "127.0.0.1:0");
    let mut session =
        LiveSession::connect(&srv.url(), None, LiveConfig::with_cache(64 << 20)).unwrap();
    // `run_until` checks every arrival's hash.
    let arrivals = run_until(&mut session, 2.0, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    assert!(!arrivals.is_empty());
    assert!(
        session.stats().checksum_failures > 0,
        "{:?}",
        session.stats()
    );
    // The tables that arrived are exactly the database's (a corrupted one was fetched
    // again, never used).
    let db = db::Database::open(&dir).unwrap();
    let want = &db.manifest().tracks[0];
    let got = &session.manifest().tracks[0];
    assert!(session.has_table(0), "{:?}", session.stats());
    for (v, vp) in got.viewpoints.iter().enumerate() {
        if session.has_table(v) {
            assert_eq!(vp.tiles, want.viewpoints[v].tiles, "viewpoint {v}");
        } else {
            assert!(vp.tiles.is_empty());
        }
    }
    // Whatever is cached is intact too.
    for (i, it) in session.table().items.iter().enumerate() {
        for (p, part) in it.parts.iter().enumerate() {
            if let Some(b) = session.part_bytes(i, p) {
                assert!(db::hash_matches(b, &part.hash));
            }
        }
    }
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn tables_arrive_nearest_first_and_the_session_grows_with_them() {
    let dir = temp_db("tables");
    let srv = Server::start(&dir, ServerConfig::default(), "127.0.0.1:0");
    let mut session =
        LiveSession::connect(&srv.url(), None, LiveConfig::with_cache(64 << 20)).unwrap();
    // From the top manifest alone: backgrounds, no tile (nothing to request for them yet).
    assert_eq!(session.tables_loaded().0, 0);
    assert!(session.table().items.iter().all(|it| it.tile.is_none()));
    assert!(session.manifest().tracks[0]
        .viewpoints
        .iter()
        .all(|v| v.tiles.is_empty()));
    let arrivals = run_until(&mut session, 0.5, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0
    });
    assert!(session.has_table(0) && session.has_table(1));
    assert!(session.table().items.iter().any(|it| it.tile.is_some()));
    // A tile's parts arrive only once its viewpoint's table is in.
    for a in &arrivals {
        let it = &session.table().items[a.item];
        assert!(it.tile.is_none() || session.has_table(it.viewpoint));
    }
    // Item numbers never change as tables come in: remember the first ones.
    let before: Vec<_> = session
        .table()
        .items
        .iter()
        .map(|it| (it.viewpoint, it.tile))
        .collect();
    let len = session.manifest().tracks[0].length;
    let more = run_until(&mut session, len, Duration::from_secs(20), |s| {
        (0..s.top().viewpoints.len()).all(|v| s.has_table(v)) && s.stats().coarse_fraction >= 1.0
    });
    // Every part held was handed to every item that uses it.
    let got: Vec<Arrival> = arrivals.into_iter().chain(more).collect();
    assert_every_held_part_handed_out(&session, &got);
    let after: Vec<_> = session
        .table()
        .items
        .iter()
        .map(|it| (it.viewpoint, it.tile))
        .collect();
    assert_eq!(&after[..before.len()], &before[..]);
    let n = session.top().viewpoints.len();
    assert_eq!(session.tables_loaded(), (n, n));
    // With every table in, the session's manifest is the database's.
    let db = db::Database::open(&dir).unwrap();
    assert_eq!(session.manifest(), db.manifest());
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn identical_parts_are_fetched_once_and_handed_to_every_tile() {
    let dir = repeating_db("repeats");
    // One request at a time, one key each, 20 ms apart: in order of priority, so the first
    // viewpoint's tiles (in view) come before the last viewpoint's table (the same tiles;
    // distant tables rank after every tile).
    let slow = ServerConfig {
        latency: Duration::from_millis(20),
        ..ServerConfig::default()
    };
    let srv = Server::start(&dir, slow, "127.0.0.1:0");
    let mut config = LiveConfig::with_cache(64 << 20);
    config.schedule.max_in_flight = 1;
    config.schedule.max_pieces = 1;
    let mut session = LiveSession::connect(&srv.url(), None, config).unwrap();
    let arrivals = run_until(&mut session, 0.5, Duration::from_secs(20), |s| {
        s.stats().coarse_fraction >= 1.0 && (0..s.top().viewpoints.len()).all(|v| s.has_table(v))
    });
    let table = session.table();
    let last = session.top().viewpoints.len() - 1;
    let mut users: std::collections::HashMap<&streamer::client::FetchKey, usize> =
        std::collections::HashMap::new();
    for it in &table.items {
        for p in &it.parts {
            *users.entry(&p.key).or_insert(0) += 1;
        }
    }
    // The last viewpoint's tiles share the first viewpoint's keys, and those of them whose
    // bytes were held before its table came were handed out all the same.
    let shared: Vec<usize> = (0..table.items.len())
        .filter(|&i| {
            let it = &table.items[i];
            it.viewpoint == last
                && it.tile.is_some()
                && users[&it.parts[0].key] > 1
                && session.part_bytes(i, 0).is_some()
        })
        .collect();
    assert!(
        !shared.is_empty(),
        "no tile of the last viewpoint shares held bytes"
    );
    assert_every_held_part_handed_out(&session, &arrivals);
    drop(session);
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}

/// One client: a recorded walk replayed through the live session on a hand-set clock (each
/// frame at its time, every request answered before the next frame, as the simulator's
/// unlimited link answers at once) asks for exactly the requests the walk simulator asks for,
/// in the same order. One request in flight, so the order does not depend on which of several
/// connections answers first.
#[test]
fn a_replayed_walk_asks_for_what_the_simulator_asks_for() {
    use streamer::client::{ManualClock, SchedulerConfig, Strategy};
    use streamer::walk::{self, WalkConfig};
    let dir = temp_db("replay");
    let srv = Server::start(&dir, ServerConfig::default(), "127.0.0.1:0");
    for strategy in ["visibility+prefetch", "ach+visibility+prefetch"] {
        let strategy = Strategy::parse(strategy).unwrap();
        let cfg = WalkConfig {
            speed_mps: 3.0,
            latency_s: 0.0,
            frame_dt_s: 0.1,
            pause_s: 1.5,
            screen_width: 320,
            screen_height: 180,
            samples_x: 16,
            samples_y: 9,
            schedule: SchedulerConfig {
                max_in_flight: 1,
                cache_bytes: total_bytes(&dir) / 2,
                ..SchedulerConfig::default()
            },
            record_requests: true,
            ..WalkConfig::default()
        };
        let url = streamer::client::ServerUrl::parse(&srv.url()).unwrap();
        let rt = tokio::runtime::Runtime::new().unwrap();
        let report = rt
            .block_on(walk::run_walk(&url, &cfg, &[strategy], &[None], |_| {}))
            .unwrap();
        let simulated = &report.runs[0].request_log;
        assert!(simulated.len() > 10, "{} requests", simulated.len());

        let clock = Arc::new(ManualClock::new(0.0));
        let config = LiveConfig {
            schedule: SchedulerConfig {
                strategy,
                ..cfg.schedule.clone()
            },
            ..LiveConfig::with_cache(1)
        };
        let mut session =
            LiveSession::connect_with_clock(&srv.url(), None, config, clock.clone()).unwrap();
        session.record_requests();
        let net = session.top().network().unwrap();
        let route = walk::route_of(&net, &cfg).unwrap();
        for f in walk::walk_frames(&net, &route, &cfg) {
            clock.set(f.t_s);
            let arrivals = session.update(f.s_m, &f.camera, None);
            check(&session, &arrivals);
            let start = Instant::now();
            while !session.idle() {
                assert!(
                    start.elapsed() < Duration::from_secs(20),
                    "requests never finished"
                );
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        let live = session.take_request_log();
        assert_eq!(live.len(), simulated.len(), "{}: requests", strategy.name());
        for (k, (a, b)) in live.iter().zip(simulated).enumerate() {
            assert_eq!(a, b, "{}: request {k}", strategy.name());
        }
    }
    srv.stop();
    let _ = std::fs::remove_dir_all(dir);
}
