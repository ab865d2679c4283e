//! A set of projectors in the service (docs/service.md, "A set of projectors"): the set's
//! model loaded and served, played through the joint pass on every projector's output in the
//! same refresh, and calibrated as a whole ([`crate::calibrate::set`]: each projector with the
//! others black, then the joint compensation verified over the set's displayable area, seam
//! figure included). Monitoring scores the camera's view of the whole set against the desired
//! view, as for one projector. A set climbs no rung (it is compensated jointly from `linear`
//! models), takes no model request for one projector, and is refitted by calibrating it again.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Duration;

use super::super::devices::{Bump, Devices, SetDevices, load_set_model};
use super::super::monitor::{SetWatch, Tap};
use super::super::protocol::{CalibrationOutcome, ModelStatus, Monitoring, ProjectorStatus, State};
use super::super::screen::{ServiceScreen, set_frames};
use super::super::{Io, clipped};
use super::calibration::{Calibrating, Kind};
use super::{
    Around, Background, Ended, Engine, Mode, begin_playback, rig_name, start_output, start_watcher,
};
use crate::calibrate::runs::Runs;
use crate::device::{FrameSource, SideBySide};
use crate::error::{Error, Result};
use crate::gpu::joint::SetPass;
use crate::model::set::SetModel;
use crate::model::{Method, MethodChoice};
use crate::output::{SetOutputs, SetTeed};
use crate::player::{Player, ViewSink, WatchedSink};
use crate::raster::{Camera, Mask};
use crate::rig::scene::Latency;
use crate::source::{self, Feed, FeedMode};

impl Engine {
    /// Loads the set's model directory `path` and serves it from now on (`why`: for the
    /// status); a model for another set or camera is refused, the one served stays.
    pub(super) fn use_set_model(&mut self, path: &Path, why: &str) -> Result<()> {
        let Devices::Set(set) = &self.devices else {
            return Err(Error::Failed(
                "a set's model is served on a set of projectors".into(),
            ));
        };
        let camera = match &**set {
            SetDevices::Virtual { scene, .. } => scene.camera.size(),
            SetDevices::Windows { camera, .. } => FrameSource::size(camera),
        };
        let model = load_set_model(path, set.len(), camera)?;
        self.serve_set(path, model, why)
    }

    /// Serves the set's `model`, from `path`, from now on (`why`: for the status).
    fn serve_set(&mut self, path: &Path, model: SetModel, why: &str) -> Result<()> {
        let Devices::Set(set) = &mut self.devices else {
            return Err(Error::Failed(
                "a set's model is served on a set of projectors".into(),
            ));
        };
        // The camera at the exposure the set was calibrated at: monitoring compares against it.
        if let Some(e) = model
            .meta
            .calibration
            .as_ref()
            .and_then(|c| c.exposure.as_ref())
            && let SetDevices::Virtual { rig, .. } = &mut **set
        {
            rig.set_exposure(e.chosen)?;
        }
        let outputs = projector_statuses(set, &model);
        self.background = Background::None;
        self.io.shared.views.set_fov(&union_fov(&model));
        self.io.shared.update(|s| {
            s.model = Some(ModelStatus::of_set(path, &model, why.into()));
            s.projectors = outputs;
            s.monitoring = Monitoring::fresh(&s.monitoring);
        });
        self.set_model = Some(model);
        self.model = None;
        self.model_path = path.to_path_buf();
        self.baseline = None;
        Ok(())
    }

    /// Plays the source through the set's joint model on every projector until an event asks
    /// for something else or the source ends.
    pub(super) fn play_set(&mut self) {
        if self.set_model.is_none() {
            self.mode = Mode::Wait;
            return;
        }
        let Some(source) = self.open_source() else {
            return;
        };
        let Some(model) = &self.set_model else {
            return;
        };
        let Some(record) = model.meta.calibration.as_ref() else {
            // A set's model is loaded only with its record (`load_set_model`).
            self.io.fail(
                "the set's model",
                &Error::Input(format!(
                    "{}: no calibration record in set.json",
                    self.model_path.display()
                )),
            );
            self.io.state(State::Idle, "idle: playback failed");
            return;
        };
        let v = &record.verification;
        let line = format!(
            "playing {} with the joint model of a set of {} projectors (verified {:.1} dB{})",
            clipped(&self.source.describe()),
            model.models.len(),
            v.psnr,
            v.seam
                .as_ref()
                .map_or(String::new(), |s| format!(", seam ratio {:.2}", s.ratio()))
        );
        let before = begin_playback(&mut self.io, &self.source, &line);
        let m = &self.config.monitoring;
        // A camera on its own clock needs the latency measured when the set was calibrated on
        // this rig: its slowest projector's.
        let rig = rig_name(&self.config.rig);
        let settle = match &self.devices {
            Devices::Set(s) if matches!(**s, SetDevices::Windows { .. }) => {
                set_settle_frames(model, &rig)
            }
            _ => None,
        };
        let watchable = matches!(&self.devices, Devices::Set(s) if matches!(**s, SetDevices::Virtual { .. }))
            || settle.is_some();
        let joint = match model.joint() {
            Ok(j) => j,
            Err(e) => {
                self.io.fail("the set's joint model", &e);
                self.io.state(State::Idle, "idle: playback failed");
                return;
            }
        };
        let covers: Vec<_> = (0..joint.projectors())
            .filter_map(|k| joint.cover(k).map(|c| c.mask()))
            .collect();
        let set = SetWatch::of(&covers, record.area, crate::calibrate::set::SEAM_LIMIT);
        let monitor = self.monitor_tap(watchable, Some(set));
        let timing = (
            Duration::from_secs_f64(m.period_s),
            Duration::from_secs_f64(self.config.log.stats_period_s),
        );
        let drift_after = self.config.rig.drift_after_s;
        let around = Around {
            before: &before,
            end_when: None,
            bump: None,
            output: self.config.output.to.clone(),
            projector_outputs: self
                .config
                .rig
                .projectors
                .iter()
                .filter_map(|p| p.to.clone())
                .collect(),
            audio: self.config.audio.out(),
            allowed: crate::service::opening::Allowed::of(&self.config),
            rig,
            seed: self.config.rig.seed,
        };
        let fps = self.config.rig.fps;
        let exposure = record.exposure.as_ref().map(|e| e.chosen);
        let result = (|| match &mut self.devices {
            Devices::Set(s) => match &mut **s {
                SetDevices::Virtual {
                    rig,
                    scene,
                    ctx,
                    bump,
                } => {
                    let pass = SetPass::new(
                        ctx,
                        &joint,
                        (record.display_range, record.area),
                        scene.projector.size(),
                    )?;
                    play_set_virtual(
                        (rig, scene, ctx, bump),
                        (pass, source, fps),
                        &mut self.io,
                        (monitor.clone(), timing),
                        (around, drift_after),
                    )
                }
                SetDevices::Windows {
                    windows, camera, ..
                } => {
                    let mut windows = windows.borrow_mut();
                    let canvas =
                        windows.sizes().first().copied().ok_or_else(|| {
                            Error::Failed("a set of windows without a window".into())
                        })?;
                    let pass = SetPass::new(
                        windows.context(),
                        &joint,
                        (record.display_range, record.area),
                        canvas,
                    )?;
                    if settle.is_some()
                        && let Some(e) = exposure
                        && let Err(e) = camera.set_exposure(e)
                    {
                        tracing::warn!("monitoring: {e}");
                    }
                    play_set_windows(
                        (&mut windows, &mut **camera),
                        (pass, source),
                        &mut self.io,
                        (monitor.clone(), settle, timing),
                        around,
                    )
                }
            },
            _ => Err(Error::Failed(
                "one projector plays its own model (Engine::play)".into(),
            )),
        })();
        if let Some(tap) = &monitor {
            self.baseline = tap.baseline().map(|b| (self.source.clone(), b));
        }
        match result {
            Ok(Ended {
                stats: Ok(stats),
                pending,
                ..
            }) => {
                self.io
                    .shared
                    .update(|s| set_frames(&mut s.frames, &stats, &before));
                match pending {
                    Some(ev) => {
                        self.handle(ev);
                        // A request that was refused changed nothing: play on.
                        if self.mode == Mode::Wait {
                            self.mode = Mode::Play;
                        }
                    }
                    None if monitor.as_ref().is_some_and(|t| t.ends_playback()) => self.on_drift(),
                    None => {
                        tracing::info!("{}: the source ended", clipped(&self.source.describe()));
                        self.io.state(State::Idle, "idle: the source ended");
                    }
                }
            }
            Ok(Ended { stats: Err(e), .. }) | Err(e) => {
                self.io
                    .fail(&format!("playing {}", clipped(&self.source.describe())), &e);
                self.io.state(State::Idle, "idle: playback failed");
            }
        }
    }

    /// Calibrates the set as a whole ([`crate::calibrate::set::calibrate_set`]) into a run
    /// folder of its own, resuming an interrupted run's captures for [`Kind::Resume`], and
    /// installs the set's model if it verified. The set's `linear` models are compensated
    /// jointly: another `[calibration] method` is said and `linear` calibrated.
    pub(super) fn calibrate_set(&mut self, kind: Kind) {
        if kind == Kind::Refit {
            tracing::info!("a set of projectors is refitted by calibrating it again");
        }
        // Each projector's whole calibration, never a refit's few sampling images.
        let Some((data, cal, cancel)) = self.begin_run(kind, false) else {
            return;
        };
        // An interrupted refit it resumes is a whole calibration too.
        let cal = Calibrating {
            refit: false,
            ..cal
        };
        let runs = Runs::new(&self.config.paths.data);
        self.io.state(State::Calibrating, "calibrating");
        tracing::info!("calibrating the set of projectors into {}", data.display());
        let mut opts = self.calibration_options(cal, cancel);
        if opts.method != MethodChoice::Rung(Method::Linear) {
            tracing::warn!(
                "[calibration] method = \"{}\": a set of projectors is calibrated with linear \
                 (each projector's model, then the joint compensation of their light)",
                opts.method
            );
            opts.method = MethodChoice::Rung(Method::Linear);
        }
        let calibrated = self.with_set_devices(cal, |displays, camera, progress| {
            crate::calibrate::set::calibrate_set(displays, camera, &data, &opts, progress)
        });
        let done = match calibrated {
            Ok(d) => d,
            Err(e) => return self.calibration_failed(cal, &data, e),
        };
        let v = done.record.verification.clone();
        tracing::info!(
            "set calibration: verification {:.2} dB / SSIM {:.3} jointly, {} alone; {:.1} s",
            v.psnr,
            v.ssim,
            v.alone_psnr
                .iter()
                .map(|p| format!("{p:.2} dB"))
                .collect::<Vec<_>>()
                .join(", "),
            done.record.total_seconds
        );
        let out = self.config.paths.model.clone();
        match self.installer.install_set(done, &out) {
            Ok(model) => {
                let seam = v
                    .seam
                    .as_ref()
                    .map_or(String::new(), |s| format!(", seam ratio {:.2}", s.ratio()));
                let message = format!(
                    "installed the set's joint model into {} (verified {:.2} dB, {:+.2} dB over \
                     its best projector alone{seam})",
                    out.display(),
                    v.psnr,
                    v.gain_db
                );
                tracing::info!("{message}");
                let why = format!(
                    "a calibration installed it (verified {:.2} dB, {:+.2} dB over its best \
                     projector alone{seam})",
                    v.psnr, v.gain_db
                );
                match self.serve_set(&out, model, &why) {
                    Ok(()) => self.io.shared.update(|s| {
                        s.last_error = None;
                        s.calibration = None;
                        s.calibrations += 1;
                        s.last_calibration = Some(CalibrationOutcome {
                            installed: true,
                            message,
                        });
                    }),
                    Err(e) => {
                        self.io.fail("the installed set's model is not served", &e);
                        self.calibration_ended(true, format!("{message}; not served: {e}"));
                    }
                }
            }
            Err(e) => {
                self.io.fail("the new model was not installed", &e);
                self.calibration_ended(false, format!("the new model was not installed: {e}"));
            }
        }
        runs.end();
        runs.prune(self.config.calibration.keep_runs);
        if self.mode != Mode::Stop {
            self.mode = self.after_calibration(cal.stay_paused);
        }
    }
}

/// Starts `[[projector]] to` (`specs`: one per projector, or none) for a playback of
/// projectors of `size` at `fps`: each file to its next free `NAME-NNNN.EXT`. Outputs that
/// cannot start are logged and left out: the show goes on without them.
fn start_set_outputs(
    specs: &[crate::output::OutputSpec],
    size: crate::raster::ImageSize,
    fps: f64,
    io: &Io,
) -> Option<SetOutputs> {
    let specs: Vec<_> = specs.iter().map(|s| s.numbered()).collect();
    match SetOutputs::start(&specs, specs.len(), size, fps, true) {
        Ok(Some(o)) => {
            let list: Vec<String> = specs.iter().map(|s| s.to_string()).collect();
            tracing::info!(
                "output: each projector's compensated frames also to {}",
                list.join(", ")
            );
            Some(o)
        }
        Ok(None) => None,
        Err(e) => {
            io.fail(
                "[[projector]] to: the outputs could not start; playing without them",
                &e,
            );
            None
        }
    }
}

/// Each projector of `set` in the status, with its own verification from `model`.
fn projector_statuses(set: &SetDevices, model: &SetModel) -> Vec<ProjectorStatus> {
    set.names()
        .into_iter()
        .zip(set.sizes())
        .zip(&model.models)
        .map(|((output, size), m)| ProjectorStatus {
            output,
            size: size.to_string(),
            verification: m.meta.calibration.as_ref().map(|c| c.verification.clone()),
        })
        .collect()
}

/// Where any projector of the set lights the camera's view (camera pixels).
fn union_fov(model: &SetModel) -> Mask<Camera> {
    let size = model.meta.camera_size;
    Mask::from_fn(size.width, size.height, |x, y| {
        model.models.iter().any(|m| m.fov.get(x, y))
    })
}

/// Exposures to wait after a change of content before the camera shows it: the slowest
/// projector's latency measured when the set was calibrated, if that was on the rig named
/// `rig`.
fn set_settle_frames(model: &SetModel, rig: &str) -> Option<u64> {
    let record = model.meta.calibration.as_ref()?;
    if record.rig != rig {
        return None;
    }
    model
        .models
        .iter()
        .map(|m| Some(m.meta.calibration.as_ref()?.latency.settle_frames))
        .collect::<Option<Vec<_>>>()?
        .into_iter()
        .max()
}

/// Plays a set on the virtual rig: each projector's image on its output (the outputs side by
/// side as one display), the rig's camera (one exposure per shown frame, no delay) watching on
/// a thread of its own and feeding monitoring and the console.
fn play_set_virtual(
    (rig, scene, ctx, bump): (
        &mut crate::rig::VirtualRig,
        &crate::rig::scene::Scene,
        &crate::gpu::GpuContext,
        &mut Option<Bump>,
    ),
    (pass, source, fps): (SetPass, Box<dyn source::VideoSource>, f64),
    io: &mut Io,
    (monitor, timing): (Option<Arc<Tap>>, (Duration, Duration)),
    (mut around, drift_after): (Around<'_>, Option<f64>),
) -> Result<Ended> {
    around.bump = bump.as_mut().and_then(|b| b.arm(drift_after));
    rig.set_latency(Latency {
        fps,
        delay_frames: 0,
        drop_rate: 0.0,
    })?;
    let outputs = (0..rig.outputs())
        .map(|k| rig.output(k))
        .collect::<Result<Vec<_>>>()?;
    let display = SideBySide::new(outputs)?;
    let whole = crate::device::DisplaySink::size(&display);
    let mut player = Player::new(pass, Feed::spawn(source, FeedMode::Latest)?);
    let views: ViewSink = {
        let tap = monitor.clone();
        let shared = io.shared.clone();
        Box::new(move |seq, _, view| {
            shared.views.offer_camera(view);
            if let Some(tap) = &tap {
                tap.offer(seq, view, &shared);
            }
            Ok(())
        })
    };
    let mut sink = WatchedSink::new(ctx, fps, display, rig.clone(), views);
    let output = start_output(around.output.take(), whole, fps, io);
    let mut teed = crate::output::Teed::new(&mut sink, output);
    let each = start_set_outputs(&around.projector_outputs, scene.projector.size(), fps, io);
    let mut teed = SetTeed::new(&mut teed, each);
    let sizes = (scene.camera.size(), scene.projector.size());
    let mut screen = ServiceScreen::new(&mut teed, io, monitor, timing, sizes);
    around.dress(&mut screen);
    screen.media = player.feed.control().cloned();
    let stats = player.run(&mut screen, None);
    screen.settle();
    if let Some(b) = bump {
        b.played(&screen.drift);
    }
    Ok(Ended {
        stats,
        pending: screen.pending.take(),
        swapped: None,
        candidate: None,
    })
}

/// Plays a set on its windows (every output in the same refresh), watched by a camera on its
/// own clock: the camera on a thread of its own that feeds monitoring with the views it saw
/// alone (`watch_camera`; `settle`: exposures of latency).
fn play_set_windows(
    (windows, camera): (
        &mut crate::window::ProjectorWindows,
        &mut (dyn FrameSource + Send),
    ),
    (pass, source): (SetPass, Box<dyn source::VideoSource>),
    io: &mut Io,
    (monitor, settle, timing): (Option<Arc<Tap>>, Option<u64>, (Duration, Duration)),
    mut around: Around<'_>,
) -> Result<Ended> {
    let sizes = windows.sizes();
    // The outputs' frames side by side ([`crate::device::side_by_side`]): what `[output] to`
    // gets.
    let whole = crate::raster::ImageSize::new(
        sizes.iter().map(|s| s.width).sum(),
        sizes.iter().map(|s| s.height).max().unwrap_or(0),
    );
    let display = sizes.first().copied().unwrap_or(whole);
    let camera_size = FrameSource::size(&*camera);
    let mut player = Player::new(pass, Feed::spawn(source, FeedMode::Latest)?);
    let (tx, rx) = mpsc::channel();
    let stop = AtomicBool::new(false);
    let shared = io.shared.clone();
    std::thread::scope(|scope| {
        let watcher = start_watcher(scope, camera, (&monitor, settle), rx, (&stop, &shared));
        let hz = windows.refresh_hz();
        let output = start_output(around.output.take(), whole, hz, io);
        let each = start_set_outputs(&around.projector_outputs, display, hz, io);
        let mut teed = crate::output::Teed::new(&mut *windows, output);
        let mut teed = SetTeed::new(&mut teed, each);
        let mut screen = ServiceScreen::new(
            &mut teed,
            io,
            monitor.clone(),
            timing,
            (camera_size, display),
        );
        around.dress(&mut screen);
        if watcher.is_some() {
            screen.changes = Some(tx);
        }
        screen.media = player.feed.control().cloned();
        let stats = player.run(&mut screen, None);
        screen.settle();
        let ended = Ended {
            stats,
            pending: screen.pending.take(),
            swapped: None,
            candidate: None,
        };
        drop(screen);
        stop.store(true, Ordering::Relaxed);
        if let Some(w) = watcher
            && w.join().is_err()
        {
            tracing::error!("monitoring: its camera thread panicked");
        }
        Ok(ended)
    })
}
