//! A set of projectors' model (docs/architecture.md, "Sets of projectors"): one model
//! directory per projector (`projector-1`, …, each its own calibration's, fitted with the others
//! black) and `set.json`, how the set was checked as a whole. The joint model is built from the
//! projectors' `linear` models when loaded ([`SetModel::joint`]).

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::Model;
use super::store::{self, FORMAT_VERSION, SET_FILE, projector_dir};
use crate::error::{Error, Result};
use crate::joint::JointModel;
use crate::raster::ImageSize;
use crate::record::SetRecord;

/// `set.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetMeta {
    pub format_version: u32,
    /// How many projectors: folders `projector-1` to `projector-N`.
    pub projectors: usize,
    /// The camera's size (camera pixels), written `[width, height]`: every projector's model
    /// sees through the same camera.
    #[serde(with = "crate::raster::as_pair")]
    pub camera_size: ImageSize,
    pub written_by: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<SetRecord>,
}

/// A loaded set's model: its metadata and each projector's model, the set's first first.
#[derive(Debug)]
pub struct SetModel {
    pub meta: SetMeta,
    pub models: Vec<Model>,
}

impl SetModel {
    /// A set's model of `models` (one per projector, the same camera) with its record.
    pub fn new(models: Vec<Model>, calibration: Option<SetRecord>) -> Result<Self> {
        let camera_size = models
            .first()
            .map(Model::camera_size)
            .ok_or_else(|| Error::Input("a set's model needs at least one projector".into()))?;
        if let Some((k, m)) = models
            .iter()
            .enumerate()
            .find(|(_, m)| m.camera_size() != camera_size)
        {
            return Err(Error::Shape(format!(
                "projector {}'s model sees a {} camera, projector 1's a {camera_size}",
                k + 1,
                m.camera_size()
            )));
        }
        Ok(SetModel {
            meta: SetMeta {
                format_version: FORMAT_VERSION,
                projectors: models.len(),
                camera_size,
                written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
                calibration,
            },
            models,
        })
    }

    /// Whether `dir` holds a set's model (its `set.json`).
    pub fn is_set(dir: &Path) -> bool {
        dir.join(SET_FILE).is_file()
    }

    /// Loads a set's model directory: `set.json` (version checked) and every projector's
    /// model; a missing or foreign part is an input error naming it.
    pub fn load(dir: &Path) -> Result<Self> {
        let file = dir.join(SET_FILE);
        let text = crate::files::read_text(&file, "a set's model metadata (JSON)")?;
        let meta: SetMeta = serde_json::from_str(&text).map_err(|e| {
            Error::Input(format!(
                "{}: not a set's model metadata ({e}); expected {{\"format_version\": \
                 {FORMAT_VERSION}, \"projectors\": N, \"camera_size\": [W, H], …}}",
                file.display()
            ))
        })?;
        if meta.format_version != FORMAT_VERSION {
            return Err(Error::Input(format!(
                "{}: format_version {} (this compend reads {FORMAT_VERSION}); calibrate the set \
                 again",
                file.display(),
                meta.format_version
            )));
        }
        if meta.projectors == 0 || meta.projectors > crate::joint::MAX_PROJECTORS {
            return Err(Error::Input(format!(
                "{}: {} projectors; a set has 1 to {}",
                file.display(),
                meta.projectors,
                crate::joint::MAX_PROJECTORS
            )));
        }
        let models = (0..meta.projectors)
            .map(|k| Model::load(&dir.join(projector_dir(k))))
            .collect::<Result<Vec<_>>>()?;
        for (k, m) in models.iter().enumerate() {
            if m.camera_size() != meta.camera_size {
                return Err(Error::Input(format!(
                    "{}: its model sees a {} camera, {} says {}",
                    dir.join(projector_dir(k)).display(),
                    m.camera_size(),
                    file.display(),
                    meta.camera_size
                )));
            }
        }
        Ok(SetModel { meta, models })
    }

    /// Saves the set's model directory atomically: every part written complete beside `dir`,
    /// then exchanged with what was there in one step. Only a model directory (a set's or one
    /// projector's) is replaced ([`store::check_output`]).
    pub fn save(&self, dir: &Path) -> Result<()> {
        store::check_output(dir)?;
        let json = serde_json::to_vec_pretty(&self.meta)
            .map_err(|e| Error::Failed(format!("a set's model metadata: {e}")))?;
        let tmp = crate::files::temp_dir_for(dir)?;
        let result = self
            .models
            .iter()
            .enumerate()
            .try_for_each(|(k, m)| m.save(&tmp.join(projector_dir(k))))
            .and_then(|()| crate::files::write_synced(&tmp.join(SET_FILE), &json))
            .and_then(|()| crate::files::swap_in_dir(&tmp, dir));
        if result.is_err() {
            let _ = std::fs::remove_dir_all(&tmp);
        }
        result
    }

    /// The joint model of the projectors' `linear` models ([`crate::joint`]); another rung is
    /// an input error naming it.
    pub fn joint(&self) -> Result<JointModel> {
        let parts = self
            .models
            .iter()
            .enumerate()
            .map(|(k, m)| match &m.kind {
                super::Kind::Linear { simplified, .. } => Ok(simplified.clone()),
                _ => Err(Error::Input(format!(
                    "projector {}'s model is {}: a set is compensated jointly from each \
                     projector's `linear` model",
                    k + 1,
                    m.meta.method
                ))),
            })
            .collect::<Result<Vec<_>>>()?;
        JointModel::new(parts, self.meta.camera_size)
    }
}
