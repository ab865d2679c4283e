//! What happened in the service, pushed to whoever listens (the console's event stream, the
//! socket's `subscribe`) and kept for the ones who come later: the last [`LOG_LEN`] events
//! and the last [`SCORES_LEN`] monitoring scores.
//!
//! Events come from two places only: [`super::Shared::update`] compares the status before and
//! after each change and publishes what moved (state, calibration phase, model, a calibration's
//! end, a monitoring score, drift, an error), and the request handlers publish each request with
//! who sent it and how it ended. So no state change can be missed by a caller forgetting to
//! announce it.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use serde::Serialize;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast};

use super::protocol::{State, Status};

/// Events kept for a subscriber that comes later (the page's log on load).
pub const LOG_LEN: usize = 500;
/// Monitoring scores kept for the chart.
pub const SCORES_LEN: usize = 2000;
/// Event streams open at once, over every surface (the console's, the socket's `subscribe`).
pub const MAX_SUBSCRIBERS: usize = 16;
/// Events a slow subscriber may fall behind before it misses some (it is told how many).
const CHANNEL_LEN: usize = 256;

/// What kind of thing happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// The service's state changed (`state` says to what).
    State,
    /// A calibration moved to another phase.
    Phase,
    /// A client asked something (`origin` says who); `text` says how it ended.
    Request,
    /// A calibration ended (installed or not).
    Calibration,
    /// Another model is served.
    Model,
    /// A monitoring score (`psnr`, dB).
    Score,
    /// Monitoring found drift.
    Drift,
    /// Something went wrong.
    Error,
}

/// One event, as subscribers receive it (one JSON object).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Event {
    /// Numbered from 1 in the order they happened.
    pub seq: u64,
    /// Wall-clock time, seconds since the Unix epoch.
    pub at_unix_s: f64,
    pub kind: Kind,
    /// For people: what happened.
    pub text: String,
    /// Who asked (requests): `unix uid 1000`, `tcp 127.0.0.1:50312`, `http 10.0.0.5:51000`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The state after a state change.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub state: Option<State>,
    /// A request's outcome.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ok: Option<bool>,
    /// A monitoring score, dB.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr: Option<f64>,
}

/// The service's events: a channel for live subscribers, the recent ones kept.
pub struct Hub {
    tx: broadcast::Sender<Event>,
    subscribers: Arc<Semaphore>,
    seq: AtomicU64,
    log: Mutex<VecDeque<Event>>,
    /// (seconds since the Unix epoch, PSNR dB) of recent monitoring checks.
    scores: Mutex<VecDeque<(f64, f64)>>,
}

impl Default for Hub {
    fn default() -> Self {
        Self {
            tx: broadcast::channel(CHANNEL_LEN).0,
            subscribers: Arc::new(Semaphore::new(MAX_SUBSCRIBERS)),
            seq: AtomicU64::new(0),
            log: Mutex::new(VecDeque::new()),
            scores: Mutex::new(VecDeque::new()),
        }
    }
}

/// An event before it is numbered and stamped.
#[derive(Clone, Debug, PartialEq)]
pub struct Draft {
    pub kind: Kind,
    pub text: String,
    pub origin: Option<String>,
    pub state: Option<State>,
    pub ok: Option<bool>,
    pub psnr: Option<f64>,
}

impl Draft {
    pub fn new(kind: Kind, text: impl Into<String>) -> Self {
        Self {
            kind,
            text: text.into(),
            origin: None,
            state: None,
            ok: None,
            psnr: None,
        }
    }
}

impl Hub {
    /// Numbers, stamps, keeps and sends `draft`.
    pub fn publish(&self, draft: Draft) {
        let event = Event {
            seq: self.seq.fetch_add(1, Ordering::Relaxed) + 1,
            at_unix_s: super::protocol::now_unix_s(),
            kind: draft.kind,
            text: draft.text,
            origin: draft.origin,
            state: draft.state,
            ok: draft.ok,
            psnr: draft.psnr,
        };
        if let Some(psnr) = event.psnr.filter(|_| event.kind == Kind::Score) {
            let mut s = self.scores.lock().unwrap_or_else(|e| e.into_inner());
            if s.len() == SCORES_LEN {
                s.pop_front();
            }
            s.push_back((event.at_unix_s, psnr));
        }
        {
            let mut log = self.log.lock().unwrap_or_else(|e| e.into_inner());
            if log.len() == LOG_LEN {
                log.pop_front();
            }
            log.push_back(event.clone());
        }
        // No subscriber is not an error.
        let _ = self.tx.send(event);
    }

    /// A subscriber's place, held while its stream is open; None when all are taken.
    pub fn slot(&self) -> Option<OwnedSemaphorePermit> {
        self.subscribers.clone().try_acquire_owned().ok()
    }

    /// A live subscription: every event from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.tx.subscribe()
    }

    /// The kept events, oldest first.
    pub fn recent(&self) -> Vec<Event> {
        let log = self.log.lock().unwrap_or_else(|e| e.into_inner());
        log.iter().cloned().collect()
    }

    /// The kept monitoring scores: (seconds since the Unix epoch, PSNR dB), oldest first.
    pub fn scores(&self) -> Vec<(f64, f64)> {
        let s = self.scores.lock().unwrap_or_else(|e| e.into_inner());
        s.iter().copied().collect()
    }
}

/// The parts of the status whose changes are events.
#[derive(Clone, Debug, PartialEq)]
pub struct Watched {
    state: State,
    phase: Option<String>,
    model: Option<(std::path::PathBuf, String)>,
    calibrations: u64,
    checks: u64,
    drifts: u64,
    last_error: Option<String>,
}

impl Watched {
    pub fn of(s: &Status) -> Self {
        Self {
            state: s.state,
            phase: s.calibration.as_ref().map(|c| c.phase.clone()),
            model: s.model.as_ref().map(|m| (m.path.clone(), m.method.clone())),
            calibrations: s.calibrations,
            checks: s.monitoring.checks,
            drifts: s.monitoring.drifts,
            last_error: s.last_error.clone(),
        }
    }

    /// The events that take the status from `self` to `after` (`now`).
    pub fn changes(&self, after: &Watched, now: &Status) -> Vec<Draft> {
        let mut out = Vec::new();
        if after.state != self.state {
            let mut d = Draft::new(
                Kind::State,
                format!("{} → {}", self.state.name(), after.state.name()),
            );
            d.state = Some(after.state);
            out.push(d);
        }
        if after.phase != self.phase
            && let (Some(phase), Some(c)) = (&after.phase, &now.calibration)
        {
            out.push(Draft::new(
                Kind::Phase,
                format!("calibration: {phase} ({} of {})", c.done, c.total),
            ));
        }
        if after.calibrations > self.calibrations {
            let text = now.last_calibration.as_ref().map_or_else(
                || "a calibration ended".to_string(),
                |c| {
                    format!(
                        "calibration {}: {}",
                        if c.installed {
                            "installed"
                        } else {
                            "not installed"
                        },
                        c.message
                    )
                },
            );
            let mut d = Draft::new(Kind::Calibration, text);
            d.ok = now.last_calibration.as_ref().map(|c| c.installed);
            out.push(d);
        }
        if after.model != self.model
            && let Some((path, method)) = &after.model
        {
            out.push(Draft::new(
                Kind::Model,
                format!("serving the {method} model {}", path.display()),
            ));
        }
        if after.checks > self.checks
            && let Some(psnr) = now.monitoring.psnr
        {
            let mut d = Draft::new(Kind::Score, format!("monitoring: {psnr:.2} dB"));
            d.psnr = Some(psnr);
            out.push(d);
        }
        if after.drifts > self.drifts {
            let mut d = Draft::new(
                Kind::Drift,
                format!(
                    "drift: {} dB against a baseline of {} dB",
                    now.monitoring
                        .psnr
                        .map_or("?".into(), |p| format!("{p:.2}")),
                    now.monitoring
                        .baseline_psnr
                        .map_or("?".into(), |p| format!("{p:.2}"))
                ),
            );
            d.psnr = now.monitoring.psnr;
            out.push(d);
        }
        if after.last_error != self.last_error
            && let Some(e) = &after.last_error
        {
            out.push(Draft::new(Kind::Error, e.clone()));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_are_numbered_kept_and_sent_in_order() {
        let hub = Hub::default();
        let mut rx = hub.subscribe();
        hub.publish(Draft::new(Kind::Request, "pause"));
        let mut score = Draft::new(Kind::Score, "monitoring: 30 dB");
        score.psnr = Some(30.0);
        hub.publish(score);
        let a = rx.try_recv().unwrap();
        let b = rx.try_recv().unwrap();
        assert_eq!((a.seq, a.kind), (1, Kind::Request));
        assert_eq!((b.seq, b.kind, b.psnr), (2, Kind::Score, Some(30.0)));
        assert_eq!(hub.recent(), vec![a, b]);
        assert_eq!(hub.scores().len(), 1);
        for i in 0..LOG_LEN {
            hub.publish(Draft::new(Kind::Request, format!("{i}")));
        }
        let recent = hub.recent();
        assert_eq!(recent.len(), LOG_LEN);
        assert_eq!(recent[0].seq, 3);
    }
}
