//! Convolution constructors with the initialisations of DESIGN.md section 5. Weight names come
//! from the VarBuilder path: `<prefix>.weight`, `<prefix>.bias`.

use candle_core::Result;
use candle_nn::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig, Init, VarBuilder};

/// How a layer's weights start.
#[derive(Clone, Copy, Debug)]
pub enum WeightInit {
    /// Kaiming normal (fan-in, ReLU gain): the CompenNet convolutions.
    KaimingNormal,
    /// Normal with the given standard deviation: the refinement CNN (σ = 1e-4), so it starts
    /// as (almost) the identity.
    Normal(f64),
}

impl WeightInit {
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

/// A k×k transposed convolution `cin → cout` with stride k (exact up-sampling by k), with bias.
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

/// Redraws every variable of `varmap` from a stream seeded by `seed`, so that training runs are
/// reproducible (candle's CPU random generator cannot be seeded). The rules are those the layer
/// constructors state, by variable name: biases zero; `warp.theta` kept (it is set from the FOV);
/// `warp.tps` and `warp.refine.*.weight` normal with σ 1e-4; every other `*.weight` Kaiming normal,
/// σ = √(2 / fan_in) with fan_in = dim(1)·k·k (PyTorch's convention, also for transposed
/// convolutions). Variables are visited in name order, so the draw does not depend on hashing.
pub fn seeded_init(varmap: &candle_nn::VarMap, seed: u64) -> Result<()> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let data = varmap
        .data()
        .lock()
        .map_err(|_| candle_core::Error::Msg("variable map lock poisoned".into()))?;
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(seed);
    for name in names {
        let var = &data[name];
        let dims = var.dims().to_vec();
        let std = if name == "warp.theta" {
            continue;
        } else if name.ends_with(".bias") {
            0.0
        } else if name == "warp.tps" {
            super::warpingnet::TPS_INIT_STD
        } else if name.starts_with("warp.refine.") {
            super::warpingnet::REFINE_INIT_STD
        } else {
            let fan_in: usize = dims.iter().skip(1).product();
            (2.0 / fan_in.max(1) as f64).sqrt()
        };
        let n: usize = dims.iter().product();
        let values: Vec<f32> = if std == 0.0 {
            vec![0.0; n]
        } else {
            let normal = Normal::new(0.0, std)
                .map_err(|e| candle_core::Error::Msg(format!("normal({std}): {e}")))?;
            (0..n).map(|_| normal.sample(&mut rng) as f32).collect()
        };
        let t = candle_core::Tensor::from_vec(values, dims, var.device())?.to_dtype(var.dtype())?;
        var.set(&t)?;
    }
    Ok(())
}
