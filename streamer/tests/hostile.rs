//! The server against hostile and broken clients over loopback: heads sent a byte at a
//! time, readers that stop or drip, more connections than the limits allow. Each test runs
//! a few seconds at most. (`tests/cli_serve.rs` runs the full attack against the binary.)

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use streamer::client::{ClientStats, Connection, ItemTable, RetryPolicy, ServerUrl};
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::synth;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio::sync::oneshot;
use tracks::manifest::Manifest;

fn temp_db(name: &str, params: &synth::SynthParams) -> (PathBuf, Manifest) {
    let dir = std::env::temp_dir().join(format!("railview-hostile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let m = synth::write_synthetic(&dir, params).expect("synthetic database");
    (dir, m)
}

/// Bigger packs than the default synthetic database: a bundle of a few is megabytes.
fn big_params() -> synth::SynthParams {
    synth::SynthParams {
        face_size: 128,
        tile_size: 32,
        bytes_per_texel: 4.0,
        ..synth::SynthParams::default()
    }
}

struct Running {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), server::ServerError>>,
    stats: Arc<ServerStats>,
}

impl Running {
    async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        self.task.await.unwrap().unwrap();
    }
}

async fn start(dir: &Path, config: ServerConfig) -> Running {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
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

/// The largest object of a database and its size.
fn largest_object(dir: &Path) -> (String, u64) {
    let mut best = (String::new(), 0);
    for sub in std::fs::read_dir(dir.join("objects")).unwrap() {
        for f in std::fs::read_dir(sub.unwrap().path()).unwrap() {
            let f = f.unwrap();
            let len = f.metadata().unwrap().len();
            if len > best.1 {
                best = (f.file_name().to_string_lossy().into_owned(), len);
            }
        }
    }
    best
}

/// A connection with a small receive buffer (16 KiB, no autotuning): a client that reads
/// slowly then holds the server's writes, instead of the kernel taking megabytes for it.
async fn connect_small_window(to: SocketAddr) -> TcpStream {
    let s = TcpSocket::new_v4().unwrap();
    s.set_recv_buffer_size(16 << 10).unwrap();
    s.connect(to).await.unwrap()
}

async fn connect_from(ip: &str, to: SocketAddr) -> TcpStream {
    let s = TcpSocket::new_v4().unwrap();
    s.bind(SocketAddr::new(ip.parse::<IpAddr>().unwrap(), 0))
        .unwrap();
    s.connect(to).await.unwrap()
}

/// Whether the server closed `s` within `within` (reads hit EOF or an error).
async fn closed_within(s: &mut TcpStream, within: Duration) -> bool {
    let mut buf = vec![0u8; 64 << 10];
    let until = Instant::now() + within;
    loop {
        let left = until.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, s.read(&mut buf)).await {
            Err(_) => return false,
            Ok(Ok(0)) | Ok(Err(_)) => return true,
            Ok(Ok(_)) => {}
        }
    }
}

/// One level group of the database, fetched and checked on a new connection: how long it
/// took.
async fn normal_fetch(addr: SocketAddr, m: &Manifest) -> Duration {
    let table = ItemTable::new(m).unwrap();
    let part = table.items[0].parts.last().unwrap().clone();
    let url = ServerUrl::parse(&format!("http://{addr}")).unwrap();
    let mut c = Connection::new(
        url,
        RetryPolicy::default(),
        Arc::new(ClientStats::default()),
    );
    let t0 = Instant::now();
    c.fetch_checked(&part.key, &part.hash, None)
        .await
        .expect("a normal client is served");
    t0.elapsed()
}

/// Regression: the request-head clock starts at its first byte and is never extended, so a
/// client that sends a byte every 100 ms is cut off at the header timeout.
#[tokio::test]
async fn a_head_sent_a_byte_at_a_time_is_cut_off_at_the_header_timeout() {
    let (dir, _) = temp_db("drip-head", &synth::SynthParams::default());
    let config = ServerConfig {
        header_timeout: Duration::from_millis(500),
        ..ServerConfig::default()
    };
    let srv = start(&dir, config).await;
    let mut s = TcpStream::connect(srv.addr).await.unwrap();
    let t0 = Instant::now();
    s.write_all(b"GET /manifest.json HTTP/1.1\r\n")
        .await
        .unwrap();
    let mut closed = false;
    for _ in 0..30 {
        tokio::time::sleep(Duration::from_millis(100)).await;
        if s.write_all(b"X").await.is_err() {
            closed = true;
            break;
        }
    }
    closed = closed || closed_within(&mut s, Duration::from_millis(100)).await;
    assert!(closed, "still open after {:?}", t0.elapsed());
    assert!(
        t0.elapsed() < Duration::from_millis(1500),
        "{:?}",
        t0.elapsed()
    );
    assert_eq!(srv.stats.header_timeouts.load(Ordering::Relaxed), 1);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

/// A client that asks for a large bundle and never reads is closed after the write timeout,
/// and so is one that reads a trickle (or for being slower than the minimum rate); meanwhile
/// the others are served. The bundle streams from the files, so neither makes the server hold
/// the bundle.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readers_that_stop_or_drip_are_closed_and_the_rest_are_served() {
    let (dir, m) = temp_db("stall", &big_params());
    let (hash, size) = largest_object(&dir);
    let k = ((8 << 20) / size).clamp(2, 64);
    let config = ServerConfig {
        write_timeout: Duration::from_millis(600),
        min_send_rate: 200_000,
        ..ServerConfig::default()
    };
    let srv = start(&dir, config).await;
    let path = format!("/bundle?p={}", vec![hash.as_str(); k as usize].join(","));
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
    let mut stalled = connect_small_window(srv.addr).await;
    stalled.write_all(request.as_bytes()).await.unwrap();
    let mut drip = connect_small_window(srv.addr).await;
    drip.write_all(request.as_bytes()).await.unwrap();
    let dripper = tokio::spawn(async move {
        // 4 KiB every 100 ms: 40 kB/s, a fifth of the minimum rate.
        let mut buf = vec![0u8; 4096];
        let t0 = Instant::now();
        let mut got = 0u64;
        while t0.elapsed() < Duration::from_secs(8) {
            match drip.read(&mut buf).await {
                Ok(0) | Err(_) => return (got, t0.elapsed()),
                Ok(n) => got += n as u64,
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        (got, t0.elapsed())
    });
    // Others are served meanwhile.
    for _ in 0..3 {
        let t = normal_fetch(srv.addr, &m).await;
        assert!(t < Duration::from_secs(1), "normal request took {t:?}");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    let (got, after) = dripper.await.unwrap();
    assert!(got < size * k, "the dripping reader got everything");
    assert!(
        after < Duration::from_secs(6),
        "dripping reader open for {after:?}"
    );
    // The stalled reader was closed: what it can still read is what the sockets held.
    assert!(closed_within(&mut stalled, Duration::from_secs(3)).await);
    // Each closed by the write timeout or the minimum rate, whichever came first (a drip
    // this slow rarely unblocks the socket at all: the kernel wakes a writer only once a
    // third of its buffer is free).
    let closed = srv.stats.write_timeouts.load(Ordering::Relaxed)
        + srv.stats.too_slow.load(Ordering::Relaxed);
    assert!(closed >= 2, "{}", srv.stats.summary());
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

/// At a peer's limit its own idle connection makes room; at the server's limit with only
/// connections too young to take, a newcomer gets 503; nothing blocks the accept loop.
#[tokio::test]
async fn beyond_the_limits_idle_connections_give_way_or_the_newcomer_gets_503() {
    let (dir, m) = temp_db("admit", &synth::SynthParams::default());
    let config = ServerConfig {
        max_connections: 4,
        max_connections_per_peer: 2,
        ..ServerConfig::default()
    };
    let srv = start(&dir, config).await;
    // Four young idle connections fill the server; a fifth finds nothing old enough to take
    // (a client that just connected always gets to send its request) and is answered 503.
    let mut a1 = connect_from("127.0.0.2", srv.addr).await;
    let mut a2 = connect_from("127.0.0.2", srv.addr).await;
    let _b1 = connect_from("127.0.0.3", srv.addr).await;
    let _b2 = connect_from("127.0.0.3", srv.addr).await;
    let mut c = connect_from("127.0.0.4", srv.addr).await;
    let mut text = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(2), c.read_to_end(&mut text)).await;
    let text = String::from_utf8_lossy(&text);
    assert!(text.starts_with("HTTP/1.1 503"), "{text}");
    assert!(srv.stats.refused.load(Ordering::Relaxed) >= 1);
    // Later, a third connection from a peer at its limit takes the place of one of its own.
    tokio::time::sleep(Duration::from_millis(400)).await;
    let _a3 = connect_from("127.0.0.2", srv.addr).await;
    let (one, two) = tokio::join!(
        closed_within(&mut a1, Duration::from_secs(1)),
        closed_within(&mut a2, Duration::from_secs(1))
    );
    assert!(
        one != two,
        "exactly one of the peer's connections gives way"
    );
    assert!(srv.stats.evicted.load(Ordering::Relaxed) >= 1);
    // Once they have aged, a normal client takes an idle stranger's place.
    tokio::time::sleep(Duration::from_millis(400)).await;
    let t = normal_fetch(srv.addr, &m).await;
    assert!(t < Duration::from_secs(1), "{t:?}");
    assert!(srv.stats.peak_open.load(Ordering::Relaxed) <= 4);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}
