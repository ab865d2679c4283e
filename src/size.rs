//! [`ImageSize`], the one size type of the crate, and its `[width, height]` serde form: a
//! foundation of its own, below [`crate::error`] (which names sizes) and [`crate::raster`] (whose
//! images have them; it re-exports this module's items).

use std::fmt;

use serde::{Deserialize, Serialize};

/// Image size in pixels (width × height) of the space it belongs to: the one size type of the
/// crate. The files compend writes (`model.json` with its FOV diagnostics and training settings,
/// the bench-gpu and bench-train records) hold a size as a `[width, height]` pair ([`as_pair`],
/// [`as_pair_opt`]); `inspect --json` writes it as `{"width", "height"}`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ImageSize {
    pub width: usize,
    pub height: usize,
}

impl ImageSize {
    pub const fn new(width: usize, height: usize) -> Self {
        Self { width, height }
    }

    /// Number of pixels.
    pub const fn area(self) -> usize {
        self.width * self.height
    }

    /// Width over height.
    pub fn aspect(self) -> f64 {
        self.width as f64 / self.height as f64
    }

    /// Parses `WxH` (e.g. `800x600`), or `N` for N×N when `square_ok`; sides from 1 to 65 536,
    /// at most [`ImageSize::MAX_PIXELS`] in all. The error says what was expected.
    pub fn parse(s: &str, square_ok: bool) -> Result<Self, String> {
        let size = Self::parse_sides(s, square_ok)?;
        if size.area() > Self::MAX_PIXELS {
            return Err(format!(
                "{size} is {} million pixels; at most {} million (8192x8192) are accepted",
                size.area() / 1_000_000,
                Self::MAX_PIXELS / 1_000_000
            ));
        }
        Ok(size)
    }

    /// The most pixels a size given on the command line may have: 8192×8192, twice an 8K
    /// projector's. One float RGB image of it is 805 MB, and a calibration holds dozens.
    pub const MAX_PIXELS: usize = 8192 * 8192;

    fn parse_sides(s: &str, square_ok: bool) -> Result<Self, String> {
        let side = |t: &str| -> Result<usize, String> {
            match t.trim().parse::<usize>() {
                Ok(0) => Err("sides must be at least 1 pixel".to_string()),
                Ok(v) if v > 65_536 => Err(format!("{v} pixels is too large")),
                Ok(v) => Ok(v),
                Err(_) => Err(format!("'{t}' is not a whole number of pixels")),
            }
        };
        let lower = s.to_ascii_lowercase();
        match lower.split_once('x') {
            Some((w, h)) => Ok(Self::new(side(w)?, side(h)?)),
            None if square_ok => {
                let n = side(&lower)?;
                Ok(Self::new(n, n))
            }
            None => Err("expected WIDTHxHEIGHT, e.g. 800x600".to_string()),
        }
    }
}

/// Serde for a size written as a `[width, height]` pair (`#[serde(with = "...")]`), the form
/// of the model directory's sizes since format version 1.
pub mod as_pair {
    use super::ImageSize;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(size: &ImageSize, s: S) -> Result<S::Ok, S::Error> {
        (size.width, size.height).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<ImageSize, D::Error> {
        let (width, height) = <(usize, usize)>::deserialize(d)?;
        Ok(ImageSize { width, height })
    }
}

/// [`as_pair`] for an optional size: `null` or a `[width, height]` pair.
pub mod as_pair_opt {
    use super::ImageSize;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(size: &Option<ImageSize>, s: S) -> Result<S::Ok, S::Error> {
        size.map(|x| (x.width, x.height)).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<ImageSize>, D::Error> {
        Ok(<Option<(usize, usize)>>::deserialize(d)?.map(ImageSize::from))
    }
}

impl From<(usize, usize)> for ImageSize {
    fn from((width, height): (usize, usize)) -> Self {
        Self { width, height }
    }
}

impl From<ImageSize> for (usize, usize) {
    fn from(s: ImageSize) -> Self {
        (s.width, s.height)
    }
}

impl fmt::Display for ImageSize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_size_parses_within_its_limits_and_says_what_is_wrong() {
        assert_eq!(
            ImageSize::parse("800x600", false),
            Ok(ImageSize::new(800, 600))
        );
        assert_eq!(ImageSize::parse("64", true), Ok(ImageSize::new(64, 64)));
        assert_eq!(
            ImageSize::parse("8192x8192", false),
            Ok(ImageSize::new(8192, 8192))
        );
        for (text, says) in [
            ("64", "WIDTHxHEIGHT"),
            ("0x4", "at least 1"),
            ("ax4", "not a whole number"),
            ("70000x1", "too large"),
            ("30000x30000", "900 million pixels"),
            ("8193x8192", "at most 67 million"),
        ] {
            let e = ImageSize::parse(text, false).unwrap_err();
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}
