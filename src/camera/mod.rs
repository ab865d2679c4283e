//! Cameras: the devices that watch the projection, as [`crate::device::FrameSource`]s (camera
//! frames with the driver's sequence number and timestamp, for calibration and monitoring).
//!
//! - [`v4l2`] (Linux): a V4L2/UVC capture device, [`V4l2Camera`]; it also plays as a video
//!   source (`v4l2:/dev/videoN`, [`crate::source`]).
//!
//! The virtual rig's camera is [`crate::rig::VirtualRig`]. Pixel formats are converted here to
//! 8-bit RGBA as the device delivered them (camera pixels, sRGB-encoded values, no colour
//! management), and from there to [`crate::raster::CamImage`] (v/255).

#[cfg(target_os = "linux")]
pub mod v4l2;

#[cfg(target_os = "linux")]
pub use v4l2::V4l2Camera;

use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// YUYV (4:2:2, Y0 U Y1 V) to RGBA, BT.601 full range (what UVC webcams send; a device in
/// limited range looks slightly washed out, not wrong). `size` is (width, height) in pixels;
/// rows are `stride` bytes apart (at least `2 × width`).
pub fn yuyv_to_rgba(
    src: &[u8],
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    stride: usize,
) -> Result<ContentFrame> {
    let row = w * 2;
    if w % 2 != 0 || stride < row || src.len() < stride * h.saturating_sub(1) + row {
        return Err(Error::Failed(format!(
            "YUYV frame {w}x{h} with rows of {stride} bytes: got {} bytes",
            src.len()
        )));
    }
    let px = |y: f32, u: f32, v: f32| {
        let c = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        [
            c(y + 1.402 * v),
            c(y - 0.344_136 * u - 0.714_136 * v),
            c(y + 1.772 * u),
            255,
        ]
    };
    let mut rgba = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        for q in src[y * stride..y * stride + row].chunks_exact(4) {
            let (u, v) = (q[1] as f32 - 128.0, q[3] as f32 - 128.0);
            rgba.extend_from_slice(&px(q[0] as f32, u, v));
            rgba.extend_from_slice(&px(q[2] as f32, u, v));
        }
    }
    ContentFrame::from_rgba(w, h, rgba)
}

/// Packed 8-bit RGB rows (`stride` bytes apart) to RGBA; `size` is (width, height) in pixels.
pub fn rgb24_to_rgba(
    src: &[u8],
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    stride: usize,
) -> Result<ContentFrame> {
    let row = w * 3;
    if stride < row || src.len() < stride * h.saturating_sub(1) + row {
        return Err(Error::Failed(format!(
            "RGB3 frame {w}x{h} with rows of {stride} bytes: got {} bytes",
            src.len()
        )));
    }
    let rows: Vec<u8> = (0..h)
        .flat_map(|y| &src[y * stride..y * stride + row])
        .copied()
        .collect();
    ContentFrame::from_rgb(w, h, &rows)
}

/// A driver's 32-bit frame counter made monotonic over 64 bits (it wraps after 2³² frames).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sequence {
    last: Option<u32>,
    wraps: u64,
}

impl Sequence {
    /// The 64-bit sequence number of a frame whose driver counter is `seq`.
    pub fn extend(&mut self, seq: u32) -> u64 {
        if self.last.is_some_and(|last| seq < last) {
            self.wraps += 1;
        }
        self.last = Some(seq);
        (self.wraps << 32) | seq as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_gray_and_colour() {
        // Two pixels of Y=128 with neutral chroma: mid gray.
        let f = yuyv_to_rgba(&[128, 128, 128, 128], ImageSize::new(2, 1), 4).unwrap();
        assert_eq!(f.rgba, vec![128, 128, 128, 255, 128, 128, 128, 255]);
        // Strong V: red up, green down.
        let f = yuyv_to_rgba(&[100, 128, 100, 228], ImageSize::new(2, 1), 4).unwrap();
        assert!(f.rgba[0] > 200 && f.rgba[1] < 60);
    }

    #[test]
    fn padded_rows_are_skipped() {
        // 2x2 YUYV with 2 bytes of padding per row; the padding must not leak into the image.
        let src = [128, 128, 128, 128, 9, 9, 0, 128, 0, 128];
        let f = yuyv_to_rgba(&src, ImageSize::new(2, 2), 6).unwrap();
        assert_eq!(&f.rgba[..4], &[128, 128, 128, 255]);
        assert_eq!(&f.rgba[8..12], &[0, 0, 0, 255]);
        let f = rgb24_to_rgba(&[1, 2, 3, 0, 4, 5, 6], ImageSize::new(1, 2), 4).unwrap();
        assert_eq!(f.rgba, vec![1, 2, 3, 255, 4, 5, 6, 255]);
        assert!(rgb24_to_rgba(&[1, 2, 3, 0, 4, 5], ImageSize::new(1, 2), 4).is_err());
    }

    #[test]
    fn sequence_survives_the_wrap() {
        let mut s = Sequence::default();
        assert_eq!(s.extend(u32::MAX - 1), u32::MAX as u64 - 1);
        assert_eq!(s.extend(u32::MAX), u32::MAX as u64);
        assert_eq!(s.extend(0), 1 << 32);
        assert_eq!(s.extend(2), (1 << 32) + 2);
    }
}
