//! Convolutions as matrix products, for training speed on the CPU.
//!
//! candle 0.11's CPU convolution builds its im2col tiles with a scalar, bounds-checked loop and
//! computes the input gradient with a direct transposed convolution (`vec_dot` per output pixel);
//! profiling CompenNet training (`perf`, width 16 at 64²) found under 5 % of the time in the
//! matrix-product kernel. Here a convolution is one op (`MatmulConv`): an im2col copy
//! ([`Im2Col`]) and one batched matrix product with the weight, the bias being the weight's last
//! column against a row of ones; its backward pass computes the weight gradient (bias included)
//! and the input gradient (a matrix product and the col2im scatter-add) directly, so the im2col
//! columns, k·k times the input, never get a gradient of their own in candle's graph. A
//! stride-k, k×k transposed convolution (CompenNet's up-sampling) is a matrix product and a pixel
//! shuffle. [`relu`] is a parallel one-pass ReLU with a one-pass backward. Results equal candle's
//! own `conv2d` / `conv_transpose2d` / `relu` to rounding, gradients included (tested).
//!
//! Tensors are NCHW; images and features in network pixels. Other devices (CUDA) use candle's
//! own convolutions.
//!
//! The ops, one file each: `im2col.rs` (the im2col columns and their adjoint, col2im),
//! `matmul.rs` (the convolution as one im2col + matrix-product op, and the stride-k transposed
//! convolution), `relu.rs` (the parallel ReLU and the fused add + ReLU); `storage.rs` holds what
//! they share (contiguous CPU slices, the f32/f64 dispatch, the parallel task size).

mod im2col;
mod matmul;
mod relu;
mod storage;

pub use im2col::Im2Col;
pub use matmul::{conv_transpose2d, conv2d};
pub use relu::{add_relu, relu};
