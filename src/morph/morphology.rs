//! Morphology with square and disk elements (pixels beyond the edge are background), the
//! summed-area table of a mask, and small mask helpers.

use imageproc::distance_transform::euclidean_squared_distance_transform;

use super::to_gray;
use crate::raster::{ImageSize, Mask, Space};

// ---------------------------------------------------------------------------------------------
// Summed-area table
// ---------------------------------------------------------------------------------------------

/// Summed-area table (integral image) of a mask: the number of set pixels in any rectangle in
/// O(1).
#[derive(Clone, Debug)]
pub struct IntegralMask {
    width: usize,
    height: usize,
    /// (width + 1) × (height + 1) prefix counts; entry (x, y) counts pixels in [0,x)×[0,y).
    sums: Vec<u32>,
}

impl IntegralMask {
    pub fn new<S: Space>(mask: &Mask<S>) -> Self {
        let ImageSize {
            width: w,
            height: h,
        } = mask.size();
        let stride = w + 1;
        let mut sums = vec![0u32; stride * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += mask.get(x, y) as u32;
                sums[(y + 1) * stride + x + 1] = sums[y * stride + x + 1] + row;
            }
        }
        Self {
            width: w,
            height: h,
            sums,
        }
    }
    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    /// Set pixels in columns x0..x1, rows y0..y1 (half-open, clipped to the image).
    pub fn count_in(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> usize {
        let (x1, y1) = (x1.min(self.width), y1.min(self.height));
        if x0 >= x1 || y0 >= y1 {
            return 0;
        }
        let s = self.width + 1;
        let at = |x: usize, y: usize| self.sums[y * s + x] as i64;
        (at(x1, y1) - at(x0, y1) - at(x1, y0) + at(x0, y0)) as usize
    }
    /// True when the rectangle lies inside the image and every pixel in it is set.
    pub fn all_set(&self, x: usize, y: usize, width: usize, height: usize) -> bool {
        x + width <= self.width
            && y + height <= self.height
            && self.count_in(x, y, x + width, y + height) == width * height
    }
}

// ---------------------------------------------------------------------------------------------
// Morphology
// ---------------------------------------------------------------------------------------------

/// A structuring element centred on the pixel, with a radius in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Element {
    /// The (2r+1)×(2r+1) square: offsets with max(|dx|, |dy|) ≤ r.
    Square(usize),
    /// The disk: offsets with dx² + dy² ≤ r².
    Disk(usize),
}

impl Element {
    pub fn radius(&self) -> usize {
        match *self {
            Element::Square(r) | Element::Disk(r) => r,
        }
    }
}

/// Squared Euclidean distance (pixels²) from each pixel to the nearest pixel of the image that is
/// set in `mask` (`to_unset = false`) or unset (`to_unset = true`); 0 on such pixels themselves,
/// +∞ when there is none. Pixels beyond the image edge are not considered. Row-major.
pub fn squared_distance<S: Space>(mask: &Mask<S>, to_unset: bool) -> Vec<f64> {
    euclidean_squared_distance_transform(&to_gray(mask, to_unset)).into_raw()
}

/// Dilation: pixels within the element of a set pixel.
pub fn dilate<S: Space>(mask: &Mask<S>, el: Element) -> Mask<S> {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    if w == 0 || h == 0 {
        return mask.clone();
    }
    match el {
        Element::Square(r) => {
            let sat = IntegralMask::new(mask);
            Mask::from_fn(w, h, |x, y| {
                sat.count_in(
                    x.saturating_sub(r),
                    y.saturating_sub(r),
                    x + r + 1,
                    y + r + 1,
                ) > 0
            })
        }
        Element::Disk(r) => {
            let r2 = (r * r) as f64;
            let d = squared_distance(mask, false);
            Mask::from_vec(w, h, d.into_iter().map(|v| v <= r2).collect())
                .expect("same size as the input")
        }
    }
}

/// Erosion: pixels whose whole element lies on set pixels. Pixels beyond the image edge count as
/// unset, so pixels within `r` of the edge are always removed.
pub fn erode<S: Space>(mask: &Mask<S>, el: Element) -> Mask<S> {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    if w == 0 || h == 0 {
        return mask.clone();
    }
    let r = el.radius();
    let inside = |x: usize, y: usize| x >= r && y >= r && x + r < w && y + r < h;
    match el {
        Element::Square(r) => {
            let sat = IntegralMask::new(mask);
            let side = 2 * r + 1;
            Mask::from_fn(w, h, |x, y| {
                inside(x, y) && sat.count_in(x - r, y - r, x + r + 1, y + r + 1) == side * side
            })
        }
        Element::Disk(r) => {
            let r2 = (r * r) as f64;
            let d = squared_distance(mask, true);
            Mask::from_fn(w, h, |x, y| inside(x, y) && d[y * w + x] > r2)
        }
    }
}

/// Copies `mask` into the middle of a larger unset mask with `pad` pixels on every side.
fn pad<S: Space>(mask: &Mask<S>, pad: usize) -> Mask<S> {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    let mut out = Mask::new(w + 2 * pad, h + 2 * pad);
    for y in 0..h {
        for x in 0..w {
            if mask.get(x, y) {
                out.set(x + pad, y + pad, true);
            }
        }
    }
    out
}

fn unpad<S: Space>(mask: &Mask<S>, pad: usize, w: usize, h: usize) -> Mask<S> {
    Mask::from_fn(w, h, |x, y| mask.get(x + pad, y + pad))
}

/// Morphological closing (dilate, then erode): fills gaps and concavities narrower than the
/// element. Computed on a copy padded with unset pixels so the result always contains the input.
pub fn close<S: Space>(mask: &Mask<S>, el: Element) -> Mask<S> {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    if w == 0 || h == 0 {
        return mask.clone();
    }
    let r = el.radius();
    let padded = pad(mask, r + 1);
    unpad(&erode(&dilate(&padded, el), el), r + 1, w, h)
}

/// Morphological opening (erode, then dilate): removes parts narrower than the element. The
/// result is the union of all placements of the element that fit in the mask, so it is contained
/// in the input.
pub fn open<S: Space>(mask: &Mask<S>, el: Element) -> Mask<S> {
    dilate(&erode(mask, el), el)
}

// ---------------------------------------------------------------------------------------------
// Small helpers on masks
// ---------------------------------------------------------------------------------------------

/// Pixels set in `a` and in `b` (same size required; panics otherwise, a programming error).
pub fn and<S: Space>(a: &Mask<S>, b: &Mask<S>) -> Mask<S> {
    assert_eq!(a.size(), b.size(), "mask sizes differ");
    let data = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&p, &q)| p && q)
        .collect();
    Mask::from_vec(a.width(), a.height(), data).expect("same size")
}

/// Pixels set in `a` but not in `b` (same size required).
pub fn and_not<S: Space>(a: &Mask<S>, b: &Mask<S>) -> Mask<S> {
    assert_eq!(a.size(), b.size(), "mask sizes differ");
    let data = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&p, &q)| p && !q)
        .collect();
    Mask::from_vec(a.width(), a.height(), data).expect("same size")
}
