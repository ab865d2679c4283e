//! [`Camera`]: a capture device opened at a path, streaming, as a [`FrameSource`].
//!
//! - Opening negotiates the format ([`super::format::choose_format`]) and learns its colorimetry.
//! - Every grab waits at most the camera's timeout; a corrupt frame (flagged by the driver, cut
//!   short, or an MJPEG that does not decode) is counted ([`Camera::corrupt_frames`]) and
//!   skipped, never returned.
//! - A device that goes away (ENODEV, EIO: unplugged, USB reset) turns the grab into an error
//!   the caller survives: [`Camera::reconnect`] reopens the same path, retrying with backoff,
//!   and applies the same format and the same control lock again.

use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::controls::{self, ControlInfo, Controls, LockReport, LockSettings};
use super::format::{ActiveFormat, FormatChoice, choose_format};
use super::pixels::{self, YCbCr};
use super::{Device, Opener, Sequence};
use crate::device::{ExposureRange, Frame, FrameSource};
use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// How [`Camera::reconnect`] retries: `attempts` opens, the first at once, then waits of
/// `first_delay`, doubling up to `max_delay`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reconnect {
    pub attempts: u32,
    pub first_delay: Duration,
    pub max_delay: Duration,
}

impl Default for Reconnect {
    /// Six tries over about 7.5 s (0, 0.25, 0.5, 1, 2, 4 s apart): long enough for a USB
    /// camera to re-enumerate after a reset.
    fn default() -> Self {
        Self {
            attempts: 6,
            first_delay: Duration::from_millis(250),
            max_delay: Duration::from_secs(4),
        }
    }
}

/// How to open a camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpenOptions {
    /// Frame size (width, height) in camera pixels; `None`: the device's current size.
    pub size: Option<ImageSize>,
    /// Y'CbCr matrix and range to decode with, overriding what the driver reports.
    pub colour: Option<YCbCr>,
    /// How long a grab waits for a good frame.
    pub timeout: Duration,
    pub reconnect: Reconnect,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self {
            size: None,
            colour: None,
            timeout: Duration::from_secs(5),
            reconnect: Reconnect::default(),
        }
    }
}

/// One capture as the device delivered it.
#[derive(Clone, Debug)]
pub struct CapturedFrame {
    /// The image, 8-bit RGBA, camera pixels.
    pub rgba: ContentFrame,
    /// The driver's sequence number, made monotonic over 64 bits (and across reconnects).
    pub seq: u64,
    /// The driver's buffer timestamp (CLOCK_MONOTONIC for UVC; the start of the exposure or the
    /// end of the frame, as the driver reports).
    pub timestamp: Duration,
}

/// A camera: a device at a path, streaming in a negotiated format.
pub struct Camera<O: Opener> {
    opener: O,
    path: PathBuf,
    options: OpenOptions,
    /// `None` after the device went away, until a reconnect succeeds.
    device: Option<O::Device>,
    active: ActiveFormat,
    colour: YCbCr,
    sequence: Sequence,
    corrupt: u64,
    reconnects: u64,
    /// The lock to apply again after a reconnect (the values the camera accepted).
    lock: Option<LockSettings>,
    last_lock: Option<LockReport>,
    /// The manual exposure (100 µs units) once the lock turned automatic exposure off.
    exposure: Option<ExposureRange>,
}

impl<O: Opener> Camera<O> {
    /// Opens `path` with `opener`, negotiates the format and starts streaming.
    pub fn open_with(mut opener: O, path: &Path, options: OpenOptions) -> Result<Self> {
        let (device, active) = open_device(&mut opener, path, options.size, None)?;
        let colour = options.colour.unwrap_or_else(|| active.ycbcr());
        Ok(Self {
            opener,
            path: path.to_path_buf(),
            options,
            device: Some(device),
            active,
            colour,
            sequence: Sequence::default(),
            corrupt: 0,
            reconnects: 0,
            lock: None,
            last_lock: None,
            exposure: None,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The format the driver set (pixel format, size, stride, colorimetry fields).
    pub fn active_format(&self) -> ActiveFormat {
        self.active
    }

    /// The Y'CbCr matrix and range frames are decoded with.
    pub fn ycbcr(&self) -> YCbCr {
        self.colour
    }

    /// Frames skipped as corrupt since the camera was opened.
    pub fn corrupt_frames(&self) -> u64 {
        self.corrupt
    }

    /// Successful reconnects since the camera was opened.
    pub fn reconnects(&self) -> u64 {
        self.reconnects
    }

    /// Whether the device is open (false after it went away, until [`Camera::reconnect`]).
    pub fn is_connected(&self) -> bool {
        self.device.is_some()
    }

    /// How long a grab waits for a good frame before it fails (at least 1 ms).
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.options.timeout = timeout.max(Duration::from_millis(1));
    }

    pub fn timeout(&self) -> Duration {
        self.options.timeout
    }

    /// For messages: the device, its frame size, pixel format and colorimetry.
    pub fn describe(&self) -> String {
        let colour = if self.active.format.is_ycbcr() {
            format!(", {}", self.colour)
        } else {
            String::new()
        };
        format!(
            "camera {} ({} {}{colour})",
            self.path.display(),
            self.active.size,
            self.active.format.fourcc()
        )
    }

    fn device(&mut self) -> Result<&mut O::Device> {
        let path = &self.path;
        self.device.as_mut().ok_or_else(|| gone(path, None))
    }

    /// The next good frame, within the timeout. Corrupt frames are counted and skipped; a device
    /// that went away is an error and leaves the camera disconnected until
    /// [`Camera::reconnect`].
    pub fn capture(&mut self) -> Result<CapturedFrame> {
        let timeout = self.options.timeout;
        let deadline = Instant::now() + timeout;
        let (active, colour) = (self.active, self.colour);
        let mut skipped = 0u64;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let Some(device) = self.device.as_mut() else {
                return Err(gone(&self.path, None));
            };
            let got = match device.next_frame(left) {
                Ok(raw) if raw.error => None,
                Ok(raw) => {
                    pixels::decode(active.format, active.size, active.stride, colour, raw.data)
                        .map_err(|e| tracing::debug!("{}: corrupt frame: {e}", self.path.display()))
                        .ok()
                        .map(|rgba| (rgba, raw.sequence, raw.timestamp))
                }
                Err(e) => match e.kind() {
                    io::ErrorKind::Interrupted | io::ErrorKind::WouldBlock if !left.is_zero() => {
                        continue;
                    }
                    io::ErrorKind::Interrupted
                    | io::ErrorKind::TimedOut
                    | io::ErrorKind::WouldBlock => {
                        return Err(self.timed_out(timeout, skipped));
                    }
                    _ if is_disconnect(&e) => {
                        self.device = None;
                        return Err(gone(&self.path, Some(&e)));
                    }
                    _ => {
                        return Err(Error::Io {
                            path: self.path.clone(),
                            op: "capture a frame",
                            source: e,
                        });
                    }
                },
            };
            match got {
                Some((rgba, seq, timestamp)) => {
                    return Ok(CapturedFrame {
                        rgba,
                        seq: self.sequence.extend(seq),
                        timestamp,
                    });
                }
                None => {
                    self.corrupt += 1;
                    skipped += 1;
                    if Instant::now() >= deadline {
                        return Err(self.timed_out(timeout, skipped));
                    }
                }
            }
        }
    }

    fn timed_out(&self, timeout: Duration, skipped: u64) -> Error {
        let skipped = if skipped > 0 {
            format!(" ({skipped} corrupt frames skipped: check the USB cable and bandwidth)")
        } else {
            String::new()
        };
        Error::Failed(format!(
            "{}: no good frame within {:.1} s{skipped}; is the camera in use by another program, \
             or is its exposure longer than the timeout?",
            self.path.display(),
            timeout.as_secs_f64()
        ))
    }

    /// Reopens the same device path after it went away (or at any time): closes what is left,
    /// then tries to open it again as [`OpenOptions::reconnect`] says, with the same pixel
    /// format and size, and the same control lock. Frame sequence numbers keep increasing.
    pub fn reconnect(&mut self) -> Result<()> {
        // Closed first, so that the kernel can give the same device node back.
        self.device = None;
        let policy = self.options.reconnect;
        let started = Instant::now();
        let mut delay = policy.first_delay;
        let mut last = None;
        for attempt in 0..policy.attempts.max(1) {
            if attempt > 0 {
                std::thread::sleep(delay);
                delay = (delay * 2).min(policy.max_delay);
            }
            match self.reopen() {
                Ok(()) => {
                    self.reconnects += 1;
                    self.sequence.restart();
                    return Ok(());
                }
                Err(e) => last = Some(e),
            }
        }
        let last = last.map_or(String::new(), |e| format!(": {e}"));
        Err(Error::Failed(format!(
            "{}: could not reopen the camera ({} attempts over {:.1} s){last}. Check that it is \
             plugged in and listed by `compend cameras`; a path under /dev/v4l/by-id/ keeps its \
             name when the camera is plugged in again",
            self.path.display(),
            policy.attempts.max(1),
            started.elapsed().as_secs_f64()
        )))
    }

    fn reopen(&mut self) -> Result<()> {
        let want = FormatChoice {
            format: self.active.format,
            size: self.active.size,
        };
        let (device, active) =
            open_device(&mut self.opener, &self.path, Some(want.size), Some(want))?;
        self.active = active;
        self.colour = self.options.colour.unwrap_or_else(|| active.ycbcr());
        self.device = Some(device);
        if let Some(settings) = self.lock
            && let Err(e) = self.apply_lock(&settings)
        {
            self.device = None;
            return Err(e);
        }
        Ok(())
    }

    /// Locks exposure, gain, white balance, focus, backlight compensation and power-line
    /// frequency for calibration ([`controls::lock`]) and returns what the camera accepted. The
    /// accepted values are applied again after every reconnect. From then on, when automatic
    /// exposure is off, the camera offers its manual exposure to calibration
    /// ([`FrameSource::exposure`], 100 µs units).
    pub fn lock_for_calibration(&mut self, settings: &LockSettings) -> Result<LockReport> {
        let report = self.apply_lock(settings)?;
        self.lock = Some(report.settings());
        Ok(report)
    }

    fn apply_lock(&mut self, settings: &LockSettings) -> Result<LockReport> {
        let device = self.device()?;
        let report = controls::lock(device, settings)?;
        let exposure = device
            .controls()?
            .into_iter()
            .find(|c| c.id == controls::cid::EXPOSURE_ABSOLUTE);
        self.exposure = match (exposure, report.exposure()) {
            (Some(c), Some(value)) if report.exposure_is_manual() => Some(ExposureRange {
                value: value as f64,
                min: c.min as f64,
                max: c.max as f64,
            }),
            _ => None,
        };
        self.last_lock = Some(report.clone());
        Ok(report)
    }

    /// The report of the last lock (after a reconnect: of the lock applied again).
    pub fn lock_report(&self) -> Option<&LockReport> {
        self.last_lock.as_ref()
    }

    /// Sets the manual exposure time (100 µs units) and returns what the camera accepted; it is
    /// kept for reconnects. Lock the camera first: with automatic exposure on, the value is
    /// ignored.
    pub fn set_exposure_100us(&mut self, exposure: i64) -> Result<i64> {
        let id = controls::cid::EXPOSURE_ABSOLUTE;
        let accepted = self.set_control(id, exposure)?;
        let lock = self.lock.get_or_insert_with(LockSettings::default);
        lock.exposure = Some(accepted);
        if let Some(range) = self.exposure.as_mut() {
            range.value = accepted as f64;
        }
        Ok(accepted)
    }

    /// Writes one control by V4L2 ID (fitted to its range) and returns the value read back.
    pub fn set_control(&mut self, id: u32, value: i64) -> Result<i64> {
        let path = self.path.clone();
        controls::set_and_read(self.device()?, id, value)
            .map_err(|e| Error::Failed(format!("{}: {e}", path.display())))
    }

    /// The device's controls with their current values.
    pub fn controls(&mut self) -> Result<Vec<ControlInfo>> {
        self.device()?.controls()
    }
}

/// The error for a camera whose device is gone.
fn gone(path: &Path, cause: Option<&io::Error>) -> Error {
    let cause = cause.map_or(String::new(), |e| format!(" ({e})"));
    Error::Failed(format!(
        "{}: the camera is gone{cause}: unplugged, or its USB link was reset. Plug it back in; \
         reconnecting reopens the same path",
        path.display()
    ))
}

/// Errors that mean the device is gone: ENODEV (unplugged), EIO (a USB error), ENXIO,
/// ESHUTDOWN (the bus went down), EPIPE.
pub fn is_disconnect(e: &io::Error) -> bool {
    const ENODEV: i32 = 19;
    const EIO: i32 = 5;
    const ENXIO: i32 = 6;
    const EPIPE: i32 = 32;
    const ESHUTDOWN: i32 = 108;
    matches!(
        e.raw_os_error(),
        Some(ENODEV | EIO | ENXIO | EPIPE | ESHUTDOWN)
    )
}

/// Opens `path`, negotiates the format and starts streaming. `again`: the format of the device
/// before a reconnect, which it must get back exactly.
fn open_device<O: Opener>(
    opener: &mut O,
    path: &Path,
    size: Option<ImageSize>,
    again: Option<FormatChoice>,
) -> Result<(O::Device, ActiveFormat)> {
    let mut device = opener.open(path)?;
    let choice = match again {
        Some(c) => c,
        None => {
            let offers = device.formats()?;
            let current = device.format().ok().map(|f| f.size);
            choose_format(path, &offers, size, current)?
        }
    };
    let active = device.set_format(choice)?;
    let size_ok = size.is_none_or(|s| s == active.size);
    if active.format != choice.format || !size_ok {
        return Err(Error::Failed(format!(
            "{}: asked for {} {}, the driver set {} {}; pick another size (`compend cameras` \
             lists them)",
            path.display(),
            choice.size,
            choice.format.fourcc(),
            active.size,
            active.format.fourcc()
        )));
    }
    device.start()?;
    Ok((device, active))
}

impl<O: Opener> FrameSource for Camera<O> {
    fn size(&self) -> ImageSize {
        self.active.size
    }

    fn grab(&mut self) -> Result<Frame> {
        let c = self.capture()?;
        Ok(Frame {
            image: c.rgba.to_image(),
            seq: c.seq,
            timestamp: c.timestamp,
        })
    }

    /// The manual exposure in 100 µs units, once [`Camera::lock_for_calibration`] turned
    /// automatic exposure off; `None` before (an automatic exposure would undo any value).
    fn exposure(&self) -> Option<ExposureRange> {
        self.exposure
    }

    /// Sets the manual exposure (100 µs units, rounded to the camera's steps and clamped to
    /// its range); returns what the camera accepted.
    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        if self.exposure.is_none() {
            return Err(Error::Input(format!(
                "{}: the camera's exposure is automatic; lock it for calibration first",
                self.path.display()
            )));
        }
        let units = value.round().clamp(i64::MIN as f64, i64::MAX as f64) as i64;
        Ok(self.set_exposure_100us(units)? as f64)
    }

    /// Reopens the device ([`Camera::reconnect`]) when a grab found it gone; a camera still
    /// open (a timeout, a corrupt stream) is not reopened.
    fn reconnect(&mut self) -> Result<bool> {
        if self.is_connected() {
            return Ok(false);
        }
        Camera::reconnect(self).map(|()| true)
    }
}
