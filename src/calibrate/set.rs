//! Calibrating a set of projectors seen by one camera (docs/architecture.md, "Sets of
//! projectors"): the displays shown side by side as one ([`SideBySide`]), so the exposure is
//! ranged with every projector white; then each projector calibrated as one projector is
//! (the phases of [`super::calibrate`]: its own latency, captures, `linear` fit, closed-loop
//! pairs and verification) with the others black and the exposure held, each projector's fits
//! running behind the next projector's captures; then the joint model ([`crate::joint`])
//! checked as a whole in closed loop, over the displayable area of the whole set, against each
//! projector compensating alone, with the seam figure along the overlaps. The parts of that
//! check that need no later projector's model (the set's views, each projector alone) are
//! taken as soon as each projector is verified, while the later projectors' refits run.

use std::path::Path;
use std::time::Instant;

use super::clock::CameraClock;
use super::{Calibrated, Capturer, Options, Progress, exposure};
use crate::dataset::{DataRoot, ProjectorSet};
use crate::device::{DisplaySink, FrameSource, HeldExposure, SideBySide, side_by_side};
use crate::error::{Error, Result};
use crate::fit::DEFAULT_RIG_GAIN_DB;
use crate::fov;
use crate::joint::JointModel;
use crate::metrics::{Accumulator, SeamFigure};
use crate::model::set::SetModel;
use crate::model::store::projector_dir;
use crate::model::{Method, MethodChoice};
use crate::playback::place_on_canvas;
use crate::raster::{CamImage, ImageSize, PrjImage, Rect};
use crate::record::{Latency, SetRecord, SetVerification};

/// The PSNR gain (dB) the joint compensation needs over the best projector compensating
/// alone: at most the ladder's closed-loop margin below it ([`DEFAULT_RIG_GAIN_DB`], 0.2 dB).
/// A set that does clearly worse than one of its projectors is not worth installing; a
/// difference smaller than the margin at which the rig calls one model better than another
/// is not counted as a loss either. A stacked set on a dark texture scores within a tenth of
/// a decibel of its better projector alone (−0.09 to +0.33 dB over six seeds,
/// docs/bench/sets.md) while leaving a quarter of its unreachable share: at 0 dB it passed or
/// failed by the seed.
pub const REQUIRED_GAIN_DB: f64 = -DEFAULT_RIG_GAIN_DB;

/// The largest seam ratio ([`SeamFigure::ratio`]) that passes. The joint physical ceiling of
/// the virtual rig's sets has 1.37 (`tiled`) and 1.44 (`stacked`), seed 0, 640×480: the band
/// along an overlap edge is where both projectors' geometry meets, and even the ceiling errs a
/// little more there. Twice the error in the band as away from it is a seam one sees.
pub const SEAM_LIMIT: f64 = 2.0;

/// The folder of the data root the set's verification writes what it showed into: for each
/// test image, the desired view (`desired-NNN.png`) and the joint projection's capture
/// (`joint-NNN.png`), camera pixels.
pub const SET_DIR: &str = "set";

/// A calibrated set: its model (each projector's, with its own calibration record, and the
/// set's record) and whether it passed.
pub struct CalibratedSet {
    pub model: SetModel,
    pub record: SetRecord,
}

/// Calibrates the set of `displays` (one per projector, the set's first first) seen by
/// `camera` into data root `data` (each projector's captures in `data/projector-N`). Only the
/// `linear` rung is compensated jointly; another method is an input error.
pub fn calibrate_set<D: DisplaySink, C: FrameSource + ?Sized>(
    displays: Vec<D>,
    camera: &mut C,
    data: &Path,
    opts: &Options,
    progress: Progress,
) -> Result<CalibratedSet> {
    if opts.method != MethodChoice::Rung(Method::Linear) {
        return Err(Error::Input(format!(
            "--method {}: a set of projectors is calibrated with `linear` (each projector's \
             model, then the joint compensation of their light)",
            opts.method
        )));
    }
    // Before any capture: where the set's verification writes must take its files.
    check_set_dir(&data.join(SET_DIR))?;
    let started = Instant::now();
    let n = displays.len();
    let mut set = SideBySide::new(displays)?;
    show_black(&mut set)?;
    progress("exposure", 0, 1);
    let exposure = exposure::range_exposure(&mut set, camera)?.report;
    progress("exposure", 1, 1);
    // Each projector in the phases of `super::calibrate`, one projector at a time on the
    // display, its fits on a thread of their own behind the next projector's captures: the
    // sampling captures of every projector (each one's first fit running behind the next's
    // captures), then the closed-loop pairs of every projector (each one's refit behind the
    // next's pairs), then each one's verification.
    let ones: Vec<Options> = (0..n)
        .map(|k| Options {
            rig: format!("{} projector {}", opts.rig, k + 1),
            ..opts.clone()
        })
        .collect();
    let dirs: Vec<std::path::PathBuf> = (0..n).map(|k| data.join(projector_dir(k))).collect();
    // Seconds each projector held the display.
    let mut projector_seconds = vec![0.0; n];
    let mut fits = Vec::with_capacity(n);
    // A projector's fit waits for the next projector's latency to be measured: on the virtual
    // rig, whose camera is simulated on this machine's cores, a fit beside the measurement
    // would slow the camera and the latency measured (and every capture's wait) would grow.
    let mut waiting: Option<Box<dyn FnOnce() -> Result<Behind<Fitted>>>> = None;
    for k in 0..n {
        opts.check_cancelled()?;
        let t = Instant::now();
        show_black(&mut set)?;
        let mut step = |phase: &str, i: usize, total: usize| {
            if phase == "captures"
                && let Some(start) = waiting.take()
            {
                fits.push(start());
            }
            progress(&format!("projector {}/{n}: {phase}", k + 1), i, total);
        };
        let captured = super::capture(
            &mut set.displays()[k],
            &mut HeldExposure(&mut *camera),
            &dirs[k],
            &ones[k],
            &mut step,
        )?;
        projector_seconds[k] += t.elapsed().as_secs_f64();
        if let Some(start) = waiting.take() {
            fits.push(start());
        }
        let one = ones[k].clone();
        waiting = Some(Box::new(move || {
            Behind::start(k, "fit", move || {
                let mut captured = captured;
                let model = super::train(&mut captured, &one, &mut |_, _, _| {})?;
                Ok((captured, model))
            })
        }));
    }
    if let Some(start) = waiting.take() {
        fits.push(start());
    }
    // Each projector's latency as its last phase left it: the set's own captures wait for the
    // slowest projector.
    let mut latencies = Vec::with_capacity(n);
    let mut refits = Vec::with_capacity(n);
    for (k, fit) in fits.into_iter().enumerate() {
        let (mut captured, model) = fit?.join(&mut *progress, n)?;
        check_in_view(k, &model.fov)?;
        opts.check_cancelled()?;
        let t = Instant::now();
        show_black(&mut set)?;
        let mut step = |phase: &str, i: usize, total: usize| {
            progress(&format!("projector {}/{n}: {phase}", k + 1), i, total);
        };
        let taken = super::take_loop_pairs(
            &mut set.displays()[k],
            &mut HeldExposure(&mut *camera),
            &mut captured,
            model,
            &ones[k],
            &mut step,
        )?;
        projector_seconds[k] += t.elapsed().as_secs_f64();
        latencies.push(captured.latency.clone());
        let one = ones[k].clone();
        refits.push(Behind::start(k, "refit", move || {
            let mut captured = captured;
            let model = super::refit(&mut captured, taken, &one, &mut |_, _, _| {})?;
            Ok((captured, model))
        })?);
    }
    // Each projector's verification as soon as its refit is in, then the parts of the set's
    // verification that need no later projector's model (the set's views, then this
    // projector compensating them alone), all while the later projectors' refits run; the
    // joint projection last.
    let root = DataRoot::open(&data.join(projector_dir(0)))?;
    let mut check: Option<SetCheck> = None;
    let mut verification_seconds = 0.0;
    let mut done: Vec<Calibrated> = Vec::with_capacity(n);
    for (k, refit) in refits.into_iter().enumerate() {
        let (captured, model) = refit.join(&mut *progress, n)?;
        opts.check_cancelled()?;
        let t = Instant::now();
        show_black(&mut set)?;
        let mut step = |phase: &str, i: usize, total: usize| {
            progress(&format!("projector {}/{n}: {phase}", k + 1), i, total);
        };
        // The camera's clock as this projector's latency measurement last mapped it: the set's
        // captures skip frames exposed before each show by it, as the projector's own do.
        let clock = captured.clock;
        let calibrated = super::verify_model(
            &mut set.displays()[k],
            &mut HeldExposure(&mut *camera),
            captured,
            model,
            &ones[k],
            &mut step,
        )?;
        projector_seconds[k] += t.elapsed().as_secs_f64();
        latencies[k] = calibrated.record.latency.clone();
        let t = Instant::now();
        let latency = worst_latency(&latencies)?;
        let check = match &mut check {
            Some(c) => c,
            None => check.insert(SetCheck::views(
                &mut set,
                camera,
                &root,
                (&latency, clock),
                opts,
            )?),
        };
        check.alone(
            &mut set,
            camera,
            (k, &calibrated.model),
            (&latency, clock),
            opts,
            progress,
        )?;
        verification_seconds += t.elapsed().as_secs_f64();
        done.push(calibrated);
    }
    let Some(check) = check else {
        return Err(Error::Failed(
            "a set of no projectors was calibrated".into(),
        ));
    };
    let latency = worst_latency(&latencies)?;
    let models: Vec<_> = done
        .into_iter()
        .map(|c| {
            let mut m = c.model;
            m.meta.calibration = Some(c.record);
            m
        })
        .collect();
    let camera_gamma_spread = gamma_spread(&models);
    let model = SetModel::new(models, None)?;
    let t = Instant::now();
    let joint = model.joint()?;
    let (area, display_range, verification) = check.joint(
        &mut set,
        camera,
        (&joint, &data.join(SET_DIR)),
        &latency,
        opts,
        progress,
    )?;
    verification_seconds += t.elapsed().as_secs_f64();
    show_black(&mut set)?;
    let record = SetRecord {
        rig: opts.rig.clone(),
        exposure,
        camera_gamma_spread,
        area,
        display_range,
        verification,
        projector_seconds,
        verification_seconds,
        total_seconds: started.elapsed().as_secs_f64(),
    };
    let mut model = model;
    model.meta.calibration = Some(record.clone());
    Ok(CalibratedSet { model, record })
}

/// Installs a calibrated set's model into `out` if it passed; otherwise an error saying why,
/// `out` unchanged.
pub fn install_set(done: CalibratedSet, out: &Path) -> Result<SetModel> {
    let v = &done.record.verification;
    if !v.passed {
        return Err(Error::Failed(format!(
            "the set's joint compensation did not verify ({}); it was not installed and {} is \
             unchanged",
            v.why.as_deref().unwrap_or("no reason recorded"),
            out.display()
        )));
    }
    done.model.save(out)?;
    Ok(done.model)
}

/// The share of an image side's length the field of view of one projector may touch before
/// its picture counts as running off the camera's view.
pub const OFF_VIEW_SHARE: f64 = 0.02;

/// An input error when projector `k`'s field of view `fov` (camera pixels) reaches an edge of
/// the camera image along more than [`OFF_VIEW_SHARE`] of it: its picture runs off the camera's
/// view, so the camera does not see the whole set and the joint model would not know what the
/// set shows there.
fn check_in_view(k: usize, fov: &crate::raster::Mask<crate::raster::Camera>) -> Result<()> {
    let (w, h) = (fov.width(), fov.height());
    if w == 0 || h == 0 {
        return Ok(());
    }
    let sides = [
        ("left", (0..h).filter(|&y| fov.get(0, y)).count(), h),
        ("right", (0..h).filter(|&y| fov.get(w - 1, y)).count(), h),
        ("top", (0..w).filter(|&x| fov.get(x, 0)).count(), w),
        ("bottom", (0..w).filter(|&x| fov.get(x, h - 1)).count(), w),
    ];
    for (side, lit, length) in sides {
        let share = lit as f64 / length as f64;
        if share > OFF_VIEW_SHARE {
            return Err(Error::Input(format!(
                "projector {}'s picture runs off the camera's view at its {side} edge (its light \
                 reaches {:.0} % of that edge): the camera must see every projector's whole \
                 picture; widen the camera's view or move it back; nothing was installed",
                k + 1,
                share * 100.0
            )));
        }
    }
    Ok(())
}

/// An input error naming what [`SET_DIR`] holds that a set's verification did not write
/// there (only its `desired-NNN.png` and `joint-NNN.png` are replaced); nothing there is fine.
fn check_set_dir(dir: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, "list", e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let ours = ["desired-", "joint-"].iter().any(|p| {
            name.strip_prefix(p)
                .and_then(|rest| rest.strip_suffix(".png"))
                .is_some_and(|n| n.len() == 3 && n.bytes().all(|b| b.is_ascii_digit()))
        });
        if !ours || !entry.file_type().is_ok_and(|t| t.is_file()) {
            return Err(Error::Input(format!(
                "{}: holds `{name}`, which a set's verification did not write; it writes only \
                 desired-NNN.png and joint-NNN.png there: choose another data folder (--data)",
                dir.display()
            )));
        }
    }
    Ok(())
}

fn show_black<D: DisplaySink>(set: &mut SideBySide<D>) -> Result<()> {
    let size = set.size();
    set.show(&PrjImage::new(size.width, size.height))
}

/// The latency record of the projector that took longest to show a change: the set's
/// captures wait for the slowest.
fn worst_latency(latencies: &[Latency]) -> Result<Latency> {
    latencies
        .iter()
        .max_by_key(|l| l.settle_frames)
        .cloned()
        .ok_or_else(|| Error::Failed("a set of no projectors was calibrated".into()))
}

/// The spread of the projectors' camera-curve exponents (largest − smallest).
fn gamma_spread(models: &[crate::model::Model]) -> f64 {
    let gammas: Vec<f32> = models
        .iter()
        .filter_map(|m| match &m.kind {
            crate::model::Kind::Linear { simplified, .. } => Some(simplified.curves.camera_gamma),
            _ => None,
        })
        .flatten()
        .collect();
    let hi = gammas.iter().copied().fold(f32::MIN, f32::max);
    let lo = gammas.iter().copied().fold(f32::MAX, f32::min);
    if gammas.is_empty() {
        0.0
    } else {
        f64::from(hi - lo)
    }
}

/// The whole set's closed-loop check (module documentation), taken in parts so that most of
/// it runs while later projectors' refits do: the displayable area of the set from its black
/// and white and the first `opts.verify_images` test images of the first projector's data root
/// placed there ([`SetCheck::views`]); each view compensated by each projector alone, as soon
/// as that projector's model is final ([`SetCheck::alone`]); then each view compensated
/// jointly, with the seam figure along the overlap edges ([`SetCheck::joint`]). Every part is
/// captured and scored inside the area.
struct SetCheck {
    area: Rect,
    range: fov::DisplayRange,
    /// The desired views (camera pixels, encoded values), the whole camera image.
    views: Vec<CamImage>,
    /// Each projector's score compensating the views alone, in projector order.
    alone: Vec<Accumulator>,
    /// The view the last capture of the set aimed at: two captures in a row that aim at one
    /// view have white between them, as closed-loop pairs do.
    last_view: Option<usize>,
    /// The camera's clock as the last projector's latency measurement mapped it: every
    /// capture skips the frames exposed before its show ([`Capturer::with_clock`]).
    clock: Option<CameraClock>,
}

impl SetCheck {
    /// The set's black and white captured, its displayable area and display range found, and
    /// the desired views placed in that area.
    fn views<D: DisplaySink, C: FrameSource + ?Sized>(
        set: &mut SideBySide<D>,
        camera: &mut C,
        root: &DataRoot,
        (latency, clock): (&Latency, Option<CameraClock>),
        opts: &Options,
    ) -> Result<Self> {
        let verify_n = opts.verify_images.min(opts.patterns.ntest);
        if verify_n == 0 {
            return Err(Error::Input(
                "verification needs at least one test image (--ntest)".into(),
            ));
        }
        let size = set.size();
        let black_whole = PrjImage::new(size.width, size.height);
        let white_whole = PrjImage::filled(size.width, size.height, [1.0; 3]);
        let mut capturer = Capturer::new(set, camera, latency, opts.sync).with_clock(clock);
        let black = capturer.capture(&black_whole, true)?;
        let white = capturer.capture(&white_whole, true)?;
        let label = format!("the set {}", opts.rig);
        let fov = fov::fov_mask(&black, &white, &label)?;
        let aspect = fov
            .mask
            .bounding_box()
            .map_or(4.0 / 3.0, |b| b.width as f64 / b.height.max(1) as f64);
        let area = fov::displayable_area(&fov.mask, aspect)?;
        let range = fov::display_range(&black, &white, area, fov::DESIRED_RANGE_QUANTILE)?;
        let views: Vec<CamImage> = (1..=verify_n)
            .map(|i| {
                let img: PrjImage =
                    crate::pngio::read_rgb(&root.image_path(ProjectorSet::Test, i))?;
                fov::place_in_area(&range.apply(&img), area, black.size())
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            area,
            range,
            views,
            alone: Vec::new(),
            last_view: None,
            clock,
        })
    }

    /// Progress steps of the whole check: each view by each projector alone, then jointly.
    fn steps(&self, n: usize) -> usize {
        self.views.len() * (1 + n)
    }

    /// Projector `k` (the next one: projectors are checked in order), with its final `model`,
    /// compensating each view alone, the other projectors black.
    fn alone<D: DisplaySink, C: FrameSource + ?Sized>(
        &mut self,
        set: &mut SideBySide<D>,
        camera: &mut C,
        (k, model): (usize, &crate::model::Model),
        (latency, clock): (&Latency, Option<CameraClock>),
        opts: &Options,
        progress: Progress,
    ) -> Result<()> {
        let n = set.displays().len();
        if k != self.alone.len() || k >= n {
            return Err(Error::Failed(format!(
                "the set's check took projector {} alone after {} of {n}",
                k + 1,
                self.alone.len()
            )));
        }
        self.clock = clock.or(self.clock);
        let sizes: Vec<_> = set.displays().iter().map(|d| d.size()).collect();
        let steps = self.steps(n);
        let mut capturer = Capturer::new(set, camera, latency, opts.sync).with_clock(self.clock);
        let mut acc = Accumulator::default();
        for (i, view) in self.views.iter().enumerate() {
            progress("set verification", self.views.len() * k + i, steps);
            opts.check_cancelled()?;
            let alone = model.infer(view)?;
            let mut frames: Vec<PrjImage> = sizes
                .iter()
                .map(|s| PrjImage::new(s.width, s.height))
                .collect();
            frames[k] = place_on_canvas(&alone, Rect::covering(sizes[k]), sizes[k])?;
            let seen = aim(
                &mut capturer,
                &mut self.last_view,
                i,
                &side_by_side(&frames),
            )?;
            acc.add(&seen.crop(self.area)?, &view.crop(self.area)?)?;
        }
        self.alone.push(acc);
        Ok(())
    }

    /// Each view compensated jointly by the set's `joint` model, what it showed written into
    /// `shown` for a person to look at; then the verdict: the joint score against the best
    /// projector alone, and the seam figure along the overlap edges.
    fn joint<D: DisplaySink, C: FrameSource + ?Sized>(
        mut self,
        set: &mut SideBySide<D>,
        camera: &mut C,
        (joint, shown): (&JointModel, &Path),
        latency: &Latency,
        opts: &Options,
        progress: Progress,
    ) -> Result<(Rect, fov::DisplayRange, SetVerification)> {
        let n = joint.projectors();
        if self.alone.len() != n {
            return Err(Error::Failed(format!(
                "the set's check has {} projectors alone of {n}",
                self.alone.len()
            )));
        }
        let sizes: Vec<_> = set.displays().iter().map(|d| d.size()).collect();
        let area = self.area;
        let covers: Vec<_> = (0..n)
            .filter_map(|k| joint.cover(k).map(|c| c.mask()))
            .collect();
        let bands = crate::joint::seam::seam_bands(&covers, area, self.views[0].size());
        std::fs::create_dir_all(shown).map_err(|e| Error::io(shown, "create folder", e))?;
        let steps = self.steps(n);
        let verify_n = self.views.len();
        let mut capturer = Capturer::new(set, camera, latency, opts.sync).with_clock(self.clock);
        let mut joint_acc = Accumulator::default();
        let mut seams: Vec<SeamFigure> = Vec::new();
        for (i, view) in self.views.iter().enumerate() {
            progress("set verification", verify_n * n + i, steps);
            opts.check_cancelled()?;
            let want = view.crop(area)?;
            let frames = joint
                .apply(view)?
                .iter()
                .enumerate()
                .map(|(k, o)| place_on_canvas(o, Rect::covering(sizes[k]), sizes[k]))
                .collect::<Result<Vec<_>>>()?;
            let seen = aim(
                &mut capturer,
                &mut self.last_view,
                i,
                &side_by_side(&frames),
            )?;
            // What the set was to show and what it showed, for a person to look at.
            crate::pngio::write_rgb(&shown.join(format!("desired-{:03}.png", i + 1)), view)?;
            crate::pngio::write_rgb(&shown.join(format!("joint-{:03}.png", i + 1)), &seen)?;
            joint_acc.add(&seen.crop(area)?, &want)?;
            if let Some((band, away)) = &bands {
                seams.push(crate::metrics::seam_figure(
                    &seen,
                    view,
                    band.data(),
                    away.data(),
                )?);
            }
        }
        progress("set verification", steps, steps);
        let j = joint_acc.finish()?;
        let alone_psnr = self
            .alone
            .into_iter()
            .map(|a| a.finish().map(|s| s.psnr))
            .collect::<Result<Vec<_>>>()?;
        let best = alone_psnr.iter().copied().fold(f64::MIN, f64::max);
        let gain_db = j.psnr - best;
        let seam = SeamFigure::mean(&seams);
        let mut why = Vec::new();
        if !(gain_db.is_finite() && gain_db >= REQUIRED_GAIN_DB) {
            why.push(format!(
                "{:.2} dB jointly against {best:.2} dB for the best projector alone",
                j.psnr
            ));
        }
        if let Some(s) = seam
            && s.ratio() > SEAM_LIMIT
        {
            why.push(format!(
                "a seam shows: {:.2}× the error along the overlap edges as away from them, at \
                 most {SEAM_LIMIT} passes",
                s.ratio()
            ));
        }
        Ok((
            area,
            self.range,
            SetVerification {
                images: verify_n,
                psnr: j.psnr,
                ssim: j.ssim,
                alone_psnr,
                gain_db,
                required_gain_db: REQUIRED_GAIN_DB,
                seam,
                seam_limit: SEAM_LIMIT,
                passed: why.is_empty(),
                why: (!why.is_empty()).then(|| why.join("; ")),
            },
        ))
    }
}

/// Captures `frame`, which aims at view `i` of the set's check: when the last capture (`last`)
/// aimed at the same view, white comes first, so the camera sees the change.
fn aim<D: DisplaySink, C: FrameSource + ?Sized>(
    capturer: &mut Capturer<'_, SideBySide<D>, C>,
    last: &mut Option<usize>,
    i: usize,
    frame: &PrjImage,
) -> Result<CamImage> {
    if *last == Some(i) {
        let ImageSize { width, height } = frame.size();
        capturer.capture_averaging(&PrjImage::filled(width, height, [1.0; 3]), true, 1)?;
    }
    let seen = capturer.capture_after_change(frame)?;
    *last = Some(i);
    Ok(seen)
}

/// A projector's captures and the model fitted on them.
type Fitted = (super::Captured, crate::model::Model);

/// A projector's fit running on a thread of its own while the display serves another
/// projector, behind the captures ([`crate::background`]).
struct Behind<T> {
    k: usize,
    what: &'static str,
    thread: std::thread::JoinHandle<Result<T>>,
}

impl<T: Send + 'static> Behind<T> {
    /// Starts `work` (projector `k`'s `what`) on a thread.
    fn start(
        k: usize,
        what: &'static str,
        work: impl FnOnce() -> Result<T> + Send + 'static,
    ) -> Result<Self> {
        let thread = std::thread::Builder::new()
            .name(format!("projector {} {what}", k + 1))
            .spawn(move || crate::background::run(work))
            .map_err(|e| {
                Error::Failed(format!(
                    "cannot start the thread of projector {}'s {what}: {e}",
                    k + 1
                ))
            })?;
        Ok(Self { k, what, thread })
    }

    /// Waits for it (saying so as a phase of the `n` projectors' progress) and returns what
    /// it made; a panic on its thread is an error naming it.
    fn join(self, progress: Progress, n: usize) -> Result<T> {
        let phase = format!("projector {}/{n}: {}", self.k + 1, self.what);
        let waits = !self.thread.is_finished();
        if waits {
            progress(&phase, 0, 1);
        }
        let out = self.thread.join().map_err(|_| {
            Error::Failed(format!(
                "projector {}'s {} stopped on an internal error (its thread panicked)",
                self.k + 1,
                self.what
            ))
        })?;
        if waits {
            progress(&phase, 1, 1);
        }
        out
    }
}
