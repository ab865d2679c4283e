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
const MIN_FRAMES: usize = 9;
const MIN_SPAN_S: f64 = 0.2;

/// How far the camera's clock may run from real time (its rate, 1 = real time) and still be
/// taken as real time.
const MAX_DRIFT: f64 = 0.2;

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

    /// When `frame`'s exposure began, on this machine's clock: an estimate never earlier than
    /// the real start.
    pub fn exposed_at(&self, frame: &Frame) -> Instant {
        let t = frame.timestamp.as_secs_f64() + self.offset;
        self.base + std::time::Duration::try_from_secs_f64(t).unwrap_or_default()
    }

    /// Takes into account `frame`, which arrived at `arrival`.
    pub fn observe(&mut self, frame: &Frame, arrival: Instant) {
        let a = arrival.saturating_duration_since(self.base).as_secs_f64();
        self.offset = self.offset.min(a - frame.timestamp.as_secs_f64());
    }
}

/// The arrival times and timestamps of frames, to find the camera's clock.
#[derive(Clone, Debug)]
pub struct ClockFinder {
    base: Instant,
    /// (arrival, timestamp) of each frame, seconds.
    samples: Vec<(f64, f64)>,
}

impl Default for ClockFinder {
    fn default() -> Self {
        Self::new()
    }
}

impl ClockFinder {
    pub fn new() -> Self {
        Self {
            base: Instant::now(),
            samples: Vec::new(),
        }
    }

    /// Notes `frame`, which arrived at `arrival`.
    pub fn observe(&mut self, frame: &Frame, arrival: Instant) {
        let a = arrival.saturating_duration_since(self.base).as_secs_f64();
        self.samples.push((a, frame.timestamp.as_secs_f64()));
    }

    /// Frames noted so far.
    pub fn frames(&self) -> usize {
        self.samples.len()
    }

    /// The camera's clock from the frames noted so far; None when there were too few or the
    /// camera's clock does not run in real time.
    ///
    /// The rate is judged by the smallest (arrival − timestamp) of the first and of the last
    /// third of the frames, which frames that waited in buffers do not disturb: for a clock
    /// running at rate r it changes by (r − 1) times the time between them.
    pub fn clock(&self) -> Option<CameraClock> {
        let n = self.samples.len();
        let (first, last) = (self.samples.first()?, self.samples.last()?);
        let span = last.0 - first.0;
        if n < MIN_FRAMES || span < MIN_SPAN_S {
            return None;
        }
        let least = |s: &[(f64, f64)]| s.iter().map(|(a, t)| a - t).fold(f64::MAX, f64::min);
        let (early, late) = (
            least(&self.samples[..n / 3]),
            least(&self.samples[n - n / 3..]),
        );
        if (early - late).abs() > MAX_DRIFT * span {
            return None;
        }
        Some(CameraClock {
            base: self.base,
            offset: least(&self.samples),
        })
    }
}

/// Most frames [`learn`] grabs: a second at 30 fps.
pub const LEARN_FRAMES: usize = 30;

/// The camera's clock learned afresh from its frames, where no measurement mapped it lately
/// (a check long after the calibration): frames are grabbed until the clock is known, at most
/// [`LEARN_FRAMES`]; `None` for a camera whose clock does not run in real time. The clock keeps
/// refining itself from the frames of the captures that use it ([`CameraClock::observe`]).
pub fn learn<C: FrameSource + ?Sized>(camera: &mut C) -> Result<Option<CameraClock>> {
    let mut timed = Timed::new(camera);
    for _ in 0..LEARN_FRAMES {
        timed.grab()?;
        if let Some(clock) = timed.clock() {
            return Ok(Some(clock));
        }
    }
    Ok(None)
}

/// A camera whose grabs are timed, to find its clock.
pub struct Timed<'c, C: ?Sized> {
    camera: &'c mut C,
    finder: ClockFinder,
}

impl<'c, C: FrameSource + ?Sized> Timed<'c, C> {
    pub fn new(camera: &'c mut C) -> Self {
        Self {
            camera,
            finder: ClockFinder::new(),
        }
    }

    /// Goes on from the frames another `Timed` saw of the same camera ([`Timed::into_finder`]),
    /// so that the clock found there is known from the first grab.
    pub fn resume(camera: &'c mut C, finder: ClockFinder) -> Self {
        Self { camera, finder }
    }

    /// The camera's clock from the frames grabbed so far ([`ClockFinder::clock`]).
    pub fn clock(&self) -> Option<CameraClock> {
        self.finder.clock()
    }

    /// The frames seen, for a [`Timed::resume`] of the same camera.
    pub fn into_finder(self) -> ClockFinder {
        self.finder
    }
}

impl<C: FrameSource + ?Sized> FrameSource for Timed<'_, C> {
    fn size(&self) -> ImageSize {
        self.camera.size()
    }

    fn grab(&mut self) -> Result<Frame> {
        let f = self.camera.grab()?;
        self.finder.observe(&f, Instant::now());
        Ok(f)
    }

    fn exposure(&self) -> Option<ExposureRange> {
        self.camera.exposure()
    }

    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        self.camera.set_exposure(value)
    }

    fn reconnect(&mut self) -> Result<bool> {
        self.camera.reconnect()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::raster::CamImage;

    /// A camera whose timestamps advance `step` per grab, each grab taking `takes`, except the
    /// first `burst`, which waited in buffers and come at once.
    struct Stepping {
        k: u64,
        step: Duration,
        takes: Duration,
        burst: u64,
    }

    impl FrameSource for Stepping {
        fn size(&self) -> ImageSize {
            ImageSize::new(2, 2)
        }
        fn grab(&mut self) -> Result<Frame> {
            if self.k >= self.burst {
                std::thread::sleep(self.takes);
            }
            self.k += 1;
            Ok(Frame {
                image: CamImage::new(2, 2),
                seq: self.k,
                timestamp: self.step * self.k as u32,
            })
        }
    }

    fn timed_frames(camera: &mut Stepping, n: usize) -> Option<CameraClock> {
        let mut timed = Timed::new(camera);
        for _ in 0..n {
            timed.grab().unwrap();
        }
        timed.clock()
    }

    #[test]
    fn a_real_time_camera_gets_a_clock_and_a_virtual_one_none() {
        let ms = Duration::from_millis;
        // 4 buffered frames, then one every 15 ms on a real-time clock.
        let mut real = Stepping {
            k: 0,
            step: ms(15),
            takes: ms(15),
            burst: 4,
        };
        let start = Instant::now();
        let clock = timed_frames(&mut real, 24).expect("a real-time clock");
        let end = Instant::now();
        let frame = |k: u32| Frame {
            image: CamImage::new(2, 2),
            seq: u64::from(k),
            timestamp: ms(15) * k,
        };
        // The last frame came in at `end`; the buffered ones were exposed before `start`.
        // Frames 5 to 24 each waited at least 15 ms after `start`, so the 24th cannot have
        // been exposed before `start` + 300 ms whatever the scheduler added (on a loaded
        // machine `end` may come well after that).
        assert!(clock.exposed_before(&frame(24), end + ms(10)));
        assert!(!clock.exposed_before(&frame(24), start + ms(280)));
        assert!(clock.exposed_before(&frame(2), start));

        // The virtual rig's clock: a frame period per grab, whatever the grab takes.
        let mut virtual_rig = Stepping {
            k: 0,
            step: ms(33),
            takes: ms(12),
            burst: 0,
        };
        assert_eq!(timed_frames(&mut virtual_rig, 24), None);
        let mut slow_virtual_rig = Stepping {
            takes: ms(50),
            ..virtual_rig
        };
        assert_eq!(timed_frames(&mut slow_virtual_rig, 12), None);
    }

    #[test]
    fn a_clock_learned_afresh_stops_once_known_and_is_none_for_a_virtual_camera() {
        let ms = Duration::from_millis;
        // 4 frames exposed before the first grab, waiting in buffers, then one every 30 ms
        // (at least: a loaded machine wakes the sleeper late), each stamped with the time it
        // really began, as a camera's clock does: known after about 0.2 s of frames, well
        // before LEARN_FRAMES.
        struct RealTime {
            start: Instant,
            k: u64,
        }
        impl FrameSource for RealTime {
            fn size(&self) -> ImageSize {
                ImageSize::new(2, 2)
            }
            fn grab(&mut self) -> Result<Frame> {
                const BUFFERED: u64 = 4;
                let timestamp = if self.k < BUFFERED {
                    Duration::from_secs(1) - Duration::from_millis(30 * (BUFFERED - self.k))
                } else {
                    std::thread::sleep(Duration::from_millis(30));
                    Duration::from_secs(1) + self.start.elapsed()
                };
                self.k += 1;
                Ok(Frame {
                    image: CamImage::new(2, 2),
                    seq: self.k,
                    timestamp,
                })
            }
        }
        let mut real = RealTime {
            start: Instant::now(),
            k: 0,
        };
        let clock = learn(&mut real).expect("grabs").expect("a real-time clock");
        assert!(real.k < LEARN_FRAMES as u64, "grabbed {}", real.k);
        let buffered = Frame {
            image: CamImage::new(2, 2),
            seq: 1,
            timestamp: ms(1000 - 120),
        };
        assert!(clock.exposed_before(&buffered, real.start));
        let next = Frame {
            timestamp: ms(1000) + real.start.elapsed() + ms(30),
            ..buffered
        };
        assert!(!clock.exposed_before(&next, Instant::now()));
        // A frame period per grab whatever the grab takes: no clock, after LEARN_FRAMES.
        let mut virtual_rig = Stepping {
            k: 0,
            step: ms(33),
            takes: ms(1),
            burst: 0,
        };
        assert_eq!(learn(&mut virtual_rig).expect("grabs"), None);
        assert_eq!(virtual_rig.k, LEARN_FRAMES as u64);
    }
}
