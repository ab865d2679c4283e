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

use std::mem::MaybeUninit;

use candle_core::{
    CpuStorage, CustomOp1, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor, bail,
};
use candle_nn::{Conv2d, ConvTranspose2d};
use rayon::prelude::*;

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
    fn im2col<T: Copy + Default + Send + Sync>(
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

fn contiguous<'a, T>(data: &'a [T], layout: &Layout, op: &str) -> Result<&'a [T]> {
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&data[start..end]),
        None => bail!("{op}: the input must be contiguous"),
    }
}

/// A two-input element-wise op's CPU body for f32 or f64 storage: `f32`/`f64` on the contiguous
/// inputs of one type; `op` names the op in the errors.
fn binary_f32_f64(
    op: &str,
    (s1, l1): (&CpuStorage, &Layout),
    (s2, l2): (&CpuStorage, &Layout),
    f32: fn(&[f32], &[f32]) -> Vec<f32>,
    f64: fn(&[f64], &[f64]) -> Vec<f64>,
) -> Result<CpuStorage> {
    Ok(match (s1, s2) {
        (CpuStorage::F32(a), CpuStorage::F32(b)) => {
            CpuStorage::F32(f32(contiguous(a, l1, op)?, contiguous(b, l2, op)?))
        }
        (CpuStorage::F64(a), CpuStorage::F64(b)) => {
            CpuStorage::F64(f64(contiguous(a, l1, op)?, contiguous(b, l2, op)?))
        }
        _ => bail!("{op}: only f32 and f64 tensors of one type are supported"),
    })
}

/// The im2col columns of a tensor as an op without a backward pass: [`MatmulConv`]'s backward
/// pass recomputes them. (B, C, H, W) → (B, C·k·k [+ 1 with `ones`], Ho·Wo); row
/// `c·k·k + kh·k + kw` matches a weight (O, C, k, k) flattened to (O, C·k·k), and the row of
/// ones matches a bias as the weight's last column.
struct Columns {
    geometry: Im2Col,
    ones: bool,
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
struct Col2Im {
    geometry: Im2Col,
    dims: (usize, usize, usize, usize),
    /// Whether the columns carry the bias row of ones (which has no input to go to).
    ones: bool,
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

/// `conv`'s forward pass on `x` (B, Cin, H, W) as im2col + matmul on the CPU (candle's own
/// convolution elsewhere). Groups and dilation other than 1 are refused.
pub fn conv2d(conv: &Conv2d, x: &Tensor) -> Result<Tensor> {
    let cfg = conv.config();
    if cfg.groups != 1 || cfg.dilation != 1 {
        bail!(
            "conv2d: groups {} and dilation {} are not supported (expected 1)",
            cfg.groups,
            cfg.dilation
        );
    }
    if !x.device().is_cpu() {
        return candle_core::Module::forward(conv, x);
    }
    let weight = conv.weight();
    let (co, ci, kh, kw) = weight.dims4()?;
    let (b, c, h, w) = x.dims4()?;
    if c != ci || kh != kw {
        bail!(
            "conv2d: input has {c} channels and the kernel is {co}×{ci}×{kh}×{kw} (square kernels only)"
        );
    }
    let geometry = Im2Col {
        k: kh,
        stride: cfg.stride,
        padding: cfg.padding,
    };
    let (ho, wo) = (geometry.out(h)?, geometry.out(w)?);
    let weight = weight.reshape((co, ci * kh * kw))?;
    // The bias as the weight's last column against im2col's row of ones: added inside the
    // matrix product, and its gradient (the row sums of the output gradient) comes out of the
    // weight gradient's product rather than a separate reduction.
    let (weight, bias) = match conv.bias() {
        Some(b) => (Tensor::cat(&[&weight, &b.reshape((co, 1))?], 1)?, true),
        None => (weight, false),
    };
    x.contiguous()?
        .apply_op2(&weight.contiguous()?, MatmulConv { geometry, bias })?
        .reshape((b, co, ho, wo))
}

/// A convolution as one op: im2col then the matrix product with the weight (O, C·k·k [+ 1 for
/// the bias]), and a backward pass that computes the input and weight gradients directly. The
/// im2col columns (k·k times the input) never become a node of candle's graph, which would
/// otherwise zero-fill and accumulate a gradient of their size in every backward pass.
#[derive(Clone, Copy, Debug)]
struct MatmulConv {
    geometry: Im2Col,
    bias: bool,
}

impl MatmulConv {
    fn fwd<T>(
        &self,
        x: &[T],
        xl: &Layout,
        w: &CpuStorage,
        wl: &Layout,
        wrap: fn(Vec<T>) -> CpuStorage,
        one: T,
    ) -> Result<(CpuStorage, Shape)>
    where
        T: Copy + Default + Send + Sync,
    {
        use candle_core::backend::BackendStorage;
        let g = &self.geometry;
        let (b, c, h, wd) = xl.shape().dims4()?;
        let (co, k) = wl.shape().dims2()?;
        let rows = c * g.k * g.k + usize::from(self.bias);
        if k != rows {
            bail!("conv: weight has {k} columns, the input's columns have {rows} rows");
        }
        let n = g.out(h)? * g.out(wd)?;
        let cols = wrap(g.im2col(
            contiguous(x, xl, "conv")?,
            (b, c, h, wd),
            self.bias.then_some(one),
        )?);
        let y = w.matmul(
            &cols,
            (b, co, n, k),
            &wl.broadcast_as((b, co, k))?,
            &Layout::contiguous((b, k, n)),
        )?;
        Ok((y, Shape::from((b, co, n))))
    }
}

impl CustomOp2 for MatmulConv {
    fn name(&self) -> &'static str {
        "matmul-conv"
    }

    /// x (B, C, H, W), weight (O, C·k·k [+ 1]) → (B, O, Ho·Wo).
    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        match s1 {
            CpuStorage::F32(x) => self.fwd(x, l1, s2, l2, CpuStorage::F32, 1.0),
            CpuStorage::F64(x) => self.fwd(x, l1, s2, l2, CpuStorage::F64, 1.0),
            _ => bail!("conv: only f32 and f64 tensors are supported"),
        }
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (b, c, h, wd) = x.dims4()?;
        let grad = grad.contiguous()?; // (B, O, n)
        // The columns again (one im2col pass) rather than kept from the forward pass.
        let cols = x.apply_op1_no_bwd(&Columns {
            geometry: self.geometry,
            ones: self.bias,
        })?; // (B, K, n)
        let dw = grad.matmul(&cols.transpose(1, 2)?)?.sum(0)?; // (O, K)
        let dcols = w.t()?.broadcast_matmul(&grad)?; // (B, K, n)
        let back = Col2Im {
            geometry: self.geometry,
            dims: (b, c, h, wd),
            ones: self.bias,
        };
        let dx = dcols.apply_op1_no_bwd(&back)?;
        Ok((Some(dx), Some(dw)))
    }
}

/// `tconv`'s forward pass on `x` (B, Cin, H, W) when its stride equals its kernel side k and it
/// has no padding (each input pixel paints its own k×k block): one matmul and a pixel shuffle on
/// the CPU; candle's own transposed convolution otherwise.
pub fn conv_transpose2d(tconv: &ConvTranspose2d, x: &Tensor) -> Result<Tensor> {
    let cfg = tconv.config();
    let weight = tconv.weight();
    let (ci, co, kh, kw) = weight.dims4()?;
    let blockwise = kh == kw
        && cfg.stride == kh
        && cfg.padding == 0
        && cfg.output_padding == 0
        && cfg.dilation == 1;
    if !x.device().is_cpu() || !blockwise {
        return candle_core::Module::forward(tconv, x);
    }
    let (b, c, h, w) = x.dims4()?;
    if c != ci {
        bail!("conv_transpose2d: input has {c} channels, the kernel {ci}×{co}×{kh}×{kw}");
    }
    let k = kh;
    let weight = weight.reshape((ci, co * k * k))?.t()?; // (co·k·k, ci)
    let x = x.reshape((b, ci, h * w))?;
    let z = match tconv.bias() {
        // The bias (one per output channel, so per k·k block of rows) as an extra weight column
        // against a row of ones under the input.
        Some(bias) => {
            let bias = bias
                .reshape((co, 1))?
                .broadcast_as((co, k * k))?
                .contiguous()?
                .reshape((co * k * k, 1))?;
            let weight = Tensor::cat(&[&weight, &bias], 1)?;
            let ones = Tensor::ones((b, 1, h * w), x.dtype(), x.device())?;
            weight.broadcast_matmul(&Tensor::cat(&[&x, &ones], 1)?)?
        }
        None => weight.broadcast_matmul(&x)?,
    }; // (B, co·k·k, H·W)
    z.reshape((b, co, k, k, h, w))?
        .permute((0, 1, 4, 2, 5, 3))?
        .contiguous()?
        .reshape((b, co, h * k, w * k))
}

/// `max(x, 0)` on the CPU in one parallel pass, with a one-pass backward (the gradient where
/// `x ≥ 0`, as candle's `relu`); candle's `relu` elsewhere. candle's own CPU `relu` runs on one
/// thread and its backward takes five passes over the tensor.
pub fn relu(x: &Tensor) -> Result<Tensor> {
    if !x.device().is_cpu() {
        return x.relu();
    }
    x.contiguous()?.apply_op1(Relu)
}

struct Relu;

/// Elements per parallel task of the element-wise ops.
const CHUNK: usize = 1 << 14;

impl CustomOp1 for Relu {
    fn name(&self) -> &'static str {
        "relu-par"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        fn go<T: Copy + PartialOrd + Default + Send + Sync>(x: &[T]) -> Vec<T> {
            let zero = T::default();
            // NaN stays NaN (`max` would hide it from the divergence checks).
            x.par_iter()
                .with_min_len(CHUNK)
                .map(|&v| if v < zero { zero } else { v })
                .collect()
        }
        let out = match storage {
            CpuStorage::F32(d) => CpuStorage::F32(go(contiguous(d, layout, "relu")?)),
            CpuStorage::F64(d) => CpuStorage::F64(go(contiguous(d, layout, "relu")?)),
            _ => bail!("relu: only f32 and f64 tensors are supported"),
        };
        Ok((out, layout.shape().clone()))
    }

    fn bwd(&self, arg: &Tensor, _res: &Tensor, grad_res: &Tensor) -> Result<Option<Tensor>> {
        Ok(Some(
            arg.contiguous()?
                .apply_op2_no_bwd(&grad_res.contiguous()?, &ReluGrad)?,
        ))
    }
}

/// (x, g) → g where x ≥ 0, else 0.
struct ReluGrad;

impl CustomOp2 for ReluGrad {
    fn name(&self) -> &'static str {
        "relu-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        fn go<T: Copy + PartialOrd + Default + Send + Sync>(x: &[T], g: &[T]) -> Vec<T> {
            let zero = T::default();
            x.par_iter()
                .zip(g)
                .with_min_len(CHUNK)
                .map(|(&x, &g)| if x >= zero { g } else { zero })
                .collect()
        }
        if l1.shape() != l2.shape() {
            bail!("relu-grad: shapes {:?} and {:?}", l1.shape(), l2.shape());
        }
        let out = binary_f32_f64("relu-grad", (s1, l1), (s2, l2), go::<f32>, go::<f64>)?;
        Ok((out, l1.shape().clone()))
    }
}

/// `max(a + b, 0)` with `b` of `a`'s shape or broadcast over `a`'s batch (`b` of shape
/// (1, …) against `a` of shape (N, …)): on the CPU one op, one parallel pass forward and one
/// backward, for CompenNet's `relu(conv + surface features)` and `relu(conv + residual)`. As an
/// add and a ReLU these are two graph nodes, each with its own pass, zero-filled gradient and
/// accumulation. The arithmetic is candle's, bit for bit: the gradient passes where `a + b ≥ 0`,
/// and `b`'s gradient sums the batch in order, as candle's `sum_keepdim` does. Elsewhere, or for
/// other shapes, `relu(a.broadcast_add(b))`.
pub fn add_relu(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    let (da, db) = (a.dims(), b.dims());
    let batched = !da.is_empty() && da.len() == db.len() && da[1..] == db[1..] && db[0] == 1;
    if !a.device().is_cpu() || a.dtype() != b.dtype() || !(da == db || batched) {
        return relu(&a.broadcast_add(b)?);
    }
    a.contiguous()?.apply_op2(&b.contiguous()?, AddRelu)
}

struct AddRelu;

/// `out[i] = f([s[i] for s in full], b[i % m])` for slices `full` of one length `n` and `b` of
/// `m` elements (`n` a multiple of `m`): `b` broadcast over the batch, in one parallel pass.
fn map_cycled<T: Copy + Send + Sync, const K: usize>(
    full: [&[T]; K],
    b: &[T],
    f: impl Fn([T; K], T) -> T + Sync,
) -> Vec<T> {
    let (n, m) = (full.first().map_or(0, |s| s.len()), b.len());
    if n == 0 || m == 0 {
        return Vec::new();
    }
    let mut out: Vec<T> = Vec::with_capacity(n);
    out.spare_capacity_mut()[..n]
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(k, dst)| {
            let lo = k * CHUNK;
            // Runs over which `b` is contiguous (from this position to the end of `b` or of
            // the chunk): equal-length slices, so the loop below has no wrap-around to check
            // and vectorises.
            let mut i = 0;
            while i < dst.len() {
                let j = (lo + i) % m;
                let len = (m - j).min(dst.len() - i);
                let d = &mut dst[i..i + len];
                let bs = &b[j..j + len];
                let srcs = full.map(|s| &s[lo + i..lo + i + len]);
                for (t, (d, &y)) in d.iter_mut().zip(bs).enumerate() {
                    d.write(f(srcs.map(|s| s[t]), y));
                }
                i += len;
            }
        });
    // SAFETY: the chunks cover all `n` elements and every element was written above.
    unsafe { out.set_len(n) };
    out
}

/// `max(a + b, 0)`, `b` cycled over `a` (see [`map_cycled`]).
fn add_relu_fwd<T: Copy + PartialOrd + Default + std::ops::Add<Output = T> + Send + Sync>(
    a: &[T],
    b: &[T],
) -> Vec<T> {
    let zero = T::default();
    map_cycled([a], b, |[x], y| {
        let v = x + y;
        // NaN stays NaN, as in `relu`.
        if v < zero { zero } else { v }
    })
}

impl CustomOp2 for AddRelu {
    fn name(&self) -> &'static str {
        "add-relu"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let out = binary_f32_f64(
            "add-relu",
            (s1, l1),
            (s2, l2),
            add_relu_fwd::<f32>,
            add_relu_fwd::<f64>,
        )?;
        Ok((out, l1.shape().clone()))
    }

    fn bwd(
        &self,
        a: &Tensor,
        b: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let ga = a.apply_op3_no_bwd(b, &grad_res.contiguous()?, &AddReluGrad)?;
        let gb = if a.dims() == b.dims() {
            ga.clone()
        } else {
            ga.apply_op1_no_bwd(&BatchSum)?
        };
        Ok((Some(ga), Some(gb)))
    }
}

/// (a, b, g) → g where a + b ≥ 0, else 0 (`b` cycled over `a` as in [`AddRelu`]), in one pass:
/// a + b is recomputed because the output cannot tell a sum of exactly 0, whose gradient
/// passes, from a negative one.
struct AddReluGrad;

impl CustomOp3 for AddReluGrad {
    fn name(&self) -> &'static str {
        "add-relu-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        fn go<T: Copy + PartialOrd + Default + std::ops::Add<Output = T> + Send + Sync>(
            a: &[T],
            b: &[T],
            g: &[T],
        ) -> Vec<T> {
            let zero = T::default();
            map_cycled([a, g], b, |[x, g], y| if x + y >= zero { g } else { zero })
        }
        if l1.shape() != l3.shape() {
            bail!(
                "add-relu-grad: shapes {:?} and {:?}",
                l1.shape(),
                l3.shape()
            );
        }
        let name = "add-relu-grad";
        let out = match (s1, s2, s3) {
            (CpuStorage::F32(a), CpuStorage::F32(b), CpuStorage::F32(g)) => CpuStorage::F32(go(
                contiguous(a, l1, name)?,
                contiguous(b, l2, name)?,
                contiguous(g, l3, name)?,
            )),
            (CpuStorage::F64(a), CpuStorage::F64(b), CpuStorage::F64(g)) => CpuStorage::F64(go(
                contiguous(a, l1, name)?,
                contiguous(b, l2, name)?,
                contiguous(g, l3, name)?,
            )),
            _ => bail!("add-relu-grad: only f32 and f64 tensors of one type are supported"),
        };
        Ok((out, l1.shape().clone()))
    }
}

/// (N, …) → (1, …): the sum over the batch, each element summed from batch 0 up (candle's
/// `sum_keepdim(0)` order, so gradients match it bit for bit).
struct BatchSum;

impl CustomOp1 for BatchSum {
    fn name(&self) -> &'static str {
        "batch-sum"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> Result<(CpuStorage, Shape)> {
        fn go<T: Copy + Default + std::ops::Add<Output = T> + Send + Sync>(
            x: &[T],
            n: usize,
        ) -> Vec<T> {
            let m = x.len() / n.max(1);
            (0..m)
                .into_par_iter()
                .with_min_len(CHUNK)
                .map(|j| (0..n).fold(T::default(), |acc, i| acc + x[i * m + j]))
                .collect()
        }
        let dims = layout.shape().dims();
        let Some(&n) = dims.first() else {
            bail!("batch-sum: expected a batch dimension, got a scalar");
        };
        let mut out_dims = dims.to_vec();
        out_dims[0] = 1;
        let out = match storage {
            CpuStorage::F32(d) => CpuStorage::F32(go(contiguous(d, layout, "batch-sum")?, n)),
            CpuStorage::F64(d) => CpuStorage::F64(go(contiguous(d, layout, "batch-sum")?, n)),
            _ => bail!("batch-sum: only f32 and f64 tensors are supported"),
        };
        Ok((out, Shape::from(out_dims)))
    }
}
