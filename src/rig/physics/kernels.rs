//! Small numeric kernels of the simulator: 3×3 colour matrices, the separable Gaussian blur,
//! the deterministic parallel loops, the 8-bit projector level, and the hashing behind the
//! camera noise.

use rayon::prelude::*;

#[inline]
pub(crate) fn mat3(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

pub(crate) fn transpose(m: &[[f32; 3]; 3]) -> [[f32; 3]; 3] {
    [
        [m[0][0], m[1][0], m[2][0]],
        [m[0][1], m[1][1], m[2][1]],
        [m[0][2], m[1][2], m[2][2]],
    ]
}

/// Normalised Gaussian taps, radius ⌈3σ⌉.
pub(super) fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let taps: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|t| (t / sum) as f32).collect()
}

/// Separable blur of an interleaved RGB image with an odd symmetric kernel and zero padding.
/// Being a symmetric operator with zero padding, it is its own adjoint.
pub(crate) fn blur_rgb(src: &[f32], w: usize, h: usize, kernel: &[f32]) -> Vec<f32> {
    let r = kernel.len() / 2;
    let row = w * 3;
    // Horizontal: out[i] += k·src[i + 3·(t − r)] over the valid range of each row.
    let mut tmp = vec![0f32; src.len()];
    tmp.par_chunks_mut(row)
        .zip(src.par_chunks(row))
        .for_each(|(o, s)| {
            for (t, &k) in kernel.iter().enumerate() {
                let off = t as isize - r as isize;
                let shift = off.unsigned_abs() * 3;
                if shift >= row {
                    continue;
                }
                if off >= 0 {
                    for (a, b) in o[..row - shift].iter_mut().zip(&s[shift..]) {
                        *a += k * b;
                    }
                } else {
                    for (a, b) in o[shift..].iter_mut().zip(&s[..row - shift]) {
                        *a += k * b;
                    }
                }
            }
        });
    // Vertical: output row y += k·tmp row (y + t − r).
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(row).enumerate().for_each(|(y, o)| {
        for (t, &k) in kernel.iter().enumerate() {
            let yy = y as isize + t as isize - r as isize;
            if yy < 0 || yy >= h as isize {
                continue;
            }
            let s = &tmp[yy as usize * row..(yy as usize + 1) * row];
            for (a, b) in o.iter_mut().zip(s) {
                *a += k * b;
            }
        }
    });
    out
}

/// Pixels per parallel work item.
pub(super) const CHUNK: usize = 4096;

/// `f(i)` for every pixel i < n as interleaved RGB, computed in parallel (the result does not
/// depend on the number of threads).
pub(super) fn par_pixels(n: usize, f: impl Fn(usize) -> [f32; 3] + Sync) -> Vec<f32> {
    let mut out = vec![0f32; n * 3];
    out.par_chunks_mut(CHUNK * 3)
        .enumerate()
        .for_each(|(c, chunk)| {
            for (j, px) in chunk.chunks_exact_mut(3).enumerate() {
                px.copy_from_slice(&f(c * CHUNK + j));
            }
        });
    out
}

/// The 8-bit level a projector shows for input value `v` (round to nearest, clamped; NaN → 0),
/// as [`crate::pngio::to_u8`] but without a call to `round`.
#[inline]
pub(super) fn level(v: f32) -> usize {
    // Through i32: the saturating float-to-i32 conversion is much cheaper than to usize.
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as i32 as usize
}

/// Runs `f` for every row in 0..h on the available cores and concatenates the results in row
/// order (the output does not depend on the number of threads).
pub(crate) fn par_rows<T: Send>(h: usize, f: impl Fn(usize) -> Vec<T> + Sync) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .clamp(1, 16);
    if threads == 1 || h < 8 {
        return (0..h).flat_map(&f).collect();
    }
    let chunk = h.div_ceil(threads);
    let f = &f;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..h)
            .step_by(chunk)
            .map(|start| {
                s.spawn(move || {
                    (start..(start + chunk).min(h))
                        .flat_map(f)
                        .collect::<Vec<T>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|hd| hd.join().expect("a simulator worker thread panicked"))
            .collect()
    })
}

/// SplitMix64 finaliser: a bijective 64-bit hash (value-stable, platform-independent).
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// An approximately standard normal value from 64 random bits: the sum of four 16-bit uniforms
/// (Irwin–Hall), centred and scaled to unit variance. Tails end at ±3.46σ.
#[inline]
pub(super) fn approx_normal(bits: u64) -> f32 {
    let u = |k: u32| ((bits >> (16 * k)) & 0xffff) as f32 + 0.5;
    let sum = (u(0) + u(1) + u(2) + u(3)) / 65536.0;
    (sum - 2.0) * 3f32.sqrt()
}
