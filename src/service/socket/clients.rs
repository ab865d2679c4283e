//! Accepting connections, at most [`MAX_CLIENTS`] at once per listener: a new one past them
//! closes the longest-idle connection (eviction), and once the service stops, accepting ends
//! and the clients are waited for.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::net::{TcpListener, TcpStream, UnixListener, UnixStream};
use tokio::sync::{Notify, Semaphore};

use crate::service::Shared;

/// How often a new connection that finds every slot answering a request tries again.
pub(super) const ROOM_RETRY: Duration = Duration::from_millis(100);

/// Connections served at once per listener; a new one past them closes the longest-idle one
/// ([`Clients::make_room`]), or waits for a slot while all are answering.
pub(super) const MAX_CLIENTS: usize = 64;

/// A listener whose connections are served as clients.
pub(super) trait Listener {
    type Conn: Send + 'static;
    /// The next connection.
    fn next(&self) -> impl std::future::Future<Output = std::io::Result<Self::Conn>> + Send;
}

impl Listener for UnixListener {
    type Conn = UnixStream;
    async fn next(&self) -> std::io::Result<UnixStream> {
        self.accept().await.map(|(stream, _)| stream)
    }
}

impl Listener for TcpListener {
    type Conn = (TcpStream, std::net::SocketAddr);
    async fn next(&self) -> std::io::Result<Self::Conn> {
        self.accept().await
    }
}

/// The open connections of one listener, for [`Clients::make_room`].
#[derive(Default)]
pub(super) struct Clients {
    open: Mutex<HashMap<u64, Client>>,
    next_id: std::sync::atomic::AtomicU64,
}

/// What [`Clients::make_room`] weighs of one connection.
pub(super) struct Client {
    /// Requests answered so far.
    answered: u64,
    /// When it connected, or when its last reply was written.
    last_active: Instant,
    /// Whether a request of its own is being answered.
    busy: bool,
    /// Whether it was told to close (it leaves once it has).
    closing: bool,
    /// Tells it to close.
    close: Arc<Notify>,
}

/// One connection's place among its listener's [`Clients`] and its slot; leaves both when
/// dropped.
pub(super) struct Lease {
    id: u64,
    clients: Arc<Clients>,
    close: Arc<Notify>,
    _slot: tokio::sync::OwnedSemaphorePermit,
}

impl Clients {
    fn open(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Client>> {
        self.open.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A new connection's lease, holding its slot.
    fn join(self: &Arc<Self>, slot: tokio::sync::OwnedSemaphorePermit) -> Lease {
        let id = self
            .next_id
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let close = Arc::new(Notify::new());
        self.open().insert(
            id,
            Client {
                answered: 0,
                last_active: Instant::now(),
                busy: false,
                closing: false,
                close: close.clone(),
            },
        );
        Lease {
            id,
            clients: self.clone(),
            close,
            _slot: slot,
        }
    }

    /// Tells the longest-idle connection that is not being answered to close: one that never
    /// completed a request before one that did, then the least recently active. Nothing while
    /// one told before is still closing. Whether one was told now.
    fn make_room(&self) -> bool {
        let mut open = self.open();
        if open.values().any(|c| c.closing) {
            return false;
        }
        let idlest = open
            .values_mut()
            .filter(|c| !c.busy)
            .min_by_key(|c| (c.answered > 0, c.last_active));
        match idlest {
            Some(c) => {
                c.closing = true;
                c.close.notify_one();
                true
            }
            None => false,
        }
    }
}

impl Lease {
    /// A request of its own is being answered.
    pub(super) fn busy(&self) {
        if let Some(c) = self.clients.open().get_mut(&self.id) {
            c.busy = true;
        }
    }

    /// Its reply was written; `counts`: the request counts as its client asking (not a line
    /// refused before its sender was known, such as an oversized one on the TCP port).
    pub(super) fn answered(&self, counts: bool) {
        if let Some(c) = self.clients.open().get_mut(&self.id) {
            c.busy = false;
            if counts {
                c.answered += 1;
                c.last_active = Instant::now();
            }
        }
    }

    /// Resolves when the connection is to close to make room for a new one.
    pub(super) async fn closing(&self) {
        self.close.notified().await
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        self.clients.open().remove(&self.id);
    }
}

/// Accepts connections on `listener` until the service stops ([`Shared::stopped`]), at most
/// [`MAX_CLIENTS`] served at once, each by `serve` on a task of its own with its [`Lease`]. A
/// new connection past them closes the longest-idle one ([`Clients::make_room`]); while every
/// one is being answered, it tries again every [`ROOM_RETRY`] until one is idle or leaves.
/// Once the service stops, it returns when its clients have ended their connections. `what`
/// names the listener in the log.
pub(super) async fn accept<L, F, Fut>(
    listener: L,
    what: &'static str,
    shared: Arc<Shared>,
    serve: F,
) where
    L: Listener,
    F: Fn(L::Conn, Lease) -> Fut,
    Fut: std::future::Future<Output = std::io::Result<()>> + Send + 'static,
{
    let slots = Arc::new(Semaphore::new(MAX_CLIENTS));
    let clients = Arc::new(Clients::default());
    // Connections closed to make room, and when that was last logged (at most once a minute).
    let (mut evicted, mut logged) = (0u64, None::<Instant>);
    let mut served = tokio::task::JoinSet::new();
    'accepting: loop {
        // Finished clients leave the set as they go.
        while served.try_join_next().is_some() {}
        let next = tokio::select! {
            next = listener.next() => next,
            () = shared.stopped() => break,
        };
        let conn = match next {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("{what}: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let permit = loop {
            if shared.is_stopped() {
                break 'accepting;
            }
            if slots.available_permits() == 0 && clients.make_room() {
                evicted += 1;
                if logged.is_none_or(|t| t.elapsed() >= Duration::from_secs(60)) {
                    tracing::warn!(
                        "{what}: {MAX_CLIENTS} clients connected; closing the longest idle for a \
                         new one ({evicted} so far; a client may be leaking connections)"
                    );
                    logged = Some(Instant::now());
                }
            }
            match tokio::time::timeout(ROOM_RETRY, slots.clone().acquire_owned()).await {
                Ok(Ok(permit)) => break permit,
                Ok(Err(_)) => break 'accepting,
                Err(_) => continue,
            }
        };
        let client = serve(conn, clients.join(permit));
        served.spawn(async move {
            if let Err(e) = client.await {
                tracing::debug!("{what}: client ended: {e}");
            }
        });
    }
    // Stopped: each client ends its connection between requests ([`requests`]).
    while served.join_next().await.is_some() {}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Connections numbered by the test, handed over through a channel.
    struct Numbered(tokio::sync::Mutex<tokio::sync::mpsc::UnboundedReceiver<usize>>);

    impl Listener for Numbered {
        type Conn = usize;
        async fn next(&self) -> std::io::Result<usize> {
            let next = self.0.lock().await.recv().await;
            next.ok_or_else(|| std::io::Error::other("no more connections"))
        }
    }

    /// What a served connection did, in order.
    #[derive(Debug, PartialEq)]
    enum Did {
        Served(usize),
        /// Told to close while its request was still being answered.
        ToldWhileBusy(usize),
        Answered(usize),
        Closed(usize),
    }

    /// Every slot taken by a connection whose request is being answered: a new connection
    /// evicts none of them and waits; once one has its answer (and so is idle), the next retry
    /// closes it and the new one is served in its slot.
    #[tokio::test]
    async fn a_new_connection_waits_while_every_connection_is_being_answered() {
        let (conns, listener) = tokio::sync::mpsc::unbounded_channel();
        let (did, mut done) = tokio::sync::mpsc::unbounded_channel();
        let answers: Vec<Arc<Notify>> =
            (0..=MAX_CLIENTS).map(|_| Arc::new(Notify::new())).collect();
        let to_answer = answers.clone();
        let (events, _engine) = std::sync::mpsc::channel();
        let accepting = tokio::spawn(accept(
            Numbered(tokio::sync::Mutex::new(listener)),
            "test listener",
            Arc::new(crate::service::Shared::new("test".into(), events)),
            move |n: usize, lease: Lease| {
                let (did, answer) = (did.clone(), to_answer[n].clone());
                async move {
                    lease.busy();
                    let _ = did.send(Did::Served(n));
                    tokio::select! {
                        _ = answer.notified() => {}
                        _ = lease.closing() => {
                            let _ = did.send(Did::ToldWhileBusy(n));
                            return Ok(());
                        }
                    }
                    lease.answered(true);
                    let _ = did.send(Did::Answered(n));
                    lease.closing().await;
                    let _ = did.send(Did::Closed(n));
                    Ok(())
                }
            },
        ));
        let next = async |done: &mut tokio::sync::mpsc::UnboundedReceiver<Did>| {
            tokio::time::timeout(Duration::from_secs(5), done.recv())
                .await
                .expect("an event within 5 s")
                .expect("the listener runs")
        };
        for n in 0..MAX_CLIENTS {
            conns.send(n).unwrap();
            assert_eq!(next(&mut done).await, Did::Served(n));
        }
        // One more while all are busy: nobody is closed, it is not served.
        conns.send(MAX_CLIENTS).unwrap();
        let waited = tokio::time::timeout(3 * ROOM_RETRY + ROOM_RETRY / 2, done.recv()).await;
        assert!(waited.is_err(), "while all were busy: {waited:?}");
        // Connection 7 gets its answer: it is closed at the next retry, the new one served.
        answers[7].notify_one();
        assert_eq!(next(&mut done).await, Did::Answered(7));
        assert_eq!(next(&mut done).await, Did::Closed(7));
        assert_eq!(next(&mut done).await, Did::Served(MAX_CLIENTS));
        accepting.abort();
    }
}
