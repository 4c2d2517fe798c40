//! Real static hosts and caches in front of railview: nginx on loopback serving a database
//! with the README's own configuration, walked by the client (the viewer's scheduler, in the
//! walk simulator) and compared with `railview serve` with and without `/bundle`; and nginx's
//! `proxy_cache` in front of `railview serve`, a second client served from the cache (ETag,
//! `immutable`, ranges from the cache).
//!
//! Needs nginx (`scripts/test.sh` installs it; the tests start it themselves, unprivileged,
//! on a free loopback port). `RAILVIEW_SKIP_NGINX_TESTS=1` marks these tests ignored.

mod common;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;

use common::nginx::{get, readme_server_block, Nginx};
use common::{railview, scratch_dir, stderr};
use streamer::client::ServerUrl;
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::{self, RunReport, Strategy, WalkConfig};

/// A small castle database (five viewpoints over 12 m, faces of 64 px).
fn castle(dir: &Path) -> PathBuf {
    let track = dir.join("short.toml");
    std::fs::write(
        &track,
        "[[track]]\nname = \"short\"\npoints = [[0, 1.7, 42], [0, 1.7, 30]]\ncount = 5\n",
    )
    .unwrap();
    let db = dir.join("db");
    let o = railview(&[
        "build",
        "--scene",
        "castle",
        "--track",
        track.to_str().unwrap(),
        "--face-size",
        "64",
        "--zstd-level",
        "3",
        "--out",
        db.to_str().unwrap(),
        "--work",
        dir.join("work").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    db
}

/// `railview serve` on its own runtime thread.
struct Serve {
    addr: SocketAddr,
    stats: Arc<ServerStats>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Serve {
    fn start(db: &Path, bundles: bool) -> Serve {
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let stats = Arc::new(ServerStats::default());
        let (db, st) = (db.to_path_buf(), stats.clone());
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async move {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
                addr_tx.send(listener.local_addr().unwrap()).unwrap();
                let config = ServerConfig {
                    bundles,
                    ..ServerConfig::default()
                };
                server::run(listener, ServedDb::open(&db).unwrap(), config, st, async {
                    let _ = stop_rx.await;
                })
                .await
                .unwrap();
            });
        });
        Serve {
            addr: addr_rx.recv().unwrap(),
            stats,
            stop: Some(stop_tx),
            thread: Some(thread),
        }
    }

    fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    fn requests(&self) -> u64 {
        self.stats.requests.load(Ordering::Relaxed)
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn walk_config() -> WalkConfig {
    WalkConfig {
        speed_mps: 2.0,
        latency_s: 0.05,
        frame_dt_s: 0.1,
        pause_s: 1.0,
        screen_width: 640,
        screen_height: 360,
        samples_x: 32,
        samples_y: 18,
        ..WalkConfig::default()
    }
}

/// Walks `visibility+prefetch` at 2 Mbit/s and unlimited, 50 ms, over `url`.
fn walk_over(url: &str) -> Vec<RunReport> {
    let url = ServerUrl::parse(url).unwrap();
    let strategies = [Strategy::parse("visibility+prefetch").unwrap()];
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(walk::run_walk(
        &url,
        &walk_config(),
        &strategies,
        &[Some(2_000_000), None],
        |_| {},
    ))
    .unwrap()
    .runs
}

#[test]
#[cfg_attr(
    railview_skip_nginx,
    ignore = "RAILVIEW_SKIP_NGINX_TESTS=1: the nginx tests are switched off"
)]
fn nginx_with_the_readme_configuration_streams_as_well_as_railview_serve() {
    let dir = scratch_dir("static-hosts", "nginx");
    let db = castle(&dir);
    let www = dir.join("www");
    std::fs::create_dir_all(&www).unwrap();
    std::os::unix::fs::symlink(&db, www.join("castle")).unwrap();
    let ngx = Nginx::start(&dir.join("nginx"), |port| readme_server_block(&www, port));

    // The README's configuration does what it says.
    let m = get(
        ngx.port,
        "/castle/manifest.json",
        &[("Accept-Encoding", "gzip")],
    );
    assert_eq!(m.status, 200, "{}", ngx.errors());
    assert_eq!(m.header("content-encoding"), Some("gzip"), "gzip_static");
    assert_eq!(m.header("cache-control"), Some("no-cache"));
    let top = db::read_top(&db).unwrap();
    let table = &top.viewpoints[0].table;
    let path = format!(
        "/castle/{}",
        tracks::manifest::object_rel_path(&table.hash).unwrap()
    );
    let o = get(ngx.port, &path, &[("Range", "bytes=0-9,20-29")]);
    assert_eq!(o.status, 206);
    assert!(o
        .header("content-type")
        .is_some_and(|t| t.starts_with("multipart/byteranges")));
    assert!(o
        .header("cache-control")
        .is_some_and(|c| c.contains("immutable")));

    // The same walk over nginx, railview serve and railview serve without /bundle.
    let nginx = walk_over(&ngx.url("/castle"));
    let served = Serve::start(&db, true);
    let serve = walk_over(&served.url());
    drop(served);
    let plain = Serve::start(&db, false);
    let no_bundles = walk_over(&plain.url());
    drop(plain);
    for (name, runs) in [("nginx", &nginx), ("serve --no-bundles", &no_bundles)] {
        for (r, base) in runs.iter().zip(&serve) {
            let bw = r.bandwidth_bps.map_or("unlimited".into(), walk::format_bps);
            eprintln!(
                "{name} at {bw}: needed {:.3} (serve {:.3}), first frame {:?} (serve {:?}), {} requests (serve {})",
                r.mean_needed_fraction,
                base.mean_needed_fraction,
                r.time_to_first_frame_s,
                base.time_to_first_frame_s,
                r.requests,
                base.requests
            );
            assert_eq!(r.checksum_failures, 0);
            assert!(
                r.mean_needed_fraction >= 0.95 * base.mean_needed_fraction,
                "{name} at {bw}: needed fraction {} against {}",
                r.mean_needed_fraction,
                base.mean_needed_fraction
            );
            let (first, base_first) = (
                r.time_to_first_frame_s.expect("a first frame"),
                base.time_to_first_frame_s.expect("a first frame"),
            );
            assert!(
                first <= 1.5 * base_first,
                "{name} at {bw}: first frame at {first} s against {base_first} s"
            );
        }
    }
    drop(ngx);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
#[cfg_attr(
    railview_skip_nginx,
    ignore = "RAILVIEW_SKIP_NGINX_TESTS=1: the nginx tests are switched off"
)]
fn a_caching_proxy_serves_the_second_client_from_its_cache() {
    let dir = scratch_dir("static-hosts", "proxy");
    let db = castle(&dir);
    let origin = Serve::start(&db, true);
    let cache = dir.join("nginx").join("temp").join("cache");
    let upstream = origin.addr;
    let ngx = Nginx::start(&dir.join("nginx"), |port| {
        format!(
            "proxy_cache_path {cache} levels=1:2 keys_zone=railview:8m max_size=256m \
             inactive=1d use_temp_path=off;\n\
             server {{\n\
                 listen 127.0.0.1:{port};\n\
                 location / {{\n\
                     proxy_pass http://{upstream};\n\
                     proxy_http_version 1.1;\n\
                     proxy_set_header Connection \"\";\n\
                     proxy_cache railview;\n\
                     proxy_cache_key $request_uri;\n\
                     add_header X-Cache-Status $upstream_cache_status always;\n\
                 }}\n\
             }}\n",
            cache = cache.display()
        )
    });

    // First client: everything comes from railview serve, and is cached on the way.
    let first = walk_over(&ngx.url(""));
    let after_first = origin.requests();
    assert!(after_first > 0);
    // Second client, the same walk: railview serve sees only the manifest again (it is
    // `no-cache`); objects, ranges and bundles come from the cache.
    let second = walk_over(&ngx.url(""));
    let origin_second = origin.requests() - after_first;
    eprintln!(
        "origin requests: first client {after_first}, second {origin_second}; client requests {} and {}",
        first.iter().map(|r| r.requests).sum::<u64>(),
        second.iter().map(|r| r.requests).sum::<u64>()
    );
    for (a, b) in first.iter().zip(&second) {
        assert_eq!(a.mean_needed_fraction, b.mean_needed_fraction);
        assert_eq!(a.bytes, b.bytes);
    }
    // Each walk fetches the manifest and its checksum file twice (once for the walker's
    // eyes, once per run): nothing else reaches the origin.
    assert!(
        origin_second <= 3 * 2 * (second.len() as u64 + 1),
        "the origin served {origin_second} requests to the second client"
    );

    // What a CDN needs, through the cache: the origin's ETag and `immutable`, a hit,
    // conditional requests and ranges answered from the cache.
    let top = db::read_top(&db).unwrap();
    let table = &top.viewpoints[1].table;
    let path = format!(
        "/{}",
        tracks::manifest::object_rel_path(&table.hash).unwrap()
    );
    let whole = get(ngx.port, &path, &[]);
    assert_eq!(whole.status, 200);
    assert_eq!(whole.header("x-cache-status"), Some("HIT"));
    assert_eq!(
        whole.header("etag"),
        Some(format!("\"{}\"", table.hash).as_str())
    );
    assert!(whole
        .header("cache-control")
        .is_some_and(|c| c.contains("immutable")));
    let before = origin.requests();
    let range = get(ngx.port, &path, &[("Range", "bytes=4-19")]);
    assert_eq!(range.status, 206);
    assert_eq!(range.header("x-cache-status"), Some("HIT"));
    assert_eq!(range.body, whole.body[4..20]);
    let multi = get(ngx.port, &path, &[("Range", "bytes=0-3,10-13")]);
    assert_eq!(multi.status, 206);
    assert!(multi
        .header("content-type")
        .is_some_and(|t| t.starts_with("multipart/byteranges")));
    let etag = format!("\"{}\"", table.hash);
    let cond = get(ngx.port, &path, &[("If-None-Match", etag.as_str())]);
    assert_eq!(cond.status, 304);
    assert_eq!(
        origin.requests(),
        before,
        "ranges and revalidation from the cache"
    );
    drop(ngx);
    drop(origin);
    let _ = std::fs::remove_dir_all(dir);
}
