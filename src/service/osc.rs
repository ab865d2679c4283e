//! Open Sound Control for show-control software (QLab, TouchOSC, Chataigne...): `[osc] listen`,
//! off by default, a UDP port on the service's tokio runtime.
//!
//! Messages are mapped onto the control socket's requests and go the same way
//! ([`super::socket::dispatch`]: the same checks, the log and the events with the origin
//! `osc IP:PORT`):
//!
//! | address | request |
//! |---|---|
//! | `/compend/play` (string: a source, optional) | `play` |
//! | `/compend/resume` | `play` without a source |
//! | `/compend/pause` | `pause` |
//! | `/compend/next`, `/compend/previous` | `next`, `previous` |
//! | `/compend/seek` (number: seconds) | `seek` |
//! | `/compend/model` (string: a model folder) | `model` |
//! | `/compend/calibrate`, `/compend/recalibrate` | `calibrate`, `recalibrate` |
//! | `/compend/refit` | `refit` |
//! | `/compend/status` | answered with `/compend/state` |
//!
//! `stop` has no address: OSC carries no credentials, and stopping the service is left to the
//! machine's own users. A message whose only argument is the number 0 is skipped: that is a
//! button's release on a TouchOSC-like surface, whose press (1) was the request.
//!
//! Each request is answered to its sender with `/compend/reply` (int 1 or 0: done or refused,
//! string: what happened). The service's events go to every `[osc] peers` address:
//! `/compend/state` (string: the new state), `/compend/score` (float: a monitoring PSNR, dB)
//! and `/compend/event` (strings: its kind and text), so a show controller can follow it.
//!
//! Senders must be on this machine, or in `[osc] allow`. At most [`IN_FLIGHT`] requests wait for
//! the engine at once; a message past them is answered as refused.

use std::net::SocketAddr;
use std::sync::Arc;

use rosc::{OscMessage, OscPacket, OscType};
use tokio::net::UdpSocket;
use tokio::sync::{Semaphore, broadcast};

use super::Shared;
use super::events::Kind;
use super::protocol::{Reply, Request};
use crate::config::OscConfig;
use crate::error::{Error, Result};

/// Requests from OSC waiting for the engine at once.
pub const IN_FLIGHT: usize = 8;
/// Bundles nested deeper than this are not looked into.
const MAX_DEPTH: usize = 4;

/// Binds `[osc] listen`; None when it is off.
pub fn bind(cfg: &OscConfig) -> Result<Option<UdpSocket>> {
    let Some(addr) = cfg.listen else {
        return Ok(None);
    };
    let std = std::net::UdpSocket::bind(addr).map_err(|e| match e.kind() {
        std::io::ErrorKind::AddrInUse => Error::Input(format!(
            "[osc] listen = \"{addr}\": the port is in use (another compend service, or another \
             program); give another port"
        )),
        _ => Error::Failed(format!("[osc] listen = \"{addr}\": cannot listen: {e}")),
    })?;
    std.set_nonblocking(true)
        .map_err(|e| Error::Failed(format!("[osc] listen = \"{addr}\": {e}")))?;
    UdpSocket::from_std(std)
        .map(Some)
        .map_err(|e| Error::Failed(format!("[osc] listen = \"{addr}\": {e}")))
}

/// What an OSC message asks.
#[derive(Debug, PartialEq)]
enum Asked {
    Request(Request),
    Status,
    /// A button's release: nothing.
    Release,
}

/// The request of message `m`, or why there is none.
fn asked(m: &OscMessage) -> std::result::Result<Asked, String> {
    let number = |t: &OscType| match t {
        OscType::Int(i) => Some(f64::from(*i)),
        OscType::Float(f) => Some(f64::from(*f)),
        OscType::Double(d) => Some(*d),
        OscType::Long(l) => Some(*l as f64),
        _ => None,
    };
    if let [only] = m.args.as_slice()
        && number(only) == Some(0.0)
        && m.addr != "/compend/seek"
    {
        return Ok(Asked::Release);
    }
    let text = |i: usize| match m.args.get(i) {
        Some(OscType::String(s)) => Ok(Some(s.clone())),
        None => Ok(None),
        Some(other) => Err(format!("{}: expected a string, got {other:?}", m.addr)),
    };
    let json = match m.addr.as_str() {
        "/compend/status" => return Ok(Asked::Status),
        "/compend/play" => match text(0)? {
            Some(s) => serde_json::json!({"cmd": "play", "source": s}),
            None => serde_json::json!({"cmd": "play"}),
        },
        "/compend/resume" => serde_json::json!({"cmd": "play"}),
        "/compend/pause" => serde_json::json!({"cmd": "pause"}),
        "/compend/next" => serde_json::json!({"cmd": "next"}),
        "/compend/previous" => serde_json::json!({"cmd": "previous"}),
        "/compend/calibrate" => serde_json::json!({"cmd": "calibrate"}),
        "/compend/recalibrate" => serde_json::json!({"cmd": "recalibrate"}),
        "/compend/refit" => serde_json::json!({"cmd": "refit"}),
        "/compend/seek" => {
            let s = m.args.first().and_then(number).ok_or_else(|| {
                "/compend/seek: expected one number, the position in seconds".to_string()
            })?;
            serde_json::json!({"cmd": "seek", "position_s": s})
        }
        "/compend/model" => {
            let p = text(0)?
                .ok_or_else(|| "/compend/model: expected one string, a model folder".to_string())?;
            serde_json::json!({"cmd": "model", "path": p})
        }
        other => {
            return Err(format!(
                "{other}: not an address of compend; it answers /compend/play, /resume, \
                 /pause, /next, /previous, /seek, /model, /calibrate, /recalibrate, /refit, /status"
            ));
        }
    };
    Request::parse(json.to_string().as_bytes()).map(Asked::Request)
}

/// The messages of `p`, bundles opened up to [`MAX_DEPTH`].
fn messages(p: OscPacket, depth: usize, out: &mut Vec<OscMessage>) {
    match p {
        OscPacket::Message(m) => out.push(m),
        OscPacket::Bundle(b) if depth < MAX_DEPTH => {
            for p in b.content {
                messages(p, depth + 1, out);
            }
        }
        OscPacket::Bundle(_) => {}
    }
}

fn packet(addr: &str, args: Vec<OscType>) -> Option<Vec<u8>> {
    rosc::encoder::encode(&OscPacket::Message(OscMessage {
        addr: addr.to_string(),
        args,
    }))
    .ok()
}

fn reply_packet(r: &Reply) -> Option<Vec<u8>> {
    let text = match (&r.error, &r.message) {
        (Some(e), _) => e.clone(),
        (None, Some(m)) => m.clone(),
        (None, None) => String::new(),
    };
    packet(
        "/compend/reply",
        vec![OscType::Int(i32::from(r.ok)), OscType::String(text)],
    )
}

/// Serves OSC on `sock` until the runtime shuts down; events go to `cfg.peers`.
pub async fn serve(sock: UdpSocket, cfg: OscConfig, shared: Arc<Shared>) {
    let sock = Arc::new(sock);
    if !cfg.peers.is_empty() {
        tokio::spawn(tell_peers(
            sock.clone(),
            cfg.peers.clone(),
            shared.hub.subscribe(),
        ));
    }
    let in_flight = Arc::new(Semaphore::new(IN_FLIGHT));
    let refusals = super::refusals::Refusals::new("osc");
    // An OSC packet fits one UDP datagram.
    let mut buf = vec![0u8; 65_536];
    loop {
        let received = tokio::select! {
            got = sock.recv_from(&mut buf) => got,
            () = shared.stopped() => return,
        };
        let (n, peer) = match received {
            Ok(got) => got,
            Err(e) => {
                tracing::debug!("osc: receive: {e}");
                continue;
            }
        };
        let ip = peer.ip().to_canonical();
        if !ip.is_loopback() && !cfg.allow.iter().any(|net| net.contains(&ip)) {
            // Logged once a minute at most per sender; nothing is answered.
            refusals.refused(&ip.to_string(), "a message dropped: not in [osc] allow");
            continue;
        }
        let mut found = Vec::new();
        match rosc::decoder::decode_udp(&buf[..n]) {
            Ok((_, p)) => messages(p, 0, &mut found),
            Err(e) => {
                let r = Reply::error(format!("not an OSC packet: {e}"));
                if let Some(b) = reply_packet(&r) {
                    let _ = sock.send_to(&b, peer).await;
                }
                continue;
            }
        }
        for m in found {
            let reply = match asked(&m) {
                Ok(Asked::Release) => continue,
                Ok(Asked::Status) => {
                    let state = shared.status().state.name().to_string();
                    if let Some(b) = packet("/compend/state", vec![OscType::String(state)]) {
                        let _ = sock.send_to(&b, peer).await;
                    }
                    continue;
                }
                Err(e) => Reply::error(e),
                Ok(Asked::Request(req)) => match in_flight.clone().try_acquire_owned() {
                    Ok(slot) => {
                        let (sock, shared) = (sock.clone(), shared.clone());
                        tokio::spawn(async move {
                            let origin = format!("osc {peer}");
                            let r = super::socket::dispatch(req, &shared, &origin).await;
                            drop(slot);
                            if let Some(b) = reply_packet(&r) {
                                let _ = sock.send_to(&b, peer).await;
                            }
                        });
                        continue;
                    }
                    Err(_) => Reply::error(format!(
                        "{IN_FLIGHT} OSC requests are waiting for the service already; this one \
                         was dropped"
                    )),
                },
            };
            if let Some(b) = reply_packet(&reply) {
                let _ = sock.send_to(&b, peer).await;
            }
        }
    }
}

/// Sends the service's events to `peers` as they come.
async fn tell_peers(
    sock: Arc<UdpSocket>,
    peers: Vec<SocketAddr>,
    mut rx: broadcast::Receiver<super::events::Event>,
) {
    loop {
        let e = match rx.recv().await {
            Ok(e) => e,
            Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => return,
        };
        let mut out = Vec::new();
        match (e.kind, e.state, e.psnr) {
            (Kind::State, Some(s), _) => {
                out.extend(packet(
                    "/compend/state",
                    vec![OscType::String(s.name().to_string())],
                ));
            }
            (Kind::Score, _, Some(p)) => {
                out.extend(packet("/compend/score", vec![OscType::Float(p as f32)]));
            }
            _ => {}
        }
        let kind = serde_json::to_value(e.kind)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default();
        if e.kind != Kind::Score {
            out.extend(packet(
                "/compend/event",
                vec![OscType::String(kind), OscType::String(e.text.clone())],
            ));
        }
        for b in &out {
            for p in &peers {
                if let Err(err) = sock.send_to(b, p).await {
                    tracing::debug!("osc: sending to {p}: {err}");
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(addr: &str, args: Vec<OscType>) -> OscMessage {
        OscMessage {
            addr: addr.into(),
            args,
        }
    }

    #[test]
    fn addresses_map_onto_requests_and_a_release_does_nothing() {
        assert_eq!(
            asked(&msg("/compend/pause", vec![])),
            Ok(Asked::Request(Request::Pause))
        );
        assert_eq!(
            asked(&msg("/compend/pause", vec![OscType::Float(1.0)])),
            Ok(Asked::Request(Request::Pause))
        );
        assert_eq!(
            asked(&msg("/compend/pause", vec![OscType::Float(0.0)])),
            Ok(Asked::Release)
        );
        assert_eq!(
            asked(&msg(
                "/compend/play",
                vec![OscType::String("pattern:bars".into())]
            )),
            Ok(Asked::Request(Request::Play {
                source: Some("pattern:bars".into())
            }))
        );
        assert_eq!(
            asked(&msg("/compend/seek", vec![OscType::Int(0)])),
            Ok(Asked::Request(Request::Seek { position_s: 0.0 }))
        );
        assert!(
            asked(&msg("/compend/seek", vec![OscType::Float(-3.0)]))
                .unwrap_err()
                .contains("position_s")
        );
        assert!(
            asked(&msg("/compend/model", vec![OscType::Int(3)]))
                .unwrap_err()
                .contains("expected a string")
        );
        let e = asked(&msg("/compend/stop", vec![])).unwrap_err();
        assert!(e.contains("not an address of compend"), "{e}");
    }

    #[test]
    fn bundles_are_opened_to_a_depth() {
        let mut inner = OscPacket::Message(msg("/compend/next", vec![]));
        for _ in 0..6 {
            inner = OscPacket::Bundle(rosc::OscBundle {
                timetag: rosc::OscTime::from((0, 1)),
                content: vec![inner],
            });
        }
        let mut out = Vec::new();
        messages(inner, 0, &mut out);
        assert!(out.is_empty());
        let shallow = OscPacket::Bundle(rosc::OscBundle {
            timetag: rosc::OscTime::from((0, 1)),
            content: vec![
                OscPacket::Message(msg("/compend/next", vec![])),
                OscPacket::Message(msg("/compend/pause", vec![])),
            ],
        });
        messages(shallow, 0, &mut out);
        assert_eq!(out.len(), 2);
    }
}
