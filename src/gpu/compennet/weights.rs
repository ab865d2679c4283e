//! A backbone layer's weights taken out of candle and repacked for the convolution kernels of
//! `shaders/conv.wgsl`.

use candle_core::Tensor;

use super::{LANES, WIDE_BLOCK};
use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// A tensor's values as f32, row-major.
pub(super) fn values(t: &Tensor, what: &str) -> Result<Vec<f32>> {
    t.to_dtype(candle_core::DType::F32)
        .and_then(|t| t.flatten_all())
        .and_then(|t| t.to_vec1::<f32>())
        .map_err(|e| Error::Candle(e.context(format!("CompenNet on the GPU: reading {what}"))))
}

/// A layer's weights as plain data: `w[co][ci][ky][kx]` (conv layout) whatever the kind.
pub(super) struct Weights {
    pub cin: usize,
    pub cout: usize,
    /// Kernel side, pixels.
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
    pub transposed: bool,
    /// (cout, cin, k, k).
    pub w: Vec<f32>,
    pub bias: Vec<f32>,
}

/// (out, in, k) of a square 4-D weight tensor, in its own dimension order.
fn square_kernel(weight: &Tensor, name: &str) -> Result<(usize, usize, usize)> {
    let (a, b, k, k2) = weight
        .dims4()
        .map_err(|e| Error::Shape(format!("CompenNet layer {name}: {e}")))?;
    if k != k2 {
        return Err(Error::Shape(format!(
            "CompenNet layer {name}: non-square kernel {k}x{k2}"
        )));
    }
    Ok((a, b, k))
}

fn bias_or_zero(bias: Option<&Tensor>, cout: usize, name: &str) -> Result<Vec<f32>> {
    match bias {
        Some(b) => values(b, name),
        None => Ok(vec![0.0; cout]),
    }
}

impl Weights {
    pub fn conv(c: &candle_nn::Conv2d, name: &str) -> Result<Self> {
        let cfg = c.config();
        if cfg.dilation != 1 || cfg.groups != 1 {
            return Err(Error::Input(format!(
                "CompenNet layer {name}: dilation {} / groups {} (the GPU pass has 1 / 1)",
                cfg.dilation, cfg.groups
            )));
        }
        let (cout, cin, k) = square_kernel(c.weight(), name)?;
        Ok(Self {
            cin,
            cout,
            k,
            stride: cfg.stride,
            pad: cfg.padding,
            transposed: false,
            w: values(c.weight(), name)?,
            bias: bias_or_zero(c.bias(), cout, name)?,
        })
    }

    pub fn tconv(c: &candle_nn::ConvTranspose2d, name: &str) -> Result<Self> {
        let cfg = c.config();
        if cfg.dilation != 1 || cfg.output_padding != 0 {
            return Err(Error::Input(format!(
                "CompenNet layer {name}: dilation {} / output padding {} (the GPU pass has 1 / 0)",
                cfg.dilation, cfg.output_padding
            )));
        }
        // candle's transposed-convolution weight is (cin, cout, k, k).
        let (cin, cout, k) = square_kernel(c.weight(), name)?;
        let src = values(c.weight(), name)?;
        let mut w = vec![0.0; src.len()];
        for ci in 0..cin {
            for co in 0..cout {
                for t in 0..k * k {
                    w[(co * cin + ci) * k * k + t] = src[(ci * cout + co) * k * k + t];
                }
            }
        }
        Ok(Self {
            cin,
            cout,
            k,
            stride: cfg.stride,
            pad: cfg.padding,
            transposed: true,
            w,
            bias: bias_or_zero(c.bias(), cout, name)?,
        })
    }

    /// Output size (width, height) in pixels for an input of `(w, h)` pixels.
    pub fn out_size(
        &self,
        ImageSize {
            width: w,
            height: h,
        }: ImageSize,
        name: &str,
    ) -> Result<ImageSize> {
        let (k, s, p) = (self.k, self.stride.max(1), self.pad);
        let size = |n: usize| -> Option<usize> {
            if self.transposed {
                ((n.checked_sub(1)?) * s + k).checked_sub(2 * p)
            } else {
                Some((n + 2 * p).checked_sub(k)? / s + 1)
            }
        };
        match (size(w), size(h)) {
            (Some(a), Some(b)) if a > 0 && b > 0 => Ok(ImageSize::new(a, b)),
            _ => Err(Error::Shape(format!(
                "CompenNet layer {name}: no output for a {w}x{h} input"
            ))),
        }
    }

    /// vec4 accumulators per invocation for this layer.
    pub fn block(&self) -> usize {
        if self.cout >= LANES * WIDE_BLOCK {
            WIDE_BLOCK
        } else {
            1
        }
    }

    /// Padded output channels: a multiple of 4 · [`Self::block`].
    pub fn cout_padded(&self) -> usize {
        let n = LANES * self.block();
        self.cout.div_ceil(n) * n
    }

    /// Weights as `[ci][ky][kx][co]`, co padded to [`Self::cout_padded`]; bias padded likewise.
    pub fn packed(&self) -> (Vec<f32>, Vec<f32>) {
        let cp = self.cout_padded();
        let kk = self.k * self.k;
        let mut w = vec![0.0; self.cin * kk * cp];
        for co in 0..self.cout {
            for ci in 0..self.cin {
                for t in 0..kk {
                    w[(ci * kk + t) * cp + co] = self.w[(co * self.cin + ci) * kk + t];
                }
            }
        }
        let mut b = vec![0.0; cp];
        b[..self.cout].copy_from_slice(&self.bias);
        (w, b)
    }
}
