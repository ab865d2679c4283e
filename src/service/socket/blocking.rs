//! The blocking client of the control socket (`compend status`, `recalibrate`, `ctl` …): one
//! request, one reply, and where the socket is.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::ENGINE_TIMEOUT;
use crate::error::{Error, Result};
use crate::service::protocol::{Reply, Request};

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
pub(super) fn exchange(
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
}
