//! The colour solve of the `linear` rung: per-pixel normal equations of the inverse model
//! (camera linear light → projector linear light), solved in closed form with a ridge pull towards
//! one global model.
//!
//! Inputs are the captures (camera pixels), the projector images (network pixels) and the grid
//! that maps the model's lattice (network pixels, or a finer lattice) to camera positions; each
//! lattice pixel's pairs are sampled in place ([`Frames`], [`Stack`]). Residuals are in linear projector
//! light.

use rayon::prelude::*;

use super::curve::{CURVE_SAMPLES, CURVE_SWEEPS, fit_curves};
use super::model::{Coefficients, Curves};
use super::normal::{Normal, PowTable, global_solution};
use super::stack::{Frames, Stack};
use crate::raster::{CamImage, Camera, ImageSize, NetImage, Network};
use crate::sample::Grid;

/// Curves and per-pixel coefficients at full resolution on all images, for a fixed grid: the
/// model's lattice is the grid's size. The projector images (network size, or already the
/// lattice's) are resampled bilinearly onto the lattice where it differs: the projector shows an
/// image stretched bilinearly over the canvas (half-pixel centres), so that gives, at each
/// lattice pixel, close to the value the projector showed there. Captures are sampled at the
/// grid's positions and images resampled pixel by pixel ([`Frames`], [`Stack`]), never whole.
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
    let (caps, shown) = (Frames::new(captures), Stack::new(targets));
    let curves = fit_curves(&caps, &shown, grid, start, ridge, stride, CURVE_SWEEPS);
    let curves_s = t.elapsed().as_secs_f64();
    let (coeffs, loss) = solve_colour(&caps, &shown, grid, &curves, ridge);
    tracing::debug!(
        "colour on {} pairs at {}: curves {curves_s:.1} s, coefficients {:.1} s",
        captures.len(),
        grid.size(),
        t.elapsed().as_secs_f64() - curves_s
    );
    (curves, coeffs, loss)
}

/// Solves the per-pixel coefficients on the grid's lattice; returns them and the mean squared
/// residual (linear light).
fn solve_colour(
    caps: &Frames,
    shown: &Stack,
    grid: &Grid<Network, Camera>,
    curves: &Curves,
    ridge: f32,
) -> (Coefficients, f64) {
    let ImageSize {
        width: w,
        height: h,
    } = grid.size();
    let n = caps.images();
    let resize = shown.resize_to(grid.size());
    let (camera, projector) = (
        PowTable::new(curves.camera_gamma),
        PowTable::new(curves.projector_gamma),
    );
    let normals: Vec<Normal> = grid
        .data()
        .par_iter()
        .enumerate()
        .map(|(p, &[gx, gy])| {
            let taps = caps.taps(gx, gy);
            let mut ne = Normal::default();
            for i in 0..n {
                let a = camera.features(&caps.sample(&taps, i));
                let y = projector.linear(&shown.resampled(&resize, p, i));
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
    // The squared residual from each pixel's sums: one pass over the data, not two; summed in
    // pixel order, so that a run reports the same loss as the last.
    let sse: Vec<f64> = normals
        .par_iter()
        .zip(&coeffs.data)
        .map(|(ne, k)| ne.sse(k))
        .collect();
    let sse: f64 = sse.iter().sum();
    (coeffs, sse / (n * w * h * 3) as f64)
}
