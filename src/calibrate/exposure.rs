//! Exposure ranging: before any capture, the camera's manual exposure is chosen so that the
//! brightest lit pixels under the projector's white sit just below saturation, using the whole
//! 8-bit range without clipping the projector's light.
//!
//! "Lit" pixels are those the projector brightens by more than 0.05 (encoded units) over black;
//! the statistic is the 99.5th percentile of their brightest channel under white. Encoded values
//! follow the sensor signal through the camera's response (`v ≈ s^(1/γ)`, γ ≈ 2.2), so the
//! exposure is scaled by `(target / level)^γ` and measured again, a few times at most.

use super::clock::Timed;
use super::sync::{SETTLE_FRAMES, SettledLevels, settled_level};
use crate::device::{DisplaySink, FrameSource};
use crate::error::Result;
use crate::raster::{CamImage, PrjImage};
use crate::record::ExposureReport;

/// Where the brightest lit pixels should sit (encoded units), and how close is close enough.
const TARGET: f64 = 0.93;
const TOLERANCE: f64 = 0.03;
/// Exposure changes tried before settling for the best so far.
const STEPS: usize = 6;
/// The most exposures waited for a shown frame (and a new exposure) to settle in the camera:
/// each level is taken once the camera's mean level has been steady for 4 exposures and at
/// least [`SETTLE_FRAMES`] after the show, as the latency phase takes its own.
const MAX_WAIT_FRAMES: u64 = 24;

/// What [`range_exposure`] found: the report (`None` when the camera has no manual exposure,
/// or the projector lights nothing it sees), and the last black and white levels when they were
/// taken at the exposure chosen (white showing), for the latency phase to start from.
pub struct Ranged {
    pub report: Option<ExposureReport>,
    pub levels: Option<SettledLevels>,
}

/// Ranges the exposure when the camera has a manual one; no report when it has not (its
/// exposure is fixed or automatic: the saturation check of the latency phase still applies).
pub fn range_exposure<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
) -> Result<Ranged> {
    let Some(range) = camera.exposure() else {
        return Ok(Ranged {
            report: None,
            levels: None,
        });
    };
    // Every frame through the clock finder: the latency phase goes on from these frames.
    let mut timed = Timed::new(camera);
    let camera = &mut timed;
    let size = display.size();
    let black = PrjImage::new(size.width, size.height);
    let white = PrjImage::filled(size.width, size.height, [1.0; 3]);
    let mut exposure = range.value;
    let mut steps = 0;
    let mut best = (f64::INFINITY, exposure, 0.0);
    let wait = (SETTLE_FRAMES, MAX_WAIT_FRAMES);
    // The last pair taken, and the exposure it was taken at.
    let mut last: (f64, SettledLevels);
    loop {
        let (black_level, under_black) = settled_level(display, camera, &black, wait)?;
        let (white_level, under_white) = settled_level(display, camera, &white, wait)?;
        let level = bright_level(&under_black, &under_white);
        // Nothing lit: leave the exposure to the latency phase, which says what is wrong.
        let Some(level) = level else {
            camera.set_exposure(range.value)?;
            return Ok(Ranged {
                report: None,
                levels: None,
            });
        };
        let miss = (level - TARGET).abs();
        if miss < best.0 {
            best = (miss, exposure, level);
        }
        last = (
            exposure,
            SettledLevels {
                black_level,
                under_black,
                white_level,
                under_white,
                frames: Default::default(),
            },
        );
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
    // The last pair serves the latency phase only when it was taken at the exposure kept (the
    // camera may be set to an earlier, better one).
    let levels = (last.0 == best.1).then_some(last.1);
    let chosen = camera.set_exposure(best.1)?;
    let levels = levels.map(|l| SettledLevels {
        frames: timed.into_finder(),
        ..l
    });
    Ok(Ranged {
        report: Some(ExposureReport {
            initial: range.value,
            chosen,
            bright_level: best.2,
            steps,
        }),
        levels: levels.filter(|_| chosen == best.1),
    })
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

#[cfg(test)]
mod tests {
    use std::cell::RefCell;
    use std::rc::Rc;
    use std::time::{Duration, Instant};

    use super::*;
    use crate::calibrate::sync::{SyncSettings, measure_latency};
    use crate::device::{ExposureRange, Frame};
    use crate::raster::ImageSize;

    /// A projector and a camera that sees its light `DELAY` exposures after the show, frames
    /// stamped on the wall clock (a grab takes 6 ms): the sensor signal is 0.02 of ambient light
    /// plus 0.07 × exposure × the shown level, encoded by `s^(1/2.2)` and clipped at 1.
    struct Bench {
        seq: u64,
        shown: Vec<(u64, f32)>,
        exposure: f64,
        start: Instant,
    }
    const DELAY: u64 = 2;
    struct Projector(Rc<RefCell<Bench>>);
    struct Camera(Rc<RefCell<Bench>>);

    fn bench() -> (Rc<RefCell<Bench>>, Projector, Camera) {
        let b = Rc::new(RefCell::new(Bench {
            seq: 0,
            shown: Vec::new(),
            exposure: 1.0,
            start: Instant::now(),
        }));
        (b.clone(), Projector(b.clone()), Camera(b))
    }

    impl DisplaySink for Projector {
        fn size(&self) -> ImageSize {
            ImageSize::new(8, 6)
        }
        fn show(&mut self, frame: &PrjImage) -> Result<()> {
            let mut b = self.0.borrow_mut();
            let seq = b.seq;
            b.shown.push((seq, frame.data()[0]));
            Ok(())
        }
    }

    impl FrameSource for Camera {
        fn size(&self) -> ImageSize {
            ImageSize::new(16, 12)
        }
        fn grab(&mut self) -> Result<Frame> {
            std::thread::sleep(Duration::from_millis(6));
            let mut b = self.0.borrow_mut();
            b.seq += 1;
            let seq = b.seq;
            let level = b
                .shown
                .iter()
                .rev()
                .find(|(at, _)| at + DELAY <= seq)
                .map_or(0.0, |s| s.1);
            let signal = 0.02 + 0.07 * b.exposure as f32 * level;
            Ok(Frame {
                image: CamImage::filled(16, 12, [signal.powf(1.0 / 2.2).min(1.0); 3]),
                seq,
                timestamp: b.start.elapsed(),
            })
        }
        fn exposure(&self) -> Option<ExposureRange> {
            Some(ExposureRange {
                value: self.0.borrow().exposure,
                min: 0.01,
                max: 100.0,
            })
        }
        fn set_exposure(&mut self, value: f64) -> Result<f64> {
            let v = value.clamp(0.01, 100.0);
            self.0.borrow_mut().exposure = v;
            Ok(v)
        }
    }

    /// The ranging reaches the target and hands its last levels, taken at the exposure it
    /// chose, with the camera's clock already found; the latency phase that starts from them
    /// measures what it measures from its own levels, in at least two settled levels' worth
    /// of frames fewer.
    #[test]
    fn the_latency_phase_goes_on_from_the_rangings_last_levels() {
        let settings = SyncSettings::default();
        let mut runs = Vec::new();
        for reuse in [true, false] {
            let (b, mut projector, mut camera) = bench();
            let ranged = range_exposure(&mut projector, &mut camera).expect("ranged");
            let report = ranged.report.expect("a manual exposure");
            assert!(
                (report.bright_level - TARGET).abs() < TOLERANCE,
                "{report:?}"
            );
            assert!(report.steps >= 1, "{report:?}");
            let levels = ranged.levels.expect("the last pair at the exposure chosen");
            assert!(
                levels.frames.clock().is_some(),
                "the clock from the ranging"
            );
            assert!(levels.white_level - levels.black_level > 0.5);
            let before = b.borrow().seq;
            let (latency, clock) = measure_latency(
                &mut projector,
                &mut camera,
                &settings,
                reuse.then_some(levels),
            )
            .expect("measured");
            // (A fresh start sees too few frames here, 6 ms apart, to find the clock.)
            assert!(clock.is_some() || !reuse);
            runs.push((latency, b.borrow().seq - before));
        }
        let ((reused, fewer), (fresh, more)) = (&runs[0], &runs[1]);
        assert_eq!(reused.trials, fresh.trials);
        assert!((reused.white_level - fresh.white_level).abs() < 0.01);
        assert!((reused.black_level - fresh.black_level).abs() < 0.01);
        assert!(
            *more >= fewer + 2 * SETTLE_FRAMES,
            "{fewer} frames against {more}"
        );
    }
}
