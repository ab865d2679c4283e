//! `[calibration]`: what `calibrate` projects and fits, and the climbs after it.

use std::str::FromStr;

use serde::Serialize;

use super::read::{Table, Walker, at_least_one, finite, span_of};
use super::{display, display_or_none};
use crate::model::MethodChoice;
use crate::raster::ImageSize;

/// When the service calibrates by itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnStart {
    /// At start when no model is installed (or an interrupted calibration is on disk).
    IfNoModel,
    /// Only when asked (`compend recalibrate`).
    Never,
}

/// `[calibration]`: what `calibrate` projects and fits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CalibrationConfig {
    #[serde(serialize_with = "display")]
    pub method: MethodChoice,
    /// Sampling images, or `auto` (rounds, [`crate::calibrate::rounds`]).
    pub ntrain: crate::calibrate::SamplingCount,
    pub ntest: usize,
    pub verify: usize,
    /// PSNR gain over the uncompensated projection a model needs to be installed, dB.
    pub min_gain_db: f64,
    /// Frames averaged per capture.
    pub average: usize,
    /// Network size of the sampling images.
    pub network: ImageSize,
    pub on_start: OnStart,
    /// Calibration run folders the service keeps under `[paths] data` (0: all).
    pub keep_runs: usize,
    /// Progressive calibration: the rung trained in the background, on the same captures, once
    /// a calibration has installed its model and playback has started; `None`: no climb.
    #[serde(serialize_with = "display_or_none")]
    pub climb: Option<crate::model::Method>,
    /// PSNR gain (dB) the climbed rung needs over the installed model (or, under `method =
    /// "auto"`, over the best linear rung) in closed loop on the rig, on the verification
    /// images, to be installed.
    pub climb_gain_db: f64,
    /// Iterations of the climbed rung's training (the progressive climb's and `auto`'s);
    /// `None`: its own schedule.
    pub climb_iters: Option<usize>,
    /// Where the CompenNet++ rungs train (a calibration's, `auto`'s climb and the progressive
    /// climb); it also sets the rung `climb = "auto"` and `method = "auto"` climb to.
    #[serde(serialize_with = "display")]
    pub device: crate::fit::TrainDevice,
    /// Closed-loop pairs taken with the `linear` rung after its first fit (0: none; `None`:
    /// [`crate::calibrate::loop_images`]'s default, as many as `ntrain`): a linear rung (and
    /// the one `auto` keeps) is refitted on every pair, a residual rung trains its correction
    /// on them, and `auto` with 8 or more judges its climb on them
    /// ([`crate::calibrate::refine`]).
    pub loop_images: Option<usize>,
    /// The display refresh rate (Hz) a climb's live pass is weighed at (`method = "auto"`'s
    /// and the progressive climb's): the rung is timed on the playback GPU first and not
    /// trained when its pass takes more than half of one refresh period. `None`: the projector
    /// window's rate (window and camera rigs; the virtual rig's climbs are then not weighed);
    /// 0: not weighed.
    pub refresh_hz: Option<f64>,
}

impl Default for CalibrationConfig {
    /// The `linear` rung from 48 sampling images, 10 test images of which 5 verify, no climb.
    fn default() -> Self {
        CalibrationConfig {
            method: MethodChoice::Rung(crate::model::Method::Linear),
            ntrain: crate::calibrate::SamplingCount::Count(crate::fit::DEFAULT_TRAIN),
            ntest: 10,
            verify: 5,
            min_gain_db: crate::calibrate::DEFAULT_MIN_GAIN_DB,
            average: 3,
            network: ImageSize::new(256, 256),
            on_start: OnStart::IfNoModel,
            keep_runs: 3,
            climb: None,
            climb_gain_db: crate::fit::DEFAULT_RIG_GAIN_DB,
            climb_iters: None,
            device: crate::fit::TrainDevice::default(),
            loop_images: None,
            refresh_hz: None,
        }
    }
}

impl CalibrationConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let d = Self::default();
        let method = w.parsed(t, "method", d.method);
        let device = w
            .parsed_with(t, "device", |s| {
                let d: crate::fit::TrainDevice =
                    s.parse().map_err(|e: crate::Error| e.to_string())?;
                if d != crate::fit::TrainDevice::Cpu && !cfg!(feature = "cuda") {
                    return Err(format!(
                        "\"{s}\": this compend was built without CUDA; rebuild it with `cargo \
                         build --release --features cuda`, or train on \"cpu\""
                    ));
                }
                Ok(d)
            })
            .unwrap_or(d.device);
        let ntrain_at = span_of(t, "ntrain");
        let ntrain = w.checked(t, "ntrain", d.ntrain, |&n| {
            if n.most() >= crate::fit::MIN_TRAIN {
                Ok(())
            } else {
                Err(format!(
                    "at least {} training images are needed",
                    crate::fit::MIN_TRAIN
                ))
            }
        });
        if ntrain == crate::calibrate::SamplingCount::Auto
            && let Some(p) = crate::calibrate::rounds_problem(method)
        {
            w.error(ntrain_at, format!("[calibration] ntrain = \"auto\": {p}"));
        }
        // Compared only when both were read without error (a wrong one stands at its
        // default), at the line of whichever of them the file gives (verify's first).
        let errors = w.errors.len();
        let at = match span_of(t, "verify") {
            s if s != (0..0) => s,
            _ => span_of(t, "ntest"),
        };
        let ntest = w.checked(t, "ntest", d.ntest, |&n| at_least_one(n));
        let verify = w.checked(t, "verify", d.verify, |&n| at_least_one(n));
        if verify > ntest && w.errors.len() == errors {
            w.error(
                at,
                format!("[calibration] verify = {verify} is more than ntest = {ntest}"),
            );
        }
        let refresh_hz = w.checked(t, "refresh_hz", d.refresh_hz, |v: &Option<f64>| {
            match v.and_then(crate::fit::refresh_rate_problem) {
                Some(problem) => Err(problem),
                None => Ok(()),
            }
        });
        let span = span_of(t, "loop_images");
        let loop_images: Option<usize> = w.get(t, "loop_images").or(d.loop_images);
        if let Some(n) = loop_images
            && let Some(p) = crate::calibrate::loop_images_problem(method, n)
        {
            w.error(span, format!("[calibration] loop_images = {n}: {p}"));
        }
        CalibrationConfig {
            method,
            ntrain,
            ntest,
            verify,
            min_gain_db: w.checked(t, "min_gain_db", d.min_gain_db, |v: &f64| finite(*v)),
            average: w.checked(t, "average", d.average, |&n| at_least_one(n)),
            network: w
                .parsed_with(t, "network", |s| {
                    let n = ImageSize::parse(s, true)?;
                    if n.width % 4 == 0 && n.height % 4 == 0 {
                        Ok(n)
                    } else {
                        Err(format!(
                            "network size {n}: width and height must be divisible by 4"
                        ))
                    }
                })
                .unwrap_or(d.network),
            on_start: w.choice(
                t,
                "on_start",
                d.on_start,
                &[
                    ("if-no-model", OnStart::IfNoModel),
                    ("never", OnStart::Never),
                ],
            ),
            keep_runs: w.get(t, "keep_runs").unwrap_or(d.keep_runs),
            climb: w
                .parsed_with(t, "climb", |s| match s {
                    "none" => Ok(None),
                    "auto" => Ok(Some(crate::fit::climb_rung(device))),
                    rung => crate::model::Method::from_str(rung)
                        .map(Some)
                        .map_err(|e| format!("{e}; or \"auto\" or \"none\"")),
                })
                .unwrap_or(d.climb),
            climb_gain_db: w.checked(t, "climb_gain_db", d.climb_gain_db, |v: &f64| finite(*v)),
            climb_iters: w
                .get::<usize>(t, "climb_iters")
                .filter(|&n| n > 0)
                .or(d.climb_iters),
            device,
            loop_images,
            refresh_hz,
        }
    }
}
