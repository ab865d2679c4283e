//! compend: projector-camera compensation (geometry and colour) after CompenNet++.
//!
//! The crate is a pure core (image math, geometry, models, the virtual rig) with no device I/O,
//! and a thin shell on top (CLI, and later camera, window, GPU and service). See `DESIGN.md`.

pub mod device;
pub mod error;
pub mod filter;
pub mod metrics;
pub mod pngio;
pub mod raster;
pub mod rig;

pub use error::{Error, Result};
