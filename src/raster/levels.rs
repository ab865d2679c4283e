//! RGB images held as the integer levels a PNG stores (8 or 16 bits a value), for the places
//! that hold many captures at once: a `linear` fit on 48 captures of 640×480 holds 44 MB of
//! 8-bit levels where f32 values took 177 MB (1.2 GB against 299 MB at 1920×1080).
//!
//! A level `v` reads as `v / 255` (8-bit) or `v / 65535` (16-bit) in f32, the value
//! [`crate::pngio::read_rgb`] gives for it, to the bit; so a fit reads the same numbers from
//! either. Layout as [`Rgb`]: row-major, interleaved RGB.

use std::borrow::Cow;
use std::fmt;
use std::hash::{Hash, Hasher};
use std::marker::PhantomData;

use super::{Mask, Rgb, Space, check_same_size};
use crate::error::{Error, Result};
use crate::size::ImageSize;

/// Read access to an RGB image's values (sRGB-encoded, nominally in [0,1]) however they are
/// held: [`Rgb`] (f32) or [`Levels`] (integer levels). The fits that hold many captures take
/// either.
pub trait ReadRgb<S: Space>: Sync {
    /// Its size in pixels.
    fn dimensions(&self) -> ImageSize;
    /// The value at index `i` of the interleaved layout: channel `i % 3` of pixel `i / 3`.
    fn value(&self, i: usize) -> f32;
    /// The image as f32 values (borrowed when it is held so).
    fn to_rgb(&self) -> Cow<'_, Rgb<S>>;
    /// Feeds the image's size and values to `h` (for fingerprints of what a fit saw).
    fn hash_values<H: Hasher>(&self, h: &mut H);

    /// The three values of pixel index `p = y · width + x`.
    #[inline]
    fn pixel(&self, p: usize) -> [f32; 3] {
        [
            self.value(p * 3),
            self.value(p * 3 + 1),
            self.value(p * 3 + 2),
        ]
    }
}

impl<S: Space> ReadRgb<S> for Rgb<S> {
    fn dimensions(&self) -> ImageSize {
        self.size()
    }
    #[inline]
    fn value(&self, i: usize) -> f32 {
        self.data()[i]
    }
    fn to_rgb(&self) -> Cow<'_, Rgb<S>> {
        Cow::Borrowed(self)
    }
    fn hash_values<H: Hasher>(&self, h: &mut H) {
        (self.width(), self.height()).hash(h);
        let bits: Vec<u32> = self.data().iter().map(|v| v.to_bits()).collect();
        bits.hash(h);
    }
}

/// An RGB image in space `S` held as integer levels ([the module](self)).
#[derive(Clone, PartialEq)]
pub struct Levels<S> {
    width: usize,
    height: usize,
    data: LevelData,
    _space: PhantomData<S>,
}

#[derive(Clone, PartialEq)]
enum LevelData {
    Eight(Vec<u8>),
    Sixteen(Vec<u16>),
}

impl<S: Space> fmt::Debug for Levels<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let bits = match self.data {
            LevelData::Eight(_) => 8,
            LevelData::Sixteen(_) => 16,
        };
        write!(
            f,
            "Levels<{}>({}x{}, {bits}-bit)",
            S::NAME,
            self.width,
            self.height
        )
    }
}

/// The f32 value of every 8-bit level, `v / 255` as [`crate::pngio::read_rgb`] computes it
/// (IEEE division rounds the same at compile time as at run time).
static EIGHT_BIT_VALUES: [f32; 256] = {
    let mut table = [0f32; 256];
    let mut v = 0;
    while v < 256 {
        table[v] = v as f32 / 255.0;
        v += 1;
    }
    table
};

impl<S: Space> Levels<S> {
    /// 8-bit levels, interleaved RGB; the length must be `width * height * 3`.
    pub fn from_u8(width: usize, height: usize, data: Vec<u8>) -> Result<Self> {
        check_len::<S>(width, height, data.len())?;
        Ok(Self::wrap(width, height, LevelData::Eight(data)))
    }

    /// 16-bit levels, interleaved RGB; the length must be `width * height * 3`.
    pub fn from_u16(width: usize, height: usize, data: Vec<u16>) -> Result<Self> {
        check_len::<S>(width, height, data.len())?;
        Ok(Self::wrap(width, height, LevelData::Sixteen(data)))
    }

    fn wrap(width: usize, height: usize, data: LevelData) -> Self {
        Self {
            width,
            height,
            data,
            _space: PhantomData,
        }
    }

    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }

    /// The image as f32 values.
    pub fn to_values(&self) -> Rgb<S> {
        let values: Vec<f32> = match &self.data {
            LevelData::Eight(d) => d.iter().map(|&v| EIGHT_BIT_VALUES[v as usize]).collect(),
            LevelData::Sixteen(d) => d.iter().map(|&v| v as f32 / 65535.0).collect(),
        };
        Rgb::wrap(self.width, self.height, values)
    }

    /// Sets every pixel outside `mask` to black (level 0), in place.
    pub fn into_masked(mut self, mask: &Mask<S>) -> Result<Self> {
        check_same_size(self.size(), mask.size(), "masking")?;
        match &mut self.data {
            LevelData::Eight(d) => blacken(d, mask),
            LevelData::Sixteen(d) => blacken(d, mask),
        }
        Ok(self)
    }

    pub fn into_space<T: Space>(self) -> Levels<T> {
        Levels::wrap(self.width, self.height, self.data)
    }
}

fn blacken<T: Copy + Default, S: Space>(data: &mut [T], mask: &Mask<S>) {
    for (px, &m) in data.chunks_exact_mut(3).zip(mask.data()) {
        if !m {
            px.fill(T::default());
        }
    }
}

fn check_len<S: Space>(width: usize, height: usize, len: usize) -> Result<()> {
    if len != width * height * 3 {
        return Err(Error::Shape(format!(
            "{} RGB image {width}x{height} needs {} levels, got {len}",
            S::NAME,
            width * height * 3,
        )));
    }
    Ok(())
}

impl<S: Space> ReadRgb<S> for Levels<S> {
    fn dimensions(&self) -> ImageSize {
        self.size()
    }
    #[inline]
    fn value(&self, i: usize) -> f32 {
        match &self.data {
            LevelData::Eight(d) => EIGHT_BIT_VALUES[d[i] as usize],
            LevelData::Sixteen(d) => d[i] as f32 / 65535.0,
        }
    }
    #[inline]
    fn pixel(&self, p: usize) -> [f32; 3] {
        let j = p * 3;
        match &self.data {
            LevelData::Eight(d) => {
                let v = &d[j..j + 3];
                [
                    EIGHT_BIT_VALUES[v[0] as usize],
                    EIGHT_BIT_VALUES[v[1] as usize],
                    EIGHT_BIT_VALUES[v[2] as usize],
                ]
            }
            LevelData::Sixteen(d) => {
                let v = &d[j..j + 3];
                [v[0], v[1], v[2]].map(|v| v as f32 / 65535.0)
            }
        }
    }
    fn to_rgb(&self) -> Cow<'_, Rgb<S>> {
        Cow::Owned(self.to_values())
    }
    fn hash_values<H: Hasher>(&self, h: &mut H) {
        (self.width, self.height).hash(h);
        match &self.data {
            LevelData::Eight(d) => (8u8, d).hash(h),
            LevelData::Sixteen(d) => (16u8, d).hash(h),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Camera;

    /// Levels read as the f32 values a PNG reader gives for them, to the bit, through every
    /// accessor, and masking blackens the same pixels as [`Rgb::into_masked`].
    #[test]
    fn levels_read_as_the_values_they_stand_for() {
        let eight: Vec<u8> = (0..=255u8).chain(0..8).collect();
        let img = Levels::<Camera>::from_u8(11, 8, eight.clone()).expect("88 pixels");
        let values = img.to_values();
        for (i, &v) in eight.iter().enumerate() {
            let want = v as f32 / 255.0;
            assert_eq!(values.data()[i].to_bits(), want.to_bits());
            assert_eq!(img.value(i).to_bits(), want.to_bits());
        }
        assert_eq!(img.pixel(5), [15.0 / 255.0, 16.0 / 255.0, 17.0 / 255.0]);
        let sixteen: Vec<u16> = (0..12).map(|i| i * 5900).collect();
        let img16 = Levels::<Camera>::from_u16(2, 2, sixteen.clone()).expect("4 pixels");
        for (i, &v) in sixteen.iter().enumerate() {
            assert_eq!(img16.value(i).to_bits(), (v as f32 / 65535.0).to_bits());
        }
        let mask = Mask::from_fn(11, 8, |x, y| (x + y) % 3 != 0);
        let masked = img.clone().into_masked(&mask).expect("same size");
        assert_eq!(
            masked.to_values(),
            values.into_masked(&mask).expect("same size")
        );
        assert!(Levels::<Camera>::from_u8(2, 2, vec![0; 11]).is_err());
        let err = img
            .into_masked(&Mask::full(3, 3))
            .expect_err("another size");
        assert!(err.to_string().contains("masking"), "{err}");
    }
}
