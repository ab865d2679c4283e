//! The `linear` model's representation and inference: geometry (a learned affine + TPS warp
//! with its dense refinement, or a fixed grid), the global response curves and the per-pixel
//! colour coefficients, and the CPU reference of the compensation pass.
//!
//! Coefficients live on the network lattice (network pixels, or the finer lattice the model was
//! fitted on); the grid maps those pixels to normalised camera coordinates (align-corners).

use serde::{Deserialize, Serialize};

use crate::raster::{CamImage, Camera, ImageSize, NetImage, Network};
use crate::sample::Grid;
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
    pub camera_size: ImageSize,
    /// The network size a learned geometry was fitted at (its domain, align-corners); the
    /// coefficients' lattice can be finer (see
    /// [`FitSettings::lattice`](super::FitSettings::lattice)).
    pub geometry_size: ImageSize,
}

/// The simplified form used for playback: one baked grid, the curves and the coefficients.
#[derive(Clone, Debug)]
pub struct SimplifiedLinear {
    pub grid: Grid<Network, Camera>,
    pub curves: Curves,
    pub coeffs: Coefficients,
}

impl LinearModel {
    pub fn network_size(&self) -> ImageSize {
        ImageSize::new(self.coeffs.width, self.coeffs.height)
    }

    /// The sampling grid from network pixels into the camera image.
    pub fn grid(&self) -> Grid<Network, Camera> {
        match &self.geometry {
            Geometry::Learned(warp, refine) => learned_grid(
                warp,
                refine.as_ref(),
                self.geometry_size,
                self.network_size(),
            ),
            Geometry::Fixed(grid) => grid.clone(),
        }
    }

    /// The sampling grid at the pixel centres of a `size` image stretched over the same canvas
    /// (a coarser network on top of this model). A fixed grid is only available at its own size.
    pub fn grid_at(&self, size: ImageSize) -> crate::error::Result<Grid<Network, Camera>> {
        match &self.geometry {
            Geometry::Learned(warp, refine) => Ok(learned_grid(
                warp,
                refine.as_ref(),
                self.geometry_size,
                size,
            )),
            Geometry::Fixed(grid) if grid.size() == size => Ok(grid.clone()),
            Geometry::Fixed(grid) => Err(crate::error::Error::Shape(format!(
                "a fixed {} grid cannot be resampled to {size}",
                grid.size()
            ))),
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
pub(super) fn learned_grid(
    warp: &Warp,
    refine: Option<&OffsetField>,
    network: ImageSize,
    lattice: ImageSize,
) -> Grid<Network, Camera> {
    if network == lattice {
        let mut grid = TpsBasis::new(lattice.width, lattice.height).grid(warp);
        if let Some(field) = refine {
            field.apply(&mut grid);
        }
        grid
    } else {
        let mut grid = TpsBasis::lattice_grid(network, lattice, warp);
        if let Some(field) = refine {
            field.apply_on_lattice(&mut grid, network);
        }
        grid
    }
}

impl SimplifiedLinear {
    /// The CPU reference of the `linear` compensation pass: sample the camera-view image through
    /// the baked grid (bilinear, align-corners, zero outside), apply the per-pixel affine colour
    /// model in linear light, bring light outside [0, 1]³ to the closest reachable
    /// (`linear::gamut`) and map back through the inverse projector curve.
    /// Input: a camera-space image (a capture x̃, or a desired viewer image z'); output: the
    /// network-space projector image.
    pub fn apply(&self, input: &CamImage) -> NetImage {
        let warped = crate::sample::grid_sample(input, &self.grid);
        apply_colour(&warped, &self.curves, &self.coeffs)
    }

    /// The forward model the colour coefficients invert: for projector input values `shown` on
    /// the model's lattice (network pixels), the camera values (encoded, as captured) it
    /// predicts at each lattice pixel, `v = clamp(M⁻¹(f_p(x) − b), 0, 1)^(1/γc)`. A pixel whose
    /// `M` cannot be inverted reads NaN. An error when `shown` is not of the lattice's size.
    pub fn predict_capture(&self, shown: &NetImage) -> crate::error::Result<NetImage> {
        use rayon::prelude::*;
        let lattice = ImageSize::new(self.coeffs.width, self.coeffs.height);
        if shown.size() != lattice {
            return Err(crate::error::Error::Shape(format!(
                "a {} projector image for a model on a {lattice} lattice",
                shown.size()
            )));
        }
        let mut out = shown.clone();
        let curves = self.curves;
        out.data_mut()
            .par_chunks_exact_mut(3)
            .zip(self.coeffs.data.par_iter())
            .for_each(|(px, k)| {
                let m = [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]];
                let Some(inv) = super::gamut::inverse(&m) else {
                    px.fill(f32::NAN);
                    return;
                };
                let l: [f32; 3] =
                    std::array::from_fn(|c| curves.projector_linear(c, px[c]) - k[9 + c]);
                for c in 0..3 {
                    let a = inv[c][0] * l[0] + inv[c][1] * l[1] + inv[c][2] * l[2];
                    px[c] = a.clamp(0.0, 1.0).powf(1.0 / curves.camera_gamma[c]);
                }
            });
        Ok(out)
    }
}

/// Applies curves and per-pixel coefficients to an already warped image (camera values in,
/// projector input values out, network or lattice pixels), with the gamut map where the model's
/// light leaves [0, 1]³.
pub fn apply_colour(warped: &NetImage, curves: &Curves, coeffs: &Coefficients) -> NetImage {
    use rayon::prelude::*;
    let mut out = warped.clone();
    out.data_mut()
        .par_chunks_exact_mut(3)
        .zip(coeffs.data.par_iter())
        .for_each(|(px, k)| {
            let a = [
                curves.camera_linear(0, px[0]),
                curves.camera_linear(1, px[1]),
                curves.camera_linear(2, px[2]),
            ];
            let mut l = [0f32; 3];
            for (c, v) in l.iter_mut().enumerate() {
                *v = k[c * 3] * a[0] + k[c * 3 + 1] * a[1] + k[c * 3 + 2] * a[2] + k[9 + c];
            }
            if l.iter().any(|&v| !(0.0..=1.0).contains(&v)) {
                l = super::gamut::nearest_reachable(
                    k,
                    l,
                    [px[0], px[1], px[2]],
                    curves.camera_gamma,
                );
            }
            for c in 0..3 {
                px[c] = curves.projector_input(c, l[c]);
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The forward model inverts the compensation: a capture compensated and predicted back
    /// is the capture again, where the colour it asks for is reachable.
    #[test]
    fn the_forward_prediction_inverts_the_colour_model() {
        let (w, h) = (3, 2);
        // A surface that mixes the channels a little and has some ambient light.
        let k: [f32; 12] = [
            1.4, -0.2, 0.1, //
            -0.1, 1.2, -0.05, //
            0.05, -0.1, 1.6, //
            -0.02, 0.01, -0.03,
        ];
        let model = SimplifiedLinear {
            grid: Grid::identity(w, h),
            curves: Curves {
                camera_gamma: [2.0, 2.2, 2.4],
                projector_gamma: [2.2, 1.8, 2.0],
            },
            coeffs: Coefficients {
                width: w,
                height: h,
                data: vec![k; w * h],
            },
        };
        let seen: Vec<f32> = (0..w * h * 3)
            .map(|i| 0.3 + 0.05 * i as f32 / 3.0)
            .collect();
        let capture = CamImage::from_vec(w, h, seen.clone()).unwrap();
        let shown = model.apply(&capture);
        let back = model.predict_capture(&shown).unwrap();
        for (a, b) in back.data().iter().zip(&seen) {
            assert!((a - b).abs() < 1e-4, "{a} against {b}");
        }
        // Another lattice's image is refused; a singular pixel reads NaN.
        let wrong = NetImage::from_vec(2, 2, vec![0.5; 12]).unwrap();
        assert!(model.predict_capture(&wrong).is_err());
        let mut singular = model.clone();
        singular.coeffs.data[0] = [0.0; 12];
        let p = singular.predict_capture(&shown).unwrap();
        assert!(p.data()[..3].iter().all(|v| v.is_nan()));
        assert!(p.data()[3..].iter().all(|v| v.is_finite()));
    }
}
