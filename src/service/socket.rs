//! The control socket: a Unix stream socket, one JSON request and one JSON reply per line
//! ([`super::protocol`]), many clients at once, each on a task of the tokio runtime.
//!
//! `status` is answered from the shared snapshot without involving the engine, so it answers
//! within milliseconds while the engine trains; other requests go to the engine thread and their
//! reply comes back on a oneshot channel. A malformed, oversized or unknown request gets an error
//! reply and the connection goes on. Peers are checked by their credentials (`SO_PEERCRED`):
//! root, the service's own user, the socket's group and `allow_uids` may connect.

use std::ffi::CString;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{Semaphore, oneshot};

use super::protocol::{MAX_REQUEST_BYTES, Reply, Request};
use super::{Envelope, Shared};
use crate::config::SocketConfig;
use crate::error::{Error, Result};

/// Connections served at once; more wait for a free slot.
const MAX_CLIENTS: usize = 64;

/// How long a request waits for the engine (it answers between two refreshes, two captures).
const ENGINE_TIMEOUT: Duration = Duration::from_secs(30);

/// Who may connect.
#[derive(Clone, Debug)]
pub struct Access {
    own_uid: u32,
    group: Option<u32>,
    allow_uids: Vec<u32>,
}

impl Access {
    /// Whether a peer with these credentials may talk to the service.
    fn allows(&self, uid: u32, gid: u32) -> bool {
        if uid == 0 || uid == self.own_uid || self.allow_uids.contains(&uid) {
            return true;
        }
        match self.group {
            Some(g) => gid == g || user_in_group(uid, g),
            None => false,
        }
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
        Ok(_) => {
            return Err(Error::Input(format!(
                "{}: exists and is not a socket; [socket] path must name a free path or an old \
                 compend socket",
                path.display()
            )));
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(Error::io(path, "inspect", e)),
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
            Some(gid)
        }
        None => None,
    };
    // SAFETY: geteuid has no preconditions and cannot fail.
    let own_uid = unsafe { libc::geteuid() };
    Ok((
        listener,
        Access {
            own_uid,
            group,
            allow_uids: cfg.allow_uids.clone(),
        },
    ))
}

/// Accepts clients until the runtime shuts down.
pub async fn serve(listener: UnixListener, access: Access, shared: Arc<Shared>) {
    let slots = Arc::new(Semaphore::new(MAX_CLIENTS));
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                tracing::warn!("control socket: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(permit) = slots.clone().acquire_owned().await else {
            return;
        };
        let shared = shared.clone();
        let access = access.clone();
        tokio::spawn(async move {
            if let Err(e) = client(stream, &access, &shared).await {
                tracing::debug!("control socket: client ended: {e}");
            }
            drop(permit);
        });
    }
}

/// One client: its requests in order, until it hangs up.
async fn client(stream: UnixStream, access: &Access, shared: &Shared) -> std::io::Result<()> {
    let cred = stream.peer_cred()?;
    let (read, mut write) = stream.into_split();
    if !access.allows(cred.uid(), cred.gid()) {
        tracing::warn!(
            "control socket: refused a client with uid {} gid {} (pid {:?})",
            cred.uid(),
            cred.gid(),
            cred.pid()
        );
        let reply = Reply::error(format!(
            "uid {} may not control this service: add it to the socket's group or to [socket] \
             allow_uids",
            cred.uid()
        ));
        write.write_all(reply.to_line().as_bytes()).await?;
        return Ok(());
    }
    let mut read = BufReader::new(read);
    let mut line = Vec::new();
    loop {
        match read_line(&mut read, &mut line).await? {
            Line::End => return Ok(()),
            Line::TooLong => {
                let reply = Reply::error(format!(
                    "request longer than {MAX_REQUEST_BYTES} bytes; it was skipped"
                ));
                write.write_all(reply.to_line().as_bytes()).await?;
            }
            Line::Complete => {
                let reply = answer(&line, shared).await;
                write.write_all(reply.to_line().as_bytes()).await?;
            }
        }
    }
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

/// The reply to one request line.
async fn answer(line: &[u8], shared: &Shared) -> Reply {
    let request = match Request::parse(line) {
        Ok(r) => r,
        Err(e) => return Reply::error(e),
    };
    if request == Request::Status {
        return Reply::status(shared.status());
    }
    let (tx, rx) = oneshot::channel();
    if !shared.send(Envelope {
        request,
        reply: Some(tx),
    }) {
        return Reply::error("the service is shutting down");
    }
    match tokio::time::timeout(ENGINE_TIMEOUT, rx).await {
        Ok(Ok(reply)) => reply,
        Ok(Err(_)) => Reply::error("the service is shutting down"),
        Err(_) => Reply::error(format!(
            "the service did not answer within {} s; see compend status",
            ENGINE_TIMEOUT.as_secs()
        )),
    }
}

/// Connects to the service's socket, sends one request and returns its reply (the clients:
/// `compend status`, `recalibrate`, `play`, `pause`, `stop`).
pub fn request(socket: &Path, req: &Request) -> Result<Reply> {
    use std::io::{BufRead, Write};
    let mut stream = std::os::unix::net::UnixStream::connect(socket).map_err(|e| {
        let hint = match e.kind() {
            std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused => {
                "is `compend serve` running? (systemctl status compend)"
            }
            std::io::ErrorKind::PermissionDenied => {
                "this user may not use it: join the socket's group"
            }
            _ => "",
        };
        Error::Input(format!(
            "{}: cannot connect ({e}); {hint}",
            socket.display()
        ))
    })?;
    stream
        .set_read_timeout(Some(ENGINE_TIMEOUT + Duration::from_secs(5)))
        .map_err(|e| Error::io(socket, "set timeout", e))?;
    let mut line = serde_json::to_string(req).map_err(|e| Error::Failed(e.to_string()))?;
    line.push('\n');
    stream
        .write_all(line.as_bytes())
        .map_err(|e| Error::io(socket, "send request", e))?;
    let mut reader = std::io::BufReader::new(stream);
    let mut answer = String::new();
    reader
        .read_line(&mut answer)
        .map_err(|e| Error::io(socket, "read reply", e))?;
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

fn group_id(name: &str) -> Option<u32> {
    if let Ok(gid) = name.parse::<u32>() {
        return Some(gid);
    }
    let c = CString::new(name).ok()?;
    let mut buf = vec![0 as libc::c_char; 16 * 1024];
    let mut grp: libc::group = unsafe { std::mem::zeroed() };
    let mut out: *mut libc::group = std::ptr::null_mut();
    // SAFETY: every pointer is valid for the call; buf outlives it and its length is passed.
    let rc =
        unsafe { libc::getgrnam_r(c.as_ptr(), &mut grp, buf.as_mut_ptr(), buf.len(), &mut out) };
    (rc == 0 && !out.is_null()).then_some(grp.gr_gid)
}

fn chown_group(path: &Path, gid: u32) -> Result<()> {
    let c = CString::new(path.as_os_str().as_encoded_bytes())
        .map_err(|_| Error::Input(format!("{}: path holds a NUL byte", path.display())))?;
    // SAFETY: c is a valid NUL-terminated path; uid -1 leaves the owner unchanged.
    let rc = unsafe { libc::chown(c.as_ptr(), u32::MAX, gid) };
    if rc != 0 {
        return Err(Error::io(
            path,
            "set socket group",
            std::io::Error::last_os_error(),
        ));
    }
    Ok(())
}

/// Whether user `uid` is a member of group `gid` (its supplementary groups).
fn user_in_group(uid: u32, gid: u32) -> bool {
    let mut buf = vec![0 as libc::c_char; 16 * 1024];
    let mut pw: libc::passwd = unsafe { std::mem::zeroed() };
    let mut out: *mut libc::passwd = std::ptr::null_mut();
    // SAFETY: as in group_id.
    let rc = unsafe { libc::getpwuid_r(uid, &mut pw, buf.as_mut_ptr(), buf.len(), &mut out) };
    if rc != 0 || out.is_null() {
        return false;
    }
    let mut groups = vec![0 as libc::gid_t; 256];
    let mut n = groups.len() as libc::c_int;
    // SAFETY: pw_name points into buf (alive); groups has room for n entries.
    let rc = unsafe { libc::getgrouplist(pw.pw_name, pw.pw_gid, groups.as_mut_ptr(), &mut n) };
    rc >= 0 && groups[..n.max(0) as usize].contains(&gid)
}

/// The socket to talk to: `--socket`, else the one `--config` names, else the default.
pub fn resolve(socket: Option<PathBuf>, config: Option<&Path>) -> Result<PathBuf> {
    match (socket, config) {
        (Some(s), _) => Ok(s),
        (None, Some(c)) => Ok(crate::config::Config::load(c)?.socket.path),
        (None, None) => Ok(crate::config::Config::defaults().socket.path),
    }
}
