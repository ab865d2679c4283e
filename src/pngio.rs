//! PNG reading and writing. On disk images are 8-bit sRGB-encoded RGB (no colour management);
//! in memory they are f32 in [0,1]. Writing rounds to the nearest 8-bit level (never truncates).
//! 16-bit PNGs are read at full precision; grayscale and alpha inputs are converted to RGB.

use std::path::Path;

use crate::error::{Error, Result};
use crate::raster::{ImageSize, Levels, Mask, Plane, Rgb, Space};

/// Reads a PNG as an RGB f32 image in space `S`.
pub fn read_rgb<S: Space>(path: &Path) -> Result<Rgb<S>> {
    let img = decode(path)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let data: Vec<f32> = if is_sixteen_bit(&img) {
        img.into_rgb16()
            .into_raw()
            .into_iter()
            .map(|v| v as f32 / 65535.0)
            .collect()
    } else {
        img.into_rgb8()
            .into_raw()
            .into_iter()
            .map(|v| v as f32 / 255.0)
            .collect()
    };
    Rgb::from_vec(w, h, data)
}

/// Reads a PNG as its RGB levels in space `S` (8 or 16 bits a value, as stored): a quarter or
/// half of [`read_rgb`]'s memory, and the same values ([`Levels`]).
pub fn read_levels<S: Space>(path: &Path) -> Result<Levels<S>> {
    let img = decode(path)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if is_sixteen_bit(&img) {
        Levels::from_u16(w, h, img.into_rgb16().into_raw())
    } else {
        Levels::from_u8(w, h, img.into_rgb8().into_raw())
    }
}

/// [`read_levels`], checking the size as [`read_rgb_sized`] does.
pub fn read_levels_sized<S: Space>(
    path: &Path,
    expected: ImageSize,
    why: &str,
) -> Result<Levels<S>> {
    let img = read_levels::<S>(path)?;
    check_size(path, img.size(), expected, why)?;
    Ok(img)
}

/// A PNG file decoded (its alpha channel is dropped later, with a warning here when it held
/// anything).
fn decode(path: &Path) -> Result<image::DynamicImage> {
    let bytes = crate::files::read_regular(path, "a PNG image", crate::files::MAX_IMAGE_BYTES)?;
    let img =
        image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| {
            Error::Decode {
                path: path.to_path_buf(),
                reason: e.to_string(),
            }
        })?;
    warn_if_translucent(path, &img);
    Ok(img)
}

fn is_sixteen_bit(img: &image::DynamicImage) -> bool {
    matches!(
        img,
        image::DynamicImage::ImageLuma16(_)
            | image::DynamicImage::ImageLumaA16(_)
            | image::DynamicImage::ImageRgb16(_)
            | image::DynamicImage::ImageRgba16(_)
    )
}

/// The alpha channel is dropped on reading (compend's images are RGB). That loses nothing when
/// every pixel is opaque; otherwise the picture a person saw is not the one used, so it is
/// logged as a warning naming the file.
fn warn_if_translucent(path: &Path, img: &image::DynamicImage) {
    let translucent = match img {
        image::DynamicImage::ImageLumaA8(i) => i.pixels().filter(|p| p.0[1] < u8::MAX).count(),
        image::DynamicImage::ImageRgba8(i) => i.pixels().filter(|p| p.0[3] < u8::MAX).count(),
        image::DynamicImage::ImageLumaA16(i) => i.pixels().filter(|p| p.0[1] < u16::MAX).count(),
        image::DynamicImage::ImageRgba16(i) => i.pixels().filter(|p| p.0[3] < u16::MAX).count(),
        _ => 0,
    };
    if translucent > 0 {
        tracing::warn!(
            "{}: alpha channel dropped, {translucent} of {} pixels are not opaque (compend reads \
             RGB; save captures without transparency)",
            path.display(),
            img.width() as usize * img.height() as usize
        );
    }
}

/// Reads a PNG and checks its size, naming `why` (what the size is required for) on mismatch.
pub fn read_rgb_sized<S: Space>(path: &Path, expected: ImageSize, why: &str) -> Result<Rgb<S>> {
    let img = read_rgb::<S>(path)?;
    check_size(path, img.size(), expected, why)?;
    Ok(img)
}

fn check_size(path: &Path, got: ImageSize, expected: ImageSize, why: &str) -> Result<()> {
    if got != expected {
        return Err(Error::Size {
            path: path.to_path_buf(),
            got,
            expected,
            why: why.to_string(),
        });
    }
    Ok(())
}

/// Only the (width, height) of a PNG, from its header.
pub fn png_size(path: &Path) -> Result<ImageSize> {
    let (file, _) = crate::files::open_regular(path, "a PNG image")?;
    let reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| Error::io(path, "read", e))?;
    let (w, h) = reader.into_dimensions().map_err(|e| Error::Decode {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(ImageSize::new(w as usize, h as usize))
}

/// Whether a PNG is grayscale (with or without alpha), from its header.
pub fn is_grayscale(path: &Path) -> Result<bool> {
    use image::ImageDecoder;
    let (file, _) = crate::files::open_regular(path, "a PNG image")?;
    let decoder = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| Error::io(path, "read", e))?
        .into_decoder()
        .map_err(|e| Error::Decode {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    Ok(matches!(
        decoder.color_type(),
        image::ColorType::L8
            | image::ColorType::La8
            | image::ColorType::L16
            | image::ColorType::La16
    ))
}

/// Converts a value in [0,1] to 8 bits, rounding to nearest and clamping.
#[inline]
pub fn to_u8(v: f32) -> u8 {
    // NaN maps to 0 through the saturating cast.
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// An image as 8-bit RGBA bytes, row-major, alpha 255 ([`to_u8`] per value): what a texture
/// of the projector frame format or a raw RGBA video frame takes.
pub fn to_rgba8<S: Space>(img: &Rgb<S>) -> Vec<u8> {
    let mut rgba = Vec::with_capacity(img.width() * img.height() * 4);
    for px in img.data().chunks_exact(3) {
        rgba.extend(px.iter().map(|&v| to_u8(v)));
        rgba.push(255);
    }
    rgba
}

/// Quantises an image to 8 bits (as saving and reloading it would).
pub fn quantize<S: Space>(img: &Rgb<S>) -> Rgb<S> {
    img.map(|v| to_u8(v) as f32 / 255.0)
}

/// Writes an RGB image as an 8-bit PNG, atomically ([`crate::files::write_with`]): a reader
/// never sees a half-written image. Parent folders are created.
pub fn write_rgb<S: Space>(path: &Path, img: &Rgb<S>) -> Result<()> {
    let bytes: Vec<u8> = img.data().iter().map(|&v| to_u8(v)).collect();
    write_png(
        path,
        &bytes,
        img.width(),
        img.height(),
        image::ColorType::Rgb8,
    )
}

/// Writes a plane as an 8-bit grayscale PNG (values clamped to [0,1]).
pub fn write_plane<S: Space>(path: &Path, img: &Plane<S>) -> Result<()> {
    let bytes: Vec<u8> = img.data().iter().map(|&v| to_u8(v)).collect();
    write_png(
        path,
        &bytes,
        img.width(),
        img.height(),
        image::ColorType::L8,
    )
}

/// Writes a mask as an 8-bit grayscale PNG (255 inside, 0 outside).
pub fn write_mask<S: Space>(path: &Path, mask: &Mask<S>) -> Result<()> {
    let bytes: Vec<u8> = mask
        .data()
        .iter()
        .map(|&b| if b { 255 } else { 0 })
        .collect();
    write_png(
        path,
        &bytes,
        mask.width(),
        mask.height(),
        image::ColorType::L8,
    )
}

/// Reads a mask PNG: a pixel is inside when its luma is at least one half.
pub fn read_mask<S: Space>(path: &Path) -> Result<Mask<S>> {
    let img = read_rgb::<S>(path)?;
    Ok(img.to_gray().threshold(0.5 - 1e-6))
}

fn write_png(path: &Path, bytes: &[u8], w: usize, h: usize, color: image::ColorType) -> Result<()> {
    crate::files::write_with(path, |out| {
        let encoder = image::codecs::png::PngEncoder::new_with_quality(
            out,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Adaptive,
        );
        image::ImageEncoder::write_image(encoder, bytes, w as u32, h as u32, color.into()).map_err(
            |e| match e {
                image::ImageError::IoError(e) => Error::io(path, "write", e),
                e => Error::Failed(format!("{}: PNG encoding failed: {e}", path.display())),
            },
        )
    })
}

/// The official dataset file name for a 1-based index: `img_0001.png`.
pub fn indexed_name(index: usize) -> String {
    format!("img_{index:04}.png")
}
