//! The im2col columns of an NCHW tensor (each k×k window of each channel as a row of the output
//! positions) and their adjoint, col2im: the copy behind the matrix-product convolution
//! (`matmul.rs`), as plain functions and as candle ops without a backward pass.

use std::mem::MaybeUninit;

use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape, bail};
use rayon::prelude::*;

use super::storage::contiguous;

/// Geometry of one im2col: input (B, C, H, W), a k×k window, stride, zero padding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Im2Col {
    pub k: usize,
    pub stride: usize,
    pub padding: usize,
}

impl Im2Col {
    /// Output side for an input side `n`.
    pub fn out(&self, n: usize) -> Result<usize> {
        let padded = n + 2 * self.padding;
        if padded < self.k || self.stride == 0 {
            bail!(
                "im2col: input side {n} with padding {} is smaller than the {}×{} window",
                self.padding,
                self.k,
                self.k
            );
        }
        Ok((padded - self.k) / self.stride + 1)
    }

    /// For kernel offset `kk` (row or column within the window), the range of output positions
    /// whose input position `o·stride + kk − padding` lies inside `0..n`.
    fn valid(&self, kk: usize, n: usize, out: usize) -> std::ops::Range<usize> {
        let (s, p) = (self.stride as isize, self.padding as isize);
        let kk = kk as isize;
        // smallest o with o·s + kk − p ≥ 0; largest with o·s + kk − p ≤ n − 1
        let lo = (p - kk).max(0);
        let lo = (lo + s - 1) / s;
        let hi = (n as isize - 1 + p - kk).div_euclid(s) + 1;
        let hi = hi.clamp(0, out as isize);
        (lo.min(hi) as usize)..(hi as usize)
    }

    /// One (image, channel) plane `x` (H×W) into its k·k rows of `cols` (each Ho·Wo long).
    /// Every element of `cols` is written: positions that fall in the padding get `zero`.
    fn plane_to_rows<T: Copy>(
        &self,
        x: &[T],
        h: usize,
        w: usize,
        cols: &mut [MaybeUninit<T>],
        zero: T,
    ) {
        let (ho, wo) = (self.out(h).unwrap_or(0), self.out(w).unwrap_or(0));
        let n = ho * wo;
        for kh in 0..self.k {
            let ys = self.valid(kh, h, ho);
            for kw in 0..self.k {
                let xs = self.valid(kw, w, wo);
                let row = &mut cols[(kh * self.k + kw) * n..][..n];
                for oy in 0..ho {
                    let dst = &mut row[oy * wo..][..wo];
                    if !ys.contains(&oy) {
                        fill(dst, zero);
                        continue;
                    }
                    let iy = oy * self.stride + kh - self.padding;
                    let src = &x[iy * w..][..w];
                    fill(&mut dst[..xs.start], zero);
                    fill(&mut dst[xs.end..], zero);
                    if self.stride == 1 {
                        let ix0 = xs.start + kw - self.padding;
                        let src = &src[ix0..ix0 + xs.len()];
                        for (d, &v) in dst[xs.clone()].iter_mut().zip(src) {
                            d.write(v);
                        }
                    } else {
                        for ox in xs.clone() {
                            dst[ox].write(src[ox * self.stride + kw - self.padding]);
                        }
                    }
                }
            }
        }
    }

    /// The adjoint: k·k rows (each Ho·Wo) summed back into one H×W plane, which arrives zeroed.
    fn rows_to_plane<T: Copy + Default + std::ops::AddAssign>(
        &self,
        cols: &[T],
        h: usize,
        w: usize,
        x: &mut [T],
    ) {
        let (ho, wo) = (self.out(h).unwrap_or(0), self.out(w).unwrap_or(0));
        let n = ho * wo;
        for kh in 0..self.k {
            let ys = self.valid(kh, h, ho);
            for kw in 0..self.k {
                let xs = self.valid(kw, w, wo);
                let row = &cols[(kh * self.k + kw) * n..][..n];
                for oy in ys.clone() {
                    let iy = oy * self.stride + kh - self.padding;
                    let dst = &mut x[iy * w..][..w];
                    let src = &row[oy * wo..][..wo];
                    if self.stride == 1 {
                        // Contiguous on both sides: a slice add the compiler vectorises.
                        let ix0 = xs.start + kw - self.padding;
                        let dst = &mut dst[ix0..ix0 + xs.len()];
                        for (d, &v) in dst.iter_mut().zip(&src[xs.clone()]) {
                            *d += v;
                        }
                    } else {
                        for ox in xs.clone() {
                            dst[ox * self.stride + kw - self.padding] += src[ox];
                        }
                    }
                }
            }
        }
    }

    /// (B, C, H, W) → (B, C·k·k [+ 1], Ho·Wo). With `one`, each image's block ends with a row
    /// of that value: the bias row, so that a weight matrix with the bias as its last column
    /// adds the bias inside the matrix product.
    pub(super) fn im2col<T: Copy + Default + Send + Sync>(
        &self,
        x: &[T],
        dims: (usize, usize, usize, usize),
        one: Option<T>,
    ) -> Result<Vec<T>> {
        let (b, c, h, w) = dims;
        let n = self.out(h)? * self.out(w)?;
        let kk = self.k * self.k;
        let per_image = (c * kk + usize::from(one.is_some())) * n;
        let len = b * per_image;
        if x.len() != b * c * h * w {
            bail!(
                "im2col: {} input values for a {b}×{c}×{h}×{w} tensor",
                x.len()
            );
        }
        if len == 0 || h * w == 0 {
            return Ok(vec![T::default(); len]);
        }
        let mut cols: Vec<T> = Vec::with_capacity(len);
        cols.spare_capacity_mut()[..len]
            .par_chunks_mut(per_image)
            .zip(x.par_chunks(c * h * w))
            .for_each(|(dst, src)| {
                let (planes, ones) = dst.split_at_mut(c * kk * n);
                planes
                    .par_chunks_mut(kk * n)
                    .zip(src.par_chunks(h * w))
                    .for_each(|(d, s)| self.plane_to_rows(s, h, w, d, T::default()));
                if let Some(one) = one {
                    fill(ones, one);
                }
            });
        // SAFETY: all `len` elements were written above: `plane_to_rows` writes every element
        // of each plane's k·k rows (copies inside the image, zeros in the padding), and the
        // ones row (present exactly when `one` is) is filled; the chunks tile `0..len` since
        // `x` holds `b` images of `c` planes.
        unsafe { cols.set_len(len) };
        Ok(cols)
    }

    /// The adjoint of [`Self::im2col`]; a bias row (`ones`), when present, has no input to go to.
    fn col2im<T: Copy + Default + Send + Sync + std::ops::AddAssign>(
        &self,
        cols: &[T],
        dims: (usize, usize, usize, usize),
        ones: bool,
    ) -> Result<Vec<T>> {
        let (b, c, h, w) = dims;
        let n = self.out(h)? * self.out(w)?;
        let kk = self.k * self.k;
        let per_image = (c * kk + usize::from(ones)) * n;
        let mut x = vec![T::default(); b * c * h * w];
        x.par_chunks_mut(c * h * w)
            .zip(cols.par_chunks(per_image))
            .for_each(|(dst, src)| {
                dst.par_chunks_mut(h * w)
                    .zip(src[..c * kk * n].par_chunks(kk * n))
                    .for_each(|(d, s)| self.rows_to_plane(s, h, w, d));
            });
        Ok(x)
    }
}

/// Writes `v` to every element of `s`.
fn fill<T: Copy>(s: &mut [MaybeUninit<T>], v: T) {
    for e in s {
        e.write(v);
    }
}

/// The im2col columns of a tensor as an op without a backward pass (the matrix-product
/// convolution's backward pass recomputes them). (B, C, H, W) → (B, C·k·k [+ 1 with `ones`], Ho·Wo); row
/// `c·k·k + kh·k + kw` matches a weight (O, C, k, k) flattened to (O, C·k·k), and the row of
/// ones matches a bias as the weight's last column.
pub(super) struct Columns {
    pub(super) geometry: Im2Col,
    pub(super) ones: bool,
}

impl CustomOp1 for Columns {
    fn name(&self) -> &'static str {
        "im2col"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = &self.geometry;
        let (b, c, h, w) = layout.shape().dims4()?;
        let rows = c * g.k * g.k + usize::from(self.ones);
        let shape = Shape::from((b, rows, g.out(h)? * g.out(w)?));
        let out = match storage {
            CpuStorage::F32(d) => CpuStorage::F32(g.im2col(
                contiguous(d, layout, "im2col")?,
                (b, c, h, w),
                self.ones.then_some(1.0),
            )?),
            CpuStorage::F64(d) => CpuStorage::F64(g.im2col(
                contiguous(d, layout, "im2col")?,
                (b, c, h, w),
                self.ones.then_some(1.0),
            )?),
            _ => bail!("im2col: only f32 and f64 tensors are supported"),
        };
        Ok((out, shape))
    }
}

/// The adjoint of the im2col columns: (B, C·k·k [+ 1], Ho·Wo) → (B, C, H, W), overlapping
/// windows summed.
pub(super) struct Col2Im {
    pub(super) geometry: Im2Col,
    /// The input's (B, C, H, W).
    pub(super) dims: (usize, usize, usize, usize),
    /// Whether the columns carry the bias row of ones (which has no input to go to).
    pub(super) ones: bool,
}

impl CustomOp1 for Col2Im {
    fn name(&self) -> &'static str {
        "col2im"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = &self.geometry;
        let (b, c, h, w) = self.dims;
        let expected = (
            b,
            c * g.k * g.k + usize::from(self.ones),
            g.out(h)? * g.out(w)?,
        );
        if layout.shape().dims3()? != expected {
            bail!(
                "col2im: gradient shape {:?}, expected {expected:?}",
                layout.shape()
            );
        }
        let out = match storage {
            CpuStorage::F32(d) => {
                CpuStorage::F32(g.col2im(contiguous(d, layout, "col2im")?, self.dims, self.ones)?)
            }
            CpuStorage::F64(d) => {
                CpuStorage::F64(g.col2im(contiguous(d, layout, "col2im")?, self.dims, self.ones)?)
            }
            _ => bail!("col2im: only f32 and f64 tensors are supported"),
        };
        Ok((out, Shape::from((b, c, h, w))))
    }
}
