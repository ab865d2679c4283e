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
use super::stack::{Captures, Frames, Stack};
use crate::raster::{Camera, ImageSize, NetImage, Network, ReadRgb};
use crate::sample::Grid;

/// Curves and per-pixel coefficients at full resolution on all images, for a fixed grid: the
/// model's lattice is the grid's size. The projector images (network size, or already the
/// lattice's) are resampled bilinearly onto the lattice where it differs: the projector shows an
/// image stretched bilinearly over the canvas (half-pixel centres), so that gives, at each
/// lattice pixel, close to the value the projector showed there. Captures are sampled at the
/// grid's positions and images resampled pixel by pixel ([`Frames`], [`Stack`]), never whole.
pub(super) fn fit_colour<C: ReadRgb<Camera>>(
    captures: &[C],
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
    let (caps, shown) = (Frames::new(captures), Stack::<f32>::new(targets));
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

/// The lattice pixels the ridge prior is estimated on: every `PRIOR_STRIDE`-th along each
/// axis. The prior is one colour model for the whole lattice (4×3 numbers), fitted on the pooled
/// samples; a sixteenth of them is still hundreds of thousands of samples, and pooling all of
/// them meant holding every pixel's normal equations at once (248 bytes a pixel: 119 MB at
/// 800×600, 514 MB at 1920×1080) before any pixel could be solved.
const PRIOR_STRIDE: usize = 4;

/// Solves the per-pixel coefficients on the grid's lattice; returns them and the mean squared
/// residual (linear light). Two passes: the prior on a subsample ([`PRIOR_STRIDE`]), then each
/// pixel's normal equations made, solved and scored where they are, never held all at once.
fn solve_colour<C: Captures>(
    caps: &C,
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
    let positions = grid.data();
    let normal_at = |p: usize| -> Normal {
        let [gx, gy] = positions[p];
        let taps = caps.taps(gx, gy);
        let mut ne = Normal::default();
        for i in 0..n {
            let a = camera.features(&caps.sample(&taps, i));
            let y = projector.linear(&shown.resampled(&resize, p, i));
            ne.add(&a, &y);
        }
        ne
    };
    // The prior: per sampled row in parallel, then the rows merged in order, so that a run
    // gives the same prior as the last.
    let rows: Vec<Normal> = (0..h)
        .into_par_iter()
        .step_by(PRIOR_STRIDE)
        .map(|y| {
            let mut row = Normal::default();
            for x in (0..w).step_by(PRIOR_STRIDE) {
                row.merge(&normal_at(y * w + x));
            }
            row
        })
        .collect();
    let mut global = Normal::default();
    for row in &rows {
        global.merge(row);
    }
    let sampled = h.div_ceil(PRIOR_STRIDE) * w.div_ceil(PRIOR_STRIDE);
    let global_beta = global_solution(&global, n * sampled);
    let lambda = ridge as f64;
    let (data, sse): (Vec<[f32; 12]>, Vec<f64>) = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let ne = normal_at(p);
            let k = ne.solve(lambda, &global_beta);
            (k, ne.sse(&k))
        })
        .unzip();
    // The squared residual from each pixel's sums (one pass over the data, not two), summed in
    // pixel order, so that a run reports the same loss as the last.
    let sse: f64 = sse.iter().sum();
    (
        Coefficients {
            width: w,
            height: h,
            data,
        },
        sse / (n * w * h * 3) as f64,
    )
}
