//! A trained model as the offline commands and playback see it: load it from a model directory,
//! map camera-space images to network-space projector images, save it.

use std::path::Path;

use crate::error::{Error, Result};
use crate::linear::LinearModel;
use crate::modeldir::{self, ModelMeta, Tensors};
use crate::raster::{CamImage, Camera, Mask, NetImage, Network};
use crate::sample::Grid;

/// The methods this build can load, by rung.
pub const METHODS: &[&str] = &[crate::linear::METHOD, "linear-sl"];

/// A loaded model with its metadata and the projector FOV mask its inputs are masked with.
#[derive(Clone, Debug)]
pub struct Model {
    pub meta: ModelMeta,
    /// Projector FOV in camera space; inputs are masked by it, as in training.
    pub fov: Mask<Camera>,
    pub kind: Kind,
}

#[derive(Clone, Debug)]
pub enum Kind {
    /// `linear` and `linear-sl` share the representation; they differ in how geometry was found.
    Linear {
        model: LinearModel,
        simplified: crate::linear::SimplifiedLinear,
    },
}

impl Model {
    pub fn linear(meta: ModelMeta, fov: Mask<Camera>, model: LinearModel) -> Self {
        let simplified = model.simplify();
        Self {
            meta,
            fov,
            kind: Kind::Linear { model, simplified },
        }
    }

    /// Loads a model directory; an unknown method, a version mismatch, a missing or mis-shaped
    /// tensor is an input error naming the file.
    pub fn load(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::Missing {
                path: dir.to_path_buf(),
                expected: format!(
                    "a model directory holding {} and {}",
                    modeldir::META_FILE,
                    modeldir::WEIGHTS_FILE
                ),
            });
        }
        let (meta, tensors) = modeldir::load(dir)?;
        let file = dir.join(modeldir::WEIGHTS_FILE);
        let (cw, ch) = meta.camera_size;
        let fov = tensors.get("fov_mask", &[ch, cw], &file)?;
        let fov = Mask::from_vec(cw, ch, fov.iter().map(|&v| v >= 0.5).collect())?;
        match meta.method.as_str() {
            m if m == crate::linear::METHOD || m == "linear-sl" => {
                let model = LinearModel::from_tensors(
                    &tensors,
                    meta.network_size,
                    meta.camera_size,
                    &file,
                )?;
                Ok(Self::linear(meta, fov, model))
            }
            other => Err(Error::Input(format!(
                "{}: method `{other}` is not one this compend can run (known: {})",
                dir.join(modeldir::META_FILE).display(),
                METHODS.join(", ")
            ))),
        }
    }

    /// Saves the model directory atomically (an existing model is replaced only when complete).
    pub fn save(&self, dir: &Path) -> Result<()> {
        let mut tensors: Tensors = match &self.kind {
            Kind::Linear { model, .. } => model.to_tensors()?,
        };
        let (cw, ch) = self.fov.size();
        tensors.insert(
            "fov_mask",
            vec![ch, cw],
            self.fov
                .data()
                .iter()
                .map(|&b| if b { 1.0 } else { 0.0 })
                .collect(),
        )?;
        modeldir::save(dir, &self.meta, &tensors)
    }

    pub fn camera_size(&self) -> (usize, usize) {
        self.meta.camera_size
    }

    pub fn network_size(&self) -> (usize, usize) {
        self.meta.network_size
    }

    /// The baked sampling grid from network pixels into the camera image.
    pub fn grid(&self) -> &Grid<Network, Camera> {
        match &self.kind {
            Kind::Linear { simplified, .. } => &simplified.grid,
        }
    }

    fn check_input(&self, img: &CamImage) -> Result<()> {
        if img.size() != self.camera_size() {
            return Err(Error::Shape(format!(
                "model expects {}x{} camera images, got {}x{}",
                self.camera_size().0,
                self.camera_size().1,
                img.width(),
                img.height()
            )));
        }
        Ok(())
    }

    /// π†: a camera-space image (a capture x̃ or a desired viewer image z') to the network-space
    /// projector image, the input masked by the FOV mask first.
    pub fn infer(&self, img: &CamImage) -> Result<NetImage> {
        self.check_input(img)?;
        let masked = img.masked(&self.fov)?;
        Ok(match &self.kind {
            Kind::Linear { simplified, .. } => simplified.apply(&masked),
        })
    }

    /// The geometry alone: the masked camera image warped to network space (the paper's
    /// "uncompensated" row compares these with the projector inputs).
    pub fn warp_only(&self, img: &CamImage) -> Result<NetImage> {
        self.check_input(img)?;
        let masked = img.masked(&self.fov)?;
        Ok(crate::sample::grid_sample(&masked, self.grid()))
    }
}

/// The paper protocol (DESIGN.md section 6) on test pairs: the model's output for each capture
/// against the projector input, and the "uncompensated" row (captures warped by the model's own
/// grid against the inputs). Returns (compensated, uncompensated).
pub fn paper_protocol(
    model: &Model,
    pairs: &crate::dataset::Pairs,
) -> Result<(crate::metrics::Scores, crate::metrics::Scores)> {
    let (mut comp, mut uncomp) = (
        crate::metrics::Accumulator::default(),
        crate::metrics::Accumulator::default(),
    );
    for (cap, input) in pairs.captures.iter().zip(&pairs.inputs) {
        let target: NetImage = input.clone().into_space();
        comp.add(&model.infer(cap)?, &target)?;
        uncomp.add(&model.warp_only(cap)?, &target)?;
    }
    Ok((comp.finish()?, uncomp.finish()?))
}
