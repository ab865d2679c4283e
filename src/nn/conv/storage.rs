//! What the CPU ops of `nn::conv` share: the contiguous slice of a tensor's storage, the f32/f64
//! dispatch of two-input element-wise ops, and the size of their parallel tasks.

use candle_core::{CpuStorage, Layout, Result, bail};

/// Elements per parallel task of the element-wise ops.
pub(super) const CHUNK: usize = 1 << 14;

/// The elements of `data` that `layout` covers, which must be contiguous; `op` names the op in
/// the error.
pub(super) fn contiguous<'a, T>(data: &'a [T], layout: &Layout, op: &str) -> Result<&'a [T]> {
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&data[start..end]),
        None => bail!("{op}: the input must be contiguous"),
    }
}

/// A two-input element-wise op's CPU body for f32 or f64 storage: `f32`/`f64` on the contiguous
/// inputs of one type; `op` names the op in the errors.
pub(super) fn binary_f32_f64(
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
