//! The CompenNet++ model (docs/architecture.md, "Models"): WarpingNet (or a fixed grid) then
//! CompenNet, the capture and the surface image warped by the same grid; its variants and their
//! schedules; one training step's loss and gradients (optionally split into shards that run in
//! parallel); restoring from stored tensors; and the simplified playback form. The training loop
//! is `nn::train`.
//!
//! Images are NCHW f32 in [0, 1]: captures and the surface image in camera pixels, projector
//! images in network pixels; grids (1, H, W, 2) hold normalised camera coordinates in [-1, 1].

use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::VarMap;
use serde::{Deserialize, Serialize};

use super::compennet::{Backbone, CompenNet, PAPER_WIDTH, SurfaceFeatures};
use super::grid_sample::grid_sample;
use super::layers::SeededInit;
use super::loss;
use super::optim::l2_penalty;
use super::warpingnet::WarpingNet;
use crate::error::Result;
use crate::raster::ImageSize;
use crate::warp::TPS_PARAMS;

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
    /// The residual rung: the CPU-sized CompenNet on `linear`'s geometry (a fixed grid) learns a
    /// signed correction added to `linear`'s output; its last layer starts at zero, so training
    /// starts from `linear`'s result.
    Res,
    /// The residual rung at full size (the paper's widths, the whole network side), for a GPU:
    /// the same design as [`Variant::Res`].
    ResFull,
}

/// A variant's training schedule (docs/architecture.md, "Models": the schedule table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Schedule {
    /// Training pairs (capture, projector image) the variant is meant to learn from: the
    /// default `--ntrain`.
    pub train_pairs: usize,
    /// Training pairs per optimiser step.
    pub batch: usize,
    /// Optimiser steps.
    pub iterations: usize,
    /// The step (0-based iteration) from which the learning rate is ×0.2.
    pub lr_step: usize,
}

impl Variant {
    pub const ALL: [Variant; 8] = [
        Variant::Full,
        Variant::NoRefine,
        Variant::Fast,
        Variant::Faster,
        Variant::Sl,
        Variant::Cpu,
        Variant::Res,
        Variant::ResFull,
    ];

    pub fn method(self) -> &'static str {
        match self {
            Variant::Full => "compennet++",
            Variant::NoRefine => "compennet++-norefine",
            Variant::Fast => "compennet++-fast",
            Variant::Faster => "compennet++-faster",
            Variant::Sl => "compennet-sl",
            Variant::Cpu => "compennet++-cpu",
            Variant::Res => "compennet++-res",
            Variant::ResFull => "compennet++-res-full",
        }
    }

    /// The base channel width of CompenNet, channels (the paper's: 32).
    pub fn width(self) -> usize {
        match self {
            Variant::Cpu | Variant::Res => PAPER_WIDTH / 2,
            _ => PAPER_WIDTH,
        }
    }

    /// The network side, pixels, is the data root's divided by this.
    pub fn network_divisor(self) -> usize {
        match self {
            Variant::Cpu | Variant::Res => 2,
            _ => 1,
        }
    }

    /// The variant of a `--method` name, if it names one.
    pub fn from_method(m: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.method() == m)
    }

    /// The paper's schedule for this variant; `compennet-sl` uses the `faster` schedule (the
    /// paper's table has no row for it; this keeps it comparable on a CPU).
    pub fn schedule(self) -> Schedule {
        let (train_pairs, batch, iterations, lr_step) = match self {
            Variant::Full | Variant::NoRefine => (500, 48, 1500, 1000),
            Variant::Fast => (48, 24, 1000, 800),
            Variant::Faster | Variant::Sl => (48, 16, 500, 400),
            Variant::Cpu | Variant::Res => (48, 4, 1000, 800),
            // The CPU-sized rung's steps with twice its batch: about 8 000 samples, the paper's
            // `faster` count, which a GPU trains in about a minute (docs/bench/gpu-h100.md).
            Variant::ResFull => (48, 8, 1000, 800),
        };
        Schedule {
            train_pairs,
            batch,
            iterations,
            lr_step,
        }
    }

    pub fn refine(self) -> bool {
        !matches!(
            self,
            Variant::NoRefine | Variant::Sl | Variant::Res | Variant::ResFull
        )
    }

    /// Whether the geometry is a fixed grid (from structured light, or `linear`'s for the
    /// residual rung) rather than learned.
    pub fn fixed_geometry(self) -> bool {
        matches!(self, Variant::Sl | Variant::Res | Variant::ResFull)
    }

    /// Whether the network learns a correction added to `linear`'s output (its last layer
    /// starts at zero, its output is signed) rather than the projector image itself.
    pub fn residual(self) -> bool {
        matches!(self, Variant::Res | Variant::ResFull)
    }
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
    /// WarpingNet with this affine (network → camera normalised coordinates, e.g. from the FOV
    /// bounding box).
    Affine([[f32; 3]; 2]),
    /// WarpingNet starting from a fitted affine + TPS warp (the `linear` rung's geometry: the
    /// same parametrisation), its refinement CNN fresh.
    Warp(crate::warp::Warp),
    /// A fixed grid (1, H, W, 2).
    Fixed(Tensor),
}

/// Tensor name of a fixed geometry's grid in the model directory.
pub const FIXED_GRID: &str = "warp.grid";

/// The trainable model: its variables and the networks built on them.
pub struct CompenNetPP {
    pub varmap: VarMap,
    pub warp: Geometry,
    pub compen: CompenNet,
}

impl CompenNetPP {
    /// A fresh model for a network of `size` (W, H) pixels with geometry `init`, every other
    /// weight drawn from `seed` as its layer's constructor says ([`SeededInit`]).
    pub fn new(
        init: GeometryInit,
        size: ImageSize,
        refine: bool,
        seed: u64,
        device: &Device,
    ) -> candle_core::Result<Self> {
        Self::with_width(init, size, refine, PAPER_WIDTH, seed, device)
    }

    /// [`CompenNetPP::new`] with CompenNet's base channel width `width` (channels).
    pub fn with_width(
        init: GeometryInit,
        size: ImageSize,
        refine: bool,
        width: usize,
        seed: u64,
        device: &Device,
    ) -> candle_core::Result<Self> {
        let seeded = SeededInit::new(seed);
        let vb = seeded.var_builder(DType::F32, device);
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
                if ImageSize::new(w, h) != size {
                    candle_core::bail!("fixed grid is {w}x{h}, the network {size}");
                }
                Geometry::Fixed(grid.to_dtype(DType::F32)?.detach())
            }
        };
        let compen = CompenNet::with_width(vb.pp("compen"), width)?;
        let varmap = seeded.finish()?;
        // A starting TPS replaces the seeded near-identity one.
        if let (Some(tps), Geometry::Learned(w)) = (tps_init, &warp) {
            if tps.len() != 2 * TPS_PARAMS {
                candle_core::bail!(
                    "starting warp has {} TPS parameters, expected {}",
                    tps.len(),
                    2 * TPS_PARAMS
                );
            }
            let value = Tensor::from_vec(tps, (2, TPS_PARAMS), device)?;
            Var::from_tensor(&w.tps)?.set(&value)?;
        }
        Ok(Self {
            varmap,
            warp,
            compen,
        })
    }

    /// Makes this the residual rung's network ([`Variant::residual`]): the backbone outputs a
    /// signed correction, and its last layer (`compen.backbone.conv6`) starts at zero, so the
    /// first output is no correction at all.
    pub fn make_residual(&mut self) -> candle_core::Result<()> {
        self.compen.backbone.residual = true;
        let conv6 = &self.compen.backbone.conv6;
        let w = conv6.weight();
        Var::from_tensor(w)?.set(&w.zeros_like()?)?;
        if let Some(b) = conv6.bias() {
            Var::from_tensor(b)?.set(&b.zeros_like()?)?;
        }
        Ok(())
    }

    /// π†: captures (B, 3, Hc, Wc) and surface (1, 3, Hc, Wc) → projector images (B, 3, Hn, Wn)
    /// (the residual rung: corrections to add to `linear`'s output).
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

    /// One training step's loss and gradients for captures `x` (B, 3, Hc, Wc), targets `y`
    /// (B, 3, Hn, Wn) and the surface image (1, 3, Hc, Wc): the fit `L1 + (1 − SSIM)` over the
    /// batch (its value is returned) plus the L2 term `(wd/2)·Σw²` over every variable. `base`
    /// (B, 3, Hn, Wn), the residual rung's: `linear`'s outputs, to which the network's
    /// corrections are added before the fit.
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
        base: Option<&Tensor>,
        surface: &Tensor,
        weight_decay: f64,
        shards: usize,
    ) -> candle_core::Result<(f64, GradStore)> {
        let vars = self.varmap.all_vars();
        let b = x.dim(0)?;
        let shards = shards.clamp(1, b.max(1));
        let device = x.device().clone();
        let l2 = l2_penalty(&vars, &device)?.affine(0.5 * weight_decay, 0.0)?;
        if shards == 1 {
            let mut out = self.forward(x, surface)?;
            if let Some(b) = base {
                out = with_base(&out, b)?;
            }
            let fit = loss::l1_ssim(&out, y)?;
            let value = to_f64(&fit)?;
            return Ok((value, (&fit + l2)?.backward()?));
        }
        self.sharded_gradients(x, (y, base), surface, l2, &vars, shards)
    }

    /// [`CompenNetPP::gradients`] for `shards` ≥ 2 shards of the batch, `l2` the weighted L2 term.
    fn sharded_gradients(
        &self,
        x: &Tensor,
        (y, base): (&Tensor, Option<&Tensor>),
        surface: &Tensor,
        l2: Tensor,
        vars: &[Var],
        shards: usize,
    ) -> candle_core::Result<(f64, GradStore)> {
        let b = x.dim(0)?;
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
        let features = SurfaceFeatures {
            s1: leaves[0].as_tensor().clone(),
            s2: leaves[1].as_tensor().clone(),
            s3: leaves[2].as_tensor().clone(),
            s4: leaves[3].as_tensor().clone(),
        };
        let g = grid_leaf.as_ref().map_or(&grid, |v| v.as_tensor());
        let (_, h, w, _) = g.dims4()?;
        // Shard k covers samples lo..lo + len; its loss is weighted by len / b.
        let shard = |k: usize| -> candle_core::Result<(f64, GradStore)> {
            let lo = k * b / shards;
            let len = (k + 1) * b / shards - lo;
            let gb = g.broadcast_as((len, h, w, 2))?.contiguous()?;
            let xw = grid_sample(&x.narrow(0, lo, len)?, &gb)?;
            let mut out = self.compen.forward_with(&xw, &features)?;
            if let Some(base) = base {
                out = with_base(&out, &base.narrow(0, lo, len)?)?;
            }
            let share = len as f64 / b as f64;
            let fit = loss::l1_ssim(&out, &y.narrow(0, lo, len)?)?.affine(share, 0.0)?;
            Ok((to_f64(&fit)?, fit.backward()?))
        };
        let parts = run_shards(shards, &shard)?;
        let value = parts.iter().map(|(v, _)| v).sum();
        // Back through the shared part: ∂/∂θ Σ t·∂t = ∂t/∂θ · ∂t for each shared output t.
        let mut through = l2;
        if let Some(leaf) = &grid_leaf
            && let Some(dg) = summed(&parts, leaf.as_tensor())?
        {
            through = (through + (&grid * dg)?.sum_all()?)?;
        }
        for (t, leaf) in shared.iter().zip(&leaves) {
            if let Some(dt) = summed(&parts, leaf.as_tensor())? {
                through = (through + (*t * dt)?.sum_all()?)?;
            }
        }
        let mut grads = through.backward()?;
        for v in vars {
            let v = v.as_tensor();
            if let Some(dv) = summed(&parts, v)? {
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

/// The residual rung's output in training: the corrections `r` (B, 3, h, w) stretched
/// bilinearly over `base` (B, 3, H, W: `linear`'s outputs at the data's network size) and
/// added, so the loss sees what the paper protocol scores.
pub fn with_base(r: &Tensor, base: &Tensor) -> candle_core::Result<Tensor> {
    let (_, _, h, w) = base.dims4()?;
    super::stretch(r, ImageSize::new(w, h))? + base
}

/// A scalar tensor's value as f64.
fn to_f64(t: &Tensor) -> candle_core::Result<f64> {
    t.to_dtype(DType::F64)?.to_scalar::<f64>()
}

/// Σ over the shards' gradient stores `parts` of tensor `t`'s gradient, in shard order; `None`
/// when no shard has one.
fn summed(parts: &[(f64, GradStore)], t: &Tensor) -> candle_core::Result<Option<Tensor>> {
    let mut acc: Option<Tensor> = None;
    for (_, grads) in parts {
        if let Some(gk) = grads.get(t) {
            acc = Some(match acc {
                None => gk.clone(),
                Some(a) => (a + gk)?,
            });
        }
    }
    Ok(acc)
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

    /// Rebuilds a model of this shape (network `size` (W, H) pixels) and fills every variable
    /// from `get(name, shape)`, which must return the stored values (it reports missing or
    /// mis-shaped tensors itself).
    pub fn restore(
        size: ImageSize,
        variant: Variant,
        device: &Device,
        mut get: impl FnMut(&str, &[usize]) -> Result<Vec<f32>>,
    ) -> Result<Self> {
        let init = if variant.fixed_geometry() {
            let dims = [1, size.height, size.width, 2];
            let g = get(FIXED_GRID, &dims)?;
            GeometryInit::Fixed(Tensor::from_vec(g, dims.to_vec(), device)?)
        } else {
            GeometryInit::Affine([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        };
        let mut model = Self::with_width(init, size, variant.refine(), variant.width(), 0, device)?;
        if variant.residual() {
            model.make_residual()?;
        }
        for (name, t) in model.named_tensors() {
            if !t.is_variable() {
                continue; // constants (the fixed grid) were set above
            }
            let dims = t.dims().to_vec();
            let values = get(&name, &dims)?;
            let value = Tensor::from_vec(values, dims, device)?;
            Var::from_tensor(&t)?.set(&value)?;
        }
        Ok(model)
    }
}

/// The playback form of a trained CompenNet++ (docs/architecture.md, "Models"): the grid baked
/// once, the surface branch run once on the warped surface image and kept as constant bias maps
/// s1..s4; only the backbone runs per frame.
#[derive(Clone, Debug)]
pub struct SimplifiedCompenNet {
    /// (1, H, W, 2) network → camera sampling grid.
    pub grid: Tensor,
    /// Constant maps added at conv1..conv4.
    pub bias: SurfaceFeatures,
    pub backbone: Backbone,
}

impl CompenNetPP {
    /// Bakes the geometry and folds the surface branch for the camera-space surface image
    /// `surface` (1, 3, Hc, Wc), masked as in training.
    pub fn simplify(&self, surface: &Tensor) -> candle_core::Result<SimplifiedCompenNet> {
        let grid = self.warp.grid()?.detach();
        let sw = grid_sample(surface, &grid)?;
        let f = self.compen.surface(&sw)?;
        let bias = SurfaceFeatures {
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
