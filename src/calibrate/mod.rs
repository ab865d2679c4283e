//! Calibration (docs/architecture.md, "Data flow"): from a projector and a camera to a verified
//! model, through the device traits, so the virtual rig and hardware run the same code.
//!
//! Phases, each timed:
//! 0. **exposure**: where the camera has a manual exposure, it is set so that the brightest lit
//!    pixels under white sit just below saturation ([`exposure::range_exposure`]);
//! 1. **latency**: black/white alternations measure the projector-to-camera delay in camera
//!    exposures ([`sync::measure_latency`]); every later capture skips that many frames;
//! 2. **patterns**: the projector-side images of the dataset layout (sampling images, black,
//!    white, the gray image) written to the data root, unless already there;
//! 3. **captures**: each pattern stretched over the canvas (the whole projector frame), shown,
//!    captured synchronised and averaged ([`sync::Capturer`]), written atomically in the
//!    dataset layout as it arrives and recorded in the manifest ([`crate::dataset::manifest`]); captures already
//!    on disk for the same pattern set are not taken again (an interrupted run resumes);
//! 4. **training**: the requested rung on the setup ([`crate::fit`]); `auto` trains the
//!    CompenNet++ rung the machine can afford on every pair, with no held-out judgement, and
//!    fits the best linear rung beside it, for the rig to judge the climb in phase 5. With
//!    `loop_images` > 0 and a linear rung, a residual rung or `auto` that kept a linear rung,
//!    **closed-loop pairs** follow: the linear rung's
//!    compensation of sampling images placed as desired views, projected and captured; these
//!    pairs sit in the range the desired images use, and the rung is fitted on every pair
//!    ([`refine`]). With 8 or more of them `auto` waits for them before it climbs: [`train`]
//!    chooses among the linear rungs, and [`refit`] trains the residual rung's correction on
//!    all of them ([`crate::fit::judges_on_loop_pairs`]);
//! 5. **verification**: held-out test images, compensated by the new model and as they are,
//!    projected, captured and scored inside the displayable area against the view they should
//!    give. After a climb, the linear rung is projected on the same images and the climbed one
//!    is kept only if it beats it there by the climbing margin ([`fit::ClimbRule::confirms`]).
//!    The caller installs the model only when it passed.

pub mod clock;
pub mod exposure;
mod grow;
mod pipeline;
pub mod progress;
pub mod rounds;
pub mod runs;
pub mod set;
pub mod sync;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::dataset::{CaptureSet, DataRoot, ProjectorSet, Reference, Setup};
use crate::device::{DisplaySink, FrameSource};
use crate::error::{Error, Result};
use crate::fit::{self, Request};
use crate::fov;
use crate::metrics::Accumulator;
use crate::model::{MethodChoice, Model};
use crate::patterns::{self, Set};
use crate::playback::place_on_canvas;
use crate::raster::{CamImage, PrjImage, Rect};
use crate::record::{
    CalibrationRecord, CaptureFloor, ClosedLoopScore, ExposureReport, Latency, LoopChoice,
    PhaseSeconds, RoundScore, SamplingCurve, Verification,
};

pub use crate::dataset::manifest::{Manifest, PatternSet};
pub use rounds::{LoopScore, Rounds, SamplingCount};
pub use sync::{Capturer, SyncSettings};

/// The setup folder's name under the data root.
pub const SETUP_NAME: &str = "capture";

/// The PSNR gain over the uncompensated projection (dB) a model needs in the verification
/// unless the configuration says otherwise (`[calibration] min_gain_db`).
pub const DEFAULT_MIN_GAIN_DB: f64 = 1.0;

/// Whether a verification passes: no failure ([`crate::failure::classify`]) and a PSNR gain
/// over the uncompensated projection (dB) of at least `required_db`.
pub fn passes(failure: Option<crate::failure::Failure>, gain_db: f64, required_db: f64) -> bool {
    failure.is_none() && gain_db.is_finite() && gain_db >= required_db
}

/// What to calibrate and how.
#[derive(Clone, Debug)]
pub struct Options {
    /// The projected images; `projector` must be the display's size.
    pub patterns: PatternSet,
    pub method: MethodChoice,
    /// Seed of the fit.
    pub fit_seed: u64,
    pub sync: SyncSettings,
    /// Test images projected in the verification.
    pub verify_images: usize,
    /// PSNR gain over the uncompensated projection a model needs, dB.
    pub required_gain_db: f64,
    /// `method = auto`: the PSNR gain (dB) a CompenNet++ rung needs over the best linear rung
    /// in closed loop on the verification images ([`crate::fit::ClimbRule`]; the rig judges).
    pub climb_gain_db: f64,
    /// Training iterations of a CompenNet++ rung: the one asked for, or the one `auto` climbs
    /// to; `None`: its schedule. Ignored by the linear rungs.
    pub iters: Option<usize>,
    /// Where a CompenNet++ rung trains (and so which one `auto` climbs to,
    /// [`fit::climb_rung`]); the linear rungs fit on the CPU.
    pub device: crate::fit::TrainDevice,
    /// `auto` only: times the climb rung's live pass on the GPU that is to play the model, at
    /// its display's refresh ([`crate::fit::LivePass`]); `None`: not weighed.
    pub live: Option<Arc<dyn crate::fit::LivePass>>,
    /// Closed-loop pairs taken with the linear rung ([`refine`]); 0: none. With `rounds` whose
    /// closed-loop pairs follow the sampling pairs, as many as the rounds chose instead, or
    /// only the first [`Rounds::loop_first`] when those show that more would not pay
    /// ([`Rounds::loops`]).
    pub loop_images: usize,
    /// `ntrain = auto`: the sampling images captured in rounds, up to `patterns.ntrain`, until
    /// one no longer gains ([`rounds`]); `None`: all `patterns.ntrain` of them.
    pub rounds: Option<Rounds>,
    /// What is calibrated, for the record (`virtual:curved`, a device path).
    pub rig: String,
    /// Set by another thread to stop the calibration: checked before each capture, between the
    /// phases and before the model is returned ([`Error::Cancelled`]). The captures on disk stay
    /// and a later run resumes from them.
    pub cancel: Option<Arc<AtomicBool>>,
}

impl Options {
    /// [`Error::Cancelled`] once [`Options::cancel`] is set.
    fn check_cancelled(&self) -> Result<()> {
        match &self.cancel {
            Some(flag) if flag.load(Ordering::Relaxed) => {
                Err(Error::Cancelled("the calibration".into()))
            }
            _ => Ok(()),
        }
    }
}

/// A trained model and how it was made and checked; install it only if
/// `record.verification.passed`.
pub struct Calibrated {
    pub model: Model,
    pub record: CalibrationRecord,
    /// The setup the captures are in.
    pub setup: PathBuf,
}

/// Progress: (phase, done, total).
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize);

/// Runs the whole calibration into the data root `data` (created; its setup is
/// `data/capture`). See the module documentation for the phases: [`capture`], [`train`] and
/// [`verify_model`] in a row.
pub fn calibrate<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    data: &Path,
    opts: &Options,
    progress: Progress,
) -> Result<Calibrated> {
    let mut captured = capture(display, camera, data, opts, progress)?;
    let model = train(&mut captured, opts, progress)?;
    let model = refine(display, camera, &mut captured, model, opts, progress)?;
    verify_model(display, camera, captured, model, opts, progress)
}

/// The most closed-loop pairs [`refine`] takes (each is a capture held in memory by the refit).
pub const MAX_LOOP_IMAGES: usize = 500;

/// Whether [`refine`] applies to a method: the linear rungs; the residual rungs, whose
/// correction trains on the closed-loop pairs of the `linear` rung they stand on; and `auto`,
/// for the linear rung it keeps (a climbed rung keeps its training).
pub fn refines(method: MethodChoice) -> bool {
    match method {
        MethodChoice::Rung(m) => m.is_linear() || m.is_residual(),
        MethodChoice::Auto => true,
    }
}

/// What is wrong with sampling rounds (`ntrain = auto`) for `method`, if anything: the rounds
/// are scored with the `linear` rung, so only a method that starts from it ([`refines`]) takes
/// them. Callers put the flag or key in front.
pub fn rounds_problem(method: MethodChoice) -> Option<String> {
    (!refines(method)).then(|| {
        format!(
            "the sampling rounds are scored with the linear rung, which {method} does not \
             start from; give a number of sampling images"
        )
    })
}

// `ntrain = auto` takes at most as many sampling pairs as the fixed default.
const _: () = assert!(rounds::MOST_PAIRS == fit::DEFAULT_TRAIN);

/// What is wrong with asking `method` for `n` closed-loop pairs, if anything: more than
/// [`MAX_LOOP_IMAGES`], or any for a method [`refine`] does not apply to. Callers put the flag
/// or key in front.
pub fn loop_images_problem(method: MethodChoice, n: usize) -> Option<String> {
    if n > MAX_LOOP_IMAGES {
        Some(format!("at most {MAX_LOOP_IMAGES} closed-loop pairs"))
    } else if n > 0 && !refines(method) {
        Some(format!(
            "only linear, linear-sl, compennet++-res, compennet++-res-full and auto take \
             closed-loop pairs, not {method}"
        ))
    } else {
        None
    }
}

/// How many closed-loop pairs [`refine`] takes: `asked` when given (by flag or configuration),
/// else as many as the sampling pairs for a rung that takes them ([`refines`]) and none for
/// another.
pub fn loop_images(method: MethodChoice, ntrain: usize, asked: Option<usize>) -> usize {
    asked.unwrap_or(if refines(method) { ntrain } else { 0 })
}

/// Phase 4b, with `opts.loop_images` = N > 0 and a rung that takes them ([`refines`]; after
/// `auto` climbed, the linear rung fitted beside the climbed one, which is returned as it is):
/// closed-loop pairs ([`take_loop_pairs`]), then the fit on every pair ([`refit`]). A sampling
/// image spends most of its range where no desired image goes; these pairs sit where the
/// desired images are, and on dark surfaces they are worth more than as many sampling images
/// (docs/bench/ladder.md). They depend on the model: an interrupted run keeps those taken of
/// the images its model compensates again, and takes the rest.
pub fn refine<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    captured: &mut Captured,
    model: Model,
    opts: &Options,
    progress: Progress,
) -> Result<Model> {
    let taken = take_loop_pairs(display, camera, captured, model, opts, progress)?;
    refit(captured, taken, opts, progress)
}

/// What [`take_loop_pairs`] leaves for [`refit`].
pub struct LoopPairs {
    /// The model that compensated them (refitted on every pair), or the one to return as it
    /// is when none were taken.
    model: Model,
    /// After `auto` climbed on held-out sampling pairs: the climbed rung, returned as it is
    /// (`model` is then the linear rung fitted beside it).
    climbed: Option<Model>,
    /// Closed-loop pairs taken.
    n: usize,
    /// The linear rung's fit on every pair, grown as the pairs were captured ([`grow`]);
    /// `None` when [`refit`] fits something else, or when it could not start.
    growing: Option<grow::Grower>,
}

impl LoopPairs {
    /// Whether [`refit`] trains a network (minutes on a CPU): a residual rung's correction, or
    /// `auto`'s climb judged on the pairs. The service runs it beside playback.
    pub fn trains_a_network(&self, opts: &Options) -> bool {
        self.n > 0
            && match opts.method {
                MethodChoice::Rung(m) => !m.is_linear(),
                MethodChoice::Auto => self.climbed.is_none() && climbs_on_loop_pairs(opts, self.n),
            }
    }
}

/// The first step of [`refine`]: for the first N sampling images (again from the first when N
/// is more than there are), the desired view (scaled into the display range and placed in the
/// displayable area, as the test images' are) is compensated by `model` (a linear rung; for
/// a residual rung, the `linear` rung [`train`] fitted); that network-size projector image is
/// written to the data root as training image `ntrain + i`, its desired view to the setup's
/// `cam/desire/train`, and it is projected, captured synchronised and written as its capture.
pub fn take_loop_pairs<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    captured: &mut Captured,
    model: Model,
    opts: &Options,
    progress: Progress,
) -> Result<LoopPairs> {
    let n = captured.loop_images;
    let untouched = |model| LoopPairs {
        model,
        climbed: None,
        n: 0,
        growing: None,
    };
    if n == 0 {
        return Ok(untouched(model));
    }
    if let Some(p) = loop_images_problem(opts.method, n) {
        return Err(Error::Input(format!("{n} closed-loop pairs: {p}")));
    }
    // The linear rung that compensates the closed-loop images, and what is fitted on every
    // pair: the rung asked for, or the linear rung `auto` kept. After a climb, the linear rung
    // fitted beside the climbed one takes them, and the rig compares the two next; the climbed
    // rung keeps its training.
    let climbed = opts.method == MethodChoice::Auto && !model.meta.method.is_linear();
    let (model, climbed) = match (climbed, captured.lower_rung.take()) {
        (false, lower) => {
            captured.lower_rung = lower;
            (model, None)
        }
        (true, Some(lower)) => (lower, Some(model)),
        (true, None) => return Ok(untouched(model)),
    };
    opts.check_cancelled()?;
    let t = Instant::now();
    let root = &captured.root;
    let setup = Setup::open(&captured.setup, Some(root.path()))?;
    let ntrain = captured.patterns.ntrain;
    // The data root may be a folder the user gave: a training image after the sampling ones
    // that this calibration did not write is never replaced.
    let mut manifest = Manifest::open(setup.path(), &captured.patterns)?;
    if let Some(theirs) = (manifest.loop_written + 1..=n)
        .map(|i| root.image_path(ProjectorSet::Train, ntrain + i))
        .find(|p| p.exists())
    {
        return Err(Error::Input(format!(
            "{}: a training image this calibration did not write, where a closed-loop pair \
             would go; choose another --data folder, or --loop-images 0",
            theirs.display()
        )));
    }
    let mut capturer =
        Capturer::new(display, camera, &captured.latency, opts.sync).with_clock(captured.clock);
    let psize = capturer.projector_size();
    let canvas = Rect::covering(psize);
    // Closed-loop images all sit in the display range, so two in a row can look alike to the
    // camera (on a dark surface the range is a few hundredths wide) and the synchronisation
    // could not tell that the new one has arrived. White before each makes both changes plain.
    let white = PrjImage::from_vec(
        psize.width,
        psize.height,
        vec![1.0; 3 * psize.width * psize.height],
    )?;
    let placement = (captured.desired.range, captured.desired.area);
    // A run killed while it took them left pairs on disk: those of the very images this model
    // compensates now are kept.
    let (resumed, mut previous) = resumable_loop_pairs(
        (root, &setup, manifest.loop_written),
        (ntrain, n),
        placement,
        &model,
    )?;
    if resumed > 0 {
        tracing::info!(
            "closed-loop pairs: {resumed} of {n} resumed from {} (their images are the ones \
             this model compensates)",
            setup.path().display()
        );
    }
    let mut flashes = 0;
    // The fit on every pair grows behind the captures when it is a linear rung's: the one
    // that grew behind the sampling pairs and gave `model`, or one from `model`.
    let grown_before = captured.grower.take();
    let growing = match refits_linear(opts, &model, climbed.is_some(), n) {
        true => grown_before.or_else(|| {
            let g = grow::Grower::from_model(&setup, &model)?;
            (1..=ntrain).for_each(|i| g.stored(i));
            Some(g)
        }),
        false => None,
    };
    // Under `ntrain = auto`, where they follow the sampling pairs, the first ones judge
    // whether more pay ([`Rounds::loops`]).
    let rule = opts.rounds.filter(|r| r.loops_follow && n > r.loop_first);
    let first = rule.map_or(n, |r| r.loop_first);
    let tell = |from: usize, to: usize| {
        if let Some(g) = &growing {
            (ntrain + from + 1..=ntrain + to).for_each(|i| g.stored(i));
        }
    };
    tell(0, resumed.min(first));
    // Pairs `from + 1..=to` of `total`: compensated ahead on a helper thread, stored behind on
    // another ([`pipeline`]): the manifest claims each training image before it is written,
    // so a later run knows it for this calibration's.
    let mut take = |from: usize, to: usize, total: usize| -> Result<()> {
        pipeline::run(
            to.saturating_sub(from),
            |k| {
                let (desired, shown) = loop_image(root, (ntrain, from + k + 1), placement, &model)?;
                let frame = place_on_canvas(&shown, canvas, psize)?;
                Ok((desired, shown, frame))
            },
            |k, (desired, shown, frame)| {
                progress("closed-loop pairs", from + k, total);
                opts.check_cancelled()?;
                // White between two views the camera could not tell apart (one frame, not
                // averaged).
                if !previous
                    .as_ref()
                    .is_some_and(|p| capturer.tells_apart(p, &desired))
                {
                    capturer.capture_averaging(&white, true, 1)?;
                    flashes += 1;
                }
                let cap = match capturer.capture(&frame, true) {
                    Ok(cap) => cap,
                    // The camera did not see it change after all (the compensation could not
                    // give the difference the two views have): white, then once more.
                    Err(Error::Input(why)) if previous.is_some() => {
                        tracing::info!(
                            "closed-loop pair {}: {why}; white first, once more",
                            from + k + 1
                        );
                        capturer.capture_averaging(&white, true, 1)?;
                        flashes += 1;
                        capturer.capture(&frame, true)?
                    }
                    Err(e) => return Err(e),
                };
                previous = Some(desired.clone());
                Ok((desired, shown, cap))
            },
            |k, (desired, shown, cap)| {
                let i = from + k + 1;
                manifest.record_loop(setup.path(), i)?;
                root.write(ProjectorSet::Train, ntrain + i, &shown)?;
                setup.write_loop_desired(ntrain + i, &desired)?;
                setup.write_capture(CaptureSet::Train, ntrain + i, &cap)?;
                if let Some(g) = &growing {
                    g.stored(ntrain + i);
                }
                Ok(())
            },
        )
    };
    take(resumed, first, n)?;
    // Judged from the pairs on disk, so that a resumed run judges as the run that took them.
    let (n, choice) = match rule {
        None => (n, None),
        Some(r) => match loop_score(&setup, (ntrain, first), &model, captured.desired.area)? {
            None => (n, None),
            Some(score) => {
                let (chosen, why) = r.loops(&score, n);
                tracing::info!("closed-loop pairs: {chosen} of {n}: {why}");
                let choice = LoopChoice {
                    rule: r.describe_loops(),
                    judged: score.pairs,
                    model_mse: score.model_mse,
                    closed_loop_mse: score.closed_loop_mse,
                    share: score.model_mse / score.closed_loop_mse,
                    chosen,
                    why,
                };
                (chosen, Some(choice))
            }
        },
    };
    tell(first, resumed.min(n));
    take(resumed.max(first), n, n)?;
    let resumed = resumed.min(n);
    progress("closed-loop pairs", n, n);
    captured.retakes += capturer.retakes;
    captured.reconnects += capturer.reconnects;
    captured.floor.add(&capturer.floor);
    captured.latency.settle_frames = capturer.settle();
    // The white frames between them are not counted as captures: nothing keeps them.
    tracing::debug!("closed-loop pairs: white shown before {flashes} of {n}");
    captured.captured += n - resumed;
    captured.resumed += resumed;
    captured.loop_pairs = n;
    captured.loop_images = n;
    captured.loop_choice = choice;
    let capturing = t.elapsed().as_secs_f64();
    captured.seconds.captures += capturing;
    tracing::info!(
        "closed-loop pairs: {} captured in {capturing:.1} s",
        n - resumed
    );
    Ok(LoopPairs {
        model,
        climbed,
        n,
        growing,
    })
}

/// Whether [`refit`] fits a linear rung on every pair (and may take the fit grown during the
/// captures, [`grow`]): the rung asked for is a linear one, or `auto` refits the linear
/// rung it chose (or the one beside its climb) rather than climbing on these pairs.
fn refits_linear(opts: &Options, model: &Model, climbed: bool, n: usize) -> bool {
    model.meta.method.is_linear()
        && match opts.method {
            MethodChoice::Rung(m) => m.is_linear(),
            MethodChoice::Auto => climbed || !climbs_on_loop_pairs(opts, n),
        }
}

/// How many closed-loop pairs, from the first, an interrupted run of this calibration left
/// complete on disk (of the `written` its manifest claims) for the images `model` compensates
/// now: the training image as written is the one compensated now (both 8-bit), the desired
/// view reads back as the one placed now, and the capture, written last, reads whole. With the desired view of the last one kept, for the
/// white flash before the next ([`Capturer::tells_apart`]).
fn resumable_loop_pairs(
    (root, setup, written): (&DataRoot, &Setup, usize),
    (ntrain, n): (usize, usize),
    placement: (fov::DisplayRange, Rect),
    model: &Model,
) -> Result<(usize, Option<CamImage>)> {
    let mut done = (0, None);
    for i in 1..=n.min(written) {
        let index = ntrain + i;
        if !setup.capture_path(CaptureSet::Train, index).is_file() {
            break;
        }
        let Ok(stored) = crate::pngio::read_rgb::<crate::raster::Projector>(
            &root.image_path(ProjectorSet::Train, index),
        ) else {
            break;
        };
        let (desired, shown) = loop_image(root, (ntrain, i), placement, model)?;
        // Both 8-bit as written: equal to within rounding.
        let same = |a: &[f32], b: &[f32]| {
            a.len() == b.len() && a.iter().zip(b).all(|(a, b)| (a - b).abs() < 0.5 / 255.0)
        };
        if stored.size() != shown.size() || !same(stored.data(), shown.data()) {
            break;
        }
        // The desired view as the fit will read it (one damaged since is taken again), and
        // the capture whole, of the camera's size.
        let view = setup
            .loop_desired_dir()
            .join(crate::pngio::indexed_name(index));
        let kept = crate::pngio::read_rgb::<crate::raster::Camera>(&view).is_ok_and(|v| {
            v.size() == desired.size() && same(v.data(), crate::pngio::quantize(&desired).data())
        });
        let captured = crate::pngio::read_rgb::<crate::raster::Camera>(
            &setup.capture_path(CaptureSet::Train, index),
        )
        .is_ok_and(|c| c.size() == desired.size());
        if !(kept && captured) {
            break;
        }
        done = (i, Some(desired));
    }
    Ok(done)
}

/// The figures [`Rounds::loops`] judges the first `k` closed-loop pairs by, read back from the
/// setup (training pairs `ntrain + 1..=ntrain + k`, their desired views beside): in the
/// displayable `area` (camera pixels), each capture against its desired view (the closed
/// loop's error), and `model`'s forward prediction of each capture from its projector image
/// against the capture (the model's own). `None` for a model without a forward model.
fn loop_score(
    setup: &Setup,
    (ntrain, k): (usize, usize),
    model: &Model,
    area: Rect,
) -> Result<Option<LoopScore>> {
    let indices: Vec<usize> = (ntrain + 1..=ntrain + k).collect();
    let views = setup.load_loop_desired(&indices)?;
    let mut pairs = crate::dataset::Pairs {
        captures: Vec::with_capacity(k),
        inputs: Vec::with_capacity(k),
    };
    let (mut sq, mut values) = (0f64, 0usize);
    for (&i, view) in indices.iter().zip(&views) {
        let (capture, shown) = setup.load_train_pair(i)?;
        let capture = crate::raster::ReadRgb::to_rgb(&capture).into_owned();
        let (seen, want) = (capture.crop(area)?, view.crop(area)?);
        for (a, b) in seen.data().iter().zip(want.data()) {
            sq += f64::from(a - b).powi(2);
        }
        values += seen.data().len();
        pairs.captures.push(capture);
        pairs.inputs.push(shown);
    }
    let Some(model_mse) = crate::model::forward_mse_in(model, &pairs, Some(area))? else {
        return Ok(None);
    };
    Ok(Some(LoopScore {
        pairs: k,
        model_mse,
        closed_loop_mse: sq / values.max(1) as f64,
    }))
}

/// The second step of [`refine`], which needs no device: the requested rung fitted on all
/// `ntrain + N` pairs: a linear rung on every pair, the residual rung's correction on the
/// closed-loop ones ([`crate::fit`]); `auto` that waited for the pairs
/// ([`climbs_on_loop_pairs`]) trains its climb on them, and after a climb the linear rung is
/// fitted beside the climbed one for the rig to compare. Returns the model for
/// [`verify_model`].
pub fn refit(
    captured: &mut Captured,
    taken: LoopPairs,
    opts: &Options,
    progress: Progress,
) -> Result<Model> {
    let LoopPairs {
        model,
        climbed,
        n,
        growing,
    } = taken;
    if n == 0 {
        return Ok(climbed.unwrap_or(model));
    }
    let judges =
        opts.method == MethodChoice::Auto && climbed.is_none() && climbs_on_loop_pairs(opts, n);
    let refit = match opts.method {
        // The climb that waited for these pairs: `auto` again, on every pair.
        MethodChoice::Auto if judges => Request {
            climb_later: false,
            ..request(opts, captured)
        },
        MethodChoice::Auto => Request {
            method: MethodChoice::Rung(model.meta.method),
            iters: None,
            batch: None,
            climb_gain_db: None,
            climb_later: false,
            ..request(opts, captured)
        },
        MethodChoice::Rung(_) => request(opts, captured),
    };
    opts.check_cancelled()?;
    progress("fit on every pair", 0, 1);
    let t = Instant::now();
    let setup = Setup::open(&captured.setup, Some(captured.root.path()))?;
    let req = Request {
        ntrain: Some(captured.patterns.ntrain + n),
        ..refit
    };
    let evidence = model.meta.training.auto.clone().filter(|_| !judges);
    let all = captured.patterns.ntrain + n;
    let mut model = match growing.map(|g| g.finish(all)) {
        Some(Ok(model)) => {
            tracing::info!(
                "closed-loop pairs: the fit on every pair grew during the captures (the \
                 geometry and curves of the fit on the first {} pairs kept)",
                model.meta.training.curves_searched_on.unwrap_or(0)
            );
            model
        }
        grown => {
            if let Some(Err(why)) = grown {
                tracing::warn!("the fit grown during the captures: {why}; fitting afresh");
            }
            fit::fit(&setup, &req, |stage, done, total| {
                progress(stage, done, total)
            })?
            .0
        }
    };
    // `auto`'s choice and its evidence stay on the rung it chose.
    if evidence.is_some() {
        model.meta.training.auto = evidence;
    }
    // A climb judged on these pairs: the rig compares it with the best linear rung next.
    if judges {
        opts.check_cancelled()?;
        captured.lower_rung = fit::lower_rung(&setup, &req, &model, |stage, done, total| {
            progress(stage, done, total)
        })?;
    }
    captured.seconds.training += t.elapsed().as_secs_f64();
    tracing::info!(
        "closed-loop pairs: {} fitted on {} of the {} pairs in {:.1} s",
        model.meta.method,
        model.meta.training.ntrain,
        captured.patterns.ntrain + n,
        t.elapsed().as_secs_f64()
    );
    Ok(match climbed {
        Some(upper) => {
            captured.lower_rung = Some(model);
            upper
        }
        None => model,
    })
}

/// Closed-loop pair `i` of a data root `root` with `ntrain` sampling images: sampling image
/// `1 + (i − 1) % ntrain`, scaled into the display range `range` and placed in the displayable
/// area `area` (camera pixels), is the desired view; `model` (a linear rung) compensates it.
/// Returns the desired view and the projector image, network size and 8-bit, as the pair
/// records it and the projector shows it (stretched over the canvas, as every sampling image
/// is). Shared by [`refine`] and the virtual rig's export.
pub fn loop_image(
    root: &DataRoot,
    (ntrain, i): (usize, usize),
    (range, area): (fov::DisplayRange, Rect),
    model: &Model,
) -> Result<(CamImage, PrjImage)> {
    let net = root.network_size()?;
    let why = format!("the network size of {}", root.path().display());
    let content: PrjImage = crate::pngio::read_rgb_sized(
        &root.image_path(ProjectorSet::Train, 1 + (i - 1) % ntrain),
        net,
        &why,
    )?;
    let desired = fov::place_in_area(&range.apply(&content), area, model.camera_size())?;
    let shown = crate::pngio::quantize(&crate::model::at_size(model.infer(&desired)?, net));
    Ok((desired, shown.into_space()))
}

/// What the capture phases leave for training and verification.
pub struct Captured {
    root: DataRoot,
    setup: PathBuf,
    desired: Desired,
    exposure: Option<ExposureReport>,
    latency: Latency,
    /// The camera's clock as the latency measurement mapped it ([`Capturer::with_clock`]).
    clock: Option<clock::CameraClock>,
    captured: usize,
    resumed: usize,
    retakes: usize,
    reconnects: usize,
    seconds: PhaseSeconds,
    started: Instant,
    /// Set by [`train`] when `auto` climbed: the best linear rung, fitted on every pair, which
    /// the climbed rung must beat in closed loop.
    lower_rung: Option<Model>,
    /// Closed-loop pairs taken by [`refine`].
    loop_pairs: usize,
    /// The pattern set the captures are of: [`Options::patterns`], with the sampling pairs
    /// the rounds chose under `ntrain = auto`.
    patterns: PatternSet,
    /// Closed-loop pairs [`refine`] takes: [`Options::loop_images`], or as many as the
    /// sampling pairs the rounds chose ([`Rounds::loops_follow`]).
    loop_images: usize,
    /// `ntrain = auto`: how the sampling pairs were chosen.
    sampling: Option<SamplingCurve>,
    /// `ntrain = auto`: how the closed-loop pairs were chosen ([`take_loop_pairs`]).
    loop_choice: Option<LoopChoice>,
    /// `ntrain = auto`: the `linear` rung of the last round, on every sampling pair; [`train`]
    /// takes it when its first fit is that very fit.
    round_model: Option<Model>,
    /// Every capture's time against its floor, over the phases so far.
    floor: CaptureFloor,
    /// The `linear` geometry the fits of [`train`] and [`refit`] share (they see the same
    /// sampling pairs first).
    geometry: Arc<crate::linear::GeometryMemo>,
    /// The thread fitting that geometry ahead, from the first sampling pairs, while the rest
    /// were captured ([`start_prefit`]); [`train`] waits for it.
    prefit: Option<std::thread::JoinHandle<()>>,
    /// When the first fit is `linear`: the fit grown behind the captures ([`grow`]), which
    /// [`train`] takes its model from and [`take_loop_pairs`] goes on growing.
    grower: Option<grow::Grower>,
}

impl Captured {
    /// The setup folder the captures are in.
    pub fn setup(&self) -> &Path {
        &self.setup
    }
}

/// Phases 0–3: exposure, latency, patterns and captures into the data root `data` (created;
/// its setup is `data/capture`), and the desired views the verification compares with.
pub fn capture<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    data: &Path,
    opts: &Options,
    progress: Progress,
) -> Result<Captured> {
    let started = Instant::now();
    let mut seconds = PhaseSeconds::default();
    if display.size() != opts.patterns.projector {
        return Err(Error::Input(format!(
            "the projector is {}, the pattern set is for {}",
            display.size(),
            opts.patterns.projector
        )));
    }
    let setup_dir = data.join(SETUP_NAME);
    // Before anything is written: captures of another pattern set are never mixed in. Under
    // `ntrain = auto` the set grows round by round, and a run that had taken closed-loop pairs
    // (they follow the sampling pairs) has settled its count.
    let (mut manifest, rounds) = match opts.rounds {
        None => (Manifest::open(&setup_dir, &opts.patterns)?, None),
        Some(r) => {
            let m = Manifest::open_rounds(&setup_dir, &opts.patterns, r.first)?;
            let open = m.loop_written == 0;
            (m, Some(r).filter(|_| open))
        }
    };
    let patterns = manifest.patterns.clone();

    // The patterns are written while the exposure and the latency are measured: those show
    // only black and white. The writing runs behind the measurement (`background`): a
    // measurement held back by it would count the lag as latency.
    let (exposure, (latency, clock), root) = std::thread::scope(|s| -> Result<_> {
        let writing = s.spawn(|| -> Result<(DataRoot, f64)> {
            crate::background::run(|| {
                let t = Instant::now();
                let root = DataRoot::create(data)?;
                write_patterns(&root, &patterns)?;
                Ok((root, t.elapsed().as_secs_f64()))
            })
        });
        let measured = (|| -> Result<_> {
            let t = Instant::now();
            progress("exposure", 0, 1);
            let exposure::Ranged {
                report: exposure,
                levels,
            } = exposure::range_exposure(display, camera)?;
            if let Some(e) = &exposure {
                tracing::info!(
                    "exposure: {} → {} (camera units) in {} steps; brightest lit pixels at {:.3}",
                    e.initial,
                    e.chosen,
                    e.steps,
                    e.bright_level
                );
            }
            seconds.exposure = t.elapsed().as_secs_f64();
            opts.check_cancelled()?;
            let t = Instant::now();
            progress("latency", 0, 1);
            let (latency, clock) = sync::measure_latency(display, camera, &opts.sync, levels)?;
            seconds.latency = t.elapsed().as_secs_f64();
            tracing::info!(
                "latency: {:?} camera exposures over {} switches; skipping {} per capture",
                latency.trials,
                latency.trials.len(),
                latency.settle_frames
            );
            Ok((exposure, latency, clock))
        })();
        let written = writing
            .join()
            .unwrap_or_else(|_| Err(Error::Failed("the pattern writer panicked".into())));
        let (exposure, latency, clock) = measured?;
        let (root, patterns_s) = written?;
        seconds.patterns = patterns_s;
        Ok((exposure, (latency, clock), root))
    })?;
    let setup = Setup::create(&root, Path::new(SETUP_NAME))?;
    // Before the first capture: a run killed after it has no capture without its manifest.
    manifest.save(setup.path())?;

    let t = Instant::now();
    let geometry: Arc<crate::linear::GeometryMemo> = Default::default();
    // Rounds fit as they go, and share the geometry among their fits. Otherwise a `linear`
    // first fit grows behind the captures, and another rung's geometry is fitted ahead.
    let grower = match rounds {
        None => first_grows(opts, &geometry)
            .and_then(|(req, pairs)| grow::Grower::fit_first(&setup, req, pairs)),
        Some(_) => None,
    };
    // Under rounds, the first round's geometry is fitted while the test pairs are captured
    // (they come after its sampling pairs), so that its fit behind the second round's
    // captures is mostly the colour solve.
    let geometry_images = crate::linear::FitSettings::default().geometry_images;
    let (ready, mut prefit) = match (rounds, &grower) {
        (None, None) => {
            let pairs = geometry_images.min(opts.patterns.ntrain);
            start_prefit(&root, &setup, (opts, pairs), &geometry)
        }
        (Some(r), _) => start_prefit(
            &root,
            &setup,
            (opts, geometry_images.min(r.first)),
            &geometry,
        ),
        _ => (None, None),
    };
    let mut capturer = Capturer::new(display, camera, &latency, opts.sync).with_clock(clock);
    let (mut captured, mut resumed) = capture_all(
        &mut capturer,
        (&root, &setup),
        &mut manifest,
        (ready, grower.as_ref()),
        opts,
        progress,
    )?;
    let (mut sampling, mut round_model, mut round_seconds) = (None, None, 0.0);
    if let Some(r) = rounds {
        let done = sampling_rounds(
            &mut capturer,
            (&root, &setup),
            (&mut manifest, captured + resumed),
            (r, &geometry, prefit.take()),
            opts,
            progress,
        )?;
        captured += done.captured;
        resumed += done.resumed;
        round_seconds = done.held;
        tracing::info!(
            "sampling rounds: {} pairs ({}), the captures held {:.1} s for the fits",
            done.curve.chosen,
            done.curve.why,
            round_seconds
        );
        sampling = Some(done.curve);
        round_model = Some(done.model);
    }
    seconds.captures = t.elapsed().as_secs_f64() - round_seconds;
    seconds.training += round_seconds;
    tracing::info!(
        "captures: {captured} taken, {resumed} found on disk, {} retaken, camera reopened {} \
         times, in {:.1} s",
        capturer.retakes,
        capturer.reconnects,
        seconds.captures
    );
    let (retakes, reconnects) = (capturer.retakes, capturer.reconnects);
    let floor = capturer.floor;
    let mut latency = latency;
    latency.settle_frames = capturer.settle();
    let desired = write_desired(&root, &setup, opts)?;
    let patterns = manifest.patterns.clone();
    let loop_images = match opts.rounds {
        Some(r) if r.loops_follow => loop_images(opts.method, patterns.ntrain, None),
        _ => opts.loop_images,
    };
    Ok(Captured {
        patterns,
        loop_images,
        sampling,
        loop_choice: None,
        round_model,
        setup: setup.path().to_path_buf(),
        root,
        desired,
        exposure,
        latency,
        clock,
        captured,
        resumed,
        retakes,
        reconnects,
        seconds,
        started,
        lower_rung: None,
        loop_pairs: 0,
        floor,
        geometry,
        prefit,
        grower,
    })
}

/// Phase 4: fits the requested rung on the captures; when `auto` climbed to a CompenNet++ rung,
/// also the best linear rung (kept in `captured` for [`verify_model`] to compare in closed
/// loop). Uses no device, so it may run on another thread while the projector shows something
/// else.
pub fn train(captured: &mut Captured, opts: &Options, progress: Progress) -> Result<Model> {
    opts.check_cancelled()?;
    let t = Instant::now();
    if let Some(prefit) = captured.prefit.take() {
        progress("geometry", 0, 1);
        if prefit.join().is_err() {
            tracing::warn!("the geometry fitted ahead panicked; the fit makes its own");
        }
    }
    let setup = Setup::open(&captured.setup, Some(captured.root.path()))?;
    let req = request(opts, captured);
    // The residual rung's closed-loop pairs are `linear`'s compensations: `linear` first, and
    // the rung itself once [`refine`] has them.
    let first = first_request(opts, captured.loop_images, &req);
    let linear = first.method == MethodChoice::Rung(crate::model::Method::Linear);
    // The last sampling round fitted `linear` on these very pairs with this very request; or
    // the fit grew behind the captures.
    let grown = match (&captured.grower, linear) {
        (Some(g), true) => {
            progress("colour", 0, 1);
            let ntrain = captured.patterns.ntrain;
            let model = g.model().and_then(|m| match m.meta.training.ntrain {
                n if n == ntrain => Ok(m),
                n => Err(Error::Failed(format!(
                    "it holds {n} of the {ntrain} sampling pairs"
                ))),
            });
            match model {
                Ok(model) => Some(model),
                Err(e) => {
                    tracing::warn!("the linear fit grown behind the captures: {e}; fitting afresh");
                    captured.grower = None;
                    None
                }
            }
        }
        _ => None,
    };
    let model = match (captured.round_model.take(), grown) {
        (Some(model), _) if linear => {
            tracing::info!("training: the last sampling round's linear fit is the first fit");
            model
        }
        (_, Some(model)) => {
            tracing::info!(
                "training: the linear fit grew behind the captures (the geometry and curves of \
                 the first {} pairs, the colour on all {})",
                model.meta.training.curves_searched_on.unwrap_or(0),
                model.meta.training.ntrain
            );
            model
        }
        _ => fit::fit(&setup, &first, |stage, done, n| progress(stage, done, n))?.0,
    };
    opts.check_cancelled()?;
    captured.lower_rung = fit::lower_rung(&setup, &req, &model, |stage, done, n| {
        progress(stage, done, n)
    })?;
    captured.seconds.training += t.elapsed().as_secs_f64();
    tracing::info!(
        "training: {} in {:.1} s",
        model.meta.method,
        t.elapsed().as_secs_f64()
    );
    Ok(model)
}

/// The fit the calibration asks for, on the sampling pairs `captured` holds, sharing its
/// geometry.
fn request(opts: &Options, captured: &Captured) -> Request {
    sampling_request(
        opts,
        (captured.patterns.ntrain, captured.loop_images),
        &captured.geometry,
    )
}

/// The fit the calibration asks for on `ntrain` sampling pairs, with `loops` closed-loop pairs
/// to come, sharing `geometry`.
fn sampling_request(
    opts: &Options,
    (ntrain, loops): (usize, usize),
    geometry: &Arc<crate::linear::GeometryMemo>,
) -> Request {
    Request {
        ntrain: Some(ntrain),
        seed: opts.fit_seed,
        iters: opts
            .iters
            .filter(|_| !matches!(opts.method, MethodChoice::Rung(m) if m.is_linear())),
        device: opts.device,
        projector: Some(opts.patterns.projector),
        cancel: opts.cancel.clone(),
        climb_gain_db: (opts.method == MethodChoice::Auto).then_some(opts.climb_gain_db),
        climb_later: climbs_on_loop_pairs(opts, loops),
        // The verification projects a climbed rung beside the best linear rung: the rig judges.
        rig_judges: opts.method == MethodChoice::Auto,
        geometry_memo: Some(geometry.clone()),
        live: opts.live.clone(),
        ..Request::new(opts.method)
    }
}

/// The first fit [`train`] makes of `req`: a residual rung that takes closed-loop pairs
/// (`loops` > 0) fits its `linear` part first, whose compensations they are; any other rung
/// fits itself.
fn first_request(opts: &Options, loops: usize, req: &Request) -> Request {
    match opts.method {
        MethodChoice::Rung(m) if loops > 0 && !m.is_linear() => Request {
            method: MethodChoice::Rung(crate::model::Method::Linear),
            iters: None,
            batch: None,
            ..req.clone()
        },
        _ => req.clone(),
    }
}

/// When a calibration's first fit is `linear` (on all its sampling pairs, sampling rounds
/// aside): the request that fits it on the first pairs behind the captures ([`grow`]) and how
/// many pairs that is (the geometry's, [`crate::linear::FitSettings::geometry_images`]).
fn first_grows(
    opts: &Options,
    geometry: &Arc<crate::linear::GeometryMemo>,
) -> Option<(Request, usize)> {
    let ntrain = opts.patterns.ntrain;
    let req = sampling_request(opts, (ntrain, opts.loop_images), geometry);
    let first = first_request(opts, opts.loop_images, &req);
    if first.method != MethodChoice::Rung(crate::model::Method::Linear) {
        return None;
    }
    let pairs = crate::linear::FitSettings::default()
        .geometry_images
        .min(ntrain);
    Some((
        Request {
            ntrain: Some(pairs),
            // The grown fit solves every pixel from its own sums: the first fit's per-pixel
            // solve would be thrown away.
            colour: crate::linear::ColourSolve::Global,
            ..first
        },
        pairs,
    ))
}

/// Whether `auto`'s climb waits for the closed-loop pairs: `auto` with enough of them for the
/// residual rung's correction to train on ([`fit::judges_on_loop_pairs`], the count offline
/// `auto` needs to judge it on some held out). [`train`] then chooses among the
/// linear rungs alone, and [`refit`] fits `auto` again once the chosen rung has taken them.
fn climbs_on_loop_pairs(opts: &Options, loops: usize) -> bool {
    opts.method == MethodChoice::Auto && fit::judges_on_loop_pairs(loops)
}

/// Phase 5: projects held-out test images compensated by `model` and as they are, scores them
/// and writes the record. After `auto` climbed, the linear rung [`train`] fitted beside it is
/// projected on the same images, and the rung the rig confirms ([`fit::ClimbRule::confirms`])
/// is the one returned, with both rungs' figures in its `training.auto`. The projector may have
/// shown other things since the captures (the service plays while it trains): synchronisation
/// starts afresh from the measured latency.
pub fn verify_model<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    captured: Captured,
    model: Model,
    opts: &Options,
    progress: Progress,
) -> Result<Calibrated> {
    let Captured {
        root,
        setup,
        desired,
        exposure,
        latency,
        clock,
        captured,
        resumed,
        retakes,
        reconnects,
        mut seconds,
        started,
        lower_rung,
        loop_pairs,
        mut floor,
        geometry: _,
        prefit: _,
        grower: _,
        patterns: _,
        loop_images: _,
        sampling,
        loop_choice,
        round_model: _,
    } = captured;
    opts.check_cancelled()?;
    let t = Instant::now();
    let mut capturer = Capturer::new(display, camera, &latency, opts.sync).with_clock(clock);
    let models: Vec<&Model> = std::iter::once(&model).chain(lower_rung.as_ref()).collect();
    let views = &desired.views;
    // The test images as they are were captured by this very run with the pairs: those
    // captures are the uncompensated projection, not taken again. Not where any capture was
    // found on disk (it may be of another day's light), nor with two models to compare,
    // whose compensations of one image may look alike and are kept apart by it.
    let plain = match (resumed, models.len()) {
        (0, 1) => Some(
            Setup::open(&setup, Some(root.path()))?
                .load_captures(CaptureSet::Test, Some(opts.verify_images.min(views.len())))?,
        ),
        _ => None,
    };
    let mut verifications = verify(
        &mut capturer,
        &models,
        &root,
        (desired.area, views, plain.as_deref()),
        opts,
        progress,
    )?;
    let (model, verification) = match (lower_rung, verifications.pop(), verifications.pop()) {
        (Some(lower), Some(lower_v), Some(upper_v)) => {
            confirm_climb((model, upper_v), (lower, lower_v), opts.climb_gain_db)
        }
        (None, Some(v), None) => (model, v),
        _ => {
            return Err(Error::Failed(
                "the verification scored another number of models than it was given".into(),
            ));
        }
    };
    seconds.verification = t.elapsed().as_secs_f64();
    floor.add(&capturer.floor);
    opts.check_cancelled()?;
    seconds.total = started.elapsed().as_secs_f64();
    let record = CalibrationRecord {
        rig: opts.rig.clone(),
        seed: Some(opts.patterns.seed),
        exposure,
        display_range: Some(desired.range),
        unreachable: Some(desired.unreachable.clone()),
        latency,
        captured,
        resumed,
        retakes: retakes + capturer.retakes,
        reconnects: reconnects + capturer.reconnects,
        seconds,
        verification,
        climb: None,
        loop_pairs,
        capture_floor: Some(floor),
        sampling,
        closed_loop: loop_choice,
    };
    Ok(Calibrated {
        model,
        record,
        setup,
    })
}

/// Closed-loop verification of `models` after a calibration, on its data root `root` and setup
/// `setup` (progressive calibration's check of a climbed rung against the installed model): the
/// first `opts.verify_images` test images, whose desired views the calibration wrote, projected
/// as they are and compensated by each model, synchronised by the calibration's `latency`.
/// One verification per model, in order.
pub fn verify_after<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    (root, setup): (&Path, &Path),
    models: &[&Model],
    latency: &Latency,
    opts: &Options,
    progress: Progress,
) -> Result<Vec<Verification>> {
    let root = DataRoot::open(root)?;
    let setup = Setup::open(setup, Some(root.path()))?;
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let label = setup.capture_dir(CaptureSet::Ref).display().to_string();
    let fov = fov::fov_mask(&black, &white, &label)?;
    let area = fov::displayable_area(&fov.mask, display.size().aspect())?;
    let views = setup.load_desired(Some(opts.verify_images))?;
    // The calibration's mapping of the camera's clock is long gone (the camera may have been
    // reopened since): learned again, so that frames waiting in its buffers from before a
    // show are skipped, not taken for the show.
    let clock = clock::learn(camera)?;
    let mut capturer = Capturer::new(display, camera, latency, opts.sync).with_clock(clock);
    verify(
        &mut capturer,
        models,
        &root,
        (area, &views, None),
        opts,
        progress,
    )
}

/// The rig's verdict on a climb ([`fit::settle_climb`]) from the verifications of the climbed
/// rung (`upper`) and of the linear rung fitted beside it (`lower`): the model kept and its
/// verification.
fn confirm_climb(
    upper: (Model, Verification),
    lower: (Model, Verification),
    gain_db: f64,
) -> (Model, Verification) {
    let score = |(m, v): &(Model, Verification)| ClosedLoopScore {
        method: m.meta.method,
        psnr: v.psnr,
        ssim: v.ssim,
        passed: v.passed,
    };
    let (su, sl) = (score(&upper), score(&lower));
    let (model, kept_upper) =
        fit::settle_climb((upper.0, su), (lower.0, sl), fit::ClimbRule { gain_db });
    (model, if kept_upper { upper.1 } else { lower.1 })
}

/// Installs a calibration's model into the model directory `out`, its record in `model.json`,
/// if it verified; the swap is atomic (the previous model is in place until it). A model that did
/// not verify is an error ([`Error::Failed`]) saying why, and `out` is left as it was.
pub fn install(done: Calibrated, out: &Path) -> Result<Model> {
    let v = &done.record.verification;
    if !v.passed {
        let failure = v
            .failure
            .map_or(String::new(), |f| format!(" ({}: {})", f, f.explain()));
        return Err(Error::Failed(format!(
            "the {} model did not verify ({:+.2} dB over the uncompensated projection, {:+.2} \
             needed){failure}; it was not installed and {} is unchanged",
            done.model.meta.method,
            v.gain_db,
            v.required_gain_db,
            out.display()
        )));
    }
    let mut model = done.model;
    model.meta.calibration = Some(done.record);
    model.save(out)?;
    Ok(model)
}

/// Writes the projector-side images the calibration projects, where not already there:
/// `train/`, `test/`, the colour cube and the gray image (network size).
/// An image already there (an interrupted run's, or another's) is kept only if it is the one
/// this pattern set would write; any other is an input error naming it
/// ([`DataRoot::write_new`]), so a calibration never projects, and trains on, images its
/// record does not describe.
fn write_patterns(root: &DataRoot, p: &PatternSet) -> Result<()> {
    let (w, h) = (p.network.width, p.network.height);
    // The whole colour cube, so the root is a complete one (`inspect` checks that `ref/` is
    // numbered without gaps); only black (1) and white (125) are projected.
    let mut images: Vec<PatternImage> = Vec::new();
    images.extend((1..=p.ntrain).map(|i| PatternImage::Sampling(Set::Train, i)));
    images.extend((1..=p.ntest).map(|i| PatternImage::Sampling(Set::Test, i)));
    images.extend((1..=patterns::CUBE_COUNT).map(PatternImage::Cube));
    images.push(PatternImage::Gray);
    let write = |image: &PatternImage| -> Result<()> {
        let written = match *image {
            PatternImage::Sampling(set, i) => write_sampling(root, p, (set, i..=i)),
            PatternImage::Cube(i) => {
                root.write_new(ProjectorSet::Ref, i, &patterns::color_cube(i, w, h)?)
            }
            PatternImage::Gray => {
                root.write_new_gray_input(&patterns::gray_image(p.gray_level, w, h))
            }
        };
        written.map_err(|e| not_ours(e, p))
    };
    // Each file is synced to the disk before it is moved into place: written one at a time,
    // the waits for the disk (two a file, 184 files by default) came one after another.
    let next = std::sync::atomic::AtomicUsize::new(0);
    let failed = std::sync::Mutex::new(None::<(usize, Error)>);
    std::thread::scope(|s| {
        for _ in 0..PATTERN_WRITERS {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(image) = images.get(k) else { return };
                    if let Err(e) = write(image) {
                        let mut first = failed.lock().unwrap_or_else(|e| e.into_inner());
                        // The first failure in the images' order, as when written in order.
                        if first.as_ref().is_none_or(|(j, _)| k < *j) {
                            *first = Some((k, e));
                        }
                        next.store(images.len(), std::sync::atomic::Ordering::Relaxed);
                        return;
                    }
                }
            });
        }
    });
    match failed.into_inner().unwrap_or_else(|e| e.into_inner()) {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}

/// Threads writing the patterns: each mostly waits for the disk.
const PATTERN_WRITERS: usize = 4;

/// One image of the pattern set ([`write_patterns`]).
enum PatternImage {
    /// Sampling image `i` (1-based) of a set.
    Sampling(Set, usize),
    /// Colour cube image `i` (1-based).
    Cube(usize),
    Gray,
}

/// An image of the data root that is not the one pattern set `p` would write there
/// ([`DataRoot::write_new`]'s input error), with what this calibration projects.
fn not_ours(e: Error, p: &PatternSet) -> Error {
    match e {
        Error::Input(m) => Error::Input(format!(
            "{m}; this calibration projects sampling seed {}, network {}, gray level {}: \
             choose another data folder (--data, or [paths] data for the service)",
            p.seed, p.network, p.gray_level
        )),
        e => e,
    }
}

/// Writes sampling images `indices` (1-based) of `set` (training or test) of the pattern set
/// `p` into the data root, where not already there ([`DataRoot::write_new`]).
fn write_sampling(
    root: &DataRoot,
    p: &PatternSet,
    (set, indices): (Set, std::ops::RangeInclusive<usize>),
) -> Result<()> {
    let pset = match set {
        Set::Train => ProjectorSet::Train,
        Set::Test => ProjectorSet::Test,
    };
    for i in indices {
        let img = patterns::sampling_image(p.seed, set, i - 1, p.network.width, p.network.height);
        root.write_new(pset, i, &img)?;
    }
    Ok(())
}

/// What [`sampling_rounds`] leaves.
struct RoundsDone {
    curve: SamplingCurve,
    /// The `linear` rung of the last round, on every sampling pair.
    model: Model,
    /// Captures taken, and found on disk, by the rounds after the first.
    captured: usize,
    resumed: usize,
    /// Seconds the captures waited for the rounds' fits (the first round's fit runs behind the
    /// next round's captures: only what outlasted them).
    held: f64,
}

/// `ntrain = auto` ([`rounds`]): with the references, the test pairs and the first round's
/// sampling pairs on disk (`on_disk` captures), fits the `linear` rung on the sampling pairs of each round in turn,
/// scores it on the test pairs in camera space, and captures the next round's while
/// [`Rounds::next`] asks for one, growing the manifest's pattern set first (a killed run
/// resumes from it, and scores its rounds again from the first; the pairs it had taken are all
/// used). The projector holds the last pattern while a round is fitted, except the first
/// round's, which is fitted behind the next round's captures (one score cannot end the rounds).
fn sampling_rounds<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    capturer: &mut Capturer<'_, D, C>,
    (root, setup): (&DataRoot, &Setup),
    (manifest, mut on_disk): (&mut Manifest, usize),
    (rounds, geometry, prefit): (
        Rounds,
        &Arc<crate::linear::GeometryMemo>,
        Option<std::thread::JoinHandle<()>>,
    ),
    opts: &Options,
    progress: Progress,
) -> Result<RoundsDone> {
    // The first round's geometry, fitted ahead ([`start_prefit`]): the first fit waits for it
    // rather than fitting the same geometry beside it.
    let prefit = std::sync::Mutex::new(prefit);
    let tests = setup.load_test(Some(manifest.patterns.ntest))?;
    let mut curve: Vec<RoundScore> = Vec::new();
    let (mut captured, mut resumed, mut held) = (0, 0, 0.0);
    // The sampling pairs up to `pairs`, captured where not on disk yet, the manifest's pattern
    // set grown first.
    let mut take_round = |pairs: usize,
                          manifest: &mut Manifest,
                          capturer: &mut Capturer<'_, D, C>,
                          progress: Progress|
     -> Result<()> {
        if pairs <= manifest.patterns.ntrain {
            return Ok(());
        }
        let from = manifest.patterns.ntrain + 1;
        manifest.grow(setup.path(), pairs)?;
        write_sampling(root, &manifest.patterns, (Set::Train, from..=pairs))
            .map_err(|e| not_ours(e, &manifest.patterns))?;
        // Every capture of the earlier rounds is counted again as found on disk.
        let (c, r) = capture_all(
            capturer,
            (root, setup),
            manifest,
            (None, None),
            opts,
            progress,
        )?;
        captured += c;
        resumed += r.saturating_sub(on_disk);
        on_disk = c + r;
        Ok(())
    };
    // The `linear` rung on the first `pairs` sampling pairs, scored on the test pairs.
    let score_round = |pairs: usize,
                       progress: &mut dyn FnMut(&str, usize, usize)|
     -> Result<(Model, RoundScore)> {
        let t = Instant::now();
        let ahead = prefit.lock().unwrap_or_else(|e| e.into_inner()).take();
        if ahead.is_some_and(|h| h.join().is_err()) {
            tracing::warn!("the thread fitting the geometry ahead panicked; the fit makes its own");
        }
        let loops = match rounds.loops_follow {
            true => loop_images(opts.method, pairs, None),
            false => opts.loop_images,
        };
        let req = Request {
            method: MethodChoice::Rung(crate::model::Method::Linear),
            iters: None,
            batch: None,
            ..sampling_request(opts, (pairs, loops), geometry)
        };
        let (model, _) = fit::fit(setup, &req, progress)?;
        let mse = crate::model::forward_mse(&model, &tests)?.ok_or_else(|| {
            Error::Failed("the sampling round's linear fit has no forward model".into())
        })?;
        let score = RoundScore {
            pairs,
            mse,
            psnr: crate::metrics::psnr_from_mse(mse),
            seconds: t.elapsed().as_secs_f64(),
        };
        tracing::info!(
            "sampling round: {pairs} pairs, held-out camera-space error {:.2e} ({:.2} dB), \
             fitted and scored in {:.1} s",
            score.mse,
            score.psnr,
            score.seconds
        );
        Ok((model, score))
    };
    let mut pairs = rounds.first;
    loop {
        take_round(pairs, manifest, capturer, &mut *progress)?;
        opts.check_cancelled()?;
        progress("sampling round", pairs, rounds.most);
        // A round whose score cannot end the rounds is fitted behind the next round's
        // captures instead of holding the projector.
        if let Some(next) = rounds
            .next_regardless(&curve, pairs)
            .filter(|&next| next > manifest.patterns.ntrain)
        {
            let (scored, taken) = std::thread::scope(|s| {
                let behind =
                    s.spawn(|| crate::background::run(|| score_round(pairs, &mut |_, _, _| {})));
                let taken = take_round(next, manifest, capturer, &mut *progress);
                let waited = Instant::now();
                let scored = behind.join().unwrap_or_else(|_| {
                    Err(Error::Failed("the sampling round's fit panicked".into()))
                });
                held += waited.elapsed().as_secs_f64();
                (scored, taken)
            });
            taken?;
            curve.push(scored?.1);
            pairs = next;
            continue;
        }
        let (model, score) = score_round(pairs, &mut *progress)?;
        held += score.seconds;
        curve.push(score);
        match rounds.next(&curve) {
            Ok(next) => pairs = next,
            // An interrupted run had taken more rounds (the rule, scored afresh, may land
            // elsewhere by a rounding): the pairs on disk are all used, their round scored.
            Err(_) if pairs < manifest.patterns.ntrain => pairs = manifest.patterns.ntrain,
            Err(why) => {
                return Ok(RoundsDone {
                    curve: SamplingCurve {
                        rule: rounds.describe(),
                        rounds: curve,
                        chosen: pairs,
                        why,
                    },
                    model,
                    captured,
                    resumed,
                    held,
                });
            }
        }
    }
}

/// How many sampling pairs the geometry fitted ahead needs, and the sender that tells its
/// thread they are on disk ([`start_prefit`]).
type PrefitReady = (usize, std::sync::mpsc::Sender<()>);

/// Starts a thread that fits the `linear` geometry of the first `pairs` sampling pairs into
/// `memo` ([`fit::prefit_geometry`]) once told that the references and those pairs are on
/// disk, so that the fit after the captures (or the first sampling round's) finds it done.
/// Returns the sender to tell it with (and how many sampling pairs it needs) and the thread;
/// neither for a method whose first fit is not `linear`. The
/// thread ends without fitting when the sender is dropped untold (the captures failed); a
/// failed fit is logged, and the fit then makes its own.
fn start_prefit(
    root: &DataRoot,
    setup: &Setup,
    (opts, pairs): (&Options, usize),
    memo: &Arc<crate::linear::GeometryMemo>,
) -> (Option<PrefitReady>, Option<std::thread::JoinHandle<()>>) {
    let linear_first = match opts.method {
        MethodChoice::Rung(m) => m == crate::model::Method::Linear || m.is_residual(),
        MethodChoice::Auto => true,
    };
    if !linear_first {
        return (None, None);
    }
    let (tx, rx) = std::sync::mpsc::channel::<()>();
    let (root, setup) = (root.path().to_path_buf(), setup.path().to_path_buf());
    let req = Request {
        projector: Some(opts.patterns.projector),
        geometry_memo: Some(memo.clone()),
        ..Request::new(MethodChoice::Rung(crate::model::Method::Linear))
    };
    let thread = std::thread::Builder::new()
        .name("geometry".into())
        .spawn(move || {
            if rx.recv().is_err() {
                return;
            }
            let fitted = crate::background::run(|| {
                Setup::open(&setup, Some(&root))
                    .and_then(|setup| fit::prefit_geometry(&setup, &req, pairs))
            });
            if let Err(e) = fitted {
                tracing::warn!("fitting the geometry ahead: {e}; the fit makes its own");
            }
        });
    match thread {
        Ok(t) => (Some((pairs, tx)), Some(t)),
        Err(e) => {
            tracing::warn!("could not start the thread that fits the geometry ahead: {e}");
            (None, None)
        }
    }
}

/// One capture to take: where it goes (relative to the setup) and what is shown.
struct Shot {
    rel: PathBuf,
    set: CaptureSet,
    index: usize,
    source: PathBuf,
}

/// Captures every pattern not yet on disk. Returns (captured now, found on disk).
/// `ready`: (k, a sender) to tell once the references and the first k sampling pairs are on
/// disk ([`start_prefit`]).
fn capture_all<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    capturer: &mut Capturer<'_, D, C>,
    (root, setup): (&DataRoot, &Setup),
    manifest: &mut Manifest,
    (ready, grower): (Option<PrefitReady>, Option<&grow::Grower>),
    opts: &Options,
    progress: Progress,
) -> Result<(usize, usize)> {
    let mut shots = Vec::new();
    for r in Reference::ALL {
        let source = match r {
            Reference::Gray => root.gray_input_path(),
            _ => root.image_path(ProjectorSet::Ref, r.index()),
        };
        shots.push((CaptureSet::Ref, r.index(), source));
    }
    let (ntrain, ntest) = (manifest.patterns.ntrain, manifest.patterns.ntest);
    let sets = [
        (CaptureSet::Train, ProjectorSet::Train, ntrain),
        (CaptureSet::Test, ProjectorSet::Test, ntest),
    ];
    // Sampling rounds score each round on the test pairs, after the first round's sampling
    // pairs: the first round's geometry is fitted ahead while the test pairs are captured
    // ([`start_prefit`]).
    for (set, pset, n) in sets {
        shots.extend((1..=n).map(|i| (set, i, root.image_path(pset, i))));
    }
    let shots: Vec<Shot> = shots
        .into_iter()
        .map(|(set, index, source)| {
            let path = setup.capture_path(set, index);
            let rel = path
                .strip_prefix(setup.path())
                .map(Path::to_path_buf)
                .unwrap_or(path);
            Shot {
                rel,
                set,
                index,
                source,
            }
        })
        .collect();
    let psize = capturer.projector_size();
    let canvas = Rect::covering(psize);
    let total = shots.len();
    let (todo, done): (Vec<Shot>, Vec<Shot>) = shots
        .into_iter()
        .partition(|shot| !manifest.has(setup.path(), &shot.rel));
    let resumed = done.len();
    let captured = todo.len();
    // The grower's first fit reads the references too: the sampling pairs found on disk are
    // told once every reference still to take is stored (they come first).
    let mut refs_todo = todo.iter().filter(|s| s.set == CaptureSet::Ref).count();
    let tell_done = || {
        if let Some(g) = grower {
            (done.iter())
                .filter(|s| s.set == CaptureSet::Train)
                .for_each(|s| g.stored(s.index));
        }
    };
    if refs_todo == 0 {
        tell_done();
    }
    // The references come first, then the sampling pairs in order: once sampling capture k is
    // stored, every capture the geometry needs is.
    let mut ready = ready;
    if let Some((k, tx)) = &ready
        && !todo
            .iter()
            .any(|s| s.set == CaptureSet::Train && s.index == *k)
    {
        // Already on disk (a resumed run): tell now.
        let _ = tx.send(());
        ready = None;
    }
    // Shown, captured and stored in a pipeline: the patterns are read and placed ahead, the
    // captures written (and recorded in the manifest, after their file) behind.
    pipeline::run(
        todo.len(),
        |k| {
            let img: PrjImage = crate::pngio::read_rgb(&todo[k].source)?;
            place_on_canvas(&img, canvas, psize)
        },
        |k, frame| {
            progress("captures", resumed + k, total);
            opts.check_cancelled()?;
            capturer.capture(&frame, true)
        },
        |k, cap| {
            let shot = &todo[k];
            setup.write_capture(shot.set, shot.index, &cap)?;
            manifest.record(setup.path(), shot.rel.clone())?;
            if shot.set == CaptureSet::Ref {
                refs_todo -= 1;
                if refs_todo == 0 {
                    tell_done();
                }
            }
            if let Some(g) = grower
                && shot.set == CaptureSet::Train
            {
                g.stored(shot.index);
            }
            if ready
                .as_ref()
                .is_some_and(|(n, _)| shot.set == CaptureSet::Train && shot.index == *n)
                && let Some((_, tx)) = ready.take()
            {
                let _ = tx.send(());
            }
            Ok(())
        },
    )?;
    progress("captures", total, total);
    Ok((captured, resumed))
}

/// What the verification compares with: the FOV, the displayable area, and the desired view of
/// each test image (camera pixels), also written to `cam/desire/test`.
struct Desired {
    area: Rect,
    range: fov::DisplayRange,
    views: Vec<CamImage>,
    /// The share of the area no model can compensate.
    unreachable: fov::ReachSummary,
}

/// The desired views of the test images: each scaled into the display range and stretched into
/// the displayable area, as `sim export` and playback place content.
fn write_desired(root: &DataRoot, setup: &Setup, opts: &Options) -> Result<Desired> {
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let label = setup.capture_dir(CaptureSet::Ref).display().to_string();
    let fov = fov::fov_mask(&black, &white, &label)?;
    let projector = opts.patterns.projector;
    let area = fov::displayable_area(&fov.mask, projector.aspect())?;
    let range = fov::display_range(&black, &white, area, fov::DESIRED_RANGE_QUANTILE)?;
    let reach = fov::reach(&black, &white, area, range)?;
    crate::pngio::write_rgb(&setup.unreachable_path(), &reach.picture(&white)?)?;
    let unreachable = reach.summary();
    tracing::info!("{}", unreachable.line());
    let mut views = Vec::new();
    for i in 1..=opts.patterns.ntest {
        let img: PrjImage = crate::pngio::read_rgb(&root.image_path(ProjectorSet::Test, i))?;
        let z = fov::place_in_area(&range.apply(&img), area, black.size())?;
        setup.write_desired(i, &z)?;
        views.push(z);
    }
    Ok(Desired {
        area,
        range,
        views,
        unreachable,
    })
}

/// Projects the first test images as they are and compensated by each of `models` (in turn,
/// image by image, so a slow drift of the rig weighs on all alike), captures them and scores
/// each inside the displayable area against their desired views: one verification per model,
/// in order, sharing the uncompensated figures. With `plain`, the captures of the test images
/// as they are (as many as are verified, taken by this calibration), those are scored as the
/// uncompensated projection instead of projecting them again.
fn verify<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    capturer: &mut Capturer<'_, D, C>,
    models: &[&Model],
    root: &DataRoot,
    (area, views, plain): (Rect, &[CamImage], Option<&[CamImage]>),
    opts: &Options,
    progress: Progress,
) -> Result<Vec<Verification>> {
    let psize = capturer.projector_size();
    let canvas = Rect::covering(psize);
    let n = opts.verify_images.min(views.len());
    if n == 0 {
        return Err(Error::Input(
            "verification needs at least one test image (--ntest)".into(),
        ));
    }
    if models.is_empty() {
        return Err(Error::Failed("the verification was given no model".into()));
    }
    let mut comp: Vec<Accumulator> = models.iter().map(|_| Accumulator::default()).collect();
    let mut outputs: Vec<Vec<crate::raster::NetImage>> =
        models.iter().map(|_| Vec::with_capacity(n)).collect();
    let mut unc = Accumulator::default();
    let plain = plain.filter(|p| p.len() >= n);
    if let Some(seen) = plain {
        for (seen, want) in seen.iter().zip(views).take(n) {
            unc.add(&seen.crop(area)?, &want.crop(area)?)?;
        }
    }
    // Per test image: the first model, the image as it is (unless captured already), then the
    // other models. Each capture follows a frame that differs from it (two rungs'
    // compensations of one image may look alike, and the capturer checks that the camera saw
    // the change). Compensated ahead and scored behind ([`pipeline`]).
    let shots: Vec<(usize, Option<usize>)> = (0..n)
        .flat_map(|i| {
            std::iter::once(Some(0))
                .chain(plain.is_none().then_some(None))
                .chain((1..models.len()).map(Some))
                .map(move |shot| (i, shot))
        })
        .collect();
    let per_image = shots.len() / n;
    pipeline::run(
        shots.len(),
        |j| {
            let (i, shot) = shots[j];
            let (shown, compensated) = match shot {
                Some(k) => {
                    let compensated = models[k].infer(&views[i])?;
                    let frame = place_on_canvas(&compensated, canvas, psize)?;
                    (frame, Some(compensated))
                }
                None => {
                    let plain: PrjImage =
                        crate::pngio::read_rgb(&root.image_path(ProjectorSet::Test, i + 1))?;
                    (place_on_canvas(&plain, canvas, psize)?, None)
                }
            };
            Ok((shown, compensated))
        },
        |j, (shown, compensated)| {
            progress("verification", j / per_image, n);
            opts.check_cancelled()?;
            Ok((capturer.capture_after_change(&shown)?, compensated))
        },
        |j, (seen, compensated)| {
            let (i, shot) = shots[j];
            let want = views[i].crop(area)?;
            match (shot, compensated) {
                (Some(k), Some(out)) => {
                    outputs[k].push(out);
                    comp[k].add(&seen.crop(area)?, &want)
                }
                _ => unc.add(&seen.crop(area)?, &want),
            }
        },
    )?;
    progress("verification", n, n);
    let u = unc.finish()?;
    let inputs: Vec<&CamImage> = views.iter().take(n).collect();
    comp.into_iter()
        .zip(&outputs)
        .map(|(acc, out)| {
            let c = acc.finish()?;
            let gain = c.psnr - u.psnr;
            let failure =
                crate::failure::classify(&inputs, &out.iter().collect::<Vec<_>>(), c.psnr, u.psnr);
            Ok(Verification {
                images: n,
                psnr: c.psnr,
                ssim: c.ssim,
                uncompensated_psnr: u.psnr,
                uncompensated_ssim: u.ssim,
                uncompensated_from_test_pairs: plain.is_some(),
                gain_db: gain,
                required_gain_db: opts.required_gain_db,
                failure,
                passed: passes(failure, gain, opts.required_gain_db),
            })
        })
        .collect()
}
