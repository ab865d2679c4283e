//! The optimal displayable area inside the FOV mask, the placement of desired images into it, and
//! the range of camera values the projector can show there. Everything in camera pixels; values
//! are encoded \[0,1\].

use serde::Serialize;

use crate::error::{Error, Result};
use crate::morph::IntegralMask;
use crate::raster::{CamImage, ImageSize, Mask, Rect, Rgb, Space, check_same_size};

/// The optimal displayable area: the largest axis-aligned rectangle of aspect ratio `aspect`
/// (width / height, the canvas aspect) whose pixels all lie in `mask` (camera view).
///
/// The rectangle's longer side `s` (width when `aspect ≥ 1`, else height) is searched; the other
/// side is `round(s / aspect)` (resp. `round(s · aspect)`), so the aspect holds to within half a
/// pixel on the shorter side. Whether some placement of a given size fits is tested over all
/// positions with a summed-area table, O(1) each; it is monotone in `s` (a smaller rectangle fits
/// inside a larger one), so `s` is found by binary search: O(w·h·log(max side)). Among the
/// placements of the best size, the one whose centre is nearest the mask's centroid is chosen
/// (the first in raster order among equals).
///
/// Errors: [`Error::Input`] for an aspect that is not finite and positive; [`Error::Failed`]
/// when not even the smallest rectangle of that aspect fits (e.g. an empty mask).
pub fn displayable_area<S: Space>(mask: &Mask<S>, aspect: f64) -> Result<Rect> {
    if !aspect.is_finite() || aspect <= 0.0 {
        return Err(Error::Input(format!(
            "displayable area: aspect ratio must be a positive number (width/height), got {aspect}"
        )));
    }
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    let wide = aspect >= 1.0;
    // (width, height) of the rectangle whose longer side is s.
    let dims = |s: usize| -> ImageSize {
        if wide {
            ImageSize::new(s, (s as f64 / aspect).round() as usize)
        } else {
            ImageSize::new((s as f64 * aspect).round() as usize, s)
        }
    };
    let limit = if wide { w } else { h };
    let sat = IntegralMask::new(mask);
    let fits = |s: usize| -> bool {
        let ImageSize {
            width: rw,
            height: rh,
        } = dims(s);
        if rw == 0 || rh == 0 || rw > w || rh > h {
            return false;
        }
        (0..=h - rh).any(|y| (0..=w - rw).any(|x| sat.all_set(x, y, rw, rh)))
    };
    // Smallest s whose shorter side rounds to at least one pixel.
    let mut lo = 1usize;
    while lo <= limit && {
        let ImageSize {
            width: rw,
            height: rh,
        } = dims(lo);
        rw == 0 || rh == 0
    } {
        lo += 1;
    }
    if lo > limit || !fits(lo) {
        let ImageSize {
            width: rw,
            height: rh,
        } = dims(lo.min(limit.max(1)));
        return Err(Error::Failed(format!(
            "displayable area: no {rw}x{rh} rectangle (aspect {aspect:.4}) fits in the FOV mask \
             ({} of {w}x{h} pixels set); expected a lit region",
            mask.count()
        )));
    }
    // Invariant: fits(lo); find the largest s in [lo, limit] that fits.
    let mut hi = limit;
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if fits(mid) {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    let ImageSize {
        width: rw,
        height: rh,
    } = dims(lo);

    // Centroid of the mask (pixel centres), and the placement whose centre is nearest to it.
    let (mut sx, mut sy, mut cnt) = (0f64, 0f64, 0f64);
    for y in 0..h {
        for x in 0..w {
            if mask.get(x, y) {
                sx += x as f64;
                sy += y as f64;
                cnt += 1.0;
            }
        }
    }
    let (cx, cy) = (sx / cnt, sy / cnt);
    let mut best: Option<(f64, Rect)> = None;
    for y in 0..=h - rh {
        for x in 0..=w - rw {
            if sat.all_set(x, y, rw, rh) {
                let dx = x as f64 + (rw - 1) as f64 / 2.0 - cx;
                let dy = y as f64 + (rh - 1) as f64 / 2.0 - cy;
                let d2 = dx * dx + dy * dy;
                if best.is_none_or(|(b, _)| d2 < b) {
                    best = Some((
                        d2,
                        Rect {
                            x,
                            y,
                            width: rw,
                            height: rh,
                        },
                    ));
                }
            }
        }
    }
    Ok(best.expect("the binary search found a fitting size").1)
}

/// Camera pixels around the displayable area that carry its edge pixels outward in a desired
/// image ([`place_in_area`]). A camera pixel on the area's edge sees light from projector
/// pixels on both sides of it (the projector's pixel footprint and the bilinear sampling of the
/// geometry). With black beyond the edge, the compensation dims the projector pixels just
/// outside, and the edge's outermost ring of camera pixels comes out too dark: on the curved
/// scene without camera noise (seed 71), more than half of `linear`'s squared error in the area
/// sat in that one-pixel ring, 13 times the oracle's there. Extending the edge by 2, 4 or 8
/// camera pixels took `linear` from 3.50 to 0.61 dB below the physical ceiling there, and on
/// seed 302 (the textured plane and the curved scene, with noise) from 0.35 and 0.39 to 0.25
/// and 0.29 dB (docs/bench/ladder.md). The viewer sees the content's edge colours continue this
/// far beyond the rectangle instead of the projector's black.
pub const EDGE_MARGIN_PX: usize = 4;

/// Places `img` (any space, e.g. a network-space test image) into `area` of a black camera-space
/// canvas of `canvas_size` = (width, height), stretched to fill the area with
/// [`crate::resize::resize_bilinear`], its edge pixels repeated [`EDGE_MARGIN_PX`] camera pixels
/// outward (within the canvas): the desired viewer image `z'` of `cam/desire/test`. Scores are
/// taken inside the area only.
pub fn place_in_area<T: Space>(
    img: &Rgb<T>,
    area: Rect,
    canvas_size: ImageSize,
) -> Result<CamImage> {
    let ImageSize {
        width: cw,
        height: ch,
    } = canvas_size;
    if area.width == 0 || area.height == 0 || area.x + area.width > cw || area.y + area.height > ch
    {
        return Err(Error::Shape(format!(
            "display area {area} is empty or does not fit in the {cw}x{ch} camera frame"
        )));
    }
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::Shape(format!(
            "cannot place an empty {}x{} image",
            img.width(),
            img.height()
        )));
    }
    let small = crate::resize::resize_bilinear(img, area.width, area.height);
    let mut out = CamImage::new(cw, ch);
    let m = EDGE_MARGIN_PX;
    let (x0, x1) = (area.x.saturating_sub(m), (area.x + area.width + m).min(cw));
    let (y0, y1) = (area.y.saturating_sub(m), (area.y + area.height + m).min(ch));
    for y in y0..y1 {
        let sy = y.clamp(area.y, area.y + area.height - 1) - area.y;
        for x in x0..x1 {
            let sx = x.clamp(area.x, area.x + area.width - 1) - area.x;
            out.set(x, y, small.get(sx, sy));
        }
    }
    Ok(out)
}

/// The neutral range of camera values the projector can produce across a displayable area:
/// desired images mapped into `[low, high]` are physically reachable almost everywhere in it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct DisplayRange {
    /// Camera value (encoded, \[0,1\]) the projector's black cannot go below at most pixels.
    pub low: f32,
    /// Camera value its white reaches at most pixels.
    pub high: f32,
}

impl DisplayRange {
    /// The whole range, no scaling.
    pub const FULL: DisplayRange = DisplayRange {
        low: 0.0,
        high: 1.0,
    };

    /// Maps an image's values `v` to `low + (high − low)·v`.
    pub fn apply<S: Space>(&self, img: &Rgb<S>) -> Rgb<S> {
        let (lo, span) = (self.low, self.high - self.low);
        img.map(|v| lo + span * v)
    }
}

/// Least rise from the black to the white capture (encoded, every channel) at a pixel the
/// projector reaches; below it the pixel is in shadow for compensation.
pub const MIN_CONTRAST: f32 = 0.02;

/// Quantile for the display range of desired images: 95 % of the displayable area can show both
/// ends of the range in every channel.
pub const DESIRED_RANGE_QUANTILE: f64 = 0.05;

/// The display range inside `area` from the black and white reference captures (camera space).
/// Only pixels where the projector makes a difference count (white above black by at least
/// 0.02 in every channel): shadows cannot be compensated at any range and must not set it. Over
/// those, `low` is the `1 − q` quantile of each pixel's brightest channel under black, `high`
/// the `q` quantile of each pixel's darkest channel under white (e.g. `q = 0.05`: 95 % of them
/// can show both ends in every channel). Errors when fewer than half the area responds.
pub fn display_range(
    black: &CamImage,
    white: &CamImage,
    area: Rect,
    q: f64,
) -> Result<DisplayRange> {
    check_same_size(
        black.size(),
        white.size(),
        "display range: black vs white capture",
    )?;
    let ImageSize {
        width: w,
        height: h,
    } = white.size();
    if area.width == 0 || area.height == 0 || area.x + area.width > w || area.y + area.height > h {
        return Err(Error::Shape(format!(
            "display range: area {area} does not fit in the {w}x{h} camera frame"
        )));
    }
    let mut lows = Vec::with_capacity(area.area());
    let mut highs = Vec::with_capacity(area.area());
    for y in area.y..area.y + area.height {
        for x in area.x..area.x + area.width {
            let (b, wv) = (black.get(x, y), white.get(x, y));
            let lo = b[0].max(b[1]).max(b[2]);
            let hi = wv[0].min(wv[1]).min(wv[2]);
            if (0..3).all(|c| wv[c] - b[c] >= MIN_CONTRAST) {
                lows.push(lo);
                highs.push(hi);
            }
        }
    }
    if lows.len() * 2 < area.area() {
        return Err(Error::Failed(format!(
            "display range: only {} of {} pixels in area {area} respond to the projector \
             (white above black by {MIN_CONTRAST})",
            lows.len(),
            area.area()
        )));
    }
    let quantile = |v: &mut Vec<f32>, q: f64| -> f32 {
        let k = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
        let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
        *x
    };
    let low = quantile(&mut lows, 1.0 - q);
    let high = quantile(&mut highs, q);
    if high <= low {
        return Err(Error::Failed(format!(
            "display range: white ({high:.3}) is not brighter than black ({low:.3}) in area {area}; \
             the projector cannot show a common range there"
        )));
    }
    Ok(DisplayRange { low, high })
}
