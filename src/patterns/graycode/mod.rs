//! Gray-code structured light: the patterns a projector shows and the decoder that turns their
//! captures into a dense camera → projector correspondence map.
//!
//! # Pattern sequence
//!
//! For a projector of `W×H` pixels, with `cb = ceil(log2 W)` column bits and `rb = ceil(log2 H)`
//! row bits, the sequence (0-based index `i`; on disk `sl/img_{i+1:04}.png`) is
//!
//! | index | image |
//! |---|---|
//! | 0 | white |
//! | 1 | black |
//! | 2 + 2k, 3 + 2k (k < cb) | column bit k (most significant first) and its inverse |
//! | 2 + 2cb + 2k, 3 + 2cb + 2k (k < rb) | row bit k (most significant first) and its inverse |
//!
//! so `len = 2 + 2·(cb + rb)`; 800×600 gives 10 + 10 bits and 42 images. Projector column `x`
//! carries the reflected binary Gray code `g = x ^ (x >> 1)`; in the pattern of column bit `k` a
//! pixel is white (1.0) where bit `cb − 1 − k` of `g(x)` is 1 and black (0.0) elsewhere; the
//! inverse is the complement. Rows likewise with `g(y)`. Codes are not centred: column 0 has code 0
//! and codes `W..2^cb` are never shown (a decoded code ≥ W is invalid).
//!
//! # Decoding
//!
//! Captures are in camera pixels, RGB in \[0,1\]; the decoder works on their channel mean. A camera
//! pixel is *lit* where `white − black` exceeds [`DecodeParams::lit_threshold`], a threshold
//! relative to the lit range of the whole capture (its 99th percentile of `white − black`) with an
//! absolute floor. A lit pixel is *valid* when, for every bit, `|pattern − inverse|` exceeds
//! [`DecodeParams::bit_threshold`] at that pixel (relative to its own `white − black`, with an
//! absolute floor), and the decoded column and row lie inside the projector. One exception, on
//! by default ([`DecodeParams::accept_boundary`]): a single undecided bit per axis is accepted
//! when flipping it changes the decoded column (row) by exactly one — the camera pixel straddles
//! the boundary between two neighbouring projector columns, which is what an undecided bit means
//! when the camera is coarser than the projector or slightly out of focus — and the coordinate
//! is then the midpoint of the two (`n + 0.5`). The correspondence
//! gives, per camera pixel, the projector position `(x, y)` it sees, in projector pixel
//! coordinates with pixel centres at integers (`0..W−1`, `0..H−1`; boundary pixels at halves).
//!
//! This module holds the codes and the pattern sequence ([`GrayCode`]); `decode` the decoder
//! ([`Decoder`], [`DecodeParams`]) and its result ([`Correspondence`]).

use crate::error::{Error, Result};
use crate::raster::{CamImage, ImageSize, PrjImage, Rgb};

mod decode;
#[cfg(test)]
mod tests;

pub use decode::{Correspondence, DecodeParams, Decoder};

/// Number of bits needed to give every one of `n` positions its own code: `ceil(log2 n)`
/// (0 for n = 1).
pub fn bits_for(n: usize) -> usize {
    if n <= 1 {
        0
    } else {
        (usize::BITS - (n - 1).leading_zeros()) as usize
    }
}

/// Reflected binary Gray code of `v`.
#[inline]
pub fn to_gray(v: u32) -> u32 {
    v ^ (v >> 1)
}

/// Inverse of [`to_gray`].
#[inline]
pub fn from_gray(mut g: u32) -> u32 {
    let mut shift = 1;
    while shift < u32::BITS {
        g ^= g >> shift;
        shift <<= 1;
    }
    g
}

/// What one image of the sequence shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatternKind {
    White,
    Black,
    /// Column bit `bit` (0 = most significant), `inverted` for the complementary image.
    Column {
        bit: usize,
        inverted: bool,
    },
    /// Row bit `bit` (0 = most significant), `inverted` for the complementary image.
    Row {
        bit: usize,
        inverted: bool,
    },
}

/// The Gray-code pattern set of a `width × height` projector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GrayCode {
    width: usize,
    height: usize,
    col_bits: usize,
    row_bits: usize,
}

impl GrayCode {
    /// Patterns for a projector of `width × height` pixels (both at least 1, at most 2^31).
    pub fn new(width: usize, height: usize) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::Input(format!(
                "structured light: projector size {width}x{height} must be at least 1x1"
            )));
        }
        let limit = 1usize << 31;
        if width > limit || height > limit {
            return Err(Error::Input(format!(
                "structured light: projector size {width}x{height} is too large"
            )));
        }
        Ok(Self {
            width,
            height,
            col_bits: bits_for(width),
            row_bits: bits_for(height),
        })
    }

    /// Projector (width, height) in pixels.
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
    /// Number of column bits, `ceil(log2 W)`.
    pub fn col_bits(&self) -> usize {
        self.col_bits
    }
    /// Number of row bits, `ceil(log2 H)`.
    pub fn row_bits(&self) -> usize {
        self.row_bits
    }

    /// Number of images in the sequence: `2 + 2·(col_bits + row_bits)`.
    pub fn len(&self) -> usize {
        2 + 2 * (self.col_bits + self.row_bits)
    }

    /// Never true: the sequence always holds at least white and black.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// What image `index` (0-based) shows, or `None` past the end.
    pub fn kind(&self, index: usize) -> Option<PatternKind> {
        match index {
            0 => Some(PatternKind::White),
            1 => Some(PatternKind::Black),
            i if i < 2 + 2 * self.col_bits => Some(PatternKind::Column {
                bit: (i - 2) / 2,
                inverted: (i - 2) % 2 == 1,
            }),
            i if i < self.len() => {
                let j = i - 2 - 2 * self.col_bits;
                Some(PatternKind::Row {
                    bit: j / 2,
                    inverted: j % 2 == 1,
                })
            }
            _ => None,
        }
    }

    /// Image `index` (0-based) of the sequence at projector resolution: values 0.0 or 1.0.
    pub fn pattern(&self, index: usize) -> Result<PrjImage> {
        let kind = self.kind(index).ok_or_else(|| {
            Error::Input(format!(
                "structured light: pattern index {index} out of range (the {} sequence has {} images)",
                self.size(),
                self.len()
            ))
        })?;
        let (w, h) = (self.width, self.height);
        Ok(match kind {
            PatternKind::White => Rgb::filled(w, h, [1.0; 3]),
            PatternKind::Black => Rgb::filled(w, h, [0.0; 3]),
            PatternKind::Column { bit, inverted } => {
                let shift = self.col_bits - 1 - bit;
                let on: Vec<bool> = (0..w)
                    .map(|x| ((to_gray(x as u32) >> shift) & 1 == 1) != inverted)
                    .collect();
                Rgb::from_fn(w, h, |x, _| if on[x] { [1.0; 3] } else { [0.0; 3] })
            }
            PatternKind::Row { bit, inverted } => {
                let shift = self.row_bits - 1 - bit;
                Rgb::from_fn(w, h, |_, y| {
                    if ((to_gray(y as u32) >> shift) & 1 == 1) != inverted {
                        [1.0; 3]
                    } else {
                        [0.0; 3]
                    }
                })
            }
        })
    }

    /// All images of the sequence, in order (generated lazily, one at a time).
    pub fn patterns(&self) -> impl Iterator<Item = PrjImage> + '_ {
        (0..self.len()).map(|i| self.pattern(i).expect("index below len() is in range"))
    }

    /// Decodes the captures of the whole sequence (same order as the patterns, all of one size)
    /// with the default [`DecodeParams`].
    pub fn decode(&self, captures: &[CamImage]) -> Result<Correspondence> {
        self.decode_with(captures, &DecodeParams::default())
    }

    /// Decodes the captures of the whole sequence with explicit thresholds.
    pub fn decode_with(
        &self,
        captures: &[CamImage],
        params: &DecodeParams,
    ) -> Result<Correspondence> {
        if captures.len() != self.len() {
            return Err(Error::Input(format!(
                "structured light: got {} captures, the {} sequence needs {} (white, black, {} column and {} row bit pairs)",
                captures.len(),
                self.size(),
                self.len(),
                self.col_bits,
                self.row_bits
            )));
        }
        let first = &captures[0];
        let mut decoder = Decoder::new(*self, first.width(), first.height(), *params);
        for c in captures {
            decoder.push(c)?;
        }
        decoder.finish()
    }
}
