//! The control socket: a Unix stream socket, one JSON request and one JSON reply per line
//! ([`super::protocol`]), many clients at once, each on a task of the tokio runtime.
//!
//! `status` is answered from the shared snapshot without involving the engine, so it answers
//! within milliseconds while the engine trains; other requests go to the engine thread and their
//! reply comes back on a oneshot channel. A malformed, oversized or unknown request gets an error
//! reply and the connection goes on. Peers are checked by their credentials (`SO_PEERCRED`):
//! root, the service's own user, the socket's group and `allow_uids` may connect.
//!
//! Optionally the same API on a loopback TCP address (`[socket] tcp`), for show-control software
//! that speaks TCP: there every request carries the token of `[socket] tcp_token_file` in a
//! `token` field; a request without it, or with another, gets an error and the connection is
//! closed.
//!
//! At most [`MAX_CLIENTS`] connections are served at once per listener. When a new one comes
//! and all are taken, the longest-idle connection is closed to make room (with a reply that
//! says why): first those that never completed a request (a client that leaked its
//! connection, or holds half a line), then the least recently active. Connections that leak
//! cannot lock the socket, and a controller that keeps one connection and asks now and then
//! keeps it while such connections come and go.
//!
//! Files by job: `access.rs` who may connect (the socket file, its group, credentials, the TCP
//! token); `clients.rs` accepting and evicting connections; `lines.rs` the line framing;
//! `blocking.rs` the blocking client the commands use; this file the server: each connection's
//! requests, subscriptions and their answers.

mod access;
mod blocking;
mod clients;
mod lines;

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, UnixListener, UnixStream};
use tokio::sync::oneshot;

use super::protocol::{MAX_REQUEST_BYTES, Reply, Request};
use super::refusals::Refusals;
use super::{Envelope, Shared};

pub use access::{Access, Token, bind, bind_tcp, check_path};
pub use blocking::{request, resolve};
use clients::{Lease, MAX_CLIENTS, accept};
use lines::{Line, WRITE_TIMEOUT, read_line, send_line, subscription};

/// How long a request waits for the engine (it answers between two refreshes, two captures).
pub(super) const ENGINE_TIMEOUT: Duration = Duration::from_secs(30);

/// Accepts clients on the Unix socket until the service stops.
pub async fn serve(listener: UnixListener, access: Access, shared: Arc<Shared>) {
    let refusals = Arc::new(Refusals::new("control socket"));
    accept(
        listener,
        "control socket",
        shared.clone(),
        move |stream, lease| {
            let (access, shared, refusals) = (access.clone(), shared.clone(), refusals.clone());
            async move { client(stream, (&access, &refusals), &shared, lease).await }
        },
    )
    .await
}

/// Accepts TCP clients until the service stops; each request must carry `token`.
pub async fn serve_tcp(listener: TcpListener, token: Token, shared: Arc<Shared>) {
    let refusals = Arc::new(Refusals::new("control port"));
    accept(
        listener,
        "control port",
        shared.clone(),
        move |(stream, peer), lease| {
            let (token, shared, refusals) = (token.clone(), shared.clone(), refusals.clone());
            async move {
                let (read, write) = stream.into_split();
                let origin = format!("tcp {peer}");
                let tcp = Tcp {
                    token: &token,
                    peer,
                    refusals: &refusals,
                };
                requests(read, write, (&shared, &origin), Some(tcp), lease).await
            }
        },
    )
    .await
}

/// What the TCP port checks a request against: the token, and the peer's refusals so far.
struct Tcp<'a> {
    token: &'a Token,
    peer: std::net::SocketAddr,
    refusals: &'a Refusals,
}

/// One client of the Unix socket, once its credentials allow it: its requests in order.
async fn client(
    stream: UnixStream,
    (access, refusals): (&Access, &Refusals),
    shared: &Shared,
    lease: Lease,
) -> std::io::Result<()> {
    let cred = stream.peer_cred()?;
    let (read, mut write) = stream.into_split();
    let who = format!("uid {}", cred.uid());
    if let Err(why) = refusals.admit(&who) {
        let reply = Reply::error(why);
        let _ = send_line(&mut write, reply.to_line()).await;
        return Ok(());
    }
    if !access.allows(cred.uid(), cred.gid()) {
        refusals.refused(
            &who,
            &format!(
                "a client with gid {} (pid {:?}) not allowed",
                cred.gid(),
                cred.pid()
            ),
        );
        let reply = Reply::error(format!(
            "uid {} may not control this service: add it to the socket's group or to [socket] \
             allow_uids",
            cred.uid()
        ));
        let _ = send_line(&mut write, reply.to_line()).await;
        return Ok(());
    }
    let origin = format!("unix uid {}", cred.uid());
    requests(read, write, (shared, &origin), None, lease).await
}

/// A connection's requests in order, one reply each, until the client hangs up or its `lease`
/// is told to make room for a new client (between requests). With `token` (TCP, and the peer's
/// address for the log), each request must carry it; the first that does not is answered with
/// an error and ends the connection.
async fn requests<R, W>(
    read: R,
    mut write: W,
    (shared, origin): (&Shared, &str),
    tcp: Option<Tcp<'_>>,
    lease: Lease,
) -> std::io::Result<()>
where
    R: tokio::io::AsyncRead + Unpin,
    W: tokio::io::AsyncWrite + Unpin,
{
    let mut read = BufReader::new(read);
    let mut line = Vec::new();
    loop {
        let next = tokio::select! {
            next = read_line(&mut read, &mut line) => next?,
            () = lease.closing() => {
                let reply = Reply::error(format!(
                    "closed to make room: the service serves at most {MAX_CLIENTS} clients at \
                     once, and this connection was the longest idle when another came"
                ));
                return reply_and_close(&mut read, &mut write, &reply, lease).await;
            }
            () = shared.stopped() => {
                let reply = Reply::error("the service stopped".to_string());
                return reply_and_close(&mut read, &mut write, &reply, lease).await;
            }
        };
        lease.busy();
        // On the TCP port a line refused before its token was read does not count as asking.
        let counts = !(tcp.is_some() && matches!(next, Line::TooLong));
        let reply = match next {
            Line::End => return Ok(()),
            Line::TooLong => Reply::error(format!(
                "request longer than {MAX_REQUEST_BYTES} bytes; it was skipped"
            )),
            Line::Complete => {
                let request = match &tcp {
                    None => std::mem::take(&mut line),
                    Some(tcp) => {
                        let ip = tcp.peer.ip().to_canonical().to_string();
                        let checked = match tcp.refusals.admit(&ip) {
                            // Backed off: the token is not looked at.
                            Err(why) => Err(Reply::error(why)),
                            Ok(()) => tcp.token.strip(&line).inspect_err(|_| {
                                tcp.refusals.refused(&ip, "no token, or the wrong one");
                            }),
                        };
                        match checked {
                            Ok(request) => {
                                tcp.refusals.accepted(&ip);
                                request
                            }
                            Err(reply) => {
                                return reply_and_close(&mut read, &mut write, &reply, lease).await;
                            }
                        }
                    }
                };
                if let Some(id) = subscription(&request) {
                    return subscribe(&mut read, &mut write, (shared, origin), id, lease).await;
                }
                answer(&request, shared, origin).await
            }
        };
        let text = reply.to_line();
        match tokio::time::timeout(WRITE_TIMEOUT, write.write_all(text.as_bytes())).await {
            Ok(written) => written?,
            Err(_) => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "the client did not read its reply",
                ));
            }
        }
        lease.answered(counts);
    }
}

/// Writes a last `reply` (given a second at most), shuts the connection's write side and
/// gives up its `lease` (its slot is free for the next client), then reads and drops what the
/// client still sends for a second, so that closing does not reset the connection before the
/// client has read the reply.
async fn reply_and_close<R, W>(
    read: &mut R,
    write: &mut W,
    reply: &Reply,
    lease: Lease,
) -> std::io::Result<()>
where
    R: tokio::io::AsyncRead + Unpin,
    W: tokio::io::AsyncWrite + Unpin,
{
    let text = reply.to_line();
    let second = Duration::from_secs(1);
    if tokio::time::timeout(second, write.write_all(text.as_bytes()))
        .await
        .is_err()
    {
        return Ok(());
    }
    let _ = tokio::time::timeout(second, write.shutdown()).await;
    drop(lease);
    let mut sink = tokio::io::sink();
    let _ = tokio::time::timeout(second, tokio::io::copy(read, &mut sink)).await;
    Ok(())
}

/// `subscribe`: the connection becomes a stream of the service's events, one line each
/// (`{"event":{...}}`, as the console's `/api/events`), until the client hangs up or the service
/// stops; what the client sends after it is read and dropped. A subscriber that falls behind by
/// more than the hub keeps is sent `{"lagged":N}` and goes on. Subscribers are never closed to
/// make room; there are at most [`super::events::MAX_SUBSCRIBERS`] at once, over all surfaces.
async fn subscribe<R, W>(
    read: &mut R,
    write: &mut W,
    (shared, origin): (&Shared, &str),
    id: Option<serde_json::Value>,
    lease: Lease,
) -> std::io::Result<()>
where
    R: tokio::io::AsyncBufRead + Unpin,
    W: tokio::io::AsyncWrite + Unpin,
{
    let Some(_slot) = shared.hub.slot() else {
        let mut reply = Reply::error(format!(
            "{} subscribers are connected already; close one",
            super::events::MAX_SUBSCRIBERS
        ));
        reply.request_id = id;
        send_line(write, reply.to_line()).await?;
        lease.answered(true);
        return Ok(());
    };
    let mut rx = shared.hub.subscribe();
    let mut reply = Reply::ok("subscribed: one event per line from now on");
    reply.request_id = id;
    send_line(write, reply.to_line()).await?;
    tracing::info!("{origin} subscribed to the events");
    loop {
        let line = tokio::select! {
            got = rx.recv() => match got {
                Ok(e) => format!("{}\n", serde_json::json!({ "event": e })),
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    format!("{}\n", serde_json::json!({ "lagged": n }))
                }
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return Ok(()),
            },
            () = shared.stopped() => return Ok(()),
            more = read.fill_buf() => {
                let n = more?.len();
                if n == 0 {
                    return Ok(());
                }
                read.consume(n);
                continue;
            }
        };
        send_line(write, line).await?;
    }
}

/// The reply to one request line from `origin`.
async fn answer(line: &[u8], shared: &Shared, origin: &str) -> Reply {
    let (parsed, id) = Request::parse_with_id(line);
    let mut reply = match parsed {
        Ok(r) => dispatch(r, shared, origin).await,
        Err(e) => Reply::error(e),
    };
    reply.request_id = id;
    reply
}

/// The reply to `request` from `origin` (`unix uid 1000`, `tcp 127.0.0.1:50312`, `http ...`):
/// `status` from the shared snapshot, the others from the engine. Every request but `status`
/// is logged and published with its origin and outcome.
pub(super) async fn dispatch(request: Request, shared: &Shared, origin: &str) -> Reply {
    if request == Request::Status {
        return Reply::status(shared.status());
    }
    let (tx, rx) = oneshot::channel();
    let reply = if !shared.send(Envelope {
        request: request.clone(),
        reply: Some(tx),
        opened: None,
    }) {
        Reply::error("the service is shutting down")
    } else {
        match tokio::time::timeout(ENGINE_TIMEOUT, rx).await {
            Ok(Ok(reply)) => reply,
            Ok(Err(_)) => Reply::error("the service is shutting down"),
            Err(_) => Reply::error(format!(
                "the service did not answer within {} s; see compend status",
                ENGINE_TIMEOUT.as_secs()
            )),
        }
    };
    shared.requested(origin, &request, &reply);
    reply
}
