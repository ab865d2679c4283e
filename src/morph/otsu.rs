//! Otsu's threshold on f32 values (the histogram spans the values' own range).

use crate::raster::{Plane, Space};

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
