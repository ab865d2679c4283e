//! The photometric pre-initialisation of CompenNet (docs/architecture.md, "Models"): CompenNet
//! trained once, independent of any setup and with no projection, on synthetic pairs — input
//! `|x − 0.3·ṡ|`, surface image `ṡ`, target `x` — where `x` and `ṡ` are colourful sampling images
//! ([`crate::patterns::sampling`]) from their own random streams. Every CompenNet++ training then
//! starts its photometric part from these weights instead of Kaiming noise, so the few samples a
//! CPU can afford go into the setup rather than into learning that the output should resemble the
//! input.
//!
//! The weights of both shipped widths (the paper's 32 and the CPU rung's 16) live in `weights/`
//! and are compiled into the program; `compend pretrain` regenerates them from the seed recorded
//! in the JSON file beside each. Images are in [0,1], network pixels; the weights do not depend on
//! the image size (the network is convolutional), so pre-training runs on small crops.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarMap};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

use super::compennet::CompenNet;
use super::layers::SeededInit;
use super::loss;
use super::optim::{adam, check_loss, l2_penalty};
use crate::error::{Error, Result};
use crate::patterns::sampling::{Set, sampling_image};
use crate::tensors::Tensors;

/// Variable prefix of CompenNet inside a CompenNet++ model (and in the pre-trained file).
pub const PREFIX: &str = "compen";
/// Version of the pre-trained weight file pair (safetensors + JSON).
pub const FORMAT_VERSION: u32 = 1;
/// What the JSON file beside the weights says it is.
pub const KIND: &str = "compennet-photometric-pretrain";
/// Weight of the synthetic surface in the input `|x − SURFACE_WEIGHT·ṡ|` (docs/architecture.md,
/// "Models"); images in [0, 1].
pub const SURFACE_WEIGHT: f64 = 0.3;

/// Settings of one pre-training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PretrainSettings {
    /// CompenNet's base channel width (32 for the paper's network, 16 for the CPU rung).
    pub width: usize,
    /// Side of the square training crops, network pixels (a multiple of 4).
    pub patch: usize,
    /// Side of the generated images the crops are cut from.
    pub image: usize,
    /// Generated content images `x` and surface images `ṡ` (each).
    pub pool: usize,
    pub batch: usize,
    pub iters: usize,
    /// Iteration at which the learning rate drops ×0.2.
    pub lr_step: usize,
    pub learning_rate: f64,
    /// L2 weight decay (added to the loss, as in CompenNet++ training).
    pub weight_decay: f64,
    pub seed: u64,
}

impl PretrainSettings {
    /// The schedule the shipped weights were made with, for base width `width`.
    pub fn shipped(width: usize) -> Self {
        Self {
            width,
            patch: 64,
            image: 128,
            pool: 96,
            batch: 8,
            iters: 2000,
            lr_step: 1600,
            // 1e-3 (the paper's rate for CompenNet++) took 1 000 iterations to reach the input's
            // own loss at width 16; 3e-3 reached it in 300; 1e-2 did not learn.
            learning_rate: 3e-3,
            weight_decay: 1e-4,
            seed: 0,
        }
    }

    fn validate(&self) -> Result<()> {
        let mut bad = Vec::new();
        if self.width == 0 {
            bad.push("width must be at least 1".to_string());
        }
        if self.patch < 4 || !self.patch.is_multiple_of(4) {
            bad.push(format!(
                "patch {} must be a positive multiple of 4",
                self.patch
            ));
        }
        if self.image < self.patch {
            bad.push(format!(
                "image side {} is smaller than the patch {}",
                self.image, self.patch
            ));
        }
        if self.pool == 0 || self.batch == 0 || self.iters == 0 {
            bad.push(format!(
                "pool ({}), batch ({}) and iterations ({}) must be at least 1",
                self.pool, self.batch, self.iters
            ));
        }
        if bad.is_empty() {
            Ok(())
        } else {
            Err(Error::Input(format!(
                "pre-training settings: {}",
                bad.join("; ")
            )))
        }
    }
}

/// Provenance stored in the JSON file beside the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PretrainMeta {
    pub format_version: u32,
    pub kind: String,
    pub settings: PretrainSettings,
    /// Mean loss (`L1 + 1 − SSIM`) over the first and the last 50 iterations.
    pub first_loss: f64,
    pub final_loss: f64,
    /// The same loss for the input `|x − 0.3·ṡ|` taken as the answer, over the last 50
    /// iterations' batches: the network has learnt to undo the surface when `final_loss` is
    /// below it.
    pub input_loss: f64,
    pub seconds: f64,
    pub written_by: String,
}

/// Pre-trained CompenNet weights: tensors named as in a CompenNet++ model (`compen.…`).
#[derive(Clone, Debug)]
pub struct Pretrained {
    pub meta: PretrainMeta,
    pub tensors: Tensors,
    /// Where they came from (a path, or `shipped:<file>`), for messages and model metadata.
    pub source: String,
}

/// The shipped weight files, compiled in: (width, file name, safetensors, JSON).
const SHIPPED: [(usize, &str, &[u8], &str); 2] = [
    (
        16,
        "weights/compennet-pretrain-w16.safetensors",
        include_bytes!("../../weights/compennet-pretrain-w16.safetensors"),
        include_str!("../../weights/compennet-pretrain-w16.json"),
    ),
    (
        32,
        "weights/compennet-pretrain-w32.safetensors",
        include_bytes!("../../weights/compennet-pretrain-w32.safetensors"),
        include_str!("../../weights/compennet-pretrain-w32.json"),
    ),
];

/// The JSON file beside a weight file: `X.safetensors` → `X.json`.
pub fn meta_path(weights: &Path) -> PathBuf {
    weights.with_extension("json")
}

impl Pretrained {
    /// The weights shipped with the program for base width `width`, if any.
    pub fn shipped(width: usize) -> Result<Option<Self>> {
        let Some((_, name, bytes, json)) = SHIPPED.iter().find(|s| s.0 == width) else {
            return Ok(None);
        };
        let path = Path::new(name);
        Self::parse(
            bytes,
            json,
            path,
            &meta_path(path),
            format!("shipped:{name}"),
        )
        .map(Some)
    }

    /// Widths with shipped weights.
    pub fn shipped_widths() -> Vec<usize> {
        SHIPPED.iter().map(|s| s.0).collect()
    }

    /// Reads `path` (safetensors) and the JSON file beside it.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = crate::files::read_regular(
            path,
            "pre-trained weights (safetensors)",
            crate::files::MAX_WEIGHTS_BYTES,
        )?;
        let mpath = meta_path(path);
        let json = crate::files::read_text(&mpath, "the pre-trained weights' metadata (JSON)")?;
        Self::parse(&bytes, &json, path, &mpath, path.display().to_string())
    }

    fn parse(bytes: &[u8], json: &str, path: &Path, mpath: &Path, source: String) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_str(json)
            .map_err(|e| Error::Input(format!("{}: not valid JSON ({e})", mpath.display())))?;
        match value.get("format_version").and_then(|v| v.as_u64()) {
            Some(v) if v == FORMAT_VERSION as u64 => {}
            other => {
                return Err(Error::Input(format!(
                    "{}: pre-trained weights format version {}, this compend reads version {FORMAT_VERSION}; regenerate them with `compend pretrain`",
                    mpath.display(),
                    other.map_or("missing".to_string(), |v| v.to_string())
                )));
            }
        }
        let meta: PretrainMeta = serde_json::from_value(value).map_err(|e| {
            Error::Input(format!(
                "{}: invalid pre-training metadata ({e})",
                mpath.display()
            ))
        })?;
        if meta.kind != KIND {
            return Err(Error::Input(format!(
                "{}: kind `{}`, expected `{KIND}`",
                mpath.display(),
                meta.kind
            )));
        }
        let tensors = Tensors::from_bytes(bytes, path)?;
        Ok(Self {
            meta,
            tensors,
            source,
        })
    }

    /// Writes the weights to `path` and the metadata beside it, each file atomically (the
    /// metadata last, so a crash in between leaves no JSON claiming new weights).
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::files::write_atomically(path, &self.tensors.to_bytes()?)?;
        let json = serde_json::to_vec_pretty(&self.meta)
            .map_err(|e| Error::Failed(format!("pre-training metadata: {e}")))?;
        crate::files::write_atomically(&meta_path(path), &json)
    }

    /// Sets every CompenNet variable of `varmap` (names `compen.…`) from these weights. Every
    /// such variable must be present with the same shape; returns how many were set.
    pub fn apply(&self, varmap: &VarMap) -> Result<usize> {
        let file = Path::new(&self.source);
        let data = varmap
            .data()
            .lock()
            .map_err(|_| Error::Failed("variable map lock poisoned".into()))?;
        let mut set = 0;
        for (name, var) in data.iter() {
            if !name.starts_with(&format!("{PREFIX}.")) {
                continue;
            }
            let dims = var.dims().to_vec();
            let values = self.tensors.get(name, &dims, file)?;
            Tensor::from_vec(values.to_vec(), dims, var.device())
                .and_then(|t| t.to_dtype(var.dtype()))
                .and_then(|t| var.set(&t))
                .map_err(|e| e.context(format!("setting `{name}` from {}", self.source)))?;
            set += 1;
        }
        if set == 0 {
            return Err(Error::Failed(format!(
                "no CompenNet variables to set from {}",
                self.source
            )));
        }
        Ok(set)
    }
}

/// The synthetic training material: content images `x` and surface images `ṡ`, (P, 3, S, S) each.
struct Pool {
    content: Tensor,
    surface: Tensor,
}

impl Pool {
    /// Content from the sampling generator's training stream, surfaces from its test stream,
    /// both under a seed derived from `seed` (so they share nothing with a dataset made with the
    /// same seed).
    fn new(settings: &PretrainSettings, device: &Device) -> Result<Self> {
        let derived = settings.seed ^ 0x5052_4554_5241_494e; // "PRETRAIN"
        let side = settings.image;
        // Surfaces are smooth (made at a quarter of the side and enlarged): a camera sees a
        // surface through its optics, and CompenNet's surface branch works at 1/2 and 1/4 of the
        // network size; content keeps its full detail.
        let coarse = (side / 4).max(1);
        let make = |set: Set| -> Result<Tensor> {
            let imgs: Vec<_> = (0..settings.pool)
                .map(|i| match set {
                    Set::Train => sampling_image(derived, set, i, side, side),
                    Set::Test => crate::resize::resize(
                        &sampling_image(derived, set, i, coarse, coarse),
                        side,
                        side,
                        crate::resize::Filter::Bilinear,
                    ),
                })
                .collect();
            Ok(super::images_to_tensor(&imgs)?.to_device(device)?)
        };
        Ok(Self {
            content: make(Set::Train)?,
            surface: make(Set::Test)?,
        })
    }

    fn crop(t: &Tensor, i: usize, x: usize, y: usize, p: usize) -> candle_core::Result<Tensor> {
        t.narrow(0, i, 1)?.narrow(2, y, p)?.narrow(3, x, p)
    }

    /// One step's batch: inputs `|x − 0.3·ṡ|` (B, 3, p, p), the surface `ṡ` (1, 3, p, p) shared
    /// by the batch, and the targets `x`.
    fn batch(
        &self,
        settings: &PretrainSettings,
        rng: &mut ChaCha8Rng,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let (p, side, n) = (settings.patch, settings.image, settings.pool);
        let corner = |rng: &mut ChaCha8Rng| {
            (
                rng.random_range(0..=side - p),
                rng.random_range(0..=side - p),
            )
        };
        let (sx, sy) = corner(rng);
        let surface = Self::crop(&self.surface, rng.random_range(0..n), sx, sy, p)?;
        let mut targets = Vec::with_capacity(settings.batch);
        for _ in 0..settings.batch {
            let (x, y) = corner(rng);
            targets.push(Self::crop(&self.content, rng.random_range(0..n), x, y, p)?);
        }
        let targets = Tensor::cat(&targets, 0)?;
        let inputs = targets
            .broadcast_sub(&surface.affine(SURFACE_WEIGHT, 0.0)?)?
            .abs()?;
        Ok((inputs, surface, targets))
    }
}

/// Pre-trains CompenNet of base width `settings.width` from a seeded Kaiming start. Reproducible
/// from the settings on the same machine and thread count (candle's CPU reductions are
/// deterministic for a fixed thread count).
pub fn pretrain(
    settings: &PretrainSettings,
    device: &Device,
    cancel: &AtomicBool,
    mut progress: impl FnMut(usize, usize, f64),
) -> Result<Pretrained> {
    settings.validate()?;
    let start = Instant::now();
    let pool = Pool::new(settings, device)?;
    let seeded = SeededInit::new(settings.seed);
    let vb = seeded.var_builder(DType::F32, device);
    let net = CompenNet::with_width(vb.pp(PREFIX), settings.width)?;
    let varmap = seeded.finish()?;
    let vars = varmap.all_vars();
    let mut opt = adam(vars.clone(), settings.learning_rate)?;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut losses = Vec::with_capacity(settings.iters);
    let window = settings.iters.min(50);
    let mut input_losses = Vec::with_capacity(window);
    for it in 0..settings.iters {
        if cancel.load(Ordering::Relaxed) {
            return Err(Error::Failed(format!(
                "pre-training cancelled at iteration {it} of {}",
                settings.iters
            )));
        }
        if it == settings.lr_step {
            opt.set_learning_rate(settings.learning_rate * 0.2);
        }
        let (x, s, y) = pool.batch(settings, &mut rng)?;
        if it >= settings.iters - window {
            input_losses.push(to_f64(&loss::l1_ssim(&x, &y)?)?);
        }
        let out = net.forward(&x, &s)?;
        let fit = loss::l1_ssim(&out, &y)?;
        let l2 = l2_penalty(&vars, device)?.affine(0.5 * settings.weight_decay, 0.0)?;
        let total = (&fit + l2)?;
        let value = to_f64(&fit)?;
        check_loss(value, it, &losses)?;
        losses.push(value);
        opt.backward_step(&total)?;
        progress(it + 1, settings.iters, value);
    }
    let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len().max(1) as f64;
    Ok(Pretrained {
        meta: PretrainMeta {
            format_version: FORMAT_VERSION,
            kind: KIND.to_string(),
            settings: settings.clone(),
            first_loss: mean(&losses[..window]),
            final_loss: mean(&losses[losses.len() - window..]),
            input_loss: mean(&input_losses),
            seconds: start.elapsed().as_secs_f64(),
            written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
        },
        tensors: weight_tensors(&varmap)?,
        source: "pre-training run".to_string(),
    })
}

/// A scalar tensor's value as f64.
fn to_f64(t: &Tensor) -> candle_core::Result<f64> {
    t.to_dtype(DType::F64)?.to_scalar::<f64>()
}

/// Every variable of `varmap` as f32 values under its name, in name order.
fn weight_tensors(varmap: &VarMap) -> Result<Tensors> {
    let mut tensors = Tensors::default();
    let data = varmap
        .data()
        .lock()
        .map_err(|_| Error::Failed("variable map lock poisoned".into()))?;
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    for name in names {
        let t = data[name].as_tensor();
        let values = t.flatten_all()?.to_dtype(DType::F32)?.to_vec1::<f32>()?;
        tensors.insert(name, t.dims().to_vec(), values)?;
    }
    Ok(tensors)
}

/// How a CompenNet++ model's photometric part (CompenNet) starts.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PhotometricInit {
    /// Kaiming-normal noise from the training seed (the paper without pre-initialisation).
    Kaiming,
    /// The weights shipped with the program for the variant's width.
    #[default]
    Shipped,
    /// Weights from a `compend pretrain` file.
    File(PathBuf),
}

impl std::str::FromStr for PhotometricInit {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "none" | "kaiming" => Ok(Self::Kaiming),
            "shipped" => Ok(Self::Shipped),
            "" => Err("expected `shipped`, `none` or a path to a .safetensors file".into()),
            path => Ok(Self::File(PathBuf::from(path))),
        }
    }
}

impl PhotometricInit {
    /// The weights to load for base width `width`, or `None` for a Kaiming start.
    pub fn resolve(&self, width: usize) -> Result<Option<Pretrained>> {
        match self {
            Self::Kaiming => Ok(None),
            Self::Shipped => Pretrained::shipped(width)?.map(Some).ok_or_else(|| {
                Error::Input(format!(
                    "no shipped photometric pre-initialisation for CompenNet width {width} (shipped: {:?}); use `--photometric-init none` or make one with `compend pretrain --width {width}`",
                    Pretrained::shipped_widths()
                ))
            }),
            Self::File(p) => {
                let w = Pretrained::load(p)?;
                if w.meta.settings.width != width {
                    return Err(Error::Input(format!(
                        "{}: pre-trained for CompenNet width {}, this variant's width is {width}",
                        p.display(),
                        w.meta.settings.width
                    )));
                }
                Ok(Some(w))
            }
        }
    }
}
