//! Where no model can help: the pixels of the displayable area whose captures under the
//! projector's black and white cannot span the display range, classified by why.
//!
//! Compensation only redistributes the projector's light. At a camera pixel the reachable
//! values run from what it shows under black (ambient light and the projector's black level)
//! to what it shows under white, so a pixel whose span does not cover the display range
//! `[low, high]` shows the desired image wrong whatever the model does. Reasons, first match:
//!
//! - **shadowed**: white rises above black by less than [`super::MIN_CONTRAST`] in some channel
//!   (the projector does not reach it: a shadow, an occluded fold, the edge of the FOV);
//! - **saturated**: the camera clips under white in some channel (254.5/255), so it cannot see
//!   what the projector does there;
//! - **too dark**: its darkest channel under white stays below `high` (dark or strongly coloured
//!   surface);
//! - **too bright**: its brightest channel under black is above `low` (ambient light, a
//!   specular spot).
//!
//! Everything is camera pixels and encoded \[0,1\] camera values, as the references are.

use serde::{Deserialize, Serialize};

use super::area::{DisplayRange, MIN_CONTRAST};
use crate::error::{Error, Result};
use crate::raster::{CamImage, ImageSize, Rect};

/// Why a pixel cannot be compensated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Unreachable {
    Shadowed,
    Saturated,
    TooDark,
    TooBright,
}

impl Unreachable {
    pub const ALL: [Unreachable; 4] = [
        Unreachable::Shadowed,
        Unreachable::Saturated,
        Unreachable::TooDark,
        Unreachable::TooBright,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Unreachable::Shadowed => "shadowed",
            Unreachable::Saturated => "saturated",
            Unreachable::TooDark => "too dark",
            Unreachable::TooBright => "too bright",
        }
    }

    /// The mask image's colour for this reason (encoded RGB).
    pub fn colour(self) -> [f32; 3] {
        match self {
            Unreachable::Shadowed => [0.0, 0.0, 1.0],
            Unreachable::Saturated => [1.0, 0.0, 1.0],
            Unreachable::TooDark => [1.0, 0.0, 0.0],
            Unreachable::TooBright => [1.0, 1.0, 0.0],
        }
    }
}

/// Camera value at which a capture counts as clipped (encoded).
const CLIPPED: f32 = 254.5 / 255.0;

/// The pixels of a displayable area no model can compensate.
#[derive(Clone, Debug, PartialEq)]
pub struct Reach {
    /// The displayable area (camera pixels).
    pub area: Rect,
    /// Per pixel of the camera frame: `None` where compensable or outside the area.
    pub reasons: Vec<Option<Unreachable>>,
    pub size: ImageSize,
    /// Pixels of the area per reason, in [`Unreachable::ALL`]'s order.
    pub counts: [usize; 4],
}

/// What `model.json` and the output report: percentages of the displayable area.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReachSummary {
    /// Percent of the displayable area that cannot be compensated, all reasons.
    pub unreachable_percent: f64,
    pub shadowed_percent: f64,
    pub saturated_percent: f64,
    pub too_dark_percent: f64,
    pub too_bright_percent: f64,
}

/// Classifies every pixel of `area` from the black and white reference captures against the
/// display range the desired images are mapped into.
pub fn reach(black: &CamImage, white: &CamImage, area: Rect, range: DisplayRange) -> Result<Reach> {
    let size = white.size();
    if black.size() != size {
        return Err(Error::Shape(format!(
            "reach: black capture {} vs white capture {size}",
            black.size()
        )));
    }
    if area.x + area.width > size.width || area.y + area.height > size.height {
        return Err(Error::Shape(format!(
            "reach: area {area} does not fit in the {size} camera frame"
        )));
    }
    let mut reasons = vec![None; size.width * size.height];
    let mut counts = [0usize; 4];
    for y in area.y..area.y + area.height {
        for x in area.x..area.x + area.width {
            let (b, w) = (black.get(x, y), white.get(x, y));
            let why = if (0..3).any(|c| w[c] - b[c] < MIN_CONTRAST) {
                Some(Unreachable::Shadowed)
            } else if w.iter().any(|&v| v >= CLIPPED) {
                Some(Unreachable::Saturated)
            } else if w[0].min(w[1]).min(w[2]) < range.high {
                Some(Unreachable::TooDark)
            } else if b[0].max(b[1]).max(b[2]) > range.low {
                Some(Unreachable::TooBright)
            } else {
                None
            };
            if let Some(r) = why {
                counts[r as usize] += 1;
                reasons[y * size.width + x] = Some(r);
            }
        }
    }
    Ok(Reach {
        area,
        reasons,
        size,
        counts,
    })
}

impl Reach {
    /// The percentages of the displayable area.
    pub fn summary(&self) -> ReachSummary {
        let n = self.area.area().max(1) as f64;
        let pc = |k: usize| 100.0 * k as f64 / n;
        ReachSummary {
            unreachable_percent: pc(self.counts.iter().sum()),
            shadowed_percent: pc(self.counts[0]),
            saturated_percent: pc(self.counts[1]),
            too_dark_percent: pc(self.counts[2]),
            too_bright_percent: pc(self.counts[3]),
        }
    }

    /// The mask as a picture over `background` (a reference capture, camera pixels): each
    /// unreachable pixel in its reason's colour, the rest of the area as it is, outside the
    /// area dimmed to a quarter.
    pub fn picture(&self, background: &CamImage) -> Result<CamImage> {
        if background.size() != self.size {
            return Err(Error::Shape(format!(
                "reach picture: background {} vs mask {}",
                background.size(),
                self.size
            )));
        }
        let a = self.area;
        Ok(CamImage::from_fn(
            self.size.width,
            self.size.height,
            |x, y| {
                let inside = x >= a.x && x < a.x + a.width && y >= a.y && y < a.y + a.height;
                match self.reasons[y * self.size.width + x] {
                    Some(r) => r.colour(),
                    None if inside => background.get(x, y),
                    None => background.get(x, y).map(|v| 0.25 * v),
                }
            },
        ))
    }
}

impl ReachSummary {
    /// One line for a person.
    pub fn line(&self) -> String {
        format!(
            "{:.1} % of the displayable area cannot be compensated ({:.1} % shadowed, {:.1} % \
             saturated, {:.1} % too dark, {:.1} % too bright)",
            self.unreachable_percent,
            self.shadowed_percent,
            self.saturated_percent,
            self.too_dark_percent,
            self.too_bright_percent
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pixel_gets_the_first_reason_that_holds_and_the_rest_of_the_area_none() {
        // A 5x1 strip: fine, shadowed, saturated, too dark, too bright; range [0.1, 0.8].
        let black = CamImage::from_fn(5, 1, |x, _| match x {
            1 => [0.3; 3],
            4 => [0.2, 0.05, 0.05],
            _ => [0.05; 3],
        });
        let white = CamImage::from_fn(5, 1, |x, _| match x {
            1 => [0.31; 3],
            2 => [1.0, 0.9, 0.9],
            3 => [0.9, 0.5, 0.9],
            _ => [0.9; 3],
        });
        let range = DisplayRange {
            low: 0.1,
            high: 0.8,
        };
        let area = Rect {
            x: 0,
            y: 0,
            width: 5,
            height: 1,
        };
        let r = reach(&black, &white, area, range).unwrap();
        assert_eq!(
            r.reasons,
            [
                None,
                Some(Unreachable::Shadowed),
                Some(Unreachable::Saturated),
                Some(Unreachable::TooDark),
                Some(Unreachable::TooBright)
            ]
        );
        let s = r.summary();
        assert_eq!(s.unreachable_percent, 80.0);
        assert_eq!(s.shadowed_percent, 20.0);
        assert!(
            s.line().starts_with("80.0 % of the displayable area"),
            "{}",
            s.line()
        );
        // Outside the area nothing is classified, and the picture dims it.
        let inner = Rect { width: 1, ..area };
        let r = reach(&black, &white, inner, range).unwrap();
        assert_eq!(r.counts, [0; 4]);
        let pic = r.picture(&white).unwrap();
        assert_eq!(pic.get(0, 0), [0.9; 3]);
        assert!((pic.get(1, 0)[0] - 0.31 * 0.25).abs() < 1e-6);
        let wide = Rect { width: 6, ..area };
        assert!(reach(&black, &white, wide, range).is_err());
    }
}
