//! Training losses in candle with the conventions of [`crate::metrics`] (docs/architecture.md,
//! "Models"): SSIM with an 11-tap Gaussian window (σ 1.5), replicate padding, C1 = 0.01²,
//! C2 = 0.03², per channel, averaged over pixels, channels and images — differentiable, so the
//! training loss `L1 + (1 − SSIM)` optimises exactly what `compend eval` reports. Images in [0, 1].

use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, Tensor, WithDType, bail};
use rayon::prelude::*;

use crate::filter::gaussian_kernel;
use crate::metrics::{SSIM_C1, SSIM_C2, SSIM_RADIUS, SSIM_SIGMA};

/// Separable Gaussian blur of (N, C, H, W) with replicate padding (each plane on its own), as
/// a custom op: candle's convolution spends most of its time on 1-channel im2col tiles here, and
/// this blur is five of the loss's passes. Its backward pass is the adjoint (the transposed
/// blur, with the padded border's weight folded back onto the edge pixels).
#[derive(Clone, Debug)]
pub struct GaussianBlur {
    /// 2r + 1 taps, centre in the middle.
    pub taps: Vec<f64>,
    adjoint: bool,
}

impl GaussianBlur {
    /// The SSIM window of [`crate::metrics`]: σ 1.5, radius 5.
    pub fn ssim_window() -> Self {
        Self {
            taps: gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS),
            adjoint: false,
        }
    }

    /// Along rows (x): `dst[x] = Σ_t g_t · src[clamp(x + t − r)]`, or its adjoint. `dst`
    /// arrives zeroed (it accumulates).
    fn along_w<T: WithDType>(&self, src: &[T], dst: &mut [T], h: usize, w: usize) {
        let r = (self.taps.len() / 2) as isize;
        for y in 0..h {
            let s = &src[y * w..][..w];
            let d = &mut dst[y * w..][..w];
            for (t, &g) in self.taps.iter().enumerate() {
                let g = T::from_f64(g);
                let off = t as isize - r;
                // x + off inside 0..w for x in lo..hi
                let lo = (-off).clamp(0, w as isize) as usize;
                let hi = (w as isize - off).clamp(0, w as isize) as usize;
                let hi = hi.max(lo);
                let shift = |x: usize| (x as isize + off) as usize;
                let interior = lo < hi;
                if !self.adjoint {
                    if interior {
                        for (dv, &sv) in d[lo..hi].iter_mut().zip(&s[shift(lo)..shift(hi)]) {
                            *dv += g * sv;
                        }
                    }
                    for dv in &mut d[..lo] {
                        *dv += g * s[0];
                    }
                    for dv in &mut d[hi..] {
                        *dv += g * s[w - 1];
                    }
                } else {
                    if interior {
                        for (dv, &sv) in d[shift(lo)..shift(hi)].iter_mut().zip(&s[lo..hi]) {
                            *dv += g * sv;
                        }
                    }
                    let head = s[..lo].iter().fold(T::zero(), |a, &v| a + v);
                    let tail = s[hi..].iter().fold(T::zero(), |a, &v| a + v);
                    d[0] += g * head;
                    d[w - 1] += g * tail;
                }
            }
        }
    }

    /// Along columns (y): `dst[y] = Σ_t g_t · src[clamp(y + t − r)]` row by row, or its adjoint. `dst`
    /// arrives zeroed (it accumulates).
    fn along_h<T: WithDType>(&self, src: &[T], dst: &mut [T], h: usize, w: usize) {
        let r = (self.taps.len() / 2) as isize;
        for y in 0..h {
            for (t, &g) in self.taps.iter().enumerate() {
                let g = T::from_f64(g);
                let yy = (y as isize + t as isize - r).clamp(0, h as isize - 1) as usize;
                let (from, to) = if self.adjoint { (y, yy) } else { (yy, y) };
                let s = &src[from * w..][..w];
                for (dv, &sv) in dst[to * w..][..w].iter_mut().zip(s) {
                    *dv += g * sv;
                }
            }
        }
    }

    fn run<T: WithDType>(&self, x: &[T], planes: usize, h: usize, w: usize) -> Vec<T> {
        let mut out = vec![T::zero(); planes * h * w];
        out.par_chunks_mut(h * w)
            .zip(x.par_chunks(h * w))
            .for_each(|(dst, src)| {
                let mut tmp = vec![T::zero(); h * w];
                if self.adjoint {
                    self.along_h(src, &mut tmp, h, w);
                    self.along_w(&tmp, dst, h, w);
                } else {
                    self.along_w(src, &mut tmp, h, w);
                    self.along_h(&tmp, dst, h, w);
                }
            });
        out
    }
}

impl CustomOp1 for GaussianBlur {
    fn name(&self) -> &'static str {
        "gaussian-blur"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let (n, c, h, w) = layout.shape().dims4()?;
        if h == 0 || w == 0 || self.taps.len().is_multiple_of(2) {
            bail!("gaussian blur: empty image {h}x{w} or an even tap count");
        }
        let Some((start, end)) = layout.contiguous_offsets() else {
            bail!("gaussian blur: the input must be contiguous");
        };
        let out = match storage {
            CpuStorage::F32(d) => CpuStorage::F32(self.run(&d[start..end], n * c, h, w)),
            CpuStorage::F64(d) => CpuStorage::F64(self.run(&d[start..end], n * c, h, w)),
            _ => bail!("gaussian blur: only f32 and f64 tensors are supported"),
        };
        Ok((out, layout.shape().clone()))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        let adjoint = Self {
            taps: self.taps.clone(),
            adjoint: !self.adjoint,
        };
        Ok(Some(grad_res.contiguous()?.apply_op1(adjoint)?))
    }
}

/// Separable Gaussian blur of (N, C, H, W) with replicate padding: [`GaussianBlur`] on the CPU,
/// candle's convolutions elsewhere.
fn blur(x: &Tensor, kx: &Tensor, ky: &Tensor) -> Result<Tensor> {
    if x.device().is_cpu() {
        return x.contiguous()?.apply_op1(GaussianBlur::ssim_window());
    }
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
