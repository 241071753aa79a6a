//! Connection limits shared by the front ends: a fixed number of permits; an accepted connection
//! holds one until it closes, and a connection past the limit is closed at once and counted,
//! so a flood of idle sockets cannot exhaust the server's file descriptors or memory.
//!
//! Front ends take the limit from [`crate::Hub::max_connections`].
//!
//! One IP address holds at most [`crate::Hub::max_connections_per_ip`] of the permits, so that a
//! single client cannot take them all.
//!
//! A connection must also send its first byte within [`crate::Hub::first_byte_timeout`], or it
//! is closed: without that, as many connections as the limit that never send anything lock
//! every client out for good.

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
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
    per_ip: Option<PerIp>,
}

/// Connections open per IP address, against a cap.
#[derive(Clone)]
struct PerIp {
    max: usize,
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

/// One connection's place in its address's count, given back when the connection closes.
struct IpPlace {
    ip: IpAddr,
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

impl Drop for IpPlace {
    fn drop(&mut self) {
        // A poisoned map still counts: the counts are plain integers, never left half-written.
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

impl ConnectionLimit {
    pub fn new(max: usize, transport: Transport, metrics: Arc<Metrics>) -> ConnectionLimit {
        ConnectionLimit {
            permits: Arc::new(Semaphore::new(max)),
            max,
            transport,
            metrics,
            first_byte: None,
            per_ip: None,
        }
    }

    /// At most `max` connections from one IP address ([`ConnectionLimit::admit_from`]).
    pub fn with_per_ip(mut self, max: usize) -> ConnectionLimit {
        self.per_ip = Some(PerIp {
            max: max.max(1),
            open: Arc::default(),
        });
        self
    }

    /// [`ConnectionLimit::admit`] for a connection from `ip`, which must also be under its
    /// address's cap.
    pub fn admit_from<S>(&self, stream: S, ip: IpAddr) -> Option<Limited<S>> {
        let place = match &self.per_ip {
            None => None,
            Some(per_ip) => {
                let mut open = per_ip.open.lock().unwrap_or_else(|p| p.into_inner());
                let n = open.entry(ip).or_insert(0);
                if *n >= per_ip.max {
                    drop(open);
                    self.refused("at the per-address connection limit", per_ip.max);
                    return None;
                }
                *n += 1;
                Some(IpPlace {
                    ip,
                    open: Arc::clone(&per_ip.open),
                })
            }
        };
        let mut admitted = self.admit(stream)?;
        admitted._place = place;
        Some(admitted)
    }

    fn refused(&self, why: &str, max: usize) {
        self.metrics
            .connections_refused
            .get_or_create(&Metrics::transport(self.transport))
            .inc();
        warn!(
            transport = self.transport.as_str(),
            max, "connection refused: {why}"
        );
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
                _place: None,
                silent: self
                    .first_byte
                    .map(|t| (Box::pin(tokio::time::sleep(t)), t)),
            }),
            Err(_) => {
                self.refused("at the connection limit", self.max);
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
    _place: Option<IpPlace>,
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

    #[tokio::test]
    async fn one_address_holds_at_most_its_share_and_a_closed_one_frees_it() {
        let metrics = Arc::new(Metrics::new());
        let limit = ConnectionLimit::new(10, Transport::Http, metrics).with_per_ip(2);
        let (a, b): (IpAddr, IpAddr) = ("10.0.0.1".parse().unwrap(), "10.0.0.2".parse().unwrap());
        let first = limit.admit_from((), a).expect("first from a");
        let _second = limit.admit_from((), a).expect("second from a");
        assert!(limit.admit_from((), a).is_none(), "a third from a");
        let _other = limit.admit_from((), b).expect("another address");
        assert_eq!(limit.in_use(), 3, "a refused connection holds no permit");
        drop(first);
        assert!(limit.admit_from((), a).is_some());
    }
}
