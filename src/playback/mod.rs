//! Live compensation, from a content frame to the projector (docs/architecture.md, "Playback").
//!
//! - [`frame`]: where a content frame goes on its way to the projector (the displayable area,
//!   the model, the canvas) and the CPU reference of that per-frame path, which the GPU pass
//!   ([`crate::gpu::CompensationPass`]) must reproduce.
//!
//! The playback loop that runs this path on the GPU for every frame is the shell's
//! [`crate::player`].

pub mod frame;

pub use frame::{
    ContentFrame, Placement, desired_view, place_on_canvas, reference_frame, reference_network,
};
