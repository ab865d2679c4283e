//! Projector-side images of a dataset (docs/architecture.md, "Dataset layout"): the sampling
//! images of `train/` and `test/`, the reference images of `ref/` (5×5×5 colour cube and the gray
//! image `x0`), and the Gray-code structured light of `sl/` with its decoder.
//!
//! Everything here is in projector space (`Rgb<Projector>`), RGB in \[0,1\], and deterministic: the
//! sampling images from `(seed, set, index)`, the rest from their parameters alone. Sampling and
//! reference images are generated at network size (the dataset stores them so); structured light
//! at projector resolution.

pub mod graycode;
pub mod sampling;
pub mod setup;

pub use graycode::{Correspondence, DecodeParams, Decoder, GrayCode, PatternKind};
pub use sampling::{Set, sampling_image};
pub use setup::{SETUP_PATTERNS, SetupPattern};

use crate::error::{Error, Result};
use crate::raster::PrjImage;

/// The five 8-bit levels of the reference colour cube: {0, 64, 128, 191, 255}.
pub const CUBE_LEVELS: [u8; 5] = [0, 64, 128, 191, 255];
/// Number of colour cube images (`ref/img_0001..img_0125`).
pub const CUBE_COUNT: usize = 125;
/// Default 8-bit level of the gray image `x0` (the official datasets use about 77/255).
pub const DEFAULT_GRAY_LEVEL: u8 = 77;

/// The colour of cube image `index` (1-based, 1..=125) as 8-bit levels.
///
/// `index = 1 + 25·r + 5·g + b` with `r, g, b ∈ 0..5` indexing [`CUBE_LEVELS`]: blue varies
/// fastest, red slowest. So `img_0001` is black (0,0,0), `img_0002` is (0,0,64), `img_0006` is
/// (0,64,0), `img_0026` is (64,0,0) and `img_0125` is white (255,255,255) — the indices of the
/// black and white reference captures ([`crate::dataset::Reference`]).
pub fn cube_colour(index: usize) -> Result<[u8; 3]> {
    if !(1..=CUBE_COUNT).contains(&index) {
        return Err(Error::Input(format!(
            "colour cube index {index} out of range 1..={CUBE_COUNT}"
        )));
    }
    let i = index - 1;
    Ok([
        CUBE_LEVELS[i / 25],
        CUBE_LEVELS[(i / 5) % 5],
        CUBE_LEVELS[i % 5],
    ])
}

/// Cube image `index` (1-based, see [`cube_colour`]): a flat `width × height` image.
pub fn color_cube(index: usize, width: usize, height: usize) -> Result<PrjImage> {
    let c = cube_colour(index)?;
    Ok(PrjImage::filled(width, height, c.map(|v| v as f32 / 255.0)))
}

/// The gray image `x0`: a flat image at 8-bit `level` (`level / 255` in every channel).
pub fn gray_image(level: u8, width: usize, height: usize) -> PrjImage {
    PrjImage::filled(width, height, [level as f32 / 255.0; 3])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_indexing() {
        use crate::dataset::Reference;
        assert_eq!(cube_colour(Reference::Black.index()).unwrap(), [0, 0, 0]);
        assert_eq!(
            cube_colour(Reference::White.index()).unwrap(),
            [255, 255, 255]
        );
        assert_eq!(cube_colour(2).unwrap(), [0, 0, 64]);
        assert_eq!(cube_colour(6).unwrap(), [0, 64, 0]);
        assert_eq!(cube_colour(26).unwrap(), [64, 0, 0]);
        // r = 3, g = 1, b = 4.
        assert_eq!(cube_colour(1 + 25 * 3 + 5 + 4).unwrap(), [191, 64, 255]);
        assert!(cube_colour(0).is_err());
        assert!(cube_colour(126).is_err());
        // Every colour appears exactly once.
        let mut all: Vec<[u8; 3]> = (1..=125).map(|i| cube_colour(i).unwrap()).collect();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), 125);
    }

    #[test]
    fn flat_images() {
        let img = color_cube(26, 4, 3).unwrap();
        assert_eq!(img.size(), crate::raster::ImageSize::new(4, 3));
        assert!(img.data().chunks(3).all(|p| p == [64.0 / 255.0, 0.0, 0.0]));
        let g = gray_image(77, 5, 2);
        assert!(g.data().iter().all(|&v| v == 77.0 / 255.0));
    }
}
