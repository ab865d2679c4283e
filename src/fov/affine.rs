//! The affine initialisation of the warp from the FOV's bounding box (network normalised
//! coordinates to camera normalised coordinates, align-corners).

use crate::error::{Error, Result};
use crate::raster::{ImageSize, Rect};

/// A 2×3 affine matrix θ in the PyTorch `affine_grid` convention: a destination position
/// (u, v) in normalised coordinates maps to the source position θ · (u, v, 1).
pub type Theta = [[f32; 3]; 2];

/// Normalised coordinate (align_corners = true) of pixel coordinate `i` on an axis of `n` pixels:
/// pixel centre 0 ↦ −1, pixel centre n−1 ↦ +1 (0 when n ≤ 1).
fn pixel_to_norm(i: f64, n: usize) -> f64 {
    if n <= 1 {
        0.0
    } else {
        2.0 * i / (n - 1) as f64 - 1.0
    }
}

/// The affine θ that makes the network image cover exactly `bbox` of the camera frame
/// (`cam_size` = (width, height)).
///
/// Convention (docs/architecture.md, "Spaces and conventions"): θ maps **network** normalised
/// coordinates (u, v) to **camera** normalised coordinates (x, y) = θ · (u, v, 1), both with
/// align_corners = true, so (−1, −1) and (1, 1) are the centres of the first and last pixels.
/// The network's corner pixel centres land on the centres of the box's corner pixels: u = −1 ↦
/// camera column `bbox.x`, u = +1 ↦ column `bbox.x + bbox.width − 1` (likewise rows). Sampling
/// the camera image with `affine_grid(θ)` at network resolution therefore crops the box and
/// stretches it to the network size. The full frame gives the identity.
pub fn affine_from_box(bbox: Rect, cam_size: ImageSize) -> Result<Theta> {
    let ImageSize {
        width: cw,
        height: ch,
    } = cam_size;
    if bbox.width == 0 || bbox.height == 0 || bbox.x + bbox.width > cw || bbox.y + bbox.height > ch
    {
        return Err(Error::Shape(format!(
            "FOV box {bbox} is empty or does not fit in the {cw}x{ch} camera frame"
        )));
    }
    // Column x_c = bbox.x + (u + 1)/2 · (bbox.width − 1); normalised x = 2 x_c/(cw − 1) − 1.
    // Linear in u: slope (bbox.width − 1)/(cw − 1), value at u = 0 is the box centre.
    let axis = |start: usize, len: usize, n: usize| -> (f32, f32) {
        let scale = if n <= 1 {
            0.0
        } else {
            (len - 1) as f64 / (n - 1) as f64
        };
        let centre = pixel_to_norm(start as f64 + (len - 1) as f64 / 2.0, n);
        (scale as f32, centre as f32)
    };
    let (sx, tx) = axis(bbox.x, bbox.width, cw);
    let (sy, ty) = axis(bbox.y, bbox.height, ch);
    Ok([[sx, 0.0, tx], [0.0, sy, ty]])
}

/// Applies θ to a normalised position (u, v): returns θ · (u, v, 1).
pub fn apply_theta(theta: &Theta, u: f32, v: f32) -> (f32, f32) {
    (
        theta[0][0] * u + theta[0][1] * v + theta[0][2],
        theta[1][0] * u + theta[1][1] * v + theta[1][2],
    )
}
