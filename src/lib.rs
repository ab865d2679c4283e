//! compend: projector-camera compensation (geometry and colour) after CompenNet++.
//!
//! The module map; docs/architecture.md explains it ("Layers" for the rules, "Data flow" for how
//! a capture becomes a model and a video frame becomes a projector frame).
//!
//! **Pure core** (no device I/O; file I/O only where a file format is the job), in layers, each
//! using only its own and those above it in this list:
//! - foundations: [`size`] (`ImageSize`, the one size type), [`error`], [`files`] (atomic
//!   writes), [`background`] (work behind the show, at a lower priority), [`raster`] (typed
//!   images), [`pngio`], [`resize`], [`sample`], [`filter`], [`metrics`], [`morph`], [`device`]
//!   (the display and camera traits), [`tensors`] (named f32 arrays and their safetensors
//!   encoding);
//! - geometry and data: [`fov`], [`warp`], [`patterns`], [`slgrid`], [`dataset`] (the
//!   CompenNet++ layout and the capture manifest);
//! - models: [`linear`], [`joint`] (a set of projectors compensated together, from each
//!   one's `linear` model), [`failure`] (how a trained model failed: diverged, collapsed, worse
//!   than uncompensated), [`nn`] (CompenNet++ in candle), [`method`] (the rung names),
//!   [`record`] (what `model.json` records of a calibration and a training), [`model`] (a loaded
//!   model; `model::store`, the model directory), [`fit`] (training any rung; `auto`'s climb and
//!   its evidence in words; the frame budget);
//! - [`playback`]: the per-frame path and its CPU reference;
//! - [`calibrate`]: from a projector and a camera (the device traits) to a verified model:
//!   latency, synchronised captures with resume, training, verification; run folders;
//! - [`rig`]: the virtual rig, a simulated projector, surface and camera.
//!
//! **Shell** (devices): [`gpu`] (the compensation pass), [`window`] (the projector window),
//! [`media`] (GStreamer: its errors in words, a playing source's handle), [`source`] (video
//! sources), [`camera`] (the V4L2 camera), [`player`] (the one playback loop), [`output`]
//! (compensated frames to other software), [`config`] (the service's TOML configuration),
//! [`rigs`] (a rig opened from `[rig]`, and a calibration's options, for `calibrate` and
//! `serve` alike), [`service`] (`compend serve`: the engine, the control socket, systemd notification); the
//! binary's commands live in `src/main.rs` and `src/cli/`.
//!
//! `tests/layout/` checks that core files never import shell files, that this map, the module
//! table of docs/architecture.md and the `pub mod` lines below agree, that no two files import
//! each other in a circle, and that no module uses one of a higher layer or closes a circle of
//! modules.

pub mod background;
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
pub mod joint;
pub mod linear;
pub mod media;
pub mod method;
pub mod metrics;
pub mod model;
pub mod morph;
pub mod nn;
pub mod output;
pub mod patterns;
pub mod playback;
pub mod player;
pub mod pngio;
pub mod raster;
pub mod record;
pub mod resize;
pub mod rig;
pub mod rigs;
pub mod sample;
pub mod service;
pub mod size;
pub mod slgrid;
pub mod source;
pub mod tensors;
pub mod warp;
pub mod window;

pub use error::{Error, Result};
