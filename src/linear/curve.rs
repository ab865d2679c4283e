//! The response-curve search of the `linear` rung: golden-section searches over the camera
//! and projector exponents, scored by how well a per-pixel forward model (projector linear light
//! → camera linear light) predicts the captures in camera-encoded values.
//!
//! Spaces: warped captures and projector images on one network-space lattice (network pixels,
//! subsampled); the residual is in camera-encoded values \[0,1\].

use rayon::prelude::*;

use super::model::Curves;
use super::normal::{IDENTITY, PowTable};
use super::stack::{Captures, Stack};
use crate::raster::{Camera, ImageSize, Network};
use crate::sample::Grid;

/// Weighted normal equations of one pixel for the forward model, one set per camera channel:
/// features `[f_p(x), 1]` (projector linear light), target `f_c(w)_c` (camera linear light).
#[derive(Clone, Copy, Default)]
struct ForwardNormal {
    ata: [[[f64; 4]; 4]; 3],
    aty: [[f64; 4]; 3],
}

impl ForwardNormal {
    #[inline]
    fn add(&mut self, f: &[f32; 4], a: &[f32; 3], wt: &[f32; 3]) {
        for c in 0..3 {
            let w = wt[c] as f64;
            if w == 0.0 {
                continue;
            }
            for i in 0..4 {
                let fi = f[i] as f64 * w;
                for (j, &fj) in f.iter().enumerate().skip(i) {
                    self.ata[c][i][j] += fi * fj as f64;
                }
                self.aty[c][i] += fi * a[c] as f64;
            }
        }
    }
    fn merge(&mut self, o: &ForwardNormal) {
        for c in 0..3 {
            for i in 0..4 {
                for j in 0..4 {
                    self.ata[c][i][j] += o.ata[c][i][j];
                }
                self.aty[c][i] += o.aty[c][i];
            }
        }
    }
    /// Per channel, solves (AᵀWA + λI)β = AᵀWa + λβ₀; returns the forward model as
    /// `[F (3×3 row-major: camera channel × projector channel), g (3)]`.
    fn solve(&self, lambda: f64, prior: &[f32; 12]) -> Option<[f32; 12]> {
        let mut out = [0f32; 12];
        for c in 0..3 {
            let mut m = nalgebra::Matrix4::<f64>::zeros();
            let mut r = nalgebra::Vector4::<f64>::zeros();
            for i in 0..4 {
                for j in 0..4 {
                    m[(i, j)] = if j >= i {
                        self.ata[c][i][j]
                    } else {
                        self.ata[c][j][i]
                    };
                }
                m[(i, i)] += lambda;
                let p = if i < 3 {
                    prior[c * 3 + i]
                } else {
                    prior[9 + c]
                };
                r[i] = self.aty[c][i] + lambda * p as f64;
            }
            let beta = m.cholesky()?.solve(&r);
            for i in 0..3 {
                out[c * 3 + i] = beta[i] as f32;
            }
            out[9 + c] = beta[3] as f32;
        }
        Some(out)
    }
}

/// Weight of a camera value in the forward fit: the squared slope of the camera encoding at the
/// captured value (so residuals count as they do in the sRGB-encoded metrics), zero where the
/// camera clipped.
#[inline]
fn encoding_weight(enc: f32, gamma: f32) -> f32 {
    if enc >= 0.995 {
        return 0.0;
    }
    let e = enc.max(0.04);
    let s = e.powf(1.0 - gamma) / gamma;
    s * s
}

/// The final curve search samples about this many network pixels along the longer side. The
/// curves are four global numbers: measured on three scenes' calibrations (curved seed 1,
/// dark-texture 5, step 7; 96 pairs, closed loop with `sim score`), 32 instead of 64 moved the
/// result by −0.005, +0.08 and 0.00 dB and cut the search from 2.7–3.6 s to 0.7–1.0 s.
pub(super) const CURVE_SAMPLES: usize = 32;

/// At most this many coordinate sweeps of the curve search (it stops earlier when a sweep
/// improves the cost by less than 1e-4 relative).
pub(super) const CURVE_SWEEPS: usize = 12;

/// Golden-section search for the minimum of `f` on `[lo, hi]` with `iters` shrinking steps;
/// returns the better of the last two probes and its value.
fn golden_min(mut lo: f32, mut hi: f32, iters: usize, mut f: impl FnMut(f32) -> f64) -> (f32, f64) {
    let phi = 0.618_034_f32;
    let (mut a, mut b) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
    let (mut fa, mut fb) = (f(a), f(b));
    for _ in 0..iters {
        if fa < fb {
            hi = b;
            b = a;
            fb = fa;
            a = hi - phi * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + phi * (hi - lo);
            fb = f(b);
        }
    }
    if fa < fb { (a, fa) } else { (b, fb) }
}

/// Fits the response curves by golden-section search on the residual of the forward model
/// ([`forward_residual`]: projector light predicting the captures, in camera-encoded values).
///
/// Parametrisation: one camera exponent `γc` shared by the channels, and per channel the ratio
/// `γp/γc`. A per-channel tone curve only fixes that ratio well (`v^γp` seen through `(·)^(1/γc)`);
/// the absolute exponent shows only through offsets and channel mixing, so searching the six
/// exponents one at a time crawls along a narrow valley. In these coordinates the valley is
/// axis-aligned. The inverse model's own residual (on the projector-input scale) is not used:
/// near black it amplifies camera noise, and minimising it drives both exponents towards 1,
/// which cost 1–1.5 dB closed loop on the rig.
pub(super) fn fit_curves(
    caps: &impl Captures,
    shown: &Stack,
    grid: &Grid<Network, Camera>,
    start: Curves,
    ridge: f32,
    stride: usize,
    sweeps: usize,
) -> Curves {
    // The curves are global: every `stride`-th pixel in each direction is plenty.
    let ImageSize {
        width: w,
        height: h,
    } = grid.size();
    let (sw, sh) = (w.div_ceil(stride), h.div_ceil(stride));
    // The captures warped by the grid and the projector images on its lattice, at those pixels.
    let n = caps.images();
    let resize = shown.resize_to(grid.size());
    // Sample k is pair k % n at picked pixel k / n.
    let (warped, shown): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..sw * sh * n)
        .into_par_iter()
        .map(|k| {
            let (q, i) = (k / n, k % n);
            let (x, y) = ((q % sw) * stride, (q / sw) * stride);
            let [gx, gy] = grid.get(x, y);
            let warped = caps.sample(&caps.taps(gx, gy), i);
            (warped, shown.resampled(&resize, y * w + x, i))
        })
        .unzip();
    let mut samples = ForwardSamples {
        n,
        warped,
        shown,
        camera: std::array::from_fn(|_| (f32::NAN, Vec::new(), Vec::new())),
        projector: std::array::from_fn(|_| (f32::NAN, Vec::new())),
    };
    let mut cost = |cv: &Curves| {
        samples.derive(cv);
        forward_residual(&samples, cv, ridge)
    };
    // Coordinates: [γc, γp0/γc, γp1/γc, γp2/γc] (the camera exponent of channel 0 speaks for all).
    let to_curves = |q: &[f32; 4]| Curves {
        camera_gamma: [q[0]; 3],
        projector_gamma: [q[0] * q[1], q[0] * q[2], q[0] * q[3]],
    };
    let g0 = start.camera_gamma[0];
    let mut best = [
        g0,
        start.projector_gamma[0] / g0,
        start.projector_gamma[1] / g0,
        start.projector_gamma[2] / g0,
    ];
    let mut best_cost = cost(&to_curves(&best));
    // Coordinate descent with golden-section line searches, plus a pattern move along each
    // sweep's total step: the cost valley runs diagonally (the tone curves fix the ratio
    // γp/γc well but the absolute exponent weakly), and plain sweeps crawl along it. Measured on
    // the rig's curved scene (seed 1): two plain sweeps from γ = 2.2 stopped at γc = 1.7 with a
    // cost 3 % above the true curves' (truth 2.2); converging closes 0.95 dB of closed-loop gap.
    let mut swept = 0;
    for _sweep in 0..sweeps {
        swept += 1;
        let before = best;
        let start_cost = best_cost;
        for which in 0..4 {
            let centre = best[which];
            let (lo, hi) = ((centre * 0.6).max(0.3), (centre * 1.6).min(4.0));
            let (v, f) = golden_min(lo, hi, 12, |v| {
                let mut q = best;
                q[which] = v;
                cost(&to_curves(&q))
            });
            if f < best_cost {
                best[which] = v;
                best_cost = f;
            }
        }
        let step: [f32; 4] = std::array::from_fn(|i| best[i] - before[i]);
        if step.iter().any(|d| *d != 0.0) {
            let along = |t: f32| -> [f32; 4] {
                std::array::from_fn(|i| (best[i] + t * step[i]).clamp(0.3, 4.0))
            };
            let (t, f) = golden_min(0.0, 4.0, 12, |t| cost(&to_curves(&along(t))));
            if f < best_cost {
                best = along(t);
                best_cost = f;
            }
        }
        if start_cost - best_cost <= 1e-4 * start_cost {
            break;
        }
    }
    tracing::debug!(
        "curves: {swept} sweeps on {sw}x{sh} pixels of {n} pairs, cost {best_cost:.4e}"
    );
    to_curves(&best)
}

/// The curve search's samples, pixel-major (`[p * n + i]` for pixel `p` of pair `i`), and what
/// the last cost evaluation derived from them through the curves, per channel: the camera
/// features and weights (which depend on that channel's camera exponent only) and the projector
/// light (its projector exponent only). A line search moves one coordinate at a time, and most
/// of them leave the camera exponent alone, so most evaluations re-derive one channel of the
/// projector light and nothing else. The values are those a direct evaluation computes.
struct ForwardSamples {
    /// Pairs.
    n: usize,
    /// Warped captures (camera-encoded values).
    warped: Vec<[f32; 3]>,
    /// Projector images (projector-encoded values).
    shown: Vec<[f32; 3]>,
    /// Per channel: the camera exponent, `f_c(w)` and [`encoding_weight`] of every sample
    /// (NaN and empty until derived).
    camera: [(f32, Vec<f32>, Vec<f32>); 3],
    /// Per channel: the projector exponent and `f_p(x)` of every sample (NaN and empty until
    /// derived).
    projector: [(f32, Vec<f32>); 3],
}

impl ForwardSamples {
    /// Derives what `curves` changed since the last call.
    fn derive(&mut self, curves: &Curves) {
        for c in 0..3 {
            let gamma = curves.camera_gamma[c];
            // A NaN exponent (never derived) differs from every exponent.
            if self.camera[c].0 != gamma {
                let (features, weights) = self
                    .warped
                    .par_iter()
                    .map(|x| (curves.camera_linear(c, x[c]), encoding_weight(x[c], gamma)))
                    .unzip();
                self.camera[c] = (gamma, features, weights);
            }
            let gamma = curves.projector_gamma[c];
            if self.projector[c].0 != gamma {
                let light = self
                    .shown
                    .par_iter()
                    .map(|x| curves.projector_linear(c, x[c]))
                    .collect();
                self.projector[c] = (gamma, light);
            }
        }
    }
}

/// Fits the weighted forward model per pixel and returns the summed squared residual of its
/// prediction of the captures in camera-encoded values (clipped captures left out), from the
/// samples as derived for `curves` ([`ForwardSamples::derive`]).
fn forward_residual(samples: &ForwardSamples, curves: &Curves, ridge: f32) -> f64 {
    let n = samples.n;
    let pixels = samples.warped.len() / n.max(1);
    let [c0, c1, c2] = &samples.camera;
    let [p0, p1, p2] = &samples.projector;
    // Sample k: features [f_p(x), 1], camera light f_c(w), weights.
    let light = |k: usize| [p0.1[k], p1.1[k], p2.1[k]];
    let normals: Vec<ForwardNormal> = (0..pixels)
        .into_par_iter()
        .map(|p| {
            let mut ne = ForwardNormal::default();
            for k in p * n..(p + 1) * n {
                let y = light(k);
                let f = [y[0], y[1], y[2], 1.0];
                let a = [c0.1[k], c1.1[k], c2.1[k]];
                let wt = [c0.2[k], c1.2[k], c2.2[k]];
                ne.add(&f, &a, &wt);
            }
            ne
        })
        .collect();
    let mut global = ForwardNormal::default();
    for ne in &normals {
        global.merge(ne);
    }
    let total_w: f64 = (0..3).map(|c| global.ata[c][3][3]).sum::<f64>() / 3.0;
    let mean_w = total_w / (n * pixels) as f64;
    let global_fwd = global.solve(1e-6 * total_w, &IDENTITY).unwrap_or(IDENTITY);
    let lambda = ridge as f64 * mean_w;
    // The camera's encoding l^(1/γc), by table: evaluated for every sample at every probe.
    let encode = PowTable::new(curves.camera_gamma.map(|g| 1.0 / g));
    // Per pixel in parallel, then summed in pixel order: the same cost every run (a parallel
    // sum's order follows the threads' timing, and the search compares costs).
    let per_pixel: Vec<f64> = (0..pixels)
        .into_par_iter()
        .map(|p| {
            let k = normals[p].solve(lambda, &global_fwd).unwrap_or(global_fwd);
            let mut s = 0f64;
            for j in p * n..(p + 1) * n {
                let x = &samples.warped[j];
                let y = light(j);
                for c in 0..3 {
                    if x[c] >= 0.995 {
                        continue;
                    }
                    let l = k[c * 3] * y[0] + k[c * 3 + 1] * y[1] + k[c * 3 + 2] * y[2] + k[9 + c];
                    let e = encode.eval(c, l.clamp(0.0, 1.0)) - x[c];
                    s += (e * e) as f64;
                }
            }
            s
        })
        .collect();
    per_pixel.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::NetImage;
    use rand::{RngExt, SeedableRng};

    impl ForwardSamples {
        /// Samples of whole images (warped captures, projector images on one lattice).
        fn of(warped: &[NetImage], shown: &[NetImage]) -> Self {
            let n = warped.len();
            let pixels = shown[0].width() * shown[0].height();
            let interleave = |images: &[NetImage]| -> Vec<[f32; 3]> {
                (0..pixels * n)
                    .map(|k| {
                        images[k % n].get((k / n) % shown[0].width(), (k / n) / shown[0].width())
                    })
                    .collect()
            };
            Self {
                n,
                warped: interleave(warped),
                shown: interleave(shown),
                camera: std::array::from_fn(|_| (f32::NAN, Vec::new(), Vec::new())),
                projector: std::array::from_fn(|_| (f32::NAN, Vec::new())),
            }
        }
    }

    /// What a line search re-derives: after curves that change one exponent, the samples hold
    /// what a fresh derivation for those curves holds, and the residual is the same to the bit.
    #[test]
    fn samples_derived_step_by_step_equal_samples_derived_afresh() {
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(11);
        let mut image =
            || NetImage::from_fn(7, 5, |_, _| [0, 1, 2].map(|_| rng.random_range(0.0..1.0)));
        let warped: Vec<NetImage> = (0..6).map(|_| image()).collect();
        let shown: Vec<NetImage> = (0..6).map(|_| image()).collect();
        let steps = [
            Curves {
                camera_gamma: [2.2; 3],
                projector_gamma: [2.2, 2.0, 2.4],
            },
            // One projector exponent, then the camera's, then all of them.
            Curves {
                camera_gamma: [2.2; 3],
                projector_gamma: [2.2, 1.7, 2.4],
            },
            Curves {
                camera_gamma: [1.9; 3],
                projector_gamma: [2.2, 1.7, 2.4],
            },
            Curves {
                camera_gamma: [2.5; 3],
                projector_gamma: [2.6, 2.1, 1.8],
            },
        ];
        let mut cached = ForwardSamples::of(&warped, &shown);
        for curves in &steps {
            cached.derive(curves);
            let mut fresh = ForwardSamples::of(&warped, &shown);
            fresh.derive(curves);
            for c in 0..3 {
                assert_eq!(cached.camera[c].1, fresh.camera[c].1, "camera light {c}");
                assert_eq!(cached.camera[c].2, fresh.camera[c].2, "weights {c}");
                assert_eq!(
                    cached.projector[c].1, fresh.projector[c].1,
                    "projector light {c}"
                );
            }
            let (a, b) = (
                forward_residual(&cached, curves, 0.01),
                forward_residual(&fresh, curves, 0.01),
            );
            assert!(a.is_finite() && a > 0.0);
            assert_eq!(a.to_bits(), b.to_bits(), "{a} against {b}");
        }
        // The residual does depend on the curves (the cache is not stale).
        let mut first = ForwardSamples::of(&warped, &shown);
        first.derive(&steps[0]);
        assert_ne!(
            forward_residual(&first, &steps[0], 0.01),
            forward_residual(&cached, &steps[3], 0.01)
        );
    }
}
