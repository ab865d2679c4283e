//! compend: projector-camera compensation (geometry and colour) after CompenNet++.
//!
//! The module map; docs/architecture.md explains it ("Layers" for the rules, "Data flow" for how
//! a capture becomes a model and a video frame becomes a projector frame).
//!
//! **Pure core** (no device I/O; file I/O only where a file format is the job):
//! - foundations: [`error`], [`files`] (atomic writes), [`raster`] (typed images, `ImageSize`),
//!   [`pngio`], [`resize`], [`sample`], [`filter`], [`metrics`], [`morph`], [`device`] (the
//!   display and camera traits);
//! - geometry and data: [`fov`], [`warp`], [`patterns`], [`slgrid`], [`dataset`];
//! - models: [`linear`], [`nn`] (CompenNet++ in candle), [`model`] (a loaded model; the rung
//!   names, `model::Method`; `model::store`, the model directory), [`fit`] (training any rung;
//!   `auto`'s climb), [`failure`] (how a trained model failed: diverged, collapsed, worse than
//!   uncompensated);
//! - [`playback`]`::frame`: the per-frame path and its CPU reference;
//! - [`calibrate`]: from a projector and a camera (the device traits) to a verified model:
//!   latency, synchronised captures with resume, training, verification; run folders;
//! - [`rig`]: the virtual rig, a simulated projector, surface and camera.
//!
//! **Shell** (devices): [`gpu`] (the compensation pass), [`window`] (the projector window),
//! [`media`] (GStreamer: its errors in words, media outputs), [`source`] (video sources), [`camera`] (the V4L2 camera), [`playback`]`::player` (the one
//! playback loop), [`config`] (the service's TOML configuration), [`service`] (`compend serve`:
//! the engine, the control socket, systemd notification); the binary's commands live in
//! `src/main.rs` and `src/cli/`.
//!
//! `tests/layout/` checks that core files never import shell files, that this map, the module
//! table of docs/architecture.md and the `pub mod` lines below agree, and that no two files
//! import each other in a circle.

pub mod calibrate;
pub mod camera;
pub mod config;
pub mod dataset;
pub mod device;
pub mod error;
pub mod failure;
pub mod files;
pub mod filter;
pub mod fit;
pub mod fov;
pub mod gpu;
pub mod linear;
pub mod media;
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
pub mod service;
pub mod slgrid;
pub mod source;
pub mod warp;
pub mod window;

pub use error::{Error, Result};
