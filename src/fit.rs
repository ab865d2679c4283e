//! Training a model on a setup: the shared core of `compend train`, `compend bench` and
//! calibration. Loads the references and training pairs, finds the projector FOV, fits the
//! requested rung and returns the model ready to save.

use std::time::Instant;

use serde::Serialize;
use serde_json::json;

use crate::dataset::{CaptureSet, Reference, Setup};
use crate::error::{Error, Result};
use crate::fov;
use crate::linear::{self, FitSettings};
use crate::model::Model;
use crate::model::store::{FORMAT_VERSION, ModelMeta};
use crate::raster::{CamImage, Camera, NetImage, Network, Rect};
use crate::sample::Grid;

/// Fewest training pairs the linear rungs accept.
pub const MIN_TRAIN: usize = 4;
/// Training pairs used when the caller does not say.
pub const DEFAULT_TRAIN: usize = 48;

/// What to train.
#[derive(Clone, Debug)]
pub struct Request {
    /// One of [`crate::model::METHODS`].
    pub method: String,
    /// Training pairs to use (the first N); `None` = all available, at most [`DEFAULT_TRAIN`].
    pub ntrain: Option<usize>,
    pub seed: u64,
    /// CompenNet++ only: override the variant's iterations (the lr step scales) and batch size.
    pub iters: Option<usize>,
    pub batch: Option<usize>,
    /// Where the CompenNet++ variants train (the `linear` rungs are closed-form CPU fits).
    pub device: TrainDevice,
    /// The `linear` rungs only: the lattice of the colour model and of its output images;
    /// `None` = [`default_lattice`] of the network size.
    pub lattice: Option<(usize, usize)>,
    /// CompenNet++ variants: how CompenNet's weights start (default: the shipped
    /// pre-initialisation, DESIGN.md 5.2).
    pub photometric: crate::nn::pretrain::PhotometricInit,
}

/// The default output lattice of the `linear` rungs: 1.5× the network size, rounded up to a
/// multiple of 4 (256² → 384²). The per-pixel model costs little more on a finer lattice, and a
/// 256² image stretched over the canvas has fewer pixels across the displayable area than the
/// desired image: on the rig's curved scene (seed 1, 48 images) 384² closes 0.46 dB of the
/// closed-loop gap to the oracle, 512² no more.
pub fn default_lattice((w, h): (usize, usize)) -> (usize, usize) {
    ((w * 3 / 2).div_ceil(4) * 4, (h * 3 / 2).div_ceil(4) * 4)
}

/// The device CompenNet++ training runs on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum TrainDevice {
    #[default]
    Cpu,
    /// An NVIDIA GPU by CUDA ordinal; needs a build with the `cuda` cargo feature.
    Cuda(usize),
}

impl std::str::FromStr for TrainDevice {
    type Err = Error;
    /// `cpu`, `cuda` (ordinal 0) or `cuda:N`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda(0)),
            _ => s
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .map(Self::Cuda)
                .ok_or_else(|| {
                    Error::Input(format!(
                        "device `{s}`: expected `cpu`, `cuda` or `cuda:N` (N a GPU ordinal)"
                    ))
                }),
        }
    }
}

impl TrainDevice {
    /// The candle device; an input error when this build has no CUDA or the GPU cannot be opened.
    pub fn candle(self) -> Result<candle_core::Device> {
        match self {
            Self::Cpu => Ok(candle_core::Device::Cpu),
            Self::Cuda(_) if !cfg!(feature = "cuda") => Err(Error::Input(
                "--device cuda: this compend was built without CUDA; rebuild with \
                 `cargo build --release --features cuda` (needs the CUDA toolkit's nvcc)"
                    .into(),
            )),
            Self::Cuda(n) => candle_core::Device::new_cuda(n)
                .map_err(|e| Error::Input(format!("--device cuda:{n}: cannot open the GPU: {e}"))),
        }
    }
}

/// What training reports besides the model.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub method: String,
    pub ntrain: usize,
    /// Wall time of the whole training (loading included), seconds.
    pub seconds: f64,
    /// Wall time of the fit alone, seconds.
    pub fit_seconds: f64,
    pub final_loss: f64,
}

/// Trains `req.method` on `setup`; `progress(stage, done, total)` reports the fit's progress.
pub fn fit(
    setup: &Setup,
    req: &Request,
    progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary)> {
    let start = Instant::now();
    let auto = req.method == AUTO;
    if !auto && !crate::model::METHODS.contains(&req.method.as_str()) {
        return Err(Error::Input(format!(
            "--method {}: not available; methods: {}, {AUTO}",
            req.method,
            crate::model::METHODS.join(", ")
        )));
    }
    let variant = crate::nn::train::Variant::from_method(&req.method);
    if variant.is_some() {
        if let Some((w, h)) = req.lattice {
            return Err(Error::Input(format!(
                "--lattice {w}x{h}: only the linear rungs have an output lattice; {} works at \
                 the network size",
                req.method
            )));
        }
        // Fail before loading anything when the device is unusable.
        req.device.candle()?;
    }
    if let Some((w, h)) = req.lattice
        && (w < 8 || h < 8)
    {
        return Err(Error::Input(format!(
            "--lattice {w}x{h}: expected at least 8x8 pixels"
        )));
    }
    let available = setup.count(CaptureSet::Train)?;
    let default_train = variant.map_or(DEFAULT_TRAIN, |v| v.schedule().0);
    let ntrain = req.ntrain.unwrap_or(available.min(default_train));
    if ntrain < MIN_TRAIN {
        return Err(Error::Input(format!(
            "--ntrain {ntrain}: the {} method needs at least {MIN_TRAIN} training pairs ({} has {available})",
            req.method,
            setup.capture_dir(CaptureSet::Train).display()
        )));
    }
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let label = format!(
        "{} and {}",
        setup.reference_path(Reference::Black).display(),
        setup.reference_path(Reference::White).display()
    );
    let fov = fov::fov_mask(&black, &white, &label)?;
    let cam_size = black.size();
    let theta = fov::affine_from_box(fov.bbox, cam_size)?;
    let pairs = setup.load_train(Some(ntrain))?;
    let network_size = pairs.inputs[0].size();
    let captures: Vec<CamImage> = pairs
        .captures
        .iter()
        .map(|c| c.masked(&fov.mask))
        .collect::<Result<_>>()?;
    let targets: Vec<NetImage> = pairs.inputs.into_iter().map(|p| p.into_space()).collect();
    if let Some(variant) = variant {
        return train_compennet(
            setup, req, variant, fov, theta, captures, targets, start, progress,
        );
    }
    let settings = FitSettings {
        network_size,
        lattice: Some(req.lattice.unwrap_or_else(|| default_lattice(network_size))),
        ..FitSettings::default()
    };
    let mut progress = progress;
    let (method, evidence) = if auto {
        choose_linear_rung(setup, &captures, &targets, theta, &settings, &mut progress)?
    } else {
        (req.method.clone(), serde_json::Value::Null)
    };
    let (fitted, report) = fit_linear_rung(
        setup,
        &method,
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
        method: method.clone(),
        network_size: fitted.network_size(),
        camera_size: cam_size,
        canvas: None,
        training: json!({
            "setup": setup.path(),
            "data_root": setup.root().path(),
            "ntrain": ntrain,
            "seed": req.seed,
            "fov": fov.diagnostics,
            "fov_bbox": fov.bbox,
            "settings": settings,
            "curves": fitted.curves,
            "final_loss": report.final_loss,
            "auto": evidence,
        }),
        metrics: serde_json::Value::Null,
        timings: json!({ "fit_seconds": report.seconds, "train_seconds": seconds }),
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
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

/// `--method auto`: the selection rule of DESIGN.md section 5.4 among the linear rungs.
pub const AUTO: &str = "auto";

/// Fits one linear rung (`linear` or `linear-sl`) on the given pairs.
fn fit_linear_rung(
    setup: &Setup,
    method: &str,
    captures: &[CamImage],
    targets: &[NetImage],
    theta: [[f32; 3]; 2],
    settings: &FitSettings,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<(linear::LinearModel, linear::FitReport)> {
    if method == "linear-sl" {
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
) -> Result<(String, serde_json::Value)> {
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
        return Ok((
            linear::METHOD.to_string(),
            json!({ "rule": rule, "chosen": linear::METHOD, "why": why, "candidates": [] }),
        ));
    }
    let (fit_c, fit_t) = (&captures[..n - held], &targets[..n - held]);
    let mut candidates = Vec::new();
    let mut best: Option<(String, f64)> = None;
    for method in [linear::METHOD, "linear-sl"] {
        let t0 = Instant::now();
        let (model, _) = fit_linear_rung(setup, method, fit_c, fit_t, theta, settings, progress)?;
        let seconds = t0.elapsed().as_secs_f64();
        let simplified = model.simplify();
        let mut acc = crate::metrics::Accumulator::default();
        for (c, t) in captures[n - held..].iter().zip(&targets[n - held..]) {
            acc.add(&crate::model::at_size(simplified.apply(c), t.size()), t)?;
        }
        let scores = acc.finish()?;
        candidates.push(json!({
            "method": method,
            "held_out_psnr": scores.psnr,
            "held_out_ssim": scores.ssim,
            "fit_seconds": seconds,
        }));
        if best.as_ref().is_none_or(|b| scores.psnr > b.1) {
            best = Some((method.to_string(), scores.psnr));
        }
    }
    let chosen = best.map_or_else(|| linear::METHOD.to_string(), |b| b.0);
    Ok((
        chosen.clone(),
        json!({
            "rule": rule,
            "chosen": chosen,
            "held_out": held,
            "fitted_on": n - held,
            "candidates": candidates,
        }),
    ))
}

/// The network→camera grid from the setup's structured-light captures; the network image is
/// assumed stretched over the whole projector frame (the size of the root's sl/ patterns).
pub fn sl_grid(setup: &Setup, network_size: (usize, usize)) -> Result<Grid<Network, Camera>> {
    let projector = setup.root().projector_size()?;
    let code = crate::patterns::GrayCode::new(projector.0, projector.1)?;
    let captures = setup.load_captures(CaptureSet::Sl, None)?;
    if captures.len() != code.len() {
        return Err(Error::Input(format!(
            "{}: {} structured-light captures, expected {} for a {}x{} projector",
            setup.capture_dir(CaptureSet::Sl).display(),
            captures.len(),
            code.len(),
            projector.0,
            projector.1
        )));
    }
    let corr = code.decode(&captures)?;
    let canvas = Rect {
        x: 0,
        y: 0,
        width: projector.0,
        height: projector.1,
    };
    Ok(crate::slgrid::grid_from_correspondence(&corr, canvas, network_size)?.grid)
}

/// Trains a CompenNet++ variant on already masked captures.
#[allow(clippy::too_many_arguments)]
fn train_compennet(
    setup: &Setup,
    req: &Request,
    variant: crate::nn::train::Variant,
    fov: fov::FovMask,
    theta: [[f32; 3]; 2],
    captures: Vec<CamImage>,
    targets: Vec<NetImage>,
    start: Instant,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary)> {
    use crate::nn::train::{Data, GeometryInit, Settings};
    let ce = |e: candle_core::Error| Error::Failed(format!("preparing CompenNet++ data: {e}"));
    // A smaller rung works on a coarser network: the projector images are shrunk onto it (their
    // canvas stretch shows the same picture, a little blurred).
    let div = variant.network_divisor();
    let full_size = targets[0].size();
    let full_targets = targets;
    let shrunk: Option<Vec<NetImage>> = (div > 1).then(|| {
        let (w, h) = full_size;
        full_targets
            .iter()
            .map(|t| crate::resize::resize_area(t, w / div, h / div))
            .collect()
    });
    let targets: &[NetImage] = shrunk.as_deref().unwrap_or(&full_targets);
    let (nw, nh) = targets[0].size();
    if nw % 4 != 0 || nh % 4 != 0 {
        return Err(Error::Input(format!(
            "{} needs network sides divisible by {}, the projector images are {}x{}",
            req.method,
            4 * div,
            nw * div,
            nh * div
        )));
    }
    let device = req.device.candle()?;
    // A bad pre-initialisation file fails now, not after the geometry fit.
    req.photometric.resolve(variant.width())?;
    let surface = setup.load_reference(Reference::Gray)?.masked(&fov.mask)?;
    let on_device = |t: candle_core::Tensor| t.to_device(&device);
    let data = Data {
        captures: crate::nn::images_to_tensor(&captures)
            .and_then(on_device)
            .map_err(ce)?,
        surface: crate::nn::images_to_tensor(std::slice::from_ref(&surface))
            .and_then(on_device)
            .map_err(ce)?,
        targets: crate::nn::images_to_tensor(targets)
            .and_then(on_device)
            .map_err(ce)?,
    };
    let mut settings = Settings::new(variant, req.seed);
    settings.iters = req.iters;
    settings.batch = req.batch;
    settings.photometric = req.photometric.clone();
    let never = std::sync::atomic::AtomicBool::new(false);
    let init = if variant.fixed_geometry() {
        let grid = sl_grid(setup, (nw, nh))?;
        let flat: Vec<f32> = grid.data().iter().flatten().copied().collect();
        GeometryInit::Fixed(
            candle_core::Tensor::from_vec(flat, (1, nh, nw, 2), &device).map_err(ce)?,
        )
    } else {
        // Climb from the rung below: the `linear` fit's affine + TPS geometry (seconds on a CPU)
        // starts the WarpingNet, so the network's few samples go into photometry. Fitted at the
        // data's network size; the warp is resolution independent.
        progress("geometry (linear rung)", 0, 1);
        let settings = FitSettings {
            network_size: full_size,
            refine: None,
            ..FitSettings::default()
        };
        // Its geometry alone: the colour model is not needed here.
        GeometryInit::Warp(crate::linear::fit_geometry(
            &captures,
            &full_targets,
            crate::warp::Warp::from_affine(theta),
            &settings,
        )?)
    };
    let geometry_init = match &init {
        GeometryInit::Fixed(_) => "structured light (fixed)",
        GeometryInit::Warp(_) => "the linear rung's affine + TPS fit",
        GeometryInit::Affine(_) => "the FOV bounding box's affine",
    };
    let (net, report) =
        crate::nn::train::train(&data, init, &settings, &never, |done, total, _| {
            progress("training", done, total)
        })?;
    // Inference, simplification and saving run on the CPU: bring the weights over.
    let net = if device.is_cpu() {
        net
    } else {
        let values: std::collections::HashMap<String, candle_core::Tensor> =
            net.named_tensors().into_iter().collect();
        crate::nn::train::CompenNetPP::restore((nw, nh), variant, &candle_core::Device::Cpu, {
            |name, _shape| {
                values
                    .get(name)
                    .ok_or_else(|| Error::Failed(format!("trained network lacks `{name}`")))?
                    .flatten_all()
                    .and_then(|t| t.to_vec1::<f32>())
                    .map_err(|e| Error::Failed(format!("copying `{name}` from the GPU: {e}")))
            }
        })?
    };
    let final_loss = report.losses.last().copied().unwrap_or(f64::NAN);
    let seconds = start.elapsed().as_secs_f64();
    let meta = ModelMeta {
        format_version: FORMAT_VERSION,
        method: req.method.clone(),
        network_size: (nw, nh),
        camera_size: surface.size(),
        canvas: None,
        training: json!({
            "setup": setup.path(),
            "data_root": setup.root().path(),
            "ntrain": captures.len(),
            "seed": req.seed,
            "fov": fov.diagnostics,
            "fov_bbox": fov.bbox,
            "settings": settings,
            "iterations": report.iterations,
            "batch": report.batch,
            "lr_step": report.lr_step,
            "final_loss": final_loss,
            "device": req.device,
            "geometry_init": geometry_init,
            "photometric_init": report.photometric_init,
        }),
        metrics: serde_json::Value::Null,
        timings: json!({ "fit_seconds": report.seconds, "train_seconds": seconds,
                         "ms_per_sample": report.ms_per_sample }),
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
    };
    let summary = Summary {
        method: req.method.clone(),
        ntrain: captures.len(),
        seconds,
        fit_seconds: report.seconds,
        final_loss,
    };
    Ok((Model::compennet(meta, fov.mask, net, surface)?, summary))
}
