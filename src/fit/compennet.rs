//! A CompenNet++ rung's training (docs/architecture.md, "Models"): its data on the training
//! device (projector images shrunk onto a coarser network for the smaller rungs), the
//! WarpingNet's start (the `linear` rung's geometry, or structured light for `compennet-sl`),
//! the training loop, the weights brought to the CPU, and the model's record.

use std::time::Instant;

use super::rule::{ClimbRule, Stop};
use super::{Request, Summary, TrainingData, common_record, sl_grid};
use crate::dataset::{Reference, Setup};
use crate::error::{Error, Result};
use crate::fov;
use crate::linear::FitSettings;
use crate::metrics::Scores;
use crate::model::store::{FORMAT_VERSION, ModelMeta};
use crate::model::{Method, Model};
use crate::raster::{CamImage, Camera, ImageSize, Levels, NetImage, Network};
use crate::record::{
    AutoCandidate, JudgedTraining, LoopCheckpoint, LoopHeldOut, Timings, TrainingRecord,
};
use crate::sample::Grid;

/// The residual rung's learning rate (Adam's step size before the lr step): a fifth of the
/// paper's, as for fine-tuning.
const RESIDUAL_LEARNING_RATE: f64 = 2e-4;

/// `auto`'s judgement of the residual rung while it trains ([`LoopHeldOut`]): pairs held out of
/// its training, and the margin it must reach on them.
pub(super) struct Judge<'a> {
    /// 1-based indices of the held-out pairs in `captures` and `targets`.
    pub(super) indices: Vec<usize>,
    /// Whether they are closed-loop pairs, judged on their desired views
    /// ([`closed_loop_data`]), or sampling pairs, judged by the paper protocol (a capture in,
    /// its projector image the target).
    pub(super) closed_loop: bool,
    /// The held-out PSNR (dB) the rung must beat by the margin; `None`: its own linear part's.
    pub(super) lower_psnr: Option<f64>,
    /// Every pair, the held-out ones included: captures masked by the FOV (camera pixels) and
    /// projector images (network pixels).
    pub(super) captures: &'a [Levels<Camera>],
    pub(super) targets: &'a [NetImage],
    /// The climbing rule: the training stops once the rung cannot reach its margin
    /// ([`ClimbRule::out_of_reach`]) or once its gain has settled past it
    /// ([`ClimbRule::settled`]).
    pub(super) rule: ClimbRule,
}

/// How many checkpoints a judged training has after its start: one every tenth of its
/// iterations.
const CHECKPOINTS: usize = 10;

/// Trains a CompenNet++ variant on already masked captures. With a `judge` (the residual rung
/// only), the rung is scored on the judge's held-out pairs as it trains and the judgement is
/// returned too; the training stops early when it cannot reach the margin, or when its gain has
/// settled past it.
pub(super) fn train_compennet(
    setup: &Setup,
    req: &Request,
    (method, variant): (Method, crate::nn::compennetpp::Variant),
    data: TrainingData<'_>,
    judge: Option<Judge<'_>>,
    start: Instant,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<(Model, Summary, Option<LoopHeldOut>)> {
    use crate::nn::train::Settings;
    if judge.is_some() && !variant.residual() {
        return Err(Error::Failed(format!(
            "{method}: only the residual rungs are judged on held-out pairs as they train"
        )));
    }
    let TrainingData {
        fov,
        theta,
        captures,
        targets,
        ..
    } = data;
    let mut prepared = prepare_compennet_data(setup, req, variant, &fov, &captures, &targets)?;
    let mut correction = Correction::None;
    let mut held = None;
    let mut geometry_reused = false;
    // The residual rung stands on the `linear` rung: fitted here on the same pairs, its output
    // for each capture (brought to the network) is what the network corrects.
    let linear = if variant.residual() {
        let settings = FitSettings {
            network_size: targets[0].size(),
            // Resolved by `fit` (the default lattice when none was asked for).
            lattice: req.lattice,
            ..FitSettings::default()
        };
        let (linear, linear_report) = crate::linear::fit_with_memo(
            &captures,
            &targets,
            crate::warp::Warp::from_affine(theta),
            &settings,
            req.geometry_memo.as_deref(),
            &mut progress,
        )?;
        geometry_reused = linear_report.geometry_reused;
        let simplified = linear.simplify();
        let ImageSize {
            width: nw,
            height: nh,
        } = targets[0].size();
        // `linear`'s output for a camera image, at the data's network size.
        let lin = |c: &CamImage| crate::resize::unstretch(&simplified.apply(c), nw, nh);
        let loop_pairs = setup.loop_pairs(captures.len())?;
        let grid = linear.grid_at(targets[0].size())?;
        if let Some(judge) = &judge {
            held = Some(HeldOut::new(
                setup,
                judge,
                (&fov, &grid),
                &simplified,
                &prepared.data.surface,
            )?);
        }
        if loop_pairs.len() >= super::MIN_TRAIN {
            let (inputs, base, goals) = closed_loop_data(
                setup,
                &loop_pairs,
                (&fov, &grid),
                (&captures, &targets),
                lin,
            )?;
            let device = &prepared.device;
            prepared.data.captures = crate::nn::images_to_tensor(&inputs)?.to_device(device)?;
            prepared.data.targets = crate::nn::images_to_tensor(&goals)?.to_device(device)?;
            prepared.data.base = Some(crate::nn::images_to_tensor(&base)?.to_device(device)?);
            correction = Correction::ClosedLoop(loop_pairs.len());
        } else {
            if !loop_pairs.is_empty() {
                tracing::warn!(
                    "{}: {} closed-loop pairs, fewer than {}; the correction trains on every \
                     pair with the paper protocol's target",
                    setup.loop_desired_dir().display(),
                    loop_pairs.len(),
                    super::MIN_TRAIN
                );
            }
            let base: Vec<NetImage> = captures.iter().map(|c| lin(&c.to_values())).collect();
            prepared.data.base =
                Some(crate::nn::images_to_tensor(&base)?.to_device(&prepared.device)?);
            correction = Correction::PaperProtocol(captures.len());
        }
        Some(linear)
    } else {
        None
    };
    let mut settings = Settings::new(variant, req.seed);
    settings.iters = req.iters;
    settings.batch = req.batch;
    settings.photometric = req.photometric.clone();
    if variant.residual() {
        // Adam's first steps move every weight by about the learning rate whatever the
        // gradient's size: from a last layer at zero, the paper's 1e-3 makes the first
        // corrections large enough to undo part of what `linear` got right.
        settings.learning_rate = RESIDUAL_LEARNING_RATE;
    }
    let never = std::sync::atomic::AtomicBool::new(false);
    let cancel = req.cancel.as_deref().unwrap_or(&never);
    let (init, geometry_init) = geometry_start(
        setup,
        (variant, linear.as_ref()),
        &prepared,
        theta,
        &captures,
        &targets,
        &mut progress,
    )?;
    let total = settings.resolved().1;
    let every = (total / CHECKPOINTS).max(1);
    let mut curve: Vec<LoopCheckpoint> = Vec::new();
    let mut last: Option<Scores> = None;
    // Where the judged training stopped early, and why.
    let mut stopped: Option<(usize, Stop)> = None;
    let (net, report) = crate::nn::train::train(
        &prepared.data,
        init,
        &settings,
        cancel,
        |done, total, _| progress("training", done, total),
        |done, net| {
            let (Some(held), Some(judge)) = (&held, &judge) else {
                return Ok(true);
            };
            if done % every != 0 && done != total {
                return Ok(true);
            }
            let scores = held.score(net)?;
            curve.push(LoopCheckpoint {
                iteration: done,
                psnr: scores.psnr,
            });
            last = Some(scores);
            let lower = judge.lower_psnr.unwrap_or(held.linear.psnr);
            let gains: Vec<(usize, f64)> = curve
                .iter()
                .map(|c| (c.iteration, c.psnr - lower))
                .collect();
            let stop = judge.rule.stop_at(&gains, done, total);
            if let (Some(Stop::OutOfReach), [.., (i1, g1), (i2, g2)]) = (stop, gains.as_slice()) {
                tracing::info!(
                    "auto: {method} stops at iteration {done} of {total}: {g2:+.2} dB over \
                     the rung below on the held-out pairs, its rise slowed to {:+.3} dB in the \
                     last {} iterations; at that rate it would not reach {:+} dB by the end",
                    g2 - g1,
                    i2 - i1,
                    judge.rule.gain_db
                );
            }
            if let (Some(Stop::Settled), [.., (_, g1), (_, g2)]) = (stop, gains.as_slice()) {
                tracing::info!(
                    "auto: {method} stops at iteration {done} of {total}: {g1:+.2} and then \
                     {g2:+.2} dB over the rung below on the held-out pairs, past the {:+} dB \
                     margin",
                    judge.rule.gain_db
                );
            }
            stopped = stop.map(|s| (done, s));
            Ok(stop.is_none())
        },
    )?;
    let net = weights_to_cpu(net, &prepared.device, prepared.size, variant)?;
    let final_loss = report.losses.last().copied().unwrap_or(f64::NAN);
    let seconds = start.elapsed().as_secs_f64();
    let CompenNetData { surface, size, .. } = prepared;
    // The residual rung's output is on `linear`'s lattice.
    let network_size = linear.as_ref().map_or(size, |l| l.network_size());
    let meta = ModelMeta {
        format_version: FORMAT_VERSION,
        method,
        network_size,
        camera_size: surface.size(),
        canvas: None,
        training: TrainingRecord {
            iterations: Some(report.iterations),
            batch: Some(report.batch),
            lr_step: Some(report.lr_step),
            device: Some(req.device),
            geometry_init: Some(geometry_init.into()),
            photometric_init: Some(report.photometric_init.clone()),
            correction: correction.describe(),
            geometry_reused,
            ..common_record(setup, captures.len(), req.seed, &fov, &settings, final_loss)?
        },
        metrics: serde_json::Value::Null,
        timings: Timings {
            fit_seconds: report.seconds,
            train_seconds: seconds,
            ms_per_sample: Some(report.ms_per_sample),
        },
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
        weights_sha256: None,
        calibration: None,
    };
    let summary = Summary {
        method,
        ntrain: captures.len(),
        seconds,
        fit_seconds: report.seconds,
        final_loss,
    };
    let model = match linear {
        Some(linear) => Model::residual(meta, fov.mask, linear, net, surface)?,
        None => Model::compennet(meta, fov.mask, net, surface)?,
    };
    let judged = match (judge, held) {
        (Some(judge), Some(held)) => {
            // The figures that decide: the last checkpoint's, on the weights the model holds.
            let up = last
                .ok_or_else(|| Error::Failed(format!("{method}: its training was never scored")))?;
            let entry = |method, s: &Scores, fit_seconds| AutoCandidate {
                method,
                held_out_psnr: s.psnr,
                held_out_ssim: s.ssim,
                fit_seconds,
            };
            let at = |why: Stop| stopped.filter(|(_, s)| *s == why).map(|(i, _)| i);
            Some(LoopHeldOut {
                pairs: judge.indices.len(),
                trained_on: correction.loop_pairs(),
                scores: vec![
                    entry(Method::Linear, &held.linear, 0.0),
                    entry(method, &up, seconds),
                ],
                training: JudgedTraining {
                    iterations: total,
                    stopped_at: at(Stop::OutOfReach),
                    settled_at: at(Stop::Settled),
                    curve,
                },
            })
        }
        _ => None,
    };
    Ok((model, summary, judged))
}

/// The held-out pairs of a [`Judge`], for scoring the residual rung as it trains: the network's
/// inputs (camera pixels: desired views of closed-loop pairs, or sampling captures), `linear`'s
/// outputs for them on its output lattice, and the pairs' targets (network pixels: from
/// [`closed_loop_data`], or the projector images).
struct HeldOut {
    inputs: candle_core::Tensor,
    surface: candle_core::Tensor,
    /// `linear`'s output for each view, on its lattice, before it is brought into range.
    lattice: Vec<NetImage>,
    goals: Vec<NetImage>,
    /// `linear`'s scores: [`HeldOut::score`] with no correction.
    linear: Scores,
}

impl HeldOut {
    fn new(
        setup: &Setup,
        judge: &Judge<'_>,
        (fov, grid): (&fov::FovMask, &Grid<Network, Camera>),
        simplified: &crate::linear::SimplifiedLinear,
        surface: &candle_core::Tensor,
    ) -> Result<Self> {
        let size = judge.targets[0].size();
        let lin =
            |c: &CamImage| crate::resize::unstretch(&simplified.apply(c), size.width, size.height);
        let (inputs, goals) = if judge.closed_loop {
            let (inputs, _, goals) = closed_loop_data(
                setup,
                &judge.indices,
                (fov, grid),
                (judge.captures, judge.targets),
                lin,
            )?;
            (inputs, goals)
        } else {
            let pair = |i: usize| {
                let k = i.checked_sub(1);
                let found = k.and_then(|k| judge.captures.get(k).zip(judge.targets.get(k)));
                found.ok_or_else(|| {
                    Error::Failed(format!(
                        "held-out pair {i} of {} training pairs",
                        judge.captures.len()
                    ))
                })
            };
            judge
                .indices
                .iter()
                .map(|&i| pair(i).map(|(c, t)| (c.to_values(), t.clone())))
                .collect::<Result<Vec<_>>>()?
                .into_iter()
                .unzip()
        };
        let lattice: Vec<NetImage> = inputs.iter().map(|d| simplified.apply(d)).collect();
        let linear = Self::scores(lattice.iter().map(|a| a.clamp01()), &goals)?;
        Ok(Self {
            inputs: crate::nn::images_to_tensor(&inputs)?.to_device(surface.device())?,
            surface: surface.clone(),
            lattice,
            goals,
            linear,
        })
    }

    /// The rung's scores with `net` as it stands, computed as inference computes its output
    /// ([`crate::model::Model::infer`]): the correction stretched over `linear`'s lattice
    /// output, the sum brought into [0, 1] (what the projector can show), then to the targets'
    /// size.
    fn score(&self, net: &crate::nn::compennetpp::CompenNetPP) -> Result<Scores> {
        // A few pairs at a time: a large data set holds many pairs out, each a camera image.
        const CHUNK: usize = 8;
        let n = self.goals.len();
        let mut outputs = Vec::with_capacity(n);
        for lo in (0..n).step_by(CHUNK) {
            let len = CHUNK.min(n - lo);
            let r = net
                .forward(&self.inputs.narrow(0, lo, len)?, &self.surface)?
                .to_device(&candle_core::Device::Cpu)?;
            for k in 0..len {
                let r: NetImage = crate::nn::tensor_to_image(&r, k)?;
                outputs.push(crate::model::add_correction(&self.lattice[lo + k], &r)?);
            }
        }
        Self::scores(outputs.into_iter(), &self.goals)
    }

    /// Scores of lattice-sized `outputs` against `goals`, each brought to its goal's size.
    fn scores(outputs: impl Iterator<Item = NetImage>, goals: &[NetImage]) -> Result<Scores> {
        let mut acc = crate::metrics::Accumulator::default();
        for (out, goal) in outputs.zip(goals) {
            acc.add(&crate::model::at_size(out, goal.size()), goal)?;
        }
        acc.finish()
    }
}

/// What the residual rung's correction trained on.
enum Correction {
    /// Not the residual rung.
    None,
    /// The paper protocol on this many pairs (sampling pairs, and closed-loop pairs too few to
    /// train on as such): input a capture, target its projector image.
    PaperProtocol(usize),
    /// This many closed-loop pairs ([`closed_loop_data`]).
    ClosedLoop(usize),
}

impl Correction {
    /// The closed-loop pairs it trained on (none for the paper protocol).
    fn loop_pairs(&self) -> usize {
        match self {
            Correction::ClosedLoop(n) => *n,
            _ => 0,
        }
    }

    /// For the record (`training.correction`).
    fn describe(&self) -> Option<String> {
        match self {
            Correction::None => None,
            Correction::PaperProtocol(n) => Some(format!(
                "{n} pairs, paper protocol (input a capture, target its projector image)"
            )),
            Correction::ClosedLoop(n) => Some(format!(
                "{n} closed-loop pairs (input the desired view, target one first-order step of \
                 linear's compensation towards it)"
            )),
        }
    }
}

/// The residual rung's data on closed-loop pairs `indices` (1-based training pair indices
/// with a desired view in `cam/desire/train`), as inference will use it: the network's input
/// is the desired view d (camera pixels, masked by the FOV) and its base `linear`'s
/// compensation `lin(d)`, not a capture. The pair's projector image y was a compensation of d
/// and its capture is x̃, so one first-order step towards d is y + lin(d) − lin(x̃) (clamped to
/// the projector's range): the correction learns y − lin(x̃), `linear`'s error where the
/// desired images are, as a function of what inference sees. On the curved and dark-texture
/// scenes this kept the rung at or above `linear` in closed loop, where the paper protocol's
/// target (the sampling image of a capture) left it below (docs/bench/ladder.md).
/// Outside the displayable area a desired view is black and asks for nothing, while the step
/// there can be large (light spilling from inside, or none reaching it). So the target blends
/// from the step to `linear`'s own output by how much of each projector pixel's camera
/// footprint (`grid`, network → camera) lies where some desired view is not black; without
/// this, the correction learned at the area's edge lost 0.16 dB to `linear` on the step scene
/// (seed 83), with it 0.00 (docs/bench/ladder.md).
/// `captures` (masked) and `targets` are the training pairs in order; `lin` is `linear`'s
/// output at the data's network size. Returns (inputs, base, targets).
fn closed_loop_data(
    setup: &Setup,
    indices: &[usize],
    (fov, grid): (&fov::FovMask, &Grid<Network, Camera>),
    (captures, targets): (&[Levels<Camera>], &[NetImage]),
    lin: impl Fn(&CamImage) -> NetImage,
) -> Result<(Vec<CamImage>, Vec<NetImage>, Vec<NetImage>)> {
    let desired: Vec<CamImage> = setup
        .load_loop_desired(indices)?
        .iter()
        .map(|d| d.masked(&fov.mask))
        .collect::<Result<_>>()?;
    let weight = asked_for(&desired, grid)?;
    let mut inputs = Vec::with_capacity(indices.len());
    let mut base = Vec::with_capacity(indices.len());
    let mut goals = Vec::with_capacity(indices.len());
    for (&i, d) in indices.iter().zip(desired) {
        let lin_d = lin(&d);
        let step = first_order_step(&targets[i - 1], &lin_d, &lin(&captures[i - 1].to_values()))?;
        goals.push(match &weight {
            Some(w) => blend(&lin_d, &step, w)?,
            None => step,
        });
        base.push(lin_d);
        inputs.push(d);
    }
    Ok((inputs, base, goals))
}

/// Network pixels: the share of each one's camera footprint (bilinear, through `grid`) where
/// some of the `desired` views is not black (the displayable area, by what the views hold);
/// `None` without views.
fn asked_for(desired: &[CamImage], grid: &Grid<Network, Camera>) -> Result<Option<NetImage>> {
    let Some(first) = desired.first() else {
        return Ok(None);
    };
    let ImageSize { width, height } = first.size();
    let mut any = vec![0.0f32; 3 * width * height];
    for d in desired {
        for (k, px) in d.data().chunks_exact(3).enumerate() {
            if px.iter().any(|&v| v > 0.0) {
                any[3 * k..3 * k + 3].fill(1.0);
            }
        }
    }
    let any = CamImage::from_vec(width, height, any)?;
    Ok(Some(crate::sample::grid_sample(&any, grid)))
}

/// `from` + `w`·(`to` − `from`), per pixel and channel.
fn blend(from: &NetImage, to: &NetImage, w: &NetImage) -> Result<NetImage> {
    let ImageSize { width, height } = from.size();
    let data = (from.data().iter().zip(to.data()).zip(w.data()))
        .map(|((a, b), w)| a + w * (b - a))
        .collect();
    NetImage::from_vec(width, height, data)
}

/// y + lin(d) − lin(x̃), clamped to [0, 1] (network pixels): the projector image that moves
/// the capture x̃ of `shown` (y) towards the desired view d, to first order in `linear`'s
/// model.
fn first_order_step(shown: &NetImage, lin_d: &NetImage, lin_x: &NetImage) -> Result<NetImage> {
    let ImageSize { width, height } = shown.size();
    for other in [lin_d, lin_x] {
        if other.size() != shown.size() {
            return Err(Error::Failed(format!(
                "closed-loop step: a {} image against a {} projector image",
                other.size(),
                shown.size()
            )));
        }
    }
    let data = (shown.data().iter().zip(lin_d.data()).zip(lin_x.data()))
        .map(|((y, a), b)| (y + a - b).clamp(0.0, 1.0))
        .collect();
    NetImage::from_vec(width, height, data)
}

/// A CompenNet++ rung's training data, on its device.
struct CompenNetData {
    data: crate::nn::train::Data,
    /// The gray surface image s̃ masked by the FOV (camera pixels).
    surface: CamImage,
    /// The rung's network size, (width, height) pixels: the data's, divided by the rung's
    /// network divisor.
    size: ImageSize,
    device: candle_core::Device,
}

/// Brings the training data onto the device: the masked captures, the masked surface image and
/// the projector images, shrunk onto the rung's network when it is coarser. Checks the sides,
/// the device and the photometric pre-initialisation before the geometry fit.
fn prepare_compennet_data(
    setup: &Setup,
    req: &Request,
    variant: crate::nn::compennetpp::Variant,
    fov: &fov::FovMask,
    captures: &[Levels<Camera>],
    full_targets: &[NetImage],
) -> Result<CompenNetData> {
    use crate::nn::train::Data;
    // A smaller rung works on a coarser network: the projector images are shrunk onto it (their
    // canvas stretch shows the same picture, a little blurred).
    let div = variant.network_divisor();
    let full_size = full_targets[0].size();
    // The residual rung's loss is at the data's network size (its corrections are stretched
    // over `linear`'s outputs there), so its targets stay whole.
    let shrunk: Option<Vec<NetImage>> = (div > 1 && !variant.residual()).then(|| {
        let ImageSize {
            width: w,
            height: h,
        } = full_size;
        full_targets
            .iter()
            .map(|t| crate::resize::resize_area(t, w / div, h / div))
            .collect()
    });
    let targets: &[NetImage] = shrunk.as_deref().unwrap_or(full_targets);
    let ImageSize {
        width: nw,
        height: nh,
    } = if variant.residual() {
        ImageSize::new(full_size.width / div, full_size.height / div)
    } else {
        targets[0].size()
    };
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
        captures: on_device(crate::nn::images_to_tensor(captures)?)?,
        surface: on_device(crate::nn::images_to_tensor::<Camera, _>(
            std::slice::from_ref(&surface),
        )?)?,
        targets: on_device(crate::nn::images_to_tensor(targets)?)?,
        base: None,
    };
    Ok(CompenNetData {
        data,
        surface,
        size: ImageSize::new(nw, nh),
        device,
    })
}

/// Where the WarpingNet starts: for a fixed-geometry rung the grid of `linear` (the residual
/// rung's, given) or of structured light, else the `linear` rung's affine + TPS fit. Returns
/// the start and its description for the record.
fn geometry_start(
    setup: &Setup,
    (variant, linear): (
        crate::nn::compennetpp::Variant,
        Option<&crate::linear::LinearModel>,
    ),
    prepared: &CompenNetData,
    theta: [[f32; 3]; 2],
    captures: &[Levels<Camera>],
    full_targets: &[NetImage],
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<(crate::nn::compennetpp::GeometryInit, &'static str)> {
    use crate::nn::compennetpp::GeometryInit;
    let ImageSize {
        width: nw,
        height: nh,
    } = prepared.size;
    let init = if variant.fixed_geometry() {
        let grid = match linear {
            Some(l) => l.grid_at(prepared.size)?,
            None => sl_grid(setup, prepared.size)?,
        };
        let flat: Vec<f32> = grid.data().iter().flatten().copied().collect();
        GeometryInit::Fixed(candle_core::Tensor::from_vec(
            flat,
            (1, nh, nw, 2),
            &prepared.device,
        )?)
    } else {
        // Climb from the rung below: the `linear` fit's affine + TPS geometry (seconds on a CPU)
        // starts the WarpingNet, so the network's few samples go into photometry. Fitted at the
        // data's network size; the warp is resolution independent.
        progress("geometry (linear rung)", 0, 1);
        let settings = FitSettings {
            network_size: full_targets[0].size(),
            refine: None,
            ..FitSettings::default()
        };
        // Its geometry alone: the colour model is not needed here.
        GeometryInit::Warp(crate::linear::fit_geometry(
            captures,
            full_targets,
            crate::warp::Warp::from_affine(theta),
            &settings,
        )?)
    };
    let description = match &init {
        GeometryInit::Fixed(_) if linear.is_some() => "the linear rung's grid (fixed)",
        GeometryInit::Fixed(_) => "structured light (fixed)",
        GeometryInit::Warp(_) => "the linear rung's affine + TPS fit",
        GeometryInit::Affine(_) => "the FOV bounding box's affine",
    };
    Ok((init, description))
}

/// Inference, simplification and saving run on the CPU: brings the weights of a network trained
/// on another device over (`size`: the rung's network size, (width, height) pixels).
fn weights_to_cpu(
    net: crate::nn::compennetpp::CompenNetPP,
    device: &candle_core::Device,
    size: ImageSize,
    variant: crate::nn::compennetpp::Variant,
) -> Result<crate::nn::compennetpp::CompenNetPP> {
    if device.is_cpu() {
        return Ok(net);
    }
    let values: std::collections::HashMap<String, candle_core::Tensor> =
        net.named_tensors().into_iter().collect();
    crate::nn::compennetpp::CompenNetPP::restore(size, variant, &candle_core::Device::Cpu, {
        |name, _shape| {
            let t = values
                .get(name)
                .ok_or_else(|| Error::Failed(format!("trained network lacks `{name}`")))?;
            Ok(t.flatten_all()?.to_vec1::<f32>()?)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_first_order_step_moves_the_shown_image_by_linears_error_within_range_and_blends() {
        let shown = NetImage::from_vec(1, 2, vec![0.5, 0.5, 0.5, 0.9, 0.1, 0.5]).unwrap();
        let lin_d = NetImage::from_vec(1, 2, vec![0.6, 0.4, 0.5, 0.9, 0.2, 0.5]).unwrap();
        let lin_x = NetImage::from_vec(1, 2, vec![0.5, 0.5, 0.5, 0.7, 0.4, 0.5]).unwrap();
        let step = first_order_step(&shown, &lin_d, &lin_x).unwrap();
        let want = [0.6, 0.4, 0.5, 1.0, 0.0, 0.5];
        for (got, want) in step.data().iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{:?}", step.data());
        }
        // Blended towards `linear`'s output by the weight, per pixel.
        let w = NetImage::from_vec(1, 2, vec![1.0, 1.0, 1.0, 0.0, 0.5, 0.5]).unwrap();
        let b = blend(&lin_d, &step, &w).unwrap();
        let want = [0.6, 0.4, 0.5, 0.9, 0.1, 0.5];
        for (got, want) in b.data().iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{:?}", b.data());
        }
        let small = NetImage::from_vec(1, 1, vec![0.5; 3]).unwrap();
        let e = first_order_step(&shown, &small, &lin_x).unwrap_err();
        assert!(e.to_string().contains("1x1"), "{e}");
    }

    #[test]
    fn only_where_a_desired_view_is_not_black_is_asked_for() {
        // A 4×2 camera; views lit in its left half only; the identity grid on a 4×2 network.
        let lit = |x: usize| if x < 2 { 0.3 } else { 0.0 };
        let view = CamImage::from_fn(4, 2, |x, _| [lit(x), 0.0, 0.0]);
        let grid = Grid::<Network, Camera>::identity(4, 2);
        let w = asked_for(&[view.clone(), view], &grid).unwrap().unwrap();
        assert_eq!(w.get(0, 0), [1.0; 3]);
        assert_eq!(w.get(3, 1), [0.0; 3]);
        assert!(asked_for(&[], &grid).unwrap().is_none());
    }
}
