//! The geometric part of the models (`T⁻¹`, docs/architecture.md, "Models"): a thin-plate-spline
//! warp of the network lattice composed with a 2×3 affine map into camera space.
//!
//! Coordinates:
//! - network pixel `p = (x, y)` has unit coordinates `(u, v) = (x / (W−1), y / (H−1))` in \[0,1\]²;
//! - the TPS adds a displacement `z(u, v)` in unit coordinates and maps to normalised network
//!   coordinates `t = 2·((u, v) + z) − 1` (align_corners = true, so `z = 0` is the identity);
//! - the affine θ maps normalised network coordinates to normalised camera coordinates:
//!   `g = θ · [t, 1]`. Composing in coordinate space (the affine grid sampled at the TPS positions)
//!   equals this product for an affine grid, so the camera image is sampled once, at `g`.
//!
//! TPS: 6×6 control points `c_k` evenly spaced on \[0,1\]², kernel `U(r) = r² log r`,
//! `z(u, v) = a0 + a1·u + a2·v + Σ_k w_k U(‖(u, v) − c_k‖)` per axis, in reduced form: the first
//! weight is `w_0 = −Σ_{k≥1} w_k`, leaving 35 weights + 3 affine terms = 38 parameters per axis,
//! 76 in all. Parameter layout per axis: `[w_1 … w_35, a0, a1, a2]`.

use serde::{Deserialize, Serialize};

use crate::raster::{Camera, ImageSize, Network};
use crate::sample::{Grid, pixel_to_norm};

/// Control points per side.
pub const TPS_SIDE: usize = 6;
/// Control points in all.
pub const TPS_POINTS: usize = TPS_SIDE * TPS_SIDE;
/// Parameters per axis in reduced form.
pub const TPS_PARAMS: usize = TPS_POINTS - 1 + 3;

/// TPS kernel U(r) = r² log r, with U(0) = 0.
#[inline]
pub fn tps_kernel(r2: f64) -> f64 {
    if r2 <= 0.0 { 0.0 } else { 0.5 * r2 * r2.ln() }
}

/// The geometry of a model: affine θ and TPS parameters (both learnable).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Warp {
    /// 2×3 matrix from normalised network to normalised camera coordinates.
    pub theta: [[f32; 3]; 2],
    /// TPS parameters, `[x axis, y axis]`, each `[w_1 … w_35, a0, a1, a2]` in unit coordinates.
    pub tps: [Vec<f32>; 2],
}

impl Warp {
    /// A warp that is exactly the affine θ (TPS displacement zero).
    pub fn from_affine(theta: [[f32; 3]; 2]) -> Self {
        Self {
            theta,
            tps: [vec![0.0; TPS_PARAMS], vec![0.0; TPS_PARAMS]],
        }
    }

    /// Number of parameters (6 affine + 76 TPS).
    pub fn param_count(&self) -> usize {
        6 + 2 * TPS_PARAMS
    }

    /// All parameters as one vector: θ row-major, then TPS x, then TPS y.
    pub fn to_params(&self) -> Vec<f32> {
        let mut p: Vec<f32> = self.theta.iter().flatten().copied().collect();
        p.extend_from_slice(&self.tps[0]);
        p.extend_from_slice(&self.tps[1]);
        p
    }

    /// Sets all parameters from a vector laid out as [`Warp::to_params`].
    pub fn set_params(&mut self, p: &[f32]) {
        for r in 0..2 {
            for c in 0..3 {
                self.theta[r][c] = p[r * 3 + c];
            }
        }
        self.tps[0].copy_from_slice(&p[6..6 + TPS_PARAMS]);
        self.tps[1].copy_from_slice(&p[6 + TPS_PARAMS..6 + 2 * TPS_PARAMS]);
    }
}

/// The TPS basis evaluated on a network lattice of `width`×`height`: one row of 38 values per pixel
/// such that the unit displacement of pixel `p` on an axis is `basis(p) · params(axis)`.
#[derive(Clone, Debug)]
pub struct TpsBasis {
    width: usize,
    height: usize,
    rows: Vec<[f32; TPS_PARAMS]>,
    /// Normalised network coordinates of the pixel centres, per column and per row.
    xs: Vec<f32>,
    ys: Vec<f32>,
}

/// Unit coordinates (0 and 1 at the first and last pixel centres of an `network`-pixel axis,
/// the align-corners convention of the warp's domain) of the pixel centres of a `lattice`-pixel
/// axis covering the same canvas with half-pixel centres, the way the canvas stretches images:
/// lattice pixel `j` sits at network pixel `(j + 0.5)·network/lattice − 0.5`. Equal sizes give
/// `j / (network − 1)`; a finer lattice reaches half a lattice pixel beyond the network's edge
/// centres (slightly outside [0, 1]).
pub fn lattice_units(network: usize, lattice: usize) -> Vec<f64> {
    let scale = network as f64 / lattice.max(1) as f64;
    let last = network.saturating_sub(1).max(1) as f64;
    (0..lattice)
        .map(|j| {
            if network == lattice {
                j as f64 / last
            } else {
                ((j as f64 + 0.5) * scale - 0.5) / last
            }
        })
        .collect()
}

/// The TPS control points in unit coordinates, in parameter order.
fn control_points() -> Vec<(f64, f64)> {
    (0..TPS_POINTS)
        .map(|k| {
            let (i, j) = (k % TPS_SIDE, k / TPS_SIDE);
            (
                i as f64 / (TPS_SIDE - 1) as f64,
                j as f64 / (TPS_SIDE - 1) as f64,
            )
        })
        .collect()
}

/// The basis row of unit position (u, v): the displacement there on an axis is this row times
/// that axis's parameters.
fn basis_row(ctrl: &[(f64, f64)], u: f64, v: f64) -> [f32; TPS_PARAMS] {
    let k = |t: usize| {
        let (cu, cv) = ctrl[t];
        tps_kernel((u - cu).powi(2) + (v - cv).powi(2))
    };
    let k0 = k(0);
    let mut row = [0f32; TPS_PARAMS];
    for t in 1..TPS_POINTS {
        row[t - 1] = (k(t) - k0) as f32;
    }
    row[TPS_POINTS - 1] = 1.0;
    row[TPS_POINTS] = u as f32;
    row[TPS_POINTS + 1] = v as f32;
    row
}

impl TpsBasis {
    pub fn new(width: usize, height: usize) -> Self {
        let unit = |n: usize| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    if n <= 1 {
                        0.0
                    } else {
                        i as f64 / (n - 1) as f64
                    }
                })
                .collect()
        };
        let norm = |n: usize| -> Vec<f32> { (0..n).map(|i| pixel_to_norm(i as f32, n)).collect() };
        Self::at_units(&unit(width), &unit(height), norm(width), norm(height))
    }

    /// The basis at the pixel centres of a `lattice` image stretched over the same canvas as a
    /// `network` image (see [`lattice_units`]); the warp keeps the network's domain.
    pub fn on_lattice(network: ImageSize, lattice: ImageSize) -> Self {
        let (us, vs) = (
            lattice_units(network.width, lattice.width),
            lattice_units(network.height, lattice.height),
        );
        let norm = |u: &[f64]| -> Vec<f32> { u.iter().map(|&u| (2.0 * u - 1.0) as f32).collect() };
        let (xs, ys) = (norm(&us), norm(&vs));
        Self::at_units(&us, &vs, xs, ys)
    }

    /// The basis at the grid of unit coordinates `us` × `vs` (columns, rows), whose normalised
    /// coordinates are `xs` × `ys`.
    fn at_units(us: &[f64], vs: &[f64], xs: Vec<f32>, ys: Vec<f32>) -> Self {
        let (width, height) = (us.len(), vs.len());
        let ctrl = control_points();
        let mut rows = Vec::with_capacity(width * height);
        for &v in vs {
            for &u in us {
                rows.push(basis_row(&ctrl, u, v));
            }
        }
        Self {
            width,
            height,
            rows,
            xs,
            ys,
        }
    }

    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }

    /// [`TpsBasis::on_lattice`]`(network, lattice).grid(warp)`, to the bit, made a row of the
    /// lattice at a time without holding the basis (38 values a pixel: 315 MB at 1920×1080).
    pub fn lattice_grid(
        network: ImageSize,
        lattice: ImageSize,
        warp: &Warp,
    ) -> Grid<Network, Camera> {
        use rayon::prelude::*;
        let (us, vs) = (
            lattice_units(network.width, lattice.width),
            lattice_units(network.height, lattice.height),
        );
        let norm = |u: f64| (2.0 * u - 1.0) as f32;
        let ctrl = control_points();
        let th = &warp.theta;
        let mut data = vec![[0f32; 2]; lattice.width * lattice.height];
        data.par_chunks_mut(lattice.width.max(1))
            .zip(&vs)
            .for_each(|(out, &v)| {
                for (g, &u) in out.iter_mut().zip(&us) {
                    let row = basis_row(&ctrl, u, v);
                    let dx: f32 = row.iter().zip(&warp.tps[0]).map(|(a, b)| a * b).sum();
                    let dy: f32 = row.iter().zip(&warp.tps[1]).map(|(a, b)| a * b).sum();
                    let (tx, ty) = (norm(u) + 2.0 * dx, norm(v) + 2.0 * dy);
                    *g = [
                        th[0][0] * tx + th[0][1] * ty + th[0][2],
                        th[1][0] * tx + th[1][1] * ty + th[1][2],
                    ];
                }
            });
        Grid::from_vec(lattice.width, lattice.height, data).expect("one position per pixel")
    }

    pub fn rows(&self) -> &[[f32; TPS_PARAMS]] {
        &self.rows
    }

    /// Normalised network coordinates `t` of every pixel after the TPS displacement.
    pub fn tps_positions(&self, warp: &Warp) -> Vec<[f32; 2]> {
        let w = self.width;
        self.rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let (x, y) = (i % w, i / w);
                let dx: f32 = row.iter().zip(&warp.tps[0]).map(|(a, b)| a * b).sum();
                let dy: f32 = row.iter().zip(&warp.tps[1]).map(|(a, b)| a * b).sum();
                [self.xs[x] + 2.0 * dx, self.ys[y] + 2.0 * dy]
            })
            .collect()
    }

    /// The sampling grid from network pixels into the camera image.
    pub fn grid(&self, warp: &Warp) -> Grid<Network, Camera> {
        let th = &warp.theta;
        let data = self
            .tps_positions(warp)
            .into_iter()
            .map(|[tx, ty]| {
                [
                    th[0][0] * tx + th[0][1] * ty + th[0][2],
                    th[1][0] * tx + th[1][1] * ty + th[1][2],
                ]
            })
            .collect();
        Grid::from_vec(self.width, self.height, data).expect("one position per pixel")
    }
}

/// The Gauss–Newton normal equations of a warp's parameters, laid out as [`Warp::to_params`]:
/// `Σ_p Bₚᵀ Hₚ Bₚ` and `Σ_p Bₚᵀ dₚ`, with `Bₚ = ∂g/∂params` (2 × 82) at pixel p, `Hₚ` the
/// pixel's 2×2 curvature and `dₚ` its gradient of a loss w.r.t. the normalised camera position
/// `g`. Row-major dense, [`Warp::param_count`]² entries.
pub struct WarpNormal {
    pub hessian: Vec<f64>,
    pub gradient: Vec<f64>,
}

/// Features of a pixel that the parameters' derivatives are linear in: `[tx, ty, 1, row…]`.
const FEATURES: usize = 3 + TPS_PARAMS;

impl TpsBasis {
    /// [`WarpNormal`] over `pixels` (row-major indices on this basis's lattice), from `curvature`
    /// (`[hxx, hxy, hyy]`) and `dl_dg` per pixel of the lattice.
    ///
    /// `∂g/∂params` is linear in the pixel's features `f = [tx, ty, 1, row]` (`t` the TPS
    /// position): `∂gx = Ax f`, `∂gy = Ay f` with fixed maps `Ax`, `Ay` (82 × 41, from θ), so
    /// the sums are three 41×41 moment matrices `Σ h f fᵀ` and two `Σ d f` mapped once, not an
    /// 82×82 product per pixel.
    pub fn gauss_newton(
        &self,
        warp: &Warp,
        pixels: &[usize],
        curvature: &[[f32; 3]],
        dl_dg: &[[f32; 2]],
    ) -> WarpNormal {
        use rayon::prelude::*;
        const F: usize = FEATURES;
        let w = self.width;
        // Moments, upper triangles: [xx, xy, yy] (F×F each), then Σ dx f and Σ dy f. Summed
        // per fixed chunk, then the chunks in order: the same sums to the bit on every run (a
        // calibration that resumes relies on refitting the same model).
        let zero = || (vec![0f64; 3 * F * F], vec![0f64; 2 * F]);
        let chunks: Vec<(Vec<f64>, Vec<f64>)> = pixels
            .par_chunks(1024)
            .map(|chunk| {
                let (mut m, mut v) = zero();
                for &p in chunk {
                    let row = &self.rows[p];
                    let dx: f32 = row.iter().zip(&warp.tps[0]).map(|(a, b)| a * b).sum();
                    let dy: f32 = row.iter().zip(&warp.tps[1]).map(|(a, b)| a * b).sum();
                    let mut f = [0f64; F];
                    f[0] = (self.xs[p % w] + 2.0 * dx) as f64;
                    f[1] = (self.ys[p / w] + 2.0 * dy) as f64;
                    f[2] = 1.0;
                    for (fk, &r) in f[3..].iter_mut().zip(row) {
                        *fk = r as f64;
                    }
                    let [hxx, hxy, hyy] = curvature[p].map(f64::from);
                    let [gx, gy] = dl_dg[p].map(f64::from);
                    for i in 0..F {
                        let (a, b, c) = (hxx * f[i], hxy * f[i], hyy * f[i]);
                        for j in i..F {
                            m[i * F + j] += a * f[j];
                            m[F * F + i * F + j] += b * f[j];
                            m[2 * F * F + i * F + j] += c * f[j];
                        }
                        v[i] += gx * f[i];
                        v[F + i] += gy * f[i];
                    }
                }
                (m, v)
            })
            .collect();
        let (mut m, mut v) = zero();
        for (m2, v2) in &chunks {
            m.iter_mut().zip(m2).for_each(|(a, b)| *a += b);
            v.iter_mut().zip(v2).for_each(|(a, b)| *a += b);
        }
        let moment = |k: usize, i: usize, j: usize| {
            let (i, j) = if i <= j { (i, j) } else { (j, i) };
            m[k * F * F + i * F + j]
        };
        // Ax, Ay as (parameter, feature, weight) lists: each parameter reads one feature.
        let th = &warp.theta;
        let n = warp.param_count();
        let mut ax: Vec<Option<(usize, f64)>> = vec![None; n];
        let mut ay: Vec<Option<(usize, f64)>> = vec![None; n];
        for c in 0..3 {
            ax[c] = Some((c, 1.0));
            ay[3 + c] = Some((c, 1.0));
        }
        for k in 0..TPS_PARAMS {
            ax[6 + k] = Some((3 + k, 2.0 * th[0][0] as f64));
            ax[6 + TPS_PARAMS + k] = Some((3 + k, 2.0 * th[0][1] as f64));
            ay[6 + k] = Some((3 + k, 2.0 * th[1][0] as f64));
            ay[6 + TPS_PARAMS + k] = Some((3 + k, 2.0 * th[1][1] as f64));
        }
        let mut hessian = vec![0f64; n * n];
        let mut gradient = vec![0f64; n];
        for a in 0..n {
            for (maps, k) in [(&ax, 0), (&ay, 1)] {
                if let Some((fa, wa)) = maps[a] {
                    gradient[a] += wa * v[k * F + fa];
                }
            }
            for b in 0..n {
                let mut sum = 0.0;
                // Bᵀ H B = Σ over (x|y, x|y) of A_row(a) M A_row(b).
                for (ma, ka) in [(&ax, 0usize), (&ay, 1usize)] {
                    let Some((fa, wa)) = ma[a] else { continue };
                    for (mb, kb) in [(&ax, 0usize), (&ay, 1usize)] {
                        let Some((fb, wb)) = mb[b] else { continue };
                        // xx, xy (= yx: each moment is symmetric), yy.
                        sum += wa * wb * moment(ka + kb, fa, fb);
                    }
                }
                hessian[a * n + b] = sum;
            }
        }
        WarpNormal { hessian, gradient }
    }
}

/// A smooth residual displacement added to a sampling grid: offsets in normalised camera
/// coordinates on a coarse lattice of `width`×`height` nodes whose corners sit on the corner
/// pixels of the network image (align-corners), interpolated bilinearly to every network pixel.
/// It refines the affine + TPS warp where the surface bends or steps more than 6×6 TPS control
/// points can follow (the `linear` model's optional refinement).
#[derive(Clone, Debug, PartialEq)]
pub struct OffsetField {
    pub width: usize,
    pub height: usize,
    /// `[dx, dy]` per node, row-major, normalised camera coordinates.
    pub offsets: Vec<[f32; 2]>,
}

impl OffsetField {
    /// A zero field of `width`×`height` nodes (each at least 2).
    pub fn zeros(width: usize, height: usize) -> Self {
        let (width, height) = (width.max(2), height.max(2));
        Self {
            width,
            height,
            offsets: vec![[0.0; 2]; width * height],
        }
    }

    /// The four nodes around network pixel (x, y) of a `nw`×`nh` image and their weights.
    #[inline]
    fn taps(&self, x: usize, y: usize, nw: usize, nh: usize) -> [(usize, f32); 4] {
        let coord = |p: usize, n: usize, nodes: usize| -> (usize, f32) {
            let u = if n > 1 {
                p as f32 * (nodes - 1) as f32 / (n - 1) as f32
            } else {
                0.0
            };
            let i = (u.floor() as usize).min(nodes - 2);
            (i, u - i as f32)
        };
        let (i, fx) = coord(x, nw, self.width);
        let (j, fy) = coord(y, nh, self.height);
        let k = j * self.width + i;
        [
            (k, (1.0 - fx) * (1.0 - fy)),
            (k + 1, fx * (1.0 - fy)),
            (k + self.width, (1.0 - fx) * fy),
            (k + self.width + 1, fx * fy),
        ]
    }

    /// Adds the interpolated offsets to every position of `grid`.
    pub fn apply(&self, grid: &mut Grid<Network, Camera>) {
        let ImageSize {
            width: nw,
            height: nh,
        } = grid.size();
        for (p, g) in grid.data_mut().iter_mut().enumerate() {
            for (k, w) in self.taps(p % nw, p / nw, nw, nh) {
                g[0] += w * self.offsets[k][0];
                g[1] += w * self.offsets[k][1];
            }
        }
    }

    /// Adds the interpolated offsets to a grid on a `lattice` stretched over the same canvas as
    /// the `network` image the field was fitted on (see [`lattice_units`]); positions beyond the
    /// outer nodes take the outer nodes' offsets.
    pub fn apply_on_lattice(&self, grid: &mut Grid<Network, Camera>, network: ImageSize) {
        let ImageSize {
            width: lw,
            height: lh,
        } = grid.size();
        let node = |u: f64, nodes: usize| -> (usize, f32) {
            let t = (u * (nodes - 1) as f64).clamp(0.0, (nodes - 1) as f64);
            let i = (t.floor() as usize).min(nodes - 2);
            (i, (t - i as f64) as f32)
        };
        let xs: Vec<_> = lattice_units(network.width, lw)
            .into_iter()
            .map(|u| node(u, self.width))
            .collect();
        let ys: Vec<_> = lattice_units(network.height, lh)
            .into_iter()
            .map(|v| node(v, self.height))
            .collect();
        for (p, g) in grid.data_mut().iter_mut().enumerate() {
            let ((i, fx), (j, fy)) = (xs[p % lw], ys[p / lw]);
            let k = j * self.width + i;
            for (k, w) in [
                (k, (1.0 - fx) * (1.0 - fy)),
                (k + 1, fx * (1.0 - fy)),
                (k + self.width, (1.0 - fx) * fy),
                (k + self.width + 1, fx * fy),
            ] {
                g[0] += w * self.offsets[k][0];
                g[1] += w * self.offsets[k][1];
            }
        }
    }

    /// The loss gradient w.r.t. the node offsets (laid out as [`OffsetField::to_params`]) from
    /// the gradient w.r.t. each grid position of a `nw`×`nh` grid.
    pub fn backward(&self, dl_dg: &[[f32; 2]], nw: usize, nh: usize) -> Vec<f32> {
        let mut grad = vec![0f32; 2 * self.offsets.len()];
        for (p, d) in dl_dg.iter().enumerate() {
            for (k, w) in self.taps(p % nw, p / nw, nw, nh) {
                grad[2 * k] += w * d[0];
                grad[2 * k + 1] += w * d[1];
            }
        }
        grad
    }

    pub fn to_params(&self) -> Vec<f32> {
        self.offsets.iter().flatten().copied().collect()
    }

    pub fn set_params(&mut self, p: &[f32]) {
        for (o, v) in self.offsets.iter_mut().zip(p.chunks_exact(2)) {
            *o = [v[0], v[1]];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A skewed affine with a small, uneven TPS displacement.
    fn a_warp() -> Warp {
        let mut warp = Warp::from_affine([[0.8, 0.1, 0.05], [-0.05, 0.9, -0.1]]);
        let params: Vec<f32> = (0..warp.param_count())
            .map(|k| {
                if k < 6 {
                    warp.to_params()[k]
                } else {
                    ((k * 37 % 11) as f32 - 5.0) * 1e-3
                }
            })
            .collect();
        warp.set_params(&params);
        warp
    }

    /// The lattice grid made row by row is the stored basis's grid, to the bit, on lattices
    /// finer, coarser and as fine as the network.
    #[test]
    fn the_lattice_grid_is_the_basis_grid() {
        let warp = a_warp();
        let network = ImageSize::new(16, 12);
        for lattice in [
            ImageSize::new(23, 17),
            ImageSize::new(9, 7),
            ImageSize::new(16, 12),
        ] {
            let want = TpsBasis::on_lattice(network, lattice).grid(&warp);
            let got = TpsBasis::lattice_grid(network, lattice, &warp);
            assert_eq!(got.size(), want.size());
            for (g, w) in got.data().iter().zip(want.data()) {
                assert_eq!(g.map(f32::to_bits), w.map(f32::to_bits), "{lattice}");
            }
        }
    }

    /// The Gauss–Newton sums are `Σ Bᵀ H B` and `Σ Bᵀ d` with `B = ∂g/∂params` taken from the
    /// grid itself by central differences (g is linear in each parameter, so the differences
    /// are exact up to f32 rounding): within 1e-3 of the largest entry, on a subset of pixels.
    #[test]
    fn the_gauss_newton_sums_are_the_jacobians_products() {
        let warp = a_warp();
        let params = warp.to_params();
        let basis = TpsBasis::new(11, 8);
        let px = 11 * 8;
        let pixels: Vec<usize> = (0..px).filter(|p| p % 3 != 1).collect();
        let unit = |p: usize, k: usize| ((p * 7 + k * 13) % 17) as f32 / 17.0 - 0.3;
        // Positive definite 2×2 curvatures and arbitrary gradients; zero off the subset.
        let mut curvature = vec![[0f32; 3]; px];
        let mut dl_dg = vec![[0f32; 2]; px];
        for &p in &pixels {
            let (a, b) = (1.0 + unit(p, 1), unit(p, 2));
            curvature[p] = [a, 0.5 * b, 1.2 - 0.5 * unit(p, 3)];
            dl_dg[p] = [unit(p, 4), unit(p, 5)];
        }
        let got = basis.gauss_newton(&warp, &pixels, &curvature, &dl_dg);
        let n = warp.param_count();
        let h = 1e-2f32;
        let columns: Vec<Vec<[f64; 2]>> = (0..n)
            .map(|k| {
                let at = |d: f32| {
                    let mut p = params.clone();
                    p[k] += d;
                    let mut w = warp.clone();
                    w.set_params(&p);
                    basis.grid(&w)
                };
                let (plus, minus) = (at(h), at(-h));
                (plus.data().iter().zip(minus.data()))
                    .map(|(a, b)| [0, 1].map(|c| (a[c] - b[c]) as f64 / (2.0 * h as f64)))
                    .collect()
            })
            .collect();
        let mut want = vec![0f64; n * n];
        let mut grad = vec![0f64; n];
        for &p in &pixels {
            let [hxx, hxy, hyy] = curvature[p].map(f64::from);
            for a in 0..n {
                let [ax, ay] = columns[a][p];
                grad[a] += ax * dl_dg[p][0] as f64 + ay * dl_dg[p][1] as f64;
                for b in 0..n {
                    let [bx, by] = columns[b][p];
                    want[a * n + b] += ax * (hxx * bx + hxy * by) + ay * (hxy * bx + hyy * by);
                }
            }
        }
        let largest = want.iter().fold(0f64, |m, v| m.max(v.abs()));
        for (i, (g, w)) in got.hessian.iter().zip(&want).enumerate() {
            assert!((g - w).abs() <= 1e-3 * largest, "H[{i}]: {g} against {w}");
        }
        let largest = grad.iter().fold(0f64, |m, v| m.max(v.abs()));
        for (k, (g, w)) in got.gradient.iter().zip(&grad).enumerate() {
            assert!((g - w).abs() <= 1e-3 * largest, "g[{k}]: {g} against {w}");
        }
    }

    /// `backward` is the adjoint of `apply`: for any field f and grid gradient g,
    /// ⟨apply(f) − base, g⟩ = ⟨f, backward(g)⟩; and the field interpolates its nodes exactly.
    #[test]
    fn offset_field_backward_is_the_adjoint_of_apply() {
        let (nw, nh) = (13, 9);
        let mut f = OffsetField::zeros(5, 4);
        let params: Vec<f32> = (0..40)
            .map(|i| ((i * 37 % 17) as f32 - 8.0) * 0.01)
            .collect();
        f.set_params(&params);
        let base = Grid::<Network, Camera>::identity(nw, nh);
        let mut moved = base.clone();
        f.apply(&mut moved);
        let g: Vec<[f32; 2]> = (0..nw * nh)
            .map(|i| {
                [
                    ((i * 7 % 11) as f32 - 5.0) * 0.1,
                    ((i * 5 % 13) as f32 - 6.0) * 0.1,
                ]
            })
            .collect();
        let lhs: f64 = moved
            .data()
            .iter()
            .zip(base.data())
            .zip(&g)
            .map(|((m, b), g)| ((m[0] - b[0]) * g[0] + (m[1] - b[1]) * g[1]) as f64)
            .sum();
        let back = f.backward(&g, nw, nh);
        let rhs: f64 = params.iter().zip(&back).map(|(p, b)| (p * b) as f64).sum();
        assert!(
            (lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
        // Corner pixels sit on corner nodes.
        let d = |x: usize, y: usize| {
            let (m, b) = (moved.get(x, y), base.get(x, y));
            [m[0] - b[0], m[1] - b[1]]
        };
        let close =
            |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6;
        assert!(close(d(0, 0), f.offsets[0]));
        assert!(close(d(nw - 1, nh - 1), f.offsets[f.offsets.len() - 1]));
    }
}
