//! How a model was trained (`model.json`'s `training` and `timings`): the data, the settings,
//! the results, and `--method auto`'s evidence as figures. The evidence in words is beside `auto`
//! ([`crate::fit::evidence_lines`]); the frame-budget rule a live cost is weighed by is in
//! [`crate::fit::live`].

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::method::Method;
use crate::raster::ImageSize;

/// How a model was trained (`model.json`'s `training`). Every field has a default, so the
/// records of earlier builds (format version 1) still load; fields of one family are absent
/// from the other's record.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainingRecord {
    /// The setup folder trained on (as given to `train --setup`).
    #[serde(default)]
    pub setup: Option<PathBuf>,
    /// The data root holding the projector-side images.
    #[serde(default)]
    pub data_root: Option<PathBuf>,
    /// Training pairs used.
    #[serde(default)]
    pub ntrain: usize,
    /// Seed of every random choice of the fit.
    #[serde(default)]
    pub seed: u64,
    /// What the FOV detection measured ([`crate::fov::FovDiagnostics`], as written).
    #[serde(default)]
    pub fov: serde_json::Value,
    /// Bounding box of the projector FOV, camera pixels.
    #[serde(default)]
    pub fov_bbox: Option<crate::raster::Rect>,
    /// The rung's own settings as written ([`crate::linear::FitSettings`] for the linear rungs,
    /// [`crate::nn::train::Settings`] for the CompenNet++ family).
    #[serde(default)]
    pub settings: serde_json::Value,
    /// The training loss at the end (`None` when it was not finite).
    #[serde(default)]
    pub final_loss: Option<f64>,
    /// Linear rungs: the fitted response curves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curves: Option<crate::linear::Curves>,
    /// `--method auto`: the rule, the held-out figures and the choice.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auto: Option<AutoEvidence>,
    /// CompenNet++: iterations run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
    /// CompenNet++: batch size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch: Option<usize>,
    /// CompenNet++: iterations between learning-rate drops.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lr_step: Option<usize>,
    /// CompenNet++: where it trained.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<crate::nn::device::TrainDevice>,
    /// CompenNet++: where the geometry started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry_init: Option<String>,
    /// CompenNet++: where CompenNet's weights started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub photometric_init: Option<String>,
    /// A residual rung: the pairs its correction trained on, and how.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correction: Option<String>,
    /// `linear` (also the residual rung's linear part): its geometry was taken from an earlier
    /// fit of the same `auto` or calibration on the same first pairs
    /// ([`crate::linear::GeometryMemo`]), so its fit time leaves the geometry out.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub geometry_reused: bool,
    /// A linear rung: its response curves were searched on the first this many pairs (those of
    /// the geometry, [`crate::linear::FitSettings::geometry_images`]), its coefficients on all
    /// `ntrain`, so that a fit grown pair by pair as a calibration's captures arrive
    /// ([`crate::fit::GrowingFit`]) is the fit on all of them. Absent in records written
    /// before 2026-12-03, whose curves were searched on every pair.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curves_searched_on: Option<usize>,
}

/// The evidence of `--method auto`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoEvidence {
    /// The selection rule, in words.
    pub rule: String,
    /// The rung chosen.
    pub chosen: Method,
    /// Why no comparison was run (too few pairs, no structured light), if none was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
    /// Training pairs held out for the comparison.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out: Option<usize>,
    /// Training pairs the candidates were fitted on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fitted_on: Option<usize>,
    /// The PSNR gain (dB) the CompenNet++ rung needed over the best linear rung.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub required_gain_db: Option<f64>,
    /// Each candidate's held-out figures.
    #[serde(default)]
    pub candidates: Vec<AutoCandidate>,
    /// `calibrate` only, when the held-out pairs chose a CompenNet++ rung: that rung and the
    /// best linear rung, each projected compensated on the same test images and captured
    /// (closed loop, camera pixels in the displayable area). The climbed rung is kept only if
    /// it beats the linear one there by the same margin.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub closed_loop: Vec<ClosedLoopScore>,
    /// When the setup has closed-loop pairs and the climb rung is a residual rung: the climb
    /// judged on closed-loop pairs held out of its training ([`LoopHeldOut`]), not on the
    /// paper protocol; `candidates` then holds the linear rungs alone (none when `linear` is
    /// the only one, `why` says so).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_held_out: Option<LoopHeldOut>,
    /// When the climb was judged on held-out sampling pairs (its figures are among
    /// `candidates`): how the climb rung's training went there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judged: Option<JudgedTraining>,
    /// When it climbed: the training of the model kept (the judged one saw fewer pairs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retrained: Option<Retrained>,
    /// The climb rung's live pass timed on the GPU that is to play it, when the caller asked
    /// for it (`calibrate` through a projector window, `train --refresh-hz`): a rung whose pass
    /// does not fit the frame budget is not climbed to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub live: Option<LiveCost>,
}

/// `auto`'s climb judged on closed-loop pairs held out of training: each held-out pair's
/// desired view compensated by `linear` (the climbed rung's own linear part) and by the
/// climbed rung, against the projector image that moves the pair's capture towards the view
/// (the first-order target the correction trains on, blended to `linear`'s output outside the
/// displayable area; projector images at the network size). It asks what closed loop asks,
/// unlike held-out sampling captures. It is in projector pixels, so it is not the camera's
/// gain: it mostly overstated that gain where the surface is dark (+1.40 dB here, +0.29 on
/// the rig for a dark texture), though it understated it on another dark texture (+0.14
/// against +0.27; docs/bench/ladder.md). So `calibrate` checks a climb on the rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopHeldOut {
    /// Closed-loop pairs held out (the setup's last ones).
    pub pairs: usize,
    /// Closed-loop pairs the climbed rung's correction trained on.
    pub trained_on: usize,
    /// `linear`, then the climbed rung: PSNR (dB) and SSIM against the targets, and the
    /// climbed rung's training time (`linear`'s is part of it: 0).
    pub scores: Vec<AutoCandidate>,
    /// How its judged training went: the last point of its curve gives `scores`.
    #[serde(flatten)]
    pub training: JudgedTraining,
}

impl LoopHeldOut {
    /// The held-out PSNR (dB) of the climbed rung and of `linear`, in that order; not a number
    /// where a score is missing (a climb never follows from one).
    pub fn figures(&self) -> (f64, f64) {
        let psnr = |i: usize| self.scores.get(i).map_or(f64::NAN, |c| c.held_out_psnr);
        (psnr(1), psnr(0))
    }
}

/// A climb rung's training while `auto` judged it on held-out pairs, scored as it went
/// ([`crate::fit::ClimbRule`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JudgedTraining {
    /// The planned iterations (0 in records written before this was recorded).
    #[serde(default)]
    pub iterations: usize,
    /// The iteration it stopped at when its held-out gain could no longer reach the margin
    /// ([`crate::fit::ClimbRule::out_of_reach`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped_at: Option<usize>,
    /// The iteration it stopped at when its held-out gain had settled at or above the margin
    /// ([`crate::fit::ClimbRule::settled`]): the rung climbs. Neither this nor `stopped_at`:
    /// it ran to the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settled_at: Option<usize>,
    /// Its PSNR (dB) on the held-out pairs as it trained, its output computed as inference
    /// computes it: at iteration 0 (its correction at zero, so its own linear part's figure)
    /// and every tenth of its iterations.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub curve: Vec<LoopCheckpoint>,
}

impl JudgedTraining {
    /// Where it stopped and why, in words after a `;`; empty when it ran to the end.
    pub fn stop(&self) -> String {
        match (self.stopped_at, self.settled_at) {
            (Some(at), _) => format!(
                "; its training stopped at iteration {at} of {}, its gain out of reach of the \
                 margin",
                self.iterations
            ),
            (None, Some(at)) => format!(
                "; its training stopped at iteration {at} of {}, its gain settled past the \
                 margin",
                self.iterations
            ),
            (None, None) => String::new(),
        }
    }
}

/// The model `auto` keeps after a climb (unless the rig then keeps the linear rung): the
/// climbed rung trained from its start, with the request's settings and seed, on every pair of
/// its kind (every pair with closed-loop pairs; the sampling pairs, without closed-loop pairs
/// after them, otherwise). Offline, it is trained again after it was judged on held-out pairs,
/// the held-out ones now included; under `calibrate` it is trained once, for the rig to judge.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Retrained {
    /// The climbed rung (the rig may still keep the linear rung instead: `chosen`).
    pub method: Method,
    /// Training pairs.
    pub pairs: usize,
    /// Time of this training, seconds.
    pub seconds: f64,
    /// Whether a training judged on held-out pairs came first (false: the rig judges this
    /// training alone). Records of earlier builds, which always judged first, read as true.
    #[serde(default = "judged_first")]
    pub after_judgement: bool,
}

fn judged_first() -> bool {
    true
}

/// One point of [`LoopHeldOut::curve`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopCheckpoint {
    /// Optimiser steps taken.
    pub iteration: usize,
    /// PSNR (dB) against the held-out targets.
    pub psnr: f64,
}

/// One rung's closed-loop verification in `auto`'s confirmation on the rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClosedLoopScore {
    pub method: Method,
    /// PSNR (dB) and SSIM of the compensated projection as captured.
    pub psnr: f64,
    pub ssim: f64,
    /// Whether this rung alone would have been installed (gain over the uncompensated
    /// projection, no failure).
    pub passed: bool,
}

impl AutoEvidence {
    /// The linear candidate with the best held-out PSNR: the rung `auto` falls back to.
    pub fn best_linear(&self) -> Option<&AutoCandidate> {
        self.candidates
            .iter()
            .filter(|c| c.method.is_linear())
            .max_by(|a, b| a.held_out_psnr.total_cmp(&b.held_out_psnr))
    }
}

/// One candidate rung of `--method auto` on the held-out pairs (paper protocol).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoCandidate {
    pub method: Method,
    /// PSNR in dB.
    pub held_out_psnr: f64,
    pub held_out_ssim: f64,
    /// Time to fit (or train) the candidate, seconds.
    pub fit_seconds: f64,
}

/// Timings of the training (`model.json`'s `timings`), seconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// The fit alone.
    #[serde(default)]
    pub fit_seconds: f64,
    /// The whole training, loading included.
    #[serde(default)]
    pub train_seconds: f64,
    /// CompenNet++: wall time per training sample, milliseconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ms_per_sample: Option<f64>,
}

/// What a rung's compensation pass costs per frame on the GPU that is to play it, against the
/// display's refresh ([`crate::fit::LivePass`]; the budget by [`crate::fit::live::LIVE_SHARE`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LiveCost {
    /// The rung timed.
    pub method: Method,
    /// The adapter it was timed on, in words.
    pub adapter: String,
    /// The projector frame the pass wrote, projector pixels.
    #[serde(with = "crate::raster::as_pair")]
    pub projector: ImageSize,
    /// The median time of its whole pass per frame (content frame to projector frame), ms:
    /// GPU timestamps where the adapter has them, else submit to idle.
    pub pass_ms: f64,
    /// The display's refresh rate, Hz.
    pub refresh_hz: f64,
    /// What the pass may take, ms.
    pub budget_ms: f64,
}

impl LiveCost {
    /// Whether the pass fits its budget; a time that is not a number never does.
    pub fn fits(&self) -> bool {
        self.pass_ms.is_finite() && self.pass_ms <= self.budget_ms
    }

    /// The measurement in words, for logs and records.
    pub fn describe(&self) -> String {
        let share = self.budget_ms * self.refresh_hz / 1e3;
        let share = if (share - 0.5).abs() < 1e-9 {
            "half".to_string()
        } else {
            readable(share)
        };
        format!(
            "{}'s live pass takes {} ms per {} frame on {}, {} the {} ms budget ({share} of one \
             refresh period at {} Hz)",
            self.method,
            readable(self.pass_ms),
            self.projector,
            self.adapter,
            if self.fits() { "within" } else { "over" },
            readable(self.budget_ms),
            readable(self.refresh_hz)
        )
    }
}

/// `v` with two decimals, in scientific notation when that would print many digits or none.
pub fn readable(v: f64) -> String {
    if v == 0.0 || (0.01..1e6).contains(&v.abs()) {
        format!("{v:.2}")
    } else {
        format!("{v:.2e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_judgement_on_closed_loop_pairs_reads_as_written_before_and_now() {
        // As a model written before `iterations` and `settled_at` were recorded has it.
        let older = r#"{"pairs": 4, "trained_on": 8, "scores": [],
            "stopped_at": 300, "curve": [{"iteration": 0, "psnr": 30.5}]}"#;
        let l: LoopHeldOut = serde_json::from_str(older).unwrap();
        assert_eq!(l.training.iterations, 0);
        assert_eq!(l.training.stopped_at, Some(300));
        assert_eq!(l.training.settled_at, None);
        assert_eq!(l.training.curve.len(), 1);
        assert!(l.training.stop().contains("out of reach"));
        // No scores: figures that climb nowhere.
        let (up, lin) = l.figures();
        assert!(up.is_nan() && lin.is_nan());
        // Now: the judged training's fields sit beside the pairs, as before.
        let now = LoopHeldOut {
            training: JudgedTraining {
                iterations: 1000,
                settled_at: Some(300),
                ..l.training.clone()
            },
            ..l
        };
        let json = serde_json::to_value(&now).unwrap();
        assert_eq!(json["settled_at"], 300, "{json}");
        assert_eq!(json["iterations"], 1000, "{json}");
        assert!(json.get("training").is_none(), "{json}");
        assert_eq!(serde_json::from_value::<LoopHeldOut>(json).unwrap(), now);
        // Out of reach is said first: it is the one that stopped the training.
        assert!(now.training.stop().contains("out of reach"));
        let settled = JudgedTraining {
            stopped_at: None,
            ..now.training
        };
        assert!(settled.stop().contains("settled past the margin"));
        assert_eq!(JudgedTraining::default().stop(), "");
    }
}
