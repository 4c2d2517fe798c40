//! Load generator: many simulated clients fetching checked level groups for a bounded time.

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::client::{ClientStats, Connection, ItemTable, Part, RetryPolicy, ServerUrl};

/// What a load run measured.
#[derive(Clone, Debug, Serialize)]
pub struct LoadReport {
    pub clients: usize,
    pub seconds: f64,
    pub requests: u64,
    pub errors: u64,
    pub bytes: u64,
    pub requests_per_s: f64,
    pub mbit_per_s: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

/// Run `clients` concurrent clients against `url` for `duration`; each has its own
/// connection and fetches level groups of track 0 (checked) in a client-specific order.
pub async fn run_load(
    url: &ServerUrl,
    clients: usize,
    duration: Duration,
) -> Result<LoadReport, crate::client::ClientError> {
    let stats = Arc::new(ClientStats::default());
    let mut first = Connection::new(url.clone(), RetryPolicy::default(), stats.clone());
    let manifest = first.manifest().await?;
    let table = ItemTable::new(&manifest)?;
    let parts: Arc<Vec<Part>> = Arc::new(
        table
            .items
            .iter()
            .flat_map(|i| i.parts.iter().cloned())
            .collect(),
    );
    if parts.is_empty() {
        return Err(crate::client::ClientError::Manifest(
            "track 0 has nothing to fetch".into(),
        ));
    }
    let start = Instant::now();
    let deadline = start + duration;
    let mut tasks = tokio::task::JoinSet::new();
    for c in 0..clients.max(1) {
        let parts = parts.clone();
        let url = url.clone();
        let stats = stats.clone();
        tasks.spawn(async move {
            let policy = RetryPolicy {
                attempts: 1,
                ..RetryPolicy::default()
            };
            let mut conn = Connection::new(url, policy, stats);
            let mut lat = Vec::new();
            let mut errors = 0u64;
            let mut bytes = 0u64;
            let mut k = c * 7919;
            while Instant::now() < deadline {
                let p = &parts[k % parts.len()];
                k += 1;
                let t0 = Instant::now();
                match conn.fetch_checked(&p.key, &p.hash, None).await {
                    Ok(b) => {
                        bytes += b.len() as u64;
                        lat.push(t0.elapsed().as_secs_f64() * 1000.0);
                    }
                    Err(e) => {
                        tracing::warn!("load client {c}: {e}");
                        errors += 1;
                    }
                }
            }
            (lat, errors, bytes)
        });
    }
    let mut lat = Vec::new();
    let mut errors = 0;
    let mut bytes = 0;
    while let Some(r) = tasks.join_next().await {
        match r {
            Ok((l, e, b)) => {
                lat.extend(l);
                errors += e;
                bytes += b;
            }
            Err(_) => errors += 1,
        }
    }
    let secs = start.elapsed().as_secs_f64();
    lat.sort_by(f64::total_cmp);
    let pct = |q: f64| -> f64 {
        if lat.is_empty() {
            0.0
        } else {
            lat[((lat.len() - 1) as f64 * q).round() as usize]
        }
    };
    Ok(LoadReport {
        clients,
        seconds: secs,
        requests: lat.len() as u64,
        errors,
        bytes,
        requests_per_s: lat.len() as f64 / secs,
        mbit_per_s: bytes as f64 * 8.0 / secs / 1e6,
        p50_ms: pct(0.5),
        p99_ms: pct(0.99),
        max_ms: lat.last().copied().unwrap_or(0.0),
    })
}
