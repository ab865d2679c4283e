//! The geometry fit of the `linear` rung: the coarse-to-fine affine + TPS warp ([`fit_warp`]),
//! by damped Gauss–Newton (Levenberg–Marquardt) on its 82 parameters, and the dense residual
//! refinement ([`refine_geometry`]), by Adam on its offsets; both on the fused per-pixel
//! residual ([`geometry_step`]), each pixel's colour coefficients solved in closed form at
//! every step (variable projection, their dependence on the position left out of the
//! Gauss–Newton curvature).
//!
//! Spaces: captures are camera images (camera pixels); targets are network images at each
//! level's size; grids and gradients are in normalised camera coordinates (align-corners,
//! \[-1,1\]) per network pixel. Residuals are in linear projector light.

use rayon::prelude::*;

use super::curve::fit_curves;
use super::model::Curves;
use super::normal::{IDENTITY, Normal, global_solution, targets_linear};
use super::settings::FitSettings;
use super::stack::Stack;
use crate::filter::gaussian_blur;
use crate::raster::{CamImage, Camera, ImageSize, NetImage, Network, Plane, ReadRgb, Rgb};
use crate::resize::resize_area;
use crate::sample::Grid;
use crate::warp::{OffsetField, TpsBasis, Warp};

/// The coarse-to-fine affine + TPS fit that [`fit`] starts with (when
/// `settings.learn_geometry`), the global curves fitted on the way at its first level; appends
/// each step's loss to `history`.
pub(super) fn fit_warp<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    history: &mut Vec<f64>,
    mut progress: impl FnMut(&str, usize, usize),
) -> (Warp, Curves) {
    let mut warp = init;
    let mut curves = Curves::default();
    if settings.learn_geometry {
        let ng = settings.geometry_images.clamp(1, captures.len());
        let total: usize = settings.levels.iter().map(|l| l.1).sum();
        let mut done = 0;
        for (level, &(side, iters, sigma)) in settings.levels.iter().enumerate() {
            let ImageSize {
                width: lw,
                height: lh,
            } = level_size(settings.network_size, side);
            let started = std::time::Instant::now();
            // Blurred a few at a time into the stack, never all beside it.
            let stack: Stack<u16> = Stack::build(ng, captures[0].dimensions(), |i| {
                blur_rgb(&captures[i], sigma)
            });
            let tgts: Vec<NetImage> = targets[..ng]
                .iter()
                .map(|t| resize_area(t, lw, lh))
                .collect();
            let basis = TpsBasis::new(lw, lh);
            let prepared = started.elapsed().as_secs_f64();
            if level == 0 {
                // The curves are global: a coarse fit here, refined once at the end.
                curves = fit_curves(
                    &stack,
                    &Stack::<f32>::new(&tgts),
                    &basis.grid(&warp),
                    curves,
                    settings.ridge,
                    2,
                    2,
                );
            }
            let lut = PowLut::new(curves.camera_gamma);
            let ylin = linear_targets(&tgts, &curves);
            let values = ng * lw * lh;
            let first = geometry_step(
                &stack,
                &ylin,
                &basis.grid(&warp),
                &lut,
                &IDENTITY,
                settings.ridge,
                Subset::ALL,
                false,
            );
            let mut prior = global_solution(&first.global, values);
            // One fixed subset per level, so that the steps' losses compare.
            let subset = Subset::rotating(settings.geometry_stride(lw * lh), 0);
            let pixels = subset.pixels(basis.size());
            let step = |warp: &Warp, prior: &[f32; 12]| {
                geometry_step(
                    &stack,
                    &ylin,
                    &basis.grid(warp),
                    &lut,
                    prior,
                    settings.ridge,
                    subset,
                    true,
                )
            };
            let mut current = step(&warp, &prior);
            prior = global_solution(&current.global, values);
            history.push(current.loss);
            let mut damping = LM_DAMPING;
            let (start, mut steps) = (current.loss, 0);
            for it in 0..iters {
                steps += 1;
                let normal = basis.gauss_newton(&warp, &pixels, &current.curvature, &current.grad);
                let Some(delta) = damped_step(&normal, damping) else {
                    damping *= 10.0;
                    done += 1;
                    progress("geometry", done, total);
                    continue;
                };
                let mut trial = warp.clone();
                let params: Vec<f32> = (warp.to_params().iter().zip(&delta))
                    .map(|(&p, &d)| p + d as f32)
                    .collect();
                trial.set_params(&params);
                let next = step(&trial, &prior);
                done += 1;
                progress("geometry", done, total);
                if next.loss.is_finite() && next.loss < current.loss {
                    let gain = (current.loss - next.loss) / current.loss.max(f64::MIN_POSITIVE);
                    warp = trial;
                    prior = global_solution(&next.global, values);
                    history.push(next.loss);
                    current = next;
                    damping = (damping / 3.0).max(LM_DAMPING * 1e-3);
                    if gain < LM_SETTLED {
                        done += iters - it - 1;
                        progress("geometry", done, total);
                        break;
                    }
                } else {
                    damping *= 4.0;
                }
            }
            tracing::debug!(
                "geometry at {lw}x{lh}: {steps} Gauss-Newton steps, loss {start:.4e} -> {:.4e}, \
                 in {:.2} s ({prepared:.2} s blurring the captures and resampling the targets)",
                current.loss,
                started.elapsed().as_secs_f64()
            );
        }
    }
    (warp, curves)
}

/// The Levenberg–Marquardt damping a level starts with, relative to each parameter's own
/// curvature (Marquardt's scaling: `(H + μ·diag H) δ = −g`).
const LM_DAMPING: f64 = 1e-3;

/// A level is settled when an accepted step lowers its loss by less than this fraction.
const LM_SETTLED: f64 = 1e-4;

/// The damped Gauss–Newton step `δ` solving `(H + μ·(diag H + ε)) δ = −g` (ε a millionth of the
/// largest curvature, for parameters the pixels barely constrain: the TPS's own affine terms
/// repeat θ's); `None` when the system cannot be factorised.
fn damped_step(normal: &crate::warp::WarpNormal, damping: f64) -> Option<Vec<f64>> {
    let n = normal.gradient.len();
    let mut h = nalgebra::DMatrix::from_row_slice(n, n, &normal.hessian);
    let largest = (0..n).map(|i| h[(i, i)]).fold(0.0f64, f64::max);
    if !(largest > 0.0 && largest.is_finite()) {
        return None;
    }
    for i in 0..n {
        h[(i, i)] += damping * (h[(i, i)] + 1e-6 * largest);
    }
    let g = nalgebra::DVector::from_iterator(n, normal.gradient.iter().map(|g| -g));
    let delta = h.cholesky()?.solve(&g);
    delta
        .iter()
        .all(|d| d.is_finite())
        .then(|| delta.iter().copied().collect())
}

/// The residual refinement: a dense offset field on top of the affine + TPS grid `base`, fitted
/// with Adam on the same per-pixel residual as the TPS levels (full network resolution, no blur).
/// Pixels that never see the projector get no gradient and keep a zero offset.
#[allow(clippy::too_many_arguments)]
pub(super) fn refine_geometry<C: ReadRgb<Camera>>(
    captures: &[C],
    targets: &[NetImage],
    base: &Grid<Network, Camera>,
    curves: &Curves,
    settings: &FitSettings,
    (spacing, iters): (usize, usize),
    history: &mut Vec<f64>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> OffsetField {
    let ImageSize {
        width: nw,
        height: nh,
    } = base.size();
    let ng = settings.geometry_images.clamp(1, captures.len());
    let caps: Stack<u16> = Stack::new(&captures[..ng]);
    let lut = PowLut::new(curves.camera_gamma);
    let ylin = linear_targets(&targets[..ng], curves);
    let values = ng * nw * nh;
    let spacing = spacing.max(1);
    let mut field = OffsetField::zeros((nw - 1) / spacing + 2, (nh - 1) / spacing + 2);
    let mut adam = Adam::new(2 * field.offsets.len());
    let first = geometry_step(
        &caps,
        &ylin,
        base,
        &lut,
        &IDENTITY,
        settings.ridge,
        Subset::ALL,
        false,
    );
    let mut prior = global_solution(&first.global, values);
    let stride = settings.geometry_stride(nw * nh);
    for it in 0..iters {
        let mut grid = base.clone();
        field.apply(&mut grid);
        let subset = Subset::rotating(stride, it);
        let step = geometry_step(
            &caps,
            &ylin,
            &grid,
            &lut,
            &prior,
            settings.ridge,
            subset,
            false,
        );
        prior = global_solution(&step.global, values);
        history.push(step.loss);
        let grad = field.backward(&step.grad, nw, nh);
        let mut params = field.to_params();
        let lr = settings.learning_rate * (1.0 - 0.7 * it as f32 / iters.max(1) as f32);
        adam.step(&mut params, &grad, lr);
        field.set_params(&params);
        progress("refine", it + 1, iters);
    }
    field
}

/// Network size of a coarse level whose longer side is at most `side`.
fn level_size(
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    side: usize,
) -> ImageSize {
    let s = (side as f64 / w.max(h) as f64).min(1.0);
    ImageSize::new(
        ((w as f64 * s).round() as usize).max(4),
        ((h as f64 * s).round() as usize).max(4),
    )
}

fn blur_rgb<C: ReadRgb<Camera>>(img: &C, sigma: f32) -> CamImage {
    if sigma <= 0.0 {
        return img.to_rgb().into_owned();
    }
    let ImageSize { width, height } = img.dimensions();
    // Each channel read straight from the capture, not from an f32 copy of all three.
    let ch: Vec<_> = (0..3)
        .map(|c| {
            let plane = Plane::from_fn(width, height, |x, y| img.value((y * width + x) * 3 + c));
            gaussian_blur(&plane, sigma as f64)
        })
        .collect();
    Rgb::from_channels(&ch[0], &ch[1], &ch[2]).expect("blurred channels keep the size")
}

/// Targets in linear projector light, laid out `[p * n + i]` (pixel-major) for the fused step.
fn linear_targets(tgts: &[NetImage], curves: &Curves) -> Vec<[f32; 3]> {
    let n = tgts.len();
    let px = tgts[0].width() * tgts[0].height();
    let mut out = vec![[0f32; 3]; px * n];
    for (i, t) in tgts.iter().enumerate() {
        for (p, x) in t.data().chunks_exact(3).enumerate() {
            out[p * n + i] = targets_linear(curves, x);
        }
    }
    out
}

/// Lookup tables of `v^γ` and its derivative on [0, 1] per channel, for the training loops
/// (about 20× cheaper than `powf`; the fitted model is applied with exact `powf`).
struct PowLut {
    value: [Vec<f32>; 3],
    slope: [Vec<f32>; 3],
}

const LUT_SIZE: usize = 4096;

impl PowLut {
    fn new(gamma: [f32; 3]) -> Self {
        let table = |g: f32, d: bool| -> Vec<f32> {
            (0..LUT_SIZE)
                .map(|i| {
                    let v = i as f32 / (LUT_SIZE - 1) as f32;
                    if d {
                        if v <= 0.0 { 0.0 } else { g * v.powf(g - 1.0) }
                    } else {
                        v.powf(g)
                    }
                })
                .collect()
        };
        Self {
            value: gamma.map(|g| table(g, false)),
            slope: gamma.map(|g| table(g, true)),
        }
    }

    /// (v^γ, d/dv v^γ) for channel `c`, `v` clamped to [0, 1], linear interpolation between entries.
    #[inline]
    fn eval(&self, c: usize, v: f32) -> (f32, f32) {
        let x = v.clamp(0.0, 1.0) * (LUT_SIZE - 1) as f32;
        let i = (x as usize).min(LUT_SIZE - 2);
        let f = x - i as f32;
        let (t, d) = (&self.value[c], &self.slope[c]);
        (t[i] + f * (t[i + 1] - t[i]), d[i] + f * (d[i + 1] - d[i]))
    }
}

/// One image's contribution at one pixel: features a = [f_c(w), 1], the slope f_c'(w), and the
/// derivatives of the warped value w.r.t. the normalised grid position.
#[derive(Clone, Copy, Default)]
struct Sample {
    a: [f32; 4],
    slope: [f32; 3],
    dgx: [f32; 3],
    dgy: [f32; 3],
}

/// What one [`geometry_step`] returns.
struct Step {
    /// Mean squared residual (linear light) over the subset.
    loss: f64,
    /// The loss gradient w.r.t. each pixel's normalised camera position (zero off the subset).
    grad: Vec<[f32; 2]>,
    /// The Gauss–Newton curvature of the loss w.r.t. each pixel's position, `[xx, xy, yy]`,
    /// in the gradient's scale (empty unless asked for).
    curvature: Vec<[f32; 3]>,
    /// The global normal equations, for the next step's prior.
    global: Normal,
}

/// One geometry step, fused per pixel: sample every capture with its spatial derivative, solve the
/// pixel's coefficients against `prior` (the previous step's global model), and accumulate the
/// residual and the loss gradient w.r.t. the pixel's normalised camera position (and, with
/// `curvature`, its Gauss–Newton curvature: the pixel's coefficients held fixed). `ylin[p * n +
/// i]` are the targets in linear projector light.
#[allow(clippy::too_many_arguments)]
fn geometry_step(
    caps: &Stack<u16>,
    ylin: &[[f32; 3]],
    grid: &Grid<Network, Camera>,
    lut: &PowLut,
    prior: &[f32; 12],
    ridge: f32,
    subset: Subset,
    curvature: bool,
) -> Step {
    let n = caps.images();
    let ImageSize {
        width: cw,
        height: ch,
    } = caps.size();
    let (sx, sy) = (0.5 * (cw.max(2) - 1) as f32, 0.5 * (ch.max(2) - 1) as f32);
    let lambda = ridge as f64;
    let pixels = subset.pixels(grid.size());
    let count = (n * pixels.len() * 3).max(1) as f32;
    type PixelStep = (f64, [f32; 2], [f32; 3], Normal);
    let results: Vec<PixelStep> = pixels
        .par_iter()
        .map_init(
            || vec![Sample::default(); n],
            |buf, &p| {
                let [gx, gy] = grid.data()[p];
                let mut ne = Normal::default();
                let at = caps.locate(gx, gy);
                for (i, s) in buf.iter_mut().enumerate() {
                    let (w, [du, dv]) = caps.sample_with_gradient(&at, i);
                    for c in 0..3 {
                        let (v, d) = lut.eval(c, w[c]);
                        s.a[c] = v;
                        s.slope[c] = d;
                        s.dgx[c] = du[c] * sx;
                        s.dgy[c] = dv[c] * sy;
                    }
                    s.a[3] = 1.0;
                    ne.add(&s.a, &ylin[p * n + i]);
                }
                let k = ne.solve(lambda, prior);
                let (mut loss, mut g, mut h) = (0f64, [0f32; 2], [0f32; 3]);
                for (i, s) in buf.iter().enumerate() {
                    let y = &ylin[p * n + i];
                    let mut dw = [0f32; 3];
                    // d w_c / d position, through the camera curve.
                    let jx = [0, 1, 2].map(|c| s.slope[c] * s.dgx[c]);
                    let jy = [0, 1, 2].map(|c| s.slope[c] * s.dgy[c]);
                    for o in 0..3 {
                        let r = k[o * 3] * s.a[0]
                            + k[o * 3 + 1] * s.a[1]
                            + k[o * 3 + 2] * s.a[2]
                            + k[9 + o]
                            - y[o];
                        loss += (r * r) as f64;
                        for (c, d) in dw.iter_mut().enumerate() {
                            *d += 2.0 * r * k[o * 3 + c];
                        }
                        if curvature {
                            let (mut rx, mut ry) = (0f32, 0f32);
                            for c in 0..3 {
                                rx += k[o * 3 + c] * jx[c];
                                ry += k[o * 3 + c] * jy[c];
                            }
                            h[0] += 2.0 * rx * rx;
                            h[1] += 2.0 * rx * ry;
                            h[2] += 2.0 * ry * ry;
                        }
                    }
                    for (c, &dwc) in dw.iter().enumerate() {
                        g[0] += dwc * jx[c];
                        g[1] += dwc * jy[c];
                    }
                }
                (loss, [g[0] / count, g[1] / count], h.map(|v| v / count), ne)
            },
        )
        .collect();
    let mut global = Normal::default();
    let mut loss = 0f64;
    let mut grad = vec![[0f32; 2]; grid.data().len()];
    let mut curv = if curvature {
        vec![[0f32; 3]; grid.data().len()]
    } else {
        Vec::new()
    };
    for (&p, (l, g, h, ne)) in pixels.iter().zip(&results) {
        loss += l;
        grad[p] = *g;
        if curvature {
            curv[p] = *h;
        }
        global.merge(ne);
    }
    Step {
        loss: loss / count as f64,
        grad,
        curvature: curv,
        global,
    }
}

/// The network pixels a [`geometry_step`] evaluates: every `stride`-th pixel in each direction,
/// starting at (`phase % stride`, `phase / stride % stride`). Successive steps move the phase, so
/// every pixel counts over `stride²` steps while each step costs `1 / stride²` of a full one.
#[derive(Clone, Copy, Debug)]
struct Subset {
    stride: usize,
    phase: usize,
}

impl Subset {
    /// Every pixel.
    const ALL: Subset = Subset {
        stride: 1,
        phase: 0,
    };

    /// Step `step`'s subset at `stride` (1: every pixel).
    fn rotating(stride: usize, step: usize) -> Self {
        Self {
            stride: stride.max(1),
            phase: step,
        }
    }

    /// Row-major indices of the subset's pixels on a lattice of `size`.
    fn pixels(&self, size: ImageSize) -> Vec<usize> {
        let s = self.stride.max(1);
        // A fixed, well-mixed order of the s² offsets, so consecutive steps sit far apart.
        let k = (self.phase * 7) % (s * s);
        let (ox, oy) = (k % s, k / s);
        let mut out = Vec::with_capacity(size.width.div_ceil(s) * size.height.div_ceil(s));
        for y in (oy..size.height).step_by(s) {
            out.extend((ox..size.width).step_by(s).map(|x| y * size.width + x));
        }
        out
    }
}

/// Adam (Kingma & Ba) over a flat parameter vector.
struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl Adam {
    fn new(n: usize) -> Self {
        Self {
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }
    fn step(&mut self, params: &mut [f32], grad: &[f32], lr: f32) {
        let (b1, b2, eps) = (0.9f32, 0.999f32, 1e-12f32);
        self.t += 1;
        let (c1, c2) = (1.0 - b1.powi(self.t), 1.0 - b2.powi(self.t));
        for i in 0..params.len() {
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * grad[i];
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * grad[i] * grad[i];
            params[i] -= lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + eps);
        }
    }
}
