//! The model directory (docs/architecture.md, "Model directory"): `model.safetensors` holds every numeric array
//! (weights, or the baked grid and constants), `model.json` the metadata (format version, method,
//! sizes, canvas, training settings, metrics, timings).
//!
//! Saving never leaves a half-written model where a good one was, and never replaces anything
//! but a model: see [`save`] and [`check_output`].

use std::fs;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::method::Method;
use crate::raster::ImageSize;
use crate::record::{CalibrationRecord, Timings, TrainingRecord};
use crate::tensors::Tensors;

/// Version of the model directory format this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const META_FILE: &str = "model.json";
/// The metadata file of a set of projectors' model ([`super::set`]), beside one model
/// directory per projector (`projector-1`, `projector-2`, …).
pub const SET_FILE: &str = "set.json";

/// The folder of projector `k` (0: the set's first) in a set's model directory.
pub fn projector_dir(k: usize) -> String {
    format!("projector-{}", k + 1)
}

/// Metadata stored in `model.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelMeta {
    pub format_version: u32,
    /// The rung, e.g. `linear`.
    pub method: Method,
    /// Network (model) size in network pixels, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub network_size: ImageSize,
    /// Camera size in camera pixels, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub camera_size: ImageSize,
    /// Where network-space images are placed in projector space, when compend owns the placement
    /// (live calibration); `None` for models trained on recorded datasets.
    #[serde(default)]
    pub canvas: Option<crate::raster::Rect>,
    /// How the model was trained: data, settings, evidence.
    #[serde(default)]
    pub training: TrainingRecord,
    /// Evaluation results, if any (free-form: written by the commands that score a model).
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// Timings of the training, seconds.
    #[serde(default)]
    pub timings: Timings,
    /// The compend version that wrote the model.
    pub written_by: String,
    /// SHA-256 of `model.safetensors` (lowercase hex), set by [`save`] and checked by [`load`]:
    /// weights from another model, or altered since, are refused. Absent in models written
    /// before it was recorded; those load unchecked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights_sha256: Option<String>,
    /// `compend calibrate`: latency, phase times and the verification that let it be installed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationRecord>,
}

/// Reads a model directory: metadata (version checked) and tensors.
pub fn load(dir: &Path) -> Result<(ModelMeta, Tensors)> {
    let meta = load_meta(dir)?;
    let weights_path = dir.join(WEIGHTS_FILE);
    let bytes = crate::files::read_regular(
        &weights_path,
        "the model's weights (safetensors)",
        crate::files::MAX_WEIGHTS_BYTES,
    )?;
    let tensors = Tensors::from_bytes(&bytes, &weights_path)?;
    if let Some(recorded) = &meta.weights_sha256 {
        let found = sha256_hex(&bytes);
        if !found.eq_ignore_ascii_case(recorded) {
            return Err(Error::Input(format!(
                "{}: not the weights {} was written with (SHA-256 {found}, recorded {recorded}): \
                 the two files of a model directory must come from one save; copy or move the \
                 whole directory, or train the model again",
                weights_path.display(),
                dir.join(META_FILE).display()
            )));
        }
    }
    Ok((meta, tensors))
}

/// The SHA-256 of `bytes` in lowercase hex.
fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Reads a model directory's metadata alone (version checked).
pub fn load_meta(dir: &Path) -> Result<ModelMeta> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::Input(format!(
            "{}: a file, not a model directory (a folder holding {META_FILE} and {WEIGHTS_FILE})",
            dir.display()
        )));
    }
    let meta_path = dir.join(META_FILE);
    let text = crate::files::read_text(&meta_path, "the model's metadata (JSON)")?;
    // Check the version before the full schema, so an old or newer model says so plainly.
    let version = serde_json::from_str::<serde_json::Value>(&text)
        .map_err(|e| Error::Input(format!("{}: not valid JSON ({e})", meta_path.display())))?
        .get("format_version")
        .and_then(|v| v.as_u64());
    match version {
        Some(v) if v == FORMAT_VERSION as u64 => {}
        Some(v) => {
            return Err(Error::Input(format!(
                "{}: model format version {v}, this compend reads version {FORMAT_VERSION}; retrain the model with this version",
                meta_path.display()
            )));
        }
        None => {
            return Err(Error::Input(format!(
                "{}: no `format_version` field; not a compend model",
                meta_path.display()
            )));
        }
    }
    serde_json::from_str(&text).map_err(|e| {
        Error::Input(format!(
            "{}: invalid model metadata ({e})",
            meta_path.display()
        ))
    })
}

/// Checks, before any work, that a model may be written at `dir`: nothing is there, an empty
/// folder, or a model directory (a folder holding only [`META_FILE`] and [`WEIGHTS_FILE`], with a
/// `format_version` in its metadata). Anything else (a regular file, a folder of other things,
/// a dataset setup) is an input error naming it, so that nothing but a model is ever replaced.
/// The folder that will hold `dir` must be writable, and so must a model directory there (its
/// files are removed once the new one is in place).
pub fn check_output(dir: &Path) -> Result<()> {
    if shape(dir, true)? {
        crate::files::check_contents_removable(dir)?;
    }
    crate::files::check_writable(dir)
}

/// What [`check_output`] checks of what is at `dir`, without needing to write there (for
/// `compend config check`, which may run as another user than the service): nothing, an empty
/// folder or a model directory. What this process may not look at is taken as nothing.
pub fn check_model_path(dir: &Path) -> Result<()> {
    shape(dir, false).map(drop)
}

/// Whether `dir` holds a model directory (`Ok(false)`: nothing there, or an empty folder);
/// anything else is an input error naming it. `strict`: a path this process cannot look at
/// is an error too.
fn shape(dir: &Path, strict: bool) -> Result<bool> {
    let refuse = |what: &str| {
        Err(Error::Input(format!(
            "{}: {what}; only a model directory ({META_FILE} + {WEIGHTS_FILE}, or a set's: \
             {SET_FILE} + projector folders) is ever replaced: choose another place for the model (--out, or [paths] model for the service) or \
             move it away",
            dir.display()
        )))
    };
    match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => Err(Error::Input(format!(
            "{}: a folder on this path is a file; choose another place for the model",
            dir.display()
        ))),
        Err(_) if !strict => Ok(false),
        Err(e) => Err(Error::io(dir, "inspect the output path", e)),
        Ok(m) if m.file_type().is_symlink() => refuse("is a symbolic link"),
        Ok(m) if !m.is_dir() => refuse("is a file, not a model directory"),
        Ok(_) => {
            let entries = match fs::read_dir(dir) {
                Ok(entries) => entries,
                Err(_) if !strict => return Ok(false),
                Err(e) => return Err(Error::io(dir, "list", e)),
            };
            let mut names = Vec::new();
            let mut folders = Vec::new();
            for entry in entries {
                let entry = entry.map_err(|e| Error::io(dir, "list", e))?;
                let name = entry.file_name().to_string_lossy().into_owned();
                // A model's two files are plain files: a folder or a FIFO of that name is
                // someone else's.
                let plain = entry.file_type().is_ok_and(|t| t.is_file());
                if (name == META_FILE || name == WEIGHTS_FILE || name == SET_FILE) && !plain {
                    return refuse(&format!(
                        "holds `{name}` that is not a plain file, so it is not a model directory"
                    ));
                }
                if entry.file_type().is_ok_and(|t| t.is_dir()) {
                    folders.push(name.clone());
                }
                names.push(name);
            }
            if names.iter().any(|n| n == SET_FILE) {
                return set_shape(dir, &names, &folders, strict, refuse);
            }
            if let Some(other) = names.iter().find(|n| *n != META_FILE && *n != WEIGHTS_FILE) {
                return refuse(&format!("holds `{other}`, so it is not a model directory"));
            }
            if !names.is_empty() && !is_model_meta(&dir.join(META_FILE)) {
                return refuse(&format!(
                    "has no readable {META_FILE} with a format_version"
                ));
            }
            Ok(!names.is_empty())
        }
    }
}

/// What [`shape`] checks of a set's model directory: `set.json` (JSON with a
/// `format_version`) and projector folders numbered from 1 without gaps, each a model
/// directory.
fn set_shape(
    dir: &Path,
    names: &[String],
    folders: &[String],
    strict: bool,
    refuse: impl Fn(&str) -> Result<bool>,
) -> Result<bool> {
    let projectors = names.len() - 1;
    for k in 0..projectors {
        let name = projector_dir(k);
        if !folders.contains(&name) {
            return refuse(&format!(
                "holds {SET_FILE} and {projectors} other entries, but no folder `{name}`, so it \
                 is not a set's model directory"
            ));
        }
        if dir.join(&name).join(SET_FILE).exists() {
            return refuse(&format!("has a set's model inside `{name}`"));
        }
        if !shape(&dir.join(&name), strict)? {
            return refuse(&format!(
                "has an empty `{name}`, so it is not a set's model"
            ));
        }
    }
    if !is_model_meta(&dir.join(SET_FILE)) {
        return refuse(&format!("has no readable {SET_FILE} with a format_version"));
    }
    Ok(true)
}

/// Whether `path` is a compend model's metadata file (JSON with a `format_version`).
fn is_model_meta(path: &Path) -> bool {
    crate::files::read_text(path, "JSON")
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v.get("format_version").is_some_and(|v| v.is_u64()))
}

/// Writes a model directory atomically: the new directory is written complete and fsynced
/// beside `dir` (`.NAME.tmp-PID`), then exchanged with the old one in one step, so `dir` always
/// holds a complete model ([`crate::files::swap_in_dir`]). What is at `dir` is checked first
/// ([`check_output`]): only a model directory is replaced. Leftovers of killed saves are removed.
pub fn save(dir: &Path, meta: &ModelMeta, tensors: &Tensors) -> Result<()> {
    check_output(dir)?;
    let weights = tensors.to_bytes()?;
    let meta = ModelMeta {
        weights_sha256: Some(sha256_hex(&weights)),
        ..meta.clone()
    };
    let json = serde_json::to_vec_pretty(&meta)
        .map_err(|e| Error::Failed(format!("model metadata: {e}")))?;
    let tmp = crate::files::temp_dir_for(dir)?;
    let result = crate::files::write_synced(&tmp.join(WEIGHTS_FILE), &weights)
        .and_then(|()| crate::files::write_synced(&tmp.join(META_FILE), &json))
        .and_then(|()| crate::files::swap_in_dir(&tmp, dir));
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}
