//! The one integration-test binary: each module tests one area, through the library API or by
//! running the real `compend` binary.

#[cfg(feature = "benches")]
mod bench;
mod calibrate;
mod calibrate_window;
mod camera;
mod cli;
mod common;
mod console;
mod dataset;
mod files;
mod fov;
mod gpu;
mod image;
mod layout;
mod linear;
mod media;
mod metrics;
mod nn;
mod patterns;
mod play;
mod probe;
mod rig;
mod service;
mod train;
mod train_cli;
mod window;
