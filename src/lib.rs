//! compend: projector-camera compensation (geometry and colour) after CompenNet++.
//!
//! The crate is a pure core (image math, geometry, models, the virtual rig) with no device I/O,
//! and a thin shell on top (CLI, and later camera, window, GPU and service). See `DESIGN.md`.

pub mod dataset;
pub mod device;
pub mod error;
pub mod filter;
pub mod fit;
pub mod fov;
pub mod gpu;
pub mod linear;
pub mod metrics;
pub mod model;
pub mod morph;
pub mod nn;
pub mod patterns;
pub mod playback;
pub mod pngio;
pub mod raster;
pub mod resize;
pub mod rig;
pub mod sample;
pub mod slgrid;
pub mod source;
pub mod warp;
pub mod window;

pub use error::{Error, Result};
