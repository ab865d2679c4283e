//! The `linear` rung of the model ladder (DESIGN.md section 5.4): learned geometry (affine + TPS,
//! [`crate::warp`]) and a per-pixel linear colour model in a linearised space.
//!
//! For network pixel `p`, the warped capture `w = x̃(g_p)` (camera values, sRGB-encoded as
//! captured) is linearised per channel by the camera curve `f_c(v) = v^γc`; the model predicts the
//! projector's linear light `ℓ = M_p f_c(w) + b_p` (3×3 matrix + offset per pixel) and the projector
//! input value through the inverse projector curve `x̂ = f_p⁻¹(ℓ) = clamp(ℓ, 0, 1)^(1/γp)`. Physically,
//! a projector pixel's light reaches its camera pixel scaled by surface reflectance and mixed by the
//! projector and camera primaries, plus ambient light: affine in linear light, which is what the
//! per-pixel model inverts; the global curves stand in for the devices' response curves.
//!
//! Fitting: for fixed geometry and curves the per-pixel coefficients have a closed form (least
//! squares in linear projector space, ridge-regularised towards one global model so pixels that
//! never see the projector stay sane). The geometry is optimised coarse to fine with Adam on the
//! same residual; by the envelope theorem its gradient at the per-pixel optimum needs no
//! differentiation through the solve. A dense offset field then refines the affine + TPS grid
//! the same way. The curves are fitted by golden-section searches on how well the per-pixel
//! forward model (projector light → camera light) predicts the captures in camera-encoded values.

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::filter::gaussian_blur;
use crate::raster::{CamImage, Camera, Mask, NetImage, Network, Rgb};
use crate::resize::resize_area;
use crate::sample::{Grid, norm_to_pixel};
use crate::warp::{OffsetField, TpsBasis, Warp};

/// Global per-channel response curves (gamma exponents).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Curves {
    /// Camera linearisation exponent per channel: linear = captured^γ.
    pub camera_gamma: [f32; 3],
    /// Projector response exponent per channel: linear light = input^γ.
    pub projector_gamma: [f32; 3],
}

impl Default for Curves {
    fn default() -> Self {
        Self {
            camera_gamma: [2.2; 3],
            projector_gamma: [2.2; 3],
        }
    }
}

impl Curves {
    #[inline]
    pub fn camera_linear(&self, c: usize, v: f32) -> f32 {
        v.max(0.0).powf(self.camera_gamma[c])
    }
    #[inline]
    pub fn projector_linear(&self, c: usize, x: f32) -> f32 {
        x.max(0.0).powf(self.projector_gamma[c])
    }
    #[inline]
    pub fn projector_input(&self, c: usize, l: f32) -> f32 {
        l.clamp(0.0, 1.0).powf(1.0 / self.projector_gamma[c])
    }
}

/// Per-pixel coefficients on the network lattice: `[M (3×3 row-major), b (3)]` per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Coefficients {
    pub width: usize,
    pub height: usize,
    pub data: Vec<[f32; 12]>,
}

/// Where a model's geometry comes from.
#[derive(Clone, Debug)]
pub enum Geometry {
    /// Learned affine + TPS warp with its optional residual refinement (`linear`).
    Learned(Warp, Option<OffsetField>),
    /// A fixed grid, e.g. from decoded structured light (`linear-sl`).
    Fixed(Grid<Network, Camera>),
}

/// A trained `linear` model: geometry, curves and per-pixel colour coefficients.
#[derive(Clone, Debug)]
pub struct LinearModel {
    pub geometry: Geometry,
    pub curves: Curves,
    pub coeffs: Coefficients,
    /// Camera image size the geometry refers to.
    pub camera_size: (usize, usize),
    /// The network size a learned geometry was fitted at (its domain, align-corners); the
    /// coefficients' lattice can be finer (see [`FitSettings::lattice`]).
    pub geometry_size: (usize, usize),
}

/// The simplified form used for playback: one baked grid, the curves and the coefficients.
#[derive(Clone, Debug)]
pub struct SimplifiedLinear {
    pub grid: Grid<Network, Camera>,
    pub curves: Curves,
    pub coeffs: Coefficients,
}

impl LinearModel {
    pub fn network_size(&self) -> (usize, usize) {
        (self.coeffs.width, self.coeffs.height)
    }

    /// The sampling grid from network pixels into the camera image.
    pub fn grid(&self) -> Grid<Network, Camera> {
        let (w, h) = self.network_size();
        match &self.geometry {
            Geometry::Learned(warp, refine) => {
                learned_grid(warp, refine.as_ref(), self.geometry_size, (w, h))
            }
            Geometry::Fixed(grid) => grid.clone(),
        }
    }

    /// Bakes the geometry into one sampling grid.
    pub fn simplify(&self) -> SimplifiedLinear {
        SimplifiedLinear {
            grid: self.grid(),
            curves: self.curves,
            coeffs: self.coeffs.clone(),
        }
    }
}

/// The sampling grid of a learned geometry (fitted on a `network` image) at the pixel centres of
/// a `lattice` image stretched over the same canvas.
fn learned_grid(
    warp: &Warp,
    refine: Option<&OffsetField>,
    network: (usize, usize),
    lattice: (usize, usize),
) -> Grid<Network, Camera> {
    if network == lattice {
        let mut grid = TpsBasis::new(lattice.0, lattice.1).grid(warp);
        if let Some(field) = refine {
            field.apply(&mut grid);
        }
        grid
    } else {
        let mut grid = TpsBasis::on_lattice(network, lattice).grid(warp);
        if let Some(field) = refine {
            field.apply_on_lattice(&mut grid, network);
        }
        grid
    }
}

impl SimplifiedLinear {
    /// The CPU reference of the `linear` compensation pass: sample the camera-view image through
    /// the baked grid (bilinear, align-corners, zero outside), apply the per-pixel affine colour
    /// model in linear light, map back through the inverse projector curve and clamp to [0, 1].
    /// Input: a camera-space image (a capture x̃, or a desired viewer image z'); output: the
    /// network-space projector image.
    pub fn apply(&self, input: &CamImage) -> NetImage {
        let warped = crate::sample::grid_sample(input, &self.grid);
        apply_colour(&warped, &self.curves, &self.coeffs)
    }
}

/// Applies curves and per-pixel coefficients to an already warped image.
pub fn apply_colour(warped: &NetImage, curves: &Curves, coeffs: &Coefficients) -> NetImage {
    let mut out = warped.clone();
    for (px, k) in out.data_mut().chunks_exact_mut(3).zip(&coeffs.data) {
        let a = [
            curves.camera_linear(0, px[0]),
            curves.camera_linear(1, px[1]),
            curves.camera_linear(2, px[2]),
        ];
        for c in 0..3 {
            let l = k[c * 3] * a[0] + k[c * 3 + 1] * a[1] + k[c * 3 + 2] * a[2] + k[9 + c];
            px[c] = curves.projector_input(c, l);
        }
    }
    out
}

/// Training settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FitSettings {
    /// Network (output) size.
    pub network_size: (usize, usize),
    /// Optimise the warp (false keeps the initial affine, e.g. for geometry from structured light).
    pub learn_geometry: bool,
    /// (network side, Adam iterations, capture blur σ in camera pixels) per coarse-to-fine level.
    pub levels: Vec<(usize, usize, f32)>,
    /// Adam step size for the parameters (normalised coordinates).
    pub learning_rate: f32,
    /// Ridge weight pulling each pixel's coefficients towards the global model: a fixed prior
    /// strength in squared linear light, so the data outweighs it more as images are added.
    /// Measured closed loop on the rig with 48 images: 1e-2 per image (the earlier rule) cost
    /// 0.65 dB on the curved scene because dark, textured pixels were pulled to the global
    /// model. With 12 images the result moves by about ±0.4 dB with this weight, through the
    /// geometry's convergence rather than the colour fit.
    pub ridge: f32,
    /// Images used for the geometry (the colour fit always uses all of them).
    pub geometry_images: usize,
    /// The residual refinement after affine + TPS: (node spacing in network pixels, Adam
    /// iterations) of a dense offset field ([`OffsetField`]); `None` keeps affine + TPS.
    /// Measured closed loop on the rig (seed 31, 48 images): the `step` scene's depth
    /// discontinuity 20.3 → 25.7 dB, `curved` +0.3 dB, `white-plane` and `dark-texture` ±0.05 dB,
    /// for 5–10 s more training (60 iterations at 256²).
    pub refine: Option<(usize, usize)>,
    /// The lattice of the colour model and of its output images, when it differs from
    /// `network_size` (`None`: the network size). The geometry is fitted at `network_size` and is
    /// resolution independent; only the per-pixel colour solve runs on the lattice, with the
    /// projector images resampled onto it. A network image stretched over an 800×600 canvas
    /// has fewer pixels across the displayable area than the desired image it should reproduce:
    /// measured closed loop on the rig's curved scene (seed 1, 48 images), 384² instead of 256²
    /// gains 0.46 dB and 512² nothing more, for about 1 s more training.
    pub lattice: Option<(usize, usize)>,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            network_size: (256, 256),
            learn_geometry: true,
            levels: vec![(64, 120, 2.0), (128, 60, 1.0), (256, 30, 0.0)],
            learning_rate: 2e-3,
            ridge: 0.012,
            geometry_images: 24,
            refine: Some((4, 60)),
            lattice: None,
        }
    }
}

/// What the fit reports.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FitReport {
    /// Mean squared residual in linear projector light at the end, per value.
    pub final_loss: f64,
    /// Loss after each geometry iteration (all levels in order).
    pub loss_history: Vec<f64>,
    pub seconds: f64,
}

/// Fits a `linear` model on training pairs: captures `x̃_i` (camera space, already masked by the
/// FOV mask if desired) and projector inputs `x_i` (network space).
pub fn fit(
    captures: &[CamImage],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(LinearModel, FitReport)> {
    let start = Instant::now();
    check_pairs(captures, targets)?;
    let cam_size = captures[0].size();
    let (nw, nh) = settings.network_size;
    let mut history = Vec::new();
    let (warp, curves) = fit_warp(
        captures,
        targets,
        init,
        settings,
        &mut history,
        &mut progress,
    );
    let mut grid = TpsBasis::new(nw, nh).grid(&warp);
    let mut refine = None;
    if let (true, Some((spacing, iters))) = (settings.learn_geometry, settings.refine) {
        let field = refine_geometry(
            captures,
            targets,
            &grid,
            &curves,
            settings,
            (spacing, iters),
            &mut history,
            &mut progress,
        );
        field.apply(&mut grid);
        refine = Some(field);
    }
    let (curves, coeffs, loss) = match settings.lattice {
        Some((lw, lh)) if (lw, lh) != (nw, nh) => {
            let fine = learned_grid(&warp, refine.as_ref(), (nw, nh), (lw, lh));
            let up = lattice_targets(targets, (lw, lh));
            let up = up.as_deref().unwrap_or(targets);
            fit_colour(captures, up, &fine, curves, settings.ridge)
        }
        _ => fit_colour(captures, targets, &grid, curves, settings.ridge),
    };
    progress("colour", 1, 1);
    Ok((
        LinearModel {
            geometry: Geometry::Learned(warp, refine),
            curves,
            coeffs,
            camera_size: cam_size,
            geometry_size: (nw, nh),
        },
        FitReport {
            final_loss: loss,
            loss_history: history,
            seconds: start.elapsed().as_secs_f64(),
        },
    ))
}

/// The affine + TPS geometry alone, as [`fit`] starts with (no dense refinement, no colour
/// model): what the CompenNet++ variants start their WarpingNet from. Inputs as for [`fit`].
pub fn fit_geometry(
    captures: &[CamImage],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
) -> Result<Warp> {
    check_pairs(captures, targets)?;
    let (warp, _) = fit_warp(
        captures,
        targets,
        init,
        settings,
        &mut Vec::new(),
        |_, _, _| {},
    );
    Ok(warp)
}

/// The coarse-to-fine affine + TPS fit that [`fit`] starts with (when
/// `settings.learn_geometry`), the global curves fitted on the way at its first level; appends
/// each step's loss to `history`.
fn fit_warp(
    captures: &[CamImage],
    targets: &[NetImage],
    init: Warp,
    settings: &FitSettings,
    history: &mut Vec<f64>,
    mut progress: impl FnMut(&str, usize, usize),
) -> (Warp, Curves) {
    let (nw, nh) = settings.network_size;
    let mut warp = init;
    let mut curves = Curves::default();
    if settings.learn_geometry {
        let ng = settings.geometry_images.clamp(1, captures.len());
        let total: usize = settings.levels.iter().map(|l| l.1).sum();
        let mut done = 0;
        let mut adam = Adam::new(warp.param_count());
        for (level, &(side, iters, sigma)) in settings.levels.iter().enumerate() {
            let (lw, lh) = level_size((nw, nh), side);
            let caps: Vec<CamImage> = captures[..ng]
                .par_iter()
                .map(|c| blur_rgb(c, sigma))
                .collect();
            let tgts: Vec<NetImage> = targets[..ng]
                .iter()
                .map(|t| resize_area(t, lw, lh))
                .collect();
            let basis = TpsBasis::new(lw, lh);
            if level == 0 {
                // The curves are global: a coarse fit here, refined once at the end.
                curves = fit_curves(
                    &caps,
                    &tgts,
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
            let (_, _, global) = geometry_step(
                &caps,
                &ylin,
                &basis.grid(&warp),
                &lut,
                &IDENTITY,
                settings.ridge,
            );
            let mut prior = global_solution(&global, values);
            for it in 0..iters {
                let grid = basis.grid(&warp);
                let (loss, dl_dg, global) =
                    geometry_step(&caps, &ylin, &grid, &lut, &prior, settings.ridge);
                prior = global_solution(&global, values);
                history.push(loss);
                let grad = basis.backward(&warp, &dl_dg);
                let mut params = warp.to_params();
                // Step size decays within a level so each level settles.
                let lr = settings.learning_rate * (1.0 - 0.7 * it as f32 / iters.max(1) as f32);
                adam.step(&mut params, &grad, lr);
                warp.set_params(&params);
                done += 1;
                progress("geometry", done, total);
            }
        }
    }
    (warp, curves)
}

/// The residual refinement: a dense offset field on top of the affine + TPS grid `base`, fitted
/// with Adam on the same per-pixel residual as the TPS levels (full network resolution, no blur).
/// Pixels that never see the projector get no gradient and keep a zero offset.
#[allow(clippy::too_many_arguments)]
fn refine_geometry(
    captures: &[CamImage],
    targets: &[NetImage],
    base: &Grid<Network, Camera>,
    curves: &Curves,
    settings: &FitSettings,
    (spacing, iters): (usize, usize),
    history: &mut Vec<f64>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> OffsetField {
    let (nw, nh) = base.size();
    let ng = settings.geometry_images.clamp(1, captures.len());
    let caps = &captures[..ng];
    let lut = PowLut::new(curves.camera_gamma);
    let ylin = linear_targets(&targets[..ng], curves);
    let values = ng * nw * nh;
    let spacing = spacing.max(1);
    let mut field = OffsetField::zeros((nw - 1) / spacing + 2, (nh - 1) / spacing + 2);
    let mut adam = Adam::new(2 * field.offsets.len());
    let (_, _, global) = geometry_step(caps, &ylin, base, &lut, &IDENTITY, settings.ridge);
    let mut prior = global_solution(&global, values);
    for it in 0..iters {
        let mut grid = base.clone();
        field.apply(&mut grid);
        let (loss, dl_dg, global) = geometry_step(caps, &ylin, &grid, &lut, &prior, settings.ridge);
        prior = global_solution(&global, values);
        history.push(loss);
        let grad = field.backward(&dl_dg, nw, nh);
        let mut params = field.to_params();
        let lr = settings.learning_rate * (1.0 - 0.7 * it as f32 / iters.max(1) as f32);
        adam.step(&mut params, &grad, lr);
        field.set_params(&params);
        progress("refine", it + 1, iters);
    }
    field
}

/// Fits only the colour part on a fixed geometry (the two-step `linear-sl` baseline): the grid
/// maps network pixels to camera positions, e.g. from decoded structured light.
pub fn fit_on_grid(
    captures: &[CamImage],
    targets: &[NetImage],
    grid: Grid<Network, Camera>,
    settings: &FitSettings,
) -> Result<(LinearModel, FitReport)> {
    let start = Instant::now();
    check_pairs(captures, targets)?;
    if grid.width() < 2 || grid.height() < 2 {
        return Err(Error::Shape(format!(
            "grid is {}x{}, expected at least 2x2",
            grid.width(),
            grid.height()
        )));
    }
    // The grid's size is the model's lattice; finer than the projector images, they are
    // resampled onto it (see [`lattice_targets`]).
    let up = lattice_targets(targets, grid.size());
    let targets = up.as_deref().unwrap_or(targets);
    let (curves, coeffs, loss) =
        fit_colour(captures, targets, &grid, Curves::default(), settings.ridge);
    Ok((
        LinearModel {
            geometry_size: grid.size(),
            geometry: Geometry::Fixed(grid),
            curves,
            coeffs,
            camera_size: captures[0].size(),
        },
        FitReport {
            final_loss: loss,
            loss_history: Vec::new(),
            seconds: start.elapsed().as_secs_f64(),
        },
    ))
}

/// Curves and per-pixel coefficients at full resolution on all images, for a fixed grid.
fn fit_colour(
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

/// The projector images resampled onto a model lattice of `size` (`None` when they already
/// have that size). The projector shows an image stretched bilinearly over the canvas (half-pixel
/// centres), so a bilinear resample with the same convention gives, at each lattice pixel, close
/// to the value the projector showed there.
fn lattice_targets(targets: &[NetImage], size: (usize, usize)) -> Option<Vec<NetImage>> {
    (targets[0].size() != size).then(|| {
        targets
            .par_iter()
            .map(|t| crate::resize::resize_bilinear(t, size.0, size.1))
            .collect()
    })
}

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

/// Checks that captures and projector images pair up and are each of one size.
fn check_pairs(captures: &[CamImage], targets: &[NetImage]) -> Result<()> {
    if captures.is_empty() || captures.len() != targets.len() {
        return Err(Error::Input(format!(
            "linear fit needs as many captures as projector images, got {} and {}",
            captures.len(),
            targets.len()
        )));
    }
    let cam_size = captures[0].size();
    if let Some(c) = captures.iter().find(|c| c.size() != cam_size) {
        return Err(Error::Shape(format!(
            "captures differ in size: {:?} and {:?}",
            cam_size,
            c.size()
        )));
    }
    let net_size = targets[0].size();
    if let Some(t) = targets.iter().find(|t| t.size() != net_size) {
        return Err(Error::Shape(format!(
            "projector images differ in size: {:?} and {:?}",
            net_size,
            t.size()
        )));
    }
    Ok(())
}

/// Network size of a coarse level whose longer side is at most `side`.
fn level_size((w, h): (usize, usize), side: usize) -> (usize, usize) {
    let s = (side as f64 / w.max(h) as f64).min(1.0);
    (
        ((w as f64 * s).round() as usize).max(4),
        ((h as f64 * s).round() as usize).max(4),
    )
}

fn blur_rgb(img: &CamImage, sigma: f32) -> CamImage {
    if sigma <= 0.0 {
        return img.clone();
    }
    let ch: Vec<_> = (0..3)
        .map(|c| gaussian_blur(&img.channel(c), sigma as f64))
        .collect();
    Rgb::from_channels(&ch[0], &ch[1], &ch[2]).expect("blurred channels keep the size")
}

/// Normal equations of one pixel: features a = [f_c(w), 1], targets y = f_p(x).
#[derive(Clone, Copy, Default)]
struct Normal {
    ata: [[f64; 4]; 4],
    aty: [[f64; 3]; 4],
}

impl Normal {
    #[inline]
    fn add(&mut self, a: &[f32; 4], y: &[f32; 3]) {
        for (i, &ai) in a.iter().enumerate() {
            for (j, &aj) in a.iter().enumerate().skip(i) {
                self.ata[i][j] += (ai * aj) as f64;
            }
            for (c, &yc) in y.iter().enumerate() {
                self.aty[i][c] += (ai * yc) as f64;
            }
        }
    }
    fn merge(&mut self, o: &Normal) {
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
    fn solve(&self, lambda: f64, prior: &[f32; 12]) -> [f32; 12] {
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
fn features(curves: &Curves, w: &[f32]) -> [f32; 4] {
    [
        curves.camera_linear(0, w[0]),
        curves.camera_linear(1, w[1]),
        curves.camera_linear(2, w[2]),
        1.0,
    ]
}

#[inline]
fn targets_linear(curves: &Curves, x: &[f32]) -> [f32; 3] {
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

/// Pixel stride of the final curve fit.
/// The final curve search samples about this many network pixels along the longer side.
const CURVE_SAMPLES: usize = 64;

/// At most this many coordinate sweeps of the curve search (it stops earlier when a sweep
/// improves the cost by less than 1e-4 relative).
const CURVE_SWEEPS: usize = 12;

/// Golden-section search for the minimum of `f` on `[lo, hi]` with `iters` shrinking steps;
/// returns the better of the last two probes and its value.
fn golden_min(mut lo: f32, mut hi: f32, iters: usize, f: impl Fn(f32) -> f64) -> (f32, f64) {
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

const IDENTITY: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];

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

/// One geometry step, fused per pixel: sample every capture with its spatial derivative, solve the
/// pixel's coefficients against `prior` (the previous step's global model), and accumulate the
/// residual and the loss gradient w.r.t. the pixel's normalised camera position. Returns the mean
/// squared residual (linear light), the gradient per pixel, and the global normal equations for
/// the next step's prior. `ylin[p * n + i]` are the targets in linear projector light.
fn geometry_step(
    caps: &[CamImage],
    ylin: &[[f32; 3]],
    grid: &Grid<Network, Camera>,
    lut: &PowLut,
    prior: &[f32; 12],
    ridge: f32,
) -> (f64, Vec<[f32; 2]>, Normal) {
    let n = caps.len();
    let (cw, ch) = caps[0].size();
    let (sx, sy) = (0.5 * (cw.max(2) - 1) as f32, 0.5 * (ch.max(2) - 1) as f32);
    let lambda = ridge as f64;
    let count = (n * grid.data().len() * 3) as f32;
    let results: Vec<(f64, [f32; 2], Normal)> = grid
        .data()
        .par_iter()
        .enumerate()
        .map_init(
            || vec![Sample::default(); n],
            |buf, (p, &[gx, gy])| {
                let mut ne = Normal::default();
                for (i, cap) in caps.iter().enumerate() {
                    let (w, [du, dv]) = sample_with_gradient(cap, gx, gy);
                    let s = &mut buf[i];
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
                let (mut loss, mut g) = (0f64, [0f32; 2]);
                for (i, s) in buf.iter().enumerate() {
                    let y = &ylin[p * n + i];
                    let mut dw = [0f32; 3];
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
                    }
                    for (c, &dwc) in dw.iter().enumerate() {
                        let d = dwc * s.slope[c];
                        g[0] += d * s.dgx[c];
                        g[1] += d * s.dgy[c];
                    }
                }
                (loss, [g[0] / count, g[1] / count], ne)
            },
        )
        .collect();
    let mut global = Normal::default();
    let mut loss = 0f64;
    let mut grad = Vec::with_capacity(results.len());
    for (l, g, ne) in &results {
        loss += l;
        grad.push(*g);
        global.merge(ne);
    }
    (loss / count as f64, grad, global)
}

/// The global (one model for all pixels) solution of accumulated normal equations.
fn global_solution(global: &Normal, values: usize) -> [f32; 12] {
    global.solve(1e-6 * values as f64, &IDENTITY)
}

/// The bilinear sample of `img` at normalised (gx, gy) and its derivatives w.r.t. the pixel
/// coordinates (u, v), per channel, zero padding (as [`crate::sample::grid_sample`]).
fn sample_with_gradient(img: &CamImage, gx: f32, gy: f32) -> ([f32; 3], [[f32; 3]; 2]) {
    let (w, h) = img.size();
    let (u, v) = (norm_to_pixel(gx, w), norm_to_pixel(gy, h));
    if !u.is_finite() || !v.is_finite() {
        return ([0.0; 3], [[0.0; 3]; 2]);
    }
    let (x0, y0) = (u.floor(), v.floor());
    let (fx, fy) = (u - x0, v - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let data = img.data();
    let px = |x: i64, y: i64| -> [f32; 3] {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            [0.0; 3]
        } else {
            let i = (y as usize * w + x as usize) * 3;
            [data[i], data[i + 1], data[i + 2]]
        }
    };
    let (p00, p10, p01, p11) = (
        px(x0, y0),
        px(x0 + 1, y0),
        px(x0, y0 + 1),
        px(x0 + 1, y0 + 1),
    );
    let mut val = [0f32; 3];
    let mut du = [0f32; 3];
    let mut dv = [0f32; 3];
    for c in 0..3 {
        let top = p00[c] + fx * (p10[c] - p00[c]);
        let bottom = p01[c] + fx * (p11[c] - p01[c]);
        val[c] = top + fy * (bottom - top);
        du[c] = (1.0 - fy) * (p10[c] - p00[c]) + fy * (p11[c] - p01[c]);
        dv[c] = bottom - top;
    }
    (val, [du, dv])
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
fn fit_curves(
    caps: &[CamImage],
    tgts: &[NetImage],
    grid: &Grid<Network, Camera>,
    start: Curves,
    ridge: f32,
    stride: usize,
    sweeps: usize,
) -> Curves {
    // The curves are global: every `stride`-th pixel in each direction is plenty.
    let (w, h) = grid.size();
    let (sw, sh) = (w.div_ceil(stride), h.div_ceil(stride));
    let grid = Grid::<Network, Camera>::from_fn(sw, sh, |x, y| grid.get(x * stride, y * stride));
    let tgts: Vec<NetImage> = tgts
        .iter()
        .map(|t| NetImage::from_fn(sw, sh, |x, y| t.get(x * stride, y * stride)))
        .collect();
    let warped: Vec<NetImage> = caps
        .par_iter()
        .map(|c| crate::sample::grid_sample(c, &grid))
        .collect();
    let cost = |cv: &Curves| forward_residual(&warped, &tgts, cv, ridge);
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
    for _sweep in 0..sweeps {
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
    to_curves(&best)
}

/// Fits the weighted forward model per pixel and returns the summed squared residual of its
/// prediction of the captures in camera-encoded values (clipped captures left out).
fn forward_residual(warped: &[NetImage], targets: &[NetImage], curves: &Curves, ridge: f32) -> f64 {
    let (w, h) = targets[0].size();
    let n = warped.len();
    let sample = |wi: &NetImage, ti: &NetImage, p: usize| {
        let x = &wi.data()[p * 3..p * 3 + 3];
        let a = features(curves, x);
        let y = targets_linear(curves, &ti.data()[p * 3..p * 3 + 3]);
        let wt = [0, 1, 2].map(|c| encoding_weight(x[c], curves.camera_gamma[c]));
        ([y[0], y[1], y[2], 1.0], [a[0], a[1], a[2]], wt)
    };
    let normals: Vec<ForwardNormal> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let mut ne = ForwardNormal::default();
            for (wi, ti) in warped.iter().zip(targets) {
                let (f, a, wt) = sample(wi, ti, p);
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
    let mean_w = total_w / (n * w * h) as f64;
    let global_fwd = global.solve(1e-6 * total_w, &IDENTITY).unwrap_or(IDENTITY);
    let lambda = ridge as f64 * mean_w;
    (0..w * h)
        .into_par_iter()
        .map(|p| {
            let k = normals[p].solve(lambda, &global_fwd).unwrap_or(global_fwd);
            let mut s = 0f64;
            for (wi, ti) in warped.iter().zip(targets) {
                let x = &wi.data()[p * 3..p * 3 + 3];
                let y = targets_linear(curves, &ti.data()[p * 3..p * 3 + 3]);
                for c in 0..3 {
                    if x[c] >= 0.995 {
                        continue;
                    }
                    let l = k[c * 3] * y[0] + k[c * 3 + 1] * y[1] + k[c * 3 + 2] * y[2] + k[9 + c];
                    let e = l.clamp(0.0, 1.0).powf(1.0 / curves.camera_gamma[c]) - x[c];
                    s += (e * e) as f64;
                }
            }
            s
        })
        .sum()
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

/// Masks every capture by the FOV mask (pixels outside read black), as the models expect.
pub fn mask_captures(captures: &[CamImage], mask: &Mask<Camera>) -> Result<Vec<CamImage>> {
    captures.iter().map(|c| c.masked(mask)).collect()
}

/// Method name of this rung.
pub const METHOD: &str = "linear";

impl LinearModel {
    /// Numeric state for the model directory: the learnable geometry, the baked grid (what playback
    /// reads), the curves and the per-pixel coefficients.
    pub fn to_tensors(&self) -> Result<crate::model::store::Tensors> {
        let (w, h) = self.network_size();
        let mut t = crate::model::store::Tensors::default();
        if let Geometry::Learned(warp, refine) = &self.geometry {
            let theta = warp.theta.iter().flatten().copied().collect();
            t.insert("warp.theta", vec![2, 3], theta)?;
            let tps: Vec<f32> = warp.tps.iter().flatten().copied().collect();
            t.insert("warp.tps", vec![2, crate::warp::TPS_PARAMS], tps)?;
            if let Some(f) = refine {
                t.insert("warp.refine", vec![f.height, f.width, 2], f.to_params())?;
            }
            if self.geometry_size != (w, h) {
                let (gw, gh) = self.geometry_size;
                t.insert("warp.network", vec![2], vec![gw as f32, gh as f32])?;
            }
        }
        let grid = self.grid();
        t.insert(
            "grid",
            vec![h, w, 2],
            grid.data().iter().flatten().copied().collect(),
        )?;
        t.insert(
            "curves.camera_gamma",
            vec![3],
            self.curves.camera_gamma.to_vec(),
        )?;
        t.insert(
            "curves.projector_gamma",
            vec![3],
            self.curves.projector_gamma.to_vec(),
        )?;
        t.insert(
            "colour.coeffs",
            vec![h, w, 12],
            self.coeffs.data.iter().flatten().copied().collect(),
        )?;
        Ok(t)
    }

    /// Rebuilds a model from the model directory's tensors; `file` names the weights in errors.
    pub fn from_tensors(
        t: &crate::model::store::Tensors,
        network_size: (usize, usize),
        camera_size: (usize, usize),
        file: &std::path::Path,
    ) -> Result<Self> {
        let (w, h) = network_size;
        let cg = t.get("curves.camera_gamma", &[3], file)?;
        let pg = t.get("curves.projector_gamma", &[3], file)?;
        let co = t.get("colour.coeffs", &[h, w, 12], file)?;
        let bad = |name: &str| {
            Error::Input(format!(
                "{}: tensor `{name}` holds non-finite or out-of-range values",
                file.display()
            ))
        };
        let grid = t.get("grid", &[h, w, 2], file)?;
        if grid.iter().chain(co).any(|v| !v.is_finite()) {
            return Err(bad("grid/colour.coeffs"));
        }
        if cg
            .iter()
            .chain(pg)
            .any(|&g| !(g.is_finite() && g > 0.05 && g < 20.0))
        {
            return Err(bad("curves"));
        }
        // A learned geometry fitted on a coarser network than the lattice says so; earlier
        // models (and every fixed geometry) have one size for both.
        let geometry_size = match t.shape("warp.network") {
            None => (w, h),
            Some(_) => {
                let v = t.get("warp.network", &[2], file)?;
                let side =
                    |x: f32| (x.is_finite() && (2.0..=65_536.0).contains(&x)).then_some(x as usize);
                match (side(v[0]), side(v[1])) {
                    (Some(gw), Some(gh)) => (gw, gh),
                    _ => return Err(bad("warp.network")),
                }
            }
        };
        // A learned model carries its warp parameters; a fixed-geometry one only the grid.
        let geometry = if t.names().any(|n| n == "warp.theta") {
            let th = t.get("warp.theta", &[2, 3], file)?;
            let tps = t.get("warp.tps", &[2, crate::warp::TPS_PARAMS], file)?;
            if th.iter().chain(tps).any(|v| !v.is_finite()) {
                return Err(bad("warp"));
            }
            let refine = match t.shape("warp.refine") {
                None => None,
                Some(&[fh, fw, 2]) if fw >= 2 && fh >= 2 => {
                    let v = t.get("warp.refine", &[fh, fw, 2], file)?;
                    if v.iter().any(|x| !x.is_finite()) {
                        return Err(bad("warp.refine"));
                    }
                    let mut f = OffsetField::zeros(fw, fh);
                    f.set_params(v);
                    Some(f)
                }
                Some(other) => {
                    return Err(Error::Input(format!(
                        "{}: tensor `warp.refine` has shape {other:?}, expected [rows, columns, 2] \
                         with at least 2 rows and columns",
                        file.display()
                    )));
                }
            };
            Geometry::Learned(
                Warp {
                    theta: [[th[0], th[1], th[2]], [th[3], th[4], th[5]]],
                    tps: [
                        tps[..crate::warp::TPS_PARAMS].to_vec(),
                        tps[crate::warp::TPS_PARAMS..].to_vec(),
                    ],
                },
                refine,
            )
        } else {
            let cells = grid.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
            Geometry::Fixed(Grid::from_vec(w, h, cells)?)
        };
        let data = co
            .chunks_exact(12)
            .map(|c| {
                let mut k = [0f32; 12];
                k.copy_from_slice(c);
                k
            })
            .collect();
        Ok(Self {
            geometry,
            curves: Curves {
                camera_gamma: [cg[0], cg[1], cg[2]],
                projector_gamma: [pg[0], pg[1], pg[2]],
            },
            coeffs: Coefficients {
                width: w,
                height: h,
                data,
            },
            camera_size,
            geometry_size,
        })
    }
}
