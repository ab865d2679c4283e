//! Closed-loop scoring on the rig: project, capture, compare with the desired image inside the
//! displayable area (the paper protocol's metrics, docs/architecture.md, "Models", on the cropped
//! area), and the three reference rows every method is compared with.

use serde::{Deserialize, Serialize};

use super::oracle::OracleOptions;
use super::physics::Simulator;
use crate::error::{Error, Result};
use crate::metrics::{Accumulator, Scores};
use crate::raster::{CamImage, Camera, ImageSize, Mask, PrjImage, Rect};

/// The camera frames closed-loop scoring captures: projector image k is seen as the mean of
/// `average` frames from `first + k·average` on, each with its own noise, as `compend
/// calibrate`'s verification averages frames (`average = 1`: frames `first`, `first + 1`, …).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frames {
    pub first: u64,
    pub average: usize,
}

impl Frames {
    /// One frame per image from `first` on.
    pub const fn single(first: u64) -> Self {
        Frames { first, average: 1 }
    }

    /// The capture of `prj` shown as the `k`-th image.
    pub fn capture(&self, sim: &Simulator, prj: &PrjImage, k: usize) -> Result<CamImage> {
        let n = self.average.max(1);
        sim.capture_mean(prj, self.first + (k * n) as u64, n)
    }
}

/// Captures each projector image (the frames of `frames`) and scores the captures against the
/// desired camera images inside `area` (camera pixels).
pub fn closed_loop(
    sim: &Simulator,
    shown: &[PrjImage],
    desired: &[CamImage],
    area: Rect,
    frames: Frames,
) -> Result<Scores> {
    if shown.len() != desired.len() {
        return Err(Error::Input(format!(
            "closed-loop scoring needs one desired image per projected image, got {} and {}",
            desired.len(),
            shown.len()
        )));
    }
    let mut acc = Accumulator::default();
    for (k, (p, z)) in shown.iter().zip(desired).enumerate() {
        let cap = frames.capture(sim, p, k)?;
        acc.add(&cap.crop(area)?, &z.crop(area)?)?;
    }
    acc.finish()
}

/// The reference rows of a scene: what the viewer sees without compensation, with the true
/// geometry but no colour correction, and with the oracle (the physical ceiling).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceScores {
    pub uncompensated: Scores,
    pub geometry_only: Scores,
    pub oracle: Scores,
}

/// The pixels of `area` as a camera-space mask of the simulator's camera size.
pub fn area_mask(sim: &Simulator, area: Rect) -> Mask<Camera> {
    let ImageSize {
        width: w,
        height: h,
    } = sim.camera_size();
    Mask::from_fn(w, h, |x, y| area.contains(x, y))
}

/// Scores the three reference rows on a test set. `uncompensated[k]` is test image k placed on
/// the canvas as is (projector space); `desired[k]` is the same image placed in the displayable
/// area `area` (camera space, its edge carried [`crate::fov::EDGE_MARGIN_PX`] outward, black
/// elsewhere). All three rows use the same `frames`, so they
/// see the same noise.
pub fn reference_scores(
    sim: &Simulator,
    uncompensated: &[PrjImage],
    desired: &[CamImage],
    area: Rect,
    opts: OracleOptions,
    frames: Frames,
) -> Result<ReferenceScores> {
    reference_scores_with_oracle(sim, uncompensated, desired, area, opts, frames)
        .map(|(scores, _)| scores)
}

/// The reference rows of a scored rig, as `compend sim score` and `compend bench` print them:
/// the uncompensated projection, geometry alone, the oracle at the network's resolution and the
/// oracle, with the oracle's projector images (for its camera views).
pub struct References {
    pub scores: ReferenceScores,
    /// The oracle's projector images brought down to the network's resolution over the canvas
    /// and back ([`oracle_at_network`]).
    pub oracle_at_network: Scores,
    pub oracle_images: Vec<PrjImage>,
}

/// [`References`] of the test images `uncompensated` (on the canvas `canvas`, projector space)
/// and their desired views `desired` in the displayable area `area`, for a model of `network`
/// pixels. Every row uses the same `frames` (captures are numbered, so the order rows are
/// scored in changes nothing).
pub fn references(
    sim: &Simulator,
    uncompensated: &[PrjImage],
    desired: &[CamImage],
    area: Rect,
    (canvas, network): (Rect, ImageSize),
    opts: OracleOptions,
    frames: Frames,
) -> Result<References> {
    let (scores, oracle_images) =
        reference_scores_with_oracle(sim, uncompensated, desired, area, opts, frames)?;
    let oracle_at_network =
        oracle_at_network(sim, &oracle_images, desired, area, canvas, network, frames)?;
    Ok(References {
        scores,
        oracle_at_network,
        oracle_images,
    })
}

/// [`reference_scores`], also returning the oracle's projector images (for further rows).
pub fn reference_scores_with_oracle(
    sim: &Simulator,
    uncompensated: &[PrjImage],
    desired: &[CamImage],
    area: Rect,
    opts: OracleOptions,
    frames: Frames,
) -> Result<(ReferenceScores, Vec<PrjImage>)> {
    let mask = area_mask(sim, area);
    let geometry: Vec<PrjImage> = desired
        .iter()
        .map(|z| sim.geometry_only(z))
        .collect::<Result<_>>()?;
    let oracle: Vec<PrjImage> = desired
        .iter()
        .map(|z| sim.oracle(z, &mask, opts))
        .collect::<Result<_>>()?;
    let scores = ReferenceScores {
        uncompensated: closed_loop(sim, uncompensated, desired, area, frames)?,
        geometry_only: closed_loop(sim, &geometry, desired, area, frames)?,
        oracle: closed_loop(sim, &oracle, desired, area, frames)?,
    };
    Ok((scores, oracle))
}

/// The oracle limited to network resolution: each oracle projector image's canvas region is
/// area-resized to `network` size and placed back on the canvas as a compensation image would be.
/// What remains between a network-space model and this row is the model; what lies between this
/// row and the oracle is the network resolution itself.
pub fn oracle_at_network(
    sim: &Simulator,
    oracle: &[PrjImage],
    desired: &[CamImage],
    area: Rect,
    canvas: Rect,
    network: ImageSize,
    frames: Frames,
) -> Result<Scores> {
    let psize = sim.projector_size();
    let shown: Vec<PrjImage> = oracle
        .iter()
        .map(|o| {
            let region = o.crop(canvas)?;
            let small = crate::resize::resize_area(&region, network.width, network.height);
            crate::playback::place_on_canvas(&small, canvas, psize)
        })
        .collect::<Result<_>>()?;
    closed_loop(sim, &shown, desired, area, frames)
}
