//! Connections before they have earned a place: each listener admits them through a
//! [`Gate`] that holds at most a set number of connections that have not yet
//! authenticated (gRPC) or are waiting for a request (HTTP), closing the oldest of them
//! to admit a new one. A flood of idle connections then holds a bounded number of file
//! descriptors, and a real caller, who authenticates or asks at once, still gets in.

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio_stream::Stream;

/// How long a listener's connections may take, and how many may wait.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// The TLS handshake on the gRPC port.
    pub handshake: Duration,
    /// An HTTP request's header, from the connection's start or the end of the previous
    /// response (an idle keep-alive connection is closed after this too).
    pub header: Duration,
    /// A gRPC connection that has made no authenticated call this long after it was
    /// accepted is closed; an authenticated one quiet this long is pinged (HTTP/2).
    pub idle: Duration,
    /// Connections per listener that have not authenticated (gRPC) or are waiting for a
    /// request (HTTP); past it, the oldest of them is closed.
    pub max_pending: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            handshake: Duration::from_secs(10),
            header: Duration::from_secs(10),
            idle: Duration::from_secs(300),
            max_pending: 256,
        }
    }
}

/// One accepted connection, as its listener's [`Gate`] sees it.
pub struct Conn {
    id: u64,
    /// Made an authenticated call (gRPC): never closed to make room.
    proven: AtomicBool,
    /// Requests being answered (HTTP): not closed to make room while any are.
    busy: AtomicUsize,
    /// Told to close, to make room for a newer connection.
    evicted: Notify,
}

impl Conn {
    fn pending(&self) -> bool {
        !self.proven.load(Ordering::Relaxed) && self.busy.load(Ordering::Relaxed) == 0
    }

    /// Marks a request as being answered until the returned guard is dropped.
    pub fn busy(self: &Arc<Self>) -> Busy {
        self.busy.fetch_add(1, Ordering::Relaxed);
        Busy(Arc::clone(self))
    }
}

/// A request being answered on a connection (see [`Conn::busy`]).
pub struct Busy(Arc<Conn>);

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.busy.fetch_sub(1, Ordering::Relaxed);
    }
}

/// A listener's connections, by peer address (unique among one listener's open
/// connections), and how many of them may be pending.
pub struct Gate {
    what: &'static str,
    max_pending: usize,
    next_id: AtomicU64,
    conns: Mutex<HashMap<SocketAddr, Arc<Conn>>>,
    /// When a flood was last reported, in ms since `start`, so that a flood is reported
    /// now and then rather than for every connection it costs.
    warned: AtomicU64,
    start: Instant,
}

impl Gate {
    pub fn new(what: &'static str, max_pending: usize) -> Arc<Self> {
        Arc::new(Self {
            what,
            max_pending: max_pending.max(1),
            next_id: AtomicU64::new(1),
            conns: Mutex::new(HashMap::new()),
            warned: AtomicU64::new(0),
            start: Instant::now(),
        })
    }

    fn conns(&self) -> std::sync::MutexGuard<'_, HashMap<SocketAddr, Arc<Conn>>> {
        self.conns.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Registers a new connection from `peer`; when the pending ones are at the cap, the
    /// oldest is told to close (the newest is the likeliest to be a caller who is about
    /// to authenticate; a flood's connections sit and age).
    pub fn admit(self: &Arc<Self>, peer: SocketAddr) -> Ticket {
        let conn = Arc::new(Conn {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            proven: AtomicBool::new(false),
            busy: AtomicUsize::new(0),
            evicted: Notify::new(),
        });
        let mut conns = self.conns();
        let mut pending = 0;
        let mut oldest: Option<(u64, SocketAddr)> = None;
        for (addr, c) in conns.iter().filter(|(_, c)| c.pending()) {
            pending += 1;
            if oldest.is_none_or(|(id, _)| c.id < id) {
                oldest = Some((c.id, *addr));
            }
        }
        if pending >= self.max_pending
            && let Some((_, addr)) = oldest
            && let Some(old) = conns.remove(&addr)
        {
            // A stored permit: the connection sees it at its next read even if it is not
            // waiting at this moment.
            old.evicted.notify_one();
            self.warn_flood();
        }
        conns.insert(peer, Arc::clone(&conn));
        Ticket { gate: Arc::clone(self), peer, conn }
    }

    /// The connection from `peer` made an authenticated call.
    pub fn prove(&self, peer: SocketAddr) {
        if let Some(c) = self.conns().get(&peer) {
            c.proven.store(true, Ordering::Relaxed);
        }
    }

    fn warn_flood(&self) {
        let now = self.start.elapsed().as_millis() as u64 + 1;
        let last = self.warned.load(Ordering::Relaxed);
        if (last == 0 || now.saturating_sub(last) >= FLOOD_REPORT_INTERVAL.as_millis() as u64)
            && self.warned.compare_exchange(last, now, Ordering::Relaxed, Ordering::Relaxed).is_ok()
        {
            tracing::warn!(
                "{}: more than {} connections waiting to authenticate or send a request; closing the oldest \
                 (--max-pending-connections)",
                self.what,
                self.max_pending
            );
        }
    }
}

const FLOOD_REPORT_INTERVAL: Duration = Duration::from_secs(60);

/// A connection's place in its [`Gate`], given up when dropped.
pub struct Ticket {
    gate: Arc<Gate>,
    peer: SocketAddr,
    conn: Arc<Conn>,
}

impl Drop for Ticket {
    fn drop(&mut self) {
        let mut conns = self.gate.conns();
        if conns.get(&self.peer).is_some_and(|c| c.id == self.conn.id) {
            conns.remove(&self.peer);
        }
    }
}

type Closer = Pin<Box<dyn Future<Output = ()> + Send>>;

/// A connection's stream that fails its reads once the connection is evicted, or, with
/// a deadline, once that passes before the connection made an authenticated call. The
/// servers always have a read outstanding, so either ends the connection promptly.
pub struct Guarded<IO> {
    io: IO,
    ticket: Ticket,
    closer: Option<Closer>,
}

impl<IO> Guarded<IO> {
    pub fn new(io: IO, ticket: Ticket, deadline: Option<Duration>) -> Self {
        let conn = Arc::clone(&ticket.conn);
        let closer: Closer = Box::pin(async move {
            let expired = async {
                match deadline {
                    Some(d) => tokio::time::sleep(d).await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                _ = expired => {}
                _ = conn.evicted.notified() => {}
            }
        });
        Self { io, ticket, closer: Some(closer) }
    }

    pub fn conn(&self) -> &Arc<Conn> {
        &self.ticket.conn
    }

    fn check(&mut self, cx: &mut Context<'_>) -> io::Result<()> {
        if let Some(closer) = &mut self.closer {
            if self.ticket.conn.proven.load(Ordering::Relaxed) {
                self.closer = None;
            } else if closer.as_mut().poll(cx).is_ready() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "closed before authenticating: too old, or making room for newer connections",
                ));
            }
        }
        Ok(())
    }
}

impl<IO: AsyncRead + Unpin> AsyncRead for Guarded<IO> {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        this.check(cx)?;
        Pin::new(&mut this.io).poll_read(cx, buf)
    }
}

impl<IO: AsyncWrite + Unpin> AsyncWrite for Guarded<IO> {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().io).poll_write(cx, buf)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }
}

/// The connection's own information, as tonic reads it (the peer's address; over TLS,
/// tonic adds the client certificate, which the farm's access control reads).
impl<IO: tonic::transport::server::Connected> tonic::transport::server::Connected for Guarded<IO> {
    type ConnectInfo = IO::ConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.io.connect_info()
    }
}

/// A listener's accepted connections, each admitted through its gate. Accepting never
/// ends the stream: an error (such as running out of file descriptors) pauses accepting
/// briefly instead of spinning on it.
pub struct Accepted {
    listener: TcpListener,
    gate: Arc<Gate>,
    deadline: Option<Duration>,
    pause: Option<Pin<Box<tokio::time::Sleep>>>,
}

impl Accepted {
    pub fn new(listener: TcpListener, gate: Arc<Gate>, deadline: Option<Duration>) -> Self {
        Self { listener, gate, deadline, pause: None }
    }
}

const ACCEPT_PAUSE: Duration = Duration::from_millis(100);

impl Stream for Accepted {
    type Item = io::Result<Guarded<TcpStream>>;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        let this = self.get_mut();
        loop {
            if let Some(pause) = &mut this.pause {
                ready!(pause.as_mut().poll(cx));
                this.pause = None;
            }
            match ready!(this.listener.poll_accept(cx)) {
                Ok((stream, peer)) => {
                    // Small request/response messages must not wait for Nagle's algorithm.
                    let _ = stream.set_nodelay(true);
                    let ticket = this.gate.admit(peer);
                    return Poll::Ready(Some(Ok(Guarded::new(stream, ticket, this.deadline))));
                }
                Err(e) => {
                    tracing::debug!("{}: accepting a connection: {e}", this.gate.what);
                    this.pause = Some(Box::pin(tokio::time::sleep(ACCEPT_PAUSE)));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peer(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    #[tokio::test]
    async fn the_oldest_pending_connection_makes_room_and_proven_ones_stay() {
        let gate = Gate::new("test", 2);
        let first = gate.admit(peer(1));
        gate.prove(peer(1));
        let second = gate.admit(peer(2));
        let third = gate.admit(peer(3));
        let busy = third.conn.busy();
        let fourth = gate.admit(peer(4));
        // Pending were the second and the fourth; a fifth evicts the second.
        let _fifth = gate.admit(peer(5));
        async fn evicted(t: &Ticket) -> bool {
            tokio::time::timeout(Duration::from_millis(20), t.conn.evicted.notified()).await.is_ok()
        }
        assert!(evicted(&second).await);
        for t in [&first, &third, &fourth] {
            assert!(!evicted(t).await);
        }
        assert_eq!(gate.conns().len(), 4);
        drop(busy);
        drop(second);
        assert_eq!(gate.conns().len(), 4, "an evicted ticket leaves its successor's entry alone");
    }
}
