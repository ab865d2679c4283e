//! Neural-network building blocks in candle for the learned models (CompenNet++ family,
//! docs/architecture.md, "Models").
//!
//! Tensors are NCHW, f32 (f64 works too, for gradient checks); images in [0,1] as in the core.
//!
//! Files, each importing only those listed before it: `device` (where training runs: the CPU
//! or a CUDA GPU), `layers` (convolution constructors and the
//! seeded variable store), `conv` (the CPU convolution and ReLU ops), `grid_sample`, `loss`,
//! `optim` (Adam, the L2 term, the divergence check), `warpingnet`, `compennet`, `compennetpp`
//! (the model, its variants and one step's gradients), `pretrain` (CompenNet's photometric
//! pre-initialisation), `train` (the training loop).

pub mod compennet;
pub mod compennetpp;
pub mod conv;
pub mod device;
pub mod grid_sample;
pub mod layers;
pub mod loss;
pub mod optim;
pub mod pretrain;
pub mod train;
pub mod warpingnet;

pub use compennet::CompenNet;
pub use grid_sample::grid_sample;
pub use warpingnet::WarpingNet;

use candle_core::{Device, Result, Tensor};

use crate::raster::{ImageSize, ReadRgb, Rgb, Space};

/// Images of one size as an (N, 3, H, W) f32 tensor on the CPU.
/// Bilinear resize of (B, C, H, W) images to `size` (half-pixel centres, as
/// [`crate::resize::resize_bilinear`]), as two matrix products, so gradients flow through it.
pub fn stretch(x: &Tensor, size: ImageSize) -> Result<Tensor> {
    let (_, _, h, w) = x.dims4()?;
    if (w, h) == (size.width, size.height) {
        return Ok(x.clone());
    }
    let dev = x.device();
    let ah = Tensor::from_vec(
        crate::resize::bilinear_matrix(h, size.height),
        (size.height, h),
        dev,
    )?;
    let awt = Tensor::from_vec(
        crate::resize::bilinear_matrix(w, size.width),
        (size.width, w),
        dev,
    )?
    .t()?
    .contiguous()?;
    // Rows: (B, C, H, W)·(W, W') → (B, C, H, W'); columns: (H', H)·(B, C, H, W') → (B, C, H', W').
    let rows = x.broadcast_matmul(&awt)?;
    ah.broadcast_matmul(&rows)
}

/// Images of one size, however their values are held, as an (N, 3, H, W) f32 tensor.
pub fn images_to_tensor<S: Space, I: ReadRgb<S>>(imgs: &[I]) -> Result<Tensor> {
    let Some(first) = imgs.first() else {
        candle_core::bail!("images_to_tensor: no images");
    };
    let ImageSize {
        width: w,
        height: h,
    } = first.dimensions();
    if let Some(other) = imgs.iter().find(|i| i.dimensions() != first.dimensions()) {
        candle_core::bail!(
            "images_to_tensor: sizes differ, ({w}, {h}) and ({}, {})",
            other.dimensions().width,
            other.dimensions().height
        );
    }
    let data: Vec<f32> = imgs
        .iter()
        .flat_map(|i| (0..w * h * 3).map(|k| i.value(k)))
        .collect();
    Tensor::from_vec(data, (imgs.len(), h, w, 3), &Device::Cpu)?
        .permute((0, 3, 1, 2))?
        .contiguous()
}

/// Image `k` of an (N, 3, H, W) tensor.
pub fn tensor_to_image<S: Space>(t: &Tensor, k: usize) -> Result<Rgb<S>> {
    let (_, _, h, w) = t.dims4()?;
    let data: Vec<f32> = t
        .narrow(0, k, 1)?
        .permute((0, 2, 3, 1))?
        .flatten_all()?
        .to_dtype(candle_core::DType::F32)?
        .to_vec1()?;
    Rgb::from_vec(w, h, data).map_err(|e| candle_core::Error::Msg(e.to_string()))
}
