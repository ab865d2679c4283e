//! The projector FOV mask from the black and white reference captures (the algorithm's steps 1–6
//! are described in [`super`]).
//!
//! Masks, images and sizes are in camera pixels; levels are blurred gray white − black
//! differences in encoded units \[0,1\].

use serde::Serialize;

use crate::error::{Error, Result};
use crate::filter::gaussian_blur;
use crate::morph::{self, Element};
use crate::raster::{CamImage, Camera, ImageSize, Mask, Plane, Rect, Rgb};

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
    #[serde(with = "crate::raster::as_pair")]
    pub size: ImageSize,
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
    check_captures(black, white, label)?;
    let ImageSize {
        width: w,
        height: h,
    } = white.size();
    let n = w * h;
    let short = w.min(h);
    let sigma = opt
        .blur_sigma
        .unwrap_or_else(|| (short as f64 / 320.0).max(1.0));

    // 1. Blurred gray difference.
    let d = blurred_difference(black, white, sigma)?;
    let dv = d.data();

    // 2. Core and lit level.
    let (t_otsu, core, lit_level) = core_and_level(&d, opt, label)?;
    let core_pixels = core.count();

    // 3–4. Noise statistics away from the lit area, low threshold, hysteresis support.
    let (support, stats, t_low) = hysteresis_support(&d, &core, lit_level, t_otsu, sigma, opt);
    let support_pixels = support.count();

    // 5. Edge refinement in a band on both sides of the support's edge.
    let band_w = opt.edge_band.unwrap_or((3.0 * sigma).ceil() as usize + 2);
    let noise_floor = if stats.pixels > 0 {
        stats.median + 3.0 * stats.sigma
    } else {
        t_low
    };
    let (refined, edge_trimmed, edge_grown) =
        refine_edge(dv, ImageSize::new(w, h), &support, band_w, noise_floor, opt);
    let parts = morph::connected_components(&refined);
    let part_labels = morph::major_labels(&parts, opt.min_part);
    let refined_count: usize = part_labels.iter().map(|&l| parts.size(l)).sum();

    // 6. Fill each part, keep the major parts of the union.
    let close_r = opt.close_radius.unwrap_or((short / 24).max(2));
    let mask = fill_parts(&parts, &part_labels, ImageSize::new(w, h), close_r, opt);
    let count = mask.count();
    let fill_added = count.saturating_sub(refined_count);
    let coverage = count as f64 / n as f64;
    let diagnostics = FovDiagnostics {
        size: ImageSize::new(w, h),
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

/// Checks that the black and white captures have one size and are not empty.
fn check_captures(black: &CamImage, white: &CamImage, label: &str) -> Result<()> {
    let ImageSize {
        width: w,
        height: h,
    } = white.size();
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
    Ok(())
}

/// Step 1: `D`, the gray of max(white − black, 0) blurred with a Gaussian of `sigma` camera
/// pixels (encoded units).
fn blurred_difference(black: &CamImage, white: &CamImage, sigma: f64) -> Result<Plane<Camera>> {
    let ImageSize {
        width: w,
        height: h,
    } = white.size();
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
    Ok(gaussian_blur(&diff.to_gray(), sigma))
}

/// Step 2: the Otsu threshold of `d`, the core (its major regions above it) and the lit level
/// (median of `d` over the core). Errors when there is no core or the lit level is below
/// `min_contrast`.
fn core_and_level(
    d: &Plane<Camera>,
    opt: &FovOptions,
    label: &str,
) -> Result<(f32, Mask<Camera>, f32)> {
    let dv = d.data();
    let d_max = dv.iter().copied().fold(0.0f32, f32::max);
    let t_otsu = morph::otsu_threshold(d);
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
    Ok((t_otsu, core, lit_level))
}

/// Steps 3–4: noise statistics away from the lit area, the low threshold and the hysteresis
/// support (regions of `d` above it that hold the core, holes filled); twice, the second time
/// with the noise taken outside the first support. Returns the support, the noise statistics
/// and the low threshold.
fn hysteresis_support(
    d: &Plane<Camera>,
    core: &Mask<Camera>,
    lit_level: f32,
    t_otsu: f32,
    sigma: f64,
    opt: &FovOptions,
) -> (Mask<Camera>, NoiseStats, f32) {
    let dv = d.data();
    let n = dv.len();
    let margin = (3.0 * sigma).ceil() as usize + 2;
    let mut lit_guess = morph::convex_hull_fill(core);
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
    (support, stats, t_low)
}

/// Step 5: edge refinement in a band of `band_w` camera pixels on both sides of the support's
/// edge (the image border is not an edge). Depth is the signed distance to the edge: positive
/// inside the support (distance to the nearest pixel outside it), negative outside (minus the
/// distance to the support). A band pixel is compared with the median difference of the support
/// pixels near it that lie at least 2 px deeper: the plateau just inward along the edge normal,
/// which for a dim texel at the edge is that texel itself. It is lit where it reaches
/// `edge_frac` of that level and stands above `noise_floor` (noise median + 3σ). Returns the
/// refined mask and the pixels trimmed and grown.
fn refine_edge(
    dv: &[f32],
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    support: &Mask<Camera>,
    band_w: usize,
    noise_floor: f32,
    opt: &FovOptions,
) -> (Mask<Camera>, usize, usize) {
    let n = w * h;
    let to_out = morph::squared_distance(support, true);
    let to_in = morph::squared_distance(support, false);
    let depth: Vec<f32> = (0..n)
        .map(|i| {
            if support.data()[i] {
                to_out[i].sqrt() as f32
            } else {
                -(to_in[i].sqrt() as f32)
            }
        })
        .collect();
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
    (refined, edge_trimmed, edge_grown)
}

/// Step 6: fill each major part of `parts` on its own (so that a closing does not bridge the
/// shadow between two parts; `close_r` is the closing's disk radius in camera pixels), then keep
/// the major parts of the union.
fn fill_parts(
    parts: &morph::Components,
    part_labels: &[u32],
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    close_r: usize,
    opt: &FovOptions,
) -> Mask<Camera> {
    let mut filled = Mask::<Camera>::new(w, h);
    for &l in part_labels {
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
    morph::major_components(&filled, opt.min_part)
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
