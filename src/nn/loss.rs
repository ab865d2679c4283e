//! Training losses in candle with the conventions of [`crate::metrics`] (DESIGN.md section 6):
//! SSIM with an 11-tap Gaussian window (σ 1.5), replicate padding, C1 = 0.01², C2 = 0.03², per
//! channel, averaged over pixels, channels and images — differentiable, so the training loss
//! `L1 + (1 − SSIM)` optimises exactly what `compend eval` reports.

use candle_core::{Result, Tensor};

use crate::filter::gaussian_kernel;
use crate::metrics::{SSIM_C1, SSIM_C2, SSIM_RADIUS, SSIM_SIGMA};

/// Separable Gaussian blur of (N, C, H, W) with replicate padding.
fn blur(x: &Tensor, kx: &Tensor, ky: &Tensor) -> Result<Tensor> {
    let (n, c, h, w) = x.dims4()?;
    let r = SSIM_RADIUS;
    let flat = x.reshape((n * c, 1, h, w))?;
    let a = flat.pad_with_same(3, r, r)?.conv2d(kx, 0, 1, 1, 1)?;
    let b = a.pad_with_same(2, r, r)?.conv2d(ky, 0, 1, 1, 1)?;
    b.reshape((n, c, h, w))
}

/// Mean SSIM of two (N, C, H, W) tensors.
pub fn ssim(x: &Tensor, y: &Tensor) -> Result<Tensor> {
    let taps: Vec<f32> = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS)
        .into_iter()
        .map(|v| v as f32)
        .collect();
    let k = 2 * SSIM_RADIUS + 1;
    let kx = Tensor::from_vec(taps.clone(), (1, 1, 1, k), x.device())?.to_dtype(x.dtype())?;
    let ky = Tensor::from_vec(taps, (1, 1, k, 1), x.device())?.to_dtype(x.dtype())?;
    let mx = blur(x, &kx, &ky)?;
    let my = blur(y, &kx, &ky)?;
    let sxx = (blur(&x.sqr()?, &kx, &ky)? - mx.sqr()?)?;
    let syy = (blur(&y.sqr()?, &kx, &ky)? - my.sqr()?)?;
    let sxy = (blur(&(x * y)?, &kx, &ky)? - (&mx * &my)?)?;
    let num = ((&mx * &my)?.affine(2.0, SSIM_C1)? * sxy.affine(2.0, SSIM_C2)?)?;
    let den =
        ((mx.sqr()? + my.sqr()?)?.affine(1.0, SSIM_C1)? * (sxx + syy)?.affine(1.0, SSIM_C2)?)?;
    (num / den)?.mean_all()
}

/// The training loss `mean |x − y| + (1 − SSIM(x, y))`.
pub fn l1_ssim(x: &Tensor, y: &Tensor) -> Result<Tensor> {
    let l1 = (x - y)?.abs()?.mean_all()?;
    l1 + ssim(x, y)?.affine(-1.0, 1.0)?
}
