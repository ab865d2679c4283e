//! Closed-loop scores of a set's joint model on the virtual rig against the set's physical
//! ceiling ([`SetSimulator::oracle`]), with each projector compensating alone and the seam
//! figure of both (`compend sim set-score`): how far the joint compensation is from what the
//! set's light could show, on the views its calibration verified.

use serde::Serialize;

use super::oracle::OracleOptions;
use super::physics::SetSimulator;
use crate::error::{Error, Result};
use crate::fov;
use crate::joint::JointModel;
use crate::metrics::{Accumulator, Scores, SeamFigure};
use crate::model::Model;
use crate::playback::place_on_canvas;
use crate::raster::{CamImage, Camera, ImageSize, Mask, NetImage, PrjImage, Rect};

/// Camera frames the set's scores capture from (apart from the calibration's and the sheets').
const FRAMES_SET_SCORE: u64 = 7_300_000;

/// The rows of a set's score.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SetScore {
    pub images: usize,
    /// The joint model, and the set's physical ceiling, in closed loop over the area.
    pub joint: Scores,
    pub ceiling: Scores,
    /// Each projector compensating alone with its own model, the others black.
    pub alone: Vec<Scores>,
    /// The seam figures of the joint model's and the ceiling's pictures (mean over the
    /// images); `None` where no overlap edge crosses the area.
    pub joint_seam: Option<SeamFigure>,
    pub ceiling_seam: Option<SeamFigure>,
    /// The share of the area (percent) the set cannot compensate in its display range, by the
    /// captures under black and white ([`fov::reach`]); each projector alone (its own white,
    /// the others black) in its own display range, and in the set's (the views the set
    /// shows).
    pub unreachable_percent: f64,
    pub alone_unreachable_percent: Vec<f64>,
    pub alone_unreachable_at_set_range_percent: Vec<f64>,
}

/// Scores `joint` (with the projectors' own `models`) on `set` for the desired views
/// `desired` (camera pixels) inside `area`.
pub fn score_set(
    set: &SetSimulator,
    (joint, models): (&JointModel, &[Model]),
    desired: &[CamImage],
    area: Rect,
    opts: OracleOptions,
) -> Result<SetScore> {
    let n = set.projectors().len();
    if joint.projectors() != n || models.len() != n {
        return Err(Error::Input(format!(
            "a model of {} projectors for a set of {n}",
            joint.projectors()
        )));
    }
    if desired.is_empty() {
        return Err(Error::Input("no desired views to score".into()));
    }
    let camera = set.camera_size();
    let sizes: Vec<ImageSize> = set
        .projectors()
        .iter()
        .map(|p| p.projector_size())
        .collect();
    let black: Vec<PrjImage> = sizes
        .iter()
        .map(|s| PrjImage::new(s.width, s.height))
        .collect();
    let placed = |k: usize, img: &NetImage| -> Result<PrjImage> {
        place_on_canvas(img, Rect::covering(sizes[k]), sizes[k])
    };
    let inside = Mask::<Camera>::from_fn(camera.width, camera.height, |x, y| area.contains(x, y));
    let covers: Vec<Mask<Camera>> = set.projectors().iter().map(|p| p.lit_mask()).collect();
    let (band, away) =
        crate::joint::seam_regions(&covers, &inside, crate::joint::seam::band_px(camera));
    let overlapping = band.data().iter().any(|&b| b) && away.data().iter().any(|&b| b);
    let mut frame = FRAMES_SET_SCORE;
    let mut capture = |images: &[PrjImage]| {
        frame += 1;
        set.capture(images, frame)
    };
    let (mut j_acc, mut c_acc) = (Accumulator::default(), Accumulator::default());
    let mut alone_acc: Vec<Accumulator> = (0..n).map(|_| Accumulator::default()).collect();
    let (mut j_seams, mut c_seams) = (Vec::new(), Vec::new());
    for view in desired {
        let want = view.crop(area)?;
        let outs = joint.apply(view)?;
        let frames = outs
            .iter()
            .enumerate()
            .map(|(k, o)| placed(k, o))
            .collect::<Result<Vec<_>>>()?;
        let seen = capture(&frames)?;
        j_acc.add(&seen.crop(area)?, &want)?;
        let best = set.oracle(view, &inside, opts)?;
        let top = capture(&best)?;
        c_acc.add(&top.crop(area)?, &want)?;
        if overlapping {
            j_seams.push(crate::metrics::seam_figure(
                &seen,
                view,
                band.data(),
                away.data(),
            )?);
            c_seams.push(crate::metrics::seam_figure(
                &top,
                view,
                band.data(),
                away.data(),
            )?);
        }
        for k in 0..n {
            let mut frames = black.clone();
            frames[k] = placed(k, &models[k].infer(view)?)?;
            alone_acc[k].add(&capture(&frames)?.crop(area)?, &want)?;
        }
    }
    let white_all = set.uniform(1.0);
    let black_cap = set.capture(&black, FRAMES_SET_SCORE - 2)?;
    let range_of =
        |white: &CamImage| fov::display_range(&black_cap, white, area, fov::DESIRED_RANGE_QUANTILE);
    let unreachable = |white: &CamImage, range: fov::DisplayRange| -> Result<f64> {
        Ok(fov::reach(&black_cap, white, area, range)?
            .summary()
            .unreachable_percent)
    };
    let set_white = set.capture(&white_all, FRAMES_SET_SCORE - 1)?;
    let set_range = range_of(&set_white)?;
    let mut alone_own = Vec::with_capacity(n);
    let mut alone_set = Vec::with_capacity(n);
    for k in 0..n {
        let mut frames = black.clone();
        frames[k] = white_all[k].clone();
        let white = set.capture(&frames, FRAMES_SET_SCORE - 3 - k as u64)?;
        alone_own.push(unreachable(&white, range_of(&white)?)?);
        alone_set.push(unreachable(&white, set_range)?);
    }
    Ok(SetScore {
        images: desired.len(),
        joint: j_acc.finish()?,
        ceiling: c_acc.finish()?,
        alone: alone_acc
            .iter()
            .map(Accumulator::finish)
            .collect::<Result<_>>()?,
        joint_seam: SeamFigure::mean(&j_seams),
        ceiling_seam: SeamFigure::mean(&c_seams),
        unreachable_percent: unreachable(&set_white, set_range)?,
        alone_unreachable_percent: alone_own,
        alone_unreachable_at_set_range_percent: alone_set,
    })
}
