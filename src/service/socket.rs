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

use std::collections::HashMap;
use std::ffi::CString;
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream, UnixListener, UnixStream};
use tokio::sync::{Notify, Semaphore, oneshot};

use super::protocol::{MAX_REQUEST_BYTES, Reply, Request};
use super::refusals::Refusals;
use super::{Envelope, Shared};
use crate::config::SocketConfig;
use crate::error::{Error, Result};

/// How often a new connection that finds every slot answering a request tries again.
const ROOM_RETRY: Duration = Duration::from_millis(100);

/// Connections served at once per listener; a new one past them closes the longest-idle one
/// ([`Clients::make_room`]), or waits for a slot while all are answering.
const MAX_CLIENTS: usize = 64;

/// How long a reply may take to write: a client that does not read its replies is closed.
const WRITE_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a request waits for the engine (it answers between two refreshes, two captures).
const ENGINE_TIMEOUT: Duration = Duration::from_secs(30);

/// Who may connect.
#[derive(Clone, Debug)]
pub struct Access {
    own_uid: u32,
    /// The socket's group: its members may connect.
    group: u32,
    allow_uids: Vec<u32>,
}

impl Access {
    /// Whether a peer with these credentials may talk to the service.
    fn allows(&self, uid: u32, gid: u32) -> bool {
        if uid == 0 || uid == self.own_uid || self.allow_uids.contains(&uid) {
            return true;
        }
        gid == self.group || user_in_group(uid, self.group)
    }
}

/// Whether the socket path `path` can be the service's: free, or a socket (an old service's,
/// replaced at the start, or a live one's, refused then); a file, a link, a device or a folder
/// is an input error, and nothing is removed. `config check` asks it as `serve` does.
pub fn check_path(path: &Path) -> Result<()> {
    let refuse = |is: &str| {
        Error::Input(format!(
            "[socket] path = \"{}\": {is}; it must name a free path or an old compend socket",
            path.display()
        ))
    };
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_socket() => Ok(()),
        Ok(meta) if meta.file_type().is_symlink() => Err(refuse("a symbolic link")),
        Ok(meta) if meta.is_dir() => Err(refuse("a folder")),
        Ok(meta) if meta.is_file() => Err(refuse("a file that is not a socket")),
        Ok(_) => Err(refuse("a device or a FIFO, not a socket")),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, "inspect", e)),
    }
}

/// Binds the socket at `cfg.path` with its mode and group. A socket file left by a service
/// that is gone is replaced; a live one (another service answering) or a path that holds
/// something other than a socket is an input error, and nothing is removed.
pub fn bind(cfg: &SocketConfig) -> Result<(UnixListener, Access)> {
    let path = &cfg.path;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, "create folder", e))?;
    }
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_socket() => {
            if std::os::unix::net::UnixStream::connect(path).is_ok() {
                return Err(Error::Input(format!(
                    "{}: another compend service is answering on this socket; stop it first \
                     (compend stop --socket {0}) or set [socket] path",
                    path.display()
                )));
            }
            std::fs::remove_file(path).map_err(|e| Error::io(path, "remove stale socket", e))?;
        }
        _ => check_path(path)?,
    }
    let listener = UnixListener::bind(path).map_err(|e| Error::io(path, "bind socket", e))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(cfg.mode))
        .map_err(|e| Error::io(path, "set socket mode", e))?;
    let group = match &cfg.group {
        Some(name) => {
            let gid = group_id(name).ok_or_else(|| {
                Error::Input(format!(
                    "[socket] group = \"{name}\": no such group on this system"
                ))
            })?;
            chown_group(path, gid)?;
            gid
        }
        // The service user's group (its effective group), set on the file even where the
        // folder's set-group-ID bit gave it the folder's: its members may open the 0660 file,
        // and so may talk to the service.
        None => {
            let gid = nix::unistd::getegid().as_raw();
            chown_group(path, gid)?;
            gid
        }
    };
    let own_uid = nix::unistd::geteuid().as_raw();
    Ok((
        listener,
        Access {
            own_uid,
            group,
            allow_uids: cfg.allow_uids.clone(),
        },
    ))
}

/// Whether a token file of `mode` in the group `gid` may be read by anyone but the service's
/// user and its group `own_gid`: other users' bits, or group bits of another group. The
/// service's group may read it: its members control the service through the socket anyway.
fn others_may_read(mode: u32, gid: u32, own_gid: u32) -> bool {
    mode & 0o007 != 0 || (mode & 0o070 != 0 && gid != own_gid)
}

/// Shortest token accepted, bytes: 16 random bytes as hex or base64 are longer.
const MIN_TOKEN_BYTES: usize = 16;

/// The token TCP requests must carry.
#[derive(Clone)]
pub struct Token(Arc<Vec<u8>>);

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Token({} bytes)", self.0.len())
    }
}

impl Token {
    /// Reads the token from `path`, the file the configuration's `key` names: its text without
    /// surrounding white space, at least [`MIN_TOKEN_BYTES`] long. A file others may read is
    /// used, with a warning.
    pub fn read(path: &Path, key: &str) -> Result<Self> {
        let text = crate::files::read_text(path, "a token file").map_err(|e| match e {
            Error::Missing { .. } => Error::Input(format!(
                "{key}: {} does not exist; write a random token into it (e.g. \
                 `openssl rand -hex 32 > {0}`) that only the service's user and group may read \
                 (mode 600 or 640, owned by that user or in that group)",
                path.display()
            )),
            Error::Io { source, .. } if source.kind() == std::io::ErrorKind::PermissionDenied => {
                Error::Input(format!(
                    "{key}: {} cannot be read by this user ({source}); let \
                     the service's user read it",
                    path.display()
                ))
            }
            Error::Input(m) => Error::Input(format!(
                "{key}: {m}; expected a token such as 64 hex digits"
            )),
            e => e,
        })?;
        let token = text.trim();
        if token.len() < MIN_TOKEN_BYTES || token.chars().any(char::is_whitespace) {
            return Err(Error::Input(format!(
                "{key}: {} must hold one token of at least {MIN_TOKEN_BYTES} \
                 characters without spaces (it holds {} characters{})",
                path.display(),
                token.chars().count(),
                if token.chars().any(char::is_whitespace) {
                    ", with spaces"
                } else {
                    ""
                }
            )));
        }
        let own_gid = nix::unistd::getegid().as_raw();
        if let Ok(meta) = std::fs::metadata(path)
            && others_may_read(meta.permissions().mode(), meta.gid(), own_gid)
        {
            tracing::warn!(
                "{key}: {} may be read by users outside the service's user and \
                 group (mode {:o}, group id {}); chmod 600 it, or give it the service's group and \
                 chmod 640",
                path.display(),
                meta.permissions().mode() & 0o777,
                meta.gid()
            );
        }
        Ok(Self(Arc::new(token.as_bytes().to_vec())))
    }

    /// Whether `given` is the token; in time that does not depend on where they differ
    /// (`subtle`; a length that differs is told at once, and says nothing of the token's
    /// bytes).
    pub(crate) fn matches(&self, given: &[u8]) -> bool {
        use subtle::ConstantTimeEq;
        bool::from(self.0.as_slice().ct_eq(given))
    }

    /// The request in `line` without its `token` field, once the token is right; otherwise the
    /// error to reply before closing the connection.
    fn strip(&self, line: &[u8]) -> std::result::Result<Vec<u8>, Reply> {
        let refuse = || {
            Reply::error(
                "a request on the TCP port must be one JSON object with \"token\", the token of \
                 [socket] tcp_token_file; this one has none or another",
            )
        };
        // `{"token":"wrong","token":"right"}` would pass a check of the parsed value, and
        // `{"cmd":"status","cmd":"stop"}` would be read as `stop` once the token is taken out:
        // a key given twice is refused on the raw line, before the token is looked at.
        super::protocol::unique_keys(line).map_err(|e| {
            Reply::error(format!(
                "{e}; a request on the TCP port gives each field once, and the token of \
                 [socket] tcp_token_file in \"token\""
            ))
        })?;
        let mut value: serde_json::Value = serde_json::from_slice(line).map_err(|_| refuse())?;
        let obj = value.as_object_mut().ok_or_else(refuse)?;
        match obj.remove("token") {
            Some(serde_json::Value::String(t)) if self.matches(t.as_bytes()) => {}
            _ => return Err(refuse()),
        }
        serde_json::to_vec(&value).map_err(|e| Reply::error(format!("bad request: {e}")))
    }
}

/// Binds the loopback TCP address `addr` of `[socket] tcp`. An address in use is an input
/// error naming it.
pub fn bind_tcp(addr: std::net::SocketAddr, key: &str) -> Result<TcpListener> {
    let std_listener = std::net::TcpListener::bind(addr).map_err(|e| match e.kind() {
        std::io::ErrorKind::AddrInUse => Error::Input(format!(
            "{key} = \"{addr}\": the address is in use (another compend service, or another \
             program); pick another port"
        )),
        _ => Error::Failed(format!("{key} = \"{addr}\": cannot listen: {e}")),
    })?;
    std_listener
        .set_nonblocking(true)
        .map_err(|e| Error::Failed(format!("{key} = \"{addr}\": {e}")))?;
    TcpListener::from_std(std_listener)
        .map_err(|e| Error::Failed(format!("{key} = \"{addr}\": {e}")))
}

/// A listener whose connections are served as clients.
trait Listener {
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
struct Clients {
    open: Mutex<HashMap<u64, Client>>,
    next_id: std::sync::atomic::AtomicU64,
}

/// What [`Clients::make_room`] weighs of one connection.
struct Client {
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
struct Lease {
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
    fn busy(&self) {
        if let Some(c) = self.clients.open().get_mut(&self.id) {
            c.busy = true;
        }
    }

    /// Its reply was written; `counts`: the request counts as its client asking (not a line
    /// refused before its sender was known, such as an oversized one on the TCP port).
    fn answered(&self, counts: bool) {
        if let Some(c) = self.clients.open().get_mut(&self.id) {
            c.busy = false;
            if counts {
                c.answered += 1;
                c.last_active = Instant::now();
            }
        }
    }

    /// Resolves when the connection is to close to make room for a new one.
    async fn closing(&self) {
        self.close.notified().await
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        self.clients.open().remove(&self.id);
    }
}

/// Accepts connections on `listener` until the runtime shuts down, at most [`MAX_CLIENTS`]
/// served at once, each by `serve` on a task of its own with its [`Lease`]. A new connection
/// past them closes the longest-idle one ([`Clients::make_room`]); while every one is being
/// answered, it tries again every [`ROOM_RETRY`] until one is idle or leaves. `what` names the
/// listener in the log.
async fn accept<L, F, Fut>(listener: L, what: &'static str, serve: F)
where
    L: Listener,
    F: Fn(L::Conn, Lease) -> Fut,
    Fut: std::future::Future<Output = std::io::Result<()>> + Send + 'static,
{
    let slots = Arc::new(Semaphore::new(MAX_CLIENTS));
    let clients = Arc::new(Clients::default());
    // Connections closed to make room, and when that was last logged (at most once a minute).
    let (mut evicted, mut logged) = (0u64, None::<Instant>);
    loop {
        let conn = match listener.next().await {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("{what}: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let permit = loop {
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
                Ok(Err(_)) => return,
                Err(_) => continue,
            }
        };
        let served = serve(conn, clients.join(permit));
        tokio::spawn(async move {
            if let Err(e) = served.await {
                tracing::debug!("{what}: client ended: {e}");
            }
        });
    }
}

/// Accepts clients on the Unix socket until the runtime shuts down.
pub async fn serve(listener: UnixListener, access: Access, shared: Arc<Shared>) {
    let refusals = Arc::new(Refusals::new("control socket"));
    accept(listener, "control socket", move |stream, lease| {
        let (access, shared, refusals) = (access.clone(), shared.clone(), refusals.clone());
        async move { client(stream, (&access, &refusals), &shared, lease).await }
    })
    .await
}

/// Accepts TCP clients until the runtime shuts down; each request must carry `token`.
pub async fn serve_tcp(listener: TcpListener, token: Token, shared: Arc<Shared>) {
    let refusals = Arc::new(Refusals::new("control port"));
    accept(listener, "control port", move |(stream, peer), lease| {
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
    })
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

enum Line {
    Complete,
    TooLong,
    End,
}

/// Reads one line into `buf` (without its newline), at most [`MAX_REQUEST_BYTES`]; the rest of
/// a longer line is read and thrown away.
async fn read_line<R: tokio::io::AsyncBufRead + Unpin>(
    r: &mut R,
    buf: &mut Vec<u8>,
) -> std::io::Result<Line> {
    buf.clear();
    let mut too_long = false;
    loop {
        let chunk = r.fill_buf().await?;
        if chunk.is_empty() {
            // A last request without its newline still counts.
            return Ok(match (buf.is_empty(), too_long) {
                (_, true) => Line::TooLong,
                (true, false) => Line::End,
                (false, false) => Line::Complete,
            });
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (chunk.len(), false),
        };
        if !too_long {
            if buf.len() + take > MAX_REQUEST_BYTES {
                too_long = true;
                buf.clear();
            } else {
                buf.extend_from_slice(&chunk[..take]);
            }
        }
        r.consume(if done { take + 1 } else { take });
        if done {
            return Ok(if too_long {
                Line::TooLong
            } else {
                Line::Complete
            });
        }
    }
}

/// Whether `line` is `{"cmd":"subscribe"}` (with a `request_id`, or not): Some(its id).
fn subscription(line: &[u8]) -> Option<Option<serde_json::Value>> {
    // Most lines are other requests: parsed here only when they may be this one.
    if !line.windows(9).any(|w| w == b"subscribe") {
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(line).ok()?;
    let o = v.as_object()?;
    if o.get("cmd")?.as_str()? != "subscribe" || o.keys().any(|k| k != "cmd" && k != "request_id") {
        return None;
    }
    Some(o.get("request_id").cloned())
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

/// Writes `text` within [`WRITE_TIMEOUT`].
async fn send_line<W: tokio::io::AsyncWrite + Unpin>(
    w: &mut W,
    text: String,
) -> std::io::Result<()> {
    match tokio::time::timeout(WRITE_TIMEOUT, w.write_all(text.as_bytes())).await {
        Ok(r) => r,
        Err(_) => Err(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            "the client did not read what it was sent",
        )),
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

/// Connects to the service's socket, sends one request and returns its reply (the clients:
/// `compend status`, `recalibrate`, `play`, `pause`, `stop`).
pub fn request(socket: &Path, req: &Request) -> Result<Reply> {
    // No service there is a failed operation (exit 1), not a mistake in what was asked
    // (exit 2, a typo in a flag); a socket this user may not use is the user's to fix.
    let stream = std::os::unix::net::UnixStream::connect(socket).map_err(|e| {
        let text = |hint: &str| format!("{}: cannot connect ({e}); {hint}", socket.display());
        match e.kind() {
            std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused => Error::Failed(
                text("is `compend serve` running? (systemctl status compend)"),
            ),
            std::io::ErrorKind::PermissionDenied => {
                Error::Input(text("this user may not use it: join the socket's group"))
            }
            _ => Error::Failed(format!("{}: cannot connect ({e})", socket.display())),
        }
    })?;
    exchange(socket, stream, req)
}

/// Sends `req` on a connected `stream` to `socket` and reads its reply. A service that refuses
/// the client (its uid) answers first and hangs up without reading, so a request that could
/// not be sent (a broken pipe) still has that answer to read.
fn exchange(
    socket: &Path,
    mut stream: std::os::unix::net::UnixStream,
    req: &Request,
) -> Result<Reply> {
    use std::io::{BufRead, Write};
    stream
        .set_read_timeout(Some(ENGINE_TIMEOUT + Duration::from_secs(5)))
        .map_err(|e| Error::io(socket, "set timeout", e))?;
    let mut line = serde_json::to_string(req).map_err(|e| Error::Failed(e.to_string()))?;
    line.push('\n');
    // The error of a request the service hung up on, kept in case it said nothing.
    let unsent = match stream.write_all(line.as_bytes()) {
        Ok(()) => None,
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset
            ) =>
        {
            Some(e)
        }
        Err(e) => return Err(Error::io(socket, "send request", e)),
    };
    let mut reader = std::io::BufReader::new(stream);
    let mut answer = String::new();
    let read = reader.read_line(&mut answer);
    if let Some(e) = unsent
        && answer.is_empty()
    {
        return Err(Error::io(socket, "send request", e));
    }
    read.map_err(|e| Error::io(socket, "read reply", e))?;
    if answer.is_empty() {
        return Err(Error::Failed(format!(
            "{}: the service closed the connection without a reply",
            socket.display()
        )));
    }
    serde_json::from_str(answer.trim()).map_err(|e| {
        Error::Failed(format!(
            "{}: unreadable reply ({e}): {}",
            socket.display(),
            answer.trim()
        ))
    })
}

/// A group's id: `name` as a number, or the group of that name (`None` when there is none, or
/// the group database cannot be read).
fn group_id(name: &str) -> Option<u32> {
    if let Ok(gid) = name.parse::<u32>() {
        return Some(gid);
    }
    let group = nix::unistd::Group::from_name(name).ok()??;
    Some(group.gid.as_raw())
}

fn chown_group(path: &Path, gid: u32) -> Result<()> {
    // No owner: it stays as it is.
    nix::unistd::chown(path, None, Some(nix::unistd::Gid::from_raw(gid)))
        .map_err(|e| Error::io(path, "set socket group", std::io::Error::from(e)))
}

/// Whether user `uid` is a member of group `gid` (its primary group or a supplementary one).
fn user_in_group(uid: u32, gid: u32) -> bool {
    let Ok(Some(user)) = nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid)) else {
        return false;
    };
    let Ok(name) = CString::new(user.name) else {
        return false;
    };
    nix::unistd::getgrouplist(&name, user.gid)
        .is_ok_and(|groups| groups.contains(&nix::unistd::Gid::from_raw(gid)))
}

/// The socket to talk to: `--socket`, else the one `--config` names, else the default.
pub fn resolve(socket: Option<PathBuf>, config: Option<&Path>) -> Result<PathBuf> {
    match (socket, config) {
        (Some(s), _) => Ok(s),
        (None, Some(c)) => Ok(crate::config::Config::load(c)?.socket.path),
        (None, None) => Ok(crate::config::Config::defaults().socket.path),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A service that answers and hangs up before the client has sent its request (as it does
    /// for a uid it refuses): the client reports that answer, not the broken pipe.
    #[test]
    fn a_reply_sent_before_the_request_is_read_is_the_answer() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let listener = std::os::unix::net::UnixListener::bind(&path).unwrap();
        let server = std::thread::spawn(move || {
            use std::io::Write;
            let (mut s, _) = listener.accept().unwrap();
            s.write_all(
                Reply::error("uid 1234 may not control this service")
                    .to_line()
                    .as_bytes(),
            )
            .unwrap();
        });
        let stream = std::os::unix::net::UnixStream::connect(&path).unwrap();
        server.join().unwrap();
        let reply = exchange(&path, stream, &Request::Status).unwrap();
        assert!(!reply.ok);
        assert_eq!(
            reply.error.as_deref(),
            Some("uid 1234 may not control this service")
        );
        // Hung up without a word: the error names the socket.
        let listener = std::os::unix::net::UnixListener::bind(dir.path().join("t.sock")).unwrap();
        let server = std::thread::spawn(move || drop(listener.accept().unwrap()));
        let stream = std::os::unix::net::UnixStream::connect(dir.path().join("t.sock")).unwrap();
        server.join().unwrap();
        let e = exchange(&dir.path().join("t.sock"), stream, &Request::Status).unwrap_err();
        assert!(e.to_string().contains("t.sock"), "{e}");
    }

    /// A token file readable by others than the service's user and group is warned about; one
    /// in the service's group is not.
    #[test]
    fn a_token_file_may_be_read_by_the_services_user_and_group_only() {
        for (mode, gid, warns) in [
            (0o600, 5, false),
            (0o640, 7, false),
            (0o640, 5, true),
            (0o604, 7, true),
            (0o660, 7, false),
            (0o400, 5, false),
        ] {
            assert_eq!(
                others_may_read(mode, gid, 7),
                warns,
                "mode {mode:o} group {gid}"
            );
        }
    }

    /// Without `[socket] group` the socket's group is the service user's (set on the file), and
    /// its members may connect; others only when root, the service's own user or listed.
    #[tokio::test]
    async fn the_socket_group_defaults_to_the_services_and_its_members_may_connect() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = crate::config::Config::defaults().socket;
        cfg.path = dir.path().join("s.sock");
        cfg.group = None;
        cfg.allow_uids = vec![4321];
        let (_listener, access) = bind(&cfg).unwrap();
        let file_gid = std::fs::metadata(&cfg.path).unwrap().gid();
        // SAFETY: getegid has no preconditions.
        assert_eq!(file_gid, unsafe { libc::getegid() });
        assert_eq!(access.group, file_gid);
        // A uid with no passwd entry is in no group but its primary one.
        let stranger = 987_654;
        assert!(access.allows(stranger, file_gid));
        assert!(!access.allows(stranger, file_gid + 1));
        assert!(access.allows(4321, file_gid + 1));
        assert!(access.allows(0, file_gid + 1));
        assert!(access.allows(access.own_uid, file_gid + 1));
    }

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
        let accepting = tokio::spawn(accept(
            Numbered(tokio::sync::Mutex::new(listener)),
            "test listener",
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

    fn token(text: &str) -> Token {
        Token(Arc::new(text.as_bytes().to_vec()))
    }

    #[test]
    fn a_tcp_request_needs_the_token_which_is_taken_out_of_it() {
        let t = token("0123456789abcdef0123");
        let ok = t
            .strip(br#"{"cmd":"play","source":"pattern:bars","token":"0123456789abcdef0123"}"#)
            .unwrap();
        let v: serde_json::Value = serde_json::from_slice(&ok).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"cmd": "play", "source": "pattern:bars"})
        );
        for bad in [
            &br#"{"cmd":"status"}"#[..],
            br#"{"cmd":"status","token":"0123456789abcdef012"}"#,
            br#"{"cmd":"status","token":"0123456789abcdef01234"}"#,
            br#"{"cmd":"status","token":"1123456789abcdef0123"}"#,
            br#"{"cmd":"status","token":12}"#,
            // The right token after a wrong one: a key given twice is refused whatever its values.
            br#"{"cmd":"status","token":"1123456789abcdef0123","token":"0123456789abcdef0123"}"#,
            br#"{"cmd":"status","token":"0123456789abcdef0123","token":"0123456789abcdef0123"}"#,
            // Read as `status` once the token is out, it would be `stop` to a map that keeps the
            // last key: refused before.
            br#"{"cmd":"stop","cmd":"status","token":"0123456789abcdef0123"}"#,
            br#"["0123456789abcdef0123"]"#,
            b"status 0123456789abcdef0123",
        ] {
            let e = t.strip(bad).unwrap_err();
            assert!(
                e.to_line().contains("tcp_token_file"),
                "{}: {}",
                String::from_utf8_lossy(bad),
                e.to_line()
            );
        }
    }

    #[test]
    fn a_token_file_must_hold_a_long_token() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("token");
        let e = Token::read(&path, "[socket] tcp_token_file")
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist") && e.contains("token"), "{e}");
        std::fs::write(&path, "short\n").unwrap();
        let e = Token::read(&path, "[socket] tcp_token_file")
            .unwrap_err()
            .to_string();
        assert!(e.contains("at least 16") && e.contains("holds 5"), "{e}");
        std::fs::write(&path, "two words that are long enough\n").unwrap();
        assert!(Token::read(&path, "[socket] tcp_token_file").is_err());
        std::fs::write(&path, "  0123456789abcdef0123\n").unwrap();
        let t = Token::read(&path, "[socket] tcp_token_file").unwrap();
        assert!(t.matches(b"0123456789abcdef0123"));
        assert!(!t.matches(b""));
        assert!(!t.matches(b"0123456789abcdef012"));
        assert!(!t.matches(b"0123456789abcdef01234"));
        assert!(!t.matches(b"1123456789abcdef0123"));
    }

    /// Groups by number or name, and a user's membership (its primary group counts), read
    /// from the system's databases: root is in group 0 on every system.
    #[test]
    fn groups_and_membership_come_from_the_system() {
        assert_eq!(group_id("0"), Some(0));
        assert_eq!(group_id("4242"), Some(4242));
        let root = nix::unistd::Group::from_gid(nix::unistd::Gid::from_raw(0))
            .unwrap()
            .unwrap();
        assert_eq!(group_id(&root.name), Some(0));
        assert_eq!(group_id("no-such-group-compend"), None);
        assert_eq!(group_id("a\0b"), None);
        assert!(user_in_group(0, 0));
        // A uid no user has is in no group.
        assert!(!user_in_group(3_999_999_999, 0));
    }
}
