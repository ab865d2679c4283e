//! Device traits: the two ends of a projector-camera system as seen by calibration, training,
//! playback and monitoring. Real hardware (the projector window, a V4L2 camera), a recorded
//! dataset and the virtual rig ([`crate::rig`]) all implement them, so the code above runs
//! unchanged on any of them.
//!
//! The traits are deliberately small and object-safe (`&mut dyn DisplaySink`,
//! `Box<dyn FrameSource>`). They say nothing about timing beyond what a camera reports: a
//! sequence number (consecutive frames differ by one; a gap means frames were dropped) and an
//! exposure timestamp. Synchronising a capture with what is shown (latency, drops) is the job of
//! the capture protocol built on top, not of the devices.

use std::time::Duration;

use crate::error::Result;
use crate::raster::{CamImage, ImageSize, PrjImage};

/// Something that shows projector-space frames: the projector window, or the virtual rig's
/// projector.
pub trait DisplaySink {
    /// (width, height) of the projector frame in projector pixels.
    fn size(&self) -> ImageSize;

    /// Shows `frame` from now on, replacing what was shown. The frame must be exactly
    /// [`DisplaySink::size`]; a different size is an error ([`crate::Error::Size`] or
    /// [`crate::Error::Shape`]). The previous frame may stay visible to a camera for a while
    /// (display and capture latency).
    fn show(&mut self, frame: &PrjImage) -> Result<()>;
}

/// One camera frame with the metadata a camera driver reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// The image, camera space, f32 in \[0,1\] (8-bit levels for real and simulated cameras).
    pub image: CamImage,
    /// Device sequence number. It increases by one per exposure; a jump of more than one
    /// means the frames in between were dropped.
    pub seq: u64,
    /// Start of the exposure on the device's clock (monotonic, arbitrary origin).
    pub timestamp: Duration,
}

/// Something that delivers camera frames: a camera, the virtual rig's camera, a recording.
pub trait FrameSource {
    /// (width, height) of the frames in camera pixels.
    fn size(&self) -> ImageSize;

    /// Waits for the next frame the device delivers and returns it. Frames come in order;
    /// a frame may have been exposed before the latest [`DisplaySink::show`] (latency).
    fn grab(&mut self) -> Result<Frame>;

    /// The manual exposure, when the camera lets it be set: its value and range in the
    /// camera's own units (100 µs for V4L2's absolute exposure; a factor of the scene's
    /// exposure for the virtual camera). `None`: fixed or automatic only.
    fn exposure(&self) -> Option<ExposureRange> {
        None
    }

    /// Sets the manual exposure (clamped to the range); returns the value the camera
    /// accepted. Frames exposed after the call use it.
    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        Err(crate::Error::Input(format!(
            "this camera has no manual exposure (asked for {value})"
        )))
    }

    /// After a [`FrameSource::grab`] failed: when the device went away (unplugged, a USB
    /// reset), opens it again with the same format and controls, retrying for a while.
    /// `Ok(true)`: frames flow again; `Ok(false)`: the device did not go away or cannot be
    /// reopened by this source, so the grab's error stands; `Err`: every reopen failed.
    fn reconnect(&mut self) -> Result<bool> {
        Ok(false)
    }
}

/// A camera's manual exposure: the current value and the range, in the camera's units.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExposureRange {
    pub value: f64,
    pub min: f64,
    pub max: f64,
}

impl<T: DisplaySink + ?Sized> DisplaySink for &mut T {
    fn size(&self) -> ImageSize {
        (**self).size()
    }
    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        (**self).show(frame)
    }
}

impl<T: FrameSource + ?Sized> FrameSource for &mut T {
    fn size(&self) -> ImageSize {
        (**self).size()
    }
    fn grab(&mut self) -> Result<Frame> {
        (**self).grab()
    }
    fn exposure(&self) -> Option<ExposureRange> {
        (**self).exposure()
    }
    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        (**self).set_exposure(value)
    }
    fn reconnect(&mut self) -> Result<bool> {
        (**self).reconnect()
    }
}

impl<T: DisplaySink + ?Sized> DisplaySink for Box<T> {
    fn size(&self) -> ImageSize {
        (**self).size()
    }
    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        (**self).show(frame)
    }
}

impl<T: FrameSource + ?Sized> FrameSource for Box<T> {
    fn size(&self) -> ImageSize {
        (**self).size()
    }
    fn grab(&mut self) -> Result<Frame> {
        (**self).grab()
    }
    fn exposure(&self) -> Option<ExposureRange> {
        (**self).exposure()
    }
    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        (**self).set_exposure(value)
    }
    fn reconnect(&mut self) -> Result<bool> {
        (**self).reconnect()
    }
}

/// Several displays shown as one (a set of projectors, each its own display): a frame of
/// [`SideBySide::size`] holds their frames left to right, top-aligned, in order; showing it
/// shows each its part. What calibrates and verifies one display (the capture protocol, the
/// exposure and latency phases) then drives them all at once, and a uniform frame (black,
/// white) is uniform on every one.
pub struct SideBySide<D> {
    displays: Vec<D>,
}

impl<D: DisplaySink> SideBySide<D> {
    /// An error where `displays` is empty.
    pub fn new(displays: Vec<D>) -> Result<Self> {
        if displays.is_empty() {
            return Err(crate::Error::Input(
                "a set of displays needs at least one".into(),
            ));
        }
        Ok(SideBySide { displays })
    }

    pub fn displays(&mut self) -> &mut [D] {
        &mut self.displays
    }

    pub fn into_displays(self) -> Vec<D> {
        self.displays
    }

    /// Where display `k`'s frame sits in the whole frame.
    pub fn part(&self, k: usize) -> Option<crate::raster::Rect> {
        let size = self.displays.get(k)?.size();
        let x = self.displays[..k].iter().map(|d| d.size().width).sum();
        Some(crate::raster::Rect {
            x,
            y: 0,
            width: size.width,
            height: size.height,
        })
    }

    /// The whole frame showing `frames` (one per display, each its display's size); what the
    /// whole frame holds beyond them is black.
    pub fn join(&self, frames: &[PrjImage]) -> Result<PrjImage> {
        if frames.len() != self.displays.len() {
            return Err(crate::Error::Shape(format!(
                "{} frames for {} displays",
                frames.len(),
                self.displays.len()
            )));
        }
        for (k, (d, f)) in self.displays.iter().zip(frames).enumerate() {
            if f.size() != d.size() {
                return Err(crate::Error::Shape(format!(
                    "display {} is {}, its frame is {}",
                    k + 1,
                    d.size(),
                    f.size()
                )));
            }
        }
        Ok(side_by_side(frames))
    }
}

/// Frames left to right, top-aligned, in one frame as tall as the tallest (black below the
/// shorter ones): the whole frame of a [`SideBySide`] of displays of the frames' sizes.
pub fn side_by_side(frames: &[PrjImage]) -> PrjImage {
    let width = frames.iter().map(|f| f.width()).sum();
    let height = frames.iter().map(|f| f.height()).max().unwrap_or(0);
    let mut out = PrjImage::new(width, height);
    let mut x0 = 0;
    for f in frames {
        for y in 0..f.height() {
            for x in 0..f.width() {
                out.set(x0 + x, y, f.get(x, y));
            }
        }
        x0 += f.width();
    }
    out
}

impl<D: DisplaySink> DisplaySink for SideBySide<D> {
    fn size(&self) -> ImageSize {
        let width = self.displays.iter().map(|d| d.size().width).sum();
        let height = self.displays.iter().map(|d| d.size().height).max();
        ImageSize::new(width, height.unwrap_or(0))
    }

    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        let whole = self.size();
        if frame.size() != whole {
            return Err(crate::Error::Shape(format!(
                "a set of displays side by side is {whole}, got a {} frame",
                frame.size()
            )));
        }
        for k in 0..self.displays.len() {
            let part = self
                .part(k)
                .ok_or_else(|| crate::Error::Failed(format!("no display {} in the set", k + 1)))?;
            let own = frame.crop(part)?;
            self.displays[k].show(&own)?;
        }
        Ok(())
    }
}

/// A camera whose exposure stays where it is: it reports no manual exposure, so a calibration
/// leaves it alone (each projector of a set calibrated at the exposure ranged for the set).
pub struct HeldExposure<C>(pub C);

impl<C: FrameSource> FrameSource for HeldExposure<C> {
    fn size(&self) -> ImageSize {
        self.0.size()
    }
    fn grab(&mut self) -> Result<Frame> {
        self.0.grab()
    }
    fn reconnect(&mut self) -> Result<bool> {
        self.0.reconnect()
    }
}
