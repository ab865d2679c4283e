//! `[osc]`: Open Sound Control for show-control software.

use serde::Serialize;

use super::display_or_none;
use super::displayed_list;
use super::read::{Table, Walker, span_of};

/// `[osc]`: Open Sound Control for show-control software.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct OscConfig {
    /// The UDP address it listens on (None: off, the default).
    #[serde(serialize_with = "display_or_none")]
    pub listen: Option<std::net::SocketAddr>,
    /// Networks senders on other machines may come from; loopback always may.
    #[serde(serialize_with = "displayed_list")]
    pub allow: Vec<ipnet::IpNet>,
    /// Where the service's state and events are sent (`IP:PORT`).
    #[serde(serialize_with = "displayed_list")]
    pub peers: Vec<std::net::SocketAddr>,
}

impl OscConfig {
    /// Off unless `listen` names where; nothing sent unless `peers` name where.
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let listen_span = span_of(t, "listen");
        let listen = w.parsed_with(t, "listen", |s: &str| {
            s.parse::<std::net::SocketAddr>().map_err(|_| {
                format!("\"{s}\" is not an address; expected IP:PORT such as \"127.0.0.1:7422\"")
            })
        });
        let allow = w.networks(t);
        let peers_span = span_of(t, "peers");
        let peers: Vec<String> = w.get(t, "peers").unwrap_or_default();
        let mut addrs = Vec::new();
        for p in &peers {
            match p.parse::<std::net::SocketAddr>() {
                Ok(a) => addrs.push(a),
                Err(_) => w.error(
                    peers_span.clone(),
                    format!(
                        "[osc] peers: \"{p}\" is not an address; expected IP:PORT such as \
                         \"10.0.0.9:53000\""
                    ),
                ),
            }
        }
        if let Some(addr) = listen
            && !addr.ip().is_loopback()
            && allow.is_empty()
        {
            w.error(
                listen_span,
                format!(
                    "[osc] listen = \"{addr}\" is reachable from other machines: it needs allow, \
                     the networks senders may come from (e.g. [\"10.0.0.0/24\"]); OSC carries no \
                     token"
                ),
            );
        }
        OscConfig {
            listen,
            allow,
            peers: addrs,
        }
    }
}
