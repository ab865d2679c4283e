//! Neural-network building blocks in candle for the learned models (CompenNet++ family).
//!
//! Tensors are NCHW, f32 (f64 works too, for gradient checks); images in [0,1] as in the core.

pub mod compennet;
pub mod grid_sample;
pub mod layers;
pub mod loss;
pub mod train;
pub mod warpingnet;

pub use compennet::CompenNet;
pub use grid_sample::grid_sample;
pub use warpingnet::WarpingNet;
