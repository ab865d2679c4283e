//! The projector's field of view in the camera (DESIGN.md section 4): the FOV mask from the black
//! and white reference captures, the affine initialisation of the warp from its bounding box, and
//! the optimal displayable area (the largest canvas-shaped rectangle inside the mask) with the
//! placement of desired images into it.
//!
//! All masks, rectangles and images here are in **camera pixels**. Pixel values are the encoded
//! \[0,1\] values of the captures (sRGB-encoded, not linearised).
//!
//! # FOV mask algorithm
//!
//! A plain Otsu threshold on white − black fails where the surface is dark (the projector adds
//! little light, so the difference is small) or saturated (black and white both clip), and where
//! the projector light falls off towards the corners: Otsu then separates bright texture from
//! dark texture instead of lit from unlit, and keeps only part of the lit area. Here Otsu only
//! finds a sure *core*; the boundary is decided by a noise-aware low threshold and a local
//! half-level test:
//!
//! 1. `D` = Gaussian blur (σ ≈ 1 px at 320 px) of gray(max(white − black, 0)).
//! 2. Core: the largest connected region of `D` above its Otsu threshold (with any other region
//!    at least `min_part` of its size: a shadow may split the projection). Lit level `L` = median
//!    of `D` over the core.
//! 3. Noise: median and robust σ (1.4826·MAD) of `D` over pixels well away from the lit area
//!    (outside the core's convex hull dilated by a margin; re-estimated once outside the first
//!    support). When there is too little of it, or it is itself lit (median above 0.3·L: the
//!    projection fills the frame), the low threshold is 0.1·L instead.
//! 4. Support: `D` above the low threshold `max(noise median + k·σ, f·L)` (capped at the Otsu
//!    threshold), the connected regions holding the core (hysteresis), holes filled. This keeps
//!    dark texture as long as it is above the camera noise, but it also includes the blur's spill
//!    a few pixels past the true edge.
//! 5. Edge: in a band on both sides of the support's edge, a pixel is lit where `D` reaches half
//!    the local level (the median `D` of support pixels nearby that lie at least 2 px deeper
//!    inside, i.e. the plateau inward along the edge normal) and stands above the noise. A
//!    blurred step crosses half its height at the true edge whatever its brightness, so the
//!    spill goes, and the edges of dim texture move out to where they belong.
//! 6. Fill, region by region: morphological closing (default; fills notches left by dark texture
//!    at the edge) or convex hull, then hole filling; keep the largest region and those at least
//!    `min_part` of its size.
//!
//! Dark or saturated patches below the noise inside the lit area become holes and are filled;
//! at the edge they become notches that the closing fills when narrow, and the hull always.
//! Limits: where the white capture clips, the lit level is underestimated and the edge moves
//! outward by up to about a pixel; a shadow narrower than about 4 σ of the total blur is bridged
//! (its middle stays above the low threshold) and ends up inside the mask.

use serde::Serialize;

use crate::error::{Error, Result};
use crate::filter::gaussian_blur;
use crate::morph::{self, Element, IntegralMask};
use crate::raster::{CamImage, Camera, Mask, Rect, Rgb, Space, check_same_size};

// ---------------------------------------------------------------------------------------------
// FOV mask
// ---------------------------------------------------------------------------------------------

/// How the FOV mask is completed after thresholding.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FovFill {
    /// Fill holes only.
    Holes,
    /// Morphological closing with a disk, then fill holes (default). Keeps concave edges.
    Close,
    /// Convex hull of the region. Recovers any dark notch at the edge, but also fills truly
    /// concave edges (e.g. a projection bent by a curved surface) with unlit pixels.
    Hull,
}

/// Settings of [`fov_mask_with`]. `Default` is what [`fov_mask`] uses.
#[derive(Clone, Debug)]
pub struct FovOptions {
    /// Gaussian σ (camera pixels) of the blur of the difference image. `None`: max(1, min(w,h)/320).
    pub blur_sigma: Option<f64>,
    /// The low threshold is at least the background median plus this many robust σ of the noise.
    pub noise_k: f32,
    /// The low threshold is at least this fraction of the lit level.
    pub min_level_frac: f32,
    /// Edge test: a pixel in the edge band is lit where its difference reaches this fraction of
    /// the local level, the median difference of the support pixels within `edge_band` of it
    /// that lie at least 2 px deeper inside (0.5: the middle of a blurred step).
    pub edge_frac: f32,
    /// Width (camera pixels) of the edge band. `None`: ceil(3σ) + 2.
    pub edge_band: Option<usize>,
    /// How to complete the mask.
    pub fill: FovFill,
    /// Disk radius (camera pixels) for [`FovFill::Close`]. `None`: max(2, min(w,h)/24).
    pub close_radius: Option<usize>,
    /// The lit level (median white − black in the core, encoded units) must reach this, or no
    /// projector light is considered found. 0.02 ≈ 5/255.
    pub min_contrast: f32,
    /// The mask must cover at least this fraction of the camera frame.
    pub min_coverage: f64,
    /// Lit regions holding at least this fraction of the largest one's pixels are kept (1.0:
    /// the largest only). A shadow cast across the projection by the surface itself (a step, a
    /// pillar) splits the lit area into parts that all belong to the FOV; small stray regions
    /// (a reflection on another wall, specks) are dropped.
    pub min_part: f64,
}

impl Default for FovOptions {
    fn default() -> Self {
        Self {
            blur_sigma: None,
            noise_k: 5.0,
            min_level_frac: 0.03,
            edge_frac: 0.5,
            edge_band: None,
            fill: FovFill::Close,
            close_radius: None,
            min_contrast: 0.02,
            min_coverage: 0.01,
            min_part: 0.25,
        }
    }
}

/// What the FOV detection measured, for logs and the model metadata. Levels are values of the
/// blurred gray white − black difference (encoded units, \[0,1\]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FovDiagnostics {
    /// Camera frame size (width, height).
    pub size: (usize, usize),
    /// Blur σ used, camera pixels.
    pub blur_sigma: f64,
    /// Otsu threshold of the difference (defines the core).
    pub otsu_threshold: f32,
    /// Median difference over the core.
    pub lit_level: f32,
    /// Median and robust σ of the difference away from the lit area, and how many pixels they
    /// come from (0 when the lit area leaves too little background, or when that background is
    /// itself lit, its median above 0.3 × lit level; then the low threshold is 0.1 × lit level).
    pub noise_median: f32,
    pub noise_sigma: f32,
    pub noise_pixels: usize,
    /// The low threshold used for the support.
    pub threshold: f32,
    /// Pixels in the core, in the support, removed from and added to the support by the edge
    /// test, added by the fill.
    pub core_pixels: usize,
    pub support_pixels: usize,
    pub edge_trimmed: usize,
    pub edge_grown: usize,
    pub fill_added: usize,
    /// Fill method used.
    pub fill: FovFill,
    /// Fraction of the camera frame inside the final mask.
    pub coverage: f64,
}

/// The projector FOV in camera space.
#[derive(Clone, Debug)]
pub struct FovMask {
    /// Lit camera pixels.
    pub mask: Mask<Camera>,
    /// Bounding box of the mask, camera pixels.
    pub bbox: Rect,
    pub diagnostics: FovDiagnostics,
}

/// [`fov_mask_with`] with default options.
pub fn fov_mask(black: &CamImage, white: &CamImage, label: &str) -> Result<FovMask> {
    fov_mask_with(black, white, label, &FovOptions::default())
}

/// The projector FOV mask from the captures of the black (img_0001) and white (img_0125)
/// reference images. `label` names them in errors (e.g. their paths).
///
/// Errors: [`Error::Input`] when the captures differ in size or are empty; [`Error::Failed`] when
/// no projector light is found or the lit region is smaller than `min_coverage` of the frame.
pub fn fov_mask_with(
    black: &CamImage,
    white: &CamImage,
    label: &str,
    opt: &FovOptions,
) -> Result<FovMask> {
    let (w, h) = white.size();
    if black.size() != white.size() {
        return Err(Error::Input(format!(
            "{label}: black capture is {}x{} but white capture is {w}x{h}; they must come from \
             the same camera setting",
            black.width(),
            black.height()
        )));
    }
    if w == 0 || h == 0 {
        return Err(Error::Input(format!(
            "{label}: captures are empty ({w}x{h})"
        )));
    }
    let n = w * h;
    let short = w.min(h);
    let sigma = opt
        .blur_sigma
        .unwrap_or_else(|| (short as f64 / 320.0).max(1.0));

    // 1. Blurred gray difference.
    let diff = Rgb::<Camera>::from_vec(
        w,
        h,
        white
            .data()
            .iter()
            .zip(black.data())
            .map(|(&a, &b)| (a - b).max(0.0))
            .collect(),
    )?;
    let d = gaussian_blur(&diff.to_gray(), sigma);
    let dv = d.data();
    let d_max = dv.iter().copied().fold(0.0f32, f32::max);

    // 2. Core and lit level.
    let t_otsu = morph::otsu_threshold(&d);
    let core = morph::major_components(&d.threshold(t_otsu), opt.min_part);
    let core_pixels = core.count();
    let no_light = |what: String| {
        Error::Failed(format!(
            "{label}: no projector light found in white − black ({what}; brightest difference \
             {d_max:.4}); check that the projector is on, shows the white image, and is in view \
             of the camera"
        ))
    };
    if core_pixels == 0 {
        return Err(no_light("the difference is uniform".into()));
    }
    let lit_level = median(
        core.data()
            .iter()
            .zip(dv)
            .filter(|(m, _)| **m)
            .map(|(_, &v)| v),
    );
    if lit_level < opt.min_contrast {
        return Err(no_light(format!(
            "lit level {lit_level:.4} is below the minimum contrast {:.4}",
            opt.min_contrast
        )));
    }

    // 3–4. Noise statistics away from the lit area, low threshold, hysteresis support; twice,
    // the second time with the noise taken outside the first support.
    let margin = (3.0 * sigma).ceil() as usize + 2;
    let mut lit_guess = morph::convex_hull_fill(&core);
    let mut stats = NoiseStats::default();
    let mut support = core.clone();
    let mut t_low = t_otsu;
    for _ in 0..2 {
        let away = morph::dilate(&lit_guess, Element::Disk(margin));
        stats = noise_stats(dv, away.data(), n);
        if stats.median > LIT_BACKGROUND * lit_level {
            // What lies outside the core is itself lit (darker texture of a projection that
            // fills the frame), not background: no noise estimate.
            stats = NoiseStats::default();
        }
        t_low = if stats.pixels > 0 {
            (stats.median + opt.noise_k * stats.sigma).max(opt.min_level_frac * lit_level)
        } else {
            (0.1 * lit_level).max(opt.min_level_frac * lit_level)
        }
        .min(t_otsu);
        let cc = morph::connected_components(&d.threshold(t_low));
        let mut hit = vec![false; cc.count() + 1];
        for (&m, &l) in core.data().iter().zip(cc.labels()) {
            hit[l as usize] |= m;
        }
        support = morph::fill_holes(&cc.select(|l| hit[l as usize]));
        lit_guess = support.clone();
    }
    let support_pixels = support.count();

    // 5. Edge refinement in a band on both sides of the support's edge (the image border is not
    // an edge). Depth is the signed distance to the edge: positive inside the support (distance
    // to the nearest pixel outside it), negative outside (minus the distance to the support).
    // A band pixel is compared with the median difference of the support pixels near it that lie
    // at least 2 px deeper: the plateau just inward along the edge normal, which for a dim texel
    // at the edge is that texel itself. It is lit where it reaches `edge_frac` of that level and
    // stands above the noise (median + 3σ).
    let band_w = opt.edge_band.unwrap_or((3.0 * sigma).ceil() as usize + 2);
    let to_out = morph::squared_distance(&support, true);
    let to_in = morph::squared_distance(&support, false);
    let depth: Vec<f32> = (0..n)
        .map(|i| {
            if support.data()[i] {
                to_out[i].sqrt() as f32
            } else {
                -(to_in[i].sqrt() as f32)
            }
        })
        .collect();
    let noise_floor = if stats.pixels > 0 {
        stats.median + 3.0 * stats.sigma
    } else {
        t_low
    };
    let r = band_w as isize;
    let bw = band_w as f32;
    let mut refined = support.clone();
    let (mut edge_trimmed, mut edge_grown) = (0, 0);
    let mut near = Vec::with_capacity((2 * band_w + 1).pow(2));
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if depth[i].abs() > bw {
                continue;
            }
            near.clear();
            for yy in (y as isize - r).max(0)..(y as isize + r + 1).min(h as isize) {
                for xx in (x as isize - r).max(0)..(x as isize + r + 1).min(w as isize) {
                    let j = yy as usize * w + xx as usize;
                    if depth[j] > 0.0 && depth[j] >= depth[i] + 2.0 {
                        near.push(dv[j]);
                    }
                }
            }
            if near.is_empty() {
                continue;
            }
            let level = median(near.iter().copied());
            let lit = dv[i] >= opt.edge_frac * level && dv[i] > noise_floor;
            if lit != support.data()[i] {
                refined.data_mut()[i] = lit;
                if lit {
                    edge_grown += 1;
                } else {
                    edge_trimmed += 1;
                }
            }
        }
    }
    let parts = morph::connected_components(&refined);
    let part_labels = morph::major_labels(&parts, opt.min_part);
    let refined_count: usize = part_labels.iter().map(|&l| parts.size(l)).sum();

    // 6. Fill, each part on its own (so that a closing does not bridge the shadow between two
    // parts), then keep the major parts of the union.
    let close_r = opt.close_radius.unwrap_or((short / 24).max(2));
    let mut filled = Mask::<Camera>::new(w, h);
    for &l in &part_labels {
        let part = parts.component::<Camera>(l);
        let done = match opt.fill {
            FovFill::Holes => morph::fill_holes(&part),
            FovFill::Close => morph::fill_holes(&morph::close(&part, Element::Disk(close_r))),
            FovFill::Hull => morph::convex_hull_fill(&part),
        };
        for (f, &v) in filled.data_mut().iter_mut().zip(done.data()) {
            *f |= v;
        }
    }
    let mask = morph::major_components(&filled, opt.min_part);
    let count = mask.count();
    let fill_added = count.saturating_sub(refined_count);
    let coverage = count as f64 / n as f64;
    let diagnostics = FovDiagnostics {
        size: (w, h),
        blur_sigma: sigma,
        otsu_threshold: t_otsu,
        lit_level,
        noise_median: stats.median,
        noise_sigma: stats.sigma,
        noise_pixels: stats.pixels,
        threshold: t_low,
        core_pixels,
        support_pixels,
        edge_trimmed,
        edge_grown,
        fill_added,
        fill: opt.fill,
        coverage,
    };
    let Some(bbox) = mask.bounding_box().filter(|_| coverage >= opt.min_coverage) else {
        return Err(Error::Failed(format!(
            "{label}: projector FOV mask too small: {count} of {w}x{h} camera pixels \
             ({:.2}%, need at least {:.2}%); lit level {lit_level:.4}, threshold {t_low:.4}, \
             Otsu threshold {t_otsu:.4}, Otsu core {core_pixels} pixels; check that the \
             projector is on and its image is in view of the camera",
            100.0 * coverage,
            100.0 * opt.min_coverage
        )));
    };
    Ok(FovMask {
        mask,
        bbox,
        diagnostics,
    })
}

/// A "background" whose median difference exceeds this fraction of the lit level is taken to be
/// lit too (the projection fills the camera frame and Otsu split bright texture from dark
/// texture). Real background stays near zero: camera noise, or some percent of stray and
/// inter-reflected light (the virtual rig's glossy inside corner reaches about 0.2).
const LIT_BACKGROUND: f32 = 0.3;

#[derive(Clone, Copy, Debug, Default)]
struct NoiseStats {
    median: f32,
    sigma: f32,
    pixels: usize,
}

/// Median and robust σ (1.4826 · median absolute deviation) of the values where `exclude` is
/// false; zero pixels when fewer than max(64, 2 % of the frame) remain.
fn noise_stats(values: &[f32], exclude: &[bool], n: usize) -> NoiseStats {
    let sample: Vec<f32> = values
        .iter()
        .zip(exclude)
        .filter(|(_, e)| !**e)
        .map(|(&v, _)| v)
        .collect();
    if sample.len() < (n / 50).max(64) {
        return NoiseStats::default();
    }
    let med = median(sample.iter().copied());
    let mad = median(sample.iter().map(|&v| (v - med).abs()));
    NoiseStats {
        median: med,
        sigma: 1.4826 * mad,
        pixels: sample.len(),
    }
}

/// Median of the values (the upper median for an even count); 0 for none.
fn median(values: impl Iterator<Item = f32>) -> f32 {
    let mut v: Vec<f32> = values.collect();
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

// ---------------------------------------------------------------------------------------------
// Affine initialisation
// ---------------------------------------------------------------------------------------------

/// A 2×3 affine matrix θ in the PyTorch `affine_grid` convention: a destination position
/// (u, v) in normalised coordinates maps to the source position θ · (u, v, 1).
pub type Theta = [[f32; 3]; 2];

/// Normalised coordinate (align_corners = true) of pixel coordinate `i` on an axis of `n` pixels:
/// pixel centre 0 ↦ −1, pixel centre n−1 ↦ +1 (0 when n ≤ 1).
fn pixel_to_norm(i: f64, n: usize) -> f64 {
    if n <= 1 {
        0.0
    } else {
        2.0 * i / (n - 1) as f64 - 1.0
    }
}

/// The affine θ that makes the network image cover exactly `bbox` of the camera frame
/// (`cam_size` = (width, height)).
///
/// Convention (DESIGN.md section 2): θ maps **network** normalised coordinates (u, v) to
/// **camera** normalised coordinates (x, y) = θ · (u, v, 1), both with align_corners = true, so
/// (−1, −1) and (1, 1) are the centres of the first and last pixels. The network's corner pixel
/// centres land on the centres of the box's corner pixels: u = −1 ↦ camera column `bbox.x`,
/// u = +1 ↦ column `bbox.x + bbox.width − 1` (likewise rows). Sampling the camera image with
/// `affine_grid(θ)` at network resolution therefore crops the box and stretches it to the
/// network size. The full frame gives the identity.
pub fn affine_from_box(bbox: Rect, cam_size: (usize, usize)) -> Result<Theta> {
    let (cw, ch) = cam_size;
    if bbox.width == 0 || bbox.height == 0 || bbox.x + bbox.width > cw || bbox.y + bbox.height > ch
    {
        return Err(Error::Shape(format!(
            "FOV box {bbox} is empty or does not fit in the {cw}x{ch} camera frame"
        )));
    }
    // Column x_c = bbox.x + (u + 1)/2 · (bbox.width − 1); normalised x = 2 x_c/(cw − 1) − 1.
    // Linear in u: slope (bbox.width − 1)/(cw − 1), value at u = 0 is the box centre.
    let axis = |start: usize, len: usize, n: usize| -> (f32, f32) {
        let scale = if n <= 1 {
            0.0
        } else {
            (len - 1) as f64 / (n - 1) as f64
        };
        let centre = pixel_to_norm(start as f64 + (len - 1) as f64 / 2.0, n);
        (scale as f32, centre as f32)
    };
    let (sx, tx) = axis(bbox.x, bbox.width, cw);
    let (sy, ty) = axis(bbox.y, bbox.height, ch);
    Ok([[sx, 0.0, tx], [0.0, sy, ty]])
}

/// Applies θ to a normalised position (u, v): returns θ · (u, v, 1).
pub fn apply_theta(theta: &Theta, u: f32, v: f32) -> (f32, f32) {
    (
        theta[0][0] * u + theta[0][1] * v + theta[0][2],
        theta[1][0] * u + theta[1][1] * v + theta[1][2],
    )
}

// ---------------------------------------------------------------------------------------------
// Optimal displayable area
// ---------------------------------------------------------------------------------------------

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
    let (w, h) = mask.size();
    let wide = aspect >= 1.0;
    // (width, height) of the rectangle whose longer side is s.
    let dims = |s: usize| -> (usize, usize) {
        if wide {
            (s, (s as f64 / aspect).round() as usize)
        } else {
            ((s as f64 * aspect).round() as usize, s)
        }
    };
    let limit = if wide { w } else { h };
    let sat = IntegralMask::new(mask);
    let fits = |s: usize| -> bool {
        let (rw, rh) = dims(s);
        if rw == 0 || rh == 0 || rw > w || rh > h {
            return false;
        }
        (0..=h - rh).any(|y| (0..=w - rw).any(|x| sat.all_set(x, y, rw, rh)))
    };
    // Smallest s whose shorter side rounds to at least one pixel.
    let mut lo = 1usize;
    while lo <= limit && {
        let (rw, rh) = dims(lo);
        rw == 0 || rh == 0
    } {
        lo += 1;
    }
    if lo > limit || !fits(lo) {
        let (rw, rh) = dims(lo.min(limit.max(1)));
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
    let (rw, rh) = dims(lo);

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

/// Places `img` (any space, e.g. a network-space test image) into `area` of a black camera-space
/// canvas of `canvas_size` = (width, height), stretched to fill the area with
/// [`crate::resize::resize_bilinear`]: the desired viewer image `z'` of `cam/desire/test`.
pub fn place_in_area<T: Space>(
    img: &Rgb<T>,
    area: Rect,
    canvas_size: (usize, usize),
) -> Result<CamImage> {
    let (cw, ch) = canvas_size;
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
    for y in 0..area.height {
        for x in 0..area.width {
            out.set(area.x + x, area.y + y, small.get(x, y));
        }
    }
    Ok(out)
}

/// The neutral range of camera values the projector can produce across a displayable area:
/// desired images mapped into `[low, high]` are physically reachable almost everywhere in it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct DisplayRange {
    /// Camera value (encoded, [0,1]) the projector's black cannot go below at most pixels.
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
    let (w, h) = white.size();
    if area.width == 0 || area.height == 0 || area.x + area.width > w || area.y + area.height > h {
        return Err(Error::Shape(format!(
            "display range: area {area} does not fit in the {w}x{h} camera frame"
        )));
    }
    const MIN_CONTRAST: f32 = 0.02;
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
