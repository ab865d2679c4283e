//! The climb's frame budget measured where the model is to play ([`crate::fit::LivePass`]): a
//! residual rung's whole pass (its `linear` part, the correction network and their sum, onto
//! the projector frame), built from a synthetic model of the shapes training would give it and
//! timed on the playback GPU, against the display's refresh.

use super::GpuContext;
use super::bench::{synthetic_residual_model, time_pass};
use super::pass::CompensationPass;
use crate::error::{Error, Result};
use crate::fit::{LiveCost, LivePass, PassShape};
use crate::fov::DisplayRange;
use crate::nn::compennetpp::Variant;
use crate::source::Pattern;

/// Untimed frames before the timed ones: the first compiles the shaders (on software drivers)
/// and a GPU idling at low clocks needs a few to wake.
const WARMUP: usize = 3;
/// Timed frames; the median is the figure.
const FRAMES: usize = 9;

/// Times passes on `ctx`, the GPU the model is to play on, for a display refreshing at
/// `refresh_hz`.
#[derive(Clone, Debug)]
pub struct GpuLivePass {
    ctx: GpuContext,
    refresh_hz: f64,
}

impl GpuLivePass {
    /// `refresh_hz` must be a positive number.
    pub fn new(ctx: GpuContext, refresh_hz: f64) -> Result<Self> {
        if !(refresh_hz.is_finite() && refresh_hz > 0.0) {
            return Err(Error::Input(format!(
                "refresh rate {refresh_hz} Hz: expected a positive number"
            )));
        }
        Ok(Self { ctx, refresh_hz })
    }
}

impl LivePass for GpuLivePass {
    fn cost(&self, shape: &PassShape) -> Result<LiveCost> {
        let variant = Variant::from_method(shape.method.name())
            .filter(|v| v.residual())
            .ok_or_else(|| {
                Error::Input(format!(
                    "{}: only the residual rungs' live pass is timed before a climb",
                    shape.method
                ))
            })?;
        let model =
            synthetic_residual_model(shape.camera, shape.lattice, shape.network, variant, 0)?;
        let ctx = &self.ctx;
        let mut pass =
            CompensationPass::for_display(ctx, &model, shape.projector, DisplayRange::FULL)?;
        // Content at the projector's resolution: the upload is not part of the pass's time.
        let content = crate::source::pattern::render(Pattern::Bars, shape.projector, 0)?;
        let t = time_pass(ctx, &mut pass, &content, WARMUP, FRAMES)?;
        Ok(LiveCost::new(
            shape.method,
            ctx.describe(),
            shape.projector,
            t.best_ms(),
            self.refresh_hz,
        ))
    }
}
