//! systemd's notification protocol (`Type=notify`): READY once the first compensated frame is
//! presented (or the service is idle with nothing to play), WATCHDOG from the render loop and
//! the engine's waits, STATUS lines with the state. Outside systemd (`$NOTIFY_SOCKET` unset)
//! every call does nothing.

use std::time::{Duration, Instant};

use sd_notify::NotifyState;

/// The service's side of the protocol, rate-limited so a render loop may call it every frame.
pub struct Notifier {
    enabled: bool,
    ready: bool,
    last_ping: Option<Instant>,
    /// Half of systemd's `WatchdogSec`, or a second.
    ping_every: Duration,
    last_status: String,
}

impl Notifier {
    pub fn new() -> Self {
        let enabled = std::env::var_os("NOTIFY_SOCKET").is_some();
        let ping_every = sd_notify::watchdog_enabled()
            .map(|d| (d / 2).min(Duration::from_secs(1)))
            .unwrap_or(Duration::from_secs(1));
        Self {
            enabled,
            ready: false,
            last_ping: None,
            ping_every,
            last_status: String::new(),
        }
    }

    fn send(&self, states: &[NotifyState]) {
        if self.enabled
            && let Err(e) = sd_notify::notify(states)
        {
            tracing::debug!("sd_notify: {e}");
        }
    }

    /// READY=1, once.
    pub fn ready(&mut self, status: &str) {
        if !self.ready {
            self.ready = true;
            self.send(&[NotifyState::Ready, NotifyState::Status(status)]);
            self.last_status = status.to_string();
            tracing::info!("ready: {status}");
        }
    }

    pub fn is_ready(&self) -> bool {
        self.ready
    }

    /// WATCHDOG=1, at most every half watchdog period.
    pub fn ping(&mut self) {
        if self
            .last_ping
            .is_none_or(|t| t.elapsed() >= self.ping_every)
        {
            self.last_ping = Some(Instant::now());
            self.send(&[NotifyState::Watchdog]);
        }
    }

    /// STATUS=…, when it changed.
    pub fn status(&mut self, status: &str) {
        if status != self.last_status {
            self.last_status = status.to_string();
            self.send(&[NotifyState::Status(status)]);
        }
    }

    /// RELOADING=1 … READY=1 around a configuration reload.
    pub fn reloading(&self) {
        if let Ok(now) = NotifyState::monotonic_usec_now() {
            self.send(&[NotifyState::Reloading, now]);
        }
    }

    pub fn reloaded(&self) {
        self.send(&[NotifyState::Ready]);
    }

    pub fn stopping(&self) {
        self.send(&[NotifyState::Stopping, NotifyState::Status("stopping")]);
    }
}

impl Default for Notifier {
    fn default() -> Self {
        Self::new()
    }
}
