//! The model directory (DESIGN.md section 7): `model.safetensors` holds every numeric array
//! (weights, or the baked grid and constants), `model.json` the metadata (format version, method,
//! sizes, canvas, training settings, metrics, timings).
//!
//! Saving never leaves a half-written model where a good one was: the new directory is written
//! beside the target under a temporary name, every file is fsynced, and only then swapped in.

use std::collections::BTreeMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Version of the model directory format this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const META_FILE: &str = "model.json";

/// Metadata stored in `model.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelMeta {
    pub format_version: u32,
    /// Method name, e.g. `linear`.
    pub method: String,
    /// Network (model) size, width × height, in network pixels.
    pub network_size: (usize, usize),
    /// Camera size, width × height, in camera pixels.
    pub camera_size: (usize, usize),
    /// Where network-space images are placed in projector space, when compend owns the placement
    /// (live calibration); `None` for models trained on recorded datasets.
    #[serde(default)]
    pub canvas: Option<crate::raster::Rect>,
    /// Free-form training settings and provenance (setup path, #train, seed, …).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Evaluation results, if any.
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// Timings in seconds (training, …).
    #[serde(default)]
    pub timings: serde_json::Value,
    /// The compend version that wrote the model.
    pub written_by: String,
}

/// Named f32 arrays with shapes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tensors {
    map: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Tensors {
    pub fn insert(&mut self, name: &str, shape: Vec<usize>, data: Vec<f32>) -> Result<()> {
        let n: usize = shape.iter().product();
        if n != data.len() {
            return Err(Error::Shape(format!(
                "tensor {name}: shape {shape:?} needs {n} values, got {}",
                data.len()
            )));
        }
        self.map.insert(name.to_string(), (shape, data));
        Ok(())
    }

    /// The tensor `name`, checked against the expected shape; `file` names the source in errors.
    pub fn get(&self, name: &str, shape: &[usize], file: &Path) -> Result<&[f32]> {
        match self.map.get(name) {
            None => Err(Error::Input(format!(
                "{}: tensor `{name}` is missing (expected shape {shape:?})",
                file.display()
            ))),
            Some((s, _)) if s.as_slice() != shape => Err(Error::Input(format!(
                "{}: tensor `{name}` has shape {s:?}, expected {shape:?}",
                file.display()
            ))),
            Some((_, d)) => Ok(d),
        }
    }

    /// The stored shape of `name`, if present.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.map.get(name).map(|(shape, _)| shape.as_slice())
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.map.keys().map(|s| s.as_str())
    }

    /// The arrays as a safetensors file's bytes (f32, little-endian).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = self
            .map
            .iter()
            .map(|(k, (s, d))| {
                (
                    k.clone(),
                    s.clone(),
                    d.iter().flat_map(|v| v.to_le_bytes()).collect(),
                )
            })
            .collect();
        let views = bytes
            .iter()
            .map(|(k, s, b)| {
                TensorView::new(Dtype::F32, s.clone(), b)
                    .map(|v| (k.clone(), v))
                    .map_err(|e| Error::Shape(format!("tensor {k}: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        safetensors::serialize(views, None)
            .map_err(|e| Error::Failed(format!("safetensors encoding failed: {e}")))
    }

    /// Parses a safetensors file's bytes (f32 arrays only); `file` names the source in errors.
    pub fn from_bytes(bytes: &[u8], file: &Path) -> Result<Self> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| {
            Error::Input(format!(
                "{}: not a readable safetensors file ({e})",
                file.display()
            ))
        })?;
        let mut out = Tensors::default();
        for (name, view) in st.tensors() {
            if view.dtype() != Dtype::F32 {
                return Err(Error::Input(format!(
                    "{}: tensor `{name}` is {:?}, expected F32",
                    file.display(),
                    view.dtype()
                )));
            }
            let data = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            out.map.insert(name, (view.shape().to_vec(), data));
        }
        Ok(out)
    }
}

/// Reads a model directory: metadata (version checked) and tensors.
pub fn load(dir: &Path) -> Result<(ModelMeta, Tensors)> {
    let meta_path = dir.join(META_FILE);
    let text = fs::read_to_string(&meta_path)
        .map_err(|e| Error::io(&meta_path, "read model metadata", e))?;
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
    let meta: ModelMeta = serde_json::from_str(&text).map_err(|e| {
        Error::Input(format!(
            "{}: invalid model metadata ({e})",
            meta_path.display()
        ))
    })?;
    let weights_path = dir.join(WEIGHTS_FILE);
    let bytes =
        fs::read(&weights_path).map_err(|e| Error::io(&weights_path, "read model weights", e))?;
    let tensors = Tensors::from_bytes(&bytes, &weights_path)?;
    Ok((meta, tensors))
}

/// Writes a model directory atomically: a temporary sibling is written and fsynced, then swapped
/// in; an existing model at `dir` is replaced only once the new one is complete.
pub fn save(dir: &Path, meta: &ModelMeta, tensors: &Tensors) -> Result<()> {
    let parent = dir
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, "create folder", e))?;
    let name = dir
        .file_name()
        .ok_or_else(|| {
            Error::Input(format!(
                "{}: not a usable model directory name",
                dir.display()
            ))
        })?
        .to_string_lossy()
        .into_owned();
    let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
    let result = write_into(&tmp, meta, tensors).and_then(|()| swap_in(&tmp, dir, &parent, &name));
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}

fn write_into(tmp: &Path, meta: &ModelMeta, tensors: &Tensors) -> Result<()> {
    if tmp.exists() {
        fs::remove_dir_all(tmp).map_err(|e| Error::io(tmp, "remove stale temporary model", e))?;
    }
    fs::create_dir_all(tmp).map_err(|e| Error::io(tmp, "create", e))?;
    write_synced(&tmp.join(WEIGHTS_FILE), &tensors.to_bytes()?)?;
    let json = serde_json::to_vec_pretty(meta)
        .map_err(|e| Error::Failed(format!("model metadata: {e}")))?;
    write_synced(&tmp.join(META_FILE), &json)?;
    sync_dir(tmp);
    Ok(())
}

fn swap_in(tmp: &Path, dir: &Path, parent: &Path, name: &str) -> Result<()> {
    let old: Option<PathBuf> = if dir.exists() {
        let old = parent.join(format!(".{name}.old-{}", std::process::id()));
        fs::rename(dir, &old).map_err(|e| Error::io(dir, "move the previous model aside", e))?;
        Some(old)
    } else {
        None
    };
    if let Err(e) = fs::rename(tmp, dir) {
        if let Some(old) = &old {
            let _ = fs::rename(old, dir); // put the previous model back
        }
        return Err(Error::io(dir, "move the new model into place", e));
    }
    sync_dir(parent);
    if let Some(old) = old {
        let _ = fs::remove_dir_all(old);
    }
    Ok(())
}

/// Writes one file atomically: a temporary sibling is written and fsynced, then renamed over
/// `path`, so a reader (or a crash) never sees a half-written file where a good one was.
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(parent).map_err(|e| Error::io(parent, "create folder", e))?;
    let name = path
        .file_name()
        .ok_or_else(|| Error::Input(format!("{}: not a usable file name", path.display())))?
        .to_string_lossy()
        .into_owned();
    let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
    let result = write_synced(&tmp, bytes)
        .and_then(|()| fs::rename(&tmp, path).map_err(|e| Error::io(path, "move into place", e)));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    } else {
        sync_dir(parent);
    }
    result
}

fn write_synced(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = fs::File::create(path).map_err(|e| Error::io(path, "create", e))?;
    f.write_all(bytes)
        .map_err(|e| Error::io(path, "write", e))?;
    f.sync_all().map_err(|e| Error::io(path, "sync", e))
}

fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}
