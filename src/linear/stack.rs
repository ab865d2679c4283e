//! The training pairs as the `linear` fit reads them, sampled where the fit needs them instead
//! of warped or resized into whole images first (at a 1920×1080 lattice and 48 pairs, whole
//! warped captures and resized projector images took 2.4 GB):
//! - [`Stack`]: images interleaved pixel-major, so that the values of every pair at one
//!   position lie together in memory. The geometry fit samples its 24 captures from one (built
//!   a few at a time, [`Stack::build`]); the colour solve resamples the projector images (network
//!   size) from one.
//! - [`Frames`]: the captures read where they lie, for the colour solve, whose lattice may be
//!   coarser than a large camera's frame (a stack of 48 1920×1080 captures is 1.2 GB).
//!
//! Each sampler repeats the arithmetic of the whole-image operation it stands in for, in the
//! same order, so the fit's results are those of warping and resizing first, to the bit:
//! [`Stack::sample`] and [`Frames::sample`] that of [`crate::sample::grid_sample`] (camera
//! pixels at normalised camera coordinates, align-corners, zero outside), [`Stack::resampled`]
//! that of [`crate::resize::resize_bilinear`] (network pixels onto a lattice, half-pixel
//! centres).

use rayon::prelude::*;

use crate::raster::{Camera, ImageSize, ReadRgb, Rgb, Space};
use crate::resize::bilinear_taps;
use crate::sample::{for_each_tap, norm_to_pixel};

/// Images of one size (RGB) interleaved pixel-major: `data[(p * images + i) * 3 + c]` for
/// pixel `p = y · width + x` of image `i`, each value held as a `T` ([`Texel`]).
pub(super) struct Stack<T = f32> {
    width: usize,
    height: usize,
    images: usize,
    data: Vec<T>,
}

/// How a [`Stack`] holds a value: `f32` as it is; `u16` as 16-bit fixed point on \[0,1\],
/// within half a step (7.7e-6) of the value, a 500th of an 8-bit camera's step, in half the
/// memory. The geometry fit's stacks of 24 captures hold them so: at 1920×1080 that is 298 MB
/// against 597 MB each.
pub(super) trait Texel: Copy + Default + Send + Sync {
    fn store(v: f32) -> Self;
    fn load(self) -> f32;
}

impl Texel for f32 {
    #[inline]
    fn store(v: f32) -> Self {
        v
    }
    #[inline]
    fn load(self) -> f32 {
        self
    }
}

impl Texel for u16 {
    /// Clamped to \[0,1\] (NaN reads as 0), rounded to the nearest step, halves up: what
    /// `round()` gives, without the call into libm that x86-64's baseline makes of it (the
    /// stacks' building spent 2 % of a fit there). `x − t` is exact (t ≤ x < t + 1 < 2¹⁶).
    #[inline]
    fn store(v: f32) -> Self {
        let x = v.clamp(0.0, 1.0) * 65535.0;
        let t = x as u16;
        if x - t as f32 >= 0.5 { t + 1 } else { t }
    }
    #[inline]
    fn load(self) -> f32 {
        self as f32 * (1.0 / 65535.0)
    }
}

/// The bilinear neighbours of one position as [`crate::sample::grid_sample`] takes them: the
/// in-bounds neighbours with a non-zero weight, in its order (pixel indices, weights).
pub(super) struct Taps {
    count: usize,
    offset: [usize; 4],
    weight: [f32; 4],
}

/// Where a normalised position falls, for [`Stack::sample_with_gradient`]: the offsets of its
/// four bilinear neighbours for image 0 (`None` outside: zero padding) and the fractional
/// position between them.
pub(super) struct Located {
    corners: [Option<usize>; 4],
    fx: f32,
    fy: f32,
}

/// The bilinear resize of a [`Stack`] onto a lattice, per axis: (lower index, upper index,
/// weight of the upper one) of each lattice column and row ([`crate::resize`]'s taps).
pub(super) struct Resize {
    columns: Vec<(usize, usize, f32)>,
    rows: Vec<(usize, usize, f32)>,
    width: usize,
}

impl Taps {
    /// The neighbours of normalised (gx, gy) in a `width`×`height` image, as
    /// [`crate::sample::for_each_tap`] gives them (pixel indices `y · width + x`).
    #[inline]
    fn at(gx: f32, gy: f32, width: usize, height: usize) -> Self {
        let mut taps = Taps {
            count: 0,
            offset: [0; 4],
            weight: [0.0; 4],
        };
        for_each_tap(gx, gy, width, height, |p, w| {
            taps.offset[taps.count] = p;
            taps.weight[taps.count] = w;
            taps.count += 1;
        });
        taps
    }

    /// The weighted sum of `value(offset)` over the taps, in [`crate::sample::grid_sample`]'s
    /// order and arithmetic.
    #[inline]
    fn blend(&self, value: impl Fn(usize) -> [f32; 3]) -> [f32; 3] {
        let mut px = [0f32; 3];
        for k in 0..self.count {
            let v = value(self.offset[k]);
            let w = self.weight[k];
            px[0] += w * v[0];
            px[1] += w * v[1];
            px[2] += w * v[2];
        }
        px
    }
}

/// Captures sampled with [`crate::sample::grid_sample`]'s arithmetic, wherever they are held:
/// a [`Stack`] or [`Frames`].
pub(super) trait Captures: Sync {
    fn images(&self) -> usize;
    fn taps(&self, gx: f32, gy: f32) -> Taps;
    fn sample(&self, taps: &Taps, i: usize) -> [f32; 3];
}

impl<T: Texel> Captures for Stack<T> {
    fn images(&self) -> usize {
        Stack::images(self)
    }
    fn taps(&self, gx: f32, gy: f32) -> Taps {
        Stack::taps(self, gx, gy)
    }
    fn sample(&self, taps: &Taps, i: usize) -> [f32; 3] {
        Stack::sample(self, taps, i)
    }
}

impl<C: ReadRgb<Camera>> Captures for Frames<'_, C> {
    fn images(&self) -> usize {
        Frames::images(self)
    }
    fn taps(&self, gx: f32, gy: f32) -> Taps {
        Frames::taps(self, gx, gy)
    }
    fn sample(&self, taps: &Taps, i: usize) -> [f32; 3] {
        Frames::sample(self, taps, i)
    }
}

/// Camera captures read where they lie (no copy): for the colour solve, whose lattice may be
/// coarser than the camera's frame, so that a stack of whole captures would cost more memory
/// than the lattice.
pub(super) struct Frames<'a, C> {
    images: &'a [C],
    width: usize,
    height: usize,
}

impl<'a, C: ReadRgb<Camera>> Frames<'a, C> {
    /// `images` must share one size (the fit checks its pairs first).
    pub(super) fn new(images: &'a [C]) -> Self {
        let size = images
            .first()
            .map_or(ImageSize::new(0, 0), ReadRgb::dimensions);
        Self {
            images,
            width: size.width,
            height: size.height,
        }
    }

    pub(super) fn images(&self) -> usize {
        self.images.len()
    }

    /// The neighbours [`Frames::sample`] reads at normalised (gx, gy).
    #[inline]
    pub(super) fn taps(&self, gx: f32, gy: f32) -> Taps {
        Taps::at(gx, gy, self.width, self.height)
    }

    /// Capture `i` sampled at `taps`: [`crate::sample::grid_sample`]'s value there.
    #[inline]
    pub(super) fn sample(&self, taps: &Taps, i: usize) -> [f32; 3] {
        let image = &self.images[i];
        taps.blend(|p| image.pixel(p))
    }
}

impl<T: Texel> Stack<T> {
    /// Interleaves `images`, which must share one size (the fit checks its pairs first).
    pub(super) fn new<S: Space, I: ReadRgb<S>>(images: &[I]) -> Self {
        let size = images
            .first()
            .map_or(ImageSize::new(0, 0), ReadRgb::dimensions);
        let mut stack = Self::empty(size, images.len());
        for (i, img) in images.iter().enumerate() {
            stack.put(i, img);
        }
        stack
    }

    /// Interleaves `count` images of `size` that `image(i)` makes, a few at a time (as many as
    /// there are threads), so that they are never all held beside the stack.
    pub(super) fn build<S: Space>(
        count: usize,
        size: ImageSize,
        image: impl Fn(usize) -> Rgb<S> + Sync,
    ) -> Self {
        let mut stack = Self::empty(size, count);
        let batch = rayon::current_num_threads().max(1);
        for start in (0..count).step_by(batch) {
            let made: Vec<Rgb<S>> = (start..(start + batch).min(count))
                .into_par_iter()
                .map(&image)
                .collect();
            for (k, img) in made.iter().enumerate() {
                stack.put(start + k, img);
            }
        }
        stack
    }

    fn empty(size: ImageSize, n: usize) -> Self {
        Self {
            width: size.width,
            height: size.height,
            images: n,
            data: vec![T::default(); size.width * size.height * n * 3],
        }
    }

    /// Copies `img` in as image `i`.
    fn put<S: Space, I: ReadRgb<S>>(&mut self, i: usize, img: &I) {
        let n = self.images;
        if n == 0 {
            return;
        }
        self.data
            .par_chunks_mut(n * 3)
            .enumerate()
            .for_each(|(p, dst)| {
                let v = img.pixel(p);
                for c in 0..3 {
                    dst[i * 3 + c] = T::store(v[c]);
                }
            });
    }

    pub(super) fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }

    pub(super) fn images(&self) -> usize {
        self.images
    }

    /// Image `i` at pixel index `p`.
    #[inline]
    fn at(&self, p: usize, i: usize) -> [f32; 3] {
        let j = (p * self.images + i) * 3;
        [
            self.data[j].load(),
            self.data[j + 1].load(),
            self.data[j + 2].load(),
        ]
    }

    /// The neighbours [`Stack::sample`] reads at normalised (gx, gy).
    #[inline]
    pub(super) fn taps(&self, gx: f32, gy: f32) -> Taps {
        Taps::at(gx, gy, self.width, self.height)
    }

    /// Image `i` sampled at `taps`: [`crate::sample::grid_sample`]'s value there.
    #[inline]
    pub(super) fn sample(&self, taps: &Taps, i: usize) -> [f32; 3] {
        taps.blend(|q| self.at(q, i))
    }

    /// How [`Stack::resampled`] maps this stack onto a `size` lattice.
    pub(super) fn resize_to(&self, size: ImageSize) -> Resize {
        Resize {
            columns: bilinear_taps(self.width, size.width),
            rows: bilinear_taps(self.height, size.height),
            width: size.width,
        }
    }

    /// Image `i` at lattice pixel index `p` of `resize`: the value of
    /// [`crate::resize::resize_bilinear`] there (the image itself when the sizes agree, as
    /// there).
    #[inline]
    pub(super) fn resampled(&self, resize: &Resize, p: usize, i: usize) -> [f32; 3] {
        let (x, y) = (p % resize.width, p / resize.width);
        if resize.width == self.width && resize.rows.len() == self.height {
            return self.at(p, i);
        }
        let (x0, x1, wx) = resize.columns[x];
        let (y0, y1, wy) = resize.rows[y];
        // The horizontal pass, then the vertical one, each summed from zero in tap order.
        let row = |j: usize| -> [f32; 3] {
            let (a, b) = (
                self.at(j * self.width + x0, i),
                self.at(j * self.width + x1, i),
            );
            std::array::from_fn(|c| {
                let mut acc = 0f32;
                acc += (1.0 - wx) * a[c];
                acc += wx * b[c];
                acc
            })
        };
        let (top, bottom) = (row(y0), row(y1));
        std::array::from_fn(|c| {
            let mut acc = 0f32;
            acc += (1.0 - wy) * top[c];
            acc += wy * bottom[c];
            acc
        })
    }

    /// Where normalised (gx, gy) falls, for [`Stack::sample_with_gradient`].
    #[inline]
    pub(super) fn locate(&self, gx: f32, gy: f32) -> Located {
        let (w, h) = (self.width, self.height);
        let (u, v) = (norm_to_pixel(gx, w), norm_to_pixel(gy, h));
        if !u.is_finite() || !v.is_finite() {
            return Located {
                corners: [None; 4],
                fx: 0.0,
                fy: 0.0,
            };
        }
        let (x0, y0) = (u.floor(), v.floor());
        let (fx, fy) = (u - x0, v - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let at = |x: i64, y: i64| -> Option<usize> {
            (x >= 0 && y >= 0 && x < w as i64 && y < h as i64).then(|| y as usize * w + x as usize)
        };
        Located {
            corners: [
                at(x0, y0),
                at(x0 + 1, y0),
                at(x0, y0 + 1),
                at(x0 + 1, y0 + 1),
            ],
            fx,
            fy,
        }
    }

    /// The bilinear sample of image `i` at `at` and its derivatives w.r.t. the pixel
    /// coordinates (u, v), per channel (the geometry fit's sampler: zero padding, a NaN
    /// position reads zero with zero derivatives).
    #[inline]
    pub(super) fn sample_with_gradient(&self, at: &Located, i: usize) -> ([f32; 3], [[f32; 3]; 2]) {
        let px = |corner: Option<usize>| corner.map_or([0.0; 3], |p| self.at(p, i));
        let [c00, c10, c01, c11] = at.corners;
        let (p00, p10, p01, p11) = (px(c00), px(c10), px(c01), px(c11));
        let (fx, fy) = (at.fx, at.fy);
        let mut val = [0f32; 3];
        let mut du = [0f32; 3];
        let mut dv = [0f32; 3];
        for c in 0..3 {
            let top = p00[c] + fx * (p10[c] - p00[c]);
            let bottom = p01[c] + fx * (p11[c] - p01[c]);
            val[c] = top + fy * (bottom - top);
            du[c] = (1.0 - fy) * (p10[c] - p00[c]) + fy * (p11[c] - p01[c]);
            dv[c] = bottom - top;
        }
        (val, [du, dv])
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::raster::{CamImage, Levels, NetImage, Network};
    use crate::sample::Grid;
    use rand::{RngExt, SeedableRng};

    /// `n` images of `w`×`h` with values uniform on [0, 1), from `seed`.
    pub(in crate::linear) fn random_images<S: Space>(
        n: usize,
        w: usize,
        h: usize,
        seed: u64,
    ) -> Vec<Rgb<S>> {
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| Rgb::from_fn(w, h, |_, _| [0, 1, 2].map(|_| rng.random_range(0.0..1.0))))
            .collect()
    }

    /// `n` random normalised positions, inside the frame and up to 0.3 outside it, then the
    /// corners, one on an edge and one that is not a number.
    fn test_positions(n: usize, seed: u64) -> Vec<[f32; 2]> {
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(seed);
        let mut positions: Vec<[f32; 2]> = (0..n)
            .map(|_| [rng.random_range(-1.3..1.3), rng.random_range(-1.3..1.3)])
            .collect();
        positions.extend([[-1.0, -1.0], [1.0, 1.0], [0.999, -0.2], [f32::NAN, 0.0]]);
        positions
    }

    /// The stack's samples are the whole-image operations' values to the bit: grid sampling at
    /// positions inside, on the edges, outside and not a number, and bilinear resizes up, down,
    /// along one axis only and to the same size.
    #[test]
    fn samples_equal_the_whole_image_operations_to_the_bit() {
        let caps: Vec<CamImage> = random_images(5, 9, 6, 7);
        let stack = Stack::<f32>::new(&caps);
        let positions = test_positions(60, 8);
        let grid = Grid::<Network, Camera>::from_vec(positions.len(), 1, positions.clone())
            .expect("one position per pixel");
        let frames = Frames::new(&caps);
        let built = Stack::<f32>::build(caps.len(), caps[0].size(), |i| caps[i].clone());
        assert_eq!(built.data, stack.data);
        // Captures held as 8-bit levels read as their f32 values do.
        let levels: Vec<Levels<Camera>> = (caps.iter())
            .map(|c| {
                let codes = c.data().iter().map(|&v| crate::pngio::to_u8(v)).collect();
                Levels::from_u8(c.width(), c.height(), codes).expect("same size")
            })
            .collect();
        let quantised: Vec<CamImage> = levels.iter().map(Levels::to_values).collect();
        let (level_frames, quantised_frames) = (Frames::new(&levels), Frames::new(&quantised));
        assert_eq!(
            Stack::<f32>::new(&levels).data,
            Stack::<f32>::new(&quantised).data
        );
        // In 16-bit fixed point, within half a step of the values.
        let fixed: Stack<u16> = Stack::new(&caps);
        for (i, cap) in caps.iter().enumerate() {
            let whole = crate::sample::grid_sample(cap, &grid);
            for (p, &[gx, gy]) in positions.iter().enumerate() {
                let got = stack.sample(&stack.taps(gx, gy), i);
                assert_eq!(got.map(f32::to_bits), whole.get(p, 0).map(f32::to_bits));
                let got = frames.sample(&frames.taps(gx, gy), i);
                assert_eq!(got.map(f32::to_bits), whole.get(p, 0).map(f32::to_bits));
                let got = fixed.sample(&fixed.taps(gx, gy), i);
                for c in 0..3 {
                    let want = whole.get(p, 0)[c];
                    assert!(
                        (got[c] - want).abs() <= 0.5 / 65535.0 + 1e-7,
                        "{got:?} {want}"
                    );
                }
                let taps = level_frames.taps(gx, gy);
                assert_eq!(
                    level_frames.sample(&taps, i).map(f32::to_bits),
                    quantised_frames.sample(&taps, i).map(f32::to_bits)
                );
            }
        }
        let shown: Vec<NetImage> = random_images(4, 7, 5, 9);
        let stack = Stack::<f32>::new(&shown);
        for (w, h) in [(17, 12), (3, 2), (7, 11), (7, 5), (16, 5)] {
            let resize = stack.resize_to(ImageSize::new(w, h));
            for (i, img) in shown.iter().enumerate() {
                let whole = crate::resize::resize_bilinear(img, w, h);
                for p in 0..w * h {
                    let got = stack.resampled(&resize, p, i);
                    let want = whole.get(p % w, p / w);
                    assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "{w}x{h} {p}");
                }
            }
        }
    }

    /// 16-bit fixed point rounds as `round()` does: every step's value, the halves between
    /// steps and the floats next to them, the ends, out of range and NaN.
    #[test]
    fn sixteen_bit_store_rounds_as_round_does() {
        let want = |v: f32| (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
        let mut values = vec![-1.0, 0.0, 1.0, 2.0, f32::NAN, f32::INFINITY, -f32::INFINITY];
        for k in 0..=65535u32 {
            for at in [k as f32, k as f32 + 0.5] {
                let v = at / 65535.0;
                values.extend([
                    v,
                    f32::from_bits(v.to_bits() + 1),
                    f32::from_bits(v.to_bits().saturating_sub(1)),
                ]);
            }
        }
        for v in values {
            assert_eq!(<u16 as Texel>::store(v), want(v), "{v:e}");
        }
    }

    /// The geometry's sampler agrees with grid sampling (within rounding: it interpolates in
    /// another order), and its derivatives are those of the sample inside a cell.
    #[test]
    fn the_geometry_sampler_and_its_derivatives_agree_with_the_bilinear_sample() {
        let caps: Vec<CamImage> = random_images(5, 9, 6, 17);
        let stack = Stack::<f32>::new(&caps);
        let positions = test_positions(40, 18);
        let (w, h) = (9.0f32, 6.0f32);
        for i in 0..caps.len() {
            for &[gx, gy] in &positions {
                let (value, [du, dv]) = stack.sample_with_gradient(&stack.locate(gx, gy), i);
                if gx.is_nan() {
                    assert_eq!((value, du, dv), ([0.0; 3], [0.0; 3], [0.0; 3]));
                    continue;
                }
                let want = stack.sample(&stack.taps(gx, gy), i);
                for c in 0..3 {
                    assert!(
                        (value[c] - want[c]).abs() <= 1e-6,
                        "{value:?} against {want:?}"
                    );
                }
                // One pixel is 2 / (side − 1) in normalised coordinates.
                let step = 1e-3f32;
                let (u, v) = (norm_to_pixel(gx, 9), norm_to_pixel(gy, 6));
                let inside =
                    |t: f32| (t - t.floor()) > 2.0 * step && (t - t.floor()) < 1.0 - 2.0 * step;
                if inside(u) && inside(v) {
                    let right = stack.locate(gx + step * 2.0 / (w - 1.0), gy);
                    let down = stack.locate(gx, gy + step * 2.0 / (h - 1.0));
                    let (vr, _) = stack.sample_with_gradient(&right, i);
                    let (vd, _) = stack.sample_with_gradient(&down, i);
                    for c in 0..3 {
                        assert!(((vr[c] - value[c]) / step - du[c]).abs() < 2e-2, "du {c}");
                        assert!(((vd[c] - value[c]) / step - dv[c]).abs() < 2e-2, "dv {c}");
                    }
                }
            }
        }
    }
}
