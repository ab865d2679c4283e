//! The climb's frame budget measured where the model is to play ([`crate::fit::LivePass`]): a
//! rung's whole pass onto the projector frame (for a residual rung its `linear` part, the
//! correction network and their sum), built from a synthetic model of the shapes training
//! would give it and timed on the playback GPU, against the display's refresh.

use super::GpuContext;
use super::pass::CompensationPass;
use super::synthetic::{
    synthetic_compennet_model, synthetic_linear_model, synthetic_residual_model,
};
use super::timing::{Timing, time_work};
use crate::error::{Error, Result};
use crate::fit::{LiveCost, LivePass, PassShape};
use crate::fov::DisplayRange;
use crate::nn::compennetpp::Variant;
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

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
        let model = match Variant::from_method(shape.method.name()) {
            Some(v) if v.residual() => {
                synthetic_residual_model(shape.camera, shape.lattice, shape.network, v, 0)?
            }
            Some(v) => {
                let div = v.network_divisor();
                let net = ImageSize::new(shape.network.width / div, shape.network.height / div);
                synthetic_compennet_model(shape.camera, net, v, 0)?
            }
            None => synthetic_linear_model(shape.camera, shape.lattice, 0),
        };
        let ctx = &self.ctx;
        let mut pass =
            CompensationPass::for_display(ctx, &model, shape.projector, DisplayRange::FULL)?;
        // Content at the projector's resolution: the upload is not part of the pass's time.
        let content = ramp(shape.projector);
        let t = time_pass(ctx, &mut pass, &content, WARMUP, FRAMES)?;
        Ok(crate::fit::budgeted(
            shape.method,
            ctx.describe(),
            shape.projector,
            t.best_ms(),
            self.refresh_hz,
        ))
    }
}

/// The compensation pass on `content` (uploaded once).
pub fn time_pass(
    ctx: &GpuContext,
    pass: &mut CompensationPass,
    content: &ContentFrame,
    warmup: usize,
    iters: usize,
) -> Result<Timing> {
    pass.upload(ctx, content)?;
    let pass = &*pass;
    time_work(ctx, warmup, iters, |enc| pass.encode(enc, None))
}

/// A horizontal gray ramp at `size` (8-bit RGBA): what is timed does not depend on the content.
fn ramp(size: ImageSize) -> ContentFrame {
    let mut rgba = Vec::with_capacity(size.area() * 4);
    for _ in 0..size.height {
        for x in 0..size.width {
            let v = (x * 255 / size.width.max(1)) as u8;
            rgba.extend_from_slice(&[v, v, v, 255]);
        }
    }
    ContentFrame {
        width: size.width,
        height: size.height,
        rgba,
    }
}
