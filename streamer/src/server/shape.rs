//! Per-connection bandwidth shaping: a token bucket on the write side of a stream.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

/// Largest burst the bucket holds, in seconds of the rate (keeps shaping smooth while still
/// letting a small response leave in one write).
const BURST_S: f64 = 0.05;
/// Smallest burst in bytes, so very low rates still make progress in sensible writes.
const MIN_BURST_BYTES: f64 = 1024.0;

/// A stream whose writes are limited to `rate_bps` bits per second; reads pass through.
pub struct Shaped<S> {
    inner: S,
    /// Bytes per second; `None` = unlimited.
    rate: Option<f64>,
    tokens: f64,
    last: Instant,
    sleep: Option<Pin<Box<Sleep>>>,
}

impl<S> Shaped<S> {
    pub fn new(inner: S, rate_bps: Option<u64>) -> Shaped<S> {
        let rate = rate_bps.filter(|&r| r > 0).map(|r| r as f64 / 8.0);
        Shaped {
            inner,
            rate,
            tokens: rate.map_or(0.0, burst),
            last: Instant::now(),
            sleep: None,
        }
    }
}

fn burst(rate: f64) -> f64 {
    (rate * BURST_S).max(MIN_BURST_BYTES)
}

impl<S: AsyncRead + Unpin> AsyncRead for Shaped<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Shaped<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let Some(rate) = this.rate else {
            return Pin::new(&mut this.inner).poll_write(cx, buf);
        };
        loop {
            if let Some(sleep) = this.sleep.as_mut() {
                if sleep.as_mut().poll(cx).is_pending() {
                    return Poll::Pending;
                }
                this.sleep = None;
            }
            let now = Instant::now();
            let dt = now.duration_since(this.last).as_secs_f64();
            this.last = now;
            this.tokens = (this.tokens + dt * rate).min(burst(rate));
            if this.tokens >= 1.0 {
                let n = (this.tokens as usize).min(buf.len());
                return match Pin::new(&mut this.inner).poll_write(cx, &buf[..n]) {
                    Poll::Ready(Ok(written)) => {
                        this.tokens -= written as f64;
                        Poll::Ready(Ok(written))
                    }
                    other => other,
                };
            }
            let wait = (1.0 - this.tokens).max(0.0) / rate;
            let want = (buf.len() as f64).min(burst(rate)) / rate;
            let secs = wait.max(want.min(BURST_S));
            this.sleep = Some(Box::pin(tokio::time::sleep(Duration::from_secs_f64(secs))));
        }
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if this.rate.is_none() {
            return Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
        }
        // Shaped: one buffer at a time through the bucket.
        let buf = bufs
            .iter()
            .find(|b| !b.is_empty())
            .map_or(&[][..], |b| &**b);
        Pin::new(this).poll_write(cx, buf)
    }

    fn is_write_vectored(&self) -> bool {
        self.rate.is_none() && self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

/// Parse a rate such as `56kbit`, `2mbit`, `10Mbit`, `1gbit`, `500000` (bits/s) or
/// `unlimited` (→ `None`).
pub fn parse_rate(text: &str) -> Result<Option<u64>, String> {
    let t = text.trim().to_ascii_lowercase();
    if t == "unlimited" || t == "none" || t == "inf" {
        return Ok(None);
    }
    let (num, mult) = if let Some(n) = t.strip_suffix("gbit") {
        (n, 1e9)
    } else if let Some(n) = t.strip_suffix("mbit") {
        (n, 1e6)
    } else if let Some(n) = t.strip_suffix("kbit") {
        (n, 1e3)
    } else if let Some(n) = t.strip_suffix("bit") {
        (n, 1.0)
    } else {
        (t.as_str(), 1.0)
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a rate like 56kbit, 2mbit or unlimited"))?;
    if !(v.is_finite() && v > 0.0) || v * mult > 1e15 {
        return Err(format!("`{text}`: rate must be positive and finite"));
    }
    Ok(Some((v * mult).round().max(1.0) as u64))
}

/// Parse a duration such as `50ms`, `1.5s`, `0`.
pub fn parse_duration(text: &str) -> Result<Duration, String> {
    let t = text.trim().to_ascii_lowercase();
    let (num, scale) = if let Some(n) = t.strip_suffix("ms") {
        (n, 1e-3)
    } else if let Some(n) = t.strip_suffix("us") {
        (n, 1e-6)
    } else if let Some(n) = t.strip_suffix('s') {
        (n, 1.0)
    } else {
        (t.as_str(), 1.0)
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a duration like 50ms or 1.5s"))?;
    if !(v.is_finite() && v >= 0.0) || v * scale > 3600.0 {
        return Err(format!("`{text}`: duration must be between 0 and 1 h"));
    }
    Ok(Duration::from_secs_f64(v * scale))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[test]
    fn rates_and_durations_parse() {
        assert_eq!(parse_rate("56kbit"), Ok(Some(56_000)));
        assert_eq!(parse_rate("2Mbit"), Ok(Some(2_000_000)));
        assert_eq!(parse_rate("unlimited"), Ok(None));
        assert_eq!(parse_rate("1200"), Ok(Some(1200)));
        assert!(parse_rate("fast").is_err());
        assert!(parse_rate("-3kbit").is_err());
        assert_eq!(parse_duration("50ms"), Ok(Duration::from_millis(50)));
        assert_eq!(parse_duration("1.5s"), Ok(Duration::from_millis(1500)));
        assert!(parse_duration("soon").is_err());
    }

    #[tokio::test(flavor = "current_thread", start_paused = true)]
    async fn shaped_writes_take_the_time_the_rate_asks() {
        let (a, mut b) = tokio::io::duplex(1 << 20);
        // 80 kbit/s = 10 000 bytes/s: 20 000 bytes take about 2 s (minus the first burst).
        let mut shaped = Shaped::new(a, Some(80_000));
        let start = Instant::now();
        let writer = tokio::spawn(async move {
            shaped.write_all(&vec![7u8; 20_000]).await.unwrap();
            shaped.shutdown().await.unwrap();
        });
        let mut got = Vec::new();
        b.read_to_end(&mut got).await.unwrap();
        writer.await.unwrap();
        let secs = start.elapsed().as_secs_f64();
        assert_eq!(got.len(), 20_000);
        assert!((1.8..2.3).contains(&secs), "took {secs} s");
    }
}
