//! Training CompenNet++ (DESIGN.md section 5.3): WarpingNet then CompenNet, capture and surface
//! image warped by the same grid, loss `L1 + (1 − SSIM)`, Adam with L2 weight decay 1e-4 (added to
//! the loss as (wd/2)·Σw², i.e. wd·w on the gradient, as the paper's optimiser does), learning rate
//! ×0.2 at the variant's step. Batches are drawn without replacement within a batch. The surface
//! branch runs once per step, not once per batch element.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

use super::{CompenNet, WarpingNet, grid_sample, loss};
use crate::error::{Error, Result};

/// The four variants of the paper's table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Variant {
    Full,
    NoRefine,
    Fast,
    Faster,
    /// The two-step baseline: CompenNet on images registered by structured light (fixed grid).
    Sl,
    /// The CPU-sized rung: the same design at half the network resolution and half the channel
    /// widths, for projection PCs without a GPU (its output is stretched over the canvas like
    /// any network image).
    Cpu,
}

impl Variant {
    pub const ALL: [Variant; 6] = [
        Variant::Full,
        Variant::NoRefine,
        Variant::Fast,
        Variant::Faster,
        Variant::Sl,
        Variant::Cpu,
    ];

    pub fn method(self) -> &'static str {
        match self {
            Variant::Full => "compennet++",
            Variant::NoRefine => "compennet++-norefine",
            Variant::Fast => "compennet++-fast",
            Variant::Faster => "compennet++-faster",
            Variant::Sl => "compennet-sl",
            Variant::Cpu => "compennet++-cpu",
        }
    }

    /// The base channel width of CompenNet (the paper's: 32).
    pub fn width(self) -> usize {
        match self {
            Variant::Cpu => super::compennet::PAPER_WIDTH / 2,
            _ => super::compennet::PAPER_WIDTH,
        }
    }

    /// The network side is the data root's divided by this.
    pub fn network_divisor(self) -> usize {
        match self {
            Variant::Cpu => 2,
            _ => 1,
        }
    }

    pub fn from_method(m: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.method() == m)
    }

    /// (#train, batch, iterations, lr step) of DESIGN.md 5.3; `compennet-sl` uses the `faster`
    /// schedule (the paper's table has no row for it; this keeps it comparable on a CPU).
    pub fn schedule(self) -> (usize, usize, usize, usize) {
        match self {
            Variant::Full | Variant::NoRefine => (500, 48, 1500, 1000),
            Variant::Fast => (48, 24, 1000, 800),
            Variant::Faster | Variant::Sl => (48, 16, 500, 400),
            Variant::Cpu => (48, 4, 1000, 800),
        }
    }

    pub fn refine(self) -> bool {
        !matches!(self, Variant::NoRefine | Variant::Sl)
    }

    /// Whether the geometry is a fixed grid (from structured light) rather than learned.
    pub fn fixed_geometry(self) -> bool {
        self == Variant::Sl
    }
}

/// Settings of one training run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Settings {
    pub variant: Variant,
    /// Override of the variant's iterations (the lr step scales with it).
    pub iters: Option<usize>,
    /// Override of the variant's batch size.
    pub batch: Option<usize>,
    pub learning_rate: f64,
    pub weight_decay: f64,
    pub seed: u64,
    /// How CompenNet's weights start (default: the shipped pre-initialisation).
    #[serde(default)]
    pub photometric: super::pretrain::PhotometricInit,
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
            photometric: super::pretrain::PhotometricInit::default(),
        }
    }

    /// (batch, iterations, lr step) after overrides.
    pub fn resolved(&self) -> (usize, usize, usize) {
        let (_, b, it, step) = self.variant.schedule();
        let iters = self.iters.unwrap_or(it).max(1);
        let step = ((step as f64) * iters as f64 / it as f64).round() as usize;
        (self.batch.unwrap_or(b).max(1), iters, step)
    }
}

/// Training data as tensors: captures (N, 3, Hc, Wc) and the surface image (1, 3, Hc, Wc), both
/// already masked by the FOV mask; projector inputs (N, 3, Hn, Wn).
pub struct Data {
    pub captures: Tensor,
    pub surface: Tensor,
    pub targets: Tensor,
}

/// Where the sampling grid comes from.
pub enum Geometry {
    /// WarpingNet, trained end to end (the CompenNet++ variants).
    Learned(Box<WarpingNet>),
    /// A fixed (1, H, W, 2) grid, e.g. from decoded structured light (`compennet-sl`).
    Fixed(Tensor),
}

impl Geometry {
    /// The (1, H, W, 2) grid from network pixels into the camera image.
    pub fn grid(&self) -> candle_core::Result<Tensor> {
        match self {
            Geometry::Learned(w) => w.grid(),
            Geometry::Fixed(g) => Ok(g.clone()),
        }
    }
}

/// How a fresh model's geometry starts.
pub enum GeometryInit {
    /// WarpingNet with this affine (e.g. from the FOV bounding box).
    Affine([[f32; 3]; 2]),
    /// WarpingNet starting from a fitted affine + TPS warp (the `linear` rung's geometry: the
    /// same parametrisation), its refinement CNN fresh.
    Warp(crate::warp::Warp),
    /// A fixed grid (1, H, W, 2).
    Fixed(Tensor),
}

/// The trainable model: its variables and the networks built on them.
pub struct CompenNetPP {
    pub varmap: VarMap,
    pub warp: Geometry,
    pub compen: CompenNet,
}

impl CompenNetPP {
    /// A fresh model for a network of `size` (W, H) with geometry `init`, every other weight
    /// drawn from `seed` ([`super::layers::seeded_init`]).
    pub fn new(
        init: GeometryInit,
        size: (usize, usize),
        refine: bool,
        seed: u64,
        device: &Device,
    ) -> candle_core::Result<Self> {
        Self::with_width(
            init,
            size,
            refine,
            super::compennet::PAPER_WIDTH,
            seed,
            device,
        )
    }

    /// [`CompenNetPP::new`] with CompenNet's base channel width `width`.
    pub fn with_width(
        init: GeometryInit,
        size: (usize, usize),
        refine: bool,
        width: usize,
        seed: u64,
        device: &Device,
    ) -> candle_core::Result<Self> {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        let mut tps_init = None;
        let warp = match init {
            GeometryInit::Affine(theta) => Geometry::Learned(Box::new(WarpingNet::new(
                vb.pp("warp"),
                Some(theta),
                size,
                refine,
            )?)),
            GeometryInit::Warp(w) => {
                tps_init = Some(w.tps.concat());
                Geometry::Learned(Box::new(WarpingNet::new(
                    vb.pp("warp"),
                    Some(w.theta),
                    size,
                    refine,
                )?))
            }
            GeometryInit::Fixed(grid) => {
                let (_, h, w, _) = grid.dims4()?;
                if (w, h) != size {
                    candle_core::bail!("fixed grid is {w}x{h}, the network {}x{}", size.0, size.1);
                }
                Geometry::Fixed(grid.to_dtype(DType::F32)?.detach())
            }
        };
        let compen = CompenNet::with_width(vb.pp("compen"), width)?;
        super::layers::seeded_init(&varmap, seed)?;
        // A starting TPS replaces the seeded near-identity one.
        if let (Some(tps), Geometry::Learned(w)) = (tps_init, &warp) {
            if tps.len() != 2 * crate::warp::TPS_PARAMS {
                candle_core::bail!(
                    "starting warp has {} TPS parameters, expected {}",
                    tps.len(),
                    2 * crate::warp::TPS_PARAMS
                );
            }
            let value = Tensor::from_vec(tps, (2, crate::warp::TPS_PARAMS), device)?;
            candle_core::Var::from_tensor(&w.tps)?.set(&value)?;
        }
        Ok(Self {
            varmap,
            warp,
            compen,
        })
    }

    /// π†: captures (B, 3, Hc, Wc) and surface (1, 3, Hc, Wc) → projector images (B, 3, Hn, Wn).
    pub fn forward(&self, captures: &Tensor, surface: &Tensor) -> candle_core::Result<Tensor> {
        let b = captures.dim(0)?;
        let grid = self.warp.grid()?;
        let sw = grid_sample(surface, &grid)?;
        let features = self.compen.surface(&sw)?;
        let (_, h, w, _) = grid.dims4()?;
        let gb = grid.broadcast_as((b, h, w, 2))?.contiguous()?;
        let xw = grid_sample(captures, &gb)?;
        self.compen.forward_with(&xw, &features)
    }
}

/// How many shards a training step of `batch` samples is split into on `device`: two on the CPU
/// (each shard runs on its own thread, see [`CompenNetPP::gradients`]), one elsewhere. The count
/// does not depend on the machine's thread count, so a seeded run does the same arithmetic on
/// any CPU.
pub fn shards_for(device: &Device, batch: usize) -> usize {
    if device.is_cpu() { batch.min(2) } else { 1 }
}

impl CompenNetPP {
    /// One training step's loss and gradients for captures `x` (B, 3, Hc, Wc), targets `y`
    /// (B, 3, Hn, Wn) and the surface image (1, 3, Hc, Wc): the fit `L1 + (1 − SSIM)` over the
    /// batch (its value is returned) plus the L2 term `(wd/2)·Σw²` over every variable.
    ///
    /// With `shards` > 1 the batch is split into that many contiguous parts whose backbone
    /// passes, forward and backward, run in parallel (one rayon task each). On a small CPU this
    /// is what makes the second core pay: each op of the CPU rung is too small to split across
    /// threads (the wake-ups cost more than the work), a shard is not. The shared part, the
    /// grid and the surface branch, still runs once per step: the shards start from detached
    /// copies of the grid and the surface features, and the gradients they return for those
    /// copies are pushed back through the shared part in one backward pass
    /// (`Σ grid·∂grid + Σ s_i·∂s_i`). Each shard's loss is weighted by its share of the batch, so
    /// the sum is the batch loss: the result equals the unsharded one up to float rounding.
    pub fn gradients(
        &self,
        x: &Tensor,
        y: &Tensor,
        surface: &Tensor,
        weight_decay: f64,
        shards: usize,
    ) -> candle_core::Result<(f64, candle_core::backprop::GradStore)> {
        use candle_core::Var;
        let vars = self.varmap.all_vars();
        let b = x.dim(0)?;
        let shards = shards.clamp(1, b.max(1));
        let device = x.device().clone();
        let l2 = l2_penalty(&vars, &device)
            .map_err(|e| candle_core::Error::Msg(e.to_string()))?
            .affine(0.5 * weight_decay, 0.0)?;
        let scalar = |t: &Tensor| t.to_dtype(DType::F64)?.to_scalar::<f64>();
        if shards == 1 {
            let out = self.forward(x, surface)?;
            let fit = loss::l1_ssim(&out, y)?;
            let value = scalar(&fit)?;
            return Ok((value, (&fit + l2)?.backward()?));
        }
        // The shared part, with its graph.
        let grid = self.warp.grid()?;
        let sw = grid_sample(surface, &grid)?;
        let f = self.compen.surface(&sw)?;
        let shared = [&f.s1, &f.s2, &f.s3, &f.s4];
        // The shards' starting points: detached copies that collect the shards' gradients.
        let grid_leaf = match self.warp {
            Geometry::Learned(_) => Some(Var::from_tensor(&grid.detach())?),
            Geometry::Fixed(_) => None,
        };
        let leaves = shared
            .iter()
            .map(|t| Var::from_tensor(&t.detach()))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let features = super::compennet::SurfaceFeatures {
            s1: leaves[0].as_tensor().clone(),
            s2: leaves[1].as_tensor().clone(),
            s3: leaves[2].as_tensor().clone(),
            s4: leaves[3].as_tensor().clone(),
        };
        let g = grid_leaf.as_ref().map_or(&grid, |v| v.as_tensor());
        let (_, h, w, _) = g.dims4()?;
        // Shard k covers samples lo..lo + len; its loss is weighted by len / b.
        let shard = |k: usize| -> candle_core::Result<(f64, candle_core::backprop::GradStore)> {
            let lo = k * b / shards;
            let len = (k + 1) * b / shards - lo;
            let gb = g.broadcast_as((len, h, w, 2))?.contiguous()?;
            let xw = grid_sample(&x.narrow(0, lo, len)?, &gb)?;
            let out = self.compen.forward_with(&xw, &features)?;
            let share = len as f64 / b as f64;
            let fit = loss::l1_ssim(&out, &y.narrow(0, lo, len)?)?.affine(share, 0.0)?;
            Ok((scalar(&fit)?, fit.backward()?))
        };
        let parts = run_shards(shards, &shard)?;
        let value = parts.iter().map(|(v, _)| v).sum();
        // Σ over shards of one tensor's gradient, in shard order.
        let summed = |t: &Tensor| -> candle_core::Result<Option<Tensor>> {
            let mut acc: Option<Tensor> = None;
            for (_, grads) in &parts {
                if let Some(gk) = grads.get(t) {
                    acc = Some(match acc {
                        None => gk.clone(),
                        Some(a) => (a + gk)?,
                    });
                }
            }
            Ok(acc)
        };
        // Back through the shared part: ∂/∂θ Σ t·∂t = ∂t/∂θ · ∂t for each shared output t.
        let mut through = l2;
        if let Some(leaf) = &grid_leaf {
            if let Some(dg) = summed(leaf.as_tensor())? {
                through = (through + (&grid * dg)?.sum_all()?)?;
            }
        }
        for (t, leaf) in shared.iter().zip(&leaves) {
            if let Some(dt) = summed(leaf.as_tensor())? {
                through = (through + (*t * dt)?.sum_all()?)?;
            }
        }
        let mut grads = through.backward()?;
        for v in &vars {
            let v = v.as_tensor();
            if let Some(dv) = summed(v)? {
                let total = match grads.get(v) {
                    Some(own) => (own + dv)?,
                    None => dv,
                };
                grads.insert(v, total);
            }
        }
        Ok((value, grads))
    }
}

/// Runs `shard(0..n)`, the shards in parallel on rayon's pool, and returns their results in
/// shard order.
fn run_shards<R: Send>(
    n: usize,
    shard: &(impl Fn(usize) -> candle_core::Result<R> + Sync),
) -> candle_core::Result<Vec<R>> {
    use rayon::prelude::*;
    (0..n).into_par_iter().with_max_len(1).map(shard).collect()
}

/// Adam with the paper's settings (β 0.9/0.999, ε 1e-8); weight decay is added to the loss.
pub(crate) fn adam(vars: Vec<candle_core::Var>, lr: f64) -> candle_core::Result<candle_nn::AdamW> {
    candle_nn::AdamW::new(
        vars,
        candle_nn::ParamsAdamW {
            lr,
            weight_decay: 0.0,
            ..Default::default()
        },
    )
}

/// Σw² over `vars` (the L2 weight-decay term before its factor wd/2).
pub(crate) fn l2_penalty(vars: &[candle_core::Var], device: &Device) -> Result<Tensor> {
    let ce = |e: candle_core::Error| Error::Failed(format!("L2 penalty: {e}"));
    vars.iter()
        .map(|v| v.as_tensor().sqr().and_then(|t| t.sum_all()))
        .try_fold(
            Tensor::zeros((), DType::F32, device).map_err(ce)?,
            |acc, t| t.and_then(|t| acc + t),
        )
        .map_err(ce)
}

/// Divergence check for iteration `it`'s loss `value` after the losses so far: a non-finite
/// loss, or one 10× the first after 10 iterations, stops training with an error.
pub(crate) fn check_loss(value: f64, it: usize, losses: &[f64]) -> Result<()> {
    if !value.is_finite() {
        return Err(Error::Failed(format!(
            "training diverged: loss {value} at iteration {it}"
        )));
    }
    if it >= 10 && value > 10.0 * losses[0] {
        return Err(Error::Failed(format!(
            "training diverged: loss {value:.4} at iteration {it}, {:.1}× the first",
            value / losses[0]
        )));
    }
    Ok(())
}

/// What training reports.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub iterations: usize,
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
pub fn train(
    data: &Data,
    init: GeometryInit,
    settings: &Settings,
    cancel: &AtomicBool,
    mut progress: impl FnMut(usize, usize, f64),
) -> Result<(CompenNetPP, Report)> {
    let start = Instant::now();
    let ce = |e: candle_core::Error| Error::Failed(format!("CompenNet++ training: {e}"));
    let n = data.captures.dim(0).map_err(ce)?;
    let (_, _, hn, wn) = data.targets.dims4().map_err(ce)?;
    let (batch, iters, lr_step) = settings.resolved();
    let batch = batch.min(n);
    if n == 0 {
        return Err(Error::Input(
            "CompenNet++ training needs at least one training pair".into(),
        ));
    }
    let device = data.captures.device().clone();
    let model = CompenNetPP::with_width(
        init,
        (wn, hn),
        settings.variant.refine(),
        settings.variant.width(),
        settings.seed,
        &device,
    )
    .map_err(ce)?;
    let photometric_init = match settings.photometric.resolve(settings.variant.width())? {
        Some(weights) => {
            weights.apply(&model.varmap)?;
            weights.source
        }
        None => "kaiming".to_string(),
    };
    let vars = model.varmap.all_vars();
    let mut opt = adam(vars.clone(), settings.learning_rate).map_err(ce)?;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut order: Vec<u32> = (0..n as u32).collect();
    let mut losses = Vec::with_capacity(iters);
    for it in 0..iters {
        if cancel.load(Ordering::Relaxed) {
            return Err(Error::Failed(format!(
                "training cancelled at iteration {it} of {iters}"
            )));
        }
        if it == lr_step {
            opt.set_learning_rate(settings.learning_rate * 0.2);
        }
        // A batch of distinct pairs.
        order.shuffle(&mut rng);
        let idx = Tensor::from_vec(order[..batch].to_vec(), batch, &device).map_err(ce)?;
        let x = data.captures.index_select(&idx, 0).map_err(ce)?;
        let y = data.targets.index_select(&idx, 0).map_err(ce)?;
        let (value, grads) = model
            .gradients(
                &x,
                &y,
                &data.surface,
                settings.weight_decay,
                shards_for(&device, batch),
            )
            .map_err(ce)?;
        check_loss(value, it, &losses)?;
        losses.push(value);
        opt.step(&grads).map_err(ce)?;
        progress(it + 1, iters, value);
    }
    // Collapse check: a model whose outputs no longer depend on the input is useless.
    let probe = data.captures.narrow(0, 0, n.min(4)).map_err(ce)?;
    let out = model.forward(&probe, &data.surface).map_err(ce)?;
    let spread: f64 = out
        .flatten_from(1)
        .and_then(|t| t.var_keepdim(1))
        .and_then(|t| t.mean_all())
        .and_then(|t| t.to_dtype(DType::F64))
        .and_then(|t| t.to_scalar())
        .map_err(ce)?;
    if spread.is_nan() || spread <= 1e-6 {
        return Err(Error::Failed(format!(
            "training collapsed: the output is flat (variance {spread:e}); no model produced"
        )));
    }
    let seconds = start.elapsed().as_secs_f64();
    Ok((
        model,
        Report {
            iterations: iters,
            batch,
            lr_step,
            ms_per_sample: 1e3 * seconds / (iters * batch) as f64,
            losses,
            photometric_init,
            seconds,
        },
    ))
}

impl CompenNetPP {
    /// Every variable by name (the model directory's tensor names).
    pub fn named_tensors(&self) -> Vec<(String, Tensor)> {
        let data = match self.varmap.data().lock() {
            Ok(d) => d,
            Err(poisoned) => poisoned.into_inner(),
        };
        let mut out: Vec<(String, Tensor)> = data
            .iter()
            .map(|(k, v)| (k.clone(), v.as_tensor().clone()))
            .collect();
        if let Geometry::Fixed(g) = &self.warp {
            out.push((FIXED_GRID.to_string(), g.clone()));
        }
        out.sort_by(|a, b| a.0.cmp(&b.0));
        out
    }

    /// Rebuilds a model of this shape and fills every variable from `get(name, shape)`, which
    /// must return the stored values (it reports missing or mis-shaped tensors itself).
    pub fn restore(
        size: (usize, usize),
        variant: Variant,
        device: &Device,
        mut get: impl FnMut(&str, &[usize]) -> Result<Vec<f32>>,
    ) -> Result<Self> {
        let ce = |e: candle_core::Error| Error::Failed(format!("CompenNet++ model: {e}"));
        let init = if variant.fixed_geometry() {
            let dims = [1, size.1, size.0, 2];
            let g = get(FIXED_GRID, &dims)?;
            GeometryInit::Fixed(Tensor::from_vec(g, dims.to_vec(), device).map_err(ce)?)
        } else {
            GeometryInit::Affine([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        };
        let model = Self::with_width(init, size, variant.refine(), variant.width(), 0, device)
            .map_err(ce)?;
        for (name, t) in model.named_tensors() {
            if !t.is_variable() {
                continue; // constants (the fixed grid) were set above
            }
            let dims = t.dims().to_vec();
            let values = get(&name, &dims)?;
            let value = Tensor::from_vec(values, dims, device).map_err(ce)?;
            candle_core::Var::from_tensor(&t)
                .and_then(|v| v.set(&value))
                .map_err(ce)?;
        }
        Ok(model)
    }
}

/// Tensor name of a fixed geometry's grid in the model directory.
pub const FIXED_GRID: &str = "warp.grid";

/// The playback form of a trained CompenNet++ (DESIGN.md 5.3): the grid baked once, the surface
/// branch run once on the warped surface image and kept as constant bias maps s1..s4; only the
/// backbone runs per frame.
#[derive(Clone, Debug)]
pub struct SimplifiedCompenNet {
    /// (1, H, W, 2) network → camera sampling grid.
    pub grid: Tensor,
    /// Constant maps added at conv1..conv4.
    pub bias: super::compennet::SurfaceFeatures,
    pub backbone: super::compennet::Backbone,
}

impl CompenNetPP {
    /// Bakes the geometry and folds the surface branch for the camera-space surface image
    /// `surface` (1, 3, Hc, Wc), masked as in training.
    pub fn simplify(&self, surface: &Tensor) -> candle_core::Result<SimplifiedCompenNet> {
        let grid = self.warp.grid()?.detach();
        let sw = grid_sample(surface, &grid)?;
        let f = self.compen.surface(&sw)?;
        let bias = super::compennet::SurfaceFeatures {
            s1: f.s1.detach(),
            s2: f.s2.detach(),
            s3: f.s3.detach(),
            s4: f.s4.detach(),
        };
        Ok(SimplifiedCompenNet {
            grid,
            bias,
            backbone: self.compen.backbone.clone(),
        })
    }
}

impl SimplifiedCompenNet {
    /// π† per frame: captures or desired images (B, 3, Hc, Wc) → projector images (B, 3, Hn, Wn).
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let b = x.dim(0)?;
        let (_, h, w, _) = self.grid.dims4()?;
        let g = self.grid.broadcast_as((b, h, w, 2))?.contiguous()?;
        self.backbone.forward(&grid_sample(x, &g)?, &self.bias)
    }
}
