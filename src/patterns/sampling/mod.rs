//! Sampling images: colourful textured projector images `x_i` for training and testing.
//!
//! Each image is generated from its own random stream, derived from `(seed, set, index)` alone, so
//! image `i` of a set can be made without making images `0..i`, and the training and test sets
//! are independent streams (they never share an image). The generator is value-stable: ChaCha8
//! streams, integer hashing and f32 arithmetic in a fixed order, no platform-dependent parts
//! beyond the libm functions (`sin`, `exp`, `powf`, `tanh`).
//!
//! Content: every image is built in resolution-independent coordinates (the same seed at another
//! size gives the same picture resampled, up to aliasing of the finest stripes and per-pixel
//! grain), from scalar
//! fields — linear and radial gradients, sine/triangle/square stripes at several scales and angles,
//! rotated checkers, spirals, fractal value noise (plain, ridged, turbulent), Gaussian blobs,
//! Voronoi cells, products and domain-warped versions of these — turned into colour by one of
//! several mappings (independent channels, a random channel mix, a colour ramp through vivid
//! colours, HSV), optionally layered through a soft mask, then given a random tone curve per
//! channel (robust stretch with some clipping, gamma, S-curve, inversion), and occasionally grain,
//! posterisation and flat patches of extreme colours (black, white, saturated primaries and
//! secondaries). Over a few dozen images every pixel sees dark and bright values in every channel
//! and the per-pixel joint RGB distribution is full-rank (see the coverage test in
//! `tests/patterns.rs`).
//!
//! Modules: `field` (scalar fields and value noise), `random` (random parameters and random
//! fields), `compose` (colour mappings, layering, tone curves and extras). Images are projector
//! images of the requested size (projector space; the dataset stores them at network size).

use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;

use crate::raster::PrjImage;

mod compose;
mod field;
mod random;
#[cfg(test)]
mod tests;

use compose::compose;
use field::Field;

/// Which set a sampling image belongs to. The sets use independent random streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Set {
    /// `ROOT/train/`: the sampling images `x_i` the models are trained on.
    Train,
    /// `ROOT/test/`: the validation images `y_i`.
    Test,
}

impl Set {
    /// The dataset folder name: `train` or `test`.
    pub fn folder(self) -> &'static str {
        match self {
            Set::Train => "train",
            Set::Test => "test",
        }
    }

    /// The dataset set it is stored in.
    pub fn projector_set(self) -> crate::dataset::ProjectorSet {
        match self {
            Set::Train => crate::dataset::ProjectorSet::Train,
            Set::Test => crate::dataset::ProjectorSet::Test,
        }
    }

    fn tag(self) -> u64 {
        match self {
            Set::Train => 0x7472_6169_6e00_0001, // "train"
            Set::Test => 0x7465_7374_0000_0002,  // "test"
        }
    }
}

/// The random stream of one sampling image: ChaCha8 keyed by a domain constant, the seed, the
/// set and the index (each as 8 little-endian bytes of the 32-byte key).
fn stream(seed: u64, set: Set, index: usize) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[0..8].copy_from_slice(b"cmpdSMPL");
    key[8..16].copy_from_slice(&seed.to_le_bytes());
    key[16..24].copy_from_slice(&set.tag().to_le_bytes());
    key[24..32].copy_from_slice(&(index as u64).to_le_bytes());
    ChaCha8Rng::from_seed(key)
}

/// Sampling image `index` (0-based; stored as `img_{index+1:04}.png`) of `set` for `seed`, at
/// `width × height` pixels, RGB in \[0,1\]. Deterministic: the same arguments always give the same
/// image, and an image depends on no other index.
pub fn sampling_image(seed: u64, set: Set, index: usize, width: usize, height: usize) -> PrjImage {
    let mut rng = stream(seed, set, index);
    let canvas = Canvas::new(width, height);
    let channels = compose(&mut rng, &canvas);
    let mut data = Vec::with_capacity(canvas.len() * 3);
    for i in 0..canvas.len() {
        for ch in &channels {
            data.push(ch[i].clamp(0.0, 1.0));
        }
    }
    PrjImage::from_vec(width, height, data).expect("three channels of width × height values")
}

// ---------------------------------------------------------------------------------------------
// Coordinates

/// Pixel centres in resolution-independent coordinates: the image centre is the origin and the
/// longer side spans one unit, so `u ∈ [-0.5, 0.5]` for a square image.
struct Canvas {
    width: usize,
    height: usize,
    coords: Vec<[f32; 2]>,
}

impl Canvas {
    fn new(width: usize, height: usize) -> Self {
        let s = width.max(height).max(1) as f32;
        let mut coords = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                coords.push([
                    (x as f32 + 0.5 - width as f32 / 2.0) / s,
                    (y as f32 + 0.5 - height as f32 / 2.0) / s,
                ]);
            }
        }
        Self {
            width,
            height,
            coords,
        }
    }

    fn len(&self) -> usize {
        self.width * self.height
    }

    /// A scalar field sampled at every pixel, stretched to [0,1] between its 0.5 % and 99.5 %
    /// quantiles (clipped outside).
    fn render(&self, f: &Field) -> Vec<f32> {
        let mut v: Vec<f32> = self.coords.iter().map(|&p| f.eval(p)).collect();
        stretch(&mut v, 0.005, 0.995);
        v
    }
}

/// Maps the `q_lo` quantile of `v` to 0 and the `q_hi` quantile to 1, clipping outside. A
/// constant input becomes 0.5.
fn stretch(v: &mut [f32], q_lo: f32, q_hi: f32) {
    if v.is_empty() {
        return;
    }
    let mut sorted = v.to_vec();
    sorted.sort_unstable_by(f32::total_cmp);
    let at = |q: f32| sorted[((sorted.len() - 1) as f32 * q).round() as usize];
    let (lo, hi) = (at(q_lo), at(q_hi));
    if hi - lo > 1e-6 {
        for x in v.iter_mut() {
            *x = ((*x - lo) / (hi - lo)).clamp(0.0, 1.0);
        }
    } else {
        v.fill(0.5);
    }
}
