//! Calibration runs under one folder (the service's `[paths] data`, and `compend calibrate
//! --config`): each calibration captures into a run folder of its own,
//! `ROOT/run-YYYYMMDD-HHMMSS` (UTC), so a recalibration (after drift, say) never reuses the
//! captures of a surface that has changed.
//!
//! A run in progress is named by a marker file, `ROOT/calibrating.json`, written before the
//! first capture and removed when the run ends (installed or refused). A calibration that starts
//! and finds the marker resumes that run from its captures on disk, so a kill -9 or a power cut
//! costs only the capture in flight. The newest `keep` runs are kept; older ones are removed,
//! and only folders that are runs (a run name and a calibration manifest inside) are touched.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The marker of a run in progress, in the runs folder.
pub const MARKER: &str = "calibrating.json";

/// What the marker holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Marker {
    /// The process that started the run (for the operator; not checked).
    pid: u32,
    /// What is calibrated (`virtual:curved`, `camera:/dev/video0`).
    rig: String,
    /// The run folder's name.
    run: String,
    /// A drift refit (few sampling images), resumed as one.
    #[serde(default)]
    refit: bool,
}

/// The runs folder.
#[derive(Clone, Debug)]
pub struct Runs {
    root: PathBuf,
}

/// A run: its data root, and whether it resumes an interrupted one.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    pub data: PathBuf,
    pub resumed: bool,
    /// A drift refit: asked for, or the interrupted run was one.
    pub refit: bool,
}

impl Runs {
    pub fn new(root: &Path) -> Self {
        Self {
            root: root.to_path_buf(),
        }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    fn marker(&self) -> PathBuf {
        self.root.join(MARKER)
    }

    /// The run an interrupted calibration left, if the marker names one.
    pub fn interrupted(&self) -> Option<PathBuf> {
        self.interrupted_marker().map(|(p, _)| p)
    }

    /// The interrupted run and whether it was a refit.
    fn interrupted_marker(&self) -> Option<(PathBuf, bool)> {
        let path = self.marker();
        let bytes = crate::files::read_regular(
            &path,
            "a calibration run marker (JSON)",
            crate::files::MAX_TEXT_BYTES,
        )
        .ok()?;
        match serde_json::from_slice::<Marker>(&bytes) {
            Ok(m) if is_run_name(&m.run) => Some((self.root.join(m.run), m.refit)),
            Ok(m) => {
                tracing::warn!(
                    "{}: {:?} is not a run folder name; a new run starts",
                    path.display(),
                    m.run
                );
                None
            }
            Err(e) => {
                tracing::warn!("{}: unreadable ({e}); a new run starts", path.display());
                None
            }
        }
    }

    /// Starts a run: the interrupted one if the marker names one, else a new one named after
    /// `now`. The marker is written (atomically) before this returns.
    pub fn begin(&self, rig: &str, now: SystemTime) -> Result<Run> {
        self.begin_with(rig, now, false)
    }

    /// [`Runs::begin`]; a new run is a drift refit when `refit` says so, a resumed one when it
    /// was one (its captures are of the refit's pattern set).
    pub fn begin_with(&self, rig: &str, now: SystemTime, refit: bool) -> Result<Run> {
        std::fs::create_dir_all(&self.root)
            .map_err(|e| Error::io(&self.root, "create folder", e))?;
        let (data, resumed, refit) = match self.interrupted_marker() {
            Some((d, was)) => (d, true, was),
            None => {
                // Two runs in one second (or a clock set back): the next free second.
                let mut t = now;
                while self.root.join(run_name(t)).exists() {
                    t += std::time::Duration::from_secs(1);
                }
                (self.root.join(run_name(t)), false, refit)
            }
        };
        let run = data
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        let marker = Marker {
            pid: std::process::id(),
            rig: rig.to_string(),
            run,
            refit,
        };
        let bytes = serde_json::to_vec(&marker).map_err(|e| Error::Failed(e.to_string()))?;
        crate::files::write_atomically(&self.marker(), &bytes)?;
        Ok(Run {
            data,
            resumed,
            refit,
        })
    }

    /// Ends the run in progress (installed or refused: it is not resumed again).
    pub fn end(&self) {
        let path = self.marker();
        if let Err(e) = std::fs::remove_file(&path)
            && e.kind() != std::io::ErrorKind::NotFound
        {
            tracing::warn!("{}: could not remove: {e}", path.display());
        }
    }

    /// Removes the oldest runs beyond the newest `keep` (0: keeps all). Returns the folders
    /// removed.
    pub fn prune(&self, keep: usize) -> Vec<PathBuf> {
        if keep == 0 {
            return Vec::new();
        }
        let Ok(entries) = std::fs::read_dir(&self.root) else {
            return Vec::new();
        };
        let mut runs: Vec<PathBuf> = entries
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_str().is_some_and(is_run_name))
            .map(|e| e.path())
            .filter(|p| {
                p.join(super::SETUP_NAME)
                    .join(crate::dataset::manifest::MANIFEST_FILE)
                    .is_file()
            })
            .filter(|p| holds_only_calibration(p))
            .collect();
        runs.sort();
        let n = runs.len().saturating_sub(keep);
        let mut removed = Vec::new();
        for old in runs.into_iter().take(n) {
            match std::fs::remove_dir_all(&old) {
                Ok(()) => {
                    tracing::info!("removed the old calibration run {}", old.display());
                    removed.push(old);
                }
                Err(e) => tracing::warn!("{}: could not remove the old run: {e}", old.display()),
            }
        }
        removed
    }
}

/// What a calibration writes at the top of its run folder: the patterns and the captures.
const RUN_ENTRIES: [&str; 4] = [super::SETUP_NAME, "ref", "test", "train"];

/// Whether the run folder `dir` holds nothing but what a calibration writes there: a folder that
/// holds anything else (a model someone put there, notes) is not removed.
fn holds_only_calibration(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    for e in entries {
        let name = e.ok().map(|e| e.file_name());
        if !name
            .as_ref()
            .and_then(|n| n.to_str())
            .is_some_and(|n| RUN_ENTRIES.contains(&n))
        {
            tracing::warn!(
                "{}: holds {:?}, which a calibration does not write; the old run is kept",
                dir.display(),
                name.unwrap_or_default()
            );
            return false;
        }
    }
    true
}

/// The run folder name of a calibration started at `now`: `run-YYYYMMDD-HHMMSS`, UTC.
pub fn run_name(now: SystemTime) -> String {
    // A clock before 1970 or past year 9999 (gone wrong) reads as the epoch.
    let secs = now.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let t = i64::try_from(secs)
        .ok()
        .and_then(|s| time::OffsetDateTime::from_unix_timestamp(s).ok())
        .unwrap_or(time::OffsetDateTime::UNIX_EPOCH);
    format!(
        "run-{:04}{:02}{:02}-{:02}{:02}{:02}",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

/// Whether `name` is a run folder name (and nothing else: no separators, no dots).
pub fn is_run_name(name: &str) -> bool {
    name.strip_prefix("run-").is_some_and(|rest| {
        rest.len() == 15
            && rest.bytes().enumerate().all(|(i, b)| {
                if i == 8 {
                    b == b'-'
                } else {
                    b.is_ascii_digit()
                }
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn run_names_are_utc_dates_and_only_they_are_runs() {
        let t = UNIX_EPOCH + Duration::from_secs(1_795_548_600); // 2026-11-24 19:30:00 UTC
        assert_eq!(run_name(t), "run-20261124-193000");
        assert_eq!(run_name(UNIX_EPOCH), "run-19700101-000000");
        // 2000-02-29, a leap day.
        let leap = UNIX_EPOCH + Duration::from_secs(951_782_400);
        assert_eq!(run_name(leap), "run-20000229-000000");
        assert!(is_run_name(&run_name(t)));
        for bad in [
            "run-2026112-193000",
            "run-20261124_193000",
            "model",
            "run-../../etc",
            "",
        ] {
            assert!(!is_run_name(bad), "{bad}");
        }
    }

    #[test]
    fn a_marked_run_is_resumed_and_old_runs_are_pruned() {
        let dir = tempfile::tempdir().unwrap();
        let runs = Runs::new(dir.path());
        let t0 = UNIX_EPOCH + Duration::from_secs(1_795_548_600);
        let a = runs.begin("virtual:curved", t0).unwrap();
        assert!(!a.resumed);
        // Interrupted: the next begin resumes it, whatever the time.
        let again = runs
            .begin("virtual:curved", t0 + Duration::from_secs(60))
            .unwrap();
        assert_eq!(
            again,
            Run {
                data: a.data.clone(),
                resumed: true,
                refit: false
            }
        );
        runs.end();
        assert!(runs.interrupted().is_none());
        // A drift refit is resumed as a refit, whatever the next begin asks for.
        let r = runs
            .begin_with("x", t0 + Duration::from_secs(120), true)
            .unwrap();
        assert!(r.refit && !r.resumed);
        let again = runs
            .begin_with("x", t0 + Duration::from_secs(180), false)
            .unwrap();
        assert!(again.refit && again.resumed && again.data == r.data);
        runs.end();
        assert!(
            !runs
                .begin("x", t0 + Duration::from_secs(240))
                .unwrap()
                .refit
        );
        runs.end();
        // A run that began in the same second does not reuse the folder.
        std::fs::create_dir_all(&a.data).unwrap();
        let same = runs.begin("x", t0).unwrap();
        assert!(same.data.ends_with("run-20261124-193001"), "{same:?}");
        runs.end();
        std::fs::remove_dir(&same.data).ok();
        // Four runs with manifests, one folder that only looks like a run, one user file.
        let mut made = vec![a.data.clone()];
        for i in 1..4 {
            let r = runs.begin("x", t0 + Duration::from_secs(i * 3600)).unwrap();
            runs.end();
            made.push(r.data);
        }
        for d in &made {
            let setup = d.join(crate::calibrate::SETUP_NAME);
            std::fs::create_dir_all(&setup).unwrap();
            std::fs::write(setup.join(crate::dataset::manifest::MANIFEST_FILE), "{}").unwrap();
        }
        let lookalike = dir.path().join("run-19990101-000000");
        std::fs::create_dir_all(&lookalike).unwrap();
        std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
        let removed = runs.prune(2);
        assert_eq!(removed, made[..2].to_vec());
        assert!(made[2].is_dir() && made[3].is_dir());
        // An old run that holds something calibration did not write stays.
        std::fs::write(made[2].join("notes.txt"), "mine").unwrap();
        assert!(runs.prune(1).is_empty());
        assert!(made[2].join("notes.txt").is_file());
        assert!(
            lookalike.is_dir(),
            "a folder without a manifest is not ours"
        );
        assert!(dir.path().join("notes.txt").is_file());
        // A garbled marker starts a new run.
        std::fs::write(dir.path().join(MARKER), "{garbage").unwrap();
        let r = runs.begin("x", t0 + Duration::from_secs(86_400)).unwrap();
        assert!(!r.resumed);
        assert!(r.data.ends_with("run-20261125-193000"));
    }
}
