//! The model directory (docs/architecture.md, "Model directory"): `model.safetensors` holds every numeric array
//! (weights, or the baked grid and constants), `model.json` the metadata (format version, method,
//! sizes, canvas, training settings, metrics, timings).
//!
//! Saving never leaves a half-written model where a good one was, and never replaces anything
//! but a model: see [`save`] and [`check_output`].

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};

use super::Method;
use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// Version of the model directory format this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const META_FILE: &str = "model.json";

/// Metadata stored in `model.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelMeta {
    pub format_version: u32,
    /// The rung, e.g. `linear`.
    pub method: Method,
    /// Network (model) size in network pixels, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub network_size: ImageSize,
    /// Camera size in camera pixels, written `[width, height]`.
    #[serde(with = "crate::raster::as_pair")]
    pub camera_size: ImageSize,
    /// Where network-space images are placed in projector space, when compend owns the placement
    /// (live calibration); `None` for models trained on recorded datasets.
    #[serde(default)]
    pub canvas: Option<crate::raster::Rect>,
    /// How the model was trained: data, settings, evidence.
    #[serde(default)]
    pub training: TrainingRecord,
    /// Evaluation results, if any (free-form: written by the commands that score a model).
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// Timings of the training, seconds.
    #[serde(default)]
    pub timings: Timings,
    /// The compend version that wrote the model.
    pub written_by: String,
    /// SHA-256 of `model.safetensors` (lowercase hex), set by [`save`] and checked by [`load`]:
    /// weights from another model, or altered since, are refused. Absent in models written
    /// before it was recorded; those load unchecked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights_sha256: Option<String>,
    /// `compend calibrate`: latency, phase times and the verification that let it be installed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationRecord>,
}

/// How `compend calibrate` made and checked a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// What was calibrated: `virtual:SCENE` or a device.
    pub rig: String,
    /// The manual exposure chosen, when the camera has one.
    #[serde(default)]
    pub exposure: Option<crate::calibrate::exposure::ExposureReport>,
    /// The range of camera values the projector reaches across the displayable area (what the
    /// verification's desired views were scaled into); playback maps content into it.
    #[serde(default)]
    pub display_range: Option<crate::fov::DisplayRange>,
    /// The share of the displayable area no model can compensate, and why
    /// (`capture/cam/unreachable.png` shows where).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreachable: Option<crate::fov::ReachSummary>,
    /// Projector-to-camera latency measured at the start, camera exposures.
    pub latency: crate::calibrate::Latency,
    /// Captures taken in this run, captures found on disk from an interrupted one, retakes.
    pub captured: usize,
    pub resumed: usize,
    pub retakes: usize,
    /// Times the camera went away during a capture and was opened again.
    #[serde(default)]
    pub reconnects: usize,
    /// Seconds per phase.
    pub seconds: PhaseSeconds,
    /// The closed-loop verification of the model this calibration installed (for a climbed
    /// model: of the rung it replaced; its own evidence is in `climb`).
    pub verification: Verification,
    /// Set when this model was climbed to after the calibration (progressive calibration): how
    /// it beat the model it replaced on the calibration's held-out test pairs and on the rig.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub climb: Option<ClimbRecord>,
    /// Closed-loop pairs the model was refitted with (`[calibration] loop_images`; included in
    /// `captured` and in the training's `ntrain`).
    #[serde(default)]
    pub loop_pairs: usize,
    /// The captures' wall time against their physical floor (the measured latency plus the
    /// averaged frames per capture, at the camera's rate); absent in records before it.
    #[serde(default)]
    pub capture_floor: Option<crate::calibrate::sync::CaptureFloor>,
    /// `ntrain = auto`: how many sampling pairs were taken and why (each round's held-out
    /// score); absent for a count asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<crate::calibrate::SamplingCurve>,
}

/// Progressive calibration's evidence: the climbed rung and the model it replaced, scored on the
/// calibration's held-out test pairs (paper protocol: network pixels, encoded values; earlier
/// builds judged a residual rung on held-out closed-loop pairs, `loop_held_out`), then on the
/// rig, which decides.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClimbRecord {
    /// The method of the model it replaced.
    pub replaced: String,
    /// Held-out PSNR of this model and of the one it replaced, dB.
    pub psnr: f64,
    pub replaced_psnr: f64,
    /// The gain it needed in closed loop on the rig, dB (earlier builds: on the held-out pairs
    /// too).
    pub required_gain_db: f64,
    /// Training and scoring, seconds.
    pub seconds: f64,
    /// The rig's check of the climb: both models projected on the verification images.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<ClimbClosedLoop>,
    /// Written by earlier builds: a residual rung on a calibration with closed-loop pairs was
    /// judged on some of those held out of its training; `psnr` and `replaced_psnr` were then
    /// its figure and its own linear part's there. Read, never written now.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_held_out: Option<LoopHeldOut>,
}

/// What a rung's compensation pass costs per frame on the GPU that is to play it, against the
/// display's refresh ([`crate::fit::LivePass`]).
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
    /// What the pass may take: [`LIVE_SHARE`] of one refresh period, ms.
    pub budget_ms: f64,
}

/// The share of one refresh period the compensation pass may take: the rest is left to the
/// content's upload, the copy into the window's surface and the compositor.
pub const LIVE_SHARE: f64 = 0.5;

impl LiveCost {
    /// A measurement, with the budget of `refresh_hz`.
    pub fn new(
        method: Method,
        adapter: String,
        projector: ImageSize,
        pass_ms: f64,
        refresh_hz: f64,
    ) -> Self {
        Self {
            method,
            adapter,
            projector,
            pass_ms,
            refresh_hz,
            budget_ms: LIVE_SHARE * 1e3 / refresh_hz,
        }
    }

    /// Whether the pass fits its budget; a time that is not a number never does.
    pub fn fits(&self) -> bool {
        self.pass_ms.is_finite() && self.pass_ms <= self.budget_ms
    }

    /// The measurement in words, for logs and records.
    pub fn describe(&self) -> String {
        format!(
            "{}'s live pass takes {} ms per {} frame on {}, {} the {} ms budget (half of one \
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

impl ClimbRecord {
    /// Where `psnr` and `replaced_psnr` were measured, in words.
    pub fn judged_on(&self) -> String {
        match &self.loop_held_out {
            Some(l) => format!(
                "{} held-out closed-loop pairs (against its own linear part)",
                l.pairs
            ),
            None => "the held-out test pairs".into(),
        }
    }
}

/// Progressive calibration's closed-loop check of a climbed model against the one it would
/// replace, on the calibration's verification images (camera pixels in the displayable area).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClimbClosedLoop {
    /// Verification images projected.
    pub images: usize,
    /// PSNR (dB) of the climbed model's and of the replaced model's compensated projection.
    pub psnr: f64,
    pub replaced_psnr: f64,
    /// Whether each would pass a calibration's verification on its own.
    pub passed: bool,
    pub replaced_passed: bool,
}

/// Seconds of each phase of a calibration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseSeconds {
    #[serde(default)]
    pub exposure: f64,
    pub latency: f64,
    pub patterns: f64,
    pub captures: f64,
    pub training: f64,
    pub verification: f64,
    pub total: f64,
}

/// Held-out test images projected compensated and uncompensated, captured and scored inside
/// the displayable area against the view they should give (camera pixels, encoded values).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Verification {
    /// Test images projected.
    pub images: usize,
    /// PSNR (dB) and SSIM of the compensated projection.
    pub psnr: f64,
    pub ssim: f64,
    /// The same for the test images projected as they are.
    pub uncompensated_psnr: f64,
    pub uncompensated_ssim: f64,
    /// PSNR gain over the uncompensated projection, dB.
    pub gain_db: f64,
    /// The gain a model needs to be installed, dB.
    pub required_gain_db: f64,
    /// How the model failed, if it did ([`crate::failure`]); a failed model never passes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failure: Option<crate::failure::Failure>,
    pub passed: bool,
}

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
    pub device: Option<crate::fit::TrainDevice>,
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

    /// The evidence for a person: each candidate's held-out figures and time, the choice and
    /// the rule.
    pub fn lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let (Some(held), Some(fitted)) = (self.held_out, self.fitted_on) {
            let figures: Vec<String> = self
                .candidates
                .iter()
                .map(|c| {
                    format!(
                        "{} {:.2} dB / SSIM {:.3} ({:.1} s)",
                        c.method, c.held_out_psnr, c.held_out_ssim, c.fit_seconds
                    )
                })
                .collect();
            out.push(format!(
                "auto: on {held} held-out {}pairs (fitted on {fitted}): {}",
                if self.loop_held_out.is_some() {
                    "sampling "
                } else {
                    ""
                },
                figures.join(", ")
            ));
        }
        if let Some(j) = &self.judged {
            let curve: Vec<String> = j.curve.iter().map(|c| format!("{:.2}", c.psnr)).collect();
            out.push(format!(
                "auto: the climb rung on the held-out pairs as it trained: {} dB{}",
                curve.join(", "),
                j.stop()
            ));
        }
        if let Some(why) = &self.why {
            out.push(format!("auto: {why}"));
        }
        // A pass over its budget is in `why`.
        if let Some(live) = self.live.as_ref().filter(|l| l.fits()) {
            out.push(format!("auto: {}", live.describe()));
        }
        if let Some(l) = &self.loop_held_out {
            let figures: Vec<String> = l
                .scores
                .iter()
                .map(|c| {
                    format!(
                        "{} {:.2} dB / SSIM {:.3}{}",
                        c.method,
                        c.held_out_psnr,
                        c.held_out_ssim,
                        if c.fit_seconds > 0.0 {
                            format!(" ({:.1} s)", c.fit_seconds)
                        } else {
                            String::new()
                        }
                    )
                })
                .collect();
            out.push(format!(
                "auto: on {} held-out closed-loop pairs (the correction trained on {}), against \
                 the projector images that move their captures towards the desired views: {}{}",
                l.pairs,
                l.trained_on,
                figures.join(", "),
                l.training.stop()
            ));
        }
        if !self.closed_loop.is_empty() {
            let figures: Vec<String> = self
                .closed_loop
                .iter()
                .map(|c| {
                    format!(
                        "{} {:.2} dB / SSIM {:.3}{}",
                        c.method,
                        c.psnr,
                        c.ssim,
                        if c.passed { "" } else { " (not installable)" }
                    )
                })
                .collect();
            out.push(format!(
                "auto: closed loop on the rig: {}",
                figures.join(", ")
            ));
        }
        out.push(format!(
            "auto: chose {} by the rule: {}",
            self.chosen, self.rule
        ));
        if let Some(r) = &self.retrained {
            let kept = if self.chosen == r.method {
                String::new()
            } else {
                format!("; the rig then kept {}", self.chosen)
            };
            out.push(if r.after_judgement {
                format!(
                    "auto: having climbed, {} trained again from its start on {} pairs, the \
                     held-out ones included ({:.1} s){kept}",
                    r.method, r.pairs, r.seconds
                )
            } else {
                format!(
                    "auto: {} trained on all {} pairs for the rig to judge ({:.1} s){kept}",
                    r.method, r.pairs, r.seconds
                )
            });
        }
        if !self.chosen.is_linear() && self.closed_loop.is_empty() && self.loop_held_out.is_none() {
            out.push(
                "auto: this climb rests on held-out captures alone, where capture noise favours \
                 a network; `compend calibrate --method auto` also checks it on the rig, in \
                 closed loop"
                    .into(),
            );
        }
        out
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

/// Named f32 arrays with shapes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tensors {
    map: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Tensors {
    pub fn insert(&mut self, name: &str, shape: Vec<usize>, data: Vec<f32>) -> Result<()> {
        let n: usize = shape.iter().product();
        if n != data.len() {
            return Err(Error::Shape(format!(
                "tensor {name}: shape {shape:?} needs {n} values, got {}",
                data.len()
            )));
        }
        self.map.insert(name.to_string(), (shape, data));
        Ok(())
    }

    /// The tensor `name`, checked against the expected shape; `file` names the source in errors.
    pub fn get(&self, name: &str, shape: &[usize], file: &Path) -> Result<&[f32]> {
        match self.map.get(name) {
            None => Err(Error::Input(format!(
                "{}: tensor `{name}` is missing (expected shape {shape:?})",
                file.display()
            ))),
            Some((s, _)) if s.as_slice() != shape => Err(Error::Input(format!(
                "{}: tensor `{name}` has shape {s:?}, expected {shape:?}",
                file.display()
            ))),
            Some((_, d)) => Ok(d),
        }
    }

    /// The stored shape of `name`, if present.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.map.get(name).map(|(shape, _)| shape.as_slice())
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.map.keys().map(|s| s.as_str())
    }

    /// Adds every tensor of `other` under `prefix` + its name (a part of a composite model).
    pub fn insert_all(&mut self, prefix: &str, other: Tensors) {
        for (k, v) in other.map {
            self.map.insert(format!("{prefix}{k}"), v);
        }
    }

    /// The tensors named `prefix` + something, named by the something.
    pub fn under(&self, prefix: &str) -> Tensors {
        Tensors {
            map: self
                .map
                .iter()
                .filter_map(|(k, v)| Some((k.strip_prefix(prefix)?.to_string(), v.clone())))
                .collect(),
        }
    }

    /// The arrays as a safetensors file's bytes (f32, little-endian).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = self
            .map
            .iter()
            .map(|(k, (s, d))| {
                (
                    k.clone(),
                    s.clone(),
                    d.iter().flat_map(|v| v.to_le_bytes()).collect(),
                )
            })
            .collect();
        let views = bytes
            .iter()
            .map(|(k, s, b)| {
                TensorView::new(Dtype::F32, s.clone(), b)
                    .map(|v| (k.clone(), v))
                    .map_err(|e| Error::Shape(format!("tensor {k}: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        safetensors::serialize(views, None)
            .map_err(|e| Error::Failed(format!("safetensors encoding failed: {e}")))
    }

    /// Parses a safetensors file's bytes (f32 arrays only); `file` names the source in errors.
    pub fn from_bytes(bytes: &[u8], file: &Path) -> Result<Self> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| {
            Error::Input(format!(
                "{}: not a readable safetensors file ({e})",
                file.display()
            ))
        })?;
        let mut out = Tensors::default();
        for (name, view) in st.tensors() {
            if view.dtype() != Dtype::F32 {
                return Err(Error::Input(format!(
                    "{}: tensor `{name}` is {:?}, expected F32",
                    file.display(),
                    view.dtype()
                )));
            }
            let data = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            out.map.insert(name, (view.shape().to_vec(), data));
        }
        Ok(out)
    }
}

/// Reads a model directory: metadata (version checked) and tensors.
pub fn load(dir: &Path) -> Result<(ModelMeta, Tensors)> {
    let meta = load_meta(dir)?;
    let weights_path = dir.join(WEIGHTS_FILE);
    let bytes = crate::files::read_regular(
        &weights_path,
        "the model's weights (safetensors)",
        crate::files::MAX_WEIGHTS_BYTES,
    )?;
    let tensors = Tensors::from_bytes(&bytes, &weights_path)?;
    if let Some(recorded) = &meta.weights_sha256 {
        let found = sha256_hex(&bytes);
        if !found.eq_ignore_ascii_case(recorded) {
            return Err(Error::Input(format!(
                "{}: not the weights {} was written with (SHA-256 {found}, recorded {recorded}): \
                 the two files of a model directory must come from one save; copy or move the \
                 whole directory, or train the model again",
                weights_path.display(),
                dir.join(META_FILE).display()
            )));
        }
    }
    Ok((meta, tensors))
}

/// The SHA-256 of `bytes` in lowercase hex.
fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Reads a model directory's metadata alone (version checked).
pub fn load_meta(dir: &Path) -> Result<ModelMeta> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::Input(format!(
            "{}: a file, not a model directory (a folder holding {META_FILE} and {WEIGHTS_FILE})",
            dir.display()
        )));
    }
    let meta_path = dir.join(META_FILE);
    let text = crate::files::read_text(&meta_path, "the model's metadata (JSON)")?;
    // Check the version before the full schema, so an old or newer model says so plainly.
    let version = serde_json::from_str::<serde_json::Value>(&text)
        .map_err(|e| Error::Input(format!("{}: not valid JSON ({e})", meta_path.display())))?
        .get("format_version")
        .and_then(|v| v.as_u64());
    match version {
        Some(v) if v == FORMAT_VERSION as u64 => {}
        Some(v) => {
            return Err(Error::Input(format!(
                "{}: model format version {v}, this compend reads version {FORMAT_VERSION}; retrain the model with this version",
                meta_path.display()
            )));
        }
        None => {
            return Err(Error::Input(format!(
                "{}: no `format_version` field; not a compend model",
                meta_path.display()
            )));
        }
    }
    serde_json::from_str(&text).map_err(|e| {
        Error::Input(format!(
            "{}: invalid model metadata ({e})",
            meta_path.display()
        ))
    })
}

/// Checks, before any work, that a model may be written at `dir`: nothing is there, an empty
/// folder, or a model directory (a folder holding only [`META_FILE`] and [`WEIGHTS_FILE`], with a
/// `format_version` in its metadata). Anything else (a regular file, a folder of other things,
/// a dataset setup) is an input error naming it, so that nothing but a model is ever replaced.
/// The folder that will hold `dir` must be writable, and so must a model directory there (its
/// files are removed once the new one is in place).
pub fn check_output(dir: &Path) -> Result<()> {
    if shape(dir, true)? {
        crate::files::check_contents_removable(dir)?;
    }
    crate::files::check_writable(dir)
}

/// What [`check_output`] checks of what is at `dir`, without needing to write there (for
/// `compend config check`, which may run as another user than the service): nothing, an empty
/// folder or a model directory. What this process may not look at is taken as nothing.
pub fn check_model_path(dir: &Path) -> Result<()> {
    shape(dir, false).map(drop)
}

/// Whether `dir` holds a model directory (`Ok(false)`: nothing there, or an empty folder);
/// anything else is an input error naming it. `strict`: a path this process cannot look at
/// is an error too.
fn shape(dir: &Path, strict: bool) -> Result<bool> {
    let refuse = |what: &str| {
        Err(Error::Input(format!(
            "{}: {what}; only a model directory ({META_FILE} + {WEIGHTS_FILE}) is ever replaced: \
             choose another place for the model (--out, or [paths] model for the service) or \
             move it away",
            dir.display()
        )))
    };
    match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => Err(Error::Input(format!(
            "{}: a folder on this path is a file; choose another place for the model",
            dir.display()
        ))),
        Err(_) if !strict => Ok(false),
        Err(e) => Err(Error::io(dir, "inspect the output path", e)),
        Ok(m) if m.file_type().is_symlink() => refuse("is a symbolic link"),
        Ok(m) if !m.is_dir() => refuse("is a file, not a model directory"),
        Ok(_) => {
            let entries = match fs::read_dir(dir) {
                Ok(entries) => entries,
                Err(_) if !strict => return Ok(false),
                Err(e) => return Err(Error::io(dir, "list", e)),
            };
            let mut names = Vec::new();
            for entry in entries {
                let entry = entry.map_err(|e| Error::io(dir, "list", e))?;
                let name = entry.file_name().to_string_lossy().into_owned();
                // A model's two files are plain files: a folder or a FIFO of that name is
                // someone else's.
                let plain = entry.file_type().is_ok_and(|t| t.is_file());
                if (name == META_FILE || name == WEIGHTS_FILE) && !plain {
                    return refuse(&format!(
                        "holds `{name}` that is not a plain file, so it is not a model directory"
                    ));
                }
                names.push(name);
            }
            if let Some(other) = names.iter().find(|n| *n != META_FILE && *n != WEIGHTS_FILE) {
                return refuse(&format!("holds `{other}`, so it is not a model directory"));
            }
            if !names.is_empty() && !is_model_meta(&dir.join(META_FILE)) {
                return refuse(&format!(
                    "has no readable {META_FILE} with a format_version"
                ));
            }
            Ok(!names.is_empty())
        }
    }
}

/// Whether `path` is a compend model's metadata file (JSON with a `format_version`).
fn is_model_meta(path: &Path) -> bool {
    crate::files::read_text(path, "JSON")
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v.get("format_version").is_some_and(|v| v.is_u64()))
}

/// Writes a model directory atomically: the new directory is written complete and fsynced
/// beside `dir` (`.NAME.tmp-PID`), then exchanged with the old one in one step, so `dir` always
/// holds a complete model ([`crate::files::swap_in_dir`]). What is at `dir` is checked first
/// ([`check_output`]): only a model directory is replaced. Leftovers of killed saves are removed.
pub fn save(dir: &Path, meta: &ModelMeta, tensors: &Tensors) -> Result<()> {
    check_output(dir)?;
    let weights = tensors.to_bytes()?;
    let meta = ModelMeta {
        weights_sha256: Some(sha256_hex(&weights)),
        ..meta.clone()
    };
    let json = serde_json::to_vec_pretty(&meta)
        .map_err(|e| Error::Failed(format!("model metadata: {e}")))?;
    let tmp = crate::files::temp_dir_for(dir)?;
    let result = crate::files::write_synced(&tmp.join(WEIGHTS_FILE), &weights)
        .and_then(|()| crate::files::write_synced(&tmp.join(META_FILE), &json))
        .and_then(|()| crate::files::swap_in_dir(&tmp, dir));
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
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
