//! The optimiser helpers shared by CompenNet++ training (`nn::train`) and CompenNet's
//! photometric pre-training (`nn::pretrain`): Adam with the paper's settings, the L2
//! weight-decay term added to the loss, and the divergence check (docs/architecture.md, "Models").

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::Optimizer;

use crate::error::{Error, Result};

/// Adam with the paper's settings (β 0.9/0.999, ε 1e-8) and learning rate `lr` (per step);
/// weight decay is not applied here but added to the loss ([`l2_penalty`]).
pub(crate) fn adam(vars: Vec<Var>, lr: f64) -> candle_core::Result<candle_nn::AdamW> {
    candle_nn::AdamW::new(
        vars,
        candle_nn::ParamsAdamW {
            lr,
            weight_decay: 0.0,
            ..Default::default()
        },
    )
}

/// Σw² over `vars` (the L2 weight-decay term before its factor wd/2), an f32 scalar on `device`.
pub(crate) fn l2_penalty(vars: &[Var], device: &Device) -> candle_core::Result<Tensor> {
    vars.iter()
        .map(|v| v.as_tensor().sqr().and_then(|t| t.sum_all()))
        .try_fold(Tensor::zeros((), DType::F32, device)?, |acc, t| {
            t.and_then(|t| acc + t)
        })
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
