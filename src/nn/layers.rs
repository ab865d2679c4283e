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
