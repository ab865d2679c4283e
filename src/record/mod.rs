//! What a model's metadata records of how it was made (`model.json`, docs/architecture.md,
//! "Model directory"): how `compend calibrate` measured and checked it
//! ([`calibration`]), how it was trained and `auto`'s evidence ([`training`]); and `set.json`
//! of a set of projectors checked as a whole ([`set`]). Plain data with
//! serde: the code that measures or writes each figure lives where the work is
//! ([`crate::calibrate`], [`crate::fit`]); [`crate::model::store`] saves and loads them.

pub mod calibration;
pub mod set;
pub mod training;

pub use calibration::{
    CalibrationRecord, CaptureFloor, ClimbClosedLoop, ClimbRecord, ExposureReport, Latency,
    LoopChoice, PhaseSeconds, RoundScore, SamplingCurve, Verification,
};
pub use set::{SetRecord, SetVerification};
pub use training::{
    AutoCandidate, AutoEvidence, ClosedLoopScore, JudgedTraining, LiveCost, LoopCheckpoint,
    LoopHeldOut, Retrained, Timings, TrainingRecord, readable,
};
