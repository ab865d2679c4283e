//! How the desired view is shared among the projectors that reach a camera point: smoothly
//! across every overlap, in proportion to what each can give there, and the same for every
//! projector's pass (each reads the same camera-space maps, so the shares of the projectors
//! reaching a point sum to 1 whichever projector's pixel asks).
//!
//! Projector j's weight at a camera pixel is `d_j² · w_j`: `d_j` its distance (camera pixels)
//! to the edge of its cover ([`super::Cover`]), so its share falls to nothing at its edge with
//! a zero slope and no seam marks where its picture ends; `w_j` its white's brightness there
//! above black (the mean over channels of `M_j⁻¹ · 1`, camera linear light), smoothed over
//! [`BRIGHTNESS_SIGMA`] camera pixels within its cover, so a brighter projector takes more of
//! the view (the two run out of light together) while the surface's texture, which both see
//! alike, does not make the shares jitter from pixel to pixel. The shares are the weights
//! normalised over the projectors that reach the pixel.

use super::Cover;
use super::solve::MAX_PROJECTORS;
use crate::linear::gamut::inverse;
use crate::raster::{Camera, ImageSize, Plane};

/// The least brightness a projector is weighed with (camera linear light).
const BRIGHTNESS_MIN: f32 = 1e-4;

/// The scale (camera pixels, Gaussian σ) the brightness is smoothed over.
pub const BRIGHTNESS_SIGMA: f64 = 8.0;

/// How much camera linear light a projector's white adds above its black where its colour
/// model is `k` (`M` row-major, then `b`): the mean over channels of `M⁻¹ · 1`; 0 where `M`
/// cannot be inverted.
pub fn brightness(k: &[f32; 12]) -> f32 {
    let m = [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]];
    inverse(&m).map_or(0.0, |a| {
        (a.iter().map(|row| row[0] + row[1] + row[2]).sum::<f32>() / 3.0).max(BRIGHTNESS_MIN)
    })
}

/// The camera-space share maps (one per projector, one value per camera pixel) of projectors
/// with covers `covers` and brightness `bright` (camera linear light per camera pixel where
/// covered); see the module documentation.
pub fn share_maps(covers: &[Cover], bright: &[Vec<f32>], camera: ImageSize) -> Vec<Vec<f32>> {
    let pixels = camera.width * camera.height;
    let smooth: Vec<Vec<f32>> = covers
        .iter()
        .zip(bright)
        .map(|(c, b)| smoothed_within(c, b, camera))
        .collect();
    let mut maps = vec![vec![0f32; pixels]; covers.len()];
    for i in 0..pixels {
        let w: Vec<f32> = covers
            .iter()
            .zip(&smooth)
            .map(|(c, b)| {
                let d = c.distances()[i];
                if c.covers(i) { d * d * b[i] } else { 0.0 }
            })
            .collect();
        let total: f32 = w.iter().sum();
        let present = covers.iter().filter(|c| c.covers(i)).count().max(1) as f32;
        for (j, map) in maps.iter_mut().enumerate() {
            map[i] = if total > 0.0 && total.is_finite() {
                w[j] / total
            } else if covers[j].covers(i) {
                1.0 / present
            } else {
                0.0
            };
        }
    }
    maps
}

/// `field` smoothed with a Gaussian of [`BRIGHTNESS_SIGMA`] within the cover only (the
/// pixels outside neither give nor take), normalised by how much of the kernel the cover
/// holds.
fn smoothed_within(cover: &Cover, field: &[f32], camera: ImageSize) -> Vec<f32> {
    let ImageSize { width, height } = camera;
    let inside = |i: usize| cover.covers(i) && field[i].is_finite();
    let masked = Plane::<Camera>::from_fn(width, height, |x, y| {
        let i = y * width + x;
        if inside(i) { field[i] } else { 0.0 }
    });
    let weight =
        Plane::<Camera>::from_fn(
            width,
            height,
            |x, y| {
                if inside(y * width + x) { 1.0 } else { 0.0 }
            },
        );
    let num = crate::filter::gaussian_blur(&masked, BRIGHTNESS_SIGMA);
    let den = crate::filter::gaussian_blur(&weight, BRIGHTNESS_SIGMA);
    num.data()
        .iter()
        .zip(den.data())
        .map(|(n, d)| if *d > 1e-6 { n / d } else { 0.0 })
        .collect()
}

/// Shares read from the maps at one point, renormalised over the projectors `present` there
/// (each in [0, 1], summing to 1 over them; equal where none has any).
pub fn renormalise(
    shares: [f32; MAX_PROJECTORS],
    present: [bool; MAX_PROJECTORS],
) -> [f32; MAX_PROJECTORS] {
    let total: f32 = (0..MAX_PROJECTORS)
        .filter(|&j| present[j])
        .map(|j| shares[j])
        .sum();
    let n = present.iter().filter(|&&p| p).count().max(1) as f32;
    std::array::from_fn(|j| match present[j] {
        false => 0.0,
        true if total > 1e-6 => shares[j] / total,
        true => 1.0 / n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Network;
    use crate::sample::{Grid, pixel_to_norm};

    fn diag(gain: f32) -> [f32; 12] {
        // M = 1/gain · I: the projector's white adds `gain` camera linear light.
        let m = 1.0 / gain;
        [m, 0.0, 0.0, 0.0, m, 0.0, 0.0, 0.0, m, 0.0, 0.0, 0.0]
    }

    /// A projector covering camera columns `x0..=x1` of a 40×10 camera.
    fn cover(x0: f32, x1: f32) -> Cover {
        let camera = ImageSize::new(40, 10);
        let n = ((x1 - x0) * 2.0) as usize + 1;
        let grid = Grid::<Network, Camera>::from_fn(n, 19, |x, y| {
            [
                pixel_to_norm(x0 + x as f32 * 0.5, camera.width),
                pixel_to_norm(y as f32 * 0.5, camera.height),
            ]
        });
        Cover::of(&grid, camera)
    }

    #[test]
    fn shares_ramp_across_the_overlap_and_follow_the_brightness() {
        let camera = ImageSize::new(40, 10);
        let covers = [cover(0.0, 25.0), cover(15.0, 39.0)];
        let bright = [
            vec![brightness(&diag(0.5)); 400],
            vec![brightness(&diag(0.25)); 400],
        ];
        let maps = share_maps(&covers, &bright, camera);
        let at = |j: usize, x: usize| maps[j][5 * 40 + x];
        // Alone at either end; in between, the first fades out towards its edge at 25 and
        // the second in from its edge at 15; the shares sum to 1 everywhere covered.
        assert_eq!(at(0, 5), 1.0);
        assert_eq!(at(1, 35), 1.0);
        for x in 0..40 {
            assert!((at(0, x) + at(1, x) - 1.0).abs() < 1e-5, "x {x}");
        }
        for x in 15..25 {
            assert!(at(0, x) >= at(0, x + 1), "x {x}");
        }
        // Equally far from both edges (x = 20), the brighter takes two thirds.
        assert!((at(0, 20) - 2.0 / 3.0).abs() < 1e-4, "{}", at(0, 20));
    }

    #[test]
    fn renormalising_keeps_only_those_present() {
        let s = renormalise([0.2, 0.6, 0.2, 0.0], [true, false, true, false]);
        assert_eq!(s, [0.5, 0.0, 0.5, 0.0]);
        let s = renormalise([0.0; 4], [true, true, false, false]);
        assert_eq!(s, [0.5, 0.5, 0.0, 0.0]);
    }
}
