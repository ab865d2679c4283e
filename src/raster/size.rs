//! [`ImageSize`], the one size type of the crate, and its `[width, height]` serde form. It
//! depends on nothing else in the crate, so that [`crate::error`] can name sizes without an
//! import circle with the image types.

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

    /// Parses `WxH` (e.g. `800x600`), or `N` for N×N when `square_ok`; sides from 1 to 65 536.
    /// The error says what was expected.
    pub fn parse(s: &str, square_ok: bool) -> Result<Self, String> {
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
