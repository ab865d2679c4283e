//! Camera pixel formats to RGB: YUYV, NV12, RGB24 (with row strides) and MJPEG ([`super::mjpeg`]).
//!
//! Every conversion writes 8-bit RGBA in camera pixels: sRGB-encoded values as the camera sent
//! them, no colour management and no linearisation ([`ContentFrame::to_image`] gives the f32
//! [`crate::raster::CamImage`], v/255). Y'CbCr formats are converted with the matrix and range
//! of a [`YCbCr`]: which one a device uses comes from the driver's format fields or the frame
//! size ([`super::format::ActiveFormat::ycbcr`]).
//!
//! Kept rather than the `yuv` crate (yuvutils-rs): here a Y'CbCr pixel is one float formula
//! for whichever of four matrices and two ranges the driver reports, rounded once, with row
//! strides and odd NV12 heights; the crate's 8-bit paths are fixed-point (a level off here and
//! there, so recorded captures would convert differently), and its documentation says it
//! panics on plane sizes it does not expect, where a short or corrupt frame from a driver is an
//! error here ([`check`]).

use serde::Serialize;

use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// A V4L2 four-character pixel format code (`YUYV`, `MJPG`, ...), as the bytes in the driver's
/// little-endian `u32`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FourCc(pub [u8; 4]);

impl FourCc {
    /// From the driver's `u32` (first character in the lowest byte).
    pub fn from_u32(code: u32) -> Self {
        Self(code.to_le_bytes())
    }

    pub fn to_u32(self) -> u32 {
        u32::from_le_bytes(self.0)
    }
}

impl std::fmt::Display for FourCc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let text: String = self
            .0
            .iter()
            .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
            .collect();
        f.write_str(text.trim_end_matches('?'))
    }
}

impl Serialize for FourCc {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

/// The pixel formats compend decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelFormat {
    /// 4:2:2 packed Y0 U Y1 V, 2 bytes per pixel.
    Yuyv,
    /// 4:2:0: a Y plane, then one plane of interleaved U V at half width and half height.
    Nv12,
    /// Packed 8-bit R G B (V4L2 `RGB3`).
    Rgb24,
    /// Motion JPEG: each frame a JPEG image (V4L2 `MJPG`, or `JPEG`).
    Mjpeg,
}

impl PixelFormat {
    /// In order of preference: uncompressed before MJPEG (no compression artefacts, no decode
    /// cost), YUYV first (what UVC cameras offer uncompressed).
    pub const PREFERRED: [PixelFormat; 4] = [Self::Yuyv, Self::Nv12, Self::Rgb24, Self::Mjpeg];

    pub fn from_fourcc(f: FourCc) -> Option<Self> {
        match &f.0 {
            b"YUYV" => Some(Self::Yuyv),
            b"NV12" => Some(Self::Nv12),
            b"RGB3" => Some(Self::Rgb24),
            b"MJPG" | b"JPEG" => Some(Self::Mjpeg),
            _ => None,
        }
    }

    /// The code compend asks a driver for.
    pub fn fourcc(self) -> FourCc {
        FourCc(*match self {
            Self::Yuyv => b"YUYV",
            Self::Nv12 => b"NV12",
            Self::Rgb24 => b"RGB3",
            Self::Mjpeg => b"MJPG",
        })
    }

    /// Whether the format is Y'CbCr (converted with a [`YCbCr`] matrix and range).
    pub fn is_ycbcr(self) -> bool {
        matches!(self, Self::Yuyv | Self::Nv12)
    }

    /// Bytes a frame needs at least: `stride` bytes per row (0: tightly packed) for the
    /// uncompressed formats; 1 for MJPEG, whose size varies.
    pub fn min_bytes(self, size: ImageSize, stride: usize) -> usize {
        let (w, h) = (size.width, size.height);
        let stride = stride.max(self.row_bytes(w));
        match self {
            Self::Yuyv | Self::Rgb24 => stride * h.saturating_sub(1) + self.row_bytes(w),
            // The UV plane starts after `h` luma rows and has ceil(h/2) rows of `stride` bytes.
            Self::Nv12 => stride * (h + h.div_ceil(2) - 1) + w.div_ceil(2) * 2,
            Self::Mjpeg => 1,
        }
    }

    /// Bytes of one row's pixels without padding (the smallest valid stride).
    pub fn row_bytes(self, width: usize) -> usize {
        match self {
            Self::Yuyv => width * 2,
            Self::Nv12 => width.div_ceil(2) * 2,
            Self::Rgb24 => width * 3,
            Self::Mjpeg => 0,
        }
    }
}

/// The Y'CbCr → R'G'B' matrix, by its luma coefficients (Kr, Kb).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Matrix {
    /// ITU-R BT.601 (SMPTE 170M): standard-definition video, JPEG.
    Bt601,
    /// ITU-R BT.709: HD video.
    Bt709,
    /// ITU-R BT.2020 (non-constant luminance).
    Bt2020,
    /// SMPTE 240M.
    Smpte240m,
}

impl Matrix {
    /// (Kr, Kb) of the matrix.
    pub fn kr_kb(self) -> (f32, f32) {
        match self {
            Self::Bt601 => (0.299, 0.114),
            Self::Bt709 => (0.2126, 0.0722),
            Self::Bt2020 => (0.2627, 0.0593),
            Self::Smpte240m => (0.212, 0.087),
        }
    }
}

/// Quantisation of 8-bit Y'CbCr.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Range {
    /// Y' in 16–235, Cb and Cr in 16–240 (video levels; V4L2's default for Y'CbCr).
    Limited,
    /// Y', Cb and Cr in 0–255 (JPEG levels).
    Full,
}

/// How a device's Y'CbCr maps to R'G'B'.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct YCbCr {
    pub matrix: Matrix,
    pub range: Range,
}

impl std::fmt::Display for YCbCr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let m = match self.matrix {
            Matrix::Bt601 => "BT.601",
            Matrix::Bt709 => "BT.709",
            Matrix::Bt2020 => "BT.2020",
            Matrix::Smpte240m => "SMPTE 240M",
        };
        let r = match self.range {
            Range::Limited => "limited",
            Range::Full => "full",
        };
        write!(f, "{m} {r} range")
    }
}

/// Per-frame constants of a Y'CbCr conversion, in 8-bit units.
#[derive(Clone, Copy, Debug)]
struct Coeffs {
    /// Y' = (Y − y_off) · y_scale.
    y_off: f32,
    y_scale: f32,
    /// Cb, Cr = (C − 128) · c_scale.
    c_scale: f32,
    r_cr: f32,
    g_cb: f32,
    g_cr: f32,
    b_cb: f32,
}

impl Coeffs {
    fn new(c: YCbCr) -> Self {
        let (kr, kb) = c.matrix.kr_kb();
        let kg = 1.0 - kr - kb;
        let (y_off, y_scale, c_scale) = match c.range {
            Range::Limited => (16.0, 255.0 / 219.0, 255.0 / 224.0),
            Range::Full => (0.0, 1.0, 1.0),
        };
        Self {
            y_off,
            y_scale,
            c_scale,
            r_cr: 2.0 * (1.0 - kr),
            g_cb: 2.0 * kb * (1.0 - kb) / kg,
            g_cr: 2.0 * kr * (1.0 - kr) / kg,
            b_cb: 2.0 * (1.0 - kb),
        }
    }

    /// One pixel from 8-bit Y, Cb, Cr to RGBA8 (rounded to nearest, clipped).
    #[inline]
    fn rgba(&self, y: u8, cb: u8, cr: u8) -> [u8; 4] {
        let y = (y as f32 - self.y_off) * self.y_scale;
        let cb = (cb as f32 - 128.0) * self.c_scale;
        let cr = (cr as f32 - 128.0) * self.c_scale;
        let q = |v: f32| (v + 0.5).clamp(0.0, 255.0) as u8;
        [
            q(y + self.r_cr * cr),
            q(y - self.g_cb * cb - self.g_cr * cr),
            q(y + self.b_cb * cb),
            255,
        ]
    }
}

/// A buffer too short for its format: what the driver filled and what it should have.
fn short(what: &str, size: ImageSize, stride: usize, got: usize, need: usize) -> Error {
    Error::Failed(format!(
        "{what} frame {size} with rows of {stride} bytes needs {need} bytes, got {got} (a \
         truncated or corrupt frame)"
    ))
}

/// Checks the buffer against the format; returns the stride to use.
fn check(
    format: PixelFormat,
    size: ImageSize,
    stride: usize,
    got: usize,
    what: &str,
) -> Result<usize> {
    if size.width == 0 || size.height == 0 {
        return Err(Error::Failed(format!("{what} frame of size {size}")));
    }
    let stride = if stride == 0 {
        format.row_bytes(size.width)
    } else {
        stride
    };
    if stride < format.row_bytes(size.width) {
        return Err(Error::Failed(format!(
            "{what} frame {size}: rows of {stride} bytes are shorter than a row of pixels ({})",
            format.row_bytes(size.width)
        )));
    }
    let need = format.min_bytes(size, stride);
    if got < need {
        return Err(short(what, size, stride, got, need));
    }
    Ok(stride)
}

/// YUYV (4:2:2, Y0 Cb Y1 Cr) to RGBA. `size` is (width, height) in camera pixels (even width);
/// rows start `stride` bytes apart (0: tightly packed, `2 × width`); bytes past a row's pixels
/// are padding and ignored.
pub fn yuyv_to_rgba(
    src: &[u8],
    size: ImageSize,
    stride: usize,
    colour: YCbCr,
) -> Result<ContentFrame> {
    let stride = check(PixelFormat::Yuyv, size, stride, src.len(), "YUYV")?;
    if !size.width.is_multiple_of(2) {
        return Err(Error::Failed(format!(
            "YUYV frame {size}: the width must be even"
        )));
    }
    let k = Coeffs::new(colour);
    let (w, h) = (size.width, size.height);
    let mut rgba = Vec::with_capacity(w * h * 4);
    for row in src.chunks(stride).take(h) {
        for q in row[..w * 2].chunks_exact(4) {
            rgba.extend_from_slice(&k.rgba(q[0], q[1], q[3]));
            rgba.extend_from_slice(&k.rgba(q[2], q[1], q[3]));
        }
    }
    ContentFrame::from_rgba(w, h, rgba)
}

/// NV12 (4:2:0) to RGBA: `height` rows of Y, then `ceil(height/2)` rows of interleaved Cb Cr
/// (one pair per 2×2 pixels), every row `stride` bytes from the next (0: tightly packed). Each
/// chroma sample is used for its 2×2 block (nearest, as most decoders do).
pub fn nv12_to_rgba(
    src: &[u8],
    size: ImageSize,
    stride: usize,
    colour: YCbCr,
) -> Result<ContentFrame> {
    let stride = check(PixelFormat::Nv12, size, stride, src.len(), "NV12")?;
    let k = Coeffs::new(colour);
    let (w, h) = (size.width, size.height);
    let (luma, chroma) = src.split_at(stride * h);
    let mut rgba = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        let yrow = &luma[y * stride..y * stride + w];
        let crow = &chroma[(y / 2) * stride..];
        for (x, &l) in yrow.iter().enumerate() {
            let c = (x / 2) * 2;
            rgba.extend_from_slice(&k.rgba(l, crow[c], crow[c + 1]));
        }
    }
    ContentFrame::from_rgba(w, h, rgba)
}

/// Packed 8-bit R G B rows, `stride` bytes apart (0: tightly packed, `3 × width`), to RGBA;
/// `size` is (width, height) in camera pixels. The values are copied as they are.
pub fn rgb24_to_rgba(src: &[u8], size: ImageSize, stride: usize) -> Result<ContentFrame> {
    let stride = check(PixelFormat::Rgb24, size, stride, src.len(), "RGB3")?;
    let (w, h) = (size.width, size.height);
    let mut rgba = Vec::with_capacity(w * h * 4);
    for row in src.chunks(stride).take(h) {
        for p in row[..w * 3].chunks_exact(3) {
            rgba.extend_from_slice(&[p[0], p[1], p[2], 255]);
        }
    }
    ContentFrame::from_rgba(w, h, rgba)
}

/// One frame as a driver delivered it, decoded to RGBA (camera pixels). `stride` is the
/// driver's bytes per line (0 when it gives none); `colour` applies to YUYV and NV12 (MJPEG
/// carries its own, full-range BT.601 as JPEG defines). A buffer that does not hold a whole
/// frame of `size`, or a JPEG that does not decode to `size`, is an error: a corrupt frame.
pub fn decode(
    format: PixelFormat,
    size: ImageSize,
    stride: usize,
    colour: YCbCr,
    data: &[u8],
) -> Result<ContentFrame> {
    match format {
        PixelFormat::Yuyv => yuyv_to_rgba(data, size, stride, colour),
        PixelFormat::Nv12 => nv12_to_rgba(data, size, stride, colour),
        PixelFormat::Rgb24 => rgb24_to_rgba(data, size, stride),
        PixelFormat::Mjpeg => super::mjpeg::decode(data, size),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BT601_FULL: YCbCr = YCbCr {
        matrix: Matrix::Bt601,
        range: Range::Full,
    };
    const BT709_LIMITED: YCbCr = YCbCr {
        matrix: Matrix::Bt709,
        range: Range::Limited,
    };

    #[test]
    fn fourcc_round_trips_and_prints() {
        let f = FourCc(*b"YUYV");
        assert_eq!(FourCc::from_u32(f.to_u32()), f);
        assert_eq!(f.to_string(), "YUYV");
        assert_eq!(
            FourCc::from_u32(u32::from_le_bytes(*b"MJPG")).to_string(),
            "MJPG"
        );
        for p in PixelFormat::PREFERRED {
            assert_eq!(PixelFormat::from_fourcc(p.fourcc()), Some(p));
        }
        assert_eq!(
            PixelFormat::from_fourcc(FourCc(*b"JPEG")),
            Some(PixelFormat::Mjpeg)
        );
        assert_eq!(PixelFormat::from_fourcc(FourCc(*b"BA81")), None);
    }

    #[test]
    fn limited_range_black_and_white_reach_the_ends() {
        for matrix in [Matrix::Bt601, Matrix::Bt709, Matrix::Bt2020] {
            let c = YCbCr {
                matrix,
                range: Range::Limited,
            };
            let f = yuyv_to_rgba(&[16, 128, 235, 128], ImageSize::new(2, 1), 0, c).unwrap();
            assert_eq!(f.rgba, vec![0, 0, 0, 255, 255, 255, 255, 255], "{c}");
        }
        // Full range: the same bytes are a dark and a light gray.
        let f = yuyv_to_rgba(&[16, 128, 235, 128], ImageSize::new(2, 1), 0, BT601_FULL).unwrap();
        assert_eq!(f.rgba, vec![16, 16, 16, 255, 235, 235, 235, 255]);
    }

    #[test]
    fn primaries_decode_with_their_matrix() {
        // BT.709 limited-range red is Y 63, Cb 102, Cr 240; 75 % red is Y 51, Cb 109, Cr 212
        // (R' = 0.75 · 255 ≈ 191).
        let f = yuyv_to_rgba(&[63, 102, 51, 240], ImageSize::new(2, 1), 0, BT709_LIMITED).unwrap();
        assert!(
            f.rgba[0] >= 254 && f.rgba[1] <= 1 && f.rgba[2] <= 1,
            "{:?}",
            f.rgba
        );
        let f = yuyv_to_rgba(&[51, 109, 51, 212], ImageSize::new(2, 1), 0, BT709_LIMITED).unwrap();
        let px = &f.rgba[..3];
        assert!(
            (px[0] as i32 - 191).abs() <= 1 && px[1] <= 1 && px[2] <= 1,
            "{px:?}"
        );
        // The same bytes through BT.601 give a visibly different red (233, not 255).
        let c601 = YCbCr {
            matrix: Matrix::Bt601,
            range: Range::Limited,
        };
        let g = yuyv_to_rgba(&[63, 102, 63, 240], ImageSize::new(2, 1), 0, c601).unwrap();
        assert!(g.rgba[0] < 240, "{:?}", &g.rgba[..3]);
        // JPEG (BT.601 full range) pure red: Y 76, Cb 85, Cr 255.
        let f = yuyv_to_rgba(&[76, 85, 76, 255], ImageSize::new(2, 1), 0, BT601_FULL).unwrap();
        assert!(
            f.rgba[0] >= 253 && f.rgba[1] <= 2 && f.rgba[2] <= 2,
            "{:?}",
            &f.rgba[..3]
        );
    }

    #[test]
    fn yuyv_rows_honour_the_stride() {
        // 2x2 with 2 bytes of padding per row (stride 6); the padding must not leak.
        let src = [128, 128, 128, 128, 9, 9, 0, 128, 0, 128];
        let f = yuyv_to_rgba(&src, ImageSize::new(2, 2), 6, BT601_FULL).unwrap();
        assert_eq!(&f.rgba[..4], &[128, 128, 128, 255]);
        assert_eq!(&f.rgba[8..12], &[0, 0, 0, 255]);
        // One byte short of the last row: corrupt.
        assert!(yuyv_to_rgba(&src[..9], ImageSize::new(2, 2), 6, BT601_FULL).is_err());
        // A stride shorter than a row, and an odd width, are errors.
        assert!(yuyv_to_rgba(&src, ImageSize::new(2, 2), 3, BT601_FULL).is_err());
        assert!(yuyv_to_rgba(&[0; 12], ImageSize::new(3, 1), 0, BT601_FULL).is_err());
    }

    #[test]
    fn nv12_uses_one_chroma_pair_per_2x2_block_and_the_stride() {
        // 4x2, stride 6 (2 bytes padding): Y rows then one UV row.
        let (w, h, s) = (4, 2, 6);
        let mut src = vec![0u8; s * h + s];
        for y in 0..h {
            for x in 0..w {
                src[y * s + x] = 128;
            }
            src[y * s + 4] = 7; // padding
        }
        // Left block neutral, right block strong Cr (red).
        src[s * h..s * h + 4].copy_from_slice(&[128, 128, 128, 255]);
        let f = nv12_to_rgba(&src, ImageSize::new(w, h), s, BT601_FULL).unwrap();
        let px = |x: usize, y: usize| &f.rgba[(y * w + x) * 4..(y * w + x) * 4 + 3];
        assert_eq!(px(0, 0), &[128, 128, 128]);
        assert_eq!(px(1, 1), &[128, 128, 128]);
        assert!(px(2, 0)[0] > 250 && px(3, 1)[1] < 60, "{:?}", px(3, 1));
        // Odd height: ceil(h/2) chroma rows are needed.
        let odd = ImageSize::new(2, 3);
        assert_eq!(PixelFormat::Nv12.min_bytes(odd, 0), 2 * 3 + 2 * 2);
        assert!(nv12_to_rgba(&[128; 9], odd, 0, BT601_FULL).is_err());
        assert!(nv12_to_rgba(&[128; 10], odd, 0, BT601_FULL).is_ok());
    }

    #[test]
    fn rgb24_rows_honour_the_stride() {
        let f = rgb24_to_rgba(&[1, 2, 3, 0, 4, 5, 6], ImageSize::new(1, 2), 4).unwrap();
        assert_eq!(f.rgba, vec![1, 2, 3, 255, 4, 5, 6, 255]);
        assert!(rgb24_to_rgba(&[1, 2, 3, 0, 4, 5], ImageSize::new(1, 2), 4).is_err());
        let f = rgb24_to_rgba(&[9, 8, 7], ImageSize::new(1, 1), 0).unwrap();
        assert_eq!(f.rgba, vec![9, 8, 7, 255]);
    }

    #[test]
    fn decode_dispatches_and_gives_camera_images_in_unit_range() {
        let f = decode(
            PixelFormat::Rgb24,
            ImageSize::new(1, 1),
            0,
            BT601_FULL,
            &[255, 0, 51],
        )
        .unwrap();
        let img: crate::raster::CamImage = f.to_image();
        let v = img.get(0, 0);
        assert_eq!(v, [1.0, 0.0, 0.2]);
    }
}
