//! The per-pixel normal equations of the `linear` rung's colour model, shared by the colour
//! solve, the response-curve search and the geometry fit: features a = [f_c(w), 1] of a warped
//! capture value w (camera linear light through the fitted curves), targets y = f_p(x) of a
//! projector value x (projector linear light), and the global solution they are pulled towards.

use super::model::Curves;

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

pub(super) const IDENTITY: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];

/// The global (one model for all pixels) solution of accumulated normal equations.
pub(super) fn global_solution(global: &Normal, values: usize) -> [f32; 12] {
    global.solve(1e-6 * values as f64, &IDENTITY)
}
