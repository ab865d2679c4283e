//! Where a film's sound goes when the configuration says `auto` (shell).
//!
//! GStreamer's own `autoaudiosink` tries every sink it knows in rank order and keeps the first
//! that opens. On a projection PC without a sound server that walk ends in JACK, whose client
//! library can block for ever on a lock left by a killed process (seen here: a film's pipeline
//! stuck in `jack_client_open` before its first frame). A service that must keep its picture
//! cannot wait on that, so `auto` is compend's own, shorter walk: the PulseAudio protocol
//! (PulseAudio, or PipeWire through pipewire-pulse), then ALSA's default device, each given a
//! few seconds to open on a thread of its own; JACK only when named. Without any, the film
//! plays silent and says so.

use std::collections::HashSet;
use std::sync::{Mutex, mpsc};
use std::time::Duration;

use gstreamer as gst;
use gstreamer::prelude::*;

/// The spelling of compend's own choice of sink.
pub const AUTO: &str = "auto";

/// The sinks `auto` tries, in order.
pub const CANDIDATES: [&str; 2] = ["pulsesink", "alsasink"];

/// How long a candidate may take to open its device.
const OPEN_TIMEOUT: Duration = Duration::from_secs(3);

/// Sinks whose opening never answered in this process: not tried again (their thread is
/// still blocked in the sound library).
static STUCK: Mutex<Option<HashSet<&'static str>>> = Mutex::new(None);

/// The sink description to build for `device`: itself unless it is [`AUTO`], else the first
/// candidate whose device opens now; None when none does (the reasons are logged once per
/// call).
pub fn resolve(device: &str) -> Option<String> {
    if device.trim() != AUTO {
        return Some(device.to_string());
    }
    let mut tried = Vec::new();
    for name in CANDIDATES {
        match opens(name) {
            Ok(()) => return Some(name.to_string()),
            Err(why) => tried.push(format!("{name}: {why}")),
        }
    }
    tracing::warn!(
        "no sound output answered ({}); the media plays silent. Name a sink in [audio] device \
         or --audio (e.g. \"alsasink device=hw:1\", \"jackaudiosink\"), or turn sound off",
        tried.join("; ")
    );
    None
}

/// Whether `name`'s default device opens (NULL to READY), within [`OPEN_TIMEOUT`].
fn opens(name: &'static str) -> Result<(), String> {
    if crate::media::init().is_err() || gst::ElementFactory::find(name).is_none() {
        return Err("not installed".into());
    }
    if let Ok(stuck) = STUCK.lock()
        && stuck.as_ref().is_some_and(|s| s.contains(name))
    {
        return Err("did not answer earlier".into());
    }
    let (tx, rx) = mpsc::channel();
    let spawned = std::thread::Builder::new()
        .name(format!("compend-{name}"))
        .spawn(move || {
            let r = match gst::ElementFactory::make(name).build() {
                Err(e) => Err(e.to_string()),
                Ok(sink) => {
                    let r = sink
                        .set_state(gst::State::Ready)
                        .map(|_| ())
                        .map_err(|_| "its device did not open".to_string());
                    let _ = sink.set_state(gst::State::Null);
                    r
                }
            };
            let _ = tx.send(r);
        });
    if let Err(e) = spawned {
        return Err(format!("no thread to try it on: {e}"));
    }
    match rx.recv_timeout(OPEN_TIMEOUT) {
        Ok(r) => r,
        Err(_) => {
            if let Ok(mut stuck) = STUCK.lock() {
                stuck.get_or_insert_with(HashSet::new).insert(name);
            }
            Err(format!("did not open within {} s", OPEN_TIMEOUT.as_secs()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_named_sink_is_kept_as_written() {
        assert_eq!(
            resolve("alsasink device=hw:1").as_deref(),
            Some("alsasink device=hw:1")
        );
        assert_eq!(resolve("jackaudiosink").as_deref(), Some("jackaudiosink"));
    }

    #[test]
    fn auto_picks_only_a_candidate_and_never_jack() {
        // On a machine without sound (CI) nothing opens; with sound one of the candidates.
        if let Some(s) = resolve(AUTO) {
            assert!(CANDIDATES.contains(&s.as_str()), "{s}");
        }
    }
}
