//! Exposure ranging: before any capture, the camera's manual exposure is chosen so that the
//! brightest lit pixels under the projector's white sit just below saturation, using the whole
//! 8-bit range without clipping the projector's light.
//!
//! "Lit" pixels are those the projector brightens by more than 0.05 (encoded units) over black;
//! the statistic is the 99.5th percentile of their brightest channel under white. Encoded values
//! follow the sensor signal through the camera's response (`v ≈ s^(1/γ)`, γ ≈ 2.2), so the
//! exposure is scaled by `(target / level)^γ` and measured again, a few times at most.

use crate::device::{DisplaySink, FrameSource};
use crate::error::Result;
use crate::raster::{CamImage, PrjImage};
use crate::record::ExposureReport;

/// Where the brightest lit pixels should sit (encoded units), and how close is close enough.
const TARGET: f64 = 0.93;
const TOLERANCE: f64 = 0.03;
/// Exposure changes tried before settling for the best so far.
const STEPS: usize = 6;
/// Exposures waited after each change (the new exposure and the shown frame reach the camera).
const WAIT_FRAMES: u64 = 12;

/// Ranges the exposure when the camera has a manual one; `None` when it has not (its exposure
/// is fixed or automatic: the saturation check of the latency phase still applies).
pub fn range_exposure<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
) -> Result<Option<ExposureReport>> {
    let Some(range) = camera.exposure() else {
        return Ok(None);
    };
    let size = display.size();
    let black = PrjImage::new(size.width, size.height);
    let white = PrjImage::filled(size.width, size.height, [1.0; 3]);
    let mut exposure = range.value;
    let mut steps = 0;
    let mut best = (f64::INFINITY, exposure, 0.0);
    loop {
        let under_black = settled_frame(display, camera, &black)?;
        let under_white = settled_frame(display, camera, &white)?;
        let level = bright_level(&under_black, &under_white);
        // Nothing lit: leave the exposure to the latency phase, which says what is wrong.
        let Some(level) = level else {
            camera.set_exposure(range.value)?;
            return Ok(None);
        };
        let miss = (level - TARGET).abs();
        if miss < best.0 {
            best = (miss, exposure, level);
        }
        if miss < TOLERANCE || steps == STEPS {
            break;
        }
        // Clipped: the level says little about how far; halve. Otherwise follow the response.
        let factor = if level >= 0.995 {
            0.5
        } else {
            (TARGET / level.max(0.05)).powf(2.2).clamp(0.25, 4.0)
        };
        let next = camera.set_exposure(exposure * factor)?;
        steps += 1;
        if next == exposure {
            break; // at the end of the range
        }
        exposure = next;
    }
    let chosen = camera.set_exposure(best.1)?;
    Ok(Some(ExposureReport {
        initial: range.value,
        chosen,
        bright_level: best.2,
        steps,
    }))
}

/// Shows `frame` and returns a camera frame exposed well after it (and after any exposure
/// change) took effect.
fn settled_frame<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    frame: &PrjImage,
) -> Result<CamImage> {
    display.show(frame)?;
    let first = camera.grab()?;
    let mut f = first.clone();
    while f.seq < first.seq + WAIT_FRAMES {
        f = camera.grab()?;
    }
    Ok(f.image)
}

/// The 99.5th percentile of the brightest channel under white over the pixels the projector
/// lights; `None` when it lights almost none (under 0.5 % of the frame).
fn bright_level(under_black: &CamImage, under_white: &CamImage) -> Option<f64> {
    let mut lit: Vec<f32> = under_white
        .data()
        .chunks_exact(3)
        .zip(under_black.data().chunks_exact(3))
        .filter(|(w, b)| (0..3).any(|c| w[c] - b[c] > 0.05))
        .map(|(w, _)| w[0].max(w[1]).max(w[2]))
        .collect();
    if lit.len() * 200 < under_white.data().len() / 3 {
        return None;
    }
    lit.sort_by(f32::total_cmp);
    let i = ((lit.len() - 1) as f64 * 0.995).round() as usize;
    Some(lit[i] as f64)
}
