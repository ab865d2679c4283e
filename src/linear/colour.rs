//! The colour solve of the `linear` rung: per-pixel normal equations of the inverse model
//! (camera linear light → projector linear light), solved in closed form with a ridge pull towards
//! one global model.
//!
//! Inputs are warped captures and projector images on the same lattice (network pixels, or the
//! model's finer lattice); residuals are in linear projector light.

use rayon::prelude::*;

use super::curve::{CURVE_SAMPLES, CURVE_SWEEPS, fit_curves};
use super::model::{Coefficients, Curves};
use super::normal::{Normal, features, global_solution, targets_linear};
use crate::raster::{CamImage, Camera, ImageSize, NetImage, Network};
use crate::sample::Grid;

/// Curves and per-pixel coefficients at full resolution on all images, for a fixed grid.
pub(super) fn fit_colour(
    captures: &[CamImage],
    targets: &[NetImage],
    grid: &Grid<Network, Camera>,
    start: Curves,
    ridge: f32,
) -> (Curves, Coefficients, f64) {
    let stride = grid
        .size()
        .width
        .max(grid.size().height)
        .div_ceil(CURVE_SAMPLES)
        .max(1);
    let t = std::time::Instant::now();
    let curves = fit_curves(captures, targets, grid, start, ridge, stride, CURVE_SWEEPS);
    let curves_s = t.elapsed().as_secs_f64();
    let warped: Vec<NetImage> = captures
        .par_iter()
        .map(|c| crate::sample::grid_sample(c, grid))
        .collect();
    let (coeffs, loss) = solve_colour(&warped, targets, &curves, ridge);
    tracing::debug!(
        "colour on {} pairs at {}: curves {curves_s:.1} s, coefficients {:.1} s",
        captures.len(),
        grid.size(),
        t.elapsed().as_secs_f64() - curves_s
    );
    (curves, coeffs, loss)
}

/// Solves the per-pixel coefficients; returns them and the mean squared residual (linear light).
fn solve_colour(
    warped: &[NetImage],
    targets: &[NetImage],
    curves: &Curves,
    ridge: f32,
) -> (Coefficients, f64) {
    let ImageSize {
        width: w,
        height: h,
    } = targets[0].size();
    let n = warped.len();
    let normals: Vec<Normal> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let mut ne = Normal::default();
            for (wi, ti) in warped.iter().zip(targets) {
                let a = features(curves, &wi.data()[p * 3..p * 3 + 3]);
                let y = targets_linear(curves, &ti.data()[p * 3..p * 3 + 3]);
                ne.add(&a, &y);
            }
            ne
        })
        .collect();
    let mut global = Normal::default();
    for ne in &normals {
        global.merge(ne);
    }
    let global_beta = global_solution(&global, n * w * h);
    let lambda = ridge as f64;
    let data: Vec<[f32; 12]> = normals
        .par_iter()
        .map(|ne| ne.solve(lambda, &global_beta))
        .collect();
    let coeffs = Coefficients {
        width: w,
        height: h,
        data,
    };
    // The squared residual from each pixel's sums: one pass over the data, not two.
    let sse: f64 = normals
        .par_iter()
        .zip(&coeffs.data)
        .map(|(ne, k)| ne.sse(k))
        .sum();
    (coeffs, sse / (n * w * h * 3) as f64)
}
