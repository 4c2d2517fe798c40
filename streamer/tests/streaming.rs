//! Server and client over loopback: hostile requests, ranges and ETags, priorities and
//! cancellation, corrupted responses, a server killed and restarted, load, and walks.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use streamer::client::{
    BundlePiece, Cache, ClientError, ClientStats, Connection, FetchKey, FetchRequest, Fetcher,
    FetcherConfig, ItemTable, RetryPolicy, ServerUrl,
};
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::{self, synth, Strategy, WalkConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tracks::manifest::Manifest;

fn temp_db(name: &str, params: &synth::SynthParams) -> (PathBuf, Manifest) {
    let dir = std::env::temp_dir().join(format!("railview-streamer-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let m = synth::write_synthetic(&dir, params).expect("synthetic database");
    (dir, m)
}

struct Running {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), server::ServerError>>,
    stats: Arc<ServerStats>,
}

impl Running {
    fn url(&self) -> ServerUrl {
        ServerUrl::parse(&format!("http://{}", self.addr)).unwrap()
    }

    async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        self.task.await.unwrap().unwrap();
    }
}

async fn start(dir: &Path, config: ServerConfig, addr: &str) -> Running {
    let listener = TcpListener::bind(addr).await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let stats = Arc::new(ServerStats::default());
    let db = ServedDb::open(dir).unwrap();
    let task = tokio::spawn(server::run(listener, db, config, stats.clone(), async {
        let _ = rx.await;
    }));
    Running {
        addr,
        stop: Some(tx),
        task,
        stats,
    }
}

/// Send raw bytes, return the status line and the whole response.
async fn raw(addr: SocketAddr, request: &[u8]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(request).await.unwrap();
    let mut out = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut out)).await;
    let text = String::from_utf8_lossy(&out).to_string();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (status, text)
}

fn get(path: &str, extra: &str) -> Vec<u8> {
    format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{extra}\r\n").into_bytes()
}

fn first_level(m: &Manifest) -> (String, tracks::manifest::LevelRef, u64) {
    let tile = m.tracks[0].viewpoints[0]
        .tiles
        .iter()
        .find(|t| t.ptm.is_some())
        .unwrap();
    let p = tile.ptm.as_ref().unwrap();
    (p.object.hash.clone(), p.levels[1].clone(), p.object.size)
}

#[tokio::test]
async fn hostile_requests_get_4xx_and_the_server_keeps_serving() {
    let (dir, m) = temp_db("hostile", &synth::SynthParams::default());
    // A file next to the database that must never be readable.
    std::fs::write(dir.join("secret.txt"), "secret").unwrap();
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let (hash, level, size) = first_level(&m);
    let unknown = "ab".repeat(32);
    let cases: Vec<(Vec<u8>, u16)> = vec![
        (get("/../secret.txt", ""), 400),
        (get("/objects/../secret.txt", ""), 400),
        (get("/objects/%2e%2e/secret.txt", ""), 400),
        (get("/secret.txt", ""), 404),
        (get("/etc/passwd", ""), 404),
        (get(&format!("/objects/ab/{unknown}"), ""), 404),
        (get(&format!("/objects/{}/{}", &hash[..2], hash.to_uppercase()), ""), 400),
        (get(&format!("/objects/zz/{hash}"), ""), 400),
        (get(&format!("/objects/{}/{hash}", &hash[..2]), &format!("Range: bytes={}-\r\n", size + 5)), 416),
        // Several ranges are answered (multipart/byteranges); nonsense among them is not.
        (get(&format!("/objects/{}/{hash}", &hash[..2]), "Range: bytes=0-1,4-5\r\n"), 206),
        (get(&format!("/objects/{}/{hash}", &hash[..2]), "Range: bytes=0-1,x-5\r\n"), 400),
        (get(&format!("/objects/{}/{hash}", &hash[..2]), &format!("Range: bytes={}\r\n", vec!["0-0"; 300].join(","))), 416),
        (get(&format!("/objects/{}/{hash}", &hash[..2]), "Range: lines=1-2\r\n"), 400),
        (b"POST /manifest.json HTTP/1.1\r\nHost: x\r\nContent-Length: 4\r\nConnection: close\r\n\r\nabcd".to_vec(), 405),
        (b"\x00\x01garbage\xff\xfe\r\n\r\n".to_vec(), 400),
        (b"GET http://evil/etc/passwd HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".to_vec(), 404),
        // HTTP/1.1 needs a Host header (RFC 9112 §3.2); HTTP/1.0 does not.
        (b"GET /manifest.json HTTP/1.1\r\nConnection: close\r\n\r\n".to_vec(), 400),
        (b"GET /manifest.json HTTP/1.0\r\n\r\n".to_vec(), 200),
        (b"GET /manifest.json HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n4\r\nabcd\r\n0\r\n\r\n".to_vec(), 413),
    ];
    for (req, want) in &cases {
        let (status, text) = raw(srv.addr, req).await;
        assert_eq!(status, *want, "{}\n{text}", String::from_utf8_lossy(req));
        assert!(
            !text.contains("secret\n") && !text.ends_with("secret"),
            "leaked: {text}"
        );
    }
    // Still serving: a range of one level group, with its hash and the cache headers.
    let (status, text) = raw(
        srv.addr,
        &get(
            &format!("/objects/{}/{hash}", &hash[..2]),
            &format!(
                "Range: bytes={}-{}\r\n",
                level.offset,
                level.offset + level.len - 1
            ),
        ),
    )
    .await;
    assert_eq!(status, 206, "{text}");
    assert!(text.contains(&format!("etag: \"{hash}\"")), "{text}");
    assert!(text.contains("immutable"));
    let (status, _) = raw(
        srv.addr,
        &get(
            &format!("/objects/{}/{hash}", &hash[..2]),
            &format!("If-None-Match: \"{hash}\"\r\n"),
        ),
    )
    .await;
    assert_eq!(status, 304);
    let answered = cases.iter().filter(|c| c.1 < 400).count() as u64;
    assert!(srv.stats.client_errors.load(Ordering::Relaxed) >= cases.len() as u64 - answered - 1);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn bundles_are_checked_piece_by_piece_and_fall_back_on_static_hosts() {
    let (dir, m) = temp_db("bundle", &synth::SynthParams::default());
    let tiles: Vec<&tracks::manifest::TileEntry> = m.tracks[0].viewpoints[0]
        .tiles
        .iter()
        .filter(|t| t.ptm.is_some() && t.mesh_range.is_some())
        .take(5)
        .collect();
    // Per tile: its mesh and every PTM level range (consecutive ranges of the pack), and
    // the pack as a whole object.
    let mut keys: Vec<(FetchKey, u64, String)> = Vec::new();
    let pack = tiles[0].ptm.as_ref().unwrap().object.clone();
    keys.push((
        FetchKey {
            object: pack.hash.as_str().into(),
            range: None,
        },
        pack.size,
        pack.hash.clone(),
    ));
    for t in &tiles {
        let p = t.ptm.as_ref().unwrap();
        let mesh = t.mesh_range.as_ref().unwrap();
        keys.push((
            FetchKey {
                object: p.object.hash.as_str().into(),
                range: Some((mesh.offset, mesh.len)),
            },
            mesh.len,
            mesh.hash.clone(),
        ));
        for l in &p.levels {
            keys.push((
                FetchKey {
                    object: p.object.hash.as_str().into(),
                    range: Some((l.offset, l.len)),
                },
                l.len,
                l.hash.clone(),
            ));
        }
    }
    let pieces: Vec<BundlePiece> = keys
        .iter()
        .map(|(key, len, hash)| BundlePiece {
            key,
            len: *len,
            hash,
        })
        .collect();
    let check = |data: &[bytes::Bytes]| {
        assert_eq!(data.len(), keys.len());
        for (d, (_, len, hash)) in data.iter().zip(&keys) {
            assert_eq!(d.len() as u64, *len);
            assert!(db::hash_matches(d, hash));
        }
    };
    // Every second response corrupted: the bundle still arrives right, in one request each.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(2),
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let stats = Arc::new(ClientStats::default());
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats.clone());
    for _ in 0..3 {
        check(&c.fetch_checked_bundle(&pieces, None).await.unwrap());
    }
    assert!(c.bundles_supported());
    assert!(stats.checksum_failures.load(Ordering::Relaxed) >= 1);
    assert!(stats.requests.load(Ordering::Relaxed) <= 6);
    // Hostile bundle queries: 4xx with a reason, the server goes on.
    let (h, size) = (&pack.hash, pack.size);
    let unknown = "ab".repeat(32);
    let many = [h.as_str(); 300].join(",");
    for (q, want) in [
        ("/bundle".to_string(), 400),
        ("/bundle?p=../../secret.txt".to_string(), 400),
        // 422, not 404: a 404 on /bundle means "no bundles here" (a static host) to clients.
        (format!("/bundle?p={unknown}"), 422),
        (format!("/bundle?p={h}:{}:5", size - 1), 416),
        (format!("/bundle?p={h}:0:99999999999999999"), 416),
        // Over the header limit before the entry limit (unit-tested in server::bundle).
        (format!("/bundle?p={many}"), 431),
        (format!("/bundle?p={h}:1"), 400),
    ] {
        let (status, text) = raw(srv.addr, &get(&q, "")).await;
        assert_eq!(status, want, "{}\n{text}", &q[..q.len().min(120)]);
    }
    let (status, text) = raw(srv.addr, &get(&format!("/bundle?p={h}"), "")).await;
    assert_eq!(status, 200, "{text}");
    assert!(
        text.contains("immutable") && text.contains("etag: \"b3-"),
        "{text}"
    );
    srv.stop().await;
    // A static host (no /bundle): the same pieces arrive, object by object.
    let srv = start(
        &dir,
        ServerConfig {
            bundles: false,
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let stats = Arc::new(ClientStats::default());
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats.clone());
    check(&c.fetch_checked_bundle(&pieces, None).await.unwrap());
    assert!(!c.bundles_supported());
    // The whole pack in one request; the tiles' meshes and level ranges, back to back in the
    // pack, in one run.
    assert_eq!(stats.requests.load(Ordering::Relaxed), 2);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn slow_header_senders_are_cut_off_and_connections_are_bounded() {
    let (dir, m) = temp_db("limits", &synth::SynthParams::default());
    let config = ServerConfig {
        header_timeout: Duration::from_millis(200),
        max_connections: 2,
        ..ServerConfig::default()
    };
    let srv = start(&dir, config, "127.0.0.1:0").await;
    // Two idle connections that never finish their headers hold both permits…
    let mut a = TcpStream::connect(srv.addr).await.unwrap();
    let mut b = TcpStream::connect(srv.addr).await.unwrap();
    a.write_all(b"GET /manifest.json HTTP/1.1\r\n")
        .await
        .unwrap();
    b.write_all(b"GET /manifest.json HTTP/1.1\r\n")
        .await
        .unwrap();
    // …until the header timeout closes them; then a normal client gets through.
    let stats = Arc::new(ClientStats::default());
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats);
    let got = tokio::time::timeout(Duration::from_secs(5), c.manifest()).await;
    let got = got.unwrap().unwrap();
    assert!(got.scene == m.scene && got.tracks.len() == m.tracks.len());
    let mut buf = Vec::new();
    let closed = tokio::time::timeout(Duration::from_secs(2), a.read_to_end(&mut buf)).await;
    assert!(closed.is_ok(), "a slow sender is disconnected");
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

fn level_requests(m: &Manifest, n: usize) -> Vec<FetchRequest> {
    let table = ItemTable::new(m).unwrap();
    table
        .items
        .iter()
        .flat_map(|i| i.parts.iter())
        .filter(|p| p.key.range.is_some())
        .take(n)
        .enumerate()
        .map(|(k, p)| FetchRequest {
            key: p.key.clone(),
            expected_hash: p.hash.clone(),
            priority: k as f64,
        })
        .collect()
}

#[tokio::test(flavor = "current_thread")]
async fn fetcher_serves_by_priority_and_drops_cancelled_requests() {
    let (dir, m) = temp_db("prio", &synth::SynthParams::default());
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            max_in_flight: 1,
            ..FetcherConfig::default()
        },
    );
    let reqs = level_requests(&m, 12);
    // On a current-thread runtime nothing runs until we await: all are queued first.
    for r in &reqs {
        f.submit(r.clone());
    }
    let cancelled: Vec<FetchKey> = reqs.iter().step_by(3).map(|r| r.key.clone()).collect();
    f.retain(|k| !cancelled.contains(k));
    let mut order = Vec::new();
    while f.pending() > 0 || order.len() < reqs.len() - cancelled.len() {
        let out = tokio::time::timeout(Duration::from_secs(10), f.next())
            .await
            .unwrap()
            .unwrap();
        let r = reqs.iter().find(|r| r.key == out.key).unwrap();
        let data = out.result.unwrap();
        assert!(db::hash_matches(&data, &r.expected_hash));
        order.push(r.priority);
    }
    assert_eq!(order.len(), reqs.len() - cancelled.len());
    assert!(
        order.windows(2).all(|w| w[0] > w[1]),
        "highest priority first: {order:?}"
    );
    for c in &cancelled {
        assert!(!reqs
            .iter()
            .filter(|r| &r.key == c)
            .any(|r| order.contains(&r.priority)));
    }
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn a_running_request_can_be_cancelled_and_the_worker_goes_on() {
    let params = synth::SynthParams {
        face_size: 128,
        tile_size: 64,
        ..synth::SynthParams::default()
    };
    let (dir, m) = temp_db("cancel", &params);
    // 8 kbit/s: a whole 64×64 tile (about 8 kB) takes seconds, long enough to cancel it.
    let slow = ServerConfig {
        throttle_bps: Some(8_000),
        ..ServerConfig::default()
    };
    let srv = start(&dir, slow, "127.0.0.1:0").await;
    let table = ItemTable::new(&m).unwrap();
    let whole = table.items[0].parts.last().unwrap();
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            max_in_flight: 1,
            ..FetcherConfig::default()
        },
    );
    f.submit(FetchRequest {
        key: whole.key.clone(),
        expected_hash: whole.hash.clone(),
        priority: 1.0,
    });
    tokio::time::sleep(Duration::from_millis(150)).await;
    assert!(f.is_pending(&whole.key));
    f.cancel(&whole.key);
    let out = tokio::time::timeout(Duration::from_secs(5), f.next())
        .await
        .unwrap()
        .unwrap();
    assert!(
        matches!(out.result, Err(ClientError::Cancelled)),
        "{:?}",
        out.result
    );
    // The same worker serves the next request (on a fresh connection).
    let level = &table.items[1].parts[1];
    f.submit(FetchRequest {
        key: level.key.clone(),
        expected_hash: level.hash.clone(),
        priority: 1.0,
    });
    let out = tokio::time::timeout(Duration::from_secs(5), f.next())
        .await
        .unwrap()
        .unwrap();
    assert!(db::hash_matches(&out.result.unwrap(), &level.hash));
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn corrupted_responses_are_fetched_again_and_never_returned() {
    let (dir, m) = temp_db("corrupt", &synth::SynthParams::default());
    let reqs = level_requests(&m, 20);
    // Every second response is corrupted: each fetch still ends with the right bytes.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(2),
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let stats = Arc::new(ClientStats::default());
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats.clone());
    for r in &reqs {
        let data = c
            .fetch_checked(&r.key, &r.expected_hash, None)
            .await
            .unwrap();
        assert!(db::hash_matches(&data, &r.expected_hash));
    }
    assert!(stats.checksum_failures.load(Ordering::Relaxed) >= 5);
    assert!(srv.stats.corrupted.load(Ordering::Relaxed) >= 5);
    srv.stop().await;
    // Every response corrupted: the client gives up with an error, never with data.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(1),
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats);
    let err = c
        .fetch_checked(&reqs[0].key, &reqs[0].expected_hash, None)
        .await
        .unwrap_err();
    assert!(matches!(err, ClientError::Checksum { .. }), "{err}");
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn level_runs_in_one_request_are_checked_part_by_part() {
    let (dir, m) = temp_db("run", &synth::SynthParams::default());
    let p = m.tracks[0].viewpoints[0]
        .tiles
        .iter()
        .find_map(|t| t.ptm.as_ref().filter(|p| p.levels.len() >= 2))
        .unwrap()
        .clone();
    let run: Vec<(u64, u64, &str)> = p
        .levels
        .iter()
        .map(|l| (l.offset, l.len, l.hash.as_str()))
        .collect();
    // Every second response corrupted: the run still arrives right, level by level.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(2),
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let stats = Arc::new(ClientStats::default());
    let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats.clone());
    for _ in 0..4 {
        let parts = c
            .fetch_checked_run(&p.object.hash, &run, None)
            .await
            .unwrap();
        assert_eq!(parts.len(), run.len());
        for (d, &(_, len, hash)) in parts.iter().zip(&run) {
            assert_eq!(d.len() as u64, len);
            assert!(db::hash_matches(d, hash));
        }
    }
    assert!(stats.checksum_failures.load(Ordering::Relaxed) >= 1);
    // Ranges with a gap are refused before anything is sent.
    let gap = [run[0], (run[1].0 + 1, run[1].1, run[1].2)];
    let err = c
        .fetch_checked_run(&p.object.hash, &gap, None)
        .await
        .unwrap_err();
    assert!(matches!(err, ClientError::Transfer { .. }), "{err}");
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

/// Ranges of one object far apart travel in one request as `multipart/byteranges`; every
/// piece is checked against its own hash, and a damaged answer is fetched again, never
/// returned.
#[tokio::test]
async fn several_ranges_travel_in_one_request_and_a_damaged_multipart_answer_is_fetched_again() {
    let (dir, m) = temp_db("multi", &synth::SynthParams::default());
    // The largest pack of the database.
    let object = m.tracks[0]
        .viewpoints
        .iter()
        .flat_map(|v| v.tiles.iter().filter_map(|t| t.ptm.as_ref()))
        .max_by_key(|p| p.object.size)
        .unwrap()
        .object
        .clone();
    let file = std::fs::read(dir.join(object.rel_path().unwrap())).unwrap();
    let size = file.len() as u64;
    assert!(size > 4000, "pack of {size} bytes");
    let spans = [(0u64, 100u64), (size / 2, 50), (size - 30, 30)];
    let hashes: Vec<String> = spans
        .iter()
        .map(|&(o, l)| {
            blake3::hash(&file[o as usize..(o + l) as usize])
                .to_hex()
                .to_string()
        })
        .collect();
    let pieces: Vec<(u64, u64, &str)> = spans
        .iter()
        .zip(&hashes)
        .map(|(&(o, l), h)| (o, l, h.as_str()))
        .collect();
    for corrupt_every in [None, Some(2)] {
        let srv = start(
            &dir,
            ServerConfig {
                bundles: false,
                corrupt_every,
                ..ServerConfig::default()
            },
            "127.0.0.1:0",
        )
        .await;
        let stats = Arc::new(ClientStats::default());
        let mut c = Connection::new(srv.url(), RetryPolicy::default(), stats.clone());
        for _ in 0..4 {
            let got = c
                .fetch_checked_ranges(&object.hash, None, &pieces, None)
                .await
                .unwrap();
            for (g, &(o, l)) in got.iter().zip(&spans) {
                assert_eq!(&g[..], &file[o as usize..(o + l) as usize]);
            }
        }
        assert_eq!(c.multi_ranges(), Some(true));
        let requests = stats.requests.load(Ordering::Relaxed);
        let damaged = stats.checksum_failures.load(Ordering::Relaxed);
        match corrupt_every {
            // One request per fetch: three ranges, one round trip.
            None => assert_eq!((requests, damaged), (4, 0)),
            // Every second answer damaged: each fetched again.
            Some(_) => assert!(damaged >= 1 && requests > 4, "{requests} {damaged}"),
        }
        srv.stop().await;
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn client_recovers_when_the_server_is_killed_and_restarted() {
    let (dir, m) = temp_db("restart", &synth::SynthParams::default());
    let reqs = level_requests(&m, 40);
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let addr = srv.addr;
    let mut f = Fetcher::new(srv.url(), FetcherConfig::default());
    let mut cache = Cache::new(4096);
    let mut done = 0;
    for r in &reqs[..20] {
        f.submit(r.clone());
    }
    while done < 20 {
        let out = f.next().await.unwrap();
        let data = out.result.unwrap();
        let _ = cache.insert(out.key, data, 0);
        done += 1;
    }
    // Kill the server, queue more work, bring a new server up on the same port later.
    let connected = f.stats().reconnects.load(Ordering::Relaxed);
    srv.stop().await;
    for r in &reqs[20..] {
        f.submit(r.clone());
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let srv = start(&dir, ServerConfig::default(), &addr.to_string()).await;
    while done < 40 {
        let out = tokio::time::timeout(Duration::from_secs(20), f.next())
            .await
            .expect("recovered in time")
            .unwrap();
        let data = out.result.expect("fetched after the restart");
        let _ = cache.insert(out.key, data, 0);
        done += 1;
    }
    // New connections to the restarted server (bundled requests need only a few).
    assert!(f.stats().reconnects.load(Ordering::Relaxed) > connected);
    // The cache holds only checked bytes and stays within its budget.
    assert!(cache.used() <= cache.budget());
    for r in &reqs {
        if let Some(b) = cache.get(&r.key) {
            assert!(db::hash_matches(b, &r.expected_hash));
        }
    }
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_concurrent_clients_see_no_errors() {
    let (dir, _) = temp_db("load", &synth::SynthParams::default());
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let r = walk::load::run_load(&srv.url(), 40, Duration::from_millis(800))
        .await
        .unwrap();
    assert_eq!(r.errors, 0);
    assert!(r.requests > 40, "{r:?}");
    assert!(r.p50_ms <= r.p99_ms);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

fn small_walk() -> WalkConfig {
    WalkConfig {
        speed_mps: 1.5,
        pause_s: 1.5,
        frame_dt_s: 0.1,
        samples_x: 32,
        samples_y: 18,
        schedule: streamer::client::SchedulerConfig {
            cache_bytes: 96 << 10,
            budget: streamer::client::BudgetParams {
                memory_bytes: 256 << 10,
                memory_static_bytes: 1 << 20,
                ..Default::default()
            },
            scale_budget: false,
            ..Default::default()
        },
        ..WalkConfig::default()
    }
}

#[tokio::test]
async fn walks_report_every_run_and_respect_the_budgets() {
    let (dir, _) = temp_db("walk", &synth::SynthParams::default());
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let strategies: Vec<Strategy> = ["naive", "ach", "visibility", "ach+prefetch"]
        .iter()
        .map(|s| Strategy::parse(s).unwrap())
        .collect();
    let bws = [Some(2_000_000), None];
    let cfg = small_walk();
    let report = walk::run_walk(&srv.url(), &cfg, &strategies, &bws, |_| {})
        .await
        .unwrap();
    assert_eq!(report.runs.len(), 8);
    for r in &report.runs {
        assert!((0.0..=1.0).contains(&r.mean_needed_fraction), "{r:?}");
        assert_eq!(r.checksum_failures, 0);
        if r.strategy != "naive" {
            assert!(
                r.max_cache_bytes <= cfg.schedule.cache_bytes,
                "{} over budget",
                r.strategy
            );
            assert!(
                r.resident_within_budget,
                "{} over its memory budget",
                r.strategy
            );
            assert!(r.max_resident_bytes > 0);
            assert!(r.max_resident_bytes <= cfg.schedule.budget.memory_static_bytes);
        }
        // Every strategy shows a whole frame at some point (the ACH lists hold no
        // backgrounds; the ACH strategies fetch the segment's as the live session does).
        assert!(
            r.time_to_first_frame_s.is_some(),
            "{} never showed a frame",
            r.strategy
        );
        assert!(r.mean_quality > 0.0, "{}", r.strategy);
    }
    let at = |s: &str, bw: Option<u64>| {
        report
            .runs
            .iter()
            .find(|r| r.strategy == s && r.bandwidth_bps == bw)
            .unwrap()
    };
    eprintln!("{}", walk::summary_markdown(&report));
    // Budgeted streaming moves fewer bytes than whole tiles in manifest order.
    assert!(at("ach", Some(2_000_000)).bytes < at("naive", Some(2_000_000)).bytes);
    let out = dir.join("out");
    walk::write_outputs(&report, &out).unwrap();
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("walk.json")).unwrap()).unwrap();
    let runs = json["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 8);
    for key in [
        "strategy",
        "bandwidth_bps",
        "time_to_first_frame_s",
        "mean_needed_fraction",
        "bytes",
    ] {
        assert!(runs.iter().all(|r| r.get(key).is_some()), "{key}");
    }
    assert!(runs.iter().any(|r| r["bandwidth_bps"].is_null()));
    assert!(out.join("walk.png").exists() && out.join("walk.csv").exists());
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

/// The ACH lists hold tiles only; a walk on them still fetches the backgrounds of its
/// segment's viewpoints (the sky), ranked with the strongest tile as the live session ranks
/// them, and so shows whole frames.
#[tokio::test]
async fn ach_walks_fetch_the_backgrounds_of_their_segment() {
    let params = synth::SynthParams {
        backgrounds: true,
        ..Default::default()
    };
    let (dir, m) = temp_db("walkbg", &params);
    assert!(m.tracks[0]
        .viewpoints
        .iter()
        .all(|v| !v.background.is_empty()));
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let strategies: Vec<Strategy> = ["ach", "visibility"]
        .iter()
        .map(|s| Strategy::parse(s).unwrap())
        .collect();
    let report = walk::run_walk(&srv.url(), &small_walk(), &strategies, &[None], |_| {})
        .await
        .unwrap();
    for r in &report.runs {
        assert!(
            r.background_bytes > 0,
            "{}: no background fetched",
            r.strategy
        );
        assert!(
            r.time_to_first_frame_s.is_some(),
            "{} never showed a frame",
            r.strategy
        );
    }
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

/// Damaged responses are fetched again and never used: the walk sees the same database, and
/// pays for the re-fetches in bytes and time on its link (as a viewer would).
#[tokio::test]
async fn a_corrupting_server_costs_refetches_and_never_shows_damage() {
    let (dir, _) = temp_db("walkcorrupt", &synth::SynthParams::default());
    let strategies = [Strategy::parse("ach+visibility+prefetch").unwrap()];
    let bws = [Some(2_000_000)];
    let cfg = small_walk();
    let clean = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let a = walk::run_walk(&clean.url(), &cfg, &strategies, &bws, |_| {})
        .await
        .unwrap();
    clean.stop().await;
    let bad = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(3),
            ..ServerConfig::default()
        },
        "127.0.0.1:0",
    )
    .await;
    let b = walk::run_walk(&bad.url(), &cfg, &strategies, &bws, |_| {})
        .await
        .unwrap();
    bad.stop().await;
    let (a, b) = (&a.runs[0], &b.runs[0]);
    assert_eq!(a.checksum_failures, 0);
    assert!(b.checksum_failures > 0);
    // Every re-fetch is a request and its bytes.
    assert!(b.bytes > a.bytes && b.requests > a.requests, "{a:?}\n{b:?}");
    // What the walk shows is the same database, a little later.
    assert!(b.time_to_first_frame_s.is_some());
    assert!(
        b.mean_needed_fraction >= 0.8 * a.mean_needed_fraction,
        "{} against {}",
        b.mean_needed_fraction,
        a.mean_needed_fraction
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Regression: many small tiles per view, a fast walk, 50 ms of latency. Each tile used to be
/// two sequential round trips (mesh, then its PTM run) on 6 request slots, so at unlimited
/// bandwidth the walk was bound by round trips: the first complete frame came seconds late
/// (or never) and most needed pixels were missing — the castle face-192 demo walk at 4 m/s
/// showed it. Bundled requests (many tiles' mesh + levels in one request) must keep up.
#[tokio::test]
async fn fast_walks_over_many_small_tiles_are_not_bound_by_round_trips() {
    let params = synth::SynthParams {
        length_m: 12.0,
        spacing_m: 2.0,
        face_size: 64,
        tile_size: 8,
        levels: 3,
        ..synth::SynthParams::default()
    };
    let (dir, _) = temp_db("manytiles", &params);
    let srv = start(&dir, ServerConfig::default(), "127.0.0.1:0").await;
    let strategies: Vec<Strategy> = ["visibility", "ach+prefetch", "ach+visibility+prefetch"]
        .iter()
        .map(|s| Strategy::parse(s).unwrap())
        .collect();
    let cfg = WalkConfig {
        speed_mps: 4.0,
        pause_s: 0.5,
        frame_dt_s: 0.1,
        samples_x: 32,
        samples_y: 18,
        ..WalkConfig::default()
    };
    let report = walk::run_walk(&srv.url(), &cfg, &strategies, &[None], |_| {})
        .await
        .unwrap();
    eprintln!("{}", walk::summary_markdown(&report));
    for r in &report.runs {
        let first = r.time_to_first_frame_s;
        assert!(
            first.is_some_and(|t| t < 1.0),
            "{}: first complete frame at {first:?}",
            r.strategy
        );
        assert!(
            r.mean_needed_fraction >= 0.8,
            "{}: needed fraction {}",
            r.strategy,
            r.mean_needed_fraction
        );
        assert!(r.resident_within_budget, "{}", r.strategy);
    }
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}
