//! Training a model on a setup: the shared core of `compend train`, `compend bench` and
//! calibration. Loads the references and training pairs, finds the projector FOV, fits the
//! requested rung and returns the model ready to save.
//!
//! Files by step: this file checks the request, loads the references, FOV and training pairs
//! and dispatches; `linear_rungs.rs` fits the linear rungs (and `auto`'s choice among them);
//! `compennet.rs` prepares the data of a CompenNet++ rung, starts its geometry, trains it and
//! brings its weights to the CPU; `growing.rs` grows a linear rung's fit pair by pair as a
//! calibration's closed-loop pairs arrive. Each writes the model's record (docs/architecture.md, "Model
//! directory"). `rule.rs` holds the climbing rule `auto` and the service share; `live.rs` the
//! frame budget a climb's live pass must fit. The training device is [`crate::nn::device`]'s.

mod auto;
mod compennet;
mod growing;
mod linear_rungs;
mod live;
mod rule;

pub use crate::nn::device::TrainDevice;
pub use auto::{climb_rung, evidence_lines, judges_on_loop_pairs, lower_rung, settle_climb};
pub use growing::GrowingFit;
pub use live::{LIVE_SHARE, LiveCost, LivePass, PassShape, budgeted, refresh_rate_problem};
pub use rule::{ClimbRule, DEFAULT_CLIMB_GAIN_DB, DEFAULT_RIG_GAIN_DB};

use std::borrow::Cow;
use std::time::Instant;

use serde::Serialize;

use crate::dataset::{CaptureSet, Reference, Setup};
use crate::error::{Error, Result};
use crate::fov;
use crate::model::{Method, MethodChoice, Model};
use crate::raster::{CamImage, Camera, ImageSize, Levels, NetImage, Network, ReadRgb, Rect};
use crate::record::TrainingRecord;
use crate::sample::Grid;

/// Fewest training pairs the linear rungs accept.
pub const MIN_TRAIN: usize = 4;
/// Training pairs used when the caller does not say.
pub const DEFAULT_TRAIN: usize = 48;

/// What to train.
#[derive(Clone, Debug)]
pub struct Request {
    /// The rung, or `auto`.
    pub method: MethodChoice,
    /// Training pairs to use (the first N); `None` = all available, at most [`DEFAULT_TRAIN`]
    /// (a CompenNet++ rung: its schedule's count), and for a linear rung, a residual rung or
    /// `auto` also every closed-loop pair (`cam/desire/train`).
    pub ntrain: Option<usize>,
    pub seed: u64,
    /// CompenNet++ only: override the variant's iterations (the lr step scales) and batch size.
    pub iters: Option<usize>,
    pub batch: Option<usize>,
    /// Where the CompenNet++ variants train (the `linear` rungs are closed-form CPU fits).
    pub device: TrainDevice,
    /// The `linear` rungs only: the lattice of the colour model and of its output images;
    /// `None` = [`default_lattice`] of the setup (the projector's resolution when known).
    pub lattice: Option<ImageSize>,
    /// The projector's resolution when the caller knows it (`calibrate` does); `None`: the size
    /// of the data root's structured-light patterns, if it has them, else the one a calibration
    /// recorded in the setup's manifest. Sets the default lattice.
    pub projector: Option<ImageSize>,
    /// CompenNet++ variants: how CompenNet's weights start (default: the shipped
    /// pre-initialisation, docs/architecture.md, "Models").
    pub photometric: crate::nn::pretrain::PhotometricInit,
    /// Set by another thread to stop a CompenNet++ training at its next iteration
    /// ([`crate::Error::Cancelled`]); the closed-form `linear` rungs run to their end.
    pub cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// `auto` only: the PSNR gain (dB) a CompenNet++ rung needs over the best linear rung to be
    /// chosen: on held-out pairs, or in closed loop on the rig with `rig_judges`; `None` =
    /// [`DEFAULT_CLIMB_GAIN_DB`], or [`DEFAULT_RIG_GAIN_DB`] with `rig_judges`.
    pub climb_gain_db: Option<f64>,
    /// `auto` only: choose among the linear rungs and leave the climb for a later fit on the
    /// closed-loop pairs the chosen rung takes (`calibrate` does, [`judges_on_loop_pairs`]).
    pub climb_later: bool,
    /// `auto` only: the caller projects the climbed rung and the best linear rung on the rig and
    /// keeps the one the rig shows better by the margin ([`settle_climb`]; `calibrate`, the
    /// service, `bench`). The climb rung is then trained on every pair of its kind, with no
    /// held-out judgement, and returned for that check; `climb_gain_db` is the rig's margin
    /// ([`DEFAULT_RIG_GAIN_DB`] when `None`).
    pub rig_judges: bool,
    /// The `linear` geometry shared by the fits of one calibration ([`crate::linear::GeometryMemo`]:
    /// a fit takes it only when it was fitted on the same things); `None`: `auto` shares one
    /// among its own fits, and any other request fits its geometry afresh.
    pub geometry_memo: Option<std::sync::Arc<crate::linear::GeometryMemo>>,
    /// `auto` only: times the climb rung's live pass where the model is to play; a rung whose
    /// pass does not fit the display's frame budget is not climbed to ([`LivePass`]). `None`:
    /// the live pass is not weighed (the model may play elsewhere).
    pub live: Option<std::sync::Arc<dyn LivePass>>,
    /// The `linear` rungs only: how their colour solve ends ([`crate::linear::ColourSolve`]):
    /// per pixel, or one global model for a fit that grows its own coefficients
    /// ([`GrowingFit`]).
    pub colour: crate::linear::ColourSolve,
}

impl Request {
    /// `method` on every available pair (see [`Request::ntrain`]), seed 0, its schedule's
    /// iterations and batch, on the CPU, the default lattice and photometric start, no
    /// cancellation, `auto` with the default margin and its climb judged now, retrained at once
    /// and not weighed for a live pass: what a caller changes is then written beside
    /// `..Request::new(method)`.
    pub fn new(method: MethodChoice) -> Self {
        Request {
            method,
            ntrain: None,
            seed: 0,
            iters: None,
            batch: None,
            device: TrainDevice::Cpu,
            lattice: None,
            projector: None,
            photometric: Default::default(),
            cancel: None,
            climb_gain_db: None,
            climb_later: false,
            rig_judges: false,
            geometry_memo: None,
            live: None,
            colour: Default::default(),
        }
    }
}

/// The default output lattice of the `linear` rungs: the projector's resolution (`projector`,
/// when the setup knows it), scaled down to at most [`LATTICE_BUDGET`] pixels with its aspect
/// kept; without it, 1.5× the network size. Sides are rounded up to a multiple of 4 (256² →
/// 384²). The per-pixel model costs little more on a finer lattice in time (memory grows about
/// 0.5 kB per lattice pixel in training), and a network-size image stretched over the canvas
/// has fewer pixels across the displayable area than the camera sees there. On the virtual
/// rig's white plane, textured plane and curved scene (seed 301, 48 pairs, 800×600
/// projector), the projector's resolution took `linear` from 0.44–0.63 dB below the physical
/// ceiling at 384² to 0.20–0.28 dB (docs/bench/ladder.md).
pub fn default_lattice(network: ImageSize, projector: Option<ImageSize>) -> ImageSize {
    let round = |v: f64| ((v.ceil() as usize).max(8)).div_ceil(4) * 4;
    match projector {
        Some(p) => {
            let pixels = (p.width * p.height) as f64;
            let k = (LATTICE_BUDGET as f64 / pixels).sqrt().min(1.0);
            ImageSize::new(round(p.width as f64 * k), round(p.height as f64 * k))
        }
        None => ImageSize::new(
            round(network.width as f64 * 1.5),
            round(network.height as f64 * 1.5),
        ),
    }
}

/// The most pixels of a default lattice: 1920×1080. A 4K projector's default lattice is this
/// many pixels of its aspect, stretched over the frame by the pass. At this size `linear` trained
/// in 15–17 s with a 1.4–1.6 GB peak (curved scene with a 1920×1080 projector and a 640×480
/// camera, 48 pairs, release build, 2 cores; docs/bench/ladder.md, "A faster, leaner `linear`
/// fit"), 0.27 dB below the physical ceiling.
pub const LATTICE_BUDGET: usize = 1920 * 1080;

/// What training reports besides the model.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub method: Method,
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
    let variant = match req.method {
        MethodChoice::Rung(m) => crate::nn::compennetpp::Variant::from_method(m.name()),
        MethodChoice::Auto => None,
    };
    check_request(req, variant)?;
    let req = &with_lattice(setup, req, variant)?;
    let ntrain = train_count(setup, req, variant)?;
    let data = load_training(setup, variant.is_none(), ntrain)?;
    match (variant, req.method) {
        (Some(variant), MethodChoice::Rung(method)) => {
            let (model, summary, _) = compennet::train_compennet(
                setup,
                req,
                (method, variant),
                data,
                None,
                start,
                progress,
            )?;
            Ok((model, summary))
        }
        (None, MethodChoice::Rung(method)) => {
            linear_rungs::fit_linear(setup, req, method, None, ntrain, data, start, progress)
        }
        (_, MethodChoice::Auto) => auto::fit_auto(setup, req, ntrain, data, start, progress),
    }
}

/// The `linear` geometry that a fit of `req` on `setup` starts with, fitted now on the setup's
/// first `pairs` pairs (the fit's geometry images, [`crate::linear::FitSettings`], or all its
/// pairs when it has fewer) and left in `req.geometry_memo` for that fit to take ([`linear::GeometryMemo`]).
/// A calibration starts it as soon as those pairs are on disk, while it still captures the
/// rest. Nothing to do without a memo.
pub fn prefit_geometry(setup: &Setup, req: &Request, pairs: usize) -> Result<()> {
    let Some(memo) = req.geometry_memo.as_deref() else {
        return Ok(());
    };
    let data = load_training(setup, true, pairs)?;
    let settings = linear_rungs::settings(req, data.network_size);
    crate::linear::prefit_geometry(
        &data.captures,
        &data.targets,
        crate::warp::Warp::from_affine(data.theta),
        &settings,
        memo,
    )
}

/// `req` with the output lattice of the linear rungs (also under the residual rung and
/// `auto`) resolved ([`lattice_choice`]), which is logged with its reason.
fn with_lattice(
    setup: &Setup,
    req: &Request,
    variant: Option<crate::nn::compennetpp::Variant>,
) -> Result<Request> {
    if req.lattice.is_some() || variant.is_some_and(|v| !v.residual()) {
        return Ok(req.clone());
    }
    let (lattice, why) = lattice_choice(setup, req)?;
    tracing::info!("the linear rungs' output lattice is {lattice}: {why}");
    let network = setup.root().network_size()?;
    if lattice.width < network.width || lattice.height < network.height {
        tracing::warn!(
            "the linear rungs' output will be {lattice}, coarser than the {network} network \
             ({why}); --lattice sets another"
        );
    }
    Ok(Request {
        lattice: Some(lattice),
        ..req.clone()
    })
}

/// The output lattice of the linear rungs for `req` on `setup`, and why, in words: as asked
/// (`req.lattice`), else the default for the projector's resolution ([`default_lattice`]):
/// the caller's (`--projector`, a calibration's display), else the structured-light patterns'
/// size, else what a calibration recorded for this setup; 1.5× the network size when none
/// says.
pub fn lattice_choice(setup: &Setup, req: &Request) -> Result<(ImageSize, String)> {
    if let Some(l) = req.lattice {
        return Ok((l, "as asked (--lattice)".into()));
    }
    let network = setup.root().network_size()?;
    let (projector, source) = projector_size(setup, req)?;
    let lattice = default_lattice(network, projector);
    let why = match projector {
        None => format!(
            "1.5× the {network} network, as the data gives no projector size (no \
             structured-light patterns, no calibration record); give --projector WxH, or \
             --lattice"
        ),
        Some(p) if p != lattice => {
            format!("the projector's {p} ({source}), scaled to at most 1920×1080 pixels")
        }
        Some(p) => format!("the projector's resolution, {p} ({source})"),
    };
    Ok((lattice, why))
}

/// The projector's resolution: the caller's, else the structured-light patterns' size, else
/// what a calibration recorded for this setup; `None` when none says. With where it came from,
/// in words.
fn projector_size(setup: &Setup, req: &Request) -> Result<(Option<ImageSize>, &'static str)> {
    Ok(match (req.projector, setup.root().projector_size()) {
        (Some(size), _) => (Some(size), "given: --projector, or the calibrated display"),
        (None, Ok(size)) => (Some(size), "the structured-light patterns' size"),
        (None, Err(Error::Missing { .. })) => (
            crate::dataset::manifest::recorded_projector(setup.path())?,
            "recorded by the calibration",
        ),
        (None, Err(e)) => return Err(e),
    })
}

/// The argument checks that need no data: `--lattice` only for the linear rungs (and `auto`'s)
/// and at least 8×8 pixels, `--iters` and `--batch` only for the CompenNet++ rungs (and the one
/// `auto` climbs to) and at least 1, a usable training device, and a climbing margin that is a
/// number, all before anything is loaded.
fn check_request(req: &Request, variant: Option<crate::nn::compennetpp::Variant>) -> Result<()> {
    let auto = req.method == MethodChoice::Auto;
    if let Some(gain) = req.climb_gain_db {
        if !auto {
            return Err(Error::Input(format!(
                "--climb-gain {gain}: only `auto` climbs the ladder; {} is one rung",
                req.method
            )));
        }
        if !gain.is_finite() {
            return Err(Error::Input(format!(
                "--climb-gain {gain}: expected a number of dB"
            )));
        }
    }
    if auto {
        req.device.candle()?;
    }
    if let Some(v) = variant {
        if let Some(lattice) = req.lattice
            && !v.residual()
        {
            return Err(Error::Input(format!(
                "--lattice {lattice}: only the linear rungs have an output lattice; {} works at \
                 the network size",
                req.method
            )));
        }
        // Fail before loading anything when the device is unusable.
        req.device.candle()?;
        if v == crate::nn::compennetpp::Variant::ResFull && req.device == TrainDevice::Cpu {
            tracing::warn!(
                "{}: sized for a GPU (--device cuda); on the CPU each sample costs about 16 \
                 times compennet++-res's multiply-adds",
                req.method
            );
        }
    }
    for (flag, value) in [("--iters", req.iters), ("--batch", req.batch)] {
        match value {
            Some(0) => {
                return Err(Error::Input(format!("{flag} 0: expected at least 1")));
            }
            Some(n) if variant.is_none() && !auto => {
                return Err(Error::Input(format!(
                    "{flag} {n}: only the CompenNet++ rungs train in iterations and batches; \
                     {} is a closed-form fit",
                    req.method
                )));
            }
            _ => {}
        }
    }
    if let Some(lattice) = req.lattice
        && (lattice.width < 8 || lattice.height < 8)
    {
        return Err(Error::Input(format!(
            "--lattice {lattice}: expected at least 8x8 pixels"
        )));
    }
    Ok(())
}

/// The number of training pairs to use: `--ntrain`, else what the setup holds up to the rung's
/// default, and for a method that takes closed-loop pairs (a linear rung, a residual rung,
/// `auto`) up to the last of those; at least [`MIN_TRAIN`].
fn train_count(
    setup: &Setup,
    req: &Request,
    variant: Option<crate::nn::compennetpp::Variant>,
) -> Result<usize> {
    let available = setup.count(CaptureSet::Train)?;
    let default_train = variant.map_or(DEFAULT_TRAIN, |v| v.schedule().train_pairs);
    let takes_loops = match req.method {
        MethodChoice::Rung(_) => variant.is_none_or(|v| v.residual()),
        MethodChoice::Auto => true,
    };
    // The closed-loop views are checked whatever --ntrain says.
    let last_loop = if takes_loops {
        let loops = crate::dataset::manifest::checked_loop_pairs(setup, available, req.ntrain)?;
        match req.ntrain {
            None => loops.last().copied().unwrap_or(0),
            Some(_) => 0,
        }
    } else {
        0
    };
    let ntrain = req
        .ntrain
        .unwrap_or(available.min(default_train).max(last_loop));
    if ntrain < MIN_TRAIN {
        return Err(Error::Input(format!(
            "--ntrain {ntrain}: the {} method needs at least {MIN_TRAIN} training pairs ({} has {available})",
            req.method,
            setup.capture_dir(CaptureSet::Train).display()
        )));
    }
    Ok(ntrain)
}

/// What every rung starts from. Its pairs are owned as loaded, or borrowed from another's
/// ([`TrainingData::first`]). The captures are held as the levels their files store
/// ([`Levels`]): 88 captures at 640×480 hold 81 MB that way, against 324 MB as f32 values.
struct TrainingData<'a> {
    /// The projector FOV mask (camera pixels) from the black and white references.
    fov: fov::FovMask,
    /// Camera size, (width, height) pixels: the black reference's.
    cam_size: ImageSize,
    /// The warp's affine start from the FOV's bounding box (network → camera, normalised).
    theta: [[f32; 3]; 2],
    /// Network size, (width, height) pixels: the first projector image's.
    network_size: ImageSize,
    /// The first `ntrain` captures x̃_i, masked by the FOV (camera pixels).
    captures: Cow<'a, [Levels<Camera>]>,
    /// Their projector images x_i (network pixels).
    targets: Cow<'a, [NetImage]>,
}

impl TrainingData<'_> {
    /// The same data with only its first `k` pairs, borrowed.
    fn first(&self, k: usize) -> TrainingData<'_> {
        TrainingData {
            fov: self.fov.clone(),
            cam_size: self.cam_size,
            theta: self.theta,
            network_size: self.network_size,
            captures: Cow::Borrowed(&self.captures[..k]),
            targets: Cow::Borrowed(&self.targets[..k]),
        }
    }
}

/// Loads the references, finds the FOV and its affine start, and loads the first `ntrain`
/// pairs. `linear`: the rung does not need the gray surface image (its absence is a warning).
fn load_training(setup: &Setup, linear: bool, ntrain: usize) -> Result<TrainingData<'static>> {
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let label = format!(
        "{} and {}",
        setup.reference_path(Reference::Black).display(),
        setup.reference_path(Reference::White).display()
    );
    let gray = setup.reference_path(Reference::Gray);
    if linear && !gray.is_file() {
        // The linear rungs do not use it; the setup is still incomplete (inspect says so).
        tracing::warn!(
            "{}: missing (the gray surface capture); the linear rungs train without it, but \
             the CompenNet++ rungs and `inspect` need it",
            gray.display()
        );
    }
    let fov = fov::fov_mask(&black, &white, &label)?;
    let cam_size = black.size();
    let theta = fov::affine_from_box(fov.bbox, cam_size)?;
    let (captures, inputs) = setup.load_train_levels(Some(ntrain))?;
    let network_size = inputs[0].size();
    // Masked in place: a second copy of every capture was a quarter of the fit's peak memory.
    let captures: Vec<Levels<Camera>> = captures
        .into_iter()
        .map(|c| c.into_masked(&fov.mask))
        .collect::<Result<_>>()?;
    check_projector_light(setup, &captures, (&black, &white), &fov.mask)?;
    let targets: Vec<NetImage> = inputs.into_iter().map(|p| p.into_space()).collect();
    Ok(TrainingData {
        fov,
        cam_size,
        theta,
        network_size,
        captures: Cow::Owned(captures),
        targets: Cow::Owned(targets),
    })
}

/// Of the way from the black to the white reference capture (mean over the projector's area),
/// the least the brightest training capture must come: sampling images average mid-gray, so
/// their captures come about halfway.
const MIN_LIGHT: f64 = 0.05;

/// Refuses training captures (masked by the FOV, camera pixels) none of which shows projector
/// light in the projector's area: taken with the projector off or covered, they would train a
/// model that shows flat gray whatever it is asked, and replace a good one.
fn check_projector_light(
    setup: &Setup,
    captures: &[Levels<Camera>],
    (black, white): (&CamImage, &CamImage),
    mask: &crate::raster::Mask<Camera>,
) -> Result<()> {
    fn inside(img: &impl ReadRgb<Camera>, mask: &crate::raster::Mask<Camera>) -> f64 {
        let sum: f64 = (mask.data().iter().enumerate())
            .filter(|(_, m)| **m)
            .map(|(p, _)| img.pixel(p).iter().map(|&v| v as f64).sum::<f64>())
            .sum();
        sum / (3 * mask.count().max(1)) as f64
    }
    let dark = inside(black, mask);
    let span = inside(white, mask) - dark;
    let brightest = captures
        .iter()
        .map(|c| inside(c, mask) - dark)
        .fold(f64::NEG_INFINITY, f64::max);
    if span > 0.0 && brightest < MIN_LIGHT * span {
        return Err(Error::Input(format!(
            "{}: none of the {} training captures shows projector light in the projector's \
             area (the brightest comes {:.1} % of the way from the black to the white \
             reference capture, expected at least {:.0} %): were they taken with the projector \
             off or covered?",
            setup.capture_dir(CaptureSet::Train).display(),
            captures.len(),
            100.0 * brightest.max(0.0) / span,
            100.0 * MIN_LIGHT
        )));
    }
    Ok(())
}

/// The network→camera grid from the setup's structured-light captures; the network image is
/// assumed stretched over the whole projector frame (the size of the root's sl/ patterns).
pub fn sl_grid(setup: &Setup, network_size: ImageSize) -> Result<Grid<Network, Camera>> {
    let projector = setup.root().projector_size()?;
    let code = crate::patterns::GrayCode::new(projector.width, projector.height)?;
    let captures = setup.load_captures(CaptureSet::Sl, None)?;
    if captures.len() != code.len() {
        return Err(Error::Input(format!(
            "{}: {} structured-light captures, expected {} for a {} projector",
            setup.capture_dir(CaptureSet::Sl).display(),
            captures.len(),
            code.len(),
            projector
        )));
    }
    let corr = code.decode(&captures)?;
    let canvas = Rect {
        x: 0,
        y: 0,
        width: projector.width,
        height: projector.height,
    };
    Ok(crate::slgrid::grid_from_correspondence(&corr, canvas, network_size)?.grid)
}

/// The part of the training record every rung writes.
fn common_record(
    setup: &Setup,
    ntrain: usize,
    seed: u64,
    fov: &fov::FovMask,
    settings: &impl Serialize,
    final_loss: f64,
) -> Result<TrainingRecord> {
    let json = |v: serde_json::Result<serde_json::Value>| {
        v.map_err(|e| Error::Failed(format!("training record: {e}")))
    };
    Ok(TrainingRecord {
        setup: Some(setup.path().to_path_buf()),
        data_root: Some(setup.root().path().to_path_buf()),
        ntrain,
        seed,
        fov: json(serde_json::to_value(&fov.diagnostics))?,
        fov_bbox: Some(fov.bbox),
        settings: json(serde_json::to_value(settings))?,
        final_loss: final_loss.is_finite().then_some(final_loss),
        ..TrainingRecord::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_lattice_is_the_projectors_within_the_budget() {
        let net = ImageSize::new(256, 256);
        // Known projector within the budget: its own resolution.
        let p = ImageSize::new(800, 600);
        assert_eq!(default_lattice(net, Some(p)), p);
        assert_eq!(
            default_lattice(net, Some(ImageSize::new(1920, 1080))),
            ImageSize::new(1920, 1080)
        );
        // 4K: scaled to the budget, aspect kept, sides multiples of 4.
        let l = default_lattice(net, Some(ImageSize::new(3840, 2160)));
        assert_eq!(l, ImageSize::new(1920, 1080));
        let l = default_lattice(net, Some(ImageSize::new(4096, 2160)));
        assert!(
            l.width * l.height <= LATTICE_BUDGET + 4 * (l.width + l.height),
            "{l}"
        );
        assert!(
            l.width.is_multiple_of(4) && l.height.is_multiple_of(4),
            "{l}"
        );
        assert!(
            (l.width as f64 / l.height as f64 - 4096.0 / 2160.0).abs() < 0.01,
            "{l}"
        );
        // Unknown projector: 1.5× the network, rounded up to a multiple of 4.
        assert_eq!(default_lattice(net, None), ImageSize::new(384, 384));
        assert_eq!(
            default_lattice(ImageSize::new(30, 22), None),
            ImageSize::new(48, 36)
        );
    }
}
