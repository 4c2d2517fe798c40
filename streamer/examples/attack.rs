//! Hostile clients against a database server, for the attack benchmark
//! (`scripts/bench-attack.sh`): slow header senders and stalled readers of a large
//! `/bundle` ([`streamer::hostile`]), spread over loopback addresses.
//!
//! ```text
//! cargo run --release -p streamer --example attack -- \
//!     --target 127.0.0.1:8080 --db castle-db --slow 400 --stalled 256 --sources 16 --seconds 30
//! cargo run --release -p streamer --example attack -- --paths castle-db 2000 > paths.txt
//! ```
//!
//! The stalled readers ask for a bundle naming the database's largest object over and over,
//! up to `--bundle-mb` (default 8 MiB). `--paths DB N` prints N level-group requests of DB
//! (`PATH RANGE` per line) for `scripts/wrk-paths.lua` and exits.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use streamer::client::ItemTable;
use streamer::hostile::{loopback_sources, Attack, AttackConfig};

fn usage() -> ! {
    eprintln!(
        "usage: attack --target HOST:PORT --db DIR [--slow N] [--stalled N] [--sources N] \
         [--seconds S] [--bundle-mb M]\n       attack --paths DIR N"
    );
    std::process::exit(2)
}

fn largest_object(db: &Path) -> std::io::Result<(String, u64)> {
    let mut best = (String::new(), 0);
    for sub in std::fs::read_dir(db.join("objects"))? {
        for f in std::fs::read_dir(sub?.path())? {
            let f = f?;
            let len = f.metadata()?.len();
            let name = f.file_name().to_string_lossy().into_owned();
            if len > best.1 && !name.starts_with('.') {
                best = (name, len);
            }
        }
    }
    Ok(best)
}

/// `n` level-group requests of track 0 (`/objects/HH/HASH bytes=A-B`), spread over it.
fn print_paths(db: &Path, n: usize) -> Result<(), String> {
    let d = db::Database::open(db).map_err(|e| e.to_string())?;
    let table = ItemTable::new(d.manifest()).map_err(|e| e.to_string())?;
    let parts: Vec<_> = table.items.iter().flat_map(|i| i.parts.iter()).collect();
    if parts.is_empty() {
        return Err("no parts in track 0".into());
    }
    let step = (parts.len() / n.max(1)).max(1);
    for p in parts.iter().step_by(step).take(n) {
        let rel = tracks::manifest::object_rel_path(&p.key.object).ok_or("bad object id")?;
        match p.key.range {
            Some((off, len)) => println!("/{rel} bytes={off}-{}", off + len - 1),
            None => println!("/{rel} bytes=0-"),
        }
    }
    Ok(())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let get = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .map(|i| args.get(i + 1).cloned().unwrap_or_else(|| usage()))
    };
    if let Some(db) = get("--paths") {
        let n = args
            .iter()
            .position(|a| a == "--paths")
            .and_then(|i| args.get(i + 2))
            .and_then(|n| n.parse().ok())
            .unwrap_or(1000);
        if let Err(e) = print_paths(Path::new(&db), n) {
            eprintln!("error: {db}: {e}");
            std::process::exit(1);
        }
        return;
    }
    let num = |name: &str, default: f64| -> f64 {
        get(name).map_or(default, |v| {
            v.parse().unwrap_or_else(|_| {
                eprintln!("error: {name} {v}: not a number");
                std::process::exit(2)
            })
        })
    };
    let target: SocketAddr = get("--target")
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| usage());
    let db = PathBuf::from(get("--db").unwrap_or_else(|| usage()));
    let (hash, size) = largest_object(&db).unwrap_or_else(|e| {
        eprintln!("error: {}: {e}", db.display());
        std::process::exit(1)
    });
    let bundle_bytes = num("--bundle-mb", 8.0) * 1048576.0;
    let copies = ((bundle_bytes / size.max(1) as f64) as usize).clamp(1, 256);
    let config = AttackConfig {
        target,
        slow: num("--slow", 400.0) as usize,
        stalled: num("--stalled", 256.0) as usize,
        stalled_path: format!("/bundle?p={}", vec![hash.as_str(); copies].join(",")),
        sources: loopback_sources(num("--sources", 16.0) as usize),
        ..AttackConfig::default()
    };
    let seconds = num("--seconds", 30.0);
    eprintln!(
        "attack: {} slow header senders, {} stalled readers of a {:.1} MiB bundle, from {} addresses, {seconds} s",
        config.slow,
        config.stalled,
        (copies as u64 * size) as f64 / 1048576.0,
        config.sources.len()
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let report = rt.block_on(async {
        let attack = Attack::start(config);
        tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
        attack.stop().await
    });
    eprintln!("attack over: {report:?}");
}
