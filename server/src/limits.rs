//! Connection limits shared by the front ends: a fixed number of permits; an accepted connection
//! holds one until it closes, and a connection past the limit is closed at once and counted,
//! so a flood of idle sockets cannot exhaust the server's file descriptors or memory.
//!
//! Front ends take the limit from [`crate::Hub::max_connections`].
//!
//! A connection must also send its first byte within [`crate::Hub::first_byte_timeout`], or it
//! is closed: without that, as many connections as the limit that never send anything lock
//! every client out for good.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tracing::warn;

use crate::metrics::{Metrics, Transport};

/// Permits for one front end's connections.
#[derive(Clone)]
pub struct ConnectionLimit {
    permits: Arc<Semaphore>,
    max: usize,
    transport: Transport,
    metrics: Arc<Metrics>,
    first_byte: Option<Duration>,
}

impl ConnectionLimit {
    pub fn new(max: usize, transport: Transport, metrics: Arc<Metrics>) -> ConnectionLimit {
        ConnectionLimit {
            permits: Arc::new(Semaphore::new(max)),
            max,
            transport,
            metrics,
            first_byte: None,
        }
    }

    /// Connections that send nothing for `timeout` after they are accepted are closed.
    pub fn with_first_byte_timeout(mut self, timeout: Duration) -> ConnectionLimit {
        self.first_byte = Some(timeout);
        self
    }

    /// `stream` wrapped with a permit, or `None` (counted and logged; the caller drops the
    /// stream, which closes it) when every permit is taken.
    pub fn admit<S>(&self, stream: S) -> Option<Limited<S>> {
        match Arc::clone(&self.permits).try_acquire_owned() {
            Ok(permit) => Some(Limited {
                inner: stream,
                _permit: permit,
                silent: self
                    .first_byte
                    .map(|t| (Box::pin(tokio::time::sleep(t)), t)),
            }),
            Err(_) => {
                self.metrics
                    .connections_refused
                    .get_or_create(&Metrics::transport(self.transport))
                    .inc();
                warn!(
                    transport = self.transport.as_str(),
                    max = self.max,
                    "connection refused: at the connection limit"
                );
                None
            }
        }
    }

    /// Connections open now.
    pub fn in_use(&self) -> usize {
        self.max - self.permits.available_permits()
    }
}

/// An accepted connection holding its permit; reads and writes go straight to the stream, and
/// until its first byte arrives a read also waits on the first-byte deadline.
pub struct Limited<S> {
    inner: S,
    _permit: OwnedSemaphorePermit,
    silent: Option<(Pin<Box<tokio::time::Sleep>>, Duration)>,
}

impl<S> Limited<S> {
    pub fn get_ref(&self) -> &S {
        &self.inner
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Limited<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let read = Pin::new(&mut self.inner).poll_read(cx, buf);
        match &read {
            Poll::Ready(_) if buf.filled().len() > before => self.silent = None,
            Poll::Pending => {
                if let Some((deadline, after)) = &mut self.silent
                    && deadline.as_mut().poll(cx).is_ready()
                {
                    let after = *after;
                    self.silent = None;
                    return Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        format!("no byte in the {after:?} after the connection opened"),
                    )));
                }
            }
            Poll::Ready(_) => {}
        }
        read
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Limited<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

impl tonic::transport::server::Connected for Limited<TcpStream> {
    type ConnectInfo = tonic::transport::server::TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.inner.connect_info()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn past_the_limit_is_refused_and_a_closed_one_frees_its_permit() {
        let metrics = Arc::new(Metrics::new());
        let limit = ConnectionLimit::new(2, Transport::Grpc, Arc::clone(&metrics));
        let a = limit.admit(()).expect("first");
        let _b = limit.admit(()).expect("second");
        assert!(limit.admit(()).is_none());
        assert_eq!(limit.in_use(), 2);
        drop(a);
        assert!(limit.admit(()).is_some());
        assert!(
            metrics
                .encode()
                .contains(r#"bounce_connections_refused_total{transport="grpc"} 1"#)
        );
    }
}
