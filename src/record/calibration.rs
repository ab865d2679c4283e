//! What `compend calibrate` records of a run in `model.json` (`calibration`): the rig, the
//! exposure ranging chose, the latency measured, the captures against their floor, the sampling
//! rounds, seconds per phase, the verification, a climb's evidence. Calibration measures these
//! ([`crate::calibrate`]); this module holds them as written.

use serde::{Deserialize, Serialize};

use super::training::LoopHeldOut;

/// How `compend calibrate` made and checked a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// What was calibrated: `virtual:SCENE` or a device.
    pub rig: String,
    /// The seed of the sampling images, and on a virtual or window rig of the simulated
    /// surface's texture and noise (`[rig] seed`); absent in records before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// The manual exposure chosen, when the camera has one.
    #[serde(default)]
    pub exposure: Option<ExposureReport>,
    /// The range of camera values the projector reaches across the displayable area (what the
    /// verification's desired views were scaled into); playback maps content into it.
    #[serde(default)]
    pub display_range: Option<crate::fov::DisplayRange>,
    /// The share of the displayable area no model can compensate, and why
    /// (`capture/cam/unreachable.png` shows where).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreachable: Option<crate::fov::ReachSummary>,
    /// Projector-to-camera latency measured at the start, camera exposures.
    pub latency: Latency,
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
    pub capture_floor: Option<CaptureFloor>,
    /// `ntrain = auto`: how many sampling pairs were taken and why (each round's held-out
    /// score); absent for a count asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<SamplingCurve>,
    /// `ntrain = auto` with the closed-loop pairs following the sampling pairs: how many were
    /// taken and why; absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<LoopChoice>,
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
    /// The uncompensated figures are of the test pairs' captures the calibration took itself,
    /// not of the test images projected again (absent in records before it: projected again).
    #[serde(default)]
    pub uncompensated_from_test_pairs: bool,
    /// PSNR gain over the uncompensated projection, dB.
    pub gain_db: f64,
    /// The gain a model needs to be installed, dB.
    pub required_gain_db: f64,
    /// How the model failed, if it did ([`crate::failure`]); a failed model never passes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failure: Option<crate::failure::Failure>,
    pub passed: bool,
}

/// What ranging chose, in the camera's exposure units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExposureReport {
    pub initial: f64,
    pub chosen: f64,
    /// The 99.5th percentile of the lit pixels' brightest channel under white, at `chosen`.
    pub bright_level: f64,
    pub steps: usize,
}

/// What the latency measurement found, in camera exposures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    /// Exposures from the first frame after each switch to the first frame showing it.
    pub trials: Vec<u64>,
    /// The worst trial plus the margin: exposures skipped after every show.
    pub settle_frames: u64,
    /// Mean camera level (encoded, \[0,1\]) under black and under white.
    pub black_level: f64,
    pub white_level: f64,
}

/// What captures took against their physical floor: each capture needs the measured latency
/// plus the frames it averages, at the camera's rate, and nothing else.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CaptureFloor {
    /// Captures taken (white frames shown between look-alike pictures included).
    pub captures: usize,
    /// Σ (worst measured latency + frames averaged) over them, exposures.
    pub frames: u64,
    /// Wall time the captures took, seconds (showing, waiting, grabbing, checking).
    pub seconds: f64,
    /// The camera's frame rate measured from its frames' timestamps, Hz (0: not measured).
    pub fps: f64,
}

impl CaptureFloor {
    /// The floor in seconds: [`Self::frames`] at the measured rate (0 when not measured).
    pub fn floor_seconds(&self) -> f64 {
        if self.fps > 0.0 {
            self.frames as f64 / self.fps
        } else {
            0.0
        }
    }

    /// This and `other` together (the rate from whichever measured one).
    pub fn add(&mut self, other: &CaptureFloor) {
        self.captures += other.captures;
        self.frames += other.frames;
        self.seconds += other.seconds;
        if self.fps <= 0.0 {
            self.fps = other.fps;
        }
    }
}

/// One round of `ntrain = auto`: the `linear` rung on its sampling pairs, scored on the
/// held-out test pairs in camera space.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoundScore {
    /// Sampling pairs fitted on.
    pub pairs: usize,
    /// Held-out mean squared error, camera values (encoded) in \[0, 1\].
    pub mse: f64,
    /// The same as a PSNR, dB.
    pub psnr: f64,
    /// The fit and its score, seconds.
    pub seconds: f64,
}

/// How `ntrain = auto` chose the sampling pairs (`model.json`, `calibration.sampling`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SamplingCurve {
    pub rule: String,
    pub rounds: Vec<RoundScore>,
    /// Sampling pairs taken.
    pub chosen: usize,
    /// Why no other round was taken.
    pub why: String,
}

impl SamplingCurve {
    /// One line for people: the rounds' pairs and scores, the count kept and why.
    pub fn line(&self) -> String {
        let rounds: Vec<String> = self
            .rounds
            .iter()
            .map(|r| format!("{} pairs {:.2} dB", r.pairs, r.psnr))
            .collect();
        format!(
            "sampling rounds (held-out camera-space PSNR of the linear rung): {}; {} sampling \
             pairs kept: {}",
            rounds.join(", "),
            self.chosen,
            self.why
        )
    }
}

/// How `ntrain = auto` chose the closed-loop pairs (`model.json`, `calibration.closed_loop`):
/// the first ones judged, in the displayable area, by how much of their closed-loop error the
/// model that compensated them leaves in its own prediction of what the camera saw.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopChoice {
    pub rule: String,
    /// The closed-loop pairs judged on (the first ones).
    pub judged: usize,
    /// The compensating model's camera-space error on them: how far its forward model's
    /// prediction of each capture is from the capture (mean squared, encoded values in
    /// \[0, 1\]).
    pub model_mse: f64,
    /// Their closed-loop error: each capture against its desired view (mean squared, encoded
    /// values).
    pub closed_loop_mse: f64,
    /// `model_mse / closed_loop_mse`.
    pub share: f64,
    /// Closed-loop pairs taken.
    pub chosen: usize,
    /// Why no more, or why all.
    pub why: String,
}

impl LoopChoice {
    /// One line for people.
    pub fn line(&self) -> String {
        format!("closed-loop pairs: {} taken: {}", self.chosen, self.why)
    }
}
