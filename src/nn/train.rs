//! Training CompenNet++ (docs/architecture.md, "Models"): WarpingNet then CompenNet, capture and
//! surface image warped by the same grid, loss `L1 + (1 − SSIM)`, Adam with L2 weight decay 1e-4
//! (added to the loss as (wd/2)·Σw², i.e. wd·w on the gradient, as the paper's optimiser does),
//! learning rate ×0.2 at the variant's step. Batches are drawn without replacement within a
//! batch. The surface branch runs once per step, not once per batch element. The model and one
//! step's gradients are in `nn::compennetpp`, the optimiser helpers in `nn::optim`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::Optimizer;
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

use super::compennetpp::{CompenNetPP, GeometryInit, Variant};
use super::optim::{adam, check_loss};
use super::pretrain::PhotometricInit;
use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// Settings of one training run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Settings {
    pub variant: Variant,
    /// Override of the variant's iterations (optimiser steps; the lr step scales with it).
    pub iters: Option<usize>,
    /// Override of the variant's batch size (training pairs per step).
    pub batch: Option<usize>,
    /// Adam's learning rate (its step size, in weight units) before the lr step.
    pub learning_rate: f64,
    /// L2 weight decay wd: (wd/2)·Σw² is added to the loss.
    pub weight_decay: f64,
    pub seed: u64,
    /// How CompenNet's weights start (default: the shipped pre-initialisation).
    #[serde(default)]
    pub photometric: PhotometricInit,
}

impl Settings {
    pub fn new(variant: Variant, seed: u64) -> Self {
        Self {
            variant,
            iters: None,
            batch: None,
            learning_rate: 1e-3,
            weight_decay: 1e-4,
            seed,
            photometric: PhotometricInit::default(),
        }
    }

    /// (batch, iterations, lr step) after overrides: training pairs per step, optimiser steps,
    /// and the step from which the learning rate is ×0.2 (scaled with the iterations).
    pub fn resolved(&self) -> (usize, usize, usize) {
        let schedule = self.variant.schedule();
        let iters = self.iters.unwrap_or(schedule.iterations).max(1);
        let step = ((schedule.lr_step as f64) * iters as f64 / schedule.iterations as f64).round()
            as usize;
        (self.batch.unwrap_or(schedule.batch).max(1), iters, step)
    }
}

/// Training data as tensors: captures (N, 3, Hc, Wc) and the surface image (1, 3, Hc, Wc), both
/// already masked by the FOV mask; projector inputs (N, 3, Hn, Wn).
pub struct Data {
    pub captures: Tensor,
    pub surface: Tensor,
    pub targets: Tensor,
    /// The residual rung: `linear`'s output for each capture at the targets' size, which the
    /// network's corrections (on its own, coarser network) are stretched over and added to.
    pub base: Option<Tensor>,
}

/// How many shards a training step of `batch` samples is split into on `device`: two on the CPU
/// (each shard runs on its own thread, see [`CompenNetPP::gradients`]), one elsewhere. The count
/// does not depend on the machine's thread count, so a seeded run does the same arithmetic on
/// any CPU.
pub fn shards_for(device: &Device, batch: usize) -> usize {
    if device.is_cpu() { batch.min(2) } else { 1 }
}

/// What training reports.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Optimiser steps taken: the settings' iterations, or fewer when the watch stopped the
    /// training ([`train`]).
    pub iterations: usize,
    /// Whether the watch stopped the training before the settings' iterations.
    pub stopped_early: bool,
    pub batch: usize,
    pub lr_step: usize,
    /// Loss per iteration.
    pub losses: Vec<f64>,
    pub seconds: f64,
    /// Milliseconds per training sample (forward + backward + update).
    pub ms_per_sample: f64,
    /// Where CompenNet's weights started: `kaiming`, or the pre-trained file's source.
    pub photometric_init: String,
}

/// Trains a fresh model. Stops with an error (and no model) when `cancel` is set, when the loss
/// becomes non-finite or blows up, or when the output collapses to a flat image.
/// `progress(done, total, loss)` runs after each step. `watch(done, model)` runs before the
/// first step (`done` = 0) and after each one; when it returns false the training ends there
/// with the model as it is (`Report::stopped_early`).
pub fn train(
    data: &Data,
    init: GeometryInit,
    settings: &Settings,
    cancel: &AtomicBool,
    mut progress: impl FnMut(usize, usize, f64),
    mut watch: impl FnMut(usize, &CompenNetPP) -> Result<bool>,
) -> Result<(CompenNetPP, Report)> {
    let start = Instant::now();
    let n = data.captures.dim(0)?;
    let (_, _, hn, wn) = data.targets.dims4()?;
    let (batch, iters, lr_step) = settings.resolved();
    let batch = batch.min(n);
    if n == 0 {
        return Err(Error::Input(
            "CompenNet++ training needs at least one training pair".into(),
        ));
    }
    let device = data.captures.device().clone();
    // A fixed grid sets the network's size: the residual rung's is coarser than its targets.
    let size = match &init {
        GeometryInit::Fixed(g) => {
            let (_, h, w, _) = g.dims4()?;
            ImageSize::new(w, h)
        }
        _ => ImageSize::new(wn, hn),
    };
    let (model, photometric_init) = fresh_model(init, size, settings, &device)?;
    let vars = model.varmap.all_vars();
    let mut opt = adam(vars.clone(), settings.learning_rate)?;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut order: Vec<u32> = (0..n as u32).collect();
    let mut losses = Vec::with_capacity(iters);
    let mut steps = 0;
    let mut go_on = watch(0, &model)?;
    while go_on && steps < iters {
        let it = steps;
        if cancel.load(Ordering::Relaxed) {
            return Err(Error::Cancelled(format!(
                "the training (at iteration {it} of {iters})"
            )));
        }
        if it == lr_step {
            opt.set_learning_rate(settings.learning_rate * 0.2);
        }
        // A batch of distinct pairs.
        order.shuffle(&mut rng);
        let idx = Tensor::from_vec(order[..batch].to_vec(), batch, &device)?;
        let x = data.captures.index_select(&idx, 0)?;
        let y = data.targets.index_select(&idx, 0)?;
        let base = match &data.base {
            Some(b) => Some(b.index_select(&idx, 0)?),
            None => None,
        };
        let (value, grads) = model.gradients(
            &x,
            &y,
            base.as_ref(),
            &data.surface,
            settings.weight_decay,
            shards_for(&device, batch),
        )?;
        check_loss(value, it, &losses)?;
        losses.push(value);
        opt.step(&grads)?;
        steps += 1;
        progress(steps, iters, value);
        go_on = watch(steps, &model)?;
    }
    check_not_collapsed(&model, data, n)?;
    let seconds = start.elapsed().as_secs_f64();
    Ok((
        model,
        Report {
            iterations: steps,
            stopped_early: steps < iters,
            batch,
            lr_step,
            ms_per_sample: 1e3 * seconds / (steps.max(1) * batch) as f64,
            losses,
            photometric_init,
            seconds,
        },
    ))
}

/// A fresh model for a network of `size` (W, H) pixels, seeded by the settings, with CompenNet's
/// weights from the photometric pre-initialisation when the settings ask for one; and where
/// those weights came from (`kaiming`, or the pre-trained file's source).
fn fresh_model(
    init: GeometryInit,
    size: ImageSize,
    settings: &Settings,
    device: &Device,
) -> Result<(CompenNetPP, String)> {
    let mut model = CompenNetPP::with_width(
        init,
        size,
        settings.variant.refine(),
        settings.variant.width(),
        settings.seed,
        device,
    )?;
    let photometric_init = match settings.photometric.resolve(settings.variant.width())? {
        Some(weights) => {
            weights.apply(&model.varmap)?;
            weights.source
        }
        None => "kaiming".to_string(),
    };
    // After the pre-initialisation: the correction starts at zero whatever it set.
    if settings.variant.residual() {
        model.make_residual()?;
    }
    Ok((model, photometric_init))
}

/// Collapse check: a model whose outputs no longer depend on the input is useless. The mean
/// per-image variance of the outputs for the first (up to 4) of the `n` captures must exceed 1e-6
/// (images in [0, 1]).
fn check_not_collapsed(model: &CompenNetPP, data: &Data, n: usize) -> Result<()> {
    let probe = data.captures.narrow(0, 0, n.min(4))?;
    let mut out = model.forward(&probe, &data.surface)?;
    if let Some(b) = &data.base {
        out = super::compennetpp::with_base(&out, &b.narrow(0, 0, n.min(4))?)?;
    }
    let spread: f64 = out
        .flatten_from(1)?
        .var_keepdim(1)?
        .mean_all()?
        .to_dtype(DType::F64)?
        .to_scalar()?;
    if spread.is_nan() || spread <= 1e-6 {
        return Err(Error::Failed(format!(
            "training collapsed: the output is flat (variance {spread:e}); no model produced"
        )));
    }
    Ok(())
}
