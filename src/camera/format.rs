//! What a camera offers and what compend picks: pixel formats with their frame sizes and rates
//! ([`FormatOffer`]), the choice made on open ([`choose_format`]), and the format the driver
//! set, with its colorimetry ([`ActiveFormat`]).

use std::path::Path;

use serde::Serialize;

use super::pixels::{FourCc, Matrix, PixelFormat, Range, YCbCr};
use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// One frame size a format offers, with its frame rates.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SizeOffer {
    /// (width, height) in camera pixels.
    #[serde(flatten)]
    pub size: ImageSize,
    /// Frame rates in frames per second, fastest first; for a continuous or stepwise range,
    /// its two ends (`fps_range`).
    pub fps: Vec<f64>,
    /// Whether `fps` is a range [slowest, fastest] in which any rate may be set.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub fps_range: bool,
}

/// Frame sizes given as a range (capture cards; UVC cameras list discrete sizes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct SizeSteps {
    pub min: ImageSize,
    pub max: ImageSize,
    /// Increments of width and height from `min` (1 for a continuous range).
    pub step: ImageSize,
}

impl SizeSteps {
    fn contains(&self, s: ImageSize) -> bool {
        let on = |v: usize, lo: usize, hi: usize, step: usize| {
            v >= lo && v <= hi && (v - lo).is_multiple_of(step.max(1))
        };
        on(s.width, self.min.width, self.max.width, self.step.width)
            && on(s.height, self.min.height, self.max.height, self.step.height)
    }
}

/// A pixel format a device offers.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FormatOffer {
    pub fourcc: FourCc,
    /// The driver's description ("YUYV 4:2:2", "Motion-JPEG").
    pub description: String,
    /// Discrete frame sizes.
    pub sizes: Vec<SizeOffer>,
    /// A range of frame sizes, when the driver gives one instead of a list.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<SizeSteps>,
}

impl FormatOffer {
    /// Whether frames of `size` can be had in this format.
    pub fn offers(&self, size: ImageSize) -> bool {
        self.sizes.iter().any(|s| s.size == size) || self.steps.is_some_and(|r| r.contains(size))
    }

    /// The largest size (by pixel count) this format offers.
    pub fn largest(&self) -> Option<ImageSize> {
        let listed = self.sizes.iter().map(|s| s.size);
        listed
            .chain(self.steps.map(|r| r.max))
            .max_by_key(|s| s.width * s.height)
    }

    /// For messages: "YUYV (640x480, 1280x720)".
    pub fn summary(&self) -> String {
        let mut sizes: Vec<String> = self.sizes.iter().map(|s| s.size.to_string()).collect();
        if let Some(r) = self.steps {
            sizes.push(format!("{} to {} in steps of {}", r.min, r.max, r.step));
        }
        format!("{} ({})", self.fourcc, sizes.join(", "))
    }
}

/// The pixel format and frame size compend asks the driver for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FormatChoice {
    pub format: PixelFormat,
    /// (width, height) in camera pixels.
    pub size: ImageSize,
}

/// Picks the format to open `device` with, from what it `offers`:
/// - the size is `requested`, else the device's `current` size when a readable format offers
///   it, else the largest size a readable format offers;
/// - at that size, the first of YUYV, NV12 and RGB24 offered (uncompressed), else MJPEG.
///
/// A device offering none of those formats, or none at the requested size, is an input error
/// naming the device and listing what it offers.
pub fn choose_format(
    device: &Path,
    offers: &[FormatOffer],
    requested: Option<ImageSize>,
    current: Option<ImageSize>,
) -> Result<FormatChoice> {
    let readable: Vec<(PixelFormat, &FormatOffer)> = PixelFormat::PREFERRED
        .iter()
        .flat_map(|p| {
            offers
                .iter()
                .filter(move |o| PixelFormat::from_fourcc(o.fourcc) == Some(*p))
                .map(move |o| (*p, o))
        })
        .collect();
    if readable.is_empty() {
        let offered: Vec<String> = offers
            .iter()
            .map(|o| format!("{} \"{}\"", o.fourcc, o.description))
            .collect();
        return Err(Error::Input(format!(
            "{}: offers no pixel format compend reads (YUYV, NV12, RGB3 or MJPG); it offers: {}. \
             Use another camera, or set the device to one of those formats if it can switch",
            device.display(),
            if offered.is_empty() {
                "nothing".to_string()
            } else {
                offered.join(", ")
            }
        )));
    }
    let at = |size: ImageSize| {
        readable
            .iter()
            .find(|(_, o)| o.offers(size))
            .map(|(p, _)| *p)
    };
    let size = match (requested, current) {
        (Some(s), _) => s,
        (None, Some(c)) if at(c).is_some() => c,
        _ => readable
            .iter()
            .filter_map(|(_, o)| o.largest())
            .max_by_key(|s| s.width * s.height)
            .ok_or_else(|| {
                Error::Input(format!(
                    "{}: lists no frame sizes for {}",
                    device.display(),
                    readable[0].1.fourcc
                ))
            })?,
    };
    match at(size) {
        Some(format) => Ok(FormatChoice { format, size }),
        None => Err(Error::Input(format!(
            "{}: no readable format offers {size}; it offers {}. Ask for one of those sizes",
            device.display(),
            readable
                .iter()
                .map(|(_, o)| o.summary())
                .collect::<Vec<_>>()
                .join("; ")
        ))),
    }
}

/// V4L2 colorimetry codes (`enum v4l2_colorspace`, `v4l2_ycbcr_encoding`, `v4l2_quantization`).
pub mod v4l2_codes {
    pub const COLORSPACE_SMPTE170M: u32 = 1;
    pub const COLORSPACE_SMPTE240M: u32 = 2;
    pub const COLORSPACE_REC709: u32 = 3;
    pub const COLORSPACE_470_SYSTEM_M: u32 = 5;
    pub const COLORSPACE_470_SYSTEM_BG: u32 = 6;
    pub const COLORSPACE_JPEG: u32 = 7;
    pub const COLORSPACE_BT2020: u32 = 10;
    pub const COLORSPACE_DCI_P3: u32 = 12;
    pub const YCBCR_ENC_601: u32 = 1;
    pub const YCBCR_ENC_709: u32 = 2;
    pub const YCBCR_ENC_XV601: u32 = 3;
    pub const YCBCR_ENC_XV709: u32 = 4;
    pub const YCBCR_ENC_SYCC: u32 = 5;
    pub const YCBCR_ENC_BT2020: u32 = 6;
    pub const YCBCR_ENC_BT2020_CONST_LUM: u32 = 7;
    pub const YCBCR_ENC_SMPTE240M: u32 = 8;
    pub const QUANTIZATION_FULL_RANGE: u32 = 1;
    pub const QUANTIZATION_LIM_RANGE: u32 = 2;
}

/// The format a driver set, as it reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ActiveFormat {
    pub format: PixelFormat,
    /// (width, height) in camera pixels.
    pub size: ImageSize,
    /// Bytes from one row to the next (`bytesperline`; 0 when the driver gives none).
    pub stride: usize,
    /// The driver's `colorspace`, `ycbcr_enc` and `quantization` fields (0: default).
    pub colorspace: u32,
    pub ycbcr_enc: u32,
    pub quantization: u32,
}

impl ActiveFormat {
    /// How the device's Y'CbCr maps to R'G'B'. The matrix is the driver's `ycbcr_enc` when it
    /// names one, else the one its `colorspace` implies (SMPTE 170M, JPEG: BT.601; Rec. 709,
    /// DCI-P3: BT.709; BT.2020; SMPTE 240M), else by frame size: BT.709 from 720 rows up (HD),
    /// BT.601 below (SD). sRGB and the default colorspace count as saying nothing: V4L2 maps
    /// them to BT.601 by convention, not because a camera reported it. The range is the
    /// driver's `quantization` when set, else full for the JPEG colorspace and limited
    /// otherwise (V4L2's default for Y'CbCr).
    pub fn ycbcr(&self) -> YCbCr {
        use v4l2_codes::*;
        let matrix = match self.ycbcr_enc {
            YCBCR_ENC_601 | YCBCR_ENC_XV601 | YCBCR_ENC_SYCC => Some(Matrix::Bt601),
            YCBCR_ENC_709 | YCBCR_ENC_XV709 => Some(Matrix::Bt709),
            YCBCR_ENC_BT2020 | YCBCR_ENC_BT2020_CONST_LUM => Some(Matrix::Bt2020),
            YCBCR_ENC_SMPTE240M => Some(Matrix::Smpte240m),
            _ => match self.colorspace {
                COLORSPACE_SMPTE170M
                | COLORSPACE_470_SYSTEM_M
                | COLORSPACE_470_SYSTEM_BG
                | COLORSPACE_JPEG => Some(Matrix::Bt601),
                COLORSPACE_REC709 | COLORSPACE_DCI_P3 => Some(Matrix::Bt709),
                COLORSPACE_BT2020 => Some(Matrix::Bt2020),
                COLORSPACE_SMPTE240M => Some(Matrix::Smpte240m),
                _ => None,
            },
        };
        let matrix = matrix.unwrap_or(if self.size.height >= 720 {
            Matrix::Bt709
        } else {
            Matrix::Bt601
        });
        let range = match self.quantization {
            QUANTIZATION_FULL_RANGE => Range::Full,
            QUANTIZATION_LIM_RANGE => Range::Limited,
            _ if self.colorspace == COLORSPACE_JPEG => Range::Full,
            _ => Range::Limited,
        };
        YCbCr { matrix, range }
    }
}

#[cfg(test)]
mod tests {
    use super::v4l2_codes::*;
    use super::*;

    fn offer(code: &[u8; 4], sizes: &[(usize, usize)]) -> FormatOffer {
        FormatOffer {
            fourcc: FourCc(*code),
            description: String::from_utf8_lossy(code).into_owned(),
            sizes: sizes
                .iter()
                .map(|&(w, h)| SizeOffer {
                    size: ImageSize::new(w, h),
                    fps: vec![30.0],
                    fps_range: false,
                })
                .collect(),
            steps: None,
        }
    }

    fn dev() -> &'static Path {
        Path::new("/dev/video7")
    }

    #[test]
    fn uncompressed_is_preferred_at_the_requested_size_else_mjpeg() {
        // A typical UVC camera: MJPEG listed first, YUYV only up to 640x480.
        let offers = [
            offer(b"MJPG", &[(1920, 1080), (1280, 720), (640, 480)]),
            offer(b"YUYV", &[(640, 480), (320, 240)]),
        ];
        let pick = |s: Option<(usize, usize)>| {
            choose_format(dev(), &offers, s.map(ImageSize::from), None).unwrap()
        };
        assert_eq!(pick(Some((640, 480))).format, PixelFormat::Yuyv);
        let hd = pick(Some((1280, 720)));
        assert_eq!(
            (hd.format, hd.size),
            (PixelFormat::Mjpeg, ImageSize::new(1280, 720))
        );
        // No size asked, no current size: the largest, in the best format that has it.
        let big = pick(None);
        assert_eq!(
            (big.format, big.size),
            (PixelFormat::Mjpeg, ImageSize::new(1920, 1080))
        );
        // The current size is kept when nothing is asked.
        let cur = choose_format(dev(), &offers, None, Some(ImageSize::new(320, 240))).unwrap();
        assert_eq!(
            (cur.format, cur.size),
            (PixelFormat::Yuyv, ImageSize::new(320, 240))
        );
        // NV12 beats RGB24, YUYV beats both.
        let offers = [offer(b"RGB3", &[(64, 48)]), offer(b"NV12", &[(64, 48)])];
        let c = choose_format(dev(), &offers, Some(ImageSize::new(64, 48)), None).unwrap();
        assert_eq!(c.format, PixelFormat::Nv12);
    }

    #[test]
    fn unreadable_formats_and_sizes_are_input_errors_naming_the_device() {
        let offers = [offer(b"BA81", &[(640, 480)]), offer(b"H264", &[(640, 480)])];
        let e = choose_format(dev(), &offers, None, None).unwrap_err();
        let msg = e.to_string();
        assert_eq!(e.exit_code(), 2);
        assert!(
            msg.contains("/dev/video7") && msg.contains("BA81") && msg.contains("H264"),
            "{msg}"
        );
        let offers = [offer(b"YUYV", &[(640, 480)])];
        let e = choose_format(dev(), &offers, Some(ImageSize::new(800, 600)), None).unwrap_err();
        let msg = e.to_string();
        assert_eq!(e.exit_code(), 2);
        assert!(
            msg.contains("/dev/video7") && msg.contains("800x600") && msg.contains("640x480"),
            "{msg}"
        );
    }

    #[test]
    fn stepwise_sizes_are_honoured() {
        let mut o = offer(b"YUYV", &[]);
        o.steps = Some(SizeSteps {
            min: ImageSize::new(16, 16),
            max: ImageSize::new(1920, 1080),
            step: ImageSize::new(16, 8),
        });
        assert!(o.offers(ImageSize::new(640, 480)));
        assert!(!o.offers(ImageSize::new(641, 480)));
        assert!(!o.offers(ImageSize::new(3840, 2160)));
        assert_eq!(o.largest(), Some(ImageSize::new(1920, 1080)));
        assert!(o.summary().contains("16x16 to 1920x1080"));
    }

    fn active(h: usize, cs: u32, enc: u32, q: u32) -> ActiveFormat {
        ActiveFormat {
            format: PixelFormat::Yuyv,
            size: ImageSize::new(h * 16 / 9, h),
            stride: 0,
            colorspace: cs,
            ycbcr_enc: enc,
            quantization: q,
        }
    }

    #[test]
    fn colorimetry_follows_the_driver_else_the_frame_size() {
        let c = |f: ActiveFormat| {
            let y = f.ycbcr();
            (y.matrix, y.range)
        };
        // Nothing said: SD is BT.601, HD BT.709, limited range.
        assert_eq!(c(active(480, 0, 0, 0)), (Matrix::Bt601, Range::Limited));
        assert_eq!(c(active(720, 0, 0, 0)), (Matrix::Bt709, Range::Limited));
        // sRGB colorspace (what older uvcvideo reports) says nothing about the matrix either.
        assert_eq!(c(active(1080, 8, 0, 0)).0, Matrix::Bt709);
        // The driver's encoding wins over the size, in both directions.
        assert_eq!(c(active(1080, 0, YCBCR_ENC_601, 0)).0, Matrix::Bt601);
        assert_eq!(c(active(480, 0, YCBCR_ENC_709, 0)).0, Matrix::Bt709);
        assert_eq!(c(active(480, COLORSPACE_REC709, 0, 0)).0, Matrix::Bt709);
        assert_eq!(c(active(1080, COLORSPACE_SMPTE170M, 0, 0)).0, Matrix::Bt601);
        assert_eq!(c(active(1080, COLORSPACE_BT2020, 0, 0)).0, Matrix::Bt2020);
        // Quantisation: explicit, else full for JPEG and limited otherwise.
        assert_eq!(c(active(480, 0, 0, QUANTIZATION_FULL_RANGE)).1, Range::Full);
        assert_eq!(
            c(active(480, COLORSPACE_JPEG, 0, 0)),
            (Matrix::Bt601, Range::Full)
        );
        assert_eq!(
            c(active(480, COLORSPACE_JPEG, 0, QUANTIZATION_LIM_RANGE)).1,
            Range::Limited
        );
    }
}
