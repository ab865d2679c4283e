//! `[paths]`: where models and captures live.

use std::path::PathBuf;

use serde::Serialize;

use super::read::{Table, Walker};

/// `[paths]`: where models and captures live.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PathsConfig {
    /// The state directory: models and captures (systemd's `StateDirectory=`).
    pub state: PathBuf,
    /// The calibration data root [default: STATE/calibration].
    pub data: PathBuf,
    /// The installed model directory [default: STATE/model].
    pub model: PathBuf,
    /// The folders whose model directories a `model` request may name [default: STATE].
    pub models: Vec<PathBuf>,
}

impl PathsConfig {
    /// Every path under the state directory `state`.
    pub fn under(state: PathBuf) -> Self {
        PathsConfig {
            data: state.join("calibration"),
            model: state.join("model"),
            models: vec![state.clone()],
            state,
        }
    }

    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let state: PathBuf = w.get(t, "state").unwrap_or_else(default_state);
        let d = Self::under(state);
        PathsConfig {
            data: w.get(t, "data").unwrap_or(d.data),
            model: w.get(t, "model").unwrap_or(d.model),
            models: w.get(t, "models").unwrap_or(d.models),
            state: d.state,
        }
    }
}

/// The state directory when the file does not name one: systemd's `$STATE_DIRECTORY` (the
/// first, when it lists several), else /var/lib/compend.
pub(super) fn default_state() -> PathBuf {
    std::env::var_os("STATE_DIRECTORY")
        .and_then(|v| {
            v.to_str()
                .and_then(|s| s.split(':').next())
                .map(PathBuf::from)
        })
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or_else(|| PathBuf::from("/var/lib/compend"))
}
