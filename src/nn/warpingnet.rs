//! WarpingNet (the geometric part `T⁻¹` of CompenNet++, docs/architecture.md, "Models") in
//! candle: the affine θ and the TPS parameters as learnable variables, composed in coordinate
//! space exactly as [`crate::warp`] does on the CPU, plus the optional refinement CNN on the
//! 2-channel grid. Grids hold normalised camera coordinates in [-1, 1] for network pixels.
//!
//! Composition: `g = θ · [t, 1]` with `t` the TPS positions. Sampling the camera-resolution affine
//! grid at `t` (the paper's formulation) gives the same values wherever `t` lies inside [-1, 1];
//! the closed form is exact everywhere and needs no sampling.

use candle_core::{D, DType, Device, Module, Result, Tensor};
use candle_nn::{Conv2d, ConvTranspose2d, VarBuilder};

use super::layers::{WeightInit, conv, tconv};
use crate::raster::ImageSize;
use crate::sample::pixel_to_norm;
use crate::warp::{TPS_PARAMS, TpsBasis};

/// Standard deviation of the refinement CNN's initial weights.
pub const REFINE_INIT_STD: f64 = 1e-4;
/// Standard deviation of the initial TPS parameters (near the identity).
pub const TPS_INIT_STD: f64 = 1e-4;

/// The refinement CNN: a residual correction of the grid, LeakyReLU(0.1) on its output.
#[derive(Clone, Debug)]
pub struct Refine {
    conv1: Conv2d,
    conv2: Conv2d,
    tconv1: ConvTranspose2d,
    tconv2: ConvTranspose2d,
}

impl Refine {
    pub fn new(vb: VarBuilder) -> Result<Self> {
        let k = WeightInit::Normal(REFINE_INIT_STD);
        Ok(Self {
            conv1: conv(vb.pp("conv1"), 2, 32, 3, 2, 1, k)?,
            conv2: conv(vb.pp("conv2"), 32, 64, 3, 2, 1, k)?,
            tconv1: tconv(vb.pp("tconv1"), 64, 32, 2, k)?,
            tconv2: tconv(vb.pp("tconv2"), 32, 2, 2, k)?,
        })
    }
}

impl Module for Refine {
    /// `g` (N, 2, H, W) → correction (N, 2, H, W).
    fn forward(&self, g: &Tensor) -> Result<Tensor> {
        let a = super::conv::relu(&super::conv::conv2d(&self.conv1, g)?)?;
        let a = super::conv::relu(&super::conv::conv2d(&self.conv2, &a)?)?;
        let a = super::conv::relu(&super::conv::conv_transpose2d(&self.tconv1, &a)?)?;
        let a = super::conv::conv_transpose2d(&self.tconv2, &a)?;
        // LeakyReLU(0.1) = max(a, 0.1·a).
        a.maximum(&a.affine(0.1, 0.0)?)
    }
}

/// WarpingNet for a network lattice of `width`×`height` (sides divisible by 4 with refinement).
#[derive(Clone, Debug)]
pub struct WarpingNet {
    /// 2×3 affine, network → camera normalised coordinates.
    pub theta: Tensor,
    /// TPS parameters (2, 38): x axis then y axis, layout of [`crate::warp::Warp::tps`].
    pub tps: Tensor,
    pub refine: Option<Refine>,
    /// TPS basis (H·W, 38) and base positions (H·W, 2), constants.
    basis: Tensor,
    base: Tensor,
    width: usize,
    height: usize,
}

impl WarpingNet {
    /// `init` is the starting affine of a fresh model (e.g. from the FOV bounding box), written
    /// into the `theta` variable; `None` keeps what `vb` holds (loaded weights). The TPS starts
    /// near the identity. Variables: `theta`, `tps`, and `refine.*` when `refine` is true.
    pub fn new(
        vb: VarBuilder,
        init: Option<[[f32; 3]; 2]>,
        ImageSize { width, height }: ImageSize,
        refine: bool,
    ) -> Result<Self> {
        let dev = vb.device().clone();
        let theta = vb.get_with_hints((2, 3), "theta", candle_nn::Init::Const(0.0))?;
        if let Some(init) = init {
            if !theta.is_variable() {
                candle_core::bail!("WarpingNet: an initial affine needs trainable variables");
            }
            let th: Vec<f32> = init.iter().flatten().copied().collect();
            let value = Tensor::from_vec(th, (2, 3), &dev)?.to_dtype(theta.dtype())?;
            candle_core::Var::from_tensor(&theta)?.set(&value)?;
        }
        let tps = vb.get_with_hints(
            (2, TPS_PARAMS),
            "tps",
            candle_nn::Init::Randn {
                mean: 0.0,
                stdev: TPS_INIT_STD,
            },
        )?;
        let refine = if refine {
            Some(Refine::new(vb.pp("refine"))?)
        } else {
            None
        };
        let (basis, base) = basis_tensors(width, height, &dev)?;
        Ok(Self {
            theta,
            tps,
            refine,
            basis,
            base,
            width,
            height,
        })
    }

    /// The sampling grid (1, H, W, 2) from network pixels into the camera image.
    pub fn grid(&self) -> Result<Tensor> {
        let (w, h) = (self.width, self.height);
        // t = base + 2 · basis · tpsᵀ, (H·W, 2)
        let t = (&self.base + self.basis.matmul(&self.tps.t()?)?.affine(2.0, 0.0)?)?;
        // g = [t, 1] · θᵀ, (H·W, 2)
        let ones = Tensor::ones((w * h, 1), t.dtype(), t.device())?;
        let g = Tensor::cat(&[&t, &ones], D::Minus1)?.matmul(&self.theta.t()?)?;
        let g = g.reshape((1, h, w, 2))?;
        match &self.refine {
            None => Ok(g),
            Some(r) => {
                let gc = g.permute((0, 3, 1, 2))?.contiguous()?;
                let refined = (&gc + r.forward(&gc)?)?.clamp(-1.0, 1.0)?;
                refined.permute((0, 2, 3, 1))?.contiguous()
            }
        }
    }
}

/// The TPS basis and the identity positions as constant tensors.
fn basis_tensors(width: usize, height: usize, dev: &Device) -> Result<(Tensor, Tensor)> {
    let basis = TpsBasis::new(width, height);
    let rows: Vec<f32> = basis.rows().iter().flatten().copied().collect();
    let b = Tensor::from_vec(rows, (width * height, TPS_PARAMS), dev)?;
    let mut base = Vec::with_capacity(width * height * 2);
    for y in 0..height {
        for x in 0..width {
            base.push(pixel_to_norm(x as f32, width));
            base.push(pixel_to_norm(y as f32, height));
        }
    }
    let base = Tensor::from_vec(base, (width * height, 2), dev)?;
    Ok((b.to_dtype(DType::F32)?, base))
}
