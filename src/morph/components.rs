//! Connected components (8-connected foreground, 4-connected background) and hole filling.

use image::Luma;
use imageproc::region_labelling::{Connectivity, connected_components as ip_components};

use super::to_gray;
use crate::raster::{ImageSize, Mask, Space};

/// Connected components of a mask's set pixels under 8-connectivity.
///
/// Labels are 1..=count in raster order of each component's first pixel; 0 is background.
#[derive(Clone, Debug)]
pub struct Components {
    width: usize,
    height: usize,
    labels: Vec<u32>,
    /// sizes[l] = number of pixels with label l (sizes[0] counts the background).
    sizes: Vec<usize>,
}

impl Components {
    /// Number of components (labels run 1..=count).
    pub fn count(&self) -> usize {
        self.sizes.len() - 1
    }
    /// Label of pixel (x, y); 0 for background.
    pub fn label(&self, x: usize, y: usize) -> u32 {
        self.labels[y * self.width + x]
    }
    /// All labels, row-major.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }
    /// Pixel count of component `label` (0 for an unknown label).
    pub fn size(&self, label: u32) -> usize {
        if label == 0 {
            return 0;
        }
        self.sizes.get(label as usize).copied().unwrap_or(0)
    }
    /// The label of the largest component (the first in raster order among equals), or `None`
    /// when there are no set pixels.
    pub fn largest(&self) -> Option<u32> {
        let mut best: Option<(u32, usize)> = None;
        for (l, &n) in self.sizes.iter().enumerate().skip(1) {
            if best.is_none_or(|(_, bn)| n > bn) {
                best = Some((l as u32, n));
            }
        }
        best.map(|(l, _)| l)
    }
    /// The mask of the components whose label satisfies `keep`.
    pub fn select<S: Space>(&self, mut keep: impl FnMut(u32) -> bool) -> Mask<S> {
        let mut lut: Vec<bool> = (0..self.sizes.len() as u32).map(&mut keep).collect();
        lut[0] = false;
        let data = self.labels.iter().map(|&l| lut[l as usize]).collect();
        Mask::from_vec(self.width, self.height, data).expect("one label per pixel")
    }
    /// The mask of one component.
    pub fn component<S: Space>(&self, label: u32) -> Mask<S> {
        self.select(|l| l == label && label != 0)
    }
}

/// Labels the 8-connected components of `mask`.
pub fn connected_components<S: Space>(mask: &Mask<S>) -> Components {
    label_impl(mask, false, Connectivity::Eight)
}

fn label_impl<S: Space>(mask: &Mask<S>, invert: bool, conn: Connectivity) -> Components {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    if w == 0 || h == 0 {
        return Components {
            width: w,
            height: h,
            labels: Vec::new(),
            sizes: vec![0],
        };
    }
    let raw = ip_components(&to_gray(mask, invert), conn, Luma([0u8])).into_raw();
    // imageproc numbers components in raster order of first appearance but does not promise
    // dense labels; renumber densely in raster order.
    let mut remap = std::collections::HashMap::<u32, u32>::new();
    let mut sizes = vec![0usize];
    let labels: Vec<u32> = raw
        .into_iter()
        .map(|l| {
            if l == 0 {
                sizes[0] += 1;
                return 0;
            }
            let next = remap.len() as u32 + 1;
            let d = *remap.entry(l).or_insert(next);
            if d as usize == sizes.len() {
                sizes.push(0);
            }
            sizes[d as usize] += 1;
            d
        })
        .collect();
    Components {
        width: w,
        height: h,
        labels,
        sizes,
    }
}

/// The largest 8-connected component of `mask` (empty when the mask is empty).
pub fn largest_component<S: Space>(mask: &Mask<S>) -> Mask<S> {
    let cc = connected_components(mask);
    match cc.largest() {
        Some(l) => cc.component(l),
        None => Mask::new(mask.width(), mask.height()),
    }
}

/// The components of `mask` holding at least `min_fraction` of the largest one's pixels, as
/// labels of `cc` (largest first). `min_fraction` ≥ 1 keeps the largest only.
pub fn major_labels(cc: &Components, min_fraction: f64) -> Vec<u32> {
    let Some(big) = cc.largest() else {
        return Vec::new();
    };
    if min_fraction >= 1.0 {
        return vec![big];
    }
    let floor = min_fraction * cc.size(big) as f64;
    let mut labels: Vec<u32> = (1..=cc.count() as u32)
        .filter(|&l| cc.size(l) as f64 >= floor)
        .collect();
    labels.sort_by_key(|&l| std::cmp::Reverse(cc.size(l)));
    labels
}

/// The union of the components of `mask` holding at least `min_fraction` of the largest one's
/// pixels (see [`major_labels`]).
pub fn major_components<S: Space>(mask: &Mask<S>, min_fraction: f64) -> Mask<S> {
    let cc = connected_components(mask);
    let keep = major_labels(&cc, min_fraction);
    cc.select(|l| keep.contains(&l))
}

/// Fills holes: unset regions not connected to the image border become set. Unset pixels are
/// connected through their 4 edge neighbours (the dual of 8-connected foreground), so a diagonal
/// chain of set pixels closes a hole.
pub fn fill_holes<S: Space>(mask: &Mask<S>) -> Mask<S> {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    if w == 0 || h == 0 {
        return mask.clone();
    }
    let bg = label_impl(mask, true, Connectivity::Four);
    let mut touches = vec![false; bg.sizes.len()];
    for x in 0..w {
        touches[bg.label(x, 0) as usize] = true;
        touches[bg.label(x, h - 1) as usize] = true;
    }
    for y in 0..h {
        touches[bg.label(0, y) as usize] = true;
        touches[bg.label(w - 1, y) as usize] = true;
    }
    let data = mask
        .data()
        .iter()
        .zip(bg.labels())
        .map(|(&m, &l)| m || !touches[l as usize])
        .collect();
    Mask::from_vec(w, h, data).expect("same size as the input")
}
