//! The header-level summary of a setup and its data root ([`crate::dataset::Setup::info`],
//! docs/architecture.md, "Dataset layout"): sizes, image counts per set, which references are
//! present, compensated models. Sizes are (width, height) in pixels of the space named.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::raster::ImageSize;

/// Image counts per set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SetCounts {
    pub train: usize,
    pub test: usize,
    #[serde(rename = "ref")]
    pub refs: usize,
    pub sl: usize,
}

/// Which named reference captures are present.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct References {
    pub black: bool,
    pub white: bool,
    pub gray: bool,
}

/// Summary of a setup and its data root.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SetupInfo {
    /// The data root (absolute).
    pub root: PathBuf,
    /// The setup folder relative to the root (`.` when it is the root itself); absolute when the
    /// setup lies outside an explicitly named root.
    pub setup: PathBuf,
    /// Camera size: the size of the black reference capture (unknown when it is unreadable).
    pub camera_size: Option<ImageSize>,
    /// Network size: the size of `ROOT/train/img_0001.png` (else `ROOT/test/img_0001.png`).
    pub network_size: Option<ImageSize>,
    /// Projector size: the size of `ROOT/sl/img_0001.png` (unknown without patterns).
    pub projector_size: Option<ImageSize>,
    /// Projector images in the root: train and test (contiguous from 1), ref cube, sl patterns.
    pub projector_images: SetCounts,
    /// Whether `ROOT/ref/img_gray.png` (the gray image x0) is present.
    pub gray_input: bool,
    /// Captures in `cam/raw/*`. Train, test and sl count the contiguous run from `img_0001`;
    /// ref counts every indexed file (only black, white and gray are required).
    pub captures: SetCounts,
    /// Which named reference captures are present.
    pub references: References,
    /// Number of desired images in `cam/desire/test`; `None` when the folder does not exist.
    pub desired_test: Option<usize>,
    /// Training pairs with a desired view in `cam/desire/train` (closed-loop pairs), sorted.
    pub loop_pairs: Vec<usize>,
    /// Model names under `prj/cmp/test/` (sorted).
    pub compensated: Vec<String>,
}
