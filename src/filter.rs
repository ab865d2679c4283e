//! Separable linear filters on single-channel planes with replicate (clamp-to-edge) padding.
//!
//! Kept rather than imageproc's `gaussian_blur_f32`: the metrics (SSIM) accumulate in f64 so
//! that their values do not depend on summation order, and the kernel's radius (3σ) is the
//! one the reference figures were measured with.

use crate::raster::{ImageSize, Plane, Space};

/// Normalised 1-D Gaussian kernel of `2 * radius + 1` taps with standard deviation `sigma` (pixels).
pub fn gaussian_kernel(sigma: f64, radius: usize) -> Vec<f64> {
    let taps: Vec<f64> = (0..=2 * radius)
        .map(|i| {
            let d = i as f64 - radius as f64;
            (-(d * d) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|t| t / sum).collect()
}

/// Correlates `src` with `kernel` along rows then columns (the same odd-length kernel both ways),
/// reading edge pixels for taps that fall outside (replicate padding). Output has the input size.
/// Accumulates in f64 so that metric values do not depend on summation order at f32 precision.
pub fn separable_replicate<S: Space>(src: &Plane<S>, kernel: &[f64]) -> Plane<S> {
    let ImageSize {
        width: w,
        height: h,
    } = src.size();
    if w == 0 || h == 0 || kernel.is_empty() {
        return src.clone();
    }
    let r = (kernel.len() / 2) as isize;
    let clampi = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let data = src.data();
    let mut tmp = vec![0f64; w * h];
    for y in 0..h {
        let row = &data[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = 0f64;
            for (k, &kv) in kernel.iter().enumerate() {
                acc += kv * row[clampi(x as isize + k as isize - r, w)] as f64;
            }
            tmp[y * w + x] = acc;
        }
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0f64;
            for (k, &kv) in kernel.iter().enumerate() {
                acc += kv * tmp[clampi(y as isize + k as isize - r, h) * w + x];
            }
            out.push(acc as f32);
        }
    }
    Plane::from_vec(w, h, out).expect("output has the input size")
}

/// Gaussian blur with replicate padding; the radius is 3σ rounded up.
pub fn gaussian_blur<S: Space>(src: &Plane<S>, sigma: f64) -> Plane<S> {
    if sigma <= 0.0 {
        return src.clone();
    }
    let radius = (3.0 * sigma).ceil() as usize;
    separable_replicate(src, &gaussian_kernel(sigma, radius))
}
