//! The camera's clock against this machine's, so that frames exposed before a show are told
//! apart from frames exposed after it even when they waited in the camera's buffers: a camera
//! keeps streaming while nobody reads it, and the reader then gets the oldest frames first, with
//! sequence numbers that say nothing about when the show happened.
//!
//! A frame's timestamp is the start of its exposure on the camera's clock, and the frame reaches
//! compend a little later. The smallest (arrival − timestamp) over many frames is the clocks'
//! offset plus the shortest delivery time, so timestamp + that offset is never earlier than the
//! real exposure: a frame whose estimate lies before a show was certainly exposed before it.
//! A camera whose clock does not run in real time (the virtual rig's advances one frame period
//! per grab, however long the grab takes) gets no clock, and nothing is skipped.

use std::time::Instant;

use crate::device::{ExposureRange, Frame, FrameSource};
use crate::error::Result;
use crate::raster::ImageSize;

/// Fewest frames, and shortest time in seconds, to tell whether the camera's clock runs in
/// real time.
const MIN_FRAMES: usize = 8;
const MIN_SPAN_S: f64 = 0.1;

/// How far the camera's clock may run from real time (a ratio of elapsed times) and still be
/// taken as real time.
const RATE_RANGE: (f64, f64) = (0.5, 2.0);

/// The camera's clock mapped onto this machine's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraClock {
    base: Instant,
    /// The smallest (arrival − timestamp) seen, seconds, arrival counted from `base`.
    offset: f64,
}

impl CameraClock {
    /// Whether `frame` was certainly exposed before `t` (this machine's clock).
    pub fn exposed_before(&self, frame: &Frame, t: Instant) -> bool {
        let t = t.saturating_duration_since(self.base).as_secs_f64();
        frame.timestamp.as_secs_f64() + self.offset < t
    }

    /// Takes into account `frame`, which arrived at `arrival`.
    pub fn observe(&mut self, frame: &Frame, arrival: Instant) {
        let a = arrival.saturating_duration_since(self.base).as_secs_f64();
        self.offset = self.offset.min(a - frame.timestamp.as_secs_f64());
    }
}

/// A camera whose grabs are timed, to find its clock.
pub struct Timed<'c, C: ?Sized> {
    camera: &'c mut C,
    base: Instant,
    /// (arrival, timestamp) of each frame, seconds.
    samples: Vec<(f64, f64)>,
}

impl<'c, C: FrameSource + ?Sized> Timed<'c, C> {
    pub fn new(camera: &'c mut C) -> Self {
        Self {
            camera,
            base: Instant::now(),
            samples: Vec::new(),
        }
    }

    /// The camera's clock from the frames grabbed so far; None when there were too few or the
    /// camera's clock does not run in real time.
    pub fn clock(&self) -> Option<CameraClock> {
        let (first, last) = (self.samples.first()?, self.samples.last()?);
        let span = last.0 - first.0;
        if self.samples.len() < MIN_FRAMES || span < MIN_SPAN_S {
            return None;
        }
        let rate = (last.1 - first.1) / span;
        if !(RATE_RANGE.0..=RATE_RANGE.1).contains(&rate) {
            return None;
        }
        let offset = self
            .samples
            .iter()
            .map(|(a, t)| a - t)
            .fold(f64::MAX, f64::min);
        Some(CameraClock {
            base: self.base,
            offset,
        })
    }
}

impl<C: FrameSource + ?Sized> FrameSource for Timed<'_, C> {
    fn size(&self) -> ImageSize {
        self.camera.size()
    }

    fn grab(&mut self) -> Result<Frame> {
        let f = self.camera.grab()?;
        let arrival = self.base.elapsed().as_secs_f64();
        self.samples.push((arrival, f.timestamp.as_secs_f64()));
        Ok(f)
    }

    fn exposure(&self) -> Option<ExposureRange> {
        self.camera.exposure()
    }

    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        self.camera.set_exposure(value)
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::raster::CamImage;

    /// A camera whose timestamps advance `step` per grab, each grab taking `takes`.
    struct Stepping {
        k: u64,
        step: Duration,
        takes: Duration,
    }

    impl FrameSource for Stepping {
        fn size(&self) -> ImageSize {
            ImageSize::new(2, 2)
        }
        fn grab(&mut self) -> Result<Frame> {
            std::thread::sleep(self.takes);
            self.k += 1;
            Ok(Frame {
                image: CamImage::new(2, 2),
                seq: self.k,
                timestamp: self.step * self.k as u32,
            })
        }
    }

    #[test]
    fn a_real_time_camera_gets_a_clock_and_a_virtual_one_none() {
        let ms = Duration::from_millis;
        let mut real = Stepping {
            k: 0,
            step: ms(15),
            takes: ms(15),
        };
        let mut timed = Timed::new(&mut real);
        for _ in 0..10 {
            timed.grab().unwrap();
        }
        let clock = timed.clock().expect("a real-time clock");
        // A frame with the last timestamp was exposed before now, and not before 0.1 s ago.
        let last = Frame {
            image: CamImage::new(2, 2),
            seq: 10,
            timestamp: ms(150),
        };
        assert!(clock.exposed_before(&last, Instant::now() + ms(50)));
        assert!(!clock.exposed_before(&last, Instant::now() - ms(100)));

        let mut virtual_rig = Stepping {
            k: 0,
            step: ms(33),
            takes: ms(12),
        };
        let mut timed = Timed::new(&mut virtual_rig);
        for _ in 0..10 {
            timed.grab().unwrap();
        }
        assert_eq!(timed.clock(), None);
    }
}
