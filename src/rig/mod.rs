//! The virtual rig: a physically motivated simulator of a projector-camera system that plugs
//! into the device traits ([`crate::device`]), so calibration, training, playback and monitoring
//! run unchanged on it.
//!
//! - [`scene`]: every parameter of a setup as serde structs, and the built-in scenes from easy to
//!   impossible ([`scene::BUILTIN`], [`scene::builtin`]).
//! - [`Simulator`]: a scene prepared once (ray casting per camera pixel, shading, ambient,
//!   vignetting) so that one capture is a gather plus per-pixel maths, noise and quantisation;
//!   deterministic from the seed and the frame index.
//! - [`VirtualRig`]: the simulator as a [`crate::device::DisplaySink`] and
//!   [`crate::device::FrameSource`] with frame delay and drops.
//! - Oracles ([`Simulator::geometry_only`], [`Simulator::oracle`]) and closed-loop scoring
//!   ([`score`]): every method is reported as a gap to the physical ceiling of its scene.
//! - [`export`]: a simulated setup written in the dataset layout (`compend sim export`), with
//!   `rig.json` recording the scene, seed, canvas and displayable area; [`sheet`]: contact
//!   sheets showing what each scene tests (`compend sim sheet`).
//!
//! Spaces: camera pixels for captures and desired images, projector pixels for what is shown;
//! pixel centres at integer coordinates (align-corners convention). Light inside the model is
//! linear; images at the interfaces are encoded values in \[0,1\] like 8-bit PNGs.

pub mod export;
mod geom;
pub mod live;
mod oracle;
mod physics;
pub mod scene;
pub mod score;
pub mod set_score;
pub mod sheet;
mod texture;
pub mod window_camera;

pub use export::{DesiredScaling, ExportOptions, export_setup};
pub use live::{VirtualOutput, VirtualRig};
pub use oracle::OracleOptions;
pub use physics::{Phase, SetSimulator, Simulator};
pub use scene::{BUILTIN, Scene, builtin};
pub use score::{ReferenceScores, closed_loop, reference_scores};
