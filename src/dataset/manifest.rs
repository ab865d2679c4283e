//! The calibration manifest (`SETUP/calibration.json`): which pattern set the captures of a
//! setup belong to and which captures are complete, so an interrupted calibration resumes from
//! what is on disk and never mixes in captures of another pattern set.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::Setup;
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

impl std::fmt::Display for PatternSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "seed {}, {} training and {} test images, network {}, projector {}, gray level {}",
            self.seed, self.ntrain, self.ntest, self.network, self.projector, self.gray_level
        )
    }
}

/// The manifest: the pattern set and the captures written so far (paths relative to the setup).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub patterns: PatternSet,
    pub captured: BTreeSet<PathBuf>,
    /// Closed-loop training images this calibration has written into the data root
    /// (`train/` after the sampling images, [`crate::calibrate::refine`]): only these may be replaced.
    #[serde(default)]
    pub loop_written: usize,
}

/// The sides a recorded projector size may have, pixels: what `calibrate --projector` takes,
/// up to a side no display has.
const PROJECTOR_SIDES: std::ops::RangeInclusive<usize> = 1..=16384;

/// What a caller reads of the manifest a calibration left in `setup` (the whole [`Manifest`],
/// or the fields it needs), if there is one: `None` when the setup has none. A manifest that
/// cannot be read or does not hold `T` is an error naming it, with `why` (what the caller reads
/// from it) in the message.
fn recorded<T: serde::de::DeserializeOwned>(setup: &Path, why: &str) -> Result<Option<T>> {
    let path = setup.join(MANIFEST_FILE);
    let text = match crate::files::read_text(&path, "the calibration manifest (JSON)") {
        Ok(text) => text,
        Err(Error::Missing { .. }) => return Ok(None),
        Err(e) => return Err(e),
    };
    serde_json::from_str(&text).map(Some).map_err(|e| {
        Error::Input(format!(
            "{}: not a calibration manifest ({e}); {why}: mend it or move it away",
            path.display()
        ))
    })
}

/// The projector size a calibration recorded for `setup` (its manifest's pattern set); `None`
/// when the setup has no manifest. It sets the `linear` rungs' default lattice, so a manifest
/// that cannot be read, is not one, or records sides outside 1–16384 pixels is an error naming
/// it, not a silently coarser model.
pub fn recorded_projector(setup: &Path) -> Result<Option<ImageSize>> {
    let Some(m) = recorded::<Manifest>(
        setup,
        "the projector size it records sets the linear rungs' default lattice (`train` also \
         takes --lattice)",
    )?
    else {
        return Ok(None);
    };
    let p = m.patterns.projector;
    if !PROJECTOR_SIDES.contains(&p.width) || !PROJECTOR_SIDES.contains(&p.height) {
        return Err(Error::Input(format!(
            "{}: patterns.projector {}x{}: expected sides of {} to {} pixels",
            setup.join(MANIFEST_FILE).display(),
            p.width,
            p.height,
            PROJECTOR_SIDES.start(),
            PROJECTOR_SIDES.end()
        )));
    }
    Ok(Some(p))
}

/// How many sampling pairs a calibration recorded for `setup` (its pattern set's `ntrain`);
/// `None` when the setup has no manifest. The training pairs after them are the closed-loop
/// pairs the calibration took (it writes no others). Only that one field is read, so a manifest
/// with fields this version does not know still serves; one that is not JSON, or records no
/// `patterns.ntrain`, is an error naming it.
pub fn recorded_sampling_pairs(setup: &Path) -> Result<Option<usize>> {
    #[derive(Deserialize)]
    struct Recorded {
        patterns: Sampling,
    }
    #[derive(Deserialize)]
    struct Sampling {
        ntrain: usize,
    }
    let recorded: Option<Recorded> = recorded(
        setup,
        "the sampling pairs it records (patterns.ntrain) tell which training pairs are \
         closed-loop pairs",
    )?;
    Ok(recorded.map(|r| r.patterns.ntrain))
}

/// The closed-loop pairs among the setup's `available` captured training pairs
/// ([`Setup::loop_pairs`], which checks that their views are one run ending at the last
/// capture), checked against the calibration's manifest when the setup has one: the training
/// pairs after the sampling pairs it records are the closed-loop pairs it took, so their views
/// start right after them. A lost first view (or a lost folder of views), or a view on a
/// sampling pair, is an error naming it rather than pairs silently taken as the other kind.
/// `used`: the training pairs a fit takes (`None`: all); a fit of the sampling pairs alone is
/// not held to the manifest.
pub fn checked_loop_pairs(
    setup: &Setup,
    available: usize,
    used: Option<usize>,
) -> Result<Vec<usize>> {
    let loops = setup.loop_pairs(available)?;
    let Some(sampling) = recorded_sampling_pairs(setup.path())? else {
        return Ok(loops);
    };
    if available <= sampling || used.is_some_and(|n| n <= sampling) {
        return Ok(loops);
    }
    let first = sampling + 1;
    let manifest = setup.path().join(MANIFEST_FILE);
    match loops.first() {
        Some(&f) if f == first => Ok(loops),
        Some(&f) if f < first => Err(Error::Input(format!(
            "{}: a desired view for training pair {f}, which {} records as a sampling pair (the \
             closed-loop pairs are {first} to {available}); move it away",
            setup
                .loop_desired_dir()
                .join(crate::pngio::indexed_name(f))
                .display(),
            manifest.display()
        ))),
        _ => Err(Error::Missing {
            path: setup
                .loop_desired_dir()
                .join(crate::pngio::indexed_name(first)),
            expected: format!(
                "the desired view of training pair {first}: {} records {sampling} sampling \
                 pairs, so training pairs {first} to {available} are the closed-loop pairs the \
                 calibration took, each with its view",
                manifest.display()
            ),
        }),
    }
}

impl Manifest {
    /// The manifest of `setup` for `patterns`: the one on disk when it is for the same pattern
    /// set, a new one when the setup holds no captures. Captures of another pattern set, or
    /// captures without a manifest, are an input error naming the folder.
    pub fn open(setup: &Path, patterns: &PatternSet) -> Result<Self> {
        let path = setup.join(MANIFEST_FILE);
        match crate::files::read_text(&path, "the calibration manifest (JSON)") {
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
                        "{}: these captures belong to another pattern set ({}; this \
                         calibration projects {}); choose another data folder (--data, or \
                         [paths] data for the service) or move this one away",
                        setup.display(),
                        m.patterns,
                        patterns
                    )));
                }
                Ok(m)
            }
            Err(Error::Missing { .. }) => {
                // A run creates `cam/raw` before it writes its manifest: empty folders are not
                // captures (a run killed in between left them).
                if holds_files(&setup.join("cam")) {
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
            Err(e) => Err(e),
        }
    }

    /// [`Manifest::open`] for sampling rounds (`ntrain = auto`, [`crate::calibrate::rounds`]): `patterns`
    /// with its `ntrain` the most the rounds take. The manifest on disk is taken when its
    /// pattern set is this one but for a count of sampling pairs up to that; a new one starts
    /// with `first` of them.
    pub fn open_rounds(setup: &Path, patterns: &PatternSet, first: usize) -> Result<Self> {
        let start = PatternSet {
            ntrain: first.min(patterns.ntrain),
            ..patterns.clone()
        };
        // The same pattern set but for its count of sampling images.
        let same_set = |m: &Manifest| {
            m.patterns
                == PatternSet {
                    ntrain: m.patterns.ntrain,
                    ..patterns.clone()
                }
        };
        match recorded::<Manifest>(setup, "the sampling rounds resume from it")? {
            Some(m) if same_set(&m) && m.patterns.ntrain <= patterns.ntrain => Ok(m),
            Some(m) if same_set(&m) => Err(Error::Input(format!(
                "{}: these captures are of {} sampling images, more than the {} sampling \
                 rounds take; calibrate there with --ntrain {} (or [calibration] ntrain), or \
                 choose another data folder",
                setup.display(),
                m.patterns.ntrain,
                patterns.ntrain,
                m.patterns.ntrain
            ))),
            Some(m) => Err(Error::Input(format!(
                "{}: these captures belong to another pattern set ({}; this calibration \
                 projects {} in rounds of up to {} training images); choose another data folder \
                 (--data, or [paths] data for the service) or move this one away",
                setup.display(),
                m.patterns,
                PatternSet {
                    ntrain: m.patterns.ntrain,
                    ..patterns.clone()
                },
                patterns.ntrain
            ))),
            None => Self::open(setup, &start),
        }
    }

    /// Grows the pattern set to `ntrain` sampling images (a later round of
    /// [`crate::calibrate::rounds`]) and writes the manifest atomically. Never shrinks it, nor grows it
    /// past closed-loop images already written after the sampling ones.
    pub fn grow(&mut self, setup: &Path, ntrain: usize) -> Result<()> {
        if self.loop_written > 0 {
            return Err(Error::Failed(format!(
                "{}: closed-loop pairs follow the {} sampling pairs; no more sampling pairs \
                 can be taken",
                setup.join(MANIFEST_FILE).display(),
                self.patterns.ntrain
            )));
        }
        self.patterns.ntrain = self.patterns.ntrain.max(ntrain);
        self.save(setup)
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

    /// Writes the manifest atomically: a run calls it before its first capture, so no capture
    /// is ever on disk without the manifest that says which pattern set it belongs to.
    pub fn save(&self, setup: &Path) -> Result<()> {
        let path = setup.join(MANIFEST_FILE);
        let json = serde_json::to_vec_pretty(self)
            .map_err(|e| Error::Failed(format!("{}: {e}", path.display())))?;
        crate::files::write_atomically(&path, &json)
    }
}

/// Whether `dir` or a folder under it holds anything but folders (false where it is missing
/// or cannot be read: the caller's reading of the folder reports those).
fn holds_files(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    entries.flatten().any(|e| match e.file_type() {
        Ok(t) if t.is_dir() => holds_files(&e.path()),
        _ => true,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_rounds_grow_the_pattern_set_and_take_only_a_smaller_one_of_it() {
        let dir = tempfile::tempdir().unwrap();
        let setup = dir.path();
        let most = PatternSet {
            seed: 3,
            ntrain: 48,
            ntest: 4,
            network: ImageSize::new(64, 64),
            projector: ImageSize::new(200, 150),
            gray_level: 128,
        };
        // A new one starts at the first round, and grows (never shrinks).
        let mut m = Manifest::open_rounds(setup, &most, 16).unwrap();
        assert_eq!(m.patterns.ntrain, 16);
        m.grow(setup, 24).unwrap();
        m.grow(setup, 20).unwrap();
        assert_eq!(m.patterns.ntrain, 24);
        // A later run takes it, and a fixed count of another size does not.
        let again = Manifest::open_rounds(setup, &most, 16).unwrap();
        assert_eq!(again.patterns.ntrain, 24);
        assert!(Manifest::open(setup, &most).is_err());
        // Another seed, or more sampling images than the rounds take, is another set.
        for other in [
            PatternSet {
                seed: 4,
                ..most.clone()
            },
            PatternSet {
                ntrain: 20,
                ..most.clone()
            },
        ] {
            let e = Manifest::open_rounds(setup, &other, 16).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{e}");
            assert!(
                e.to_string().contains("another pattern set")
                    || e.to_string()
                        .contains("more than the 20 sampling rounds take"),
                "{e}"
            );
        }
        // Closed-loop pairs settle the count.
        m.record_loop(setup, 2).unwrap();
        let e = m.grow(setup, 32).unwrap_err();
        assert!(e.to_string().contains("closed-loop pairs follow"), "{e}");
    }

    #[test]
    fn empty_capture_folders_without_a_manifest_are_not_captures() {
        let dir = tempfile::tempdir().unwrap();
        let setup = dir.path();
        let patterns = PatternSet {
            seed: 2,
            ntrain: 8,
            ntest: 2,
            network: ImageSize::new(64, 64),
            projector: ImageSize::new(200, 150),
            gray_level: 128,
        };
        // A run killed after it created `cam/raw`, before its manifest: a new manifest.
        std::fs::create_dir_all(setup.join("cam/raw")).unwrap();
        let m = Manifest::open(setup, &patterns).unwrap();
        assert!(m.captured.is_empty());
        // A capture without a manifest cannot be matched to a pattern set.
        std::fs::write(setup.join("cam/raw/img_0001.png"), b"png").unwrap();
        let e = Manifest::open(setup, &patterns).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(e.to_string().contains("holds captures but no"), "{e}");
        // Once saved, the same folder opens as this pattern set's.
        m.save(setup).unwrap();
        assert_eq!(Manifest::open(setup, &patterns).unwrap().patterns, patterns);
    }

    #[test]
    fn a_recorded_projector_size_is_read_or_its_manifest_named() {
        let dir = tempfile::tempdir().unwrap();
        let setup = dir.path();
        assert_eq!(recorded_projector(setup).unwrap(), None);
        let manifest = |projector: ImageSize| Manifest {
            patterns: PatternSet {
                seed: 1,
                ntrain: 4,
                ntest: 2,
                network: ImageSize::new(64, 64),
                projector,
                gray_level: 128,
            },
            captured: BTreeSet::new(),
            loop_written: 0,
        };
        let path = setup.join(MANIFEST_FILE);
        let good = serde_json::to_string(&manifest(ImageSize::new(800, 600))).unwrap();
        std::fs::write(&path, &good).unwrap();
        assert_eq!(
            recorded_projector(setup).unwrap(),
            Some(ImageSize::new(800, 600))
        );
        let none = serde_json::to_string(&manifest(ImageSize::new(0, 600))).unwrap();
        let unknown = good.replacen('{', "{\"extra\":1,", 1);
        for (text, says) in [
            (&good[..good.len() / 2], "not a calibration manifest"),
            (unknown.as_str(), "unknown field `extra`"),
            (
                none.as_str(),
                "patterns.projector 0x600: expected sides of 1 to 16384",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let e = recorded_projector(setup).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{e}");
            let e = e.to_string();
            assert!(e.starts_with(&path.display().to_string()), "{e}");
            assert!(e.contains(says), "{e}");
        }
        std::fs::remove_file(&path).unwrap();
        std::fs::create_dir(&path).unwrap();
        let e = recorded_projector(setup).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(
            e.to_string()
                .contains("a folder, not the calibration manifest"),
            "{e}"
        );
    }
}
