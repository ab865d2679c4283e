//! `[monitoring]`: scoring the compensated projection during playback, and drift.

use serde::Serialize;

use super::read::{Table, Walker};

/// What the service does when monitoring finds drift.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DriftPolicy {
    /// Say so in `status` and the log, and keep playing.
    Report,
    /// Calibrate again (captures, fit, verification); install only if it verifies.
    Recalibrate,
    /// Refit fast: a calibration from `refit_ntrain` sampling images (seconds of captures
    /// instead of a minute), geometry and colour of the `linear` rung; installed only if it
    /// verifies. `calibrate`/`recalibrate` requests still run the full calibration.
    Refit,
}

/// `[monitoring]`: scoring the compensated projection during playback.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MonitoringConfig {
    pub enabled: bool,
    /// Seconds between two monitoring captures.
    pub period_s: f64,
    /// Drop of the monitoring PSNR below the one measured at installation that counts as
    /// drift, dB.
    pub drift_threshold_db: f64,
    pub on_drift: DriftPolicy,
    /// `on_drift = "refit"`: sampling images the refit projects and fits on.
    pub refit_ntrain: usize,
}

impl Default for MonitoringConfig {
    /// A score every 30 s; a drop of 3 dB is drift, answered by a recalibration.
    fn default() -> Self {
        MonitoringConfig {
            enabled: true,
            period_s: 30.0,
            drift_threshold_db: 3.0,
            on_drift: DriftPolicy::Recalibrate,
            refit_ntrain: 8,
        }
    }
}

impl MonitoringConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        MonitoringConfig {
            enabled: w.get(t, "enabled").unwrap_or(d.enabled),
            period_s: w.positive(t, "period_s", d.period_s),
            drift_threshold_db: w.positive(t, "drift_threshold_db", d.drift_threshold_db),
            on_drift: w.choice(
                t,
                "on_drift",
                d.on_drift,
                &[
                    ("report", DriftPolicy::Report),
                    ("recalibrate", DriftPolicy::Recalibrate),
                    ("refit", DriftPolicy::Refit),
                ],
            ),
            refit_ntrain: w.checked(t, "refit_ntrain", d.refit_ntrain, |&n| {
                if n >= crate::fit::MIN_TRAIN {
                    Ok(())
                } else {
                    Err(format!(
                        "at least {} sampling images are needed",
                        crate::fit::MIN_TRAIN
                    ))
                }
            }),
        }
    }
}
