//! Sampling grids and bilinear grid sampling — the CPU reference that the models' differentiable
//! sampler and the GPU compensation pass must match.
//!
//! Conventions (docs/architecture.md, "Spaces and conventions"): a grid lives on the
//! *destination* pixel lattice and holds, per
//! destination pixel, a position in the *source* image in normalised coordinates in [-1, 1] with
//! align_corners = true: -1 and +1 are the centres of the first and last source pixels, so source
//! pixel coordinate `u = (gx + 1) / 2 · (W − 1)`. Bilinear interpolation reads zero for the
//! neighbours that fall outside the source (PyTorch `grid_sample(mode="bilinear",
//! padding_mode="zeros", align_corners=True)`).

use std::marker::PhantomData;

use crate::error::{Error, Result};
use crate::raster::{ImageSize, Rgb, Space};

/// A sampling grid from destination space `D` into source space `Src`: `width`×`height` positions
/// `[x, y]` in normalised source coordinates (align_corners = true), row-major.
#[derive(Clone, PartialEq)]
pub struct Grid<D, Src> {
    width: usize,
    height: usize,
    data: Vec<[f32; 2]>,
    _spaces: PhantomData<(D, Src)>,
}

impl<D: Space, Src: Space> std::fmt::Debug for Grid<D, Src> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Grid<{}→{}>({}x{})",
            D::NAME,
            Src::NAME,
            self.width,
            self.height
        )
    }
}

/// Normalised coordinate (align_corners = true) of pixel index `i` on an axis of `n` pixels.
#[inline]
pub fn pixel_to_norm(i: f32, n: usize) -> f32 {
    if n <= 1 {
        0.0
    } else {
        2.0 * i / (n - 1) as f32 - 1.0
    }
}

/// Pixel coordinate of normalised coordinate `g` on an axis of `n` pixels.
#[inline]
pub fn norm_to_pixel(g: f32, n: usize) -> f32 {
    (g + 1.0) * 0.5 * (n.max(1) - 1) as f32
}

impl<D: Space, Src: Space> Grid<D, Src> {
    pub fn from_vec(width: usize, height: usize, data: Vec<[f32; 2]>) -> Result<Self> {
        if data.len() != width * height {
            return Err(Error::Shape(format!(
                "grid {}x{} needs {} positions, got {}",
                width,
                height,
                width * height,
                data.len()
            )));
        }
        Ok(Self {
            width,
            height,
            data,
            _spaces: PhantomData,
        })
    }

    /// Builds a grid from a function of destination pixel (x, y) returning normalised source (x, y).
    pub fn from_fn(
        width: usize,
        height: usize,
        mut f: impl FnMut(usize, usize) -> [f32; 2],
    ) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self {
            width,
            height,
            data,
            _spaces: PhantomData,
        }
    }

    /// The identity grid: destination pixel (x, y) reads the source at the same normalised place.
    pub fn identity(width: usize, height: usize) -> Self {
        Self::from_fn(width, height, |x, y| {
            [
                pixel_to_norm(x as f32, width),
                pixel_to_norm(y as f32, height),
            ]
        })
    }

    /// The affine grid of a 2×3 matrix θ mapping destination normalised coordinates (x, y, 1) to
    /// source normalised coordinates (PyTorch `affine_grid(..., align_corners=True)`).
    pub fn affine(theta: &[[f32; 3]; 2], width: usize, height: usize) -> Self {
        Self::from_fn(width, height, |x, y| {
            let (u, v) = (
                pixel_to_norm(x as f32, width),
                pixel_to_norm(y as f32, height),
            );
            [
                theta[0][0] * u + theta[0][1] * v + theta[0][2],
                theta[1][0] * u + theta[1][1] * v + theta[1][2],
            ]
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
    pub fn data(&self) -> &[[f32; 2]] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [[f32; 2]] {
        &mut self.data
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 2] {
        self.data[y * self.width + x]
    }

    /// Composes grids in coordinate space: `self` maps D → M, `inner` maps M → Src; the result maps
    /// D → Src by sampling `inner`'s coordinates bilinearly at `self`'s positions (as the models
    /// compose the TPS and affine grids: one image sampling at the end, not two). Positions of
    /// `self` outside M read zero weight for the missing neighbours, exactly as image sampling does.
    pub fn compose<Src2: Space>(&self, inner: &Grid<Src, Src2>) -> Grid<D, Src2> {
        let ImageSize {
            width: iw,
            height: ih,
        } = inner.size();
        let data = self
            .data
            .iter()
            .map(|&[gx, gy]| {
                let mut out = [0f32; 2];
                for_each_tap(gx, gy, iw, ih, |idx, w| {
                    out[0] += w * inner.data[idx][0];
                    out[1] += w * inner.data[idx][1];
                });
                out
            })
            .collect();
        Grid {
            width: self.width,
            height: self.height,
            data,
            _spaces: PhantomData,
        }
    }
}

/// Calls `f(index, weight)` for the in-bounds bilinear neighbours of normalised position (gx, gy)
/// in a `w`×`h` source (align_corners = true; out-of-bounds neighbours are skipped = read zero).
#[inline]
pub fn for_each_tap(gx: f32, gy: f32, w: usize, h: usize, mut f: impl FnMut(usize, f32)) {
    let (u, v) = (norm_to_pixel(gx, w), norm_to_pixel(gy, h));
    if !u.is_finite() || !v.is_finite() {
        return;
    }
    let (x0, y0) = (u.floor(), v.floor());
    let (fx, fy) = (u - x0, v - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    for (dy, wy) in [(0i64, 1.0 - fy), (1, fy)] {
        let yy = y0 + dy;
        if yy < 0 || yy >= h as i64 || wy == 0.0 {
            continue;
        }
        for (dx, wx) in [(0i64, 1.0 - fx), (1, fx)] {
            let xx = x0 + dx;
            if xx < 0 || xx >= w as i64 || wx == 0.0 {
                continue;
            }
            f(yy as usize * w + xx as usize, wx * wy);
        }
    }
}

/// Bilinear grid sampling: output pixel (x, y) of space `D` = `src` at `grid(x, y)`, zero outside.
pub fn grid_sample<D: Space, Src: Space>(src: &Rgb<Src>, grid: &Grid<D, Src>) -> Rgb<D> {
    let ImageSize {
        width: w,
        height: h,
    } = src.size();
    let s = src.data();
    let mut out = Vec::with_capacity(grid.data.len() * 3);
    for &[gx, gy] in &grid.data {
        let mut px = [0f32; 3];
        for_each_tap(gx, gy, w, h, |idx, wt| {
            px[0] += wt * s[idx * 3];
            px[1] += wt * s[idx * 3 + 1];
            px[2] += wt * s[idx * 3 + 2];
        });
        out.extend_from_slice(&px);
    }
    Rgb::from_vec(grid.width, grid.height, out).expect("one pixel per grid position")
}
