//! The engine's calibrations. A calibration runs in steps (`crate::calibrate`): the captures
//! (exposure, latency, patterns) on the engine thread with the projector; the training on a
//! thread of its own; the closed-loop pairs on the engine thread with the projector, and the
//! refit on them (seconds for a linear rung, there too; a network's training, for
//! a residual rung or `auto`'s climb judged on the pairs, on a thread of its own again); the
//! verification on the engine thread with the projector, and the install if it verified. The
//! engine meanwhile feeds the watchdog and answers requests.
//! When a model is already serving and `autoplay` is on (a recalibration, after drift say), the
//! projector plays the old model while the new one trains (unless playback was paused), so the
//! picture is interrupted only for the captures, the closed-loop pairs and the verification.
//!
//! Each calibration captures into a run folder of its own under `[paths] data`
//! (`crate::calibrate::runs`), named in a marker until it ends, so a service killed at any point
//! resumes it from the captures on disk at its next start.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Instant, SystemTime};

use super::super::climb;
use super::super::protocol::{
    CalibrationOutcome, CalibrationProgress, ModelStatus, Monitoring, Reply, Request, State,
};
use super::super::{Event, Shared};
use super::{Background, Engine, Mode, rig_name};
use crate::calibrate::runs::Runs;
use crate::calibrate::{self, Options};
use crate::config::Config;
use crate::error::{Error, Result};
use crate::model::Model;
use crate::service::views::Tapped;

use super::super::devices::{Devices, Hardware, SetDevices};

/// What a calibration's training thread does.
enum Job {
    /// The requested rung on the captures ([`calibrate::train`]).
    Fit,
    /// The fit on every pair once the closed-loop pairs are taken ([`calibrate::refit`]).
    Refit(Box<calibrate::LoopPairs>),
}

/// Which calibration the engine runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    /// The configured one, resuming an interrupted run's captures when one is on disk.
    Resume,
    /// The configured one in a new run, never resuming (after drift the surface is not what
    /// an interrupted run captured).
    Fresh,
    /// The `linear` rung from `[monitoring] refit_ntrain` sampling images, in a new run (drift's
    /// `on_drift = "refit"`, or a `refit` request).
    Refit,
}

/// A calibration under way, from its first step to its end (installed, failed or dropped):
/// what the engine keeps about it between its steps.
#[derive(Clone, Copy, Debug)]
pub(super) struct Calibrating {
    /// When it began: the status's seconds count from here.
    pub(super) started: Instant,
    /// It refits the `linear` rung from `[monitoring] refit_ntrain` sampling images (drift's
    /// `on_drift = "refit"`, or the interrupted run it resumes was a refit).
    pub(super) refit: bool,
    /// The projector was paused when it began: it stays dark after it.
    pub(super) stay_paused: bool,
}

impl Calibrating {
    /// Progressive calibration's check of a climbed model: no calibration of its own, but
    /// the same steps on the devices.
    fn climb_check() -> Self {
        Calibrating {
            started: Instant::now(),
            refit: false,
            stay_paused: false,
        }
    }
}

/// Which [`Job`] a [`Training`] runs: what follows it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    Fit,
    Refit,
}

/// What the closed-loop pairs' step on the devices ends with.
enum AfterLoops {
    /// The model verified (refitted on the devices' thread: seconds).
    Verified(Box<calibrate::Calibrated>),
    /// A refit to run beside playback.
    Refit(Box<(calibrate::Captured, calibrate::LoopPairs)>),
}

/// A model training on its own thread while the old one plays; dropped, it cancels the training
/// (a CompenNet++ rung stops at its next iteration, `linear` at its end).
pub(super) struct Training {
    /// The run's data root.
    data: PathBuf,
    stage: Stage,
    /// The calibration it is a step of.
    calibrating: Calibrating,
    cancel: Arc<AtomicBool>,
    /// Set once the result is sent: the playback beside it ends.
    pub(super) done: Arc<AtomicBool>,
    result: mpsc::Receiver<(calibrate::Captured, Result<Model>)>,
}

impl Training {
    /// `None` while it trains; then the captures and the trained model (or why not), or
    /// `Some(None)` when its thread is gone without an answer.
    pub(super) fn poll(&self) -> Option<Option<(calibrate::Captured, Result<Model>)>> {
        match self.result.try_recv() {
            Ok(done) => Some(Some(done)),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(None),
        }
    }
}

/// Sets its flag when dropped.
struct SetOnDrop(Arc<AtomicBool>);

impl Drop for SetOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

impl Drop for Training {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Why `[calibration] device` cannot train what the configuration trains on it (a network:
/// `method`, or `climb`), in words; `None` when it can, or when nothing trains there. The
/// playback needs no CUDA, so the service starts anyway and says so at once, rather than at
/// its first training.
pub(super) fn device_problem(c: &crate::config::CalibrationConfig) -> Option<String> {
    let trains = c.method.may_train_a_network() || c.climb.is_some_and(|m| !m.is_linear());
    if !trains || c.device == crate::fit::TrainDevice::Cpu {
        return None;
    }
    c.device.candle().err().map(|e| {
        format!(
            "[calibration] device = \"{}\": {e}; every training of a CompenNet++ rung there \
             (method = \"{}\", climb = \"{}\") will fail until it is mended",
            c.device,
            c.method,
            c.climb.map_or("none", |m| m.name())
        )
    })
}

impl Engine {
    /// The options ([`crate::rigs::calibration_options`]) of calibration `cal` on this
    /// engine's projector.
    pub(super) fn calibration_options(&self, cal: Calibrating, cancel: Arc<AtomicBool>) -> Options {
        crate::rigs::calibration_options(
            &self.config.rig,
            &self.config.calibration,
            cal.refit.then_some(self.config.monitoring.refit_ntrain),
            self.devices.display_size(),
            self.devices.live_pass(self.config.calibration.refresh_hz),
            Some(cancel),
        )
    }

    /// A calibration's run begins: the cancel flag reset, what ran beside the last calibration
    /// dropped, a run folder begun under `[paths] data` (an interrupted run resumed for
    /// [`Kind::Resume`]; `refit` recorded in a new one). Its folder, its [`Calibrating`] and its
    /// cancel flag; `None` when it could not begin, counted and reported as a calibration that
    /// failed, and the next mode set.
    pub(super) fn begin_run(
        &mut self,
        kind: Kind,
        refit: bool,
    ) -> Option<(PathBuf, Calibrating, Arc<AtomicBool>)> {
        let stay_paused = self.io.shared.status().state == State::Paused;
        let cancel = self.io.shared.cancel.clone();
        cancel.store(false, Ordering::Relaxed);
        // A climb or a training from the previous calibration is moot (and must not install
        // over this one).
        self.background = Background::None;
        let runs = Runs::new(&self.config.paths.data);
        if kind != Kind::Resume {
            runs.end();
        }
        let started = Instant::now();
        match runs.begin_with(&rig_name(&self.config.rig), SystemTime::now(), refit) {
            Ok(run) => Some((
                run.data,
                Calibrating {
                    started,
                    refit: run.refit,
                    stay_paused,
                },
                cancel,
            )),
            Err(e) => {
                // It ends before its first capture (the data folder unwritable, a full disk):
                // counted and reported as any calibration that failed, so that a client
                // waiting for it (`recalibrate --wait`) and `status` see the failure.
                self.io.fail("calibration failed", &e);
                self.calibration_ended(false, format!("failed before its first capture: {e}"));
                self.mode = self.after_calibration(stay_paused);
                None
            }
        }
    }

    /// A calibration: captures, then training (beside playback of the current model when there
    /// is one to play), then verification and install ([`Engine::finish_calibration`]).
    pub(super) fn calibrate(&mut self, kind: Kind) {
        if matches!(self.devices, Devices::Set(_)) {
            return self.calibrate_set(kind);
        }
        let Some((data, cal, cancel)) = self.begin_run(kind, kind == Kind::Refit) else {
            return;
        };
        let what = if cal.refit {
            "refitting"
        } else {
            "calibrating"
        };
        self.io.state(State::Calibrating, what);
        tracing::info!("{what} into {}", data.display());
        let opts = self.calibration_options(cal, cancel);
        let captured = self.with_devices(
            cal,
            ("captures", Work::Calibration),
            |display, camera, progress| calibrate::capture(display, camera, &data, &opts, progress),
        );
        let captured = match captured {
            Ok(c) => c,
            Err(e) => return self.calibration_failed(cal, &data, e),
        };
        if self.mode == Mode::Stop {
            return;
        }
        self.train_beside_playback(cal, data, captured, &opts, Job::Fit);
    }

    /// Training runs on a thread of its own, so the engine goes on feeding the watchdog and
    /// answering requests. The current model plays meanwhile unless playback is paused or off;
    /// the playback (or the wait) ends when training does, and the next step on the devices
    /// follows ([`Engine::trained`]).
    fn train_beside_playback(
        &mut self,
        cal: Calibrating,
        data: PathBuf,
        captured: calibrate::Captured,
        opts: &Options,
        job: Job,
    ) {
        let what = match job {
            Job::Fit => opts.method.to_string(),
            Job::Refit(_) => format!("{} on the closed-loop pairs", opts.method),
        };
        let training = self.start_training(cal, data, captured, opts, job);
        self.background = Background::Training(training);
        if self.model.is_some() && self.config.playback.autoplay && !cal.stay_paused {
            tracing::info!("training {what} beside playback of the current model");
            self.mode = Mode::Play;
        } else {
            tracing::info!("training {what}");
            self.io.state(State::Training, "training");
            self.mode = Mode::Wait;
        }
    }

    /// Starts `job` on its own thread.
    fn start_training(
        &mut self,
        calibrating: Calibrating,
        data: PathBuf,
        mut captured: calibrate::Captured,
        opts: &Options,
        job: Job,
    ) -> Training {
        let stage = match job {
            Job::Fit => Stage::Fit,
            Job::Refit(_) => Stage::Refit,
        };
        let cancel = Arc::new(AtomicBool::new(false));
        let mut opts = opts.clone();
        opts.cancel = Some(cancel.clone());
        let (tx, result) = mpsc::channel();
        let done = Arc::new(AtomicBool::new(false));
        let finished = done.clone();
        let shared = self.io.shared.clone();
        let started = calibrating.started;
        let spawned = std::thread::Builder::new()
            .name("compend-train".into())
            .spawn(move || {
                // Set however the thread ends (a panic included): the playback beside it ends
                // and the engine finds the answer, or its absence.
                let _done = SetOnDrop(finished);
                let mut progress = training_progress(shared, started);
                // Behind the show: the playback beside it keeps its pace on a busy machine.
                let model = crate::background::run(|| match job {
                    Job::Fit => calibrate::train(&mut captured, &opts, &mut progress),
                    Job::Refit(taken) => {
                        calibrate::refit(&mut captured, *taken, &opts, &mut progress)
                    }
                });
                let _ = tx.send((captured, model));
            });
        if let Err(e) = spawned {
            // The receiver sees a closed channel: `lost()`, reported by the engine.
            tracing::error!("cannot start the training thread: {e}");
            done.store(true, Ordering::Relaxed);
        }
        Training {
            data,
            stage,
            calibrating,
            cancel,
            done,
            result,
        }
    }

    /// A training that ended beside playback (or in the engine's wait): the closed-loop pairs,
    /// verification and install; after a refit on the closed-loop pairs, verification and
    /// install.
    pub(super) fn trained(&mut self, captured: calibrate::Captured, model: Result<Model>) {
        let Some(t) = self.background.take_training() else {
            return;
        };
        let (cal, data) = (t.calibrating, t.data.clone());
        match t.stage {
            Stage::Fit => self.finish_calibration(cal, data, captured, model),
            Stage::Refit => self.verify_refitted(cal, data, captured, model),
        }
    }

    /// A training whose thread ended without an answer.
    pub(super) fn training_lost(&mut self) {
        if let Some(t) = self.background.take_training() {
            let e = Error::Failed("the training thread ended without an answer".into());
            self.calibration_failed(t.calibrating, &t.data, e);
        }
    }

    /// Takes the closed-loop pairs with a trained model on the projector; refits it on them,
    /// verifies it and installs it if it passed. A refit that trains a network (minutes on a
    /// CPU: a residual rung, `auto`'s climb judged on the pairs) runs on a thread of its own
    /// instead, beside playback as the first training did ([`Engine::verify_refitted`] next).
    fn finish_calibration(
        &mut self,
        cal: Calibrating,
        data: PathBuf,
        captured: calibrate::Captured,
        model: Result<Model>,
    ) {
        let model = match model {
            Ok(m) => m,
            Err(e) => return self.calibration_failed(cal, &data, e),
        };
        let setup = captured.setup().to_path_buf();
        let opts = self.calibration_options(cal, self.io.shared.cancel.clone());
        let mut captured = Some(captured);
        let mut model = Some(model);
        let step = self.with_devices(
            cal,
            ("verification", Work::Calibration),
            |display, camera, progress| match (captured.take(), model.take()) {
                (Some(mut c), Some(m)) => {
                    let taken =
                        calibrate::take_loop_pairs(display, camera, &mut c, m, &opts, progress)?;
                    if taken.trains_a_network(&opts) {
                        return Ok(AfterLoops::Refit(Box::new((c, taken))));
                    }
                    let m = calibrate::refit(&mut c, taken, &opts, progress)?;
                    calibrate::verify_model(display, camera, c, m, &opts, progress)
                        .map(|d| AfterLoops::Verified(Box::new(d)))
                }
                _ => Err(Error::Failed("the verification ran twice".into())),
            },
        );
        match step {
            Ok(AfterLoops::Verified(done)) => self.install_verified(cal, data, setup, *done),
            Ok(AfterLoops::Refit(b)) => {
                if self.mode != Mode::Stop {
                    let (c, taken) = *b;
                    self.train_beside_playback(cal, data, c, &opts, Job::Refit(Box::new(taken)));
                }
            }
            Err(e) => self.calibration_failed(cal, &data, e),
        }
    }

    /// Verifies a model refitted on the closed-loop pairs on the projector and installs it if
    /// it passed.
    fn verify_refitted(
        &mut self,
        cal: Calibrating,
        data: PathBuf,
        captured: calibrate::Captured,
        model: Result<Model>,
    ) {
        let model = match model {
            Ok(m) => m,
            Err(e) => return self.calibration_failed(cal, &data, e),
        };
        let setup = captured.setup().to_path_buf();
        let opts = self.calibration_options(cal, self.io.shared.cancel.clone());
        let mut both = Some((captured, model));
        let verified = self.with_devices(
            cal,
            ("verification", Work::Calibration),
            |display, camera, progress| match both.take() {
                Some((c, m)) => calibrate::verify_model(display, camera, c, m, &opts, progress),
                None => Err(Error::Failed("the verification ran twice".into())),
            },
        );
        match verified {
            Ok(done) => self.install_verified(cal, data, setup, done),
            Err(e) => self.calibration_failed(cal, &data, e),
        }
    }

    /// Installs a verified calibration's model if it passed, and ends the run.
    fn install_verified(
        &mut self,
        cal: Calibrating,
        data: PathBuf,
        setup: PathBuf,
        done: calibrate::Calibrated,
    ) {
        let v = done.record.verification.clone();
        tracing::info!(
            "calibration: {} captures taken, {} found on disk; verification {:.2} dB / SSIM {:.3} \
             against {:.2} dB uncompensated ({:+.2} dB); {:.1} s",
            done.record.captured,
            done.record.resumed,
            v.psnr,
            v.ssim,
            v.uncompensated_psnr,
            v.gain_db,
            done.record.seconds.total
        );
        let out = self.config.paths.model.clone();
        let installed = self.installer.install(done, &out);
        match installed {
            Ok(model) => {
                tracing::info!("installed {} into {}", model.meta.method, out.display());
                let c = &self.config.calibration;
                self.background =
                    climb::Plan::after_install(c, model.meta.method, &data, setup, &out)
                        .map_or(Background::None, Background::ClimbPlanned);
                let message = format!(
                    "installed {} into {} (verified {:.2} dB, {:+.2} dB over uncompensated)",
                    model.meta.method,
                    out.display(),
                    v.psnr,
                    v.gain_db
                );
                let why = format!(
                    "{} installed it (verified {:.2} dB, {:+.2} dB over uncompensated)",
                    if cal.refit {
                        "a refit"
                    } else {
                        "a calibration"
                    },
                    v.psnr,
                    v.gain_db
                );
                self.io.shared.views.set_fov(&model.fov);
                self.io.shared.update(|s| {
                    s.model = Some(ModelStatus::of(&out, &model, why));
                    s.monitoring = Monitoring::fresh(&s.monitoring);
                    s.last_error = None;
                    s.calibration = None;
                    s.calibrations += 1;
                    s.last_calibration = Some(CalibrationOutcome {
                        installed: true,
                        message,
                    });
                });
                self.model = Some(model);
                self.model_path = out;
                self.baseline = None;
            }
            Err(e) => {
                self.io.fail("the new model was not installed", &e);
                self.calibration_ended(false, format!("the new model was not installed: {e}"));
            }
        }
        let runs = Runs::new(&self.config.paths.data);
        runs.end();
        runs.prune(self.config.calibration.keep_runs);
        if self.mode != Mode::Stop {
            self.mode = self.after_calibration(cal.stay_paused);
        }
    }

    /// Progressive calibration's check on the rig: a climbed model that beat the installed one
    /// on the held-out pairs, and the installed one, projected on the calibration's
    /// verification images; the climbed one is installed and served from now on only if the rig
    /// confirms the margin ([`climb::settle`]). Playback resumes either way, unless a stop or a
    /// calibration was asked for during the check.
    pub(super) fn confirm_climb(&mut self, c: climb::Candidate) {
        self.check_climb(c);
        // Playback resumes, unless a stop or a calibration was asked for meanwhile.
        if self.mode == Mode::Wait {
            self.mode = Mode::Play;
        }
    }

    /// [`Engine::confirm_climb`]'s check and install.
    fn check_climb(&mut self, c: climb::Candidate) {
        let method = c.plan.method;
        let latency = match c.installed.meta.calibration.as_ref() {
            Some(cal) => cal.latency.clone(),
            None => {
                tracing::warn!(
                    "progressive calibration: {method} is not installed: the installed model has \
                     no calibration record to check it with"
                );
                return;
            }
        };
        let cancel = self.io.shared.cancel.clone();
        cancel.store(false, Ordering::Relaxed);
        let check = Calibrating::climb_check();
        let opts = self.calibration_options(check, cancel);
        self.io
            .state(State::Verifying, "verifying the climbed model");
        let (root, setup) = (c.plan.root.clone(), c.plan.setup.clone());
        let verified = self.with_devices(
            check,
            ("the climb's check", Work::ClimbCheck),
            |display, camera, progress| {
                calibrate::verify_after(
                    display,
                    camera,
                    (&root, &setup),
                    &[&c.model, &c.installed],
                    &latency,
                    &opts,
                    progress,
                )
            },
        );
        self.io.shared.update(|s| s.calibration = None);
        let path = c.plan.model.clone();
        let seconds = c.seconds;
        let settled = verified.and_then(|v| climb::settle(&mut self.installer, c, &v));
        match settled {
            Ok(Ok(model)) => {
                let figures = model
                    .meta
                    .calibration
                    .as_ref()
                    .and_then(|c| c.climb.as_ref())
                    .and_then(|r| r.closed_loop.as_ref().map(|cl| (r, cl)));
                let msg = match figures {
                    Some((r, cl)) => format!(
                        "installed {method} into {}: {:.2} dB against {:.2} dB for {} in closed \
                         loop on {} images ({:+.2} dB; held-out test pairs {:+.2} dB); {seconds:.0} s \
                         of training",
                        path.display(),
                        cl.psnr,
                        cl.replaced_psnr,
                        r.replaced,
                        cl.images,
                        cl.psnr - cl.replaced_psnr,
                        r.psnr - r.replaced_psnr
                    ),
                    None => format!("installed {method} into {}", path.display()),
                };
                tracing::info!("progressive calibration: {msg}");
                let why = format!("progressive calibration climbed to it: {msg}");
                self.io.climbed(method, true, msg);
                self.io.shared.views.set_fov(&model.fov);
                self.io.shared.update(|s| {
                    s.model = Some(ModelStatus::of(&path, &model, why));
                    s.monitoring = Monitoring::fresh(&s.monitoring);
                });
                self.model = Some(model);
                self.model_path = path;
                self.baseline = None;
            }
            Ok(Err(r)) => {
                let msg = match &r.closed_loop {
                    Some(cl) => format!(
                        "kept {}: on the rig {method} scored {:.2} dB against {:.2} dB in closed \
                         loop ({:+.2} dB, {:+.2} needed{}); {:+.2} dB on {}",
                        r.replaced,
                        cl.psnr,
                        cl.replaced_psnr,
                        cl.psnr - cl.replaced_psnr,
                        r.required_gain_db,
                        if cl.passed {
                            ""
                        } else {
                            "; it would not pass verification"
                        },
                        r.psnr - r.replaced_psnr,
                        r.judged_on()
                    ),
                    None => format!("kept {}: the rig did not confirm {method}", r.replaced),
                };
                tracing::info!("progressive calibration: {msg}");
                self.io.climbed(method, false, msg);
            }
            Err(Error::Cancelled(_)) => {
                tracing::info!("progressive calibration: the check of {method} was stopped");
            }
            Err(e) => {
                self.io
                    .climbed(method, false, format!("checking {method} failed: {e}"));
                self.io
                    .fail(&format!("progressive calibration: checking {method}"), &e);
            }
        }
    }

    /// A calibration that stopped: cancelled (its captures stay for the next run), refused (the
    /// run ends) or failed (the marker stays, so the next calibration resumes it).
    pub(super) fn calibration_failed(
        &mut self,
        cal: Calibrating,
        data: &std::path::Path,
        e: Error,
    ) {
        let message = match &e {
            Error::Cancelled(_) => format!("cancelled; its captures stay in {}", data.display()),
            e => format!("failed: {e}"),
        };
        self.calibration_ended(false, message);
        match e {
            Error::Cancelled(_) => tracing::info!(
                "calibration cancelled; its captures stay in {} for the next run",
                data.display()
            ),
            e => {
                self.io.fail("calibration failed", &e);
                // A refused setup is not retried at every start; a failed operation (a camera
                // gone, a full disk) is resumed by the next calibration.
                if e.exit_code() != 1 {
                    Runs::new(&self.config.paths.data).end();
                }
            }
        }
        if self.mode != Mode::Stop {
            self.mode = self.after_calibration(cal.stay_paused);
        }
    }

    /// A calibration has ended, installed or not: counted with its outcome in one update, so
    /// that a client never sees the count without it.
    pub(super) fn calibration_ended(&mut self, installed: bool, message: String) {
        self.io.shared.update(|s| {
            s.calibration = None;
            s.calibrations += 1;
            s.last_calibration = Some(CalibrationOutcome { installed, message });
        });
    }

    /// After a calibration: play if there is a model and the configuration says so, unless the
    /// projector was paused before (`stay_paused`) or during the calibration.
    pub(super) fn after_calibration(&mut self, stay_paused: bool) -> Mode {
        let paused = stay_paused || self.io.shared.status().state == State::Paused;
        if paused && self.serves() {
            Mode::Pause
        } else if self.serves() && self.config.playback.autoplay {
            Mode::Play
        } else {
            let line = if self.serves() {
                "idle"
            } else {
                "idle: no model installed"
            };
            self.io.state(State::Idle, line);
            self.io.notify.ready(line);
            Mode::Wait
        }
    }

    /// Runs `step` on the devices (the projector and the camera) with a progress callback that
    /// keeps the status, systemd and the event channel served between two captures.
    fn with_devices<T>(
        &mut self,
        cal: Calibrating,
        (what, work): (&str, Work),
        step: impl FnOnce(
            &mut dyn crate::device::DisplaySink,
            &mut dyn crate::device::FrameSource,
            calibrate::Progress,
        ) -> Result<T>,
    ) -> Result<T> {
        // The console sees what the camera captures.
        let shared = self.io.shared.clone();
        let mut progress = DeviceProgress::new(
            (&mut self.io, &mut self.mode, &mut self.reload),
            cal.started,
            work,
        );
        let mut progress =
            |phase: &str, done: usize, total: usize| progress.report(phase, done, total);
        tracing::debug!("calibration: {what}");
        match &mut self.devices {
            Devices::Virtual(v) => {
                // The scene's delay and drops (playback sets a camera that watches every frame).
                v.rig.set_latency(v.scene.latency.clone())?;
                let (mut display, mut camera) = (v.rig.clone(), v.rig.clone());
                let mut seen = Tapped::new(&mut camera, &shared.views);
                step(&mut display, &mut seen, &mut progress)
            }
            Devices::Hardware(h) => {
                let Hardware { win, camera, .. } = &mut **h;
                let mut seen = Tapped::new(&mut **camera, &shared.views);
                step(win, &mut seen, &mut progress)
            }
            Devices::Set(_) => Err(Error::Failed(format!(
                "{what}: a set of projectors is calibrated as a whole (Engine::calibrate_set)"
            ))),
        }
    }

    /// Runs `step` on a set's devices (each projector's output, in the set's order, and the
    /// camera) with [`Engine::with_devices`]' progress callback.
    pub(super) fn with_set_devices<T>(
        &mut self,
        cal: Calibrating,
        step: impl FnOnce(
            Vec<Box<dyn crate::device::DisplaySink>>,
            &mut dyn crate::device::FrameSource,
            calibrate::Progress,
        ) -> Result<T>,
    ) -> Result<T> {
        let shared = self.io.shared.clone();
        let mut progress = DeviceProgress::new(
            (&mut self.io, &mut self.mode, &mut self.reload),
            cal.started,
            Work::Calibration,
        );
        let mut progress =
            |phase: &str, done: usize, total: usize| progress.report(phase, done, total);
        let Devices::Set(set) = &mut self.devices else {
            return Err(Error::Failed(
                "one projector is calibrated step by step (Engine::calibrate)".into(),
            ));
        };
        if let SetDevices::Virtual { rig, scene, .. } = &mut **set {
            // The scene's delay and drops (playback sets a camera that watches every frame).
            rig.set_latency(scene.latency.clone())?;
        }
        let displays = set.displays()?;
        let mut seen = Tapped::new(set.camera(), &shared.views);
        step(displays, &mut seen, &mut progress)
    }
}

/// The progress callback of a calibration on the devices: the status, systemd's watchdog and
/// status line, the log, and the events that come meanwhile ([`busy`]).
struct DeviceProgress<'a> {
    io: &'a mut super::super::Io,
    mode: &'a mut Mode,
    reload: &'a mut Option<Box<Config>>,
    started: Instant,
    work: Work,
    lines: Option<calibrate::progress::ProgressLines>,
}

impl<'a> DeviceProgress<'a> {
    fn new(
        (io, mode, reload): (
            &'a mut super::super::Io,
            &'a mut Mode,
            &'a mut Option<Box<Config>>,
        ),
        started: Instant,
        work: Work,
    ) -> Self {
        Self {
            io,
            mode,
            reload,
            started,
            work,
            lines: None,
        }
    }

    fn report(&mut self, phase: &str, done: usize, total: usize) {
        log_progress(&mut self.lines, phase, done, total);
        // A set's phases are each projector's (`projector 1/2: captures`) and the whole set's.
        let step = phase.rsplit(": ").next().unwrap_or(phase);
        let state = match step {
            "verification" | "set verification" => State::Verifying,
            "exposure" | "latency" | "captures" | "closed-loop pairs" => State::Calibrating,
            _ => State::Training,
        };
        let started = self.started;
        self.io.shared.update(|s| {
            s.state = state;
            s.calibration = Some(CalibrationProgress {
                phase: phase.to_string(),
                done,
                total,
                seconds: started.elapsed().as_secs_f64(),
            });
        });
        self.io
            .notify
            .status(&format!("{}: {phase} {done}/{total}", state.name()));
        self.io.notify.ping();
        while let Ok(ev) = self.io.rx.try_recv() {
            busy(
                ev,
                (phase, self.work),
                self.mode,
                self.reload,
                &self.io.shared.cancel,
            );
        }
    }
}

/// The progress of a training, for the status (beside playback the state stays `playing` and
/// paused stays `paused`; the calibration's phase says what trains).
fn training_progress(
    shared: Arc<Shared>,
    started: Instant,
) -> impl FnMut(&str, usize, usize) + Send {
    let mut lines = None;
    move |phase: &str, done: usize, total: usize| {
        log_progress(&mut lines, phase, done, total);
        shared.update(|s| {
            if !matches!(s.state, State::Playing | State::Paused | State::Setup) {
                s.state = State::Training;
            }
            s.calibration = Some(CalibrationProgress {
                phase: phase.to_string(),
                done,
                total,
                seconds: started.elapsed().as_secs_f64(),
            });
        });
    }
}

/// A calibration's progress in the log (the journal): a line when a phase starts and ends,
/// and one at least every [`calibrate::progress::LINE_PERIOD`] while it reports.
fn log_progress(
    lines: &mut Option<calibrate::progress::ProgressLines>,
    phase: &str,
    done: usize,
    total: usize,
) {
    let line = match lines {
        Some(p) => p.update(phase, done, total),
        None => {
            let p = calibrate::progress::ProgressLines::new(phase, done, total);
            let line = p.line();
            *lines = Some(p);
            Some(line)
        }
    };
    if let Some(line) = line {
        tracing::info!("calibration: {line}");
    }
}

/// What the devices are busy with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Work {
    /// A calibration (captures or its verification).
    Calibration,
    /// Progressive calibration's check of a climbed model on the rig (playback paused).
    ClimbCheck,
}

/// An event that came while calibrating: `stop` and signals stop it (the cancel flag is
/// already set), a reload waits for its end, the rest is answered "busy". During a climb's
/// check a calibration request stops the check and is what runs next.
/// `cancel` is set again for a stop: a stop queued before the calibration began finds the flag
/// reset by it.
fn busy(
    ev: Event,
    (phase, work): (&str, Work),
    mode: &mut Mode,
    reload: &mut Option<Box<Config>>,
    cancel: &AtomicBool,
) {
    match ev {
        Event::Terminate(signal) => {
            tracing::info!("{signal}: stopping the calibration at its next capture");
            cancel.store(true, Ordering::Relaxed);
            *mode = Mode::Stop;
        }
        Event::Reload(c) => *reload = Some(c),
        Event::Request(env) => {
            let reply = match env.request {
                Request::Stop => {
                    cancel.store(true, Ordering::Relaxed);
                    *mode = Mode::Stop;
                    Reply::ok("stopping the calibration at its next capture")
                }
                Request::Status => Reply::error("status is answered by the socket"),
                Request::Calibrate | Request::Recalibrate | Request::Refit
                    if work == Work::ClimbCheck =>
                {
                    if *mode != Mode::Stop {
                        cancel.store(true, Ordering::Relaxed);
                        *mode = Mode::Calibrate(if env.request == Request::Refit {
                            Kind::Refit
                        } else {
                            Kind::Resume
                        });
                    }
                    Reply::ok("stopping the climb's check; calibrating next")
                }
                Request::Calibrate | Request::Recalibrate | Request::Refit => {
                    Reply::ok(format!("already calibrating ({phase})"))
                }
                _ => Reply::error(format!(
                    "busy calibrating ({phase}); ask again when compend status says playing or \
                     idle"
                )),
            };
            env.answer(reply);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::TrainDevice;
    use crate::model::Method;

    #[test]
    fn a_training_device_that_cannot_open_is_said_at_once() {
        let mut c = Config::defaults().calibration;
        // The CPU always trains; a linear method on a GPU trains nothing there.
        assert_eq!(device_problem(&c), None);
        // No machine has a 4097th GPU, and this build (CI's) may have no CUDA at all.
        c.device = TrainDevice::Cuda(4096);
        assert_eq!(device_problem(&c), None);
        c.climb = Some(Method::CompenNetPpResFull);
        let w = device_problem(&c).expect("a device that cannot open");
        assert!(
            w.contains("[calibration] device = \"cuda:4096\"")
                && w.contains("climb = \"compennet++-res-full\"")
                && w.contains("will fail until it is mended"),
            "{w}"
        );
        if !cfg!(feature = "cuda") {
            assert!(w.contains("built without CUDA"), "{w}");
        }
    }
}
