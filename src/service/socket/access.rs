//! Who may use the control socket and the control port: the socket file made safe to bind
//! (a live service's, or a path that is not a socket, is refused), its group and mode, the
//! peers' credentials checked against them, and the TCP port's token.

use std::ffi::CString;
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::path::Path;
use std::sync::Arc;

use tokio::net::{TcpListener, UnixListener};

use crate::config::SocketConfig;
use crate::error::{Error, Result};
use crate::service::protocol::Reply;

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
    pub(super) fn allows(&self, uid: u32, gid: u32) -> bool {
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
pub(super) fn others_may_read(mode: u32, gid: u32, own_gid: u32) -> bool {
    mode & 0o007 != 0 || (mode & 0o070 != 0 && gid != own_gid)
}

/// Shortest token accepted, bytes: 16 random bytes as hex or base64 are longer.
pub(super) const MIN_TOKEN_BYTES: usize = 16;

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
    pub(super) fn strip(&self, line: &[u8]) -> std::result::Result<Vec<u8>, Reply> {
        let refuse = || {
            Reply::error(
                "a request on the TCP port must be one JSON object with \"token\", the token of \
                 [socket] tcp_token_file; this one has none or another",
            )
        };
        // `{"token":"wrong","token":"right"}` would pass a check of the parsed value, and
        // `{"cmd":"status","cmd":"stop"}` would be read as `stop` once the token is taken out:
        // a key given twice is refused on the raw line, before the token is looked at.
        crate::service::protocol::unique_keys(line).map_err(|e| {
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

/// A group's id: `name` as a number, or the group of that name (`None` when there is none, or
/// the group database cannot be read).
pub(super) fn group_id(name: &str) -> Option<u32> {
    if let Ok(gid) = name.parse::<u32>() {
        return Some(gid);
    }
    let group = nix::unistd::Group::from_name(name).ok()??;
    Some(group.gid.as_raw())
}

pub(super) fn chown_group(path: &Path, gid: u32) -> Result<()> {
    // No owner: it stays as it is.
    nix::unistd::chown(path, None, Some(nix::unistd::Gid::from_raw(gid)))
        .map_err(|e| Error::io(path, "set socket group", std::io::Error::from(e)))
}

/// Whether user `uid` is a member of group `gid` (its primary group or a supplementary one).
pub(super) fn user_in_group(uid: u32, gid: u32) -> bool {
    let Ok(Some(user)) = nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid)) else {
        return false;
    };
    let Ok(name) = CString::new(user.name) else {
        return false;
    };
    nix::unistd::getgrouplist(&name, user.gid)
        .is_ok_and(|groups| groups.contains(&nix::unistd::Gid::from_raw(gid)))
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(file_gid, nix::unistd::getegid().as_raw());
        assert_eq!(access.group, file_gid);
        // A uid with no passwd entry is in no group but its primary one.
        let stranger = 987_654;
        assert!(access.allows(stranger, file_gid));
        assert!(!access.allows(stranger, file_gid + 1));
        assert!(access.allows(4321, file_gid + 1));
        assert!(access.allows(0, file_gid + 1));
        assert!(access.allows(access.own_uid, file_gid + 1));
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
