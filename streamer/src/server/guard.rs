//! The socket of one connection, seen through its [`ConnState`]: bytes read start the
//! request-head clock, writes the socket refuses start the blocked-write clock, bytes the
//! socket takes are counted. No timers here: the sweeper reads the state
//! ([`super::admit::timed_out`]).
//!
//! A connection the server closes for a reason (a timeout, eviction) is reset, not shut
//! down: an orderly close would leave the kernel delivering what the send buffer holds (up
//! to megabytes) to a peer that reads a byte a second, for minutes.

use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use super::admit::{Clock, ConnState};

/// A stream whose progress is recorded in a [`ConnState`].
pub(crate) struct Guarded<S: Abort> {
    inner: S,
    state: Arc<ConnState>,
    clock: Clock,
}

/// A stream that can be closed with a reset, its unsent data dropped.
pub(crate) trait Abort {
    fn abort_on_close(&self);
}

impl Abort for tokio::net::TcpStream {
    fn abort_on_close(&self) {
        // SO_LINGER 0: close() sends RST and frees the send buffer (never blocks).
        if let Err(e) = self.set_zero_linger() {
            tracing::debug!("SO_LINGER: {e}");
        }
    }
}

impl<S: Abort> Guarded<S> {
    pub(crate) fn new(inner: S, state: Arc<ConnState>, clock: Clock) -> Guarded<S> {
        Guarded {
            inner,
            state,
            clock,
        }
    }
}

impl<S: Abort> Drop for Guarded<S> {
    fn drop(&mut self) {
        if self.state.close_reason().is_some() {
            self.inner.abort_on_close();
        }
    }
}

impl<S: AsyncRead + Abort + Unpin> AsyncRead for Guarded<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let r = Pin::new(&mut this.inner).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = r {
            this.state
                .on_read(buf.filled().len() - before, this.clock.now_ms());
        }
        r
    }
}

impl<S: AsyncWrite + Abort + Unpin> Guarded<S> {
    fn record(&self, r: &Poll<io::Result<usize>>) {
        match r {
            Poll::Pending => self.state.on_write_blocked(self.clock.now_ms()),
            Poll::Ready(Ok(n)) => self.state.on_written(*n),
            Poll::Ready(Err(_)) => {}
        }
    }
}

impl<S: AsyncWrite + Abort + Unpin> AsyncWrite for Guarded<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write(cx, buf);
        this.record(&r);
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
        this.record(&r);
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}
