//! Cameras: the devices that watch the projection, as [`crate::device::FrameSource`]s (camera
//! frames with the driver's sequence number and timestamp, for calibration and monitoring).
//!
//! - [`pixels`] and [`mjpeg`]: YUYV, NV12, RGB24 and MJPEG frames to RGBA (pure, tested).
//! - [`format`]: what a device offers, the format picked on open, the colorimetry it reports.
//! - [`controls`]: controls by V4L2 ID and the lock before calibration, with its report.
//! - [`capture`]: [`Camera`], a device opened, streaming and surviving corrupt frames and
//!   unplugging, over any [`Device`] (V4L2 on Linux; a scripted fake in the tests).
//! - [`v4l2`] (Linux): the V4L2 device on the `v4l` crate's bindings, [`V4l2Camera`]; it also
//!   plays as a video source (`v4l2:/dev/videoN`, [`crate::source`]).
//! - [`list`]: what `compend cameras` prints: devices, formats, sizes, rates and controls.
//! - [`find`]: which cameras there are (index, name, device node), through nokhwa; what a
//!   `--camera` value (a path, an index, part of a name) names.
//!
//! Which crate does what: nokhwa finds cameras ([`find`]): its query of the platform's native
//! camera API is the same call on Linux, macOS and Windows, so the listing and naming of
//! cameras is portable, and its camera type is the way to capture on other platforms later
//! (behind [`Device`]). On Linux each camera found is opened at its device node through `v4l`
//! (its ioctl bindings and wrappers): formats, controls by ID and memory-mapped buffers with
//! their sequence numbers and timestamps. Calibration needs what nokhwa's capture hides there
//! (sequence numbers, exposure timestamps, row strides, colorimetry, exposure by
//! `V4L2_CID_EXPOSURE_ABSOLUTE`), so nokhwa does not stream here. nokhwa's Linux query panics
//! on a `/dev/video*` name without a number (a udev link `/dev/video-cam`); such a `/dev` is
//! scanned by [`find`] itself. The high-level parts of `v4l` are avoided too: its mmap
//! stream cannot resume after a poll timeout and panics when dropped after an I/O error
//! other than ENODEV, and its control and capability readers panic on unknown control types
//! and on names that are not UTF-8.
//!
//! The virtual rig's camera is [`crate::rig::VirtualRig`]. Pixel formats are converted to
//! 8-bit RGBA as the device delivered them (camera pixels, sRGB-encoded values, no colour
//! management), and from there to [`crate::raster::CamImage`] (v/255).

pub mod capture;
pub mod controls;
pub mod find;
pub mod format;
pub mod list;
pub mod mjpeg;
pub mod pixels;
#[cfg(target_os = "linux")]
mod ring;
#[cfg(target_os = "linux")]
pub mod v4l2;

use std::io;
use std::path::Path;
use std::time::Duration;

pub use capture::{Camera, CapturedFrame, OpenOptions, Reconnect};
pub use controls::{Controls, LockReport, LockSettings, PowerLine};
pub use format::{ActiveFormat, FormatChoice, FormatOffer};
pub use pixels::{FourCc, Matrix, PixelFormat, Range, YCbCr, rgb24_to_rgba, yuyv_to_rgba};
#[cfg(target_os = "linux")]
pub use v4l2::{V4l2, V4l2Camera};

use crate::error::Result;

/// One filled buffer as the driver returned it.
#[derive(Clone, Copy, Debug)]
pub struct RawFrame<'a> {
    /// The bytes the driver filled (`bytesused`).
    pub data: &'a [u8],
    /// The driver's frame counter (32 bits; it wraps).
    pub sequence: u32,
    /// The driver's buffer timestamp on its monotonic clock.
    pub timestamp: Duration,
    /// The driver marked the buffer as corrupt (`V4L2_BUF_FLAG_ERROR`).
    pub error: bool,
}

/// An open capture device, as [`Camera`] drives it.
pub trait Device: Controls {
    /// The pixel formats the device offers, with frame sizes and rates.
    fn formats(&mut self) -> Result<Vec<FormatOffer>>;
    /// The format the device is set to now.
    fn format(&mut self) -> Result<ActiveFormat>;
    /// Asks for `choice` and returns what the driver set (it may differ).
    fn set_format(&mut self, choice: FormatChoice) -> Result<ActiveFormat>;
    /// Starts streaming (buffers allocated and queued); a no-op when streaming.
    fn start(&mut self) -> Result<()>;
    /// The next filled buffer, waiting at most `timeout`. Errors are the OS's: `TimedOut`
    /// when nothing came, ENODEV or EIO when the device went away.
    fn next_frame(&mut self, timeout: Duration) -> io::Result<RawFrame<'_>>;
}

/// Opens devices by path: the first open and every reconnect.
pub trait Opener {
    type Device: Device;
    fn open(&mut self, path: &Path) -> Result<Self::Device>;
}

/// A driver's 32-bit frame counter made monotonic over 64 bits: it wraps after 2³² frames,
/// and it starts again after a reconnect ([`Sequence::restart`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sequence {
    last: Option<u32>,
    /// Added to the driver's counter.
    offset: u64,
    last_out: Option<u64>,
}

impl Sequence {
    /// The 64-bit sequence number of a frame whose driver counter is `seq`.
    pub fn extend(&mut self, seq: u32) -> u64 {
        if self.last.is_some_and(|last| seq < last) {
            self.offset += 1 << 32;
        }
        self.last = Some(seq);
        let out = self.offset + seq as u64;
        self.last_out = Some(out);
        out
    }

    /// The driver's counter starts over (a reopened device): numbers continue after the last
    /// one given, so they stay increasing.
    pub fn restart(&mut self) {
        self.offset = self.last_out.map_or(0, |v| v + 1);
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_survives_the_wrap() {
        let mut s = Sequence::default();
        assert_eq!(s.extend(u32::MAX - 1), u32::MAX as u64 - 1);
        assert_eq!(s.extend(u32::MAX), u32::MAX as u64);
        assert_eq!(s.extend(0), 1 << 32);
        assert_eq!(s.extend(2), (1 << 32) + 2);
    }

    #[test]
    fn sequence_keeps_increasing_after_a_restart() {
        let mut s = Sequence::default();
        assert_eq!(s.extend(40), 40);
        assert_eq!(s.extend(41), 41);
        s.restart();
        assert_eq!(s.extend(0), 42);
        assert_eq!(s.extend(1), 43);
        assert_eq!(s.extend(5), 47);
    }
}
