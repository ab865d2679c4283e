//! Convolution constructors that own their initialisation (docs/architecture.md, "Models"), and
//! [`SeededInit`], the variable store that draws those initialisations from a seeded stream.
//! Weight names come from the VarBuilder path: `<prefix>.weight`, `<prefix>.bias`.
//!
//! Each layer group's `new(vb, …)` states how its variables start, as the hint it passes with
//! each variable: biases zero, CompenNet's weights Kaiming normal, the refinement CNN's and the
//! TPS parameters normal with σ 1e-4, WarpingNet's affine the constant it is then set to. Built on
//! a plain [`VarMap`] these starts come from candle's random generator, which cannot be seeded;
//! built on a [`SeededInit`] they are drawn from one ChaCha8 stream, so training runs are
//! reproducible.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};

use candle_core::{DType, Device, Result, Shape, Tensor, bail};
use candle_nn::init::{FanInOut, NonLinearity, NormalOrUniform};
use candle_nn::var_builder::SimpleBackend;
use candle_nn::{
    Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig, Init, VarBuilder, VarMap,
};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// How a layer's weights start.
#[derive(Clone, Copy, Debug)]
pub enum WeightInit {
    /// Kaiming normal (fan-in, ReLU gain): the CompenNet convolutions. σ = √(2 / fan_in) with
    /// fan_in = dim(1)·k·k (PyTorch's convention, also for transposed convolutions).
    KaimingNormal,
    /// Normal with the given standard deviation: the refinement CNN (σ = 1e-4), so it starts
    /// as (almost) the identity.
    Normal(f64),
}

impl WeightInit {
    /// The hint passed with the weight to the variable store.
    fn init(self) -> Init {
        match self {
            WeightInit::KaimingNormal => candle_nn::init::DEFAULT_KAIMING_NORMAL,
            WeightInit::Normal(stdev) => Init::Randn { mean: 0.0, stdev },
        }
    }
}

/// A k×k convolution `cin → cout` with bias; biases start at zero.
pub fn conv(
    vb: VarBuilder,
    cin: usize,
    cout: usize,
    k: usize,
    stride: usize,
    padding: usize,
    init: WeightInit,
) -> Result<Conv2d> {
    let weight = vb.get_with_hints((cout, cin, k, k), "weight", init.init())?;
    let bias = vb.get_with_hints(cout, "bias", candle_nn::init::ZERO)?;
    let cfg = Conv2dConfig {
        padding,
        stride,
        ..Default::default()
    };
    Ok(Conv2d::new(weight, Some(bias), cfg))
}

/// A k×k transposed convolution `cin → cout` with stride k (exact up-sampling by k), with bias;
/// biases start at zero.
pub fn tconv(
    vb: VarBuilder,
    cin: usize,
    cout: usize,
    k: usize,
    init: WeightInit,
) -> Result<ConvTranspose2d> {
    let weight = vb.get_with_hints((cin, cout, k, k), "weight", init.init())?;
    let bias = vb.get_with_hints(cout, "bias", candle_nn::init::ZERO)?;
    let cfg = ConvTranspose2dConfig {
        stride: k,
        ..Default::default()
    };
    Ok(ConvTranspose2d::new(weight, Some(bias), cfg))
}

/// A normal start still to be drawn: its mean and standard deviation (in the variable's units).
#[derive(Clone, Copy, Debug)]
struct Draw {
    mean: f64,
    std: f64,
}

impl Draw {
    /// The random start a constructor's hint `init` asks for on a variable of `dims`; `None` for
    /// a constant start (set when the variable is created, nothing drawn).
    fn of(init: Init, dims: &[usize], name: &str) -> Result<Option<Self>> {
        match init {
            Init::Const(_) => Ok(None),
            Init::Randn { mean, stdev } => Ok(Some(Self { mean, std: stdev })),
            Init::Kaiming {
                dist: NormalOrUniform::Normal,
                fan: FanInOut::FanIn,
                non_linearity: NonLinearity::ReLU,
            } => {
                let fan_in: usize = dims.iter().skip(1).product();
                Ok(Some(Self {
                    mean: 0.0,
                    std: (2.0 / fan_in.max(1) as f64).sqrt(),
                }))
            }
            other => bail!("seeded initialisation of `{name}`: {other:?} is not supported"),
        }
    }
}

/// A variable store (a [`VarMap`] behind a [`VarBuilder`]) whose random starts come from a stream
/// seeded by `seed`. Layers built on [`SeededInit::var_builder`] get their variables at once, a
/// random start as zeros until [`SeededInit::finish`] draws them all: in name order, not in the
/// order the layers were built, so the draw does not depend on construction order or hashing
/// (and the shipped pre-trained weights, `weights/`, were made with this order). Constant starts
/// (biases, WarpingNet's affine) are set when the variable is created and draw nothing.
#[derive(Clone)]
pub struct SeededInit {
    varmap: VarMap,
    /// Variables whose start is still to be drawn, by name; `None` once drawn.
    pending: Arc<Mutex<Option<BTreeMap<String, Draw>>>>,
    seed: u64,
}

fn lock<T>(m: &Mutex<T>) -> Result<MutexGuard<'_, T>> {
    m.lock()
        .map_err(|_| candle_core::Error::Msg("variable store lock poisoned".into()))
}

impl SeededInit {
    /// An empty store whose random starts will be drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            varmap: VarMap::new(),
            pending: Arc::new(Mutex::new(Some(BTreeMap::new()))),
            seed,
        }
    }

    /// A builder whose variables land in this store.
    pub fn var_builder(&self, dtype: DType, device: &Device) -> VarBuilder<'static> {
        VarBuilder::from_backend(Box::new(self.clone()), dtype, device.clone())
    }

    /// Draws every pending random start from one ChaCha8 stream seeded by the seed, variables in
    /// name order, each value from `Normal(mean, σ)` in f64 and stored as f32 (then the
    /// variable's dtype); a σ of 0 gives zeros without drawing. Returns the variables.
    pub fn finish(self) -> Result<VarMap> {
        let Some(pending) = lock(&self.pending)?.take() else {
            bail!("seeded initialisation: the starts were already drawn");
        };
        {
            let data = lock(self.varmap.data())?;
            let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
            for (name, draw) in &pending {
                let Some(var) = data.get(name) else {
                    bail!("seeded initialisation: `{name}` is not in the variable map");
                };
                let dims = var.dims().to_vec();
                let n: usize = dims.iter().product();
                let values: Vec<f32> = if draw.std == 0.0 {
                    vec![0.0; n]
                } else {
                    let normal = Normal::new(draw.mean, draw.std).map_err(|e| {
                        candle_core::Error::Msg(format!(
                            "`{name}`: normal({}, {}): {e}",
                            draw.mean, draw.std
                        ))
                    })?;
                    (0..n).map(|_| normal.sample(&mut rng) as f32).collect()
                };
                let t = Tensor::from_vec(values, dims, var.device())?.to_dtype(var.dtype())?;
                var.set(&t)?;
            }
        }
        Ok(self.varmap)
    }
}

impl SimpleBackend for SeededInit {
    fn get(&self, s: Shape, name: &str, h: Init, dtype: DType, dev: &Device) -> Result<Tensor> {
        let draw = Draw::of(h, s.dims(), name)?;
        let mut pending = lock(&self.pending)?;
        let Some(pending) = pending.as_mut() else {
            bail!("seeded initialisation: `{name}` created after the starts were drawn");
        };
        let start = if draw.is_some() { Init::Const(0.0) } else { h };
        let t = self.varmap.get(s, name, start, dtype, dev)?;
        if let Some(draw) = draw {
            pending.insert(name.to_string(), draw);
        }
        Ok(t)
    }

    fn get_unchecked(&self, name: &str, dtype: DType, dev: &Device) -> Result<Tensor> {
        SimpleBackend::get_unchecked(&self.varmap, name, dtype, dev)
    }

    fn contains_tensor(&self, name: &str) -> bool {
        SimpleBackend::contains_tensor(&self.varmap, name)
    }
}
