//! The colour solve of the `linear` rung: per-pixel normal equations of the inverse model
//! (camera linear light → projector linear light), solved in closed form with a ridge pull towards
//! one global model.
//!
//! Inputs are warped captures and projector images on the same lattice (network pixels, or the
//! model's finer lattice); residuals are in linear projector light.

use rayon::prelude::*;

use super::curve::{CURVE_SAMPLES, CURVE_SWEEPS, fit_curves};
use super::model::{Coefficients, Curves};
use crate::raster::{CamImage, Camera, NetImage, Network};
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
        .0
        .max(grid.size().1)
        .div_ceil(CURVE_SAMPLES)
        .max(1);
    let curves = fit_curves(captures, targets, grid, start, ridge, stride, CURVE_SWEEPS);
    let warped: Vec<NetImage> = captures
        .par_iter()
        .map(|c| crate::sample::grid_sample(c, grid))
        .collect();
    let (coeffs, loss) = solve_colour(&warped, targets, &curves, ridge);
    (curves, coeffs, loss)
}

/// Normal equations of one pixel: features a = [f_c(w), 1], targets y = f_p(x).
#[derive(Clone, Copy, Default)]
pub(super) struct Normal {
    ata: [[f64; 4]; 4],
    aty: [[f64; 3]; 4],
}

impl Normal {
    #[inline]
    pub(super) fn add(&mut self, a: &[f32; 4], y: &[f32; 3]) {
        for (i, &ai) in a.iter().enumerate() {
            for (j, &aj) in a.iter().enumerate().skip(i) {
                self.ata[i][j] += (ai * aj) as f64;
            }
            for (c, &yc) in y.iter().enumerate() {
                self.aty[i][c] += (ai * yc) as f64;
            }
        }
    }
    pub(super) fn merge(&mut self, o: &Normal) {
        for i in 0..4 {
            for j in 0..4 {
                self.ata[i][j] += o.ata[i][j];
            }
            for c in 0..3 {
                self.aty[i][c] += o.aty[i][c];
            }
        }
    }
    /// Solves (AᵀA + λI)β = Aᵀy + λβ₀ for β (4×3); returns coefficients as [M row-major, b].
    pub(super) fn solve(&self, lambda: f64, prior: &[f32; 12]) -> [f32; 12] {
        let mut m = nalgebra::Matrix4::<f64>::zeros();
        for i in 0..4 {
            for j in 0..4 {
                m[(i, j)] = if j >= i {
                    self.ata[i][j]
                } else {
                    self.ata[j][i]
                };
            }
            m[(i, i)] += lambda;
        }
        // Prior β₀ in the same 4×3 layout: rows = features (3 colours, 1), columns = outputs.
        let mut rhs = nalgebra::Matrix4x3::<f64>::zeros();
        for i in 0..4 {
            for c in 0..3 {
                let p = if i < 3 {
                    prior[c * 3 + i]
                } else {
                    prior[9 + c]
                };
                rhs[(i, c)] = self.aty[i][c] + lambda * p as f64;
            }
        }
        let Some(beta) = m.cholesky().map(|ch| ch.solve(&rhs)) else {
            return *prior;
        };
        let mut out = [0f32; 12];
        for c in 0..3 {
            for i in 0..3 {
                out[c * 3 + i] = beta[(i, c)] as f32;
            }
            out[9 + c] = beta[(3, c)] as f32;
        }
        out
    }
}

#[inline]
pub(super) fn features(curves: &Curves, w: &[f32]) -> [f32; 4] {
    [
        curves.camera_linear(0, w[0]),
        curves.camera_linear(1, w[1]),
        curves.camera_linear(2, w[2]),
        1.0,
    ]
}

#[inline]
pub(super) fn targets_linear(curves: &Curves, x: &[f32]) -> [f32; 3] {
    [
        curves.projector_linear(0, x[0]),
        curves.projector_linear(1, x[1]),
        curves.projector_linear(2, x[2]),
    ]
}

/// Solves the per-pixel coefficients; returns them and the mean squared residual (linear light).
fn solve_colour(
    warped: &[NetImage],
    targets: &[NetImage],
    curves: &Curves,
    ridge: f32,
) -> (Coefficients, f64) {
    let (w, h) = targets[0].size();
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
    let sse: f64 = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let k = &coeffs.data[p];
            let mut s = 0f64;
            for (wi, ti) in warped.iter().zip(targets) {
                let a = features(curves, &wi.data()[p * 3..p * 3 + 3]);
                let y = targets_linear(curves, &ti.data()[p * 3..p * 3 + 3]);
                for c in 0..3 {
                    let r = k[c * 3] * a[0] + k[c * 3 + 1] * a[1] + k[c * 3 + 2] * a[2] + k[9 + c]
                        - y[c];
                    s += (r * r) as f64;
                }
            }
            s
        })
        .sum();
    (coeffs, sse / (n * w * h * 3) as f64)
}

pub(super) const IDENTITY: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];

/// The global (one model for all pixels) solution of accumulated normal equations.
pub(super) fn global_solution(global: &Normal, values: usize) -> [f32; 12] {
    global.solve(1e-6 * values as f64, &IDENTITY)
}
