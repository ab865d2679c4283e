//! The linear rungs' fit (docs/architecture.md, "Models"): `linear` and `linear-sl` on the
//! output lattice (1.5× the network size by default, [`super::default_lattice`]), `auto`'s
//! choice between them on held-out training pairs, and the model's record.

use std::time::Instant;

use super::{MIN_TRAIN, Request, Summary, TrainingData, common_record, default_lattice, sl_grid};
use crate::dataset::{CaptureSet, Setup};
use crate::error::{Error, Result};
use crate::linear::{self, FitSettings};
use crate::model::store::{
    AutoCandidate, AutoEvidence, FORMAT_VERSION, ModelMeta, Timings, TrainingRecord,
};
use crate::model::{Method, MethodChoice, Model};
use crate::raster::{CamImage, NetImage};

/// The linear rungs (and `auto`, which picks one of them): the fit on the output lattice and
/// its record.
pub(super) fn fit_linear(
    setup: &Setup,
    req: &Request,
    ntrain: usize,
    data: TrainingData,
    start: Instant,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary)> {
    let TrainingData {
        fov,
        cam_size,
        theta,
        network_size,
        captures,
        targets,
    } = data;
    let settings = FitSettings {
        network_size,
        lattice: Some(req.lattice.unwrap_or_else(|| default_lattice(network_size))),
        ..FitSettings::default()
    };
    let (method, evidence) = match req.method {
        MethodChoice::Auto => {
            let evidence =
                choose_linear_rung(setup, &captures, &targets, theta, &settings, &mut progress)?;
            (evidence.chosen, Some(evidence))
        }
        MethodChoice::Rung(m) => (m, None),
    };
    let (fitted, report) = fit_linear_rung(
        setup,
        method,
        &captures,
        &targets,
        theta,
        &settings,
        &mut progress,
    )?;
    if !report.final_loss.is_finite() {
        return Err(Error::Failed(format!(
            "training {} diverged (final loss {}); no model produced",
            req.method, report.final_loss
        )));
    }
    let seconds = start.elapsed().as_secs_f64();
    let meta = ModelMeta {
        format_version: FORMAT_VERSION,
        method,
        network_size: fitted.network_size(),
        camera_size: cam_size,
        canvas: None,
        training: TrainingRecord {
            curves: Some(fitted.curves),
            auto: evidence,
            ..common_record(setup, ntrain, req.seed, &fov, &settings, report.final_loss)?
        },
        metrics: serde_json::Value::Null,
        timings: Timings {
            fit_seconds: report.seconds,
            train_seconds: seconds,
            ms_per_sample: None,
        },
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
        calibration: None,
    };
    let summary = Summary {
        method,
        ntrain,
        seconds,
        fit_seconds: report.seconds,
        final_loss: report.final_loss,
    };
    Ok((Model::linear(meta, fov.mask, fitted), summary))
}

/// Fits one linear rung (`linear` or `linear-sl`) on the given pairs.
fn fit_linear_rung(
    setup: &Setup,
    method: Method,
    captures: &[CamImage],
    targets: &[NetImage],
    theta: [[f32; 3]; 2],
    settings: &FitSettings,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<(linear::LinearModel, linear::FitReport)> {
    if method == Method::LinearSl {
        let grid = sl_grid(setup, settings.lattice.unwrap_or(settings.network_size))?;
        linear::fit_on_grid(captures, targets, grid, settings)
    } else {
        linear::fit(
            captures,
            targets,
            crate::warp::Warp::from_affine(theta),
            settings,
            &mut *progress,
        )
    }
}

/// Picks the linear rung for `auto`: every candidate (`linear`, and `linear-sl` when the setup
/// has structured-light captures) is fitted on all but the last sixth of the training pairs (at
/// least 4 held out) and scored with the paper protocol on the held-out pairs; the highest PSNR
/// wins and is then refitted on every pair by the caller. Returns the choice and the evidence
/// recorded in the model metadata. With too few pairs to hold any out, `linear` is chosen.
fn choose_linear_rung(
    setup: &Setup,
    captures: &[CamImage],
    targets: &[NetImage],
    theta: [[f32; 3]; 2],
    settings: &FitSettings,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<AutoEvidence> {
    let n = captures.len();
    let held = (n / 6).max(4);
    let has_sl = setup.count(CaptureSet::Sl).unwrap_or(0) > 0;
    let rule = "highest paper-protocol PSNR on held-out training pairs among the linear rungs";
    if n < held + MIN_TRAIN || !has_sl {
        let why = if has_sl {
            format!("{n} training pairs are too few to hold {held} out")
        } else {
            "no structured-light captures: `linear` is the only linear rung".into()
        };
        return Ok(AutoEvidence {
            rule: rule.into(),
            chosen: Method::Linear,
            why: Some(why),
            held_out: None,
            fitted_on: None,
            candidates: Vec::new(),
        });
    }
    let (fit_c, fit_t) = (&captures[..n - held], &targets[..n - held]);
    let mut candidates = Vec::new();
    let mut best: Option<(Method, f64)> = None;
    for method in [Method::Linear, Method::LinearSl] {
        let t0 = Instant::now();
        let (model, _) = fit_linear_rung(setup, method, fit_c, fit_t, theta, settings, progress)?;
        let seconds = t0.elapsed().as_secs_f64();
        let simplified = model.simplify();
        let mut acc = crate::metrics::Accumulator::default();
        for (c, t) in captures[n - held..].iter().zip(&targets[n - held..]) {
            acc.add(&crate::model::at_size(simplified.apply(c), t.size()), t)?;
        }
        let scores = acc.finish()?;
        candidates.push(AutoCandidate {
            method,
            held_out_psnr: scores.psnr,
            held_out_ssim: scores.ssim,
            fit_seconds: seconds,
        });
        if best.as_ref().is_none_or(|b| scores.psnr > b.1) {
            best = Some((method, scores.psnr));
        }
    }
    Ok(AutoEvidence {
        rule: rule.into(),
        chosen: best.map_or(Method::Linear, |b| b.0),
        why: None,
        held_out: Some(held),
        fitted_on: Some(n - held),
        candidates,
    })
}
