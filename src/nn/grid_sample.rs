//! Differentiable bilinear grid sampling for candle, which has none: the training-time twin of
//! [`crate::sample::grid_sample`] (same conventions: normalised coordinates, align_corners = true,
//! zeros outside).
//!
//! Built from ops that have gradients: the integer corner positions are `floor`ed and detached,
//! the bilinear weights are differentiable functions of the grid, corners outside the image get
//! weight zero, and the four corner values are `gather`ed from the flattened image (whose backward
//! pass scatters the gradient back to the image). Gradients therefore reach both the image and the
//! grid; at integer pixel positions the grid gradient is one-sided (the sampler has a kink there).

use candle_core::{D, DType, Result, Tensor};

/// Samples `input` (N, C, H, W) at `grid` (N, Ho, Wo, 2) holding normalised source positions
/// `[x, y]`; returns (N, C, Ho, Wo).
pub fn grid_sample(input: &Tensor, grid: &Tensor) -> Result<Tensor> {
    let (n, c, h, w) = input.dims4()?;
    let (gn, ho, wo, two) = grid.dims4()?;
    if gn != n || two != 2 {
        candle_core::bail!(
            "grid_sample: grid shape {:?} does not fit input {:?} (expected ({n}, Ho, Wo, 2))",
            grid.dims(),
            input.dims()
        );
    }
    let dtype = input.dtype();
    let grid = grid.to_dtype(dtype)?;
    // Source pixel coordinates: u = (gx + 1)/2 · (W − 1).
    let half_w = (w.max(1) - 1) as f64 / 2.0;
    let half_h = (h.max(1) - 1) as f64 / 2.0;
    let ix = grid
        .narrow(D::Minus1, 0, 1)?
        .squeeze(D::Minus1)?
        .affine(half_w, half_w)?;
    let iy = grid
        .narrow(D::Minus1, 1, 1)?
        .squeeze(D::Minus1)?
        .affine(half_h, half_h)?;
    let x0 = ix.floor()?.detach();
    let y0 = iy.floor()?.detach();
    let fx = (&ix - &x0)?;
    let fy = (&iy - &y0)?;
    let flat = input.flatten_from(2)?.contiguous()?; // (N, C, H·W)
    let mut out: Option<Tensor> = None;
    for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let xc = x0.affine(1.0, dx)?;
        let yc = y0.affine(1.0, dy)?;
        // 1 where the corner lies inside the image, else 0 (no gradient: a step function).
        let inside = xc
            .ge(0.0)?
            .to_dtype(dtype)?
            .mul(&xc.le((w - 1) as f64)?.to_dtype(dtype)?)?
            .mul(&yc.ge(0.0)?.to_dtype(dtype)?)?
            .mul(&yc.le((h - 1) as f64)?.to_dtype(dtype)?)?;
        let wx = if dx == 0.0 {
            fx.affine(-1.0, 1.0)?
        } else {
            fx.clone()
        };
        let wy = if dy == 0.0 {
            fy.affine(-1.0, 1.0)?
        } else {
            fy.clone()
        };
        let weight = wx.mul(&wy)?.mul(&inside)?; // (N, Ho, Wo)
        let index = yc
            .clamp(0.0, (h - 1) as f64)?
            .affine(w as f64, 0.0)?
            .add(&xc.clamp(0.0, (w - 1) as f64)?)?
            .to_dtype(DType::U32)?
            .flatten_from(1)?
            .unsqueeze(1)?
            .broadcast_as((n, c, ho * wo))?
            .contiguous()?;
        let values = flat.gather(&index, 2)?.reshape((n, c, ho, wo))?;
        let term = values.broadcast_mul(&weight.unsqueeze(1)?)?;
        out = Some(match out {
            None => term,
            Some(acc) => (acc + term)?,
        });
    }
    out.ok_or_else(|| candle_core::Error::Msg("grid_sample: no corners".into()))
}
