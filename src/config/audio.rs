//! `[audio]`: where media sources' sound goes.

use serde::Serialize;

use super::read::{Table, Walker};

/// `[audio]`: where media sources' sound goes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AudioConfig {
    /// Play the sound of films and streams.
    pub enabled: bool,
    /// `auto` (PulseAudio or PipeWire, else ALSA's default device) or a GStreamer audio sink
    /// description: `alsasink device=hw:1`, `pulsesink device=NAME`, `jackaudiosink`.
    pub device: String,
    /// A trim added to the measured picture latency the sound is delayed by, ms (positive:
    /// the sound later).
    pub delay_ms: f64,
}

impl Default for AudioConfig {
    /// Sound on, to the desktop's sound server or ALSA's default device, no trim.
    fn default() -> Self {
        AudioConfig {
            enabled: true,
            device: crate::media::audio::AUTO.to_string(),
            delay_ms: 0.0,
        }
    }
}

impl AudioConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        AudioConfig {
            enabled: w.get(t, "enabled").unwrap_or(d.enabled),
            device: w.checked(t, "device", d.device, |s: &String| {
                if s.trim().is_empty() {
                    Err("an empty sink; e.g. \"auto\" or \"alsasink device=hw:1\"".into())
                } else {
                    Ok(())
                }
            }),
            delay_ms: w.checked(t, "delay_ms", d.delay_ms, |v: &f64| {
                if v.is_finite() && v.abs() <= 10_000.0 {
                    Ok(())
                } else {
                    Err(format!("{v} ms: expected -10000 to 10000"))
                }
            }),
        }
    }

    /// The sound's way out for the sources.
    pub fn out(&self) -> crate::source::AudioOut {
        crate::source::AudioOut {
            sink: self.enabled.then(|| self.device.clone()),
            delay_ms: self.delay_ms,
        }
    }
}
