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
///
/// Each output value is summed from zero in tap order, as the plain double loop would
/// (`tests::reference`), so the result is that loop's to the bit; the work is arranged for
/// speed: taps clamped only within the kernel's radius of an edge, the column pass a row of
/// sums at a time, rows in parallel.
pub fn separable_replicate<S: Space>(src: &Plane<S>, kernel: &[f64]) -> Plane<S> {
    use rayon::prelude::*;
    let ImageSize {
        width: w,
        height: h,
    } = src.size();
    if w == 0 || h == 0 || kernel.is_empty() {
        return src.clone();
    }
    let r = kernel.len() / 2;
    let clampi = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let data = src.data();
    // Rows: clamped taps near the ends, direct ones between.
    let mut tmp = vec![0f64; w * h];
    tmp.par_chunks_mut(w)
        .zip(data.par_chunks(w))
        .for_each(|(out, row)| {
            let clamped = |x: usize| {
                let mut acc = 0f64;
                for (k, &kv) in kernel.iter().enumerate() {
                    acc += kv * row[clampi(x as isize + k as isize - r as isize, w)] as f64;
                }
                acc
            };
            let inner = r.min(w)..w.saturating_sub(r).max(r.min(w));
            for x in (0..inner.start).chain(inner.end..w) {
                out[x] = clamped(x);
            }
            for x in inner {
                let taps = &row[x - r..x - r + kernel.len()];
                let mut acc = 0f64;
                for (&kv, &v) in kernel.iter().zip(taps) {
                    acc += kv * v as f64;
                }
                out[x] = acc;
            }
        });
    // Columns: each output row summed tap by tap over whole rows of `tmp`.
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0f64; w],
        |acc, (y, out)| {
            acc.fill(0.0);
            for (k, &kv) in kernel.iter().enumerate() {
                let j = clampi(y as isize + k as isize - r as isize, h);
                for (a, &t) in acc.iter_mut().zip(&tmp[j * w..(j + 1) * w]) {
                    *a += kv * t;
                }
            }
            for (o, &a) in out.iter_mut().zip(acc.iter()) {
                *o = a as f32;
            }
        },
    );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Camera;

    /// The plain double loop `separable_replicate` must equal to the bit: every tap clamped,
    /// each value summed from zero in tap order, rows then columns.
    fn reference(src: &Plane<Camera>, kernel: &[f64]) -> Vec<f32> {
        let ImageSize {
            width: w,
            height: h,
        } = src.size();
        let r = (kernel.len() / 2) as isize;
        let clampi = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let d = src.data();
        let mut tmp = vec![0f64; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0f64;
                for (k, &kv) in kernel.iter().enumerate() {
                    acc += kv * d[y * w + clampi(x as isize + k as isize - r, w)] as f64;
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
        out
    }

    /// Planes wider and narrower than the kernel, a kernel of one tap and an uneven one.
    #[test]
    fn the_blur_is_the_plain_loop_to_the_bit() {
        let mut state = 12345u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32
        };
        let kernels = [
            gaussian_kernel(2.0, 6),
            gaussian_kernel(0.7, 1),
            vec![1.0],
            vec![0.1, 0.5, 0.25, 0.1, 0.05],
        ];
        for (w, h) in [(37, 23), (5, 9), (1, 1), (13, 2), (64, 48)] {
            let plane = Plane::<Camera>::from_fn(w, h, |_, _| next());
            for kernel in &kernels {
                let fast = separable_replicate(&plane, kernel);
                let want = reference(&plane, kernel);
                let same = fast
                    .data()
                    .iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(
                    same,
                    "{w}x{h}, {} taps: differs from the plain loop",
                    kernel.len()
                );
            }
        }
    }
}
