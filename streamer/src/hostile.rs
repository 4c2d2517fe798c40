//! Hostile clients, for the server's tests and the attack benchmark: what a server on the
//! open internet meets and must survive without starving its other clients.
//!
//! - *slow header senders* open a connection, send the start of a request head and then one
//!   byte every `slow_interval`, never finishing it; when the server closes the connection
//!   they open another after `reconnect_pause`;
//! - *stalled readers* ask for `stalled_path` (a large `/bundle`, say) and never read the
//!   response; every half second they send one more byte, which fails once the server has
//!   closed the connection, and then they open another.
//!
//! Connections are spread over `sources` (local addresses to connect from: on Linux every
//! `127.x.y.z` is loopback, so one machine can play many peers).
//!
//! ```no_run
//! # async fn f() {
//! use streamer::hostile::{Attack, AttackConfig};
//! let attack = Attack::start(AttackConfig {
//!     target: "127.0.0.1:8080".parse().unwrap(),
//!     slow: 400,
//!     stalled: 256,
//!     stalled_path: "/manifest.json".into(),
//!     ..AttackConfig::default()
//! });
//! tokio::time::sleep(std::time::Duration::from_secs(10)).await;
//! println!("{:?}", attack.stop().await);
//! # }
//! ```

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::AsyncWriteExt;
use tokio::net::{TcpSocket, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinSet;

/// What to attack and how.
#[derive(Clone, Debug)]
pub struct AttackConfig {
    pub target: SocketAddr,
    /// Slow header senders.
    pub slow: usize,
    /// Stalled readers.
    pub stalled: usize,
    /// Path (and query) the stalled readers ask for.
    pub stalled_path: String,
    /// A slow sender's pause between header bytes.
    pub slow_interval: Duration,
    /// Pause before a closed connection is opened again.
    pub reconnect_pause: Duration,
    /// Local addresses to connect from, round robin (empty: the system's choice).
    pub sources: Vec<IpAddr>,
    /// Receive buffer of the stalled readers, bytes (`None`: the system's, which on Linux
    /// grows to megabytes; a small one keeps the server's writes blocked instead of the
    /// kernel taking the response off its hands).
    pub stalled_recv_buffer: Option<u32>,
}

impl Default for AttackConfig {
    fn default() -> Self {
        AttackConfig {
            target: SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 8080),
            slow: 0,
            stalled: 0,
            stalled_path: "/manifest.json".into(),
            slow_interval: Duration::from_millis(500),
            reconnect_pause: Duration::from_millis(100),
            sources: Vec::new(),
            stalled_recv_buffer: Some(16 << 10),
        }
    }
}

/// `n` loopback addresses from `127.0.0.2` on (one machine playing `n` peers).
pub fn loopback_sources(n: usize) -> Vec<IpAddr> {
    (0..n as u32)
        .map(|i| {
            let k = i + 2;
            IpAddr::V4(Ipv4Addr::new(127, (k >> 16) as u8, (k >> 8) as u8, k as u8))
        })
        .collect()
}

/// What the attackers saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AttackReport {
    /// Connections opened, and attempts that failed.
    pub connects: u64,
    pub connect_errors: u64,
    /// Connections the server closed (or refused after accepting).
    pub closed_by_server: u64,
}

#[derive(Default)]
struct Counters {
    connects: AtomicU64,
    connect_errors: AtomicU64,
    closed: AtomicU64,
}

/// Running attackers; [`Attack::stop`] ends them.
pub struct Attack {
    stop: watch::Sender<bool>,
    tasks: JoinSet<()>,
    counters: Arc<Counters>,
}

impl Attack {
    /// Start the attackers on the current tokio runtime.
    pub fn start(config: AttackConfig) -> Attack {
        let (stop, stop_rx) = watch::channel(false);
        let counters = Arc::new(Counters::default());
        let mut tasks = JoinSet::new();
        let config = Arc::new(config);
        for i in 0..config.slow + config.stalled {
            let source =
                (!config.sources.is_empty()).then(|| config.sources[i % config.sources.len()]);
            let stalled = i >= config.slow;
            let (config, counters, stop) = (config.clone(), counters.clone(), stop_rx.clone());
            tasks.spawn(async move {
                let mut stop = stop;
                // Spread the first connections over the first interval.
                let first = config.slow_interval.mul_f64((i % 97) as f64 / 97.0);
                tokio::select! {
                    _ = tokio::time::sleep(first) => {}
                    _ = stop.wait_for(|s| *s) => return,
                }
                loop {
                    let run = attacker(&config, source, stalled, &counters);
                    tokio::select! {
                        _ = run => {}
                        _ = stop.wait_for(|s| *s) => return,
                    }
                    tokio::select! {
                        _ = tokio::time::sleep(config.reconnect_pause) => {}
                        _ = stop.wait_for(|s| *s) => return,
                    }
                }
            });
        }
        Attack {
            stop,
            tasks,
            counters,
        }
    }

    /// What the attackers saw so far.
    pub fn report(&self) -> AttackReport {
        AttackReport {
            connects: self.counters.connects.load(Relaxed),
            connect_errors: self.counters.connect_errors.load(Relaxed),
            closed_by_server: self.counters.closed.load(Relaxed),
        }
    }

    /// Stop every attacker and close their connections.
    pub async fn stop(mut self) -> AttackReport {
        let _ = self.stop.send(true);
        while self.tasks.join_next().await.is_some() {}
        self.report()
    }
}

async fn connect(
    target: SocketAddr,
    source: Option<IpAddr>,
    recv_buffer: Option<u32>,
) -> std::io::Result<TcpStream> {
    let socket = if target.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    if let Some(n) = recv_buffer {
        socket.set_recv_buffer_size(n)?;
    }
    if let Some(ip) = source {
        socket.bind(SocketAddr::new(ip, 0))?;
    }
    tokio::time::timeout(Duration::from_secs(5), socket.connect(target))
        .await
        .map_err(|_| std::io::Error::from(std::io::ErrorKind::TimedOut))?
}

/// One connection of one attacker, until the server closes it.
async fn attacker(config: &AttackConfig, source: Option<IpAddr>, stalled: bool, c: &Counters) {
    let recv_buffer = config.stalled_recv_buffer.filter(|_| stalled);
    let mut stream = match connect(config.target, source, recv_buffer).await {
        Ok(s) => s,
        Err(_) => {
            c.connect_errors.fetch_add(1, Relaxed);
            return;
        }
    };
    c.connects.fetch_add(1, Relaxed);
    let head = if stalled {
        format!(
            "GET {} HTTP/1.1\r\nHost: x\r\n\r\nGET /manifest.json HTTP/1.1\r\nX-Wait: ",
            config.stalled_path
        )
    } else {
        "GET /manifest.json HTTP/1.1\r\nHost: x\r\nX-Slow: ".to_string()
    };
    let interval = if stalled {
        Duration::from_millis(500)
    } else {
        config.slow_interval
    };
    if stream.write_all(head.as_bytes()).await.is_err() {
        c.closed.fetch_add(1, Relaxed);
        return;
    }
    // One more byte per interval: a write fails once the server has closed the connection
    // (the response, if any, is never read).
    loop {
        tokio::time::sleep(interval).await;
        let wrote = tokio::time::timeout(Duration::from_secs(5), stream.write_all(b"a")).await;
        if !matches!(wrote, Ok(Ok(()))) {
            c.closed.fetch_add(1, Relaxed);
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_sources_are_distinct_and_skip_the_usual_address() {
        let s = loopback_sources(300);
        assert_eq!(s[0], "127.0.0.2".parse::<IpAddr>().unwrap());
        assert_eq!(s[299], "127.0.1.45".parse::<IpAddr>().unwrap());
        let set: std::collections::HashSet<_> = s.iter().collect();
        assert_eq!(set.len(), 300);
    }
}
