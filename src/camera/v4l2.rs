//! A V4L2 capture device (a UVC webcam, a capture card): memory-mapped streaming in YUYV, RGB3 or
//! MJPEG (whichever the device offers first in that order), converted to 8-bit RGBA.
//!
//! [`V4l2Camera`] is a [`FrameSource`]: each frame carries the driver's sequence number (a gap
//! means the driver dropped frames) and buffer timestamp. A grab waits at most the camera's
//! timeout ([`V4l2Camera::set_timeout`]) for a frame, so a stalled device is an error, not a
//! hang. The same camera plays as a video source (`v4l2:/dev/videoN`; [`crate::source`]).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use v4l::buffer::{Flags, Type};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::{Sequence, rgb24_to_rgba, yuyv_to_rgba};
use crate::device::{Frame, FrameSource};
use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// Pixel formats compend decodes, in order of preference.
const PREFERRED: [&[u8; 4]; 3] = [b"YUYV", b"RGB3", b"MJPG"];

/// Buffers the driver fills in turn.
const BUFFERS: u32 = 4;

/// An open V4L2 camera, streaming.
pub struct V4l2Camera {
    path: PathBuf,
    /// (width, height) of the frames, camera pixels.
    size: ImageSize,
    fourcc: [u8; 4],
    /// Bytes from one row to the next in the driver's buffers (YUYV and RGB3).
    stride: usize,
    stream: Stream<'static>,
    timeout: Duration,
    sequence: Sequence,
}

/// One capture as the device delivered it.
#[derive(Clone, Debug)]
pub struct CapturedFrame {
    /// The image, 8-bit RGBA, camera pixels.
    pub rgba: ContentFrame,
    /// The driver's sequence number, made monotonic over 64 bits.
    pub seq: u64,
    /// The driver's buffer timestamp (CLOCK_MONOTONIC for UVC; the start of the exposure or the
    /// end of the frame, as the driver reports).
    pub timestamp: Duration,
}

fn dev_err(path: &Path, op: &'static str, e: std::io::Error) -> Error {
    if e.kind() == std::io::ErrorKind::NotFound {
        Error::Missing {
            path: path.to_path_buf(),
            expected: "a V4L2 capture device (see `v4l2-ctl --list-devices`)".into(),
        }
    } else {
        Error::Io {
            path: path.to_path_buf(),
            op,
            source: e,
        }
    }
}

fn fourcc_name(f: &[u8; 4]) -> String {
    String::from_utf8_lossy(f).into_owned()
}

/// The first of [`PREFERRED`] that `dev` offers.
fn pick_format(dev: &Device, path: &Path) -> Result<[u8; 4]> {
    let offered: Vec<[u8; 4]> = dev
        .enum_formats()
        .map_err(|e| dev_err(path, "list formats", e))?
        .iter()
        .map(|f| f.fourcc.repr)
        .collect();
    PREFERRED
        .iter()
        .map(|f| **f)
        .find(|f| offered.contains(f))
        .ok_or_else(|| {
            Error::Input(format!(
                "{}: offers none of YUYV, RGB3, MJPG (offers {})",
                path.display(),
                offered
                    .iter()
                    .map(fourcc_name)
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
}

/// One buffer's bytes in `fourcc` to RGBA; `size` is (width, height) in camera pixels, `stride`
/// the bytes from row to row (YUYV and RGB3).
fn decode(
    path: &Path,
    fourcc: &[u8; 4],
    size: ImageSize,
    stride: usize,
    data: &[u8],
) -> Result<ContentFrame> {
    let frame = match fourcc {
        b"YUYV" => yuyv_to_rgba(data, size, stride.max(size.width * 2))?,
        b"RGB3" => rgb24_to_rgba(data, size, stride.max(size.width * 3))?,
        _ => {
            let img = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg)
                .map_err(|e| Error::Failed(format!("{}: MJPEG frame: {e}", path.display())))?
                .to_rgba8();
            let (w, h) = img.dimensions();
            ContentFrame::from_rgba(w as usize, h as usize, img.into_raw())?
        }
    };
    if frame.size() != size {
        return Err(Error::Failed(format!(
            "{}: a {}x{} frame from a device set to {}",
            path.display(),
            frame.width,
            frame.height,
            size
        )));
    }
    Ok(frame)
}

/// A driver timestamp as a duration since the clock's origin (negative fields count as zero).
fn timestamp(ts: v4l::Timestamp) -> Duration {
    let usec = ts.usec.clamp(0, 999_999) as u64;
    Duration::from_secs(ts.sec.max(0) as u64) + Duration::from_micros(usec)
}

impl V4l2Camera {
    /// How long a grab waits for a frame unless told otherwise.
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(5);

    /// Opens `path`, picks a pixel format the device offers and, when given, the frame size
    /// ((width, height), camera pixels; the driver may pick the nearest it has), and starts
    /// streaming.
    pub fn open(path: &Path, size: Option<ImageSize>) -> Result<Self> {
        let dev = Device::with_path(path).map_err(|e| dev_err(path, "open", e))?;
        let fourcc = pick_format(&dev, path)?;
        let mut fmt = dev.format().map_err(|e| dev_err(path, "read format", e))?;
        fmt.fourcc = FourCC::new(&fourcc);
        if let Some(size) = size {
            fmt.width = size.width as u32;
            fmt.height = size.height as u32;
        }
        let fmt = dev
            .set_format(&fmt)
            .map_err(|e| dev_err(path, "set format", e))?;
        if fmt.fourcc.repr != fourcc {
            return Err(Error::Failed(format!(
                "{}: the driver did not accept {}",
                path.display(),
                fourcc_name(&fourcc)
            )));
        }
        let stream = Stream::with_buffers(&dev, Type::VideoCapture, BUFFERS)
            .map_err(|e| dev_err(path, "start streaming", e))?;
        let mut camera = Self {
            path: path.to_path_buf(),
            size: ImageSize::new(fmt.width as usize, fmt.height as usize),
            fourcc,
            stride: fmt.stride as usize,
            stream,
            timeout: Self::DEFAULT_TIMEOUT,
            sequence: Sequence::default(),
        };
        camera.set_timeout(Self::DEFAULT_TIMEOUT);
        Ok(camera)
    }

    /// How long a grab waits for the next frame before it fails (at least 1 ms).
    pub fn set_timeout(&mut self, timeout: Duration) {
        // The driver poll takes whole milliseconds in an i32.
        let ms = timeout.as_millis().clamp(1, i32::MAX as u128) as u64;
        self.timeout = Duration::from_millis(ms);
        self.stream.set_timeout(self.timeout);
    }

    /// For messages: the device, its frame size and pixel format.
    pub fn describe(&self) -> String {
        format!(
            "V4L2 device {} ({} {})",
            self.path.display(),
            self.size,
            fourcc_name(&self.fourcc)
        )
    }

    /// The next frame the device delivers, as 8-bit RGBA with the driver's metadata. Frames the
    /// driver marks as corrupted are skipped; no good frame within the timeout is an error.
    pub fn capture(&mut self) -> Result<CapturedFrame> {
        let deadline = Instant::now() + self.timeout;
        loop {
            let (buf, meta) = self.stream.next().map_err(|e| {
                if e.kind() == std::io::ErrorKind::TimedOut {
                    Error::Failed(format!(
                        "{}: no frame within {:.1} s (is the device busy or unplugged?)",
                        self.path.display(),
                        self.timeout.as_secs_f64()
                    ))
                } else {
                    dev_err(&self.path, "capture", e)
                }
            })?;
            if meta.flags.contains(Flags::ERROR) && Instant::now() < deadline {
                continue;
            }
            let data = &buf[..(meta.bytesused as usize).min(buf.len())];
            let (seq, stamp) = (meta.sequence, meta.timestamp);
            let rgba = decode(&self.path, &self.fourcc, self.size, self.stride, data)?;
            return Ok(CapturedFrame {
                rgba,
                seq: self.sequence.extend(seq),
                timestamp: timestamp(stamp),
            });
        }
    }
}

impl FrameSource for V4l2Camera {
    fn size(&self) -> ImageSize {
        self.size
    }

    fn grab(&mut self) -> Result<Frame> {
        let c = self.capture()?;
        Ok(Frame {
            image: c.rgba.to_image(),
            seq: c.seq,
            timestamp: c.timestamp,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[ignore = "needs a V4L2 camera"]
    fn grabs_frames_from_dev_video0() {
        let mut cam = V4l2Camera::open(Path::new("/dev/video0"), None).unwrap();
        let a = cam.grab().unwrap();
        let b = cam.grab().unwrap();
        assert_eq!(a.image.size(), FrameSource::size(&cam));
        assert!(b.seq > a.seq, "sequence {} then {}", a.seq, b.seq);
        assert!(b.timestamp >= a.timestamp);
    }

    #[test]
    fn a_missing_device_is_an_input_error() {
        let e = V4l2Camera::open(Path::new("/dev/no-such-video-device"), None)
            .err()
            .unwrap();
        assert_eq!(e.exit_code(), 2, "{e}");
    }
}
