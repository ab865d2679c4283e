//! The projector's field of view in the camera (docs/architecture.md, "Spaces and conventions"):
//! the FOV mask from the black and white reference captures, the affine initialisation of the
//! warp from its bounding box, and the optimal displayable area (the largest canvas-shaped
//! rectangle inside the mask) with the placement of desired images into it.
//!
//! All masks, rectangles and images here are in **camera pixels**. Pixel values are the encoded
//! \[0,1\] values of the captures (sRGB-encoded, not linearised).
//!
//! # FOV mask algorithm
//!
//! A plain Otsu threshold on white − black fails where the surface is dark (the projector adds
//! little light, so the difference is small) or saturated (black and white both clip), and where
//! the projector light falls off towards the corners: Otsu then separates bright texture from
//! dark texture instead of lit from unlit, and keeps only part of the lit area. Here Otsu only
//! finds a sure *core*; the boundary is decided by a noise-aware low threshold and a local
//! half-level test:
//!
//! 1. `D` = Gaussian blur (σ ≈ 1 px at 320 px) of gray(max(white − black, 0)).
//! 2. Core: the largest connected region of `D` above its Otsu threshold (with any other region
//!    at least `min_part` of its size: a shadow may split the projection). Lit level `L` = median
//!    of `D` over the core.
//! 3. Noise: median and robust σ (1.4826·MAD) of `D` over pixels well away from the lit area
//!    (outside the core's convex hull dilated by a margin; re-estimated once outside the first
//!    support). When there is too little of it, or it is itself lit (median above 0.3·L: the
//!    projection fills the frame), the low threshold is 0.1·L instead.
//! 4. Support: `D` above the low threshold `max(noise median + k·σ, f·L)` (capped at the Otsu
//!    threshold), the connected regions holding the core (hysteresis), holes filled. This keeps
//!    dark texture as long as it is above the camera noise, but it also includes the blur's spill
//!    a few pixels past the true edge.
//! 5. Edge: in a band on both sides of the support's edge, a pixel is lit where `D` reaches half
//!    the local level (the median `D` of support pixels nearby that lie at least 2 px deeper
//!    inside, i.e. the plateau inward along the edge normal) and stands above the noise. A
//!    blurred step crosses half its height at the true edge whatever its brightness, so the
//!    spill goes, and the edges of dim texture move out to where they belong.
//! 6. Fill, region by region: morphological closing (default; fills notches left by dark texture
//!    at the edge) or convex hull, then hole filling; keep the largest region and those at least
//!    `min_part` of its size.
//!
//! Dark or saturated patches below the noise inside the lit area become holes and are filled;
//! at the edge they become notches that the closing fills when narrow, and the hull always.
//! Limits: where the white capture clips, the lit level is underestimated and the edge moves
//! outward by up to about a pixel; a shadow narrower than about 4 σ of the total blur is bridged
//! (its middle stays above the low threshold) and ends up inside the mask.
//!
//! Modules: `mask` (the FOV mask, steps 1–6 above), `affine` (the affine initialisation),
//! `area` (the displayable area, placement and display range), `reach` (the pixels of the
//! displayable area no model can compensate, and why).

mod affine;
mod area;
mod mask;
mod reach;

pub use affine::{Theta, affine_from_box, apply_theta};
pub use area::{
    DESIRED_RANGE_QUANTILE, DisplayRange, EDGE_MARGIN_PX, MIN_CONTRAST, display_range,
    displayable_area, place_in_area,
};
pub use mask::{FovDiagnostics, FovFill, FovMask, FovOptions, fov_mask, fov_mask_with};
pub use reach::{Reach, ReachSummary, Unreachable, reach};
