//! The convolution as one op, im2col (`im2col.rs`) and one batched matrix product with the
//! weight, with its own backward pass; and the stride-k, k×k transposed convolution as a matrix
//! product and a pixel shuffle. NCHW tensors, features in network pixels.

use candle_core::{CpuStorage, CustomOp2, Layout, Result, Shape, Tensor, bail};
use candle_nn::{Conv2d, ConvTranspose2d};

use super::im2col::{Col2Im, Columns, Im2Col};
use super::storage::contiguous;

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
