//! Clients refused again and again: a wrong token on the TCP port or the console, a uid the
//! control socket does not allow, OSC from a network not in `[osc] allow`.
//!
//! Each listener keeps one [`Refusals`]. A peer (an IP address, or `uid N` on the Unix socket)
//! gets [`FREE_TRIES`] refusals in a row; after that it is **backed off**: for a time that
//! doubles with each further refusal, from [`FIRST_BACKOFF`] up to [`MAX_BACKOFF`], its requests
//! are refused at once, without their token being looked at, with the time left in the reply.
//! A right token (or any request that is let in) forgives the peer. Guessing a token of 16 or
//! more random bytes is hopeless anyway; the backoff keeps a flood of wrong tokens from costing
//! the service its CPU and the operator a log of millions of lines.
//!
//! The log gets the first refusal of a peer, then at most one line per peer per
//! [`LOG_PERIOD`]: how many refusals were not logged since, and the last reason.
//!
//! Peers on the TCP port's loopback all share the address 127.0.0.1: one local user flooding it
//! backs off the others for at most [`MAX_BACKOFF`] at a time. Local clients should use the Unix
//! socket, which tells users apart.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Refusals in a row before a peer is backed off.
pub const FREE_TRIES: u32 = 5;
/// The first backoff, after [`FREE_TRIES`] refusals; it doubles with each refusal after.
pub const FIRST_BACKOFF: Duration = Duration::from_millis(250);
/// The longest backoff.
pub const MAX_BACKOFF: Duration = Duration::from_secs(8);
/// At most one log line per peer in this time.
pub const LOG_PERIOD: Duration = Duration::from_secs(60);
/// Peers remembered at once; the one refused longest ago is forgotten for a new one.
const MAX_PEERS: usize = 4096;
/// A peer not refused for this long is forgotten (after its summary is logged).
const FORGET_AFTER: Duration = Duration::from_secs(600);

/// What is known of one peer.
#[derive(Debug)]
struct Peer {
    /// Refusals in a row (reset when the peer is let in).
    in_a_row: u32,
    /// Backed off until then.
    until: Option<Instant>,
    /// The last refusal, and why.
    last: Instant,
    why: String,
    /// When the last log line about this peer was written (None: never), and refusals not
    /// logged since.
    logged: Option<Instant>,
    unlogged: u64,
}

/// The refusals of one listener (see the module documentation).
#[derive(Debug)]
pub struct Refusals {
    /// The listener, for the log: `control port`, `console`...
    what: &'static str,
    peers: Mutex<HashMap<String, Peer>>,
    /// When the peers were last swept for summaries to log and peers to forget.
    swept: Mutex<Instant>,
}

impl Refusals {
    pub fn new(what: &'static str) -> Self {
        Self {
            what,
            peers: Mutex::new(HashMap::new()),
            swept: Mutex::new(Instant::now()),
        }
    }

    fn peers(&self) -> std::sync::MutexGuard<'_, HashMap<String, Peer>> {
        self.peers.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Before a request of `peer` is looked at: `Err(the reply)` while the peer is backed off.
    /// The refusal is counted (for the log) but does not lengthen the backoff, so a peer that
    /// waits as told is let in.
    pub fn admit(&self, peer: &str) -> Result<(), String> {
        self.admit_at(peer, Instant::now())
    }

    fn admit_at(&self, peer: &str, now: Instant) -> Result<(), String> {
        self.sweep(now);
        let mut peers = self.peers();
        let Some(p) = peers.get_mut(peer) else {
            return Ok(());
        };
        match p.until {
            Some(until) if until > now => {
                p.unlogged += 1;
                p.last = now;
                Err(format!(
                    "{} refusals in a row from {peer}: refused without a look for {:.1} s more",
                    p.in_a_row,
                    (until - now).as_secs_f64()
                ))
            }
            _ => Ok(()),
        }
    }

    /// `peer` was refused because of `why`: counted, backed off after [`FREE_TRIES`] in a row,
    /// and logged as the module documentation says.
    pub fn refused(&self, peer: &str, why: &str) {
        self.refused_at(peer, why, Instant::now());
    }

    fn refused_at(&self, peer: &str, why: &str, now: Instant) {
        let mut peers = self.peers();
        if !peers.contains_key(peer) && peers.len() >= MAX_PEERS {
            // Room for the new one: the peer refused longest ago goes.
            if let Some(oldest) = peers
                .iter()
                .min_by_key(|(_, p)| p.last)
                .map(|(k, _)| k.clone())
            {
                peers.remove(&oldest);
            }
        }
        let p = peers.entry(peer.to_string()).or_insert_with(|| Peer {
            in_a_row: 0,
            until: None,
            last: now,
            why: String::new(),
            logged: None,
            unlogged: 0,
        });
        p.in_a_row = p.in_a_row.saturating_add(1);
        p.last = now;
        p.why = why.to_string();
        if p.in_a_row >= FREE_TRIES {
            let doublings = (p.in_a_row - FREE_TRIES).min(16);
            p.until = Some(now + (FIRST_BACKOFF * (1u32 << doublings)).min(MAX_BACKOFF));
        }
        if p.logged.is_none_or(|t| now.duration_since(t) >= LOG_PERIOD) {
            let line = summary(self.what, peer, p, 1);
            tracing::warn!("{line}");
            p.logged = Some(now);
            p.unlogged = 0;
        } else {
            p.unlogged += 1;
        }
    }

    /// `peer` was let in: its refusals in a row are forgiven (the log's count stays).
    pub fn accepted(&self, peer: &str) {
        if let Some(p) = self.peers().get_mut(peer) {
            p.in_a_row = 0;
            p.until = None;
        }
    }

    /// At most every few seconds: the summaries of peers whose last line is older than
    /// [`LOG_PERIOD`], and peers quiet for [`FORGET_AFTER`] forgotten.
    fn sweep(&self, now: Instant) {
        {
            let mut swept = self.swept.lock().unwrap_or_else(|e| e.into_inner());
            if now.duration_since(*swept) < Duration::from_secs(5) {
                return;
            }
            *swept = now;
        }
        let mut peers = self.peers();
        for (name, p) in peers.iter_mut() {
            if p.unlogged > 0 && p.logged.is_none_or(|t| now.duration_since(t) >= LOG_PERIOD) {
                let line = summary(self.what, name, p, 0);
                tracing::warn!("{line}");
                p.logged = Some(now);
                p.unlogged = 0;
            }
        }
        peers.retain(|_, p| p.unlogged > 0 || now.duration_since(p.last) < FORGET_AFTER);
    }

    /// How many peers are remembered (for tests).
    #[cfg(test)]
    fn len(&self) -> usize {
        self.peers().len()
    }
}

/// The log line for `peer`: the refusal just made (`now` = 1) and those not logged before.
fn summary(what: &str, peer: &str, p: &Peer, now: u64) -> String {
    let more = p.unlogged + now;
    let backoff = match p.until {
        Some(_) => format!("; backed off after {} in a row", p.in_a_row),
        None => String::new(),
    };
    if p.unlogged == 0 {
        format!("{what}: refused {peer}: {}{backoff}", p.why)
    } else {
        format!(
            "{what}: {more} refusal(s) of {peer} since the last line about it (the last: \
             {}){backoff}",
            p.why
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_peer_is_backed_off_after_its_free_tries_and_forgiven_when_let_in() {
        let r = Refusals::new("test");
        let t0 = Instant::now();
        for i in 0..FREE_TRIES {
            assert!(r.admit_at("10.0.0.1", t0).is_ok(), "try {i}");
            r.refused_at("10.0.0.1", "wrong token", t0);
        }
        // Backed off: refused without a look, with the time left; another peer is not.
        let e = r.admit_at("10.0.0.1", t0).unwrap_err();
        assert!(e.contains("10.0.0.1") && e.contains("0.2"), "{e}");
        assert!(r.admit_at("10.0.0.2", t0).is_ok());
        // Refusals while backed off do not lengthen it: the peer that waits is let in.
        for _ in 0..100 {
            let _ = r.admit_at("10.0.0.1", t0 + Duration::from_millis(100));
        }
        assert!(r.admit_at("10.0.0.1", t0 + FIRST_BACKOFF).is_ok());
        // Each refusal after the free tries doubles the backoff, up to the most.
        let mut at = t0 + FIRST_BACKOFF;
        let mut last = Duration::ZERO;
        for _ in 0..10 {
            r.refused_at("10.0.0.1", "wrong token", at);
            let until = r.peers()["10.0.0.1"].until.unwrap();
            let backoff = until - at;
            assert!(backoff >= last && backoff <= MAX_BACKOFF, "{backoff:?}");
            last = backoff;
            at = until;
        }
        assert_eq!(last, MAX_BACKOFF);
        r.accepted("10.0.0.1");
        assert!(r.admit_at("10.0.0.1", at).is_ok());
        assert_eq!(r.peers()["10.0.0.1"].in_a_row, 0);
    }

    #[test]
    fn the_log_gets_one_line_per_peer_and_period_and_forgets_quiet_peers() {
        let r = Refusals::new("test");
        let t0 = Instant::now();
        for i in 0..1000u64 {
            r.refused_at("uid 1000", "not allowed", t0 + Duration::from_millis(i));
        }
        // The first was logged; the other 999 wait for the next line.
        assert_eq!(r.peers()["uid 1000"].unlogged, 999);
        let later = t0 + LOG_PERIOD + Duration::from_secs(1);
        r.refused_at("uid 1000", "not allowed", later);
        {
            let peers = r.peers();
            let p = &peers["uid 1000"];
            assert_eq!((p.unlogged, p.logged), (0, Some(later)));
            let line = summary("test", "uid 1000", p, 1);
            assert!(line.contains("backed off"), "{line}");
        }
        // Quiet for long enough, a peer is forgotten (its count logged first).
        r.sweep(later + FORGET_AFTER + Duration::from_secs(1));
        assert_eq!(r.len(), 0);
    }

    #[test]
    fn peers_remembered_are_bounded() {
        let r = Refusals::new("test");
        let t0 = Instant::now();
        for i in 0..(MAX_PEERS + 10) {
            r.refused_at(
                &format!("peer {i}"),
                "x",
                t0 + Duration::from_micros(i as u64),
            );
        }
        assert_eq!(r.len(), MAX_PEERS);
        // The oldest went.
        assert!(!r.peers().contains_key("peer 0"));
    }
}
