//! Live compensation, from a content frame to the projector (docs/architecture.md, "Playback").
//!
//! - [`frame`]: where a content frame goes on its way to the projector (the displayable area,
//!   the model, the canvas) and the CPU reference of that per-frame path, which the GPU pass
//!   ([`crate::gpu::CompensationPass`]) must reproduce.
//! - [`player`]: the one playback loop: a source's frames through the GPU pass to any
//!   [`crate::device::DisplaySink`]-like display (the projector window, the virtual rig, no
//!   display at all), paced at the display's refresh, with the frame accounting.

pub mod frame;
pub mod player;

pub use frame::{
    ContentFrame, Placement, desired_view, place_on_canvas, reference_frame, reference_network,
};
