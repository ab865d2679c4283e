//! The per-pixel normal equations of the `linear` rung's colour model, shared by the colour
//! solve, the response-curve search and the geometry fit: features a = [f_c(w), 1] of a warped
//! capture value w (camera linear light through the fitted curves), targets y = f_p(x) of a
//! projector value x (projector linear light), and the global solution they are pulled towards.

use super::model::Curves;

/// Normal equations of one pixel: features a = [f_c(w), 1], targets y = f_p(x), and the
/// targets' sum of squares, so that a solution's squared residual needs no second pass over the
/// data ([`Normal::sse`]).
#[derive(Clone, Copy, Default)]
pub(super) struct Normal {
    ata: [[f64; 4]; 4],
    aty: [[f64; 3]; 4],
    yty: [f64; 3],
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
        for (c, &yc) in y.iter().enumerate() {
            self.yty[c] += (yc * yc) as f64;
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
        for c in 0..3 {
            self.yty[c] += o.yty[c];
        }
    }

    /// The squared residual Σ‖M a + b − y‖² of coefficients `k` ([M row-major, b]) over the
    /// samples added, from the accumulated sums: Σy² − 2 βᵀ(Aᵀy) + βᵀ(AᵀA)β per output channel
    /// (at least 0; rounding can take a near-perfect fit just below). The sums hold f32
    /// products, so at a good fit this is a few significant digits of the residual, not all.
    pub(super) fn sse(&self, k: &[f32; 12]) -> f64 {
        let ata = |i: usize, j: usize| {
            if j >= i {
                self.ata[i][j]
            } else {
                self.ata[j][i]
            }
        };
        let mut total = 0.0;
        for c in 0..3 {
            let beta = [k[c * 3], k[c * 3 + 1], k[c * 3 + 2], k[9 + c]].map(f64::from);
            let mut quad = 0.0;
            let mut cross = 0.0;
            for i in 0..4 {
                cross += beta[i] * self.aty[i][c];
                for j in 0..4 {
                    quad += beta[i] * ata(i, j) * beta[j];
                }
            }
            // Not `max`, which would turn a diverged fit's NaN into 0.
            let v = self.yty[c] - 2.0 * cross + quad;
            total += if v < 0.0 { 0.0 } else { v };
        }
        total
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
pub(super) fn targets_linear(curves: &Curves, x: &[f32]) -> [f32; 3] {
    [
        curves.projector_linear(0, x[0]),
        curves.projector_linear(1, x[1]),
        curves.projector_linear(2, x[2]),
    ]
}

/// `v^e` per channel for `v` ≥ 0 by table, for the fits' inner loops, where `powf` was a fifth
/// of a fit's time (the fitted model is applied with `powf`). Tabulated on `t = √v`
/// (`v^e = t^(2e)`), which keeps a steep start (e < 1, the camera's encoding) smooth; linear
/// interpolation between 4096 entries is within 3e-4 of `powf` for exponents from 1/4 to 4
/// (the curve search's range and its inverse), far below a camera's 8-bit step. Values above 1
/// (not in 8-bit images) fall back to `powf`.
pub(super) struct PowTable {
    exponent: [f32; 3],
    table: [Vec<f32>; 3],
}

const POW_TABLE_SIZE: usize = 4096;

impl PowTable {
    pub(super) fn new(exponent: [f32; 3]) -> Self {
        Self {
            exponent,
            table: exponent.map(|e| {
                (0..POW_TABLE_SIZE)
                    .map(|i| (i as f32 / (POW_TABLE_SIZE - 1) as f32).powf(2.0 * e))
                    .collect()
            }),
        }
    }

    /// `v.max(0)^e_c`.
    #[inline]
    pub(super) fn eval(&self, c: usize, v: f32) -> f32 {
        if v > 1.0 {
            return v.powf(self.exponent[c]);
        }
        let x = v.max(0.0).sqrt() * (POW_TABLE_SIZE - 1) as f32;
        let i = (x as usize).min(POW_TABLE_SIZE - 2);
        let f = x - i as f32;
        let t = &self.table[c];
        t[i] + f * (t[i + 1] - t[i])
    }

    /// The features `[f_c(w), 1]` of a warped capture value through this table (the
    /// camera's exponents).
    #[inline]
    pub(super) fn features(&self, w: &[f32]) -> [f32; 4] {
        [
            self.eval(0, w[0]),
            self.eval(1, w[1]),
            self.eval(2, w[2]),
            1.0,
        ]
    }

    /// [`targets_linear`] through this table (the projector's exponents).
    #[inline]
    pub(super) fn linear(&self, x: &[f32]) -> [f32; 3] {
        [self.eval(0, x[0]), self.eval(1, x[1]), self.eval(2, x[2])]
    }
}

pub(super) const IDENTITY: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];

/// The global (one model for all pixels) solution of accumulated normal equations.
pub(super) fn global_solution(global: &Normal, values: usize) -> [f32; 12] {
    global.solve(1e-6 * values as f64, &IDENTITY)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table against `powf` over the exponents the fits use: the curves' (0.3–4) and the
    /// camera encoding's inverse (1/4–1/0.3), at and between the entries, near 0 and at 1.
    #[test]
    fn the_power_table_is_within_its_stated_error_of_powf() {
        for e in [0.25f32, 0.3, 0.45, 1.0, 1.8, 2.2, 2.6, 3.3, 4.0] {
            let t = PowTable::new([e; 3]);
            let worst = (0..=20_000)
                .map(|i| i as f32 / 20_000.0)
                .chain([1e-7, 1e-5, 3e-4, 1.0])
                .map(|v| (t.eval(1, v) - v.powf(e)).abs())
                .fold(0f32, f32::max);
            assert!(worst < 3e-4, "exponent {e}: worst error {worst}");
            assert_eq!(t.eval(0, -0.5), 0.0);
            assert_eq!(t.eval(2, 1.5), 1.5f32.powf(e));
        }
    }
    use rand::{RngExt, SeedableRng};

    #[test]
    fn the_squared_residual_from_the_sums_is_the_residual_summed() {
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(3);
        let mut ne = Normal::default();
        let mut samples = Vec::new();
        for _ in 0..96 {
            let a = [
                rng.random_range(0.0..1.0f32),
                rng.random_range(0.0..1.0f32),
                rng.random_range(0.0..1.0f32),
                1.0,
            ];
            // A near-linear response with noise of 1 % of full scale, as a fitted pixel has: the
            // residual at the fit is about a thousandth of Σy², where the sums cancel most.
            let y = [0, 1, 2].map(|c| 0.8 * a[c] + 0.1 + rng.random_range(-0.01..0.01f32));
            ne.add(&a, &y);
            samples.push((a, y));
        }
        let direct = |k: &[f32; 12]| -> f64 {
            samples
                .iter()
                .map(|(a, y)| {
                    (0..3)
                        .map(|c| {
                            let r = k[c * 3] * a[0]
                                + k[c * 3 + 1] * a[1]
                                + k[c * 3 + 2] * a[2]
                                + k[9 + c]
                                - y[c];
                            (r * r) as f64
                        })
                        .sum::<f64>()
                })
                .sum()
        };
        // At the least-squares solution (the residual is smallest, where cancellation is
        // worst) and away from it.
        let fitted = ne.solve(1e-9, &IDENTITY);
        // A diverged fit's residual stays not-a-number: the fit is refused on it.
        assert!(ne.sse(&[f32::NAN; 12]).is_nan());
        assert!(!ne.sse(&[f32::INFINITY; 12]).is_finite());
        for k in [fitted, IDENTITY, [0.5; 12]] {
            let (from_sums, summed) = (ne.sse(&k), direct(&k));
            // The sums hold f32 products, so the difference loses digits: 5e-5 of the residual
            // here. The figure is reported (`final_loss`) and checked for being finite only.
            assert!(
                (from_sums - summed).abs() <= 1e-3 * summed,
                "{from_sums} against {summed} for {k:?}"
            );
        }
    }
}
