//! The settings of a `linear` fit (recorded in `model.json`'s `training.settings`).

use crate::raster::ImageSize;
use serde::{Deserialize, Serialize};

/// The most network pixels a geometry step evaluates by default ([`FitSettings::geometry_pixels`]):
/// 128², so the 256² level and the dense refinement run on every other pixel in each
/// direction. Measured on the demo's calibration data (curved, seed 1, 48 pairs, closed loop
/// with `sim score`): the geometry took 3.8 s instead of 7.1 s at 31.032 dB against 31.031;
/// 64² (every third and fourth pixel) took 2.4 s and lost 0.02 dB.
pub const GEOMETRY_PIXELS: usize = 128 * 128;

/// Training settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FitSettings {
    /// Network (output) size.
    #[serde(with = "crate::raster::as_pair")]
    pub network_size: ImageSize,
    /// Optimise the warp (false keeps the initial affine, e.g. for geometry from structured light).
    pub learn_geometry: bool,
    /// (network side, Gauss–Newton steps at most, capture blur σ in camera pixels) per
    /// coarse-to-fine level of the affine + TPS fit (a level stops earlier once a step gains
    /// less than 10⁻⁴ of its loss). Models written before 2026-12-03 record Adam iterations
    /// here ((64, 120, 2), (128, 60, 1), (256, 30, 0)).
    /// Measured closed loop on the rig (`train` on calibrations of four scenes, seeds 41–44):
    /// (12, 8, 6) steps were within ±0.02 dB of Adam's 210 iterations on the curved, white and
    /// dark-texture scenes and +3.5 dB on the step, whose depth edge Adam never reached; (8, 5,
    /// 4) lost 0.3 dB of that on the step.
    pub levels: Vec<(usize, usize, f32)>,
    /// Adam step size of the dense refinement's offsets (normalised coordinates).
    pub learning_rate: f32,
    /// Ridge weight pulling each pixel's coefficients towards the global model: a fixed prior
    /// strength in squared linear light, so the data outweighs it more as images are added.
    /// Measured closed loop on the rig with 48 images: 1e-2 per image (the earlier rule) cost
    /// 0.65 dB on the curved scene because dark, textured pixels were pulled to the global
    /// model. With 12 images the result moves by about ±0.4 dB with this weight, through the
    /// geometry's convergence rather than the colour fit.
    pub ridge: f32,
    /// Images used for the geometry and the response curves (the first ones; the per-pixel
    /// colour solve always uses all of them).
    pub geometry_images: usize,
    /// The residual refinement after affine + TPS: (node spacing in network pixels, Adam
    /// iterations) of a dense offset field ([`OffsetField`](crate::warp::OffsetField)); `None`
    /// keeps affine + TPS.
    /// Measured closed loop on the rig (seed 31, 48 images): the `step` scene's depth
    /// discontinuity 20.3 → 25.7 dB, `curved` +0.3 dB, `white-plane` and `dark-texture` ±0.05 dB,
    /// for 5–10 s more training (60 iterations at 256²).
    pub refine: Option<(usize, usize)>,
    /// The lattice of the colour model and of its output images, when it differs from
    /// `network_size` (`None`: the network size). The geometry is fitted at `network_size` and is
    /// resolution independent; only the per-pixel colour solve runs on the lattice, with the
    /// projector images resampled onto it. A network image stretched over an 800×600 canvas
    /// has fewer pixels across the displayable area than the desired image it should reproduce:
    /// measured closed loop on the rig's curved scene (seed 1, 48 images), 384² instead of 256²
    /// gains 0.46 dB and 512² nothing more, for about 1 s more training.
    #[serde(with = "crate::raster::as_pair_opt")]
    pub lattice: Option<ImageSize>,
    /// The most network pixels one geometry step evaluates (`None`: every pixel, as models
    /// written before this setting were fitted). A finer level is evaluated on every k-th pixel
    /// in each direction, k the smallest that fits, at an offset that moves each step, so every
    /// pixel counts over k² steps ([`Self::geometry_stride`]).
    #[serde(default)]
    pub geometry_pixels: Option<usize>,
    /// How the colour solve ends. Not recorded: a model's coefficients are always per pixel
    /// ([`ColourSolve::Global`] only seeds a fit that solves its own).
    #[serde(skip)]
    pub colour: ColourSolve,
}

/// How the colour solve of a `linear` fit ends.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ColourSolve {
    /// Each lattice pixel's coefficients, pulled towards one global model: the rung's model.
    #[default]
    PerPixel,
    /// The global model at every pixel, as the per-pixel solve estimates its prior: for a fit
    /// whose per-pixel coefficients a [`ColourSums`](super::ColourSums) solves from sums of its
    /// own (a calibration's fit grown behind the captures), where the per-pixel solve (0.5–0.6 s
    /// for 24 pairs at 800×600) would be thrown away.
    Global,
}

impl FitSettings {
    /// The pixel stride of a geometry step on a lattice of `pixels` network pixels: the smallest
    /// k ≥ 1 with `pixels / k² ≤ geometry_pixels`.
    pub fn geometry_stride(&self, pixels: usize) -> usize {
        match self.geometry_pixels {
            Some(most) if most > 0 => {
                let mut k = 1;
                while pixels.div_ceil(k * k) > most {
                    k += 1;
                }
                k
            }
            _ => 1,
        }
    }
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            network_size: ImageSize::new(256, 256),
            learn_geometry: true,
            levels: vec![(64, 12, 2.0), (128, 8, 1.0), (256, 6, 0.0)],
            learning_rate: 2e-3,
            ridge: 0.012,
            geometry_images: 24,
            refine: Some((4, 60)),
            lattice: None,
            geometry_pixels: Some(GEOMETRY_PIXELS),
            colour: ColourSolve::PerPixel,
        }
    }
}
