//! Synchronised capture (docs/architecture.md, "Data flow"): show a projector frame and capture
//! only camera frames exposed after it was really on the surface.
//!
//! Time is counted in camera exposures, by the frames' sequence numbers, so dropped frames do
//! not shorten the wait. After [`DisplaySink::show`], the first frame grabbed has sequence
//! number `s1`; frames up to `s1 + settle` may still show the previous image, where `settle` is
//! the worst projector-to-camera latency measured at the start ([`measure_latency`]) plus a
//! margin. A capture averages a few frames after that against noise, and is retaken when those
//! frames disagree (the image changed while they were taken) or when it does not differ from
//! the previous capture (the new pattern was not on the surface yet).
//!
//! Frames that waited in the camera's buffers (the reader paused, e.g. to write captures or to
//! train) were exposed before the show whatever their sequence numbers: when the camera's clock
//! runs in real time, the latency measurement maps it onto this machine's
//! ([`super::clock::CameraClock`]) and each capture first skips the frames exposed before its
//! show.

use std::time::Instant;

use super::clock::{CameraClock, ClockFinder, Timed};
use crate::device::{DisplaySink, FrameSource};
use crate::error::{Error, Result};
use crate::raster::{CamImage, ImageSize, PrjImage};
use crate::record::{CaptureFloor, Latency};

/// Most frames skipped as exposed before a show: more than a camera's capture buffers (4 for
/// compend's V4L2 camera).
const MAX_STALE_FRAMES: u64 = 16;

/// How captures are synchronised and averaged.
#[derive(Clone, Copy, Debug)]
pub struct SyncSettings {
    /// Black/white alternations for the latency measurement.
    pub latency_trials: usize,
    /// Exposures added to the worst measured latency before the first capture. 0 by default:
    /// a capture waits the measured latency and no more; when retakes (the frames disagreed,
    /// or the capture did not change with the pattern) become frequent, every later capture
    /// waits a frame more ([`Capturer::settle`]).
    pub margin_frames: u64,
    /// Frames averaged per capture.
    pub average: usize,
    /// Retakes of a capture that fails its checks before giving up.
    pub retakes: usize,
    /// Most exposures to wait for a change during the latency measurement.
    pub max_wait_frames: u64,
}

impl Default for SyncSettings {
    fn default() -> Self {
        Self {
            latency_trials: 4,
            margin_frames: 0,
            average: 3,
            retakes: 3,
            max_wait_frames: 120,
        }
    }
}

/// Mean of all values of a camera image (encoded units).
fn mean_level(img: &CamImage) -> f64 {
    let d = img.data();
    d.iter().map(|&v| v as f64).sum::<f64>() / d.len().max(1) as f64
}

/// Mean absolute difference of two camera images' block means (8×8-pixel blocks, encoded
/// units): a change of the projected pattern moves block means, sensor noise mostly averages
/// out of them.
fn block_diff(a: &CamImage, b: &CamImage) -> f64 {
    let (w, h) = ((a.width() / 8).max(1), (a.height() / 8).max(1));
    mean_abs_diff(
        &crate::resize::resize_area(a, w, h),
        &crate::resize::resize_area(b, w, h),
    )
}

/// Mean absolute difference of two camera images (encoded units).
fn mean_abs_diff(a: &CamImage, b: &CamImage) -> f64 {
    let (x, y) = (a.data(), b.data());
    x.iter()
        .zip(y)
        .map(|(&p, &q)| (p - q).abs() as f64)
        .sum::<f64>()
        / x.len().max(1) as f64
}

/// Exposures after a show before [`settled_level`] may take a level: past the delay of most
/// rigs (8 exposures: 267 ms at 30 fps); [`measure_latency`] waits longer when it was not.
pub(super) const SETTLE_FRAMES: u64 = 8;

/// How much brighter than under black the camera's mean level must be under white (encoded
/// units) for a pair of levels to show the projector's switch.
const SWITCH_SEEN: f64 = 0.02;

/// The camera's mean levels (encoded units) and a frame under the projector's black and under
/// its white, each settled ([`settled_level`]): how [`measure_latency`] starts, and what
/// exposure ranging ends with when its last pair was taken at the exposure it chose.
#[derive(Clone, Debug)]
pub struct SettledLevels {
    pub black_level: f64,
    pub under_black: CamImage,
    pub white_level: f64,
    pub under_white: CamImage,
    /// The frames the camera delivered while they were taken (arrival times and timestamps),
    /// so that the camera's clock is known from the next grab on.
    pub frames: ClockFinder,
}

/// Measures the projector-to-camera latency by alternating black and white frames and counting
/// the exposures until the camera's mean level crosses half-way. An error when the camera does
/// not see the projector change (no light reaches it, or it does not look at the surface).
///
/// `known`: levels just taken at the camera's present exposure with white showing last (exposure
/// ranging's last pair), used instead of settling on black and white again when they show the
/// projector's switch.
pub fn measure_latency<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    settings: &SyncSettings,
    known: Option<SettledLevels>,
) -> Result<(Latency, Option<CameraClock>)> {
    let mut known = known.filter(|k| k.white_level - k.black_level >= SWITCH_SEEN);
    let camera = &mut match &mut known {
        Some(k) => Timed::resume(camera, std::mem::take(&mut k.frames)),
        None => Timed::new(camera),
    };
    let size = display.size();
    let black = PrjImage::new(size.width, size.height);
    let white = PrjImage::filled(size.width, size.height, [1.0; 3]);
    // Levels: settle on black, then on white. A level taken before the switch reached the
    // camera reads the frame before it (black as bright as white, or brighter): then both are
    // taken again, each waiting three times as long before it may settle, at most twice (a
    // camera that does not see the projector is told so after 2 × (8 + 24 + 72) exposures,
    // about 7 s at 30 fps, where one try took about 0.5 s).
    let mut at_least = SETTLE_FRAMES;
    if known.is_some() {
        tracing::debug!("latency: the exposure ranging's last black and white levels taken");
    }
    let (black_level, under_black, white_level, under_white) = loop {
        if let Some(k) = known.take() {
            break (k.black_level, k.under_black, k.white_level, k.under_white);
        }
        let (black_level, under_black) = settled_level(
            display,
            camera,
            &black,
            (at_least, settings.max_wait_frames),
        )?;
        let (white_level, under_white) = settled_level(
            display,
            camera,
            &white,
            (at_least, settings.max_wait_frames),
        )?;
        if white_level - black_level >= SWITCH_SEEN || at_least >= SETTLE_FRAMES * 9 {
            break (black_level, under_black, white_level, under_white);
        }
        tracing::info!(
            "latency: black read {black_level:.3} and white {white_level:.3} after {at_least} \
             exposures; waiting longer in case the switch had not reached the camera"
        );
        at_least = (at_least * 3).min(settings.max_wait_frames);
    };
    check_exposure(black_level, white_level, &under_black, &under_white)?;
    let half = 0.5 * (black_level + white_level);
    let mut trials = Vec::with_capacity(settings.latency_trials);
    for t in 0..settings.latency_trials {
        // Alternate: white is showing, so the first trial switches to black.
        let (frame, rising) = if t % 2 == 0 {
            (&black, false)
        } else {
            (&white, true)
        };
        // Counted as a capture waits (`Capturer::capture_once`): from the first frame not
        // certainly exposed before the show. Frames that waited in the camera's buffers while
        // this machine was busy (writing the patterns, a fit beside it) would add the
        // reader's lag to the latency, and every capture would then wait that much longer
        // after skipping such frames itself.
        let clock = camera.clock();
        let shown_at = Instant::now();
        display.show(frame)?;
        let mut first = camera.grab()?;
        let mut stale = 0;
        while stale < MAX_STALE_FRAMES && clock.is_some_and(|c| c.exposed_before(&first, shown_at))
        {
            first = camera.grab()?;
            stale += 1;
        }
        let mut f = first.clone();
        loop {
            let level = mean_level(&f.image);
            if (rising && level > half) || (!rising && level < half) {
                break;
            }
            if f.seq - first.seq >= settings.max_wait_frames {
                return Err(Error::Failed(format!(
                    "the camera did not see the projector switch within {} frames; is the \
                     projector on and the camera pointed at it?",
                    settings.max_wait_frames
                )));
            }
            f = camera.grab()?;
        }
        tracing::debug!(
            "latency trial {t}: {stale} stale frames skipped (clock {}), change after {} \
             exposures",
            if clock.is_some() { "found" } else { "none" },
            f.seq - first.seq
        );
        trials.push(f.seq - first.seq);
    }
    let worst = trials.iter().copied().max().unwrap_or(0);
    let latency = Latency {
        trials,
        settle_frames: worst + settings.margin_frames,
        black_level,
        white_level,
    };
    Ok((latency, camera.clock()))
}

/// Whether the camera sees the projector well enough to calibrate, from its mean levels and a
/// frame under black and under white (encoded units): an input error saying what to change when
/// it does not see the projector at all, when the projector is too dim against ambient light,
/// or when the projector drives the camera into saturation.
fn check_exposure(
    black_level: f64,
    white_level: f64,
    under_black: &CamImage,
    under_white: &CamImage,
) -> Result<()> {
    let contrast = white_level - black_level;
    if contrast < SWITCH_SEEN {
        return Err(Error::Input(format!(
            "the camera does not see the projector: its mean level is {black_level:.3} under \
             black and {white_level:.3} under white (encoded units); point the camera at the \
             projected area, open its aperture or dim the room"
        )));
    }
    if contrast < 0.08 && black_level > 0.25 {
        return Err(Error::Input(format!(
            "the projector is too dim against the ambient light: the camera's mean level is \
             {black_level:.3} under black and only {white_level:.3} under white; dim the room \
             or raise the projector's brightness"
        )));
    }
    // Pixels the projector drives to full scale (not already there under black).
    let full = 254.5 / 255.0;
    let (mut lit, mut clipped) = (0usize, 0usize);
    for (w, b) in under_white
        .data()
        .chunks_exact(3)
        .zip(under_black.data().chunks_exact(3))
    {
        let rise = (0..3).map(|c| w[c] - b[c]).fold(f32::MIN, f32::max);
        if rise > 0.05 {
            lit += 1;
            if (0..3).any(|c| w[c] >= full && b[c] < full) {
                clipped += 1;
            }
        }
    }
    if lit > 0 && clipped * 10 > lit {
        return Err(Error::Input(format!(
            "the camera saturates under the projector's white: {:.0} % of the lit pixels are at \
             full scale; lower the camera's exposure or gain (or the projector's brightness)",
            100.0 * clipped as f64 / lit as f64
        )));
    }
    Ok(())
}

/// Shows `frame` and waits until the camera's mean level stops changing (steady for 4
/// exposures, and at least `at_least` exposures after the show, at most `max_wait`); returns it
/// and the last frame.
pub(super) fn settled_level<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    frame: &PrjImage,
    (at_least, max_wait): (u64, u64),
) -> Result<(f64, CamImage)> {
    display.show(frame)?;
    let first = camera.grab()?;
    let mut last = mean_level(&first.image);
    let mut still = 0;
    loop {
        let f = camera.grab()?;
        let level = mean_level(&f.image);
        still = if (level - last).abs() < 0.002 {
            still + 1
        } else {
            0
        };
        last = level;
        // Steady for 4 exposures and past `at_least` exposures after the show.
        if (still >= 4 && f.seq - first.seq >= at_least) || f.seq - first.seq >= max_wait {
            return Ok((level, f.image));
        }
    }
}

/// Captures through a display and a camera, synchronised by the measured latency.
pub struct Capturer<'a, D: ?Sized, C: ?Sized> {
    display: &'a mut D,
    camera: &'a mut C,
    settings: SyncSettings,
    settle: u64,
    clock: Option<CameraClock>,
    previous: Option<CamImage>,
    /// Block-mean noise of the last capture's averaged frames (encoded units).
    noise: f64,
    /// The worst measured latency, exposures: the floor's wait.
    latency_frames: u64,
    /// What the captures took against their floor.
    pub floor: CaptureFloor,
    /// First and last frame seen: (sequence number, timestamp in seconds), for the camera's
    /// measured rate ([`CaptureFloor::fps`]).
    span: Option<((u64, f64), (u64, f64))>,
    /// Captures retaken because a check failed.
    pub retakes: usize,
    /// Times the camera went away during a capture and was opened again (the capture was
    /// then taken again from the start).
    pub reconnects: usize,
}

/// Most reconnects of the camera in one calibration's captures: a camera that keeps going away
/// (a bad cable, a hub short of power) fails the calibration instead of stretching it forever.
pub const MAX_RECONNECTS: usize = 3;

impl<'a, D: DisplaySink + ?Sized, C: FrameSource + ?Sized> Capturer<'a, D, C> {
    pub fn new(
        display: &'a mut D,
        camera: &'a mut C,
        latency: &Latency,
        settings: SyncSettings,
    ) -> Self {
        Self {
            display,
            camera,
            settings,
            settle: latency.settle_frames,
            clock: None,
            previous: None,
            noise: 0.0,
            latency_frames: latency.trials.iter().copied().max().unwrap_or(0),
            floor: CaptureFloor::default(),
            span: None,
            retakes: 0,
            reconnects: 0,
        }
    }

    /// Captures that first skip the frames the camera exposed before each show, by its clock
    /// as the latency measurement mapped it onto this machine's ([`measure_latency`]); `None`
    /// (a latency taken from a record, a camera without a real-time clock): by sequence
    /// numbers alone.
    pub fn with_clock(mut self, clock: Option<CameraClock>) -> Self {
        self.clock = clock;
        self
    }

    /// The projector size frames must have.
    pub fn projector_size(&self) -> ImageSize {
        self.display.size()
    }

    /// Exposures each capture now skips after its show: the measured latency plus the
    /// margin, plus one each time retakes passed one capture in twenty. Write it back into the
    /// [`Latency`] a later capturer starts from.
    pub fn settle(&self) -> u64 {
        self.settle
    }

    /// Whether the camera can tell a capture of `b` from one of `a` (two views it is to see,
    /// camera pixels, encoded units) by their block means, with room to spare over the check
    /// each capture passes: when not, show something plainly different between them.
    pub fn tells_apart(&self, a: &CamImage, b: &CamImage) -> bool {
        a.size() == b.size() && block_diff(a, b) > 3.0 * self.change_threshold()
    }

    /// The least block-mean change from the previous capture that counts as a new picture.
    fn change_threshold(&self) -> f64 {
        (3.0 * self.noise).max(0.004)
    }

    /// The camera's next frame, its arrival refining the camera's clock.
    fn grab(&mut self) -> Result<crate::device::Frame> {
        let f = self.camera.grab()?;
        if let Some(c) = &mut self.clock {
            c.observe(&f, Instant::now());
        }
        self.observe(&f);
        Ok(f)
    }

    /// The camera's rate from the frames seen so far, into [`Self::floor`].
    fn observe(&mut self, f: &crate::device::Frame) {
        let now = (f.seq, f.timestamp.as_secs_f64());
        let (first, _) = self.span.unwrap_or((now, now));
        self.span = Some((first, now));
        let (frames, secs) = (now.0.saturating_sub(first.0), now.1 - first.1);
        if frames >= 2 && secs > 0.0 {
            self.floor.fps = frames as f64 / secs;
        }
    }

    /// Shows `frame` and returns the average of `average` camera frames exposed after it was
    /// on the surface. `differs`: the frame differs from the previously captured one, so the
    /// capture must differ from the previous capture too. A camera that goes away meanwhile
    /// (unplugged, a USB reset) is opened again and the capture taken again from the start, up
    /// to [`MAX_RECONNECTS`] times in all; then the error is reported.
    pub fn capture(&mut self, frame: &PrjImage, differs: bool) -> Result<CamImage> {
        self.capture_averaging(frame, differs, self.settings.average)
    }

    /// [`Capturer::capture`] of a frame that differs from the previous one, where the two may
    /// look alike to the camera (a model's compensation of an image after the image as it is,
    /// on a projector that lights a small part of the camera's view): when the camera does not
    /// see the change, white is shown and captured once (one frame), and the frame once more.
    pub fn capture_after_change(&mut self, frame: &PrjImage) -> Result<CamImage> {
        match self.capture(frame, true) {
            Err(Error::Input(why)) if self.previous.is_some() => {
                tracing::info!("{why}; white first, once more");
                let ImageSize { width, height } = frame.size();
                self.capture_averaging(&PrjImage::filled(width, height, [1.0; 3]), true, 1)?;
                self.capture(frame, true)
            }
            other => other,
        }
    }

    /// [`Capturer::capture`] averaging `average` frames instead of the settings' (1: a frame
    /// shown only to change the picture, e.g. white between two that look alike).
    pub fn capture_averaging(
        &mut self,
        frame: &PrjImage,
        differs: bool,
        average: usize,
    ) -> Result<CamImage> {
        let average = average.max(1);
        self.floor.captures += 1;
        self.floor.frames += self.latency_frames + average as u64;
        let started = Instant::now();
        let taken = self.capture_retrying(frame, differs, average);
        self.floor.seconds += started.elapsed().as_secs_f64();
        taken
    }

    fn capture_retrying(
        &mut self,
        frame: &PrjImage,
        differs: bool,
        average: usize,
    ) -> Result<CamImage> {
        loop {
            let error = match self.capture_once(frame, differs, average) {
                Ok(image) => return Ok(image),
                Err(e) => e,
            };
            if self.reconnects >= MAX_RECONNECTS {
                return Err(error);
            }
            match self.camera.reconnect() {
                Ok(true) => {
                    self.reconnects += 1;
                    tracing::warn!(
                        "{error}; the camera is back (reconnect {} of at most \
                         {MAX_RECONNECTS}); taking the capture again",
                        self.reconnects
                    );
                }
                Ok(false) => return Err(error),
                Err(again) => {
                    return Err(Error::Failed(format!("{error}; then: {again}")));
                }
            }
        }
    }

    fn capture_once(&mut self, frame: &PrjImage, differs: bool, count: usize) -> Result<CamImage> {
        let mut settle = self.settle;
        for attempt in 0..=self.settings.retakes {
            let shown_at = Instant::now();
            self.display.show(frame)?;
            let mut f = self.grab()?;
            // Frames exposed before the show waited in the camera's buffers: skip them (no more
            // than a camera buffers).
            let mut stale = 0;
            while stale < MAX_STALE_FRAMES
                && self.clock.is_some_and(|c| c.exposed_before(&f, shown_at))
            {
                f = self.grab()?;
                stale += 1;
            }
            // Exposures up to `settle` after the first one may still show the previous frame.
            let counts_from = f.seq + settle;
            while f.seq < counts_from {
                f = self.grab()?;
            }
            let mut frames = vec![f.image];
            while frames.len() < count {
                frames.push(self.grab()?.image);
            }
            // Block-mean disagreement between the first and last averaged frames: noise, or a
            // change of the image while they were exposed.
            let noise = block_diff(&frames[0], &frames[frames.len() - 1]);
            let avg = average(&frames)?;
            let stable = frames.len() < 2 || noise < 0.02;
            tracing::debug!(
                "capture attempt {attempt}: {stale} stale frames skipped, block noise \
                 {noise:.4}, change from the previous capture {:?}, settle {settle}",
                self.previous.as_ref().map(|p| block_diff(p, &avg))
            );
            let threshold = (3.0 * noise).max(0.004);
            let new = !differs
                || self
                    .previous
                    .as_ref()
                    .is_none_or(|p| block_diff(p, &avg) > threshold);
            if stable && new {
                if frames.len() >= 2 {
                    self.noise = noise;
                }
                self.previous = Some(avg.clone());
                return Ok(avg);
            }
            if attempt < self.settings.retakes {
                self.retakes += 1;
                settle += 1 + settle / 2;
                // The measured latency is not enough often enough (a second retake, and more
                // than one capture in 20 retaken): every later capture waits a frame more, at
                // most MAX_STALE_FRAMES more than measured. A lone retake costs one capture; a
                // frame more on every capture costs a fifth of a capture each.
                if self.retakes >= 2
                    && self.retakes * 20 > self.floor.captures
                    && self.settle < self.latency_frames + MAX_STALE_FRAMES
                {
                    self.settle += 1;
                    tracing::info!(
                        "a capture was retaken; waiting {} exposures after each show from now on",
                        self.settle
                    );
                }
            }
        }
        Err(Error::Input(format!(
            "no stable capture of the new pattern after {} retakes (waited up to {settle} \
             frames): the camera keeps changing its picture; lock its exposure, gain and white \
             balance, and check that the projector shows every pattern",
            self.settings.retakes
        )))
    }
}

/// The per-pixel mean of same-sized camera images.
fn average(frames: &[CamImage]) -> Result<CamImage> {
    let first = frames
        .first()
        .ok_or_else(|| Error::Failed("no frame to average".into()))?;
    let n = frames.len() as f32;
    let mut sum = vec![0f32; first.data().len()];
    for f in frames {
        if f.size() != first.size() {
            return Err(Error::Shape(format!(
                "camera frames of {} and {} in one capture",
                first.size(),
                f.size()
            )));
        }
        for (s, &v) in sum.iter_mut().zip(f.data()) {
            *s += v;
        }
    }
    CamImage::from_vec(
        first.width(),
        first.height(),
        sum.into_iter().map(|s| s / n).collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::Frame;
    use std::time::Duration;

    fn flat(v: f32) -> CamImage {
        CamImage::filled(16, 12, [v; 3])
    }

    #[test]
    fn exposure_checks_name_what_to_change() {
        let err = |b: f32, w: f32| {
            check_exposure(b as f64, w as f64, &flat(b), &flat(w)).map_err(|e| e.to_string())
        };
        assert!(
            err(0.10, 0.11)
                .unwrap_err()
                .contains("does not see the projector")
        );
        assert!(err(0.40, 0.45).unwrap_err().contains("too dim"));
        assert!(err(0.05, 1.0).unwrap_err().contains("saturates"));
        assert!(err(0.05, 0.9).is_ok());
    }

    /// A projector and camera whose picture brightens a little with every frame, whatever is
    /// shown: a camera with automatic exposure that never settles.
    struct Drifting {
        seq: u64,
    }

    impl DisplaySink for Drifting {
        fn size(&self) -> ImageSize {
            ImageSize::new(8, 6)
        }
        fn show(&mut self, _: &PrjImage) -> Result<()> {
            Ok(())
        }
    }

    impl FrameSource for Drifting {
        fn size(&self) -> ImageSize {
            ImageSize::new(16, 12)
        }
        fn grab(&mut self) -> Result<Frame> {
            self.seq += 1;
            Ok(Frame {
                image: flat((0.2 + 0.01 * self.seq as f32).min(1.0)),
                seq: self.seq,
                timestamp: Duration::from_millis(33 * self.seq),
            })
        }
    }

    #[test]
    fn a_picture_that_never_settles_is_retaken_then_refused() {
        let (mut d, mut c) = (Drifting { seq: 0 }, Drifting { seq: 0 });
        let latency = Latency {
            trials: vec![1],
            settle_frames: 2,
            black_level: 0.0,
            white_level: 1.0,
        };
        let settings = SyncSettings {
            average: 8,
            ..SyncSettings::default()
        };
        let mut cap = Capturer::new(&mut d, &mut c, &latency, settings);
        let e = cap.capture(&PrjImage::new(8, 6), true).unwrap_err();
        assert!(e.to_string().contains("keeps changing"), "{e}");
        assert_eq!(e.exit_code(), 2);
        assert_eq!(cap.retakes, settings.retakes);
    }
}
