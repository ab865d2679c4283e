//! The `linear` rung of the model ladder (docs/architecture.md, "Models"): learned geometry
//! (affine + TPS, [`crate::warp`]) and a per-pixel linear colour model in a linearised space.
//!
//! For network pixel `p`, the warped capture `w = x̃(g_p)` (camera values, sRGB-encoded as
//! captured) is linearised per channel by the camera curve `f_c(v) = v^γc`; the model predicts the
//! projector's linear light `ℓ = M_p f_c(w) + b_p` (3×3 matrix + offset per pixel) and the projector
//! input value through the inverse projector curve `x̂ = f_p⁻¹(ℓ)`, where `ℓ` is in [0, 1]³
//! (`gamut` maps an `ℓ` outside it to the reachable colour closest in camera-encoded values, as
//! PSNR measures; `f_p⁻¹(ℓ) = ℓ^(1/γp)`). Physically,
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
//!
//! Spaces: captures are camera images (camera pixels, encoded values in \[0,1\]); projector
//! images, coefficients and model outputs are network images (network pixels, or the finer
//! lattice of [`FitSettings::lattice`]); grids map network pixels to normalised camera
//! coordinates (align-corners, \[-1,1\]).
//!
//! Files: `model` holds the representation ([`LinearModel`], [`Curves`], [`Coefficients`]) and
//! inference ([`SimplifiedLinear::apply`], [`apply_colour`]); `fit` the training entry points
//! ([`fit()`], [`fit_geometry`], [`fit_on_grid`]) and their settings; `geometry` the
//! coarse-to-fine affine + TPS fit and the dense refinement (Adam on the fused per-pixel
//! residual); `colour` the per-pixel normal equations and the closed-form colour solve; `curve`
//! the response-curve search on the forward model; `stack` the pixel-major stacks the fits read
//! their pairs from (sampled in place, never warped or resized whole); `tensors` the model
//! directory's tensors ([`LinearModel::to_tensors`], [`LinearModel::from_tensors`]).

mod colour;
mod curve;
mod fit;
pub(crate) mod gamut;
mod geometry;
mod model;
mod normal;
mod settings;
mod stack;
mod tensors;

pub use colour::ColourSums;
pub use fit::{
    FitReport, GeometryMemo, fit, fit_geometry, fit_on_grid, fit_with_memo, prefit_geometry,
};
pub use gamut::inverse as gamut_inverse;
pub use model::{Coefficients, Curves, Geometry, LinearModel, SimplifiedLinear, apply_colour};
pub use settings::{ColourSolve, FitSettings};

use crate::error::Result;
use crate::raster::{CamImage, Camera, Mask};

/// Masks every capture by the FOV mask (pixels outside read black), as the models expect.
pub fn mask_captures(captures: &[CamImage], mask: &Mask<Camera>) -> Result<Vec<CamImage>> {
    captures.iter().map(|c| c.masked(mask)).collect()
}

/// Method name of this rung.
pub const METHOD: &str = "linear";
