//! MJPEG frames: each buffer one JPEG image, decoded with the `image` crate's JPEG decoder to
//! RGBA (camera pixels, sRGB-encoded values; JPEG is full-range BT.601 by definition).
//!
//! Two UVC habits are handled before decoding:
//! - Many cameras leave out the Huffman tables (the "MJPG" of AVI files uses the fixed tables of
//!   ITU-T T.81 Annex K.3), so a frame without a DHT segment gets those tables inserted.
//! - A frame cut short on the bus can still decode (lenient decoders fill the missing blocks
//!   with gray), so a frame must end with the end-of-image marker (trailing zero padding
//!   allowed) or it is corrupt.

use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// Start of image, Huffman tables, start of scan, end of image (the byte after 0xFF).
const SOI: u8 = 0xD8;
const DHT: u8 = 0xC4;
const SOS: u8 = 0xDA;
const EOI: u8 = 0xD9;

/// The DHT segment of ITU-T T.81 tables K.3–K.6 (luma DC, chroma DC, luma AC, chroma AC):
/// for each, the class/id byte, the 16 code counts by length, then the symbols.
fn default_huffman_segment() -> Vec<u8> {
    const LUMA_DC_BITS: [u8; 16] = [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
    const CHROMA_DC_BITS: [u8; 16] = [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0];
    const DC_VALUES: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    const LUMA_AC_BITS: [u8; 16] = [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7D];
    const LUMA_AC_VALUES: [u8; 162] = [
        0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61,
        0x07, 0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xA1, 0x08, 0x23, 0x42, 0xB1, 0xC1, 0x15, 0x52,
        0xD1, 0xF0, 0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0A, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x25,
        0x26, 0x27, 0x28, 0x29, 0x2A, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45,
        0x46, 0x47, 0x48, 0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64,
        0x65, 0x66, 0x67, 0x68, 0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x83,
        0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99,
        0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6,
        0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3,
        0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE1, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8,
        0xE9, 0xEA, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8, 0xF9, 0xFA,
    ];
    const CHROMA_AC_BITS: [u8; 16] = [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77];
    const CHROMA_AC_VALUES: [u8; 162] = [
        0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61,
        0x71, 0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xA1, 0xB1, 0xC1, 0x09, 0x23, 0x33,
        0x52, 0xF0, 0x15, 0x62, 0x72, 0xD1, 0x0A, 0x16, 0x24, 0x34, 0xE1, 0x25, 0xF1, 0x17, 0x18,
        0x19, 0x1A, 0x26, 0x27, 0x28, 0x29, 0x2A, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44,
        0x45, 0x46, 0x47, 0x48, 0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63,
        0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A,
        0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97,
        0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4,
        0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA,
        0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7,
        0xE8, 0xE9, 0xEA, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8, 0xF9, 0xFA,
    ];
    let tables: [(u8, &[u8; 16], &[u8]); 4] = [
        (0x00, &LUMA_DC_BITS, &DC_VALUES),
        (0x01, &CHROMA_DC_BITS, &DC_VALUES),
        (0x10, &LUMA_AC_BITS, &LUMA_AC_VALUES),
        (0x11, &CHROMA_AC_BITS, &CHROMA_AC_VALUES),
    ];
    let body: usize = tables.iter().map(|(_, _, v)| 17 + v.len()).sum();
    let len = (body + 2) as u16;
    let mut seg = vec![0xFF, DHT, (len >> 8) as u8, len as u8];
    for (class_id, bits, values) in tables {
        seg.push(class_id);
        seg.extend_from_slice(bits);
        seg.extend_from_slice(values);
    }
    seg
}

/// Whether the JPEG's header (the segments before the first scan) holds Huffman tables. A
/// header that cannot be walked counts as having them (the decoder then says what is wrong).
fn has_huffman_tables(data: &[u8]) -> bool {
    let mut i = 2;
    while i + 1 < data.len() {
        if data[i] != 0xFF {
            return true;
        }
        let marker = data[i + 1];
        match marker {
            0xFF => i += 1, // fill byte
            DHT => return true,
            SOS | EOI => return false,
            0x01 | 0xD0..=0xD7 => i += 2, // markers without a length
            _ => {
                let Some(len) = data.get(i + 2..i + 4) else {
                    return true;
                };
                i += 2 + u16::from_be_bytes([len[0], len[1]]) as usize;
            }
        }
    }
    true
}

/// Whether the frame ends with the end-of-image marker, after any zero padding a driver added.
fn ends_with_eoi(data: &[u8]) -> bool {
    let end = data.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    end >= 2 && data[end - 2] == 0xFF && data[end - 1] == EOI
}

/// The frame with the standard Huffman tables inserted after SOI when it has none; `None` when
/// it needs nothing.
pub fn with_default_tables(data: &[u8]) -> Option<Vec<u8>> {
    if data.len() < 4 || has_huffman_tables(data) {
        return None;
    }
    let seg = default_huffman_segment();
    let mut out = Vec::with_capacity(data.len() + seg.len());
    out.extend_from_slice(&data[..2]);
    out.extend_from_slice(&seg);
    out.extend_from_slice(&data[2..]);
    Some(out)
}

/// One MJPEG frame to RGBA. It must start with SOI, end with EOI (zero padding allowed), decode,
/// and be `size` ((width, height), camera pixels); anything else is a corrupt frame (an error).
pub fn decode(data: &[u8], size: ImageSize) -> Result<ContentFrame> {
    if data.len() < 4 || data[0] != 0xFF || data[1] != SOI {
        return Err(Error::Failed(format!(
            "MJPEG frame of {} bytes does not start with a JPEG header (corrupt frame)",
            data.len()
        )));
    }
    if !ends_with_eoi(data) {
        return Err(Error::Failed(format!(
            "MJPEG frame of {} bytes has no end-of-image marker (truncated frame)",
            data.len()
        )));
    }
    let fixed = with_default_tables(data);
    let bytes = fixed.as_deref().unwrap_or(data);
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
        .map_err(|e| Error::Failed(format!("MJPEG frame does not decode: {e}")))?
        .to_rgba8();
    let (w, h) = img.dimensions();
    if (w as usize, h as usize) != (size.width, size.height) {
        return Err(Error::Failed(format!(
            "MJPEG frame is {w}x{h}, the device was set to {size}"
        )));
    }
    ContentFrame::from_rgba(w as usize, h as usize, img.into_raw())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w`×`h` JPEG of a colour gradient, from the `image` crate's encoder (which writes the
    /// Annex K tables).
    pub(crate) fn jpeg(w: u32, h: u32) -> Vec<u8> {
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([(x * 255 / w) as u8, (y * 255 / h) as u8, 128])
        });
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
            .encode_image(&img)
            .unwrap();
        out
    }

    /// The JPEG without its DHT segments.
    fn strip_dht(data: &[u8]) -> Vec<u8> {
        let mut out = data[..2].to_vec();
        let mut i = 2;
        while data[i + 1] != SOS {
            let len = u16::from_be_bytes([data[i + 2], data[i + 3]]) as usize;
            if data[i + 1] != DHT {
                out.extend_from_slice(&data[i..i + 2 + len]);
            }
            i += 2 + len;
        }
        out.extend_from_slice(&data[i..]);
        out
    }

    #[test]
    fn decodes_a_jpeg_frame_with_padding() {
        let mut data = jpeg(32, 16);
        data.extend_from_slice(&[0; 100]);
        let f = decode(&data, ImageSize::new(32, 16)).unwrap();
        assert_eq!(f.size(), ImageSize::new(32, 16));
        // The gradient survives: red grows to the right.
        assert!(f.rgba[(8 * 32 + 30) * 4] > f.rgba[(8 * 32 + 1) * 4] + 150);
    }

    #[test]
    fn frames_without_huffman_tables_get_the_standard_ones() {
        let data = jpeg(24, 16);
        let bare = strip_dht(&data);
        assert!(bare.len() < data.len() && !has_huffman_tables(&bare));
        assert!(has_huffman_tables(&data));
        assert_eq!(default_huffman_segment().len(), 2 + 418);
        let a = decode(&data, ImageSize::new(24, 16)).unwrap();
        let b = decode(&bare, ImageSize::new(24, 16)).unwrap();
        assert_eq!(a.rgba, b.rgba);
        assert!(with_default_tables(&data).is_none());
    }

    #[test]
    fn truncated_garbage_and_mis_sized_frames_are_corrupt() {
        let data = jpeg(32, 16);
        let size = ImageSize::new(32, 16);
        assert!(decode(&data[..data.len() / 2], size).is_err());
        assert!(decode(&data[2..], size).is_err());
        assert!(decode(&[0xFF, 0xD8, 0xFF, 0xD9], size).is_err());
        assert!(decode(&[], size).is_err());
        let e = decode(&data, ImageSize::new(64, 16)).unwrap_err();
        assert!(e.to_string().contains("32x16"), "{e}");
        // Damaged entropy-coded data between intact markers must not come back as a frame of
        // the wrong size or panic; whatever the decoder makes of it is at least 32x16 RGBA.
        let mut bad = data.clone();
        let n = bad.len();
        for b in &mut bad[n / 2..n / 2 + 8] {
            *b = 0xFF;
        }
        if let Ok(f) = decode(&bad, size) {
            assert_eq!(f.rgba.len(), 32 * 16 * 4);
        }
    }
}
