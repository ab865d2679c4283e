//! Resizing. Both methods keep the pixel space and change only the resolution.
//!
//! - Bilinear uses half-pixel centres (the convention of OpenCV's INTER_LINEAR and PyTorch's
//!   `interpolate(..., align_corners=False)` without antialiasing): output pixel `x` samples source
//!   coordinate `(x + 0.5) · src_w / dst_w − 0.5`, clamped to the first and last pixel centres.
//! - Area is an exact box filter: each output pixel is the mean of the source area it covers,
//!   fractional pixels weighted by their covered fraction. Use it to shrink; when enlarging it
//!   reduces to nearest-neighbour replication.

use crate::raster::{ImageSize, Plane, Rgb, Space};

/// Per-axis bilinear taps: (lower index, upper index, weight of the upper one).
pub(crate) fn bilinear_taps(src: usize, dst: usize) -> Vec<(usize, usize, f32)> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|i| {
            let s = ((i as f64 + 0.5) * scale - 0.5).clamp(0.0, (src - 1) as f64);
            let i0 = s.floor() as usize;
            let i1 = (i0 + 1).min(src - 1);
            (i0, i1, (s - i0 as f64) as f32)
        })
        .collect()
}

/// The bilinear resize of one axis from `src` to `dst` samples as a `dst`×`src` matrix
/// (row-major): row `i` holds the weights of output sample `i`, the taps of [`resize_bilinear`].
/// A differentiable framework resizes with it by matrix products.
pub fn bilinear_matrix(src: usize, dst: usize) -> Vec<f32> {
    let mut m = vec![0f32; dst * src];
    if src == 0 {
        return m;
    }
    for (i, (i0, i1, w)) in bilinear_taps(src, dst).into_iter().enumerate() {
        m[i * src + i0] += 1.0 - w;
        m[i * src + i1] += w;
    }
    m
}

/// Per-axis box taps: for each output pixel, the (source index, weight) pairs, weights summing to 1.
fn area_taps(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|i| {
            let (a, b) = (i as f64 * scale, (i + 1) as f64 * scale);
            let mut taps = Vec::new();
            let mut j = a.floor() as usize;
            while (j as f64) < b && j < src {
                let cover = (b.min(j as f64 + 1.0) - a.max(j as f64)).max(0.0);
                if cover > 1e-12 {
                    taps.push((j, (cover / scale) as f32));
                }
                j += 1;
            }
            taps
        })
        .collect()
}

/// Resizes interleaved data with `ch` channels through separable taps given as sparse rows.
fn resample(
    src: &[f32],
    ImageSize {
        width: sw,
        height: sh,
    }: ImageSize,
    ch: usize,
    xt: &[Vec<(usize, f32)>],
    yt: &[Vec<(usize, f32)>],
) -> Vec<f32> {
    let dw = xt.len();
    // Horizontal pass: sh rows of dw pixels.
    let mut tmp = vec![0f32; sh * dw * ch];
    for y in 0..sh {
        for (x, taps) in xt.iter().enumerate() {
            for c in 0..ch {
                let mut acc = 0f32;
                for &(j, w) in taps {
                    acc += w * src[(y * sw + j) * ch + c];
                }
                tmp[(y * dw + x) * ch + c] = acc;
            }
        }
    }
    let mut out = vec![0f32; yt.len() * dw * ch];
    for (y, taps) in yt.iter().enumerate() {
        for x in 0..dw {
            for c in 0..ch {
                let mut acc = 0f32;
                for &(j, w) in taps {
                    acc += w * tmp[(j * dw + x) * ch + c];
                }
                out[(y * dw + x) * ch + c] = acc;
            }
        }
    }
    out
}

fn bilinear_sparse(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    bilinear_taps(src, dst)
        .into_iter()
        .map(|(i0, i1, w)| vec![(i0, 1.0 - w), (i1, w)])
        .collect()
}

/// Which resampling filter to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    Bilinear,
    Area,
}

fn taps(filter: Filter, src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    match filter {
        Filter::Bilinear => bilinear_sparse(src, dst),
        Filter::Area => area_taps(src, dst),
    }
}

/// Resizes an RGB image to `width`×`height`. A zero-sized source or target gives a black image
/// of the target size.
pub fn resize<S: Space>(img: &Rgb<S>, width: usize, height: usize, filter: Filter) -> Rgb<S> {
    resize_with(img, width, height, |src, dst| taps(filter, src, dst))
}

/// Resizes through separable per-axis taps `axis_taps(source length, target length)`.
fn resize_with<S: Space>(
    img: &Rgb<S>,
    width: usize,
    height: usize,
    axis_taps: impl Fn(usize, usize) -> Vec<Vec<(usize, f32)>>,
) -> Rgb<S> {
    if img.size() == ImageSize::new(width, height) {
        return img.clone();
    }
    if img.width() == 0 || img.height() == 0 || width == 0 || height == 0 {
        return Rgb::new(width, height);
    }
    let data = resample(
        img.data(),
        img.size(),
        3,
        &axis_taps(img.width(), width),
        &axis_taps(img.height(), height),
    );
    Rgb::from_vec(width, height, data).expect("resample yields width*height*3 values")
}

/// The `width`×`height` image whose bilinear enlargement to `img`'s size is closest to `img` in
/// least squares, per axis: the smaller image that, stretched the way the canvas stretches, shows
/// what `img` shows (as nearly as it can). Used to score an image made on a finer lattice against
/// network-size images; a plain bilinear or area shrink blurs it on top of the stretch it already
/// carries. When the target is not smaller along an axis, that axis is resized bilinearly.
pub fn unstretch<S: Space>(img: &Rgb<S>, width: usize, height: usize) -> Rgb<S> {
    resize_with(img, width, height, unstretch_taps)
}

/// Per-axis taps of the least-squares inverse of the bilinear enlargement `dst → src`
/// (`(UᵀU)⁻¹Uᵀ` with `U` the `src×dst` interpolation matrix); bilinear taps when `dst ≥ src`.
fn unstretch_taps(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    if dst >= src {
        return bilinear_sparse(src, dst);
    }
    let mut u = nalgebra::DMatrix::<f64>::zeros(src, dst);
    for (i, row) in bilinear_sparse(dst, src).iter().enumerate() {
        for &(j, w) in row {
            u[(i, j)] += w as f64;
        }
    }
    let normal = u.transpose() * &u;
    // Bilinear enlargement has full column rank, so the normal matrix is positive definite; a
    // tiny ridge keeps the factorisation safe at any size.
    let normal = normal + nalgebra::DMatrix::<f64>::identity(dst, dst) * 1e-9;
    let p = match normal.cholesky() {
        Some(ch) => ch.solve(&u.transpose()),
        None => return area_taps(src, dst),
    };
    (0..dst)
        .map(|i| {
            let row = p.row(i);
            let peak = row.iter().fold(0f64, |m, v| m.max(v.abs()));
            row.iter()
                .enumerate()
                .filter(|(_, v)| v.abs() > 1e-6 * peak)
                .map(|(j, &v)| (j, v as f32))
                .collect()
        })
        .collect()
}

/// Resizes a single-channel plane to `width`×`height`.
pub fn resize_plane<S: Space>(
    img: &Plane<S>,
    width: usize,
    height: usize,
    filter: Filter,
) -> Plane<S> {
    if img.size() == ImageSize::new(width, height) {
        return img.clone();
    }
    if img.width() == 0 || img.height() == 0 || width == 0 || height == 0 {
        return Plane::new(width, height);
    }
    let data = resample(
        img.data(),
        img.size(),
        1,
        &taps(filter, img.width(), width),
        &taps(filter, img.height(), height),
    );
    Plane::from_vec(width, height, data).expect("resample yields width*height values")
}

/// Bilinear resize (half-pixel centres).
pub fn resize_bilinear<S: Space>(img: &Rgb<S>, width: usize, height: usize) -> Rgb<S> {
    resize(img, width, height, Filter::Bilinear)
}

/// Area (box-filter) resize.
pub fn resize_area<S: Space>(img: &Rgb<S>, width: usize, height: usize) -> Rgb<S> {
    resize(img, width, height, Filter::Area)
}
