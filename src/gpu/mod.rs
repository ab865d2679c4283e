//! The GPU shell: live compensation in wgpu compute passes (DESIGN.md section 1, playback).
//!
//! - [`context`]: instance, adapter, device, queue; "no adapter" is reported, not an error.
//! - [`pass`]: the compensation pass (content frame → projector frame at native resolution),
//!   with its stages in `shaders/*.wgsl`; the model's photometric stage is a [`pass::Photometric`]
//!   variant ([`linear`] for the `linear` rung, [`compennet`] for the CompenNet++ family).
//! - [`bench`]: per-frame GPU time of the pass against a plain texture copy of the same size.
//!
//! Every stage has a CPU reference in the core ([`crate::playback`]), and tests compare them.

pub mod bench;
pub mod compennet;
pub mod context;
mod kernel;
pub mod linear;
pub mod pass;

pub use context::{GpuContext, NoAdapter};
pub use pass::{CompensationPass, FRAME_FORMAT, Photometric};
