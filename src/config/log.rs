//! `[log]`: what the log says besides events.

use serde::Serialize;

use super::read::{Table, Walker};

/// `[log]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LogConfig {
    /// Seconds between two frame-count lines in the log during playback.
    pub stats_period_s: f64,
}

impl Default for LogConfig {
    /// A frame-count line a minute.
    fn default() -> Self {
        LogConfig {
            stats_period_s: 60.0,
        }
    }
}

impl LogConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        LogConfig {
            stats_period_s: w.positive(t, "stats_period_s", d.stats_period_s),
        }
    }
}
