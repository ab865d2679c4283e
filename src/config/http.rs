//! `[http]`: the operator's console (a web page), its event stream and metrics.

use std::path::PathBuf;

use serde::Serialize;

use super::read::{Table, Walker, span_of};
use super::{display_or_none, displayed_list};

/// The console's address unless `[http] listen` says otherwise.
pub const DEFAULT_HTTP: &str = "127.0.0.1:7421";

/// `[http]`: the operator's console (a web page), its event stream and metrics.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HttpConfig {
    /// Where it listens (None: off). Loopback by default; another address needs `token_file`
    /// and `allow`.
    #[serde(serialize_with = "display_or_none")]
    pub listen: Option<std::net::SocketAddr>,
    /// The file holding the token a client from another machine gives (a header, or the login
    /// page's cookie).
    pub token_file: Option<PathBuf>,
    /// Networks clients from other machines may come from (`10.0.0.0/24`); loopback always may.
    #[serde(serialize_with = "displayed_list")]
    pub allow: Vec<ipnet::IpNet>,
    /// HTTPS: the certificate chain and its private key (PEM files); both or neither.
    pub tls: Option<TlsFiles>,
}

/// A certificate chain and its private key, PEM files.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TlsFiles {
    pub cert: PathBuf,
    pub key: PathBuf,
}

impl Default for HttpConfig {
    /// On loopback at [`DEFAULT_HTTP`], plain HTTP, no other machine let in.
    fn default() -> Self {
        HttpConfig {
            listen: DEFAULT_HTTP.parse().ok(),
            token_file: None,
            allow: Vec::new(),
            tls: None,
        }
    }
}

impl HttpConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        let listen_span = span_of(t, "listen");
        let listen = w
            .parsed_with(t, "listen", |s: &str| {
                if s == "off" {
                    return Ok(None);
                }
                s.parse::<std::net::SocketAddr>().map(Some).map_err(|_| {
                    format!(
                        "\"{s}\" is not an address; expected IP:PORT such as \"{DEFAULT_HTTP}\", \
                         or \"off\""
                    )
                })
            })
            .unwrap_or(d.listen);
        let token_file: Option<PathBuf> = w.get(t, "token_file");
        let nets = w.networks(t);
        if let Some(addr) = listen
            && !addr.ip().is_loopback()
        {
            if token_file.is_none() {
                w.error(
                    listen_span.clone(),
                    format!(
                        "[http] listen = \"{addr}\" is reachable from other machines: it needs \
                         token_file, a file holding the token their requests carry"
                    ),
                );
            }
            if nets.is_empty() {
                w.error(
                    listen_span,
                    format!(
                        "[http] listen = \"{addr}\" is reachable from other machines: it needs \
                         allow, the networks they may come from (e.g. [\"10.0.0.0/24\"])"
                    ),
                );
            }
        }
        let cert_span = span_of(t, "tls_cert");
        let cert: Option<PathBuf> = w.get(t, "tls_cert");
        let key_span = span_of(t, "tls_key");
        let key: Option<PathBuf> = w.get(t, "tls_key");
        let tls = match (cert, key) {
            (Some(cert), Some(key)) => Some(TlsFiles { cert, key }),
            (None, None) => None,
            (Some(_), None) => {
                w.error(
                    cert_span,
                    "[http] tls_cert needs tls_key, the certificate's private key".into(),
                );
                None
            }
            (None, Some(_)) => {
                w.error(
                    key_span,
                    "[http] tls_key needs tls_cert, the certificate chain it signs for".into(),
                );
                None
            }
        };
        HttpConfig {
            listen,
            token_file,
            allow: nets,
            tls,
        }
    }
}
