//! The fetcher's bundles against a real server on loopback: many small keys in few requests,
//! priorities across bundles, corrupted pieces fetched again, cancellation of queued and
//! running keys, and a server without `/bundle`.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use streamer::client::{
    ClientError, FetchKey, FetchOutcome, FetchRequest, Fetcher, FetcherConfig, ItemTable, ServerUrl,
};
use streamer::server::{self, ServedDb, ServerConfig, ServerStats};
use streamer::walk::synth;
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tracks::manifest::Manifest;

fn temp_db(name: &str, params: &synth::SynthParams) -> (PathBuf, Manifest) {
    let dir = std::env::temp_dir().join(format!("railview-fetcher-{name}-{}", std::process::id()));
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

    fn requests(&self) -> u64 {
        self.stats.requests.load(Ordering::Relaxed)
    }

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

/// Every part of the first track (meshes as whole objects, PTM levels as ranges) with its
/// length; priorities descend in table order.
fn all_parts(m: &Manifest) -> Vec<(FetchRequest, Option<u64>)> {
    let table = ItemTable::new(m).unwrap();
    let parts: Vec<_> = table.items.iter().flat_map(|i| i.parts.iter()).collect();
    let n = parts.len();
    parts
        .into_iter()
        .enumerate()
        .map(|(k, p)| {
            (
                FetchRequest {
                    key: p.key.clone(),
                    expected_hash: p.hash.clone(),
                    priority: (n - k) as f64,
                },
                Some(p.bytes),
            )
        })
        .collect()
}

async fn next(f: &mut Fetcher) -> FetchOutcome {
    tokio::time::timeout(Duration::from_secs(20), f.next())
        .await
        .expect("an outcome in time")
        .expect("fetcher running")
}

/// Submit everything, collect one outcome per key; checks the bytes of every success.
async fn fetch_all(f: &mut Fetcher, reqs: &[(FetchRequest, Option<u64>)]) -> Vec<FetchOutcome> {
    f.submit_all(reqs.iter().cloned());
    let mut out = Vec::new();
    while out.len() < reqs.len() {
        let o = next(f).await;
        let (r, _) = reqs.iter().find(|r| r.0.key == o.key).unwrap();
        if let Ok(b) = &o.result {
            assert!(db::hash_matches(b, &r.expected_hash));
        }
        out.push(o);
    }
    assert_eq!(f.pending(), 0);
    out
}

#[tokio::test(flavor = "current_thread")]
async fn many_small_keys_travel_in_few_requests() {
    let (dir, m) = temp_db("few", &synth::SynthParams::default());
    let reqs = all_parts(&m);
    assert!(reqs.len() >= 60, "{} parts", reqs.len());
    // Meshes too: ranges of their viewpoint's pack, like the level groups.
    assert!(reqs.iter().all(|r| r.0.key.range.is_some()));
    let srv = start(&dir, ServerConfig::default()).await;
    let config = FetcherConfig {
        max_in_flight: 2,
        bundle_max_bytes: 1 << 20,
        ..FetcherConfig::default()
    };
    let mut f = Fetcher::new(srv.url(), config.clone());
    let before = srv.requests();
    let out = fetch_all(&mut f, &reqs).await;
    assert!(out.iter().all(|o| o.result.is_ok()));
    let bundled = srv.requests() - before;
    let client = f.stats().requests.load(Ordering::Relaxed);
    let max = reqs.len().div_ceil(config.bundle_max_entries) as u64 + 2;
    assert!(bundled <= max, "{bundled} requests for {} keys", reqs.len());
    assert_eq!(client, bundled);
    // Each outcome names its request; the keys of one request add up to its bytes.
    let mut per_request: std::collections::HashMap<u64, (usize, u64)> = Default::default();
    for o in &out {
        let e = per_request.entry(o.request.id).or_default();
        e.0 += 1;
        e.1 += o.result.as_ref().unwrap().len() as u64;
    }
    for o in &out {
        assert_eq!(
            per_request[&o.request.id],
            (o.request.keys, o.request.bytes)
        );
    }
    assert_eq!(per_request.len() as u64, bundled);
    drop(f);

    // The same keys one request each (bundles off in the config).
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            bundle_max_entries: 1,
            ..config
        },
    );
    assert!(!f.bundles_enabled());
    let before = srv.requests();
    let out = fetch_all(&mut f, &reqs).await;
    assert!(out.iter().all(|o| o.result.is_ok()));
    assert_eq!(srv.requests() - before, reqs.len() as u64);
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "current_thread")]
async fn the_first_bundle_holds_the_top_keys_and_respects_the_byte_limit() {
    let (dir, m) = temp_db("prio", &synth::SynthParams::default());
    let srv = start(&dir, ServerConfig::default()).await;
    // Priorities shuffled against table order (a fixed permutation).
    let mut reqs = all_parts(&m);
    let n = reqs.len();
    for (k, r) in reqs.iter_mut().enumerate() {
        r.0.priority = ((k * 37) % n) as f64;
    }
    let limit = 2000;
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            max_in_flight: 1,
            bundle_max_entries: 8,
            bundle_max_bytes: limit,
            ..FetcherConfig::default()
        },
    );
    assert_eq!(f.bundle_max_bytes(), limit);
    // On a current-thread runtime nothing runs until we await: all are queued first.
    let out = fetch_all(&mut f, &reqs).await;
    let prio = |o: &FetchOutcome| reqs.iter().find(|r| r.0.key == o.key).unwrap().0.priority;
    let order: Vec<f64> = out.iter().map(prio).collect();
    assert!(
        order.windows(2).all(|w| w[0] > w[1]),
        "one worker: highest priority first, across and within bundles: {order:?}"
    );
    let first = out[0].request;
    assert!(first.keys > 1 && first.keys <= 8, "{first:?}");
    let mut ids: Vec<u64> = out.iter().map(|o| o.request.id).collect();
    ids.dedup();
    let requests = ids.len();
    assert!(requests < n, "{requests} requests for {n} keys");
    for id in ids {
        let keys: Vec<&FetchOutcome> = out.iter().filter(|o| o.request.id == id).collect();
        assert!(keys.len() <= 8);
        let bytes = keys[0].request.bytes;
        // Over the limit only when the bundle's first key alone is.
        let first_len = keys[0].result.as_ref().unwrap().len() as u64;
        assert!(
            bytes <= limit || keys.len() == 1 && bytes == first_len,
            "{bytes}"
        );
    }
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "current_thread")]
async fn corrupted_pieces_are_fetched_again_and_never_delivered() {
    let (dir, m) = temp_db("corrupt", &synth::SynthParams::default());
    let reqs = all_parts(&m);
    // Every third response has a flipped byte: bundles are fetched again. One worker, so
    // the server's count of requests does not single out one connection.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(3),
            ..ServerConfig::default()
        },
    )
    .await;
    let config = FetcherConfig {
        max_in_flight: 1,
        bundle_max_entries: 16,
        bundle_max_bytes: 1 << 20,
        ..FetcherConfig::default()
    };
    let mut f = Fetcher::new(srv.url(), config.clone());
    let out = fetch_all(&mut f, &reqs).await;
    for o in &out {
        assert!(o.result.is_ok(), "{:?}", o.result);
    }
    assert!(f.stats().checksum_failures.load(Ordering::Relaxed) > 0);
    assert!(srv.stats.corrupted.load(Ordering::Relaxed) > 0);
    drop(f);
    srv.stop().await;

    // Every response corrupted: each key reports a checksum error, none delivers bytes.
    let srv = start(
        &dir,
        ServerConfig {
            corrupt_every: Some(1),
            ..ServerConfig::default()
        },
    )
    .await;
    let mut f = Fetcher::new(srv.url(), config);
    let few: Vec<_> = reqs
        .iter()
        .filter(|r| r.0.key.range.is_some())
        .take(6)
        .cloned()
        .collect();
    let out = fetch_all(&mut f, &few).await;
    for o in &out {
        assert!(
            matches!(o.result, Err(ClientError::Checksum { .. })),
            "{:?}",
            o.result
        );
    }
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(flavor = "current_thread")]
async fn a_server_without_bundles_serves_one_key_per_request() {
    let (dir, m) = temp_db("static", &synth::SynthParams::default());
    let reqs = all_parts(&m);
    let srv = start(
        &dir,
        ServerConfig {
            bundles: false,
            ..ServerConfig::default()
        },
    )
    .await;
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            max_in_flight: 2,
            bundle_max_bytes: 1 << 20,
            ..FetcherConfig::default()
        },
    );
    assert!(f.bundles_enabled());
    let out = fetch_all(&mut f, &reqs).await;
    assert!(out.iter().all(|o| o.result.is_ok()));
    assert!(!f.bundles_enabled(), "the missing /bundle is remembered");
    // At most one refused bundle per worker; the rest one key (or one level run) each.
    let client = f.stats().requests.load(Ordering::Relaxed);
    assert!(client <= reqs.len() as u64, "{client}");
    assert!(srv.requests() >= client);
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn queued_and_running_keys_of_bundles_can_be_cancelled() {
    let params = synth::SynthParams {
        face_size: 128,
        tile_size: 64,
        ..synth::SynthParams::default()
    };
    let (dir, m) = temp_db("cancel", &params);
    // The 24 largest levels, priorities descending.
    let mut reqs: Vec<_> = all_parts(&m)
        .into_iter()
        .filter(|r| r.0.key.range.is_some())
        .collect();
    reqs.sort_by_key(|r| std::cmp::Reverse(r.1));
    reqs.truncate(24);
    for (k, r) in reqs.iter_mut().enumerate() {
        r.0.priority = (100 - k) as f64;
    }
    // Throttled so that a bundle of 8 takes about 3 s: long enough to cancel within it.
    let bundle: u64 = reqs[..8].iter().map(|r| r.1.unwrap()).sum();
    let throttle_bps = bundle * 8 / 3;
    let srv = start(
        &dir,
        ServerConfig {
            throttle_bps: Some(throttle_bps),
            ..ServerConfig::default()
        },
    )
    .await;
    let mut f = Fetcher::new(
        srv.url(),
        FetcherConfig {
            max_in_flight: 1,
            bundle_max_entries: 8,
            bundle_max_bytes: 1 << 20,
            ..FetcherConfig::default()
        },
    );
    f.submit_all(reqs.iter().cloned());
    tokio::time::sleep(Duration::from_millis(200)).await;
    // The first bundle (the top 8) runs; the rest is queued.
    assert_eq!(f.running(), 8);
    assert_eq!(f.pending(), 24);
    let running: Vec<FetchKey> = reqs[..8].iter().map(|r| r.0.key.clone()).collect();
    assert!(running.iter().all(|k| f.is_pending(k)));
    // Cancel half the running bundle and all of the queue.
    let keep: Vec<FetchKey> = running.iter().step_by(2).cloned().collect();
    f.retain(|k| keep.contains(k));
    assert_eq!(f.pending(), 8, "queued keys dropped at once");
    let mut got = Vec::new();
    for _ in 0..8 {
        got.push(next(&mut f).await);
    }
    for o in &got {
        if keep.contains(&o.key) {
            let r = reqs.iter().find(|r| r.0.key == o.key).unwrap();
            let b = o.result.as_ref().expect("kept keys arrive");
            assert!(db::hash_matches(b, &r.0.expected_hash));
        } else {
            assert!(
                matches!(o.result, Err(ClientError::Cancelled)),
                "{:?}",
                o.result
            );
        }
    }
    assert_eq!(f.pending(), 0);
    // Nothing else was fetched: the queued keys never produce outcomes.
    assert!(f.try_next().is_none());

    // A bundle whose keys are all cancelled is abandoned mid-transfer.
    f.submit_all(reqs[8..16].iter().cloned());
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(f.running(), 8);
    let t0 = std::time::Instant::now();
    f.retain(|_| false);
    for _ in 0..8 {
        let o = next(&mut f).await;
        assert!(
            matches!(o.result, Err(ClientError::Cancelled)),
            "{:?}",
            o.result
        );
    }
    // Well before the rest of the transfer would have arrived.
    let second: u64 = reqs[8..16].iter().map(|r| r.1.unwrap()).sum();
    let transfer_s = (second * 8) as f64 / throttle_bps as f64;
    assert!(transfer_s > 1.0, "{transfer_s}");
    let took = t0.elapsed().as_secs_f64();
    assert!(
        took < (transfer_s - 0.2) / 2.0,
        "{took} s of {transfer_s} s"
    );
    // The worker goes on with the next request.
    f.submit_all(reqs[16..17].iter().cloned());
    let o = next(&mut f).await;
    assert!(o.result.is_ok(), "{:?}", o.result);
    drop(f);
    srv.stop().await;
    let _ = std::fs::remove_dir_all(dir);
}
