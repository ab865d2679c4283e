//! Binary-image and threshold tools on the core types: Otsu threshold of a plane, connected
//! components, hole filling, convex hull, morphology, and a summed-area table of a mask.
//!
//! Every operation keeps the pixel space of its input. Pixel (x, y) is column x, row y; masks are
//! `true` inside. Neighbourhoods beyond the image edge are **background** (the image is taken to
//! be surrounded by an infinite unset plane): dilation never reaches outside, erosion removes
//! pixels within the element radius of the edge, and closing is computed on a padded copy so that
//! it never removes pixels (closing ⊇ input, opening ⊆ input).
//!
//! imageproc does the component labelling and the Euclidean distance transform behind the disk
//! element (through its 8-bit images; the conversion is one pass). Otsu is computed here on the
//! f32 values because quantising a dim difference image to 8 bits would throw away the very
//! levels the projector FOV detection needs; the hull, hole filling and square elements are
//! small enough to write directly.
//!
//! - `otsu`: [`otsu_threshold`] and [`otsu_threshold_values`];
//! - `components`: [`Components`], [`connected_components`], the largest and major components,
//!   [`fill_holes`];
//! - `hull`: [`convex_hull`], [`fill_convex_polygon`], [`convex_hull_fill`];
//! - `morphology`: [`IntegralMask`], [`Element`], [`dilate`], [`erode`], [`close`], [`open`],
//!   [`squared_distance`], [`and`], [`and_not`].

use image::GrayImage;

use crate::raster::{Mask, Space};

mod components;
mod hull;
mod morphology;
mod otsu;
#[cfg(test)]
mod tests;

pub use components::{
    Components, connected_components, fill_holes, largest_component, major_components, major_labels,
};
pub use hull::{convex_hull, convex_hull_fill, fill_convex_polygon};
pub use morphology::{
    Element, IntegralMask, and, and_not, close, dilate, erode, open, squared_distance,
};
pub use otsu::{OTSU_BINS, otsu_threshold, otsu_threshold_values};

// ---------------------------------------------------------------------------------------------
// Conversions to imageproc's 8-bit images
// ---------------------------------------------------------------------------------------------

/// The mask as an 8-bit image: 255 on set pixels (on unset ones when `invert`), 0 elsewhere.
fn to_gray<S: Space>(mask: &Mask<S>, invert: bool) -> GrayImage {
    let data = mask
        .data()
        .iter()
        .map(|&b| if b != invert { 255u8 } else { 0 })
        .collect();
    GrayImage::from_raw(mask.width() as u32, mask.height() as u32, data)
        .expect("one byte per mask pixel")
}
