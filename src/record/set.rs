//! What `set.json` records of a set of projectors calibrated together (docs/architecture.md,
//! "Sets of projectors"): how the set was checked as a whole. Each projector's own calibration
//! is in its own `model.json`.

use serde::{Deserialize, Serialize};

use super::ExposureReport;
use crate::metrics::SeamFigure;
use crate::raster::Rect;

/// The calibration of a set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetRecord {
    /// What was calibrated (`virtual:tiled`).
    pub rig: String,
    /// The exposure ranged with every projector white, at which each was calibrated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<ExposureReport>,
    /// The projectors' camera-curve exponents spread (largest − smallest over projectors and
    /// channels): one camera, so they should agree; the joint model linearises each projector's
    /// pixels with its own.
    pub camera_gamma_spread: f64,
    /// The displayable area of the whole set (camera pixels): the largest rectangle of the
    /// desired aspect inside the union of the projectors' fields of view.
    pub area: Rect,
    /// The range of camera values (encoded) desired views are scaled into there: what the set
    /// reaches across its area.
    pub display_range: crate::fov::DisplayRange,
    pub verification: SetVerification,
    /// Seconds: each projector's calibration, in order, then the whole set's verification,
    /// and the total.
    pub projector_seconds: Vec<f64>,
    pub verification_seconds: f64,
    pub total_seconds: f64,
}

/// The whole set's closed-loop check: test images placed in the set's displayable area,
/// compensated jointly and by each projector alone (its own model, the others black),
/// projected, captured and scored inside the area.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetVerification {
    pub images: usize,
    /// PSNR (dB) and SSIM of the joint compensation over the whole area.
    pub psnr: f64,
    pub ssim: f64,
    /// PSNR (dB) of each projector compensating alone, in order.
    pub alone_psnr: Vec<f64>,
    /// The joint PSNR over the best projector alone, dB.
    pub gain_db: f64,
    /// The gain the set needs over its best projector alone, dB.
    pub required_gain_db: f64,
    /// The seam figure of the joint projection over the test images: the residual in a band
    /// along the overlap edges against away from them. `None` where no projectors overlap.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seam: Option<SeamFigure>,
    /// The largest seam ratio ([`SeamFigure::ratio`]) that passes.
    pub seam_limit: f64,
    pub passed: bool,
    /// Why it did not pass, in words.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
}
