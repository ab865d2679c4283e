//! Where one projector of a set lands in the camera image: the inverse of its model's sampling
//! grid (network lattice → camera), rasterised on the camera's pixels, and each covered camera
//! pixel's distance to the edge of that cover (the blend weights' ramp).
//!
//! Spaces: camera pixel coordinates (pixel centres at integers) in and out; lattice coordinates
//! are the model's network pixels (pixel centres at integers). A grid holds normalised camera
//! coordinates (align-corners, [`crate::sample`]).

use rayon::prelude::*;

use crate::raster::{Camera, ImageSize, Mask, Network};
use crate::sample::{Grid, norm_to_pixel};

/// The camera pixels one projector lights in its model, with the lattice position each sees.
#[derive(Clone, Debug)]
pub struct Cover {
    camera: ImageSize,
    /// Per camera pixel (row-major): the lattice position (x, y) seen there, NaN where the
    /// projector's frame does not reach.
    lattice: Vec<[f32; 2]>,
    /// Per camera pixel: the distance in camera pixels to the nearest camera pixel the
    /// projector does not reach (the image's own border is not an edge); 0 where not covered.
    distance: Vec<f32>,
}

impl Cover {
    /// Rasterises `grid` (a model's lattice → normalised camera coordinates) over a camera image
    /// of `camera` pixels: each lattice cell is two triangles, and a camera pixel whose centre
    /// lies in one takes the lattice position interpolated across it. Where the grid folds, the
    /// first cell in lattice order keeps the pixel.
    pub fn of(grid: &Grid<Network, Camera>, camera: ImageSize) -> Cover {
        let (cw, ch) = (camera.width, camera.height);
        let (gw, gh) = (grid.width(), grid.height());
        let at = |x: usize, y: usize| {
            let [u, v] = grid.get(x, y);
            [norm_to_pixel(u, cw), norm_to_pixel(v, ch)]
        };
        let mut lattice = vec![[f32::NAN; 2]; cw * ch];
        for y in 0..gh.saturating_sub(1) {
            for x in 0..gw.saturating_sub(1) {
                let corners = [
                    (at(x, y), [x as f32, y as f32]),
                    (at(x + 1, y), [x as f32 + 1.0, y as f32]),
                    (at(x + 1, y + 1), [x as f32 + 1.0, y as f32 + 1.0]),
                    (at(x, y + 1), [x as f32, y as f32 + 1.0]),
                ];
                for tri in [
                    [corners[0], corners[1], corners[2]],
                    [corners[0], corners[2], corners[3]],
                ] {
                    fill_triangle(&mut lattice, camera, tri);
                }
            }
        }
        let distance = distance_to_edge(&lattice, camera);
        Cover {
            camera,
            lattice,
            distance,
        }
    }

    pub fn camera_size(&self) -> ImageSize {
        self.camera
    }

    /// Whether camera pixel `i` (row-major) is lit by the projector.
    pub fn covers(&self, i: usize) -> bool {
        self.lattice.get(i).is_some_and(|p| p[0].is_finite())
    }

    /// The lattice position camera pixel `i` (row-major) sees; `None` where not covered.
    pub fn lattice_of(&self, i: usize) -> Option<[f32; 2]> {
        self.lattice.get(i).copied().filter(|p| p[0].is_finite())
    }

    /// The camera pixels the projector lights.
    pub fn mask(&self) -> Mask<Camera> {
        let ImageSize { width, height } = self.camera;
        Mask::from_fn(width, height, |x, y| self.covers(y * width + x))
    }

    /// The lattice position seen at camera point (u, v) (camera pixels): `None` where the
    /// nearest camera pixel is not covered; otherwise the bilinear interpolation of the covered
    /// neighbours' positions, their weights renormalised.
    pub fn lattice_at(&self, u: f32, v: f32) -> Option<[f32; 2]> {
        let nearest = self.index(u.round(), v.round())?;
        if !self.covers(nearest) {
            return None;
        }
        let (mut sum, mut weight) = ([0f32; 2], 0f32);
        self.taps(u, v, |i, w| {
            if self.covers(i) {
                sum[0] += w * self.lattice[i][0];
                sum[1] += w * self.lattice[i][1];
                weight += w;
            }
        });
        (weight > 0.0).then(|| [sum[0] / weight, sum[1] / weight])
    }

    /// The distance to the cover's edge at camera point (u, v), bilinear (0 outside the cover).
    pub fn distance_at(&self, u: f32, v: f32) -> f32 {
        self.bilinear(&self.distance, u, v)
    }

    /// Per camera pixel (row-major): the distance to the cover's edge, camera pixels.
    pub fn distances(&self) -> &[f32] {
        &self.distance
    }

    /// A camera-space field (one value per camera pixel, row-major) at camera point (u, v),
    /// bilinear, reading 0 outside the image.
    pub fn bilinear(&self, field: &[f32], u: f32, v: f32) -> f32 {
        let mut d = 0.0;
        self.taps(u, v, |i, w| d += w * field.get(i).copied().unwrap_or(0.0));
        d
    }

    fn index(&self, x: f32, y: f32) -> Option<usize> {
        let ImageSize { width, height } = self.camera;
        (x.is_finite() && y.is_finite() && x >= 0.0 && y >= 0.0)
            .then_some((x as usize, y as usize))
            .filter(|&(x, y)| x < width && y < height)
            .map(|(x, y)| y * width + x)
    }

    /// The in-bounds bilinear neighbours of camera point (u, v) with their weights.
    fn taps(&self, u: f32, v: f32, mut f: impl FnMut(usize, f32)) {
        if !u.is_finite() || !v.is_finite() {
            return;
        }
        let (x0, y0) = (u.floor(), v.floor());
        let (fx, fy) = (u - x0, v - y0);
        for (dy, wy) in [(0.0, 1.0 - fy), (1.0, fy)] {
            for (dx, wx) in [(0.0, 1.0 - fx), (1.0, fx)] {
                if let Some(i) = self.index(x0 + dx, y0 + dy)
                    && wx * wy > 0.0
                {
                    f(i, wx * wy);
                }
            }
        }
    }
}

/// Sets the camera pixels whose centres lie in the triangle (camera pixel positions, lattice
/// positions at its corners) and are not set yet.
fn fill_triangle(lattice: &mut [[f32; 2]], camera: ImageSize, tri: [([f32; 2], [f32; 2]); 3]) {
    let [(a, la), (b, lb), (c, lc)] = tri;
    if [a, b, c]
        .iter()
        .any(|p| !p[0].is_finite() || !p[1].is_finite())
    {
        return;
    }
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if det.abs() < 1e-12 {
        return;
    }
    let (w, h) = (camera.width as f32, camera.height as f32);
    let lo_x = a[0].min(b[0]).min(c[0]).ceil().max(0.0);
    let hi_x = a[0].max(b[0]).max(c[0]).floor().min(w - 1.0);
    let lo_y = a[1].min(b[1]).min(c[1]).ceil().max(0.0);
    let hi_y = a[1].max(b[1]).max(c[1]).floor().min(h - 1.0);
    if lo_x > hi_x || lo_y > hi_y {
        return;
    }
    // Barycentric coordinates with a tolerance, so a pixel centre on a shared edge is taken.
    const EDGE: f32 = -1e-5;
    let mut y = lo_y;
    while y <= hi_y {
        let mut x = lo_x;
        while x <= hi_x {
            let s = ((b[0] - x) * (c[1] - y) - (c[0] - x) * (b[1] - y)) / det;
            let t = ((c[0] - x) * (a[1] - y) - (a[0] - x) * (c[1] - y)) / det;
            let r = 1.0 - s - t;
            if s >= EDGE && t >= EDGE && r >= EDGE {
                let i = y as usize * camera.width + x as usize;
                if !lattice[i][0].is_finite() {
                    lattice[i] = [
                        s * la[0] + t * lb[0] + r * lc[0],
                        s * la[1] + t * lb[1] + r * lc[1],
                    ];
                }
            }
            x += 1.0;
        }
        y += 1.0;
    }
}

/// Per camera pixel, the chamfer distance (steps 1 and √2, camera pixels) to the nearest
/// pixel not covered, 0 for those; where every pixel is covered, the image's diagonal.
fn distance_to_edge(lattice: &[[f32; 2]], camera: ImageSize) -> Vec<f32> {
    let ImageSize {
        width: w,
        height: h,
    } = camera;
    let far = ((w * w + h * h) as f32).sqrt();
    let mut d: Vec<f32> = lattice
        .par_iter()
        .map(|p| if p[0].is_finite() { far } else { 0.0 })
        .collect();
    let diag = std::f32::consts::SQRT_2;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut v = d[i];
            if x > 0 {
                v = v.min(d[i - 1] + 1.0);
            }
            if y > 0 {
                v = v.min(d[i - w] + 1.0);
                if x > 0 {
                    v = v.min(d[i - w - 1] + diag);
                }
                if x + 1 < w {
                    v = v.min(d[i - w + 1] + diag);
                }
            }
            d[i] = v;
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            let i = y * w + x;
            let mut v = d[i];
            if x + 1 < w {
                v = v.min(d[i + 1] + 1.0);
            }
            if y + 1 < h {
                v = v.min(d[i + w] + 1.0);
                if x + 1 < w {
                    v = v.min(d[i + w + 1] + diag);
                }
                if x > 0 {
                    v = v.min(d[i + w - 1] + diag);
                }
            }
            d[i] = v;
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::pixel_to_norm;

    /// A lattice that maps onto the camera's left half, upright and scaled: its inverse is
    /// the scale back, its cover the left half, and the distance grows away from the half's
    /// right edge only (the image's border is not an edge).
    #[test]
    fn a_grid_is_inverted_on_the_camera_pixels_it_reaches() {
        let camera = ImageSize::new(20, 10);
        // Lattice 19×19 over camera x in [0, 9], y in [0, 9]: half a camera pixel per cell.
        let grid = Grid::<Network, Camera>::from_fn(19, 19, |x, y| {
            [
                pixel_to_norm(x as f32 * 0.5, camera.width),
                pixel_to_norm(y as f32 * 0.5, camera.height),
            ]
        });
        let cover = Cover::of(&grid, camera);
        for y in 0..10 {
            for x in 0..20 {
                let i = y * 20 + x;
                assert_eq!(cover.covers(i), x <= 9, "pixel ({x}, {y})");
            }
        }
        let [lx, ly] = cover.lattice_at(3.0, 4.0).unwrap();
        assert!(
            (lx - 6.0).abs() < 1e-4 && (ly - 8.0).abs() < 1e-4,
            "{lx} {ly}"
        );
        let [lx, _] = cover.lattice_at(3.5, 4.0).unwrap();
        assert!((lx - 7.0).abs() < 1e-4, "{lx}");
        assert!(cover.lattice_at(12.0, 4.0).is_none());
        assert!(cover.lattice_at(-3.0, 4.0).is_none());
        // Distance: 1 at the last covered column, 10 at the first; 0 outside.
        assert_eq!(cover.distance_at(9.0, 5.0), 1.0);
        assert_eq!(cover.distance_at(0.0, 0.0), 10.0);
        assert_eq!(cover.distance_at(15.0, 5.0), 0.0);
        assert_eq!(cover.mask().data().iter().filter(|&&b| b).count(), 100);
    }
}
