//! Binary-image and threshold tools on the core types: Otsu threshold of a plane, connected
//! components, hole filling, convex hull, morphology, and a summed-area table of a mask.
//!
//! Every operation keeps the pixel space of its input. Pixel (x, y) is column x, row y; masks are
//! `true` inside. Neighbourhoods beyond the image edge are **background** (the image is taken to
//! be surrounded by an infinite unset plane): dilation never reaches outside, erosion removes
//! pixels within the element radius of the edge, and closing is computed on a padded copy so that
//! it never removes pixels (closing ⊇ input, opening ⊆ input).
//!
//! imageproc does the component labelling and the Euclidean distance transform behind the disk
//! element (through its 8-bit images; the conversion is one pass). Otsu is computed here on the
//! f32 values because quantising a dim difference image to 8 bits would throw away the very
//! levels the projector FOV detection needs; the hull, hole filling and square elements are
//! small enough to write directly.

use image::{GrayImage, Luma};
use imageproc::distance_transform::euclidean_squared_distance_transform;
use imageproc::region_labelling::{Connectivity, connected_components as ip_components};

use crate::raster::{Mask, Plane, Space};

// ---------------------------------------------------------------------------------------------
// Otsu threshold
// ---------------------------------------------------------------------------------------------

/// Number of histogram bins used by [`otsu_threshold`].
pub const OTSU_BINS: usize = 256;

/// Otsu's threshold of a plane: the value `t` for which `plane.threshold(t)` (values strictly
/// above `t`) is the upper of the two classes that maximise the between-class variance.
///
/// The histogram has [`OTSU_BINS`] bins spanning the plane's own [min, max] range (not a fixed
/// [0, 1]), so dim images keep their full resolution. The returned value lies halfway between the
/// largest value of the lower class and the smallest value of the upper class, so it separates the
/// two classes exactly. Non-finite values are ignored. A constant plane (or one with no finite
/// values) returns its value (0.0 when none), which puts every pixel in the lower class.
pub fn otsu_threshold<S: Space>(plane: &Plane<S>) -> f32 {
    otsu_threshold_values(plane.data())
}

/// [`otsu_threshold`] of a slice of values (e.g. a plane restricted to a region).
pub fn otsu_threshold_values(values: &[f32]) -> f32 {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for &v in values.iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return 0.0;
    }
    if hi <= lo {
        return lo;
    }
    let scale = OTSU_BINS as f64 / (hi as f64 - lo as f64);
    let mut count = [0u64; OTSU_BINS];
    let mut sum = [0f64; OTSU_BINS];
    let mut bmin = [f32::INFINITY; OTSU_BINS];
    let mut bmax = [f32::NEG_INFINITY; OTSU_BINS];
    for &v in values.iter().filter(|v| v.is_finite()) {
        let b = (((v - lo) as f64 * scale) as usize).min(OTSU_BINS - 1);
        count[b] += 1;
        sum[b] += v as f64;
        bmin[b] = bmin[b].min(v);
        bmax[b] = bmax[b].max(v);
    }
    let total: u64 = count.iter().sum();
    let total_sum: f64 = sum.iter().sum();

    // Split after bin k: class 0 = bins 0..=k. Between-class variance ∝ w0·w1·(μ0 − μ1)².
    let (mut best_k, mut best_var) = (0usize, -1.0f64);
    let (mut w0, mut s0) = (0u64, 0f64);
    for k in 0..OTSU_BINS - 1 {
        w0 += count[k];
        s0 += sum[k];
        let w1 = total - w0;
        if w0 == 0 || w1 == 0 {
            continue;
        }
        let (m0, m1) = (s0 / w0 as f64, (total_sum - s0) / w1 as f64);
        let var = w0 as f64 * w1 as f64 * (m0 - m1) * (m0 - m1);
        if var > best_var {
            best_var = var;
            best_k = k;
        }
    }
    let upper_of_low = bmax[..=best_k]
        .iter()
        .copied()
        .fold(f32::NEG_INFINITY, f32::max);
    let lower_of_high = bmin[best_k + 1..]
        .iter()
        .copied()
        .fold(f32::INFINITY, f32::min);
    // Both are finite: the chosen split has pixels on each side (hi > lo guarantees one exists).
    0.5 * (upper_of_low + lower_of_high)
}

// ---------------------------------------------------------------------------------------------
// Conversions to imageproc's 8-bit images
// ---------------------------------------------------------------------------------------------

fn to_gray<S: Space>(mask: &Mask<S>, invert: bool) -> GrayImage {
    let data = mask
        .data()
        .iter()
        .map(|&b| if b != invert { 255u8 } else { 0 })
        .collect();
    GrayImage::from_raw(mask.width() as u32, mask.height() as u32, data)
        .expect("one byte per mask pixel")
}

// ---------------------------------------------------------------------------------------------
// Connected components
// ---------------------------------------------------------------------------------------------

/// Connected components of a mask's set pixels under 8-connectivity.
///
/// Labels are 1..=count in raster order of each component's first pixel; 0 is background.
#[derive(Clone, Debug)]
pub struct Components {
    width: usize,
    height: usize,
    labels: Vec<u32>,
    /// sizes[l] = number of pixels with label l (sizes[0] counts the background).
    sizes: Vec<usize>,
}

impl Components {
    /// Number of components (labels run 1..=count).
    pub fn count(&self) -> usize {
        self.sizes.len() - 1
    }
    /// Label of pixel (x, y); 0 for background.
    pub fn label(&self, x: usize, y: usize) -> u32 {
        self.labels[y * self.width + x]
    }
    /// All labels, row-major.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }
    /// Pixel count of component `label` (0 for an unknown label).
    pub fn size(&self, label: u32) -> usize {
        if label == 0 {
            return 0;
        }
        self.sizes.get(label as usize).copied().unwrap_or(0)
    }
    /// The label of the largest component (the first in raster order among equals), or `None`
    /// when there are no set pixels.
    pub fn largest(&self) -> Option<u32> {
        let mut best: Option<(u32, usize)> = None;
        for (l, &n) in self.sizes.iter().enumerate().skip(1) {
            if best.is_none_or(|(_, bn)| n > bn) {
                best = Some((l as u32, n));
            }
        }
        best.map(|(l, _)| l)
    }
    /// The mask of the components whose label satisfies `keep`.
    pub fn select<S: Space>(&self, mut keep: impl FnMut(u32) -> bool) -> Mask<S> {
        let mut lut: Vec<bool> = (0..self.sizes.len() as u32).map(&mut keep).collect();
        lut[0] = false;
        let data = self.labels.iter().map(|&l| lut[l as usize]).collect();
        Mask::from_vec(self.width, self.height, data).expect("one label per pixel")
    }
    /// The mask of one component.
    pub fn component<S: Space>(&self, label: u32) -> Mask<S> {
        self.select(|l| l == label && label != 0)
    }
}

/// Labels the 8-connected components of `mask`.
pub fn connected_components<S: Space>(mask: &Mask<S>) -> Components {
    label_impl(mask, false, Connectivity::Eight)
}

fn label_impl<S: Space>(mask: &Mask<S>, invert: bool, conn: Connectivity) -> Components {
    let (w, h) = mask.size();
    if w == 0 || h == 0 {
        return Components {
            width: w,
            height: h,
            labels: Vec::new(),
            sizes: vec![0],
        };
    }
    let raw = ip_components(&to_gray(mask, invert), conn, Luma([0u8])).into_raw();
    // imageproc numbers components in raster order of first appearance but does not promise
    // dense labels; renumber densely in raster order.
    let mut remap = std::collections::HashMap::<u32, u32>::new();
    let mut sizes = vec![0usize];
    let labels: Vec<u32> = raw
        .into_iter()
        .map(|l| {
            if l == 0 {
                sizes[0] += 1;
                return 0;
            }
            let next = remap.len() as u32 + 1;
            let d = *remap.entry(l).or_insert(next);
            if d as usize == sizes.len() {
                sizes.push(0);
            }
            sizes[d as usize] += 1;
            d
        })
        .collect();
    Components {
        width: w,
        height: h,
        labels,
        sizes,
    }
}

/// The largest 8-connected component of `mask` (empty when the mask is empty).
pub fn largest_component<S: Space>(mask: &Mask<S>) -> Mask<S> {
    let cc = connected_components(mask);
    match cc.largest() {
        Some(l) => cc.component(l),
        None => Mask::new(mask.width(), mask.height()),
    }
}

/// The components of `mask` holding at least `min_fraction` of the largest one's pixels, as
/// labels of `cc` (largest first). `min_fraction` ≥ 1 keeps the largest only.
pub fn major_labels(cc: &Components, min_fraction: f64) -> Vec<u32> {
    let Some(big) = cc.largest() else {
        return Vec::new();
    };
    if min_fraction >= 1.0 {
        return vec![big];
    }
    let floor = min_fraction * cc.size(big) as f64;
    let mut labels: Vec<u32> = (1..=cc.count() as u32)
        .filter(|&l| cc.size(l) as f64 >= floor)
        .collect();
    labels.sort_by_key(|&l| std::cmp::Reverse(cc.size(l)));
    labels
}

/// The union of the components of `mask` holding at least `min_fraction` of the largest one's
/// pixels (see [`major_labels`]).
pub fn major_components<S: Space>(mask: &Mask<S>, min_fraction: f64) -> Mask<S> {
    let cc = connected_components(mask);
    let keep = major_labels(&cc, min_fraction);
    cc.select(|l| keep.contains(&l))
}

/// Fills holes: unset regions not connected to the image border become set. Unset pixels are
/// connected through their 4 edge neighbours (the dual of 8-connected foreground), so a diagonal
/// chain of set pixels closes a hole.
pub fn fill_holes<S: Space>(mask: &Mask<S>) -> Mask<S> {
    let (w, h) = mask.size();
    if w == 0 || h == 0 {
        return mask.clone();
    }
    let bg = label_impl(mask, true, Connectivity::Four);
    let mut touches = vec![false; bg.sizes.len()];
    for x in 0..w {
        touches[bg.label(x, 0) as usize] = true;
        touches[bg.label(x, h - 1) as usize] = true;
    }
    for y in 0..h {
        touches[bg.label(0, y) as usize] = true;
        touches[bg.label(w - 1, y) as usize] = true;
    }
    let data = mask
        .data()
        .iter()
        .zip(bg.labels())
        .map(|(&m, &l)| m || !touches[l as usize])
        .collect();
    Mask::from_vec(w, h, data).expect("same size as the input")
}

// ---------------------------------------------------------------------------------------------
// Convex hull
// ---------------------------------------------------------------------------------------------

fn cross(o: (i64, i64), a: (i64, i64), b: (i64, i64)) -> i64 {
    (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
}

/// The convex hull of the set pixels' centres, as integer pixel coordinates (x, y) in order
/// around the hull (counter-clockwise with y pointing up, i.e. clockwise as seen on screen),
/// without collinear points. Empty for an empty mask; one point for a single pixel; two points
/// when all set pixels lie on one line.
pub fn convex_hull<S: Space>(mask: &Mask<S>) -> Vec<(i64, i64)> {
    // Only the leftmost and rightmost set pixel of each row can be hull vertices.
    let mut pts = Vec::new();
    for y in 0..mask.height() {
        let row = &mask.data()[y * mask.width()..(y + 1) * mask.width()];
        if let (Some(a), Some(b)) = (row.iter().position(|&v| v), row.iter().rposition(|&v| v)) {
            pts.push((a as i64, y as i64));
            if b != a {
                pts.push((b as i64, y as i64));
            }
        }
    }
    hull_of_points(pts)
}

/// Andrew's monotone chain on integer points (exact arithmetic).
fn hull_of_points(mut pts: Vec<(i64, i64)>) -> Vec<(i64, i64)> {
    pts.sort_unstable();
    pts.dedup();
    if pts.len() <= 2 {
        return pts;
    }
    let mut hull: Vec<(i64, i64)> = Vec::with_capacity(2 * pts.len());
    for &p in &pts {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    let lower_len = hull.len() + 1;
    for &p in pts.iter().rev().skip(1) {
        while hull.len() >= lower_len && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    hull.pop(); // the first point again
    hull
}

/// Rasterises a convex polygon given by integer vertices in order (either orientation, as
/// returned by [`convex_hull`]): sets every pixel whose centre lies inside or on the boundary.
/// One vertex sets one pixel; two vertices set the lattice points of the segment. Vertices
/// outside the image are allowed; only pixels inside it are set.
pub fn fill_convex_polygon<S: Space>(poly: &[(i64, i64)], width: usize, height: usize) -> Mask<S> {
    let mut out = Mask::new(width, height);
    if poly.is_empty() || width == 0 || height == 0 {
        return out;
    }
    let xmin = poly.iter().map(|p| p.0).min().unwrap_or(0).max(0);
    let xmax = poly
        .iter()
        .map(|p| p.0)
        .max()
        .unwrap_or(-1)
        .min(width as i64 - 1);
    let ymin = poly.iter().map(|p| p.1).min().unwrap_or(0).max(0);
    let ymax = poly
        .iter()
        .map(|p| p.1)
        .max()
        .unwrap_or(-1)
        .min(height as i64 - 1);
    // Orientation sign so that inside means s·cross(edge, p − a) ≥ 0 for every edge.
    let area2: i64 = (0..poly.len())
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            a.0 * b.1 - b.0 * a.1
        })
        .sum();
    let s = if area2 < 0 { -1 } else { 1 };
    for y in ymin..=ymax {
        // Intersect the row with every edge's half-plane: s·(dx·(y − ay) − dy·(x − ax)) ≥ 0,
        // i.e. d·(x − ax) ≤ c with d = s·dy, c = s·dx·(y − ay).
        let (mut lo, mut hi) = (xmin, xmax);
        if poly.len() >= 2 {
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                let (dx, dy) = (b.0 - a.0, b.1 - a.1);
                let (c, d) = (s * dx * (y - a.1), s * dy);
                if d > 0 {
                    hi = hi.min(a.0 + c.div_euclid(d));
                } else if d < 0 {
                    // (x − ax) ≥ c / d = (−c) / (−d), rounded up.
                    lo = lo.max(a.0 - c.div_euclid(-d));
                } else if c < 0 {
                    lo = 1;
                    hi = 0;
                }
            }
        }
        for x in lo..=hi {
            out.set(x as usize, y as usize, true);
        }
    }
    out
}

/// The rasterised convex hull of a mask: every pixel whose centre lies in the hull of the set
/// pixels' centres (so the result contains the mask).
pub fn convex_hull_fill<S: Space>(mask: &Mask<S>) -> Mask<S> {
    fill_convex_polygon(&convex_hull(mask), mask.width(), mask.height())
}

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
        let (w, h) = mask.size();
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
    let (w, h) = mask.size();
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
    let (w, h) = mask.size();
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
    let (w, h) = mask.size();
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
    let (w, h) = mask.size();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Unspecified;

    /// Parses a mask drawn with '#' (set) and '.' (unset), one string per row.
    fn m(rows: &[&str]) -> Mask<Unspecified> {
        let h = rows.len();
        let w = rows[0].len();
        Mask::from_fn(w, h, |x, y| rows[y].as_bytes()[x] == b'#')
    }

    fn show(mask: &Mask<Unspecified>) -> Vec<String> {
        (0..mask.height())
            .map(|y| {
                (0..mask.width())
                    .map(|x| if mask.get(x, y) { '#' } else { '.' })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn otsu_splits_two_clusters_in_the_gap() {
        // Ten pixels at 0.1 and ten at 0.8: the classes are {0.1} and {0.8}; the threshold is
        // halfway between the largest low value and the smallest high value.
        let mut v = vec![0.1f32; 10];
        v.extend(vec![0.8f32; 10]);
        let p = Plane::<Unspecified>::from_vec(20, 1, v).unwrap();
        let t = otsu_threshold(&p);
        assert!((t - 0.45).abs() < 1e-6, "t = {t}");
        assert_eq!(p.threshold(t).count(), 10);
    }

    #[test]
    fn otsu_keeps_resolution_for_dim_values() {
        // Dim values (as in a dark scene's white − black difference): noise around 0.001 and a
        // lit level around 0.012, all below 4/255. An 8-bit histogram would merge them.
        let mut v = Vec::new();
        for i in 0..100 {
            v.push(0.0005 + 0.00001 * i as f32);
        }
        for i in 0..60 {
            v.push(0.011 + 0.00002 * i as f32);
        }
        let t = otsu_threshold_values(&v);
        assert!(t > 0.0015 && t < 0.011, "t = {t}");
        assert_eq!(v.iter().filter(|&&x| x > t).count(), 60);
    }

    #[test]
    fn otsu_three_clusters_picks_the_larger_gap_split() {
        // 0.0 ×50, 0.5 ×5, 1.0 ×45. Between-class variance for split {0}|{0.5,1}:
        // w0 w1 (μ0−μ1)² = 50·50·(0 − 0.95)² = 2256; for {0,0.5}|{1}: 55·45·(0.04545 − 1)² = 2255.
        // So the first split wins, narrowly: threshold halfway between 0 and 0.5.
        let mut v = vec![0.0f32; 50];
        v.extend(vec![0.5f32; 5]);
        v.extend(vec![1.0f32; 45]);
        let t = otsu_threshold_values(&v);
        assert!((t - 0.25).abs() < 1e-6, "t = {t}");
    }

    #[test]
    fn otsu_constant_and_empty() {
        assert_eq!(otsu_threshold_values(&[0.3; 7]), 0.3);
        assert_eq!(otsu_threshold_values(&[]), 0.0);
        assert_eq!(otsu_threshold_values(&[f32::NAN, 0.2]), 0.2);
    }

    #[test]
    fn components_use_8_connectivity() {
        let mask = m(&[
            "##....", //
            "..#...", // diagonal link to the pair above
            "......", //
            "....##", //
            "....##", //
        ]);
        let cc = connected_components(&mask);
        assert_eq!(cc.count(), 2);
        assert_eq!(cc.label(0, 0), 1);
        assert_eq!(cc.label(2, 1), 1);
        assert_eq!(cc.label(4, 3), 2);
        assert_eq!(cc.size(1), 3);
        assert_eq!(cc.size(2), 4);
        assert_eq!(cc.largest(), Some(2));
        assert_eq!(
            show(&largest_component(&mask)),
            ["......", "......", "......", "....##", "....##"]
        );
    }

    #[test]
    fn largest_component_ties_take_the_first_and_empty_stays_empty() {
        let mask = m(&["#.#"]);
        assert_eq!(show(&largest_component(&mask)), ["#.."]);
        let empty = m(&["..."]);
        assert_eq!(connected_components(&empty).largest(), None);
        assert_eq!(largest_component(&empty).count(), 0);
    }

    #[test]
    fn major_components_keep_the_big_ones() {
        // Sizes 6, 3 and 1.
        let mask = m(&[
            "###..#", //
            "###...", //
            "......", //
            "##....", //
            "#.....", //
        ]);
        assert_eq!(
            show(&major_components(&mask, 0.5)),
            ["###...", "###...", "......", "##....", "#....."]
        );
        assert_eq!(
            show(&major_components(&mask, 1.0)),
            show(&largest_component(&mask))
        );
        assert_eq!(major_components(&mask, 0.1).count(), 10);
        assert_eq!(major_components(&m(&["..."]), 0.5).count(), 0);
    }

    #[test]
    fn fill_holes_fills_enclosed_background_only() {
        let mask = m(&[
            "#####...", //
            "#..##...", // hole of two pixels
            "#####..#", //
            "......#.", //
            ".###...#", // this notch is open to the border below
            ".#.#....", //
        ]);
        let expected = [
            "#####...", //
            "#####...", //
            "#####..#", //
            "......#.", //
            ".###...#", //
            ".#.#....", //
        ];
        assert_eq!(show(&fill_holes(&mask)), expected);
        // A ring closed only through diagonal steps still encloses its centre (4-connected
        // background).
        let ring = m(&[".....", "..#..", ".#.#.", "..#..", "....."]);
        assert_eq!(
            show(&fill_holes(&ring)),
            [".....", "..#..", ".###.", "..#..", "....."]
        );
    }

    #[test]
    fn hull_of_an_l_shape() {
        let mask = m(&[
            "#.....", //
            "#.....", //
            "#.....", //
            "######", //
        ]);
        // Hull vertices: (0,0), (0,3), (5,3) — a right triangle. Pixel centres inside or on it:
        // row y has x ≤ 5·y/3.
        let hull = convex_hull(&mask);
        assert_eq!(hull.len(), 3, "{hull:?}");
        for v in [(0, 0), (0, 3), (5, 3)] {
            assert!(hull.contains(&v), "{hull:?}");
        }
        assert_eq!(
            show(&convex_hull_fill(&mask)),
            ["#.....", "##....", "####..", "######"]
        );
    }

    #[test]
    fn hull_degenerate_cases() {
        let one = m(&["....", ".#..", "...."]);
        assert_eq!(convex_hull(&one), vec![(1, 1)]);
        assert_eq!(show(&convex_hull_fill(&one)), show(&one));
        // Two pixels on a diagonal: the segment's lattice points are exactly its three pixels.
        let diag = m(&["#...", "....", "..#."]);
        assert_eq!(convex_hull(&diag).len(), 2);
        assert_eq!(show(&convex_hull_fill(&diag)), ["#...", ".#..", "..#."]);
        assert!(convex_hull(&m(&["..."])).is_empty());
    }

    #[test]
    fn hull_of_a_diamond_keeps_the_diamond() {
        let diamond = m(&[
            "...#...", //
            "..###..", //
            ".#####.", //
            "..###..", //
            "...#...", //
        ]);
        assert_eq!(show(&convex_hull_fill(&diamond)), show(&diamond));
        // Removing the inside changes nothing in the hull.
        let outline = m(&[
            "...#...", //
            "..#.#..", //
            ".#...#.", //
            "..#.#..", //
            "...#...", //
        ]);
        assert_eq!(show(&convex_hull_fill(&outline)), show(&diamond));
    }

    #[test]
    fn integral_counts() {
        let mask = m(&["#.#", "###", "..#"]);
        let sat = IntegralMask::new(&mask);
        assert_eq!(sat.count_in(0, 0, 3, 3), 6);
        assert_eq!(sat.count_in(1, 0, 3, 2), 3);
        assert_eq!(sat.count_in(2, 0, 9, 9), 3); // clipped
        assert!(sat.all_set(0, 1, 3, 1));
        assert!(!sat.all_set(0, 0, 2, 2));
        assert!(!sat.all_set(2, 2, 1, 2)); // leaves the image
    }

    #[test]
    fn dilate_and_erode_square_and_disk() {
        let dot = m(&[".....", ".....", "..#..", ".....", "....."]);
        assert_eq!(
            show(&dilate(&dot, Element::Square(1))),
            [".....", ".###.", ".###.", ".###.", "....."]
        );
        // Disk of radius 1: the 4 edge neighbours only (diagonals are at distance √2 > 1).
        assert_eq!(
            show(&dilate(&dot, Element::Disk(1))),
            [".....", "..#..", ".###.", "..#..", "....."]
        );
        // Disk of radius 2 includes the diagonals (√2) but not (2,1)-offsets (√5).
        assert_eq!(
            show(&dilate(&dot, Element::Disk(2))),
            ["..#..", ".###.", "#####", ".###.", "..#.."]
        );
        let block = m(&["#####", "#####", "#####", "####.", "#####"]);
        // Erosion: the edge counts as background, so only (1..=3, 1..=3) can survive, and those
        // whose element reaches the missing pixel (4,3) go: (3,2) and (3,3) for the square,
        // only its edge neighbour (3,3) for the radius-1 disk.
        assert_eq!(
            show(&erode(&block, Element::Square(1))),
            [".....", ".###.", ".##..", ".##..", "....."]
        );
        assert_eq!(
            show(&erode(&block, Element::Disk(1))),
            [".....", ".###.", ".###.", ".##..", "....."]
        );
    }

    #[test]
    fn morphology_of_empty_and_full_masks() {
        let empty = m(&[".....", ".....", "....."]);
        for el in [Element::Square(1), Element::Disk(2)] {
            assert_eq!(dilate(&empty, el).count(), 0);
            assert_eq!(close(&empty, el).count(), 0);
        }
        let full = m(&["#####", "#####", "#####"]);
        // Radius 1: only the middle row's inner pixels are one pixel away from the edge.
        for el in [Element::Square(1), Element::Disk(1)] {
            assert_eq!(show(&erode(&full, el)), [".....", ".###.", "....."]);
            assert_eq!(show(&close(&full, el)), show(&full));
        }
        // Opening is the union of element placements inside the mask (the outside being
        // background): squares cover the whole rectangle, crosses cannot reach its corners.
        assert_eq!(show(&open(&full, Element::Square(1))), show(&full));
        assert_eq!(
            show(&open(&full, Element::Disk(1))),
            [".###.", "#####", ".###."]
        );
    }

    #[test]
    fn closing_fills_a_gap_and_opening_removes_a_spur() {
        let gap = m(&[
            "........", //
            ".##.###.", //
            ".##.###.", //
            "........", //
        ]);
        assert_eq!(
            show(&close(&gap, Element::Square(1))),
            ["........", ".######.", ".######.", "........"]
        );
        // Closing near the image edge keeps the unset margin (padded computation) and never
        // removes pixels.
        let edge = m(&["#....", "#....", "#...."]);
        assert_eq!(show(&close(&edge, Element::Disk(2))), show(&edge));
        let spur = m(&[
            ".......", //
            ".###...", //
            ".######", // a one-pixel-high spur to the right
            ".###...", //
            ".......", //
        ]);
        assert_eq!(
            show(&open(&spur, Element::Square(1))),
            [".......", ".###...", ".###...", ".###...", "......."]
        );
    }

    #[test]
    fn closing_a_one_pixel_notch_square_versus_disk() {
        // A 1-pixel notch into the top edge of a block. The square fills it. A Euclidean disk
        // has a one-pixel tip (offset (0, r) is in it, (±1, r) are not), so a disk centred above
        // the block touches the notch without meeting the block: disk closing leaves it.
        let notch = m(&[
            ".......", //
            ".##.##.", //
            ".#####.", //
            ".#####.", //
            ".......", //
        ]);
        assert_eq!(
            show(&close(&notch, Element::Square(1))),
            [".......", ".#####.", ".#####.", ".#####.", "......."]
        );
        assert_eq!(show(&close(&notch, Element::Disk(2))), show(&notch));
    }
}
