//! The linear rungs' fit (docs/architecture.md, "Models"): `linear` and `linear-sl` on the
//! output lattice (the projector's resolution by default, [`super::default_lattice`]), their
//! held-out scores for `auto` ([`super::auto`]), and the model's record.

use std::time::Instant;

use super::{Request, Summary, TrainingData, common_record, sl_grid};
use crate::dataset::{CaptureSet, Setup};
use crate::error::{Error, Result};
use crate::linear::{self, FitSettings};
use crate::model::store::{FORMAT_VERSION, ModelMeta};
use crate::model::{Method, Model};
use crate::raster::{Camera, Levels, NetImage};
use crate::record::{AutoCandidate, AutoEvidence, Timings, TrainingRecord};

/// A linear rung: the fit on the output lattice and its record. `evidence`: how `auto` chose
/// it, recorded with the model.
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_linear(
    setup: &Setup,
    req: &Request,
    method: Method,
    evidence: Option<AutoEvidence>,
    ntrain: usize,
    data: TrainingData<'_>,
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
    let settings = settings(req, network_size);
    let (fitted, report) = fit_linear_rung(
        setup,
        method,
        (&captures, &targets),
        theta,
        &settings,
        req.geometry_memo.as_deref(),
        &mut progress,
    )?;
    if !report.final_loss.is_finite() {
        return Err(Error::Failed(format!(
            "training {method} diverged (final loss {}); no model produced",
            report.final_loss
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
            geometry_reused: report.geometry_reused,
            curves_searched_on: Some(settings.geometry_images.clamp(1, captures.len())),
            ..common_record(setup, ntrain, req.seed, &fov, &settings, report.final_loss)?
        },
        metrics: serde_json::Value::Null,
        timings: Timings {
            fit_seconds: report.seconds,
            train_seconds: seconds,
            ms_per_sample: None,
        },
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
        weights_sha256: None,
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

/// The linear rungs' fit settings: the request's output lattice ([`super::fit`] has set it to
/// [`super::default_lattice`] when none was asked for).
pub(super) fn settings(req: &Request, network_size: crate::raster::ImageSize) -> FitSettings {
    FitSettings {
        network_size,
        lattice: req.lattice,
        colour: req.colour,
        ..FitSettings::default()
    }
}

/// Fits one linear rung (`linear` or `linear-sl`) on the given pairs; `linear` takes its
/// geometry from `memo` when it can ([`linear::GeometryMemo`]).
fn fit_linear_rung(
    setup: &Setup,
    method: Method,
    (captures, targets): (&[Levels<Camera>], &[NetImage]),
    theta: [[f32; 3]; 2],
    settings: &FitSettings,
    memo: Option<&linear::GeometryMemo>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<(linear::LinearModel, linear::FitReport)> {
    if method == Method::LinearSl {
        let grid = sl_grid(setup, settings.lattice.unwrap_or(settings.network_size))?;
        linear::fit_on_grid(captures, targets, grid, settings)
    } else {
        linear::fit_with_memo(
            captures,
            targets,
            crate::warp::Warp::from_affine(theta),
            settings,
            memo,
            &mut *progress,
        )
    }
}

/// The linear rungs a setup can fit: `linear`, and `linear-sl` when it has structured-light
/// captures.
pub(super) fn linear_rungs(setup: &Setup) -> &'static [Method] {
    if setup.count(CaptureSet::Sl).unwrap_or(0) > 0 {
        &[Method::Linear, Method::LinearSl]
    } else {
        &[Method::Linear]
    }
}

/// `auto`'s first step: every linear rung (`linear`, and `linear-sl` when the setup has
/// structured-light captures) fitted on `fit` pairs and scored with the paper protocol on the
/// `held` pairs. Returns each candidate's figures, in that order.
pub(super) fn score_linear_rungs(
    setup: &Setup,
    req: &Request,
    (fit_c, fit_t): (&[Levels<Camera>], &[NetImage]),
    (held_c, held_t): (&[Levels<Camera>], &[NetImage]),
    theta: [[f32; 3]; 2],
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Vec<AutoCandidate>> {
    let settings = settings(req, fit_t[0].size());
    let mut candidates = Vec::new();
    for &method in linear_rungs(setup) {
        let t0 = Instant::now();
        let (model, _) = fit_linear_rung(
            setup,
            method,
            (fit_c, fit_t),
            theta,
            &settings,
            req.geometry_memo.as_deref(),
            progress,
        )?;
        let seconds = t0.elapsed().as_secs_f64();
        let simplified = model.simplify();
        let mut acc = crate::metrics::Accumulator::default();
        for (c, t) in held_c.iter().zip(held_t) {
            acc.add(
                &crate::model::at_size(simplified.apply(&c.to_values()), t.size()),
                t,
            )?;
        }
        let scores = acc.finish()?;
        candidates.push(AutoCandidate {
            method,
            held_out_psnr: scores.psnr,
            held_out_ssim: scores.ssim,
            fit_seconds: seconds,
        });
    }
    Ok(candidates)
}
