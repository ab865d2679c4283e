//! Test patterns for aiming and focusing a rig before its first calibration (the service's setup
//! view): a grid, a crosshair, white and black, at the projector's size, projected as they are
//! (no model). Projector pixels, RGB in \[0,1\].

use std::fmt;
use std::str::FromStr;

use crate::error::{Error, Result};
use crate::raster::{ImageSize, PrjImage};

/// A setup pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SetupPattern {
    /// White lines every 1/16 of the width and height on black, one pixel wide, plus the
    /// border: shows keystone, focus across the field and the overlap with the surface.
    Grid,
    /// A white cross through the centre and a centred circle on black: aims the projector.
    Crosshair,
    /// Full white: the brightest the projector gives, for the camera's clipping.
    White,
    /// Full black: the projector's black level and the room's light.
    Black,
}

/// The spellings, in order.
pub const SETUP_PATTERNS: [&str; 4] = ["grid", "crosshair", "white", "black"];

impl FromStr for SetupPattern {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "grid" => Ok(Self::Grid),
            "crosshair" => Ok(Self::Crosshair),
            "white" => Ok(Self::White),
            "black" => Ok(Self::Black),
            other => Err(Error::Input(format!(
                "setup pattern {other:?}: expected one of {}",
                SETUP_PATTERNS.join(", ")
            ))),
        }
    }
}

impl fmt::Display for SetupPattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Grid => "grid",
            Self::Crosshair => "crosshair",
            Self::White => "white",
            Self::Black => "black",
        })
    }
}

impl SetupPattern {
    /// The pattern at `size` (projector pixels).
    pub fn render(self, size: ImageSize) -> PrjImage {
        let (w, h) = (size.width, size.height);
        match self {
            Self::White => PrjImage::filled(w, h, [1.0; 3]),
            Self::Black => PrjImage::new(w, h),
            Self::Grid => {
                // Lines at i·w/16 (i = 0..=16, the last one on the far edge).
                let on = |v: usize, n: usize| {
                    (0..=16).any(|i| (i * (n - 1)).div_euclid(16) == v) && n > 1
                };
                PrjImage::from_fn(w, h, |x, y| {
                    if on(x, w) || on(y, h) {
                        [1.0; 3]
                    } else {
                        [0.0; 3]
                    }
                })
            }
            Self::Crosshair => {
                let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
                let r = w.min(h) as f64 / 4.0;
                PrjImage::from_fn(w, h, |x, y| {
                    let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                    let line = dx.abs() < 1.0 || dy.abs() < 1.0;
                    let ring = ((dx * dx + dy * dy).sqrt() - r).abs() < 1.0;
                    if line || ring { [1.0; 3] } else { [0.0; 3] }
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_parse_and_render_at_the_size() {
        let size = ImageSize {
            width: 64,
            height: 48,
        };
        for name in SETUP_PATTERNS {
            let p: SetupPattern = name.parse().unwrap();
            assert_eq!(p.to_string(), name);
            assert_eq!(p.render(size).size(), size);
        }
        assert!("checker".parse::<SetupPattern>().is_err());
        let grid = SetupPattern::Grid.render(size);
        assert_eq!(grid.get(0, 20), [1.0; 3]);
        assert_eq!(grid.get(63, 20), [1.0; 3]);
        assert_eq!(grid.get(5, 4), [0.0; 3]);
        let cross = SetupPattern::Crosshair.render(size);
        assert_eq!(cross.get(31, 5), [1.0; 3]);
        assert_eq!(cross.get(2, 2), [0.0; 3]);
        assert_eq!(SetupPattern::White.render(size).get(9, 9), [1.0; 3]);
    }
}
