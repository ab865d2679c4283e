//! Where a seam between projected pictures would show: the band along every overlap edge, and
//! the pixels well away from any, for [`crate::metrics::seam_figure`].

use crate::morph::{Element, dilate};
use crate::raster::{Camera, ImageSize, Mask, Rect};

/// The band's half-width for a camera of `camera` pixels: 1 % of its width, at least 2.
pub fn band_px(camera: ImageSize) -> usize {
    (camera.width / 100).max(2)
}

/// [`seam_regions`] inside the rectangle `area` of a camera of `camera` pixels, at
/// [`band_px`]: the band and the pixels away from it, or `None` where either is empty (no two
/// projectors overlap there: a tiled set without a blend).
pub fn seam_bands(
    masks: &[Mask<Camera>],
    area: Rect,
    camera: ImageSize,
) -> Option<(Mask<Camera>, Mask<Camera>)> {
    let inside = Mask::from_fn(camera.width, camera.height, |x, y| area.contains(x, y));
    let (band, away) = seam_regions(masks, &inside, band_px(camera));
    let some = |m: &Mask<Camera>| m.data().iter().any(|&b| b);
    (some(&band) && some(&away)).then_some((band, away))
}

/// Inside `region` (camera pixels): the pixels within `band_px` of an overlap edge (a pixel at
/// the edge of one projector's light, `masks[k]`, that another projector lights too: where one
/// picture ends inside another), and the pixels more than `2·band_px` from any such edge.
/// Masks of another size than `region` count as lighting nothing.
pub fn seam_regions(
    masks: &[Mask<Camera>],
    region: &Mask<Camera>,
    band_px: usize,
) -> (Mask<Camera>, Mask<Camera>) {
    let ImageSize {
        width: w,
        height: h,
    } = region.size();
    let lit = |k: usize, x: usize, y: usize| {
        masks[k].size() == region.size() && masks[k].data()[y * w + x]
    };
    let edges = Mask::<Camera>::from_fn(w, h, |x, y| {
        (0..masks.len()).any(|k| {
            let at_edge = lit(k, x, y)
                && [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
                    .iter()
                    .any(|(dx, dy)| {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        nx >= 0
                            && ny >= 0
                            && (nx as usize) < w
                            && (ny as usize) < h
                            && !lit(k, nx as usize, ny as usize)
                    });
            at_edge && (0..masks.len()).any(|j| j != k && lit(j, x, y))
        })
    });
    let near = dilate(&edges, Element::Disk(band_px));
    let far = dilate(&edges, Element::Disk(2 * band_px));
    let band = Mask::from_fn(w, h, |x, y| {
        near.data()[y * w + x] && region.data()[y * w + x]
    });
    let away = Mask::from_fn(w, h, |x, y| {
        !far.data()[y * w + x] && region.data()[y * w + x]
    });
    (band, away)
}
