//! The GPU shell: live compensation in wgpu compute passes (docs/architecture.md, "Playback").
//!
//! - [`context`]: instance, adapter, device and queue; "no adapter" is an [`crate::Error::Gpu`]
//!   that [`is_no_adapter`] recognises, so callers can skip instead of failing.
//! - [`pass`]: the compensation pass (content frame → projector frame at native resolution),
//!   with its stages in `shaders/*.wgsl`; the model's photometric stage is a [`pass::Photometric`]
//!   variant ([`linear`] for the `linear` rung, [`compennet`] for the CompenNet++ family,
//!   [`residual`] for the residual rungs, which run both and add).
//! - [`joint`]: the joint pass of a set of projectors (each projector's image from one desired
//!   view, compensated for the surface and the others' light).
//! - `bench` (a build with the `benches` feature): per-frame GPU time of the pass against a plain
//!   texture copy of the same size, each stage and each CompenNet layer alone.
//! - [`live`]: a climb rung's pass timed where the model is to play, for `auto`'s frame budget.
//! - [`timing`]: the timer of GPU work (GPU timestamps where the adapter has them), and
//!   [`synthetic`]: models of a rung's shapes to time.
//!
//! Every stage has a CPU reference in the core ([`crate::playback`]), and tests compare them.

#[cfg(feature = "benches")]
pub mod bench;
pub mod compennet;
pub mod context;
pub mod joint;
mod kernel;
pub mod linear;
pub mod live;
pub mod pass;
pub mod residual;
pub mod synthetic;
pub mod timing;

pub use context::{ConvKernels, GpuContext, NoAdapter, is_no_adapter};
pub use pass::{CompensationPass, FRAME_FORMAT, FramePass, PassStage, Photometric};
