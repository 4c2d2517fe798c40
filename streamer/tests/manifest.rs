//! The manifest over HTTP: served gzip-compressed to clients that accept it (as nginx's
//! `gzip_static` would), decoded within a limit and checked against `manifest.json.blake3`
//! by the client, and charged to the walk simulator's link.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use db::{gunzip_limited, gzip, hash_hex, MANIFEST_FILE, MANIFEST_GZ_FILE};
use streamer::client::{ClientError, ClientStats, Connection, RetryPolicy, ServerUrl};
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::{self, synth, Strategy, WalkConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tracks::manifest::Manifest;

fn temp_db(name: &str) -> (PathBuf, Manifest) {
    let dir = std::env::temp_dir().join(format!("railview-manifest-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let m = synth::write_synthetic(&dir, &synth::SynthParams::default()).expect("database");
    (dir, m)
}

/// Runs the real server on `dir`; returns its address and a stopper.
async fn start(dir: &Path) -> (SocketAddr, oneshot::Sender<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let db = ServedDb::open(dir).unwrap();
    tokio::spawn(server::run(
        listener,
        db,
        ServerConfig::default(),
        Arc::new(ServerStats::default()),
        async {
            let _ = rx.await;
        },
    ));
    (addr, tx)
}

fn url(addr: SocketAddr) -> ServerUrl {
    ServerUrl::parse(&format!("http://{addr}")).unwrap()
}

/// One request with `Connection: close`: (status, lowercase header lines, body).
async fn raw_get(addr: SocketAddr, path: &str, extra: &str) -> (u16, Vec<String>, Vec<u8>) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{extra}\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut out))
        .await
        .unwrap()
        .unwrap();
    let split = out.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&out[..split]).to_ascii_lowercase();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split_whitespace().nth(1).unwrap();
    (
        status.parse().unwrap(),
        lines.map(str::to_string).collect(),
        out[split + 4..].to_vec(),
    )
}

fn header<'a>(headers: &'a [String], name: &str) -> Option<&'a str> {
    headers
        .iter()
        .find_map(|h| h.strip_prefix(name)?.strip_prefix(':').map(str::trim))
}

#[tokio::test]
async fn the_manifest_travels_gzipped_and_is_checked() {
    let (dir, m) = temp_db("served");
    let json = std::fs::read(dir.join(MANIFEST_FILE)).unwrap();
    let gz = std::fs::read(dir.join(MANIFEST_GZ_FILE)).unwrap();
    let (addr, stop) = start(&dir).await;

    let (status, h, body) = raw_get(addr, "/manifest.json", "Accept-Encoding: gzip, br\r\n").await;
    assert_eq!(status, 200);
    assert_eq!(header(&h, "content-encoding"), Some("gzip"));
    assert_eq!(header(&h, "vary"), Some("accept-encoding"));
    assert_eq!(body, gz);
    assert_eq!(gunzip_limited(&body, 1 << 30).unwrap(), json);
    let gz_etag = header(&h, "etag").unwrap().to_string();

    for extra in [
        "",
        "Accept-Encoding: br\r\n",
        "Accept-Encoding: gzip;q=0\r\n",
    ] {
        let (status, h, body) = raw_get(addr, "/manifest.json", extra).await;
        assert_eq!(status, 200);
        assert_eq!(header(&h, "content-encoding"), None, "{extra}");
        assert_eq!(header(&h, "vary"), Some("accept-encoding"));
        assert_eq!(body, json);
        let etag = header(&h, "etag").unwrap();
        assert_eq!(etag, format!("\"{}\"", hash_hex(&json)));
        assert_ne!(etag, gz_etag, "the two encodings share an ETag");
    }
    let (status, _, body) = raw_get(addr, "/manifest.json.blake3", "").await;
    assert_eq!(
        (status, body),
        (200, format!("{}\n", hash_hex(&json)).into_bytes())
    );

    let stats = Arc::new(ClientStats::default());
    let mut conn = Connection::new(url(addr), RetryPolicy::default(), stats.clone());
    let got = conn.fetch_manifest().await.unwrap();
    assert_eq!(got.top, db::split::split(&m).unwrap().0);
    assert!(got.gzip && got.checked);
    // The root and its checksum file side by side, then the index's pieces.
    let (piece_bytes, pieces, _) = index_cost(&dir);
    assert_eq!(got.requests, 2 + pieces);
    assert_eq!(got.transferred_bytes, gz.len() as u64 + 65 + piece_bytes);
    assert_eq!(got.json_bytes, json.len() as u64);
    assert_eq!(stats.bytes.load(Ordering::Relaxed), got.transferred_bytes);
    let _ = stop.send(());

    // A damaged .gz on disk is not served: clients get the identity body.
    let mut bad = gz.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0x20;
    std::fs::write(dir.join(MANIFEST_GZ_FILE), &bad).unwrap();
    assert!(!ServedDb::open(&dir).unwrap().serves_gzip_manifest());
    let (addr, stop) = start(&dir).await;
    let (_, h, body) = raw_get(addr, "/manifest.json", "Accept-Encoding: gzip\r\n").await;
    assert_eq!(header(&h, "content-encoding"), None);
    assert_eq!(body, json);
    // An older database without the copy: no Vary, no encoding.
    std::fs::remove_file(dir.join(MANIFEST_GZ_FILE)).unwrap();
    let _ = stop.send(());
    let (addr, stop) = start(&dir).await;
    let (_, h, body) = raw_get(addr, "/manifest.json", "Accept-Encoding: gzip\r\n").await;
    assert_eq!(
        (header(&h, "content-encoding"), header(&h, "vary")),
        (None, None)
    );
    assert_eq!(body, json);
    let mut conn = Connection::new(url(addr), RetryPolicy::default(), stats);
    let got = conn.fetch_manifest().await.unwrap();
    assert!(!got.gzip && got.checked);
    assert_eq!(
        got.transferred_bytes,
        json.len() as u64 + 65 + index_cost(&dir).0
    );
    let _ = stop.send(());
    let _ = std::fs::remove_dir_all(dir);
}

/// What a hand-written server answers for `/manifest.json` to a gzip-accepting request.
#[derive(Clone)]
struct Fake {
    hash_file: Vec<u8>,
    /// Body sent with `Content-Encoding: gzip` when the request accepts gzip.
    gz_body: Vec<u8>,
    /// Body sent otherwise.
    identity_body: Vec<u8>,
    /// The database, whose objects are served as they are.
    dir: PathBuf,
}

/// A minimal keep-alive HTTP/1.1 server answering `Fake`'s bodies (hyper's server would not
/// send a broken gzip body; this one does). Counts gzip and identity answers.
async fn fake_server(fake: Fake) -> (SocketAddr, Arc<[std::sync::atomic::AtomicU64; 2]>) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let counts = Arc::new([
        std::sync::atomic::AtomicU64::new(0),
        std::sync::atomic::AtomicU64::new(0),
    ]);
    let c = counts.clone();
    tokio::spawn(async move {
        while let Ok((mut s, _)) = listener.accept().await {
            let fake = fake.clone();
            let c = c.clone();
            tokio::spawn(async move {
                let mut buf = Vec::new();
                loop {
                    let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") else {
                        let mut chunk = [0u8; 4096];
                        match s.read(&mut chunk).await {
                            Ok(0) | Err(_) => return,
                            Ok(n) => buf.extend_from_slice(&chunk[..n]),
                        }
                        continue;
                    };
                    let head = String::from_utf8_lossy(&buf[..end]).to_ascii_lowercase();
                    buf.drain(..end + 4);
                    let path = head.split_whitespace().nth(1).unwrap_or("").to_string();
                    let gzip = head.contains("accept-encoding: gzip");
                    let (status, body, enc) = if path == "/manifest.json.blake3" {
                        ("200 OK", fake.hash_file.clone(), "")
                    } else if path == "/manifest.json" && gzip {
                        c[0].fetch_add(1, Ordering::Relaxed);
                        ("200 OK", fake.gz_body.clone(), "Content-Encoding: gzip\r\n")
                    } else if path == "/manifest.json" {
                        c[1].fetch_add(1, Ordering::Relaxed);
                        ("200 OK", fake.identity_body.clone(), "")
                    } else if let Some(Ok(b)) = path
                        .strip_prefix("/objects/")
                        .map(|rel| std::fs::read(fake.dir.join("objects").join(rel)))
                    {
                        ("200 OK", b, "")
                    } else {
                        ("404 Not Found", b"no\n".to_vec(), "")
                    };
                    let resp = format!(
                        "HTTP/1.1 {status}\r\nContent-Length: {}\r\n{enc}\r\n",
                        body.len()
                    );
                    if s.write_all(resp.as_bytes()).await.is_err()
                        || s.write_all(&body).await.is_err()
                    {
                        return;
                    }
                }
            });
        }
    });
    (addr, counts)
}

#[tokio::test]
async fn a_damaged_gzip_manifest_is_never_returned() {
    let (dir, m) = temp_db("fake");
    let json = std::fs::read(dir.join(MANIFEST_FILE)).unwrap();
    let gz = std::fs::read(dir.join(MANIFEST_GZ_FILE)).unwrap();
    let hash_file = format!("{}\n", hash_hex(&json)).into_bytes();
    let mut flipped = gz.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x01;
    // Valid gzip of other JSON: decodes fine, fails the checksum.
    let mut other = json.clone();
    other[1] = b' ';
    let cases = [
        ("flipped byte", flipped),
        ("wrong manifest", gzip(&other).unwrap()),
    ];
    for (what, gz_body) in cases {
        let (addr, counts) = fake_server(Fake {
            hash_file: hash_file.clone(),
            gz_body,
            identity_body: json.clone(),
            dir: dir.clone(),
        })
        .await;
        let stats = Arc::new(ClientStats::default());
        let mut conn = Connection::new(url(addr), RetryPolicy::default(), stats.clone());
        let got = conn.fetch_manifest().await.unwrap();
        assert_eq!(got.top, db::split::split(&m).unwrap().0, "{what}");
        assert!(!got.gzip, "{what}: the damaged gzip body was accepted");
        assert_eq!(stats.checksum_failures.load(Ordering::Relaxed), 1, "{what}");
        assert_eq!(
            (
                counts[0].load(Ordering::Relaxed),
                counts[1].load(Ordering::Relaxed)
            ),
            (1, 1),
            "{what}: one gzip try, then uncompressed"
        );
    }

    // Both encodings wrong: an error after the allowed attempts, never a manifest.
    let (addr, _) = fake_server(Fake {
        hash_file: hash_file.clone(),
        gz_body: gzip(&other).unwrap(),
        identity_body: other.clone(),
        dir: dir.clone(),
    })
    .await;
    let stats = Arc::new(ClientStats::default());
    let mut conn = Connection::new(url(addr), RetryPolicy::default(), stats.clone());
    let err = conn.fetch_manifest().await.unwrap_err();
    assert!(matches!(err, ClientError::Checksum { .. }), "{err}");
    assert_eq!(
        stats.checksum_failures.load(Ordering::Relaxed),
        u64::from(RetryPolicy::default().checksum_attempts)
    );

    // A small body that expands past the limit stops at the limit with a typed error.
    let bomb = gzip(&vec![b' '; 4 << 20]).unwrap();
    assert!(bomb.len() < 64 << 10);
    let (addr, _) = fake_server(Fake {
        hash_file,
        gz_body: bomb,
        identity_body: json,
        dir: dir.clone(),
    })
    .await;
    let policy = RetryPolicy {
        max_body: 1 << 20,
        ..RetryPolicy::default()
    };
    let mut conn = Connection::new(url(addr), policy, Arc::new(ClientStats::default()));
    let err = conn.fetch_manifest().await.unwrap_err();
    assert!(
        matches!(err, ClientError::DecodedTooLarge { limit, .. } if limit == 1 << 20),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn the_walk_counts_the_manifest() {
    let (dir, _) = temp_db("walk");
    let json_len = std::fs::metadata(dir.join(MANIFEST_FILE)).unwrap().len();
    let gz_len = std::fs::metadata(dir.join(MANIFEST_GZ_FILE)).unwrap().len();
    let cfg = WalkConfig {
        speed_mps: 3.0,
        pause_s: 0.5,
        frame_dt_s: 0.1,
        samples_x: 32,
        samples_y: 18,
        ..WalkConfig::default()
    };
    let strategies = [Strategy::parse("visibility").unwrap()];
    let bw = 2_000_000u64;
    let mut runs = Vec::new();
    for with_gz in [true, false] {
        if !with_gz {
            std::fs::remove_file(dir.join(MANIFEST_GZ_FILE)).unwrap();
        }
        let (addr, stop) = start(&dir).await;
        let report = walk::run_walk(&url(addr), &cfg, &strategies, &[Some(bw), None], |_| {})
            .await
            .unwrap();
        let _ = stop.send(());
        runs.push(report.runs);
    }
    for (runs, body) in [(&runs[0], gz_len), (&runs[1], json_len)] {
        for r in runs {
            // The body and the checksum file, two requests side by side (one round trip),
            // then the index's pieces a level of the tree a round trip, before anything else.
            let (piece_bytes, _, levels) = index_cost(&dir);
            let bytes = body + 65 + piece_bytes;
            assert_eq!(r.manifest_bytes, bytes);
            let want = match r.bandwidth_bps {
                Some(b) => (1 + levels) as f64 * cfg.latency_s + bytes as f64 * 8.0 / b as f64,
                None => (1 + levels) as f64 * cfg.latency_s,
            };
            assert!(
                (r.manifest_s - want).abs() < 1e-9,
                "{} vs {want}",
                r.manifest_s
            );
            let first = r.time_to_first_frame_s.expect("a complete frame");
            assert!(first >= r.manifest_s);
            assert!(r.frames.iter().all(|f| f.t_s >= r.manifest_s - 1e-9));
        }
    }
    // Everything after the manifest is the same walk: the first frame moves by exactly the
    // manifest's time, and the uncompressed manifest costs more of it.
    for (a, b) in runs[0].iter().zip(&runs[1]) {
        let (fa, fb) = (
            a.time_to_first_frame_s.unwrap(),
            b.time_to_first_frame_s.unwrap(),
        );
        assert!(((fb - b.manifest_s) - (fa - a.manifest_s)).abs() < 1e-9);
        assert_eq!(a.bytes, b.bytes);
        if a.bandwidth_bps.is_some() {
            assert!(b.manifest_s > a.manifest_s);
        }
    }
    let md = walk::summary_markdown(&walk::WalkReport {
        scene: "s".into(),
        track: "t".into(),
        length_m: 1.0,
        speed_mps: 1.0,
        latency_s: 0.05,
        runs: runs[0].clone(),
        error: None,
    });
    let with_index = gz_len + 65 + index_cost(&dir).0;
    assert!(md.contains("manifest bytes") && md.contains(&with_index.to_string()));
    let json = serde_json::to_value(&runs[0][0]).unwrap();
    assert!(json.get("manifest_bytes").is_some() && json.get("manifest_s").is_some());
    let _ = std::fs::remove_dir_all(dir);
}

/// The first complete frame waits for the top manifest, the tables of the viewpoints around
/// the walker (the current segment's, and the next one's once prefetch starts) and their
/// tiles — never for the whole database's entries.
#[tokio::test]
async fn the_first_frame_needs_the_nearest_tables_and_their_tiles_only() {
    let dir = std::env::temp_dir().join(format!("railview-manifest-first-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let params = synth::SynthParams {
        length_m: 24.0,
        ..synth::SynthParams::default()
    };
    let m = synth::write_synthetic(&dir, &params).expect("database");
    let db = db::Database::open(&dir).unwrap();
    let top = db.top().clone();
    let vps = &top.viewpoints;
    assert!(vps.len() >= 6, "{} viewpoints", vps.len());
    let all_tables: u64 = vps.iter().map(|v| v.table.size).sum();
    // The current segment's two tables, and the next segment's once the view has no holes
    // (prefetch starts when the coarse levels are in, before the frame is complete).
    let near_tables: u64 = vps[..4].iter().map(|v| v.table.size).sum();
    // Every part of the first four viewpoints' items (all levels) and every background.
    let table = streamer::client::ItemTable::new(&m).unwrap();
    let tiles: u64 = table
        .items
        .iter()
        .filter(|it| it.viewpoint < 4 || it.tile.is_none())
        .flat_map(|it| it.parts.iter().map(|p| p.bytes))
        .sum();
    let cfg = WalkConfig {
        speed_mps: 1.5,
        pause_s: 0.0,
        frame_dt_s: 0.05,
        samples_x: 32,
        samples_y: 18,
        ..WalkConfig::default()
    };
    let (addr, stop) = start(&dir).await;
    let report = walk::run_walk(
        &url(addr),
        &cfg,
        &[Strategy::parse("visibility+prefetch").unwrap()],
        &[Some(2_000_000)],
        |_| {},
    )
    .await
    .unwrap();
    let _ = stop.send(());
    let r = &report.runs[0];
    let first = r.first_frame_bytes.expect("a complete frame");
    let first_tables = r.first_frame_table_bytes.unwrap();
    assert!(
        first_tables <= near_tables,
        "{first_tables} bytes of tables before the first frame, the first four are {near_tables}"
    );
    assert!(
        first <= r.manifest_bytes + near_tables + tiles,
        "{first} > {} + {near_tables} + {tiles}",
        r.manifest_bytes
    );
    assert!(
        first_tables < all_tables,
        "{first_tables} of {all_tables} bytes of tables before the first frame"
    );
    // Every table is still fetched, on the link, over the walk.
    assert_eq!(r.table_bytes, all_tables);
    assert!(r.bytes >= r.table_bytes);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn an_item_table_grown_in_any_order_equals_the_one_built_at_once() {
    let (dir, m) = temp_db("grown-table");
    let whole = streamer::client::ItemTable::new(&m).unwrap();
    assert!(
        whole.segment_ach.iter().any(|l| !l.is_empty()),
        "the synthetic database has ACH lists"
    );
    let t = &m.tracks[0];
    let n = t.viewpoints.len();
    let segments_from = |vi: usize| -> Vec<_> {
        t.segments
            .iter()
            .filter(|s| s.from == t.viewpoints[vi].index)
            .cloned()
            .collect()
    };
    // Tables far end first, ACH lists of every other viewpoint before its table (they wait
    // for the tiles they name), the rest with their tables.
    let mut grown = streamer::client::ItemTable::empty(&m).unwrap();
    for vi in (0..n).step_by(2) {
        grown.add_segments(vi, &segments_from(vi));
    }
    for vi in (0..n).rev() {
        let v = &t.viewpoints[vi];
        let segs = if vi % 2 == 0 {
            Vec::new()
        } else {
            segments_from(vi)
        };
        grown
            .add_viewpoint(vi, &v.background, &v.tiles, &segs)
            .unwrap();
    }
    // Items are numbered in arrival order: compare by what they are.
    let name = |table: &streamer::client::ItemTable, item: usize| {
        let it = &table.items[item];
        (it.viewpoint, it.tile, it.background)
    };
    let lists = |table: &streamer::client::ItemTable| -> Vec<Vec<_>> {
        table
            .segment_ach
            .iter()
            .map(|l| l.iter().map(|&(i, a)| (name(table, i), a)).collect())
            .collect()
    };
    assert_eq!(lists(&grown), lists(&whole));
    let _ = std::fs::remove_dir_all(dir);
}

/// The index's pieces of the database in `dir`: their bytes, their number, and the levels of
/// the tree they fill (a round trip each).
fn index_cost(dir: &Path) -> (u64, u64, u64) {
    let (root, _) = db::read_root(dir).unwrap();
    let levels = root.index.levels as u64 + u64::from(root.index.root.is_some());
    let (_, refs) = db::read_index(dir, root).unwrap();
    (refs.iter().map(|r| r.size).sum(), refs.len() as u64, levels)
}

#[tokio::test]
async fn site_files_travel_gzipped_to_clients_that_accept_it() {
    let (dir, _) = temp_db("site-gzip");
    const BODY: &str = "export const X = 1;\n// padding that compresses well: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\n";
    static SITE: &[server::SiteFile] = &[
        server::SiteFile {
            name: "index.html",
            body: "<!doctype html>",
        },
        server::SiteFile {
            name: "main.js",
            body: BODY,
        },
    ];
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let config = ServerConfig {
        site: SITE,
        ..ServerConfig::default()
    };
    tokio::spawn(server::run(
        listener,
        ServedDb::open(&dir).unwrap(),
        config,
        Arc::new(ServerStats::default()),
        async {
            let _ = rx.await;
        },
    ));
    let (status, h, body) = raw_get(addr, "/main.js", "Accept-Encoding: gzip, br\r\n").await;
    assert_eq!(status, 200);
    assert_eq!(header(&h, "content-encoding"), Some("gzip"));
    assert_eq!(header(&h, "vary"), Some("accept-encoding"));
    assert!(body.len() < BODY.len());
    assert_eq!(gunzip_limited(&body, 1 << 20).unwrap(), BODY.as_bytes());
    for extra in [
        "",
        "Accept-Encoding: gzip;q=0\r\n",
        "Accept-Encoding: br\r\n",
    ] {
        let (status, h, body) = raw_get(addr, "/main.js", extra).await;
        assert_eq!(status, 200);
        assert_eq!(header(&h, "content-encoding"), None, "{extra}");
        assert_eq!(body, BODY.as_bytes(), "{extra}");
    }
    // A file gzip would not make smaller goes as it is, with no Vary.
    let (_, h, body) = raw_get(addr, "/", "Accept-Encoding: gzip\r\n").await;
    assert_eq!(header(&h, "content-encoding"), None);
    assert_eq!(header(&h, "vary"), None);
    assert_eq!(body, b"<!doctype html>");
    let _ = tx.send(());
    let _ = std::fs::remove_dir_all(dir);
}
