//! `[socket]`: the control socket, and its loopback TCP twin.

use std::path::PathBuf;

use serde::Serialize;

use super::read::{Table, Walker, span_of};

/// `[socket]`: the control socket.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SocketConfig {
    pub path: PathBuf,
    /// File mode of the socket (octal in the file, e.g. "0660").
    pub mode: u32,
    /// Group the socket belongs to; its members may connect (None: the service user's).
    pub group: Option<String>,
    /// User ids allowed besides root, the service's own user and the group's members.
    pub allow_uids: Vec<u32>,
    /// The same API on a loopback TCP address, for show-control software (None: off).
    pub tcp: Option<std::net::SocketAddr>,
    /// The file holding the token every TCP request must carry (required with `tcp`).
    pub tcp_token_file: Option<PathBuf>,
}

impl Default for SocketConfig {
    /// In systemd's runtime directory, mode 0660, no TCP.
    fn default() -> Self {
        SocketConfig {
            path: default_socket(),
            mode: 0o660,
            group: None,
            allow_uids: Vec::new(),
            tcp: None,
            tcp_token_file: None,
        }
    }
}

impl SocketConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        let path = w.get(t, "path").unwrap_or(d.path);
        let mode = w
            .parsed_with(t, "mode", |s: &str| {
                let digits = s.strip_prefix("0o").unwrap_or(s);
                match u32::from_str_radix(digits, 8) {
                    Ok(m) if m <= 0o777 => Ok(m),
                    _ => Err(format!(
                        "\"{s}\" is not a file mode; expected octal digits such as \"0660\""
                    )),
                }
            })
            .unwrap_or(d.mode);
        let group = w.get(t, "group").or(d.group);
        let allow_uids = w.get(t, "allow_uids").unwrap_or(d.allow_uids);
        let tcp_span = span_of(t, "tcp");
        let has_tcp = t.entries.iter().any(|(k, _, _)| k == "tcp");
        let tcp = w.parsed_with(t, "tcp", |s: &str| {
            let addr: std::net::SocketAddr = s.parse().map_err(|_| {
                format!("\"{s}\" is not an address; expected IP:PORT such as \"127.0.0.1:7420\"")
            })?;
            if !addr.ip().is_loopback() {
                return Err(format!(
                    "\"{s}\" is not a loopback address: the TCP API listens on this machine \
                     only (127.0.0.1 or [::1])"
                ));
            }
            Ok(addr)
        });
        let tcp_token_file: Option<PathBuf> = w.get(t, "tcp_token_file");
        if has_tcp && tcp_token_file.is_none() {
            w.error(
                tcp_span,
                "[socket] tcp needs tcp_token_file, a file holding the token every TCP request \
                 carries"
                    .into(),
            );
        }
        SocketConfig {
            path,
            mode,
            group,
            allow_uids,
            tcp,
            tcp_token_file,
        }
    }
}

/// The socket when the file does not name one: in systemd's `$RUNTIME_DIRECTORY`, else
/// /run/compend/compend.sock.
fn default_socket() -> PathBuf {
    std::env::var_os("RUNTIME_DIRECTORY")
        .and_then(|v| {
            v.to_str()
                .and_then(|s| s.split(':').next())
                .map(PathBuf::from)
        })
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or_else(|| PathBuf::from("/run/compend"))
        .join("compend.sock")
}
