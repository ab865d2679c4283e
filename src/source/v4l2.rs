//! V4L2 capture devices (`v4l2:/dev/videoN[?size=WxH]`): memory-mapped streaming in YUYV, RGB3
//! or MJPEG (whichever the device offers first in that order), converted to RGBA.
//!
//! YUYV is converted with BT.601 full-range coefficients (what UVC webcams send); a device in
//! limited range looks slightly washed out, not wrong.

use std::path::{Path, PathBuf};

use v4l::buffer::Type;
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::{Next, VideoSource};
use crate::error::{Error, Result};
use crate::playback::ContentFrame;

const PREFERRED: [&[u8; 4]; 3] = [b"YUYV", b"RGB3", b"MJPG"];

pub struct Camera {
    path: PathBuf,
    size: (usize, usize),
    fourcc: [u8; 4],
    stream: Stream<'static>,
}

fn dev_err(path: &Path, what: &str, e: std::io::Error) -> Error {
    if e.kind() == std::io::ErrorKind::NotFound {
        Error::Missing {
            path: path.to_path_buf(),
            expected: "a V4L2 capture device (see `v4l2-ctl --list-devices`)".into(),
        }
    } else {
        Error::Failed(format!("{}: {what}: {e}", path.display()))
    }
}

impl Camera {
    /// Opens `path`, picks a pixel format the device offers and, when given, the frame size.
    pub fn open(path: &Path, size: Option<(usize, usize)>) -> Result<Self> {
        let dev = Device::with_path(path).map_err(|e| dev_err(path, "open", e))?;
        let offered: Vec<[u8; 4]> = dev
            .enum_formats()
            .map_err(|e| dev_err(path, "list formats", e))?
            .iter()
            .map(|f| f.fourcc.repr)
            .collect();
        let fourcc = PREFERRED
            .iter()
            .map(|f| **f)
            .find(|f| offered.contains(f))
            .ok_or_else(|| {
                Error::Input(format!(
                    "{}: offers none of YUYV, RGB3, MJPG (offers {})",
                    path.display(),
                    offered
                        .iter()
                        .map(|f| String::from_utf8_lossy(f).into_owned())
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            })?;
        let mut fmt = dev.format().map_err(|e| dev_err(path, "read format", e))?;
        fmt.fourcc = FourCC::new(&fourcc);
        if let Some((w, h)) = size {
            fmt.width = w as u32;
            fmt.height = h as u32;
        }
        let fmt = dev
            .set_format(&fmt)
            .map_err(|e| dev_err(path, "set format", e))?;
        if fmt.fourcc.repr != fourcc {
            return Err(Error::Failed(format!(
                "{}: the driver did not accept {}",
                path.display(),
                String::from_utf8_lossy(&fourcc)
            )));
        }
        let stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
            .map_err(|e| dev_err(path, "start streaming", e))?;
        Ok(Self {
            path: path.to_path_buf(),
            size: (fmt.width as usize, fmt.height as usize),
            fourcc,
            stream,
        })
    }
}

/// YUYV (4:2:2, Y0 U Y1 V) to RGBA, BT.601 full range.
pub fn yuyv_to_rgba(src: &[u8], (w, h): (usize, usize)) -> Result<ContentFrame> {
    if src.len() < w * h * 2 || w % 2 != 0 {
        return Err(Error::Failed(format!(
            "YUYV frame {w}x{h}: got {} bytes",
            src.len()
        )));
    }
    let mut rgba = Vec::with_capacity(w * h * 4);
    let px = |y: f32, u: f32, v: f32| {
        let c = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        [
            c(y + 1.402 * v),
            c(y - 0.344_136 * u - 0.714_136 * v),
            c(y + 1.772 * u),
            255,
        ]
    };
    for q in src[..w * h * 2].chunks_exact(4) {
        let (u, v) = (q[1] as f32 - 128.0, q[3] as f32 - 128.0);
        rgba.extend_from_slice(&px(q[0] as f32, u, v));
        rgba.extend_from_slice(&px(q[2] as f32, u, v));
    }
    ContentFrame::from_rgba(w, h, rgba)
}

impl VideoSource for Camera {
    fn describe(&self) -> String {
        format!(
            "V4L2 device {} ({}x{} {})",
            self.path.display(),
            self.size.0,
            self.size.1,
            String::from_utf8_lossy(&self.fourcc)
        )
    }

    fn next(&mut self) -> Result<Next> {
        let (buf, meta) = self
            .stream
            .next()
            .map_err(|e| dev_err(&self.path, "capture", e))?;
        let data = &buf[..(meta.bytesused as usize).min(buf.len())];
        let (w, h) = self.size;
        let frame = match &self.fourcc {
            b"YUYV" => yuyv_to_rgba(data, (w, h))?,
            b"RGB3" => ContentFrame::from_rgb(w, h, &data[..(w * h * 3).min(data.len())])?,
            _ => {
                let img = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg)
                    .map_err(|e| {
                        Error::Failed(format!("{}: MJPEG frame: {e}", self.path.display()))
                    })?
                    .to_rgba8();
                let (iw, ih) = img.dimensions();
                ContentFrame::from_rgba(iw as usize, ih as usize, img.into_raw())?
            }
        };
        Ok(Next::Frame { frame, wait: None })
    }

    fn ends_playback(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_gray_and_colour() {
        // Two pixels of Y=128 with neutral chroma: mid gray.
        let f = yuyv_to_rgba(&[128, 128, 128, 128], (2, 1)).unwrap();
        assert_eq!(f.rgba, vec![128, 128, 128, 255, 128, 128, 128, 255]);
        // Strong V: red up, green down.
        let f = yuyv_to_rgba(&[100, 128, 100, 228], (2, 1)).unwrap();
        assert!(f.rgba[0] > 200 && f.rgba[1] < 60);
    }

    #[test]
    #[ignore = "needs a V4L2 device"]
    fn captures_a_frame_from_dev_video0() {
        let mut cam = Camera::open(Path::new("/dev/video0"), None).unwrap();
        match cam.next().unwrap() {
            Next::Frame { frame, .. } => assert_eq!(frame.size(), cam.size),
            Next::End => panic!("a camera does not end"),
        }
    }

    #[test]
    fn a_missing_device_is_an_input_error() {
        let e = Camera::open(Path::new("/dev/no-such-video-device"), None)
            .err()
            .unwrap();
        assert_eq!(e.exit_code(), 2, "{e}");
    }
}
