//! `railview serve` under attack, as a hostile but fair tester runs it: 400 connections that
//! send their request heads a byte at a time and reconnect when closed, and 256 that ask
//! for a multi-megabyte `/bundle` naming the largest object over and over and never read
//! the answer, from 16 loopback addresses, against the server's default limits. A normal
//! client must be served within a second throughout, and the server's memory must stay
//! bounded. About ten seconds.

mod common;

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::scratch_dir;
use streamer::client::{ClientStats, Connection, ItemTable, RetryPolicy, ServerUrl};
use streamer::hostile::{loopback_sources, Attack, AttackConfig};
use streamer::walk::synth;

/// Peak resident memory the server may reach under the attack. The attack asks for 256 ×
/// 8 MiB of bundles that are never read: a server that assembled responses in memory would
/// hold 2 GiB. Streamed, each connection holds a 32 KiB chunk and its write buffer.
const MAX_SERVER_RSS_MIB: u64 = 128;

struct Server {
    child: Child,
    addr: SocketAddr,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn serve(db: &Path, extra: &[&str]) -> Server {
    let mut child = Command::new(env!("CARGO_BIN_EXE_railview"))
        .args(["serve", db.to_str().unwrap(), "--addr", "127.0.0.1:0"])
        .args(extra)
        .stderr(Stdio::piped())
        .spawn()
        .expect("start railview serve");
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let line = lines
        .next()
        .expect("serve prints its address")
        .expect("read serve's output");
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|a| a.split_whitespace().next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("no address in `{line}`"));
    // Keep draining its output so it never blocks on a full pipe.
    std::thread::spawn(move || for _ in lines {});
    Server { child, addr }
}

/// `VmHWM` (peak resident set) of a process, KiB.
fn peak_rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

fn largest_object(db: &Path) -> (String, u64) {
    let mut best = (String::new(), 0);
    for sub in std::fs::read_dir(db.join("objects")).unwrap() {
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

#[test]
fn a_normal_client_is_served_within_a_second_while_400_slow_and_256_stalled_clients_attack() {
    let dir = scratch_dir("serve", "attack");
    let db = dir.join("db");
    let params = synth::SynthParams {
        face_size: 128,
        tile_size: 32,
        bytes_per_texel: 4.0,
        ..synth::SynthParams::default()
    };
    let m = synth::write_synthetic(&db, &params).unwrap();
    let (hash, size) = largest_object(&db);
    let copies = ((8u64 << 20) / size).clamp(2, 256) as usize;
    let server = serve(&db, &[]);
    let addr = server.addr;
    let table = ItemTable::new(&m).unwrap();
    let parts: Vec<_> = table.items.iter().flat_map(|i| i.parts.clone()).collect();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (times, report) = rt.block_on(async {
        let attack = Attack::start(AttackConfig {
            target: addr,
            slow: 400,
            stalled: 256,
            stalled_path: format!("/bundle?p={}", vec![hash.as_str(); copies].join(",")),
            sources: loopback_sources(16),
            ..AttackConfig::default()
        });
        // Let every attacker connect and the stalled ones fill their sockets.
        tokio::time::sleep(Duration::from_secs(3)).await;
        let url = ServerUrl::parse(&format!("http://{addr}")).unwrap();
        let mut times = Vec::new();
        for k in 0..10 {
            // A new connection each time: admission is what is tested.
            let mut c = Connection::new(
                url.clone(),
                RetryPolicy::default(),
                Arc::new(ClientStats::default()),
            );
            let p = &parts[(k * 37) % parts.len()];
            let t0 = Instant::now();
            let got = tokio::time::timeout(
                Duration::from_secs(20),
                c.fetch_checked(&p.key, &p.hash, None),
            )
            .await;
            times.push(t0.elapsed());
            assert!(
                matches!(got, Ok(Ok(_))),
                "request {k} failed: {got:?} after {:?}",
                t0.elapsed()
            );
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
        let report = attack.stop().await;
        (times, report)
    });
    let rss_mib = peak_rss_kib(server.child.id()) / 1024;
    eprintln!(
        "normal requests under attack: {times:?}; attackers: {report:?}; server peak RSS {rss_mib} MiB"
    );
    assert!(report.connects >= 656, "{report:?}");
    for t in &times {
        assert!(*t < Duration::from_secs(1), "a normal request took {t:?}");
    }
    assert!(
        rss_mib > 0 && rss_mib <= MAX_SERVER_RSS_MIB,
        "server peak RSS {rss_mib} MiB, limit {MAX_SERVER_RSS_MIB} MiB"
    );
    drop(server);
    let _ = std::fs::remove_dir_all(dir);
}
