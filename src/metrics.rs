//! Image quality metrics with the paper's conventions (docs/architecture.md, "Models").
//!
//! Over a set of image pairs: MSE is averaged over all pixels, channels and images (pooled);
//! PSNR = 10·log10(1/MSE) of that pooled mean (peak 1.0); RMSE = √(3·MSE), i.e. the root of the
//! per-pixel squared RGB error; SSIM uses an 11×11 Gaussian window (σ = 1.5) with replicate
//! padding, C1 = 0.01², C2 = 0.03² (data range 1), computed per channel on the full-size map and
//! averaged over pixels, channels and images. Values are compared as they are in memory: no mask,
//! no clamping, no colour conversion.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::filter::{gaussian_kernel, separable_replicate};
use crate::raster::{Plane, Rgb, Space};

/// Gaussian window of the SSIM: 11 taps, σ = 1.5 pixels.
pub const SSIM_RADIUS: usize = 5;
pub const SSIM_SIGMA: f64 = 1.5;
pub const SSIM_C1: f64 = 0.01 * 0.01;
pub const SSIM_C2: f64 = 0.03 * 0.03;

/// Scores of a set of image pairs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// dB; infinite when the images are identical.
    pub psnr: f64,
    pub rmse: f64,
    pub ssim: f64,
    /// Number of image pairs.
    pub n: usize,
}

/// Mean squared error over all pixels and channels of one pair.
pub fn mse<S: Space>(a: &Rgb<S>, b: &Rgb<S>) -> Result<f64> {
    check(a, b)?;
    let sum: f64 = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&x, &y)| {
            let d = x as f64 - y as f64;
            d * d
        })
        .sum();
    Ok(sum / a.data().len().max(1) as f64)
}

/// Mean squared error over the channels of the pixels of one pair that `mask` holds (pixel
/// (x, y) at `y·width + x`); `None` when it holds none. A mask of another size than the images
/// is an input error.
pub fn masked_mse<S: Space>(a: &Rgb<S>, b: &Rgb<S>, mask: &[bool]) -> Result<Option<f64>> {
    check(a, b)?;
    let pixels = a.width() * a.height();
    if mask.len() != pixels {
        return Err(Error::Shape(format!(
            "a mask of {} pixels for {}x{} images",
            mask.len(),
            a.width(),
            a.height()
        )));
    }
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        for c in 0..3 {
            let d = a.data()[3 * i + c] as f64 - b.data()[3 * i + c] as f64;
            sum += d * d;
        }
        n += 3;
    }
    Ok((n > 0).then(|| sum / n as f64))
}

/// PSNR in dB for a mean squared error with peak value 1.
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        10.0 * (1.0 / mse).log10()
    }
}

/// RMSE of the RGB error vector: √(3·MSE).
pub fn rmse_from_mse(mse: f64) -> f64 {
    (3.0 * mse).sqrt()
}

/// Mean SSIM of one pair, averaged over the three channels.
pub fn ssim<S: Space>(a: &Rgb<S>, b: &Rgb<S>) -> Result<f64> {
    check(a, b)?;
    let kernel = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS);
    let mut total = 0.0;
    for c in 0..3 {
        total += ssim_plane(&a.channel(c), &b.channel(c), &kernel);
    }
    Ok(total / 3.0)
}

/// Mean of the SSIM map of two planes.
fn ssim_plane<S: Space>(x: &Plane<S>, y: &Plane<S>, kernel: &[f64]) -> f64 {
    let xx = Plane::<S>::from_vec(
        x.width(),
        x.height(),
        x.data().iter().map(|v| v * v).collect(),
    );
    let yy = Plane::<S>::from_vec(
        y.width(),
        y.height(),
        y.data().iter().map(|v| v * v).collect(),
    );
    let xy = Plane::<S>::from_vec(
        x.width(),
        x.height(),
        x.data().iter().zip(y.data()).map(|(a, b)| a * b).collect(),
    );
    let (Ok(xx), Ok(yy), Ok(xy)) = (xx, yy, xy) else {
        return f64::NAN; // unreachable: sizes come from the inputs
    };
    let mx = separable_replicate(x, kernel);
    let my = separable_replicate(y, kernel);
    let sxx = separable_replicate(&xx, kernel);
    let syy = separable_replicate(&yy, kernel);
    let sxy = separable_replicate(&xy, kernel);
    let n = x.data().len();
    let mut sum = 0.0;
    for i in 0..n {
        let (mx, my) = (mx.data()[i] as f64, my.data()[i] as f64);
        let vx = sxx.data()[i] as f64 - mx * mx;
        let vy = syy.data()[i] as f64 - my * my;
        let cxy = sxy.data()[i] as f64 - mx * my;
        sum += ((2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2))
            / ((mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2));
    }
    sum / n.max(1) as f64
}

/// Scores a set of pairs: pooled MSE for PSNR and RMSE, mean SSIM over images.
pub fn score_pairs<'a, S: Space + 'a>(
    pairs: impl IntoIterator<Item = (&'a Rgb<S>, &'a Rgb<S>)>,
) -> Result<Scores> {
    let mut acc = Accumulator::default();
    for (a, b) in pairs {
        acc.add(a, b)?;
    }
    acc.finish()
}

/// Accumulates scores pair by pair, so a large test set need not be held in memory.
#[derive(Clone, Debug, Default)]
pub struct Accumulator {
    sq_err: f64,
    values: usize,
    ssim_sum: f64,
    n: usize,
}

impl Accumulator {
    pub fn add<S: Space>(&mut self, a: &Rgb<S>, b: &Rgb<S>) -> Result<()> {
        let m = mse(a, b)?;
        self.sq_err += m * a.data().len() as f64;
        self.values += a.data().len();
        self.ssim_sum += ssim(a, b)?;
        self.n += 1;
        Ok(())
    }

    pub fn finish(&self) -> Result<Scores> {
        if self.n == 0 {
            return Err(Error::Input("no image pairs to score".into()));
        }
        let mse = self.sq_err / self.values.max(1) as f64;
        Ok(Scores {
            psnr: psnr_from_mse(mse),
            rmse: rmse_from_mse(mse),
            ssim: self.ssim_sum / self.n as f64,
            n: self.n,
        })
    }
}

fn check<S: Space>(a: &Rgb<S>, b: &Rgb<S>) -> Result<()> {
    if a.size() != b.size() {
        return Err(Error::Shape(format!(
            "cannot compare {}x{} with {}x{} {} images",
            a.width(),
            a.height(),
            b.width(),
            b.height(),
            S::NAME
        )));
    }
    Ok(())
}

/// How sharp a camera image is, for focusing: the variance of the 4-neighbour Laplacian of its
/// luma (Rec. 709 weights on the encoded values), over the interior pixels. Larger is sharper;
/// the figure depends on the scene, so it is compared while the focus ring turns, not across
/// rigs. 0 for an image smaller than 3×3.
pub fn sharpness<S: Space>(img: &Rgb<S>) -> f64 {
    let (w, h) = (img.width(), img.height());
    if w < 3 || h < 3 {
        return 0.0;
    }
    let luma: Vec<f64> = img
        .data()
        .chunks_exact(3)
        .map(|p| 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
        .collect();
    let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let c = luma[y * w + x];
            let l = luma[y * w + x - 1]
                + luma[y * w + x + 1]
                + luma[(y - 1) * w + x]
                + luma[(y + 1) * w + x]
                - 4.0 * c;
            sum += l;
            sum2 += l * l;
            n += 1.0;
        }
    }
    let mean = sum / n;
    (sum2 / n - mean * mean).max(0.0)
}

/// The shares of pixels (0 to 1) with a channel at the top of the range (≥ 254.5/255: clipped
/// highlights, the exposure is too long) and with every channel at the bottom (≤ 0.5/255:
/// crushed shadows), in encoded values.
pub fn clipping<S: Space>(img: &Rgb<S>) -> (f64, f64) {
    let n = (img.width() * img.height()).max(1) as f64;
    let (mut high, mut low) = (0usize, 0usize);
    for p in img.data().chunks_exact(3) {
        if p.iter().any(|&v| v >= 254.5 / 255.0) {
            high += 1;
        }
        if p.iter().all(|&v| v <= 0.5 / 255.0) {
            low += 1;
        }
    }
    (high as f64 / n, low as f64 / n)
}

/// How visible a seam is where projected pictures meet: the residual (seen − desired) in a band
/// along the edges against the same away from them, inside one region. A seam shows as more
/// error in the band, or as a step in the residual there (its gradient energy).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SeamFigure {
    /// Mean squared residual in the band and away from it (encoded values², per channel).
    pub band_mse: f64,
    pub away_mse: f64,
    /// Mean squared step of the residual between neighbouring pixels (right and down, both
    /// in the region), in the band and away from it (encoded values², per channel).
    pub band_gradient: f64,
    pub away_gradient: f64,
}

impl SeamFigure {
    /// The mean of each part over several figures (several images); `None` for none.
    pub fn mean(figures: &[SeamFigure]) -> Option<SeamFigure> {
        if figures.is_empty() {
            return None;
        }
        let k = figures.len() as f64;
        let mean = |f: fn(&SeamFigure) -> f64| figures.iter().map(f).sum::<f64>() / k;
        Some(SeamFigure {
            band_mse: mean(|s| s.band_mse),
            away_mse: mean(|s| s.away_mse),
            band_gradient: mean(|s| s.band_gradient),
            away_gradient: mean(|s| s.away_gradient),
        })
    }

    /// The larger of the band's error and its gradient energy over the same away from it: about
    /// 1 where nothing marks the edges; a floor of 1e-6 (encoded values²) away keeps it finite.
    pub fn ratio(&self) -> f64 {
        let r = |band: f64, away: f64| band / away.max(1e-6);
        r(self.band_mse, self.away_mse).max(r(self.band_gradient, self.away_gradient))
    }
}

/// The [`SeamFigure`] of `seen` against `desired` (same size, encoded values), with the band
/// and the pixels away from it given as masks of the same size (pixel (x, y) at `y·width + x`).
/// An empty band or an empty away region is an input error.
pub fn seam_figure<S: Space>(
    seen: &Rgb<S>,
    desired: &Rgb<S>,
    band: &[bool],
    away: &[bool],
) -> Result<SeamFigure> {
    check(seen, desired)?;
    let (w, h) = (seen.width(), seen.height());
    if band.len() != w * h || away.len() != w * h {
        return Err(Error::Shape(format!(
            "seam masks of {} and {} pixels for {w}x{h} images",
            band.len(),
            away.len()
        )));
    }
    let r: Vec<f64> = seen
        .data()
        .iter()
        .zip(desired.data())
        .map(|(a, b)| f64::from(a - b))
        .collect();
    // Per region: squared residual sum and count, squared step sum and count.
    let mut sums = [[0f64; 4]; 2];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for (k, region) in [band, away].iter().enumerate() {
                if !region[i] {
                    continue;
                }
                let acc = &mut sums[k];
                for c in 0..3 {
                    acc[0] += r[i * 3 + c] * r[i * 3 + c];
                }
                acc[1] += 3.0;
                for j in [(x + 1 < w).then_some(i + 1), (y + 1 < h).then_some(i + w)]
                    .into_iter()
                    .flatten()
                {
                    if region[j] {
                        for c in 0..3 {
                            let d = r[j * 3 + c] - r[i * 3 + c];
                            acc[2] += d * d;
                        }
                        acc[3] += 3.0;
                    }
                }
            }
        }
    }
    for (k, what) in ["band", "region away from it"].iter().enumerate() {
        if sums[k][1] == 0.0 || sums[k][3] == 0.0 {
            return Err(Error::Input(format!(
                "the seam's {what} holds no pair of neighbouring pixels"
            )));
        }
    }
    let mean = |k: usize, v: usize, n: usize| sums[k][v] / sums[k][n];
    Ok(SeamFigure {
        band_mse: mean(0, 0, 1),
        away_mse: mean(1, 0, 1),
        band_gradient: mean(0, 2, 3),
        away_gradient: mean(1, 2, 3),
    })
}
