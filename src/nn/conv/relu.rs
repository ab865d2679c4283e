//! The element-wise ops of CompenNet's forward pass on the CPU: a parallel one-pass ReLU and the
//! fused `max(a + b, 0)`, each with a one-pass backward and candle's arithmetic bit for bit.

use candle_core::{
    CpuStorage, CustomOp1, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor, bail,
};
use rayon::prelude::*;

use super::storage::{CHUNK, binary_f32_f64, contiguous};

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
