//! The calibration manifest (`SETUP/calibration.json`): which pattern set the captures of a
//! setup belong to and which captures are complete, so an interrupted calibration resumes from
//! what is on disk and never mixes in captures of another pattern set.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// The manifest's file name in the setup folder.
pub const MANIFEST_FILE: &str = "calibration.json";

/// What determines the projected images: equal pattern sets project identical images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PatternSet {
    /// Seed of the sampling images.
    pub seed: u64,
    pub ntrain: usize,
    pub ntest: usize,
    /// Network size of the sampling images, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub network: ImageSize,
    /// Projector size, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub projector: ImageSize,
    /// Level of the gray image x0 (0–255).
    pub gray_level: u8,
}

/// The manifest: the pattern set and the captures written so far (paths relative to the setup).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub patterns: PatternSet,
    pub captured: BTreeSet<PathBuf>,
    /// Closed-loop training images this calibration has written into the data root
    /// (`train/` after the sampling images, [`super::refine`]): only these may be replaced.
    #[serde(default)]
    pub loop_written: usize,
}

/// The projector size a calibration recorded for `setup` (its manifest's pattern set); `None`
/// when the setup has no readable manifest.
pub fn recorded_projector(setup: &Path) -> Option<ImageSize> {
    let text = std::fs::read_to_string(setup.join(MANIFEST_FILE)).ok()?;
    let m: Manifest = serde_json::from_str(&text).ok()?;
    Some(m.patterns.projector)
}

impl Manifest {
    /// The manifest of `setup` for `patterns`: the one on disk when it is for the same pattern
    /// set, a new one when the setup holds no captures. Captures of another pattern set, or
    /// captures without a manifest, are an input error naming the folder.
    pub fn open(setup: &Path, patterns: &PatternSet) -> Result<Self> {
        let path = setup.join(MANIFEST_FILE);
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let m: Manifest = serde_json::from_str(&text).map_err(|e| {
                    Error::Input(format!(
                        "{}: not a calibration manifest ({e}); move the folder away to \
                         calibrate anew",
                        path.display()
                    ))
                })?;
                if m.patterns != *patterns {
                    return Err(Error::Input(format!(
                        "{}: these captures belong to another pattern set ({:?}, this \
                         calibration projects {:?}); choose another --data folder or move this \
                         one away",
                        setup.display(),
                        m.patterns,
                        patterns
                    )));
                }
                Ok(m)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if setup.join("cam").exists() {
                    return Err(Error::Input(format!(
                        "{}: holds captures but no {MANIFEST_FILE}, so they cannot be matched \
                         to this calibration's patterns; choose another --data folder or move \
                         this one away",
                        setup.display()
                    )));
                }
                Ok(Manifest {
                    patterns: patterns.clone(),
                    captured: BTreeSet::new(),
                    loop_written: 0,
                })
            }
            Err(e) => Err(Error::io(&path, "read", e)),
        }
    }

    /// Whether `rel` (relative to `setup`) was captured and is still there.
    pub fn has(&self, setup: &Path, rel: &Path) -> bool {
        self.captured.contains(rel) && setup.join(rel).is_file()
    }

    /// Records a completed capture and writes the manifest atomically.
    pub fn record(&mut self, setup: &Path, rel: PathBuf) -> Result<()> {
        self.captured.insert(rel);
        self.save(setup)
    }

    /// Records that closed-loop training images up to the `count`th are this calibration's
    /// and writes the manifest atomically.
    pub fn record_loop(&mut self, setup: &Path, count: usize) -> Result<()> {
        self.loop_written = self.loop_written.max(count);
        self.save(setup)
    }

    /// Writes the manifest atomically.
    fn save(&self, setup: &Path) -> Result<()> {
        let path = setup.join(MANIFEST_FILE);
        let json = serde_json::to_vec_pretty(self)
            .map_err(|e| Error::Failed(format!("{}: {e}", path.display())))?;
        crate::files::write_atomically(&path, &json)
    }
}
