//! The engine: the service's main thread. It owns the devices, the GPU pass and the model, and
//! moves between the states of [`State`]; see [`super`] for the threads around it.
//!
//! What it does next is one of: wait for an event, calibrate, play, pause, stop. Events
//! (requests, signals, a reload) are looked at between two refreshes while playing, between two
//! captures while calibrating, and every half second while idle; a request that changes what
//! the engine does ends the current playback (calibration answers "busy" except to `stop`).
//!
//! Each calibration captures into a run folder of its own under `[paths] data`
//! ([`crate::calibrate::runs`]), so a recalibration (after drift, say) never reuses the
//! captures of a surface that has changed; the newest `[calibration] keep_runs` are kept.
//!
//! Crash safety: a run in progress is named by a marker file (`DATA/calibrating.json`) until it
//! ends; a service that starts and finds it resumes that run from the captures on disk, after
//! putting the installed model back on the projector. Models are
//! installed with an atomic swap ([`crate::model::store`]), so a kill at any moment leaves the
//! previous verified model or the new one, complete.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use super::climb;
mod calibration;
mod set;
mod setup;

use super::devices::{Devices, Hardware, VirtualDevices, load_model, match_exposure, other_rig};
use super::monitor::{self, SetWatch, Tap};
use super::notify::Notifier;
use super::opening::{Allowed, Opened, Opening};
use super::protocol::{Frames, ModelStatus, Monitoring, Reply, Request, State};
use super::screen::{ServiceScreen, set_frames};
use super::{Event, Io, Shared, clipped};
use crate::calibrate::runs::Runs;
use crate::config::{Config, DriftPolicy};
use crate::device::{DisplaySink, FrameSource};
use crate::error::Result;
use crate::fov::DisplayRange;
use crate::model::Model;
use crate::output::{MediaOutput, OutputSpec, Teed};
use crate::player::{PlayStats, Player, ViewSink, WatchedSink};
use crate::raster::ImageSize;
use crate::rig::VirtualRig;
use crate::rig::scene::Latency;
pub use crate::rigs::rig_name;
use crate::source::{self, FeedMode, Playlist};

/// What the engine does: the step its loop runs next. Each step sets the one after it (a
/// request or an event met during a step may set it too); what runs beside the steps is the
/// engine's [`Background`], and what a calibration keeps between its steps travels with it
/// ([`calibration::Calibrating`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// Idle or paused: wait for an event.
    Wait,
    /// A calibration of this kind.
    Calibrate(calibration::Kind),
    Play,
    /// Black on the projector, then wait.
    Pause,
    /// The setup view with this pattern.
    Setup(crate::patterns::SetupPattern),
    Stop,
}

/// What runs beside the engine's own work, one at a time: a calibration's model training
/// (beside playback of the model it will replace), then the progressive climb its install
/// planned, then that climb under way (it trains beside playback, which checks it between
/// refreshes). A calibration, or a model the operator chose, drops whichever it is.
enum Background {
    None,
    Training(calibration::Training),
    ClimbPlanned(climb::Plan),
    Climbing(climb::Climb),
}

impl Background {
    fn training(&self) -> Option<&calibration::Training> {
        match self {
            Background::Training(t) => Some(t),
            _ => None,
        }
    }

    /// The training, leaving nothing in its place; anything else stays.
    fn take_training(&mut self) -> Option<calibration::Training> {
        match std::mem::replace(self, Background::None) {
            Background::Training(t) => Some(t),
            other => {
                *self = other;
                None
            }
        }
    }

    /// The planned climb, leaving nothing in its place; anything else stays.
    fn take_plan(&mut self) -> Option<climb::Plan> {
        match std::mem::replace(self, Background::None) {
            Background::ClimbPlanned(p) => Some(p),
            other => {
                *self = other;
                None
            }
        }
    }

    /// The climb under way, leaving nothing in its place; anything else stays.
    fn take_climbing(&mut self) -> Option<climb::Climb> {
        match std::mem::replace(self, Background::None) {
            Background::Climbing(c) => Some(c),
            other => {
                *self = other;
                None
            }
        }
    }
}

pub struct Engine {
    config: Config,
    devices: Devices,
    io: Io,
    /// One projector's model being served.
    model: Option<Model>,
    /// A set of projectors' model being served (the devices are a set; `model` is then
    /// `None`).
    set_model: Option<crate::model::set::SetModel>,
    /// Where the model being served came from.
    model_path: PathBuf,
    /// What `play` plays: the configured source or playlist, or the source a request named.
    source: Playlist,
    /// A `play` request's source, opened already for the next playback; used only while it
    /// is still `source`.
    opened: Option<(Playlist, Opened)>,
    mode: Mode,
    /// The first monitoring score of the current model and the source it was measured on: what
    /// drift is measured against, dB.
    baseline: Option<(Playlist, f64)>,
    /// A configuration that came while calibrating, applied after it.
    reload: Option<Box<Config>>,
    /// What runs beside the engine's own work: a calibration's training, or a climb.
    background: Background,
    /// The one right to replace the model directory.
    installer: climb::Installer,
}

impl Engine {
    /// Opens the devices, loads the installed model and decides what to do first.
    pub fn start(config: Config, shared: Arc<Shared>, rx: Receiver<Event>) -> Result<Self> {
        let devices = Devices::open(&config)?;
        let mut engine = Engine {
            model_path: config.paths.model.clone(),
            source: config.playback.source.clone(),
            opened: None,
            config,
            devices,
            io: Io {
                shared,
                rx,
                notify: Notifier::new(),
                loader: Default::default(),
            },
            model: None,
            set_model: None,
            mode: Mode::Wait,
            baseline: None,
            reload: None,
            background: Background::None,
            installer: climb::Installer::new(),
        };
        let path = engine.model_path.clone();
        let installed = path.join(crate::model::store::META_FILE).is_file()
            || crate::model::set::SetModel::is_set(&path);
        if installed
            && let Err(e) =
                engine.use_any_model(&path, "the installed model when the service started")
        {
            engine.io.fail("the installed model was not loaded", &e);
        }
        if let Some(w) = calibration::device_problem(&engine.config.calibration) {
            tracing::warn!("{w}");
        }
        let runs = Runs::new(&engine.config.paths.data);
        tracing::info!(
            "compend {} serving {}; model: {}; source: {}",
            env!("CARGO_PKG_VERSION"),
            engine.devices.describe(),
            engine
                .served()
                .map_or("none installed".to_string(), |m| format!(
                    "{m} from {}",
                    path.display()
                )),
            engine.source.describe()
        );
        engine.mode = match (engine.served(), runs.interrupted()) {
            (_, Some(run)) => {
                tracing::info!(
                    "an interrupted calibration is on disk ({}); resuming it",
                    run.display()
                );
                Mode::Calibrate(calibration::Kind::Resume)
            }
            (None, None)
                if engine.config.calibration.on_start == crate::config::OnStart::IfNoModel =>
            {
                Mode::Calibrate(calibration::Kind::Resume)
            }
            (Some(_), None) if engine.config.playback.autoplay => Mode::Play,
            _ => Mode::Wait,
        };
        if engine.mode == Mode::Wait {
            let line = match engine.served() {
                None => "idle: no model installed; run compend recalibrate".to_string(),
                Some(m) => format!("idle with model {m}; run compend play"),
            };
            engine.io.notify.ready(&line);
        }
        Ok(engine)
    }

    /// Runs until stopped.
    pub fn run(mut self) -> Result<()> {
        loop {
            match std::mem::replace(&mut self.mode, Mode::Wait) {
                Mode::Stop => break,
                Mode::Wait => self.wait(),
                Mode::Calibrate(kind) => self.calibrate(kind),
                Mode::Play => self.play(),
                Mode::Setup(p) => self.setup(p),
                Mode::Pause => {
                    if let Err(e) = self.devices.black() {
                        self.io.fail("pausing", &e);
                    }
                    self.io.state(State::Paused, "paused");
                }
            }
            if let Some(c) = self.reload.take()
                && !matches!(self.mode, Mode::Stop)
            {
                self.apply(*c);
            }
        }
        self.io.shared.update(|s| s.state = State::Stopping);
        self.io.notify.stopping();
        if let Err(e) = self.devices.black() {
            tracing::warn!("stopping: could not show black: {e}");
        }
        tracing::info!("stopped");
        Ok(())
    }

    /// Idle or paused: waits for an event.
    fn wait(&mut self) {
        self.io.notify.ping();
        match self.io.rx.recv_timeout(Duration::from_millis(500)) {
            Ok(ev) => self.handle(ev),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => self.mode = Mode::Stop,
        }
        if self.mode == Mode::Wait {
            self.training_ended();
        }
    }

    /// Drops a calibration's training (the operator chose another model): its run ends, so it
    /// is not resumed at the next start either.
    fn abandon_training(&mut self, why: &str) {
        if self.background.take_training().is_some() {
            crate::calibrate::runs::Runs::new(&self.config.paths.data).end();
            self.io.shared.update(|s| s.calibration = None);
            tracing::info!("calibration abandoned: {why}");
        }
    }

    /// A training beside playback that has ended goes on to its verification.
    fn training_ended(&mut self) -> bool {
        let Some(t) = self.background.training() else {
            return false;
        };
        match t.poll() {
            None => false,
            Some(Some((captured, model))) => {
                self.trained(captured, model);
                true
            }
            Some(None) => {
                self.training_lost();
                true
            }
        }
    }

    fn handle(&mut self, ev: Event) {
        match ev {
            Event::Terminate(signal) => {
                tracing::info!("{signal}: stopping");
                self.mode = Mode::Stop;
            }
            Event::Reload(c) => {
                self.io.notify.reloading();
                self.apply(*c);
                self.io.notify.reloaded();
                // Playback picks up the new settings when it starts again.
                if self.io.shared.status().state == State::Playing {
                    self.mode = Mode::Play;
                }
            }
            Event::Request(mut env) => {
                let opened = env.opened.take();
                let reply = self.request(&env.request, opened);
                env.answer(reply);
            }
        }
    }

    /// Applies a reloaded configuration: what can change while running does; the rest (the
    /// devices, the paths, the socket) needs a restart, and the log says so.
    fn apply(&mut self, c: Config) {
        for (what, same) in [
            ("[rig]", c.rig == self.config.rig),
            ("[paths]", c.paths == self.config.paths),
            ("[socket]", c.socket == self.config.socket),
            ("[http]", c.http == self.config.http),
            ("[osc]", c.osc == self.config.osc),
        ] {
            if !same {
                tracing::warn!("reload: {what} changed; it takes effect when the service restarts");
            }
        }
        if c.playback.source != self.config.playback.source {
            self.source = c.playback.source.clone();
        }
        if c.calibration != self.config.calibration
            && let Some(w) = calibration::device_problem(&c.calibration)
        {
            tracing::warn!("reload: {w}");
        }
        self.config.calibration = c.calibration;
        self.config.playback = c.playback;
        self.config.audio = c.audio;
        self.config.output = c.output;
        self.config.monitoring = c.monitoring;
        self.config.log = c.log;
        tracing::info!("reload: configuration applied");
    }

    /// The reply to `r`; `opened`: a `play` request's source, opened and shown to play while
    /// the playback before went on ([`super::opening`]).
    fn request(&mut self, r: &Request, opened: Option<Opened>) -> Reply {
        match r {
            Request::Status => Reply::status(self.io.shared.status()),
            Request::Calibrate | Request::Recalibrate => {
                self.mode = Mode::Calibrate(calibration::Kind::Resume);
                Reply::ok(format!(
                    "calibrating into {}; compend status shows the progress",
                    self.config.paths.data.display()
                ))
            }
            Request::Refit if matches!(self.devices, Devices::Set(_)) => {
                self.mode = Mode::Calibrate(calibration::Kind::Refit);
                Reply::ok(format!(
                    "a set of projectors is refitted by calibrating it again: calibrating into \
                     a new run in {}; compend status shows the progress",
                    self.config.paths.data.display()
                ))
            }
            Request::Refit => {
                self.mode = Mode::Calibrate(calibration::Kind::Refit);
                Reply::ok(format!(
                    "refitting the linear rung from {} sampling images into a new run in {}; \
                     compend status shows the progress",
                    self.config.monitoring.refit_ntrain,
                    self.config.paths.data.display()
                ))
            }
            Request::Play { source } => {
                if !self.serves() {
                    return Reply::error(
                        "no model to play with: calibrate first (compend recalibrate)",
                    );
                }
                // A source that cannot be played changes nothing: the one in place stays.
                if let Some(s) = source {
                    if let Err(e) = super::protocol::check_requested_source(s) {
                        return Reply::error(e);
                    }
                    // Opened here unless the playback before did (while it went on): on a
                    // thread, the watchdog kept alive, within its time limit.
                    let opened = match opened {
                        Some(o) => Ok(o),
                        None => {
                            let notify = &mut self.io.notify;
                            Opening::start(
                                s.clone(),
                                self.config.audio.out(),
                                Allowed::of(&self.config),
                            )
                            .and_then(|o| o.wait(|| notify.ping()))
                        }
                    };
                    let list = Playlist::single(s.clone());
                    match opened {
                        Ok(o) => self.opened = Some((list.clone(), o)),
                        Err(e) => return Reply::error(e.to_string()),
                    }
                    self.source = list;
                }
                self.mode = Mode::Play;
                Reply::ok(format!("playing {}", self.source.describe()))
            }
            Request::Pause => {
                self.mode = Mode::Pause;
                Reply::ok("paused")
            }
            Request::Seek { .. } | Request::Next | Request::Previous => Reply::error(
                "nothing is playing: seek, next and previous act on a film or playlist while it \
                 plays (compend play starts it)",
            ),
            Request::Model { path } => match Allowed::of(&self.config).model(path).and_then(|()| {
                self.use_any_model(
                    path,
                    "swapped in by a model request (the event log says who sent it)",
                )
            }) {
                Ok(()) => {
                    let warning = self
                        .model
                        .as_ref()
                        .and_then(|m| {
                            other_rig(m, &rig_name(&self.config.rig), self.config.rig.seed)
                        })
                        .map_or(String::new(), |w| {
                            tracing::warn!("{}: {w}", clipped(&path.display().to_string()));
                            format!("; {w}")
                        });
                    // Paused stays paused: the projector stays dark until the operator plays.
                    if self.io.shared.status().state == State::Paused {
                        Reply::ok(format!(
                            "paused; {} is the model now, and compend play shows {} with \
                             it{warning}",
                            path.display(),
                            self.source.describe()
                        ))
                    } else {
                        self.mode = Mode::Play;
                        Reply::ok(format!(
                            "playing {} with {}{warning}",
                            self.source.describe(),
                            path.display()
                        ))
                    }
                }
                Err(e) => Reply::error(e.to_string()),
            },
            Request::Setup { pattern } => {
                let p = match pattern
                    .as_deref()
                    .unwrap_or("grid")
                    .parse::<crate::patterns::SetupPattern>()
                {
                    Ok(p) => p,
                    Err(e) => return Reply::error(e.to_string()),
                };
                self.mode = Mode::Setup(p);
                Reply::ok(format!(
                    "setup: the {p} pattern up, the camera watched; play, pause or calibrate \
                     leaves it"
                ))
            }
            Request::Stop => {
                self.mode = Mode::Stop;
                Reply::ok("stopping")
            }
        }
    }

    /// What is served, in words (`linear`, `linear (a set of 2, joint)`); `None`: nothing.
    fn served(&self) -> Option<String> {
        match (&self.model, &self.set_model) {
            (Some(m), _) => Some(m.meta.method.to_string()),
            (None, Some(s)) => Some(format!(
                "{} (a set of {}, joint)",
                crate::model::Method::Linear,
                s.models.len()
            )),
            (None, None) => None,
        }
    }

    /// Whether a model is served.
    fn serves(&self) -> bool {
        self.model.is_some() || self.set_model.is_some()
    }

    /// Loads the model directory `path` and serves it from now on: a set's model on a set of
    /// projectors, one projector's otherwise.
    fn use_any_model(&mut self, path: &Path, why: &str) -> Result<()> {
        if matches!(self.devices, Devices::Set(_)) {
            self.use_set_model(path, why)
        } else {
            self.use_model(path, why)
        }
    }

    /// Loads the model directory `path` and serves it from now on (`why`: for the status); a
    /// model for another camera size is refused.
    fn use_model(&mut self, path: &Path, why: &str) -> Result<()> {
        let model = load_model(path, self.devices.camera_size())?;
        // A climb from the model it replaces, or a calibration training beside playback, would
        // install over the operator's choice.
        self.abandon_training("another model was chosen");
        self.background = Background::None;
        if let Devices::Virtual(v) = &mut self.devices {
            match_exposure(&mut v.rig, &model)?;
        }
        self.io.shared.views.set_fov(&model.fov);
        self.io.shared.update(|s| {
            s.model = Some(ModelStatus::of(path, &model, why.into()));
            s.monitoring = Monitoring::fresh(&s.monitoring);
        });
        self.model = Some(model);
        self.model_path = path.to_path_buf();
        self.baseline = None;
        Ok(())
    }

    /// Plays the source through the model until an event asks for something else or the
    /// source ends.
    fn play(&mut self) {
        if matches!(self.devices, Devices::Set(_)) {
            return self.play_set();
        }
        if self.model.is_none() {
            self.mode = Mode::Wait;
            return;
        }
        let Some(source) = self.open_source() else {
            return;
        };
        let Some(model) = &self.model else {
            return;
        };
        let line = format!(
            "playing {} with {}{}",
            clipped(&self.source.describe()),
            model.meta.method,
            model
                .meta
                .calibration
                .as_ref()
                .map_or(String::new(), |c| format!(
                    " (verified {:.1} dB)",
                    c.verification.psnr
                ))
        );
        if let Some(plan) = self.background.take_plan() {
            // A rung the display cannot keep up with is not trained: its pass is timed first,
            // alone on the GPU, before this playback starts.
            let method = plan.method;
            let probe = self.devices.live_pass(self.config.calibration.refresh_hz);
            let affordable = match plan.live_cost(probe.as_deref(), self.devices.display_size()) {
                Ok(None) => true,
                Ok(Some(cost)) if cost.fits() => {
                    tracing::info!("progressive calibration: {}", cost.describe());
                    true
                }
                Ok(Some(cost)) => {
                    let msg = format!("{}: {method} is not climbed to", cost.describe());
                    tracing::warn!("progressive calibration: {msg}");
                    self.io.climbed(method, false, msg);
                    false
                }
                Err(e) => {
                    let msg = format!(
                        "{method}'s live pass could not be timed on the playback GPU ({e}): it \
                         is not climbed to"
                    );
                    tracing::warn!("progressive calibration: {msg}");
                    self.io.climbed(method, false, msg);
                    false
                }
            };
            if affordable {
                match climb::Climb::start(plan) {
                    Ok(c) => self.background = Background::Climbing(c),
                    Err(e) => self.io.fail("progressive calibration", &e),
                }
            }
        }
        let before = begin_playback(&mut self.io, &self.source, &line);
        let range = model.display_range();
        let m = &self.config.monitoring;
        // A camera on its own clock needs the latency measured at calibration on this rig.
        let settle = match &self.devices {
            Devices::Virtual(_) | Devices::Set(_) => None,
            Devices::Hardware(_) => settle_frames(model, &rig_name(&self.config.rig)),
        };
        let watchable = matches!(self.devices, Devices::Virtual(_)) || settle.is_some();
        let monitor = self.monitor_tap(watchable, None);
        let period = Duration::from_secs_f64(m.period_s);
        let stats_every = Duration::from_secs_f64(self.config.log.stats_period_s);
        let fps = self.config.rig.fps;
        let drift_after = self.config.rig.drift_after_s;
        // A calibration's model training beside this playback ends it when it is trained.
        let end_when = self.background.training().map(|t| t.done.clone());
        // A climb under way goes along with the playback, which checks it between refreshes.
        let mut climb = self.background.take_climbing();
        let output = self.config.output.to.clone();
        let audio = self.config.audio.out();
        let result = match &mut self.devices {
            Devices::Virtual(v) => {
                let bump = v.bump.as_mut().and_then(|b| b.arm(drift_after));
                play_virtual(
                    v,
                    model,
                    (range, source, fps),
                    (&mut self.io, &mut climb),
                    (monitor.clone(), (period, stats_every)),
                    Around {
                        before: &before,
                        end_when,
                        bump,
                        output: output.clone(),
                        projector_outputs: Vec::new(),
                        audio: audio.clone(),
                        allowed: Allowed::of(&self.config),
                        rig: rig_name(&self.config.rig),
                        seed: self.config.rig.seed,
                    },
                )
            }
            Devices::Hardware(h) => {
                let bump = h.bump.as_mut().and_then(|b| b.arm(drift_after));
                play_hardware(
                    h,
                    model,
                    (range, source),
                    (&mut self.io, &mut climb),
                    (monitor.clone(), settle, (period, stats_every)),
                    Around {
                        before: &before,
                        end_when,
                        bump,
                        output: output.clone(),
                        projector_outputs: Vec::new(),
                        audio: audio.clone(),
                        allowed: Allowed::of(&self.config),
                        rig: rig_name(&self.config.rig),
                        seed: self.config.rig.seed,
                    },
                )
            }
            Devices::Set(_) => Err(crate::error::Error::Failed(
                "a set of projectors plays its joint model (Engine::play_set)".into(),
            )),
        };
        if let Some(c) = climb {
            self.background = Background::Climbing(c);
        }
        // A model swapped in while playing is the one served from now on (also when the
        // playback then failed).
        let swapped = match &result {
            Ok(ended) => ended.swapped.is_some(),
            Err(_) => false,
        };
        let result = result.map(|mut ended| {
            if let Some((path, model)) = ended.swapped.take() {
                self.model = Some(model);
                self.model_path = path;
            }
            ended
        });
        if swapped {
            self.abandon_training("another model was swapped in");
        }
        if swapped {
            self.baseline = None;
        }
        if let Some(tap) = &monitor {
            self.baseline = tap.baseline().map(|b| (self.source.clone(), b));
        }
        match result {
            Ok(Ended {
                stats: Ok(stats),
                pending,
                candidate,
                ..
            }) => {
                self.io
                    .shared
                    .update(|s| set_frames(&mut s.frames, &stats, &before));
                match (pending, candidate) {
                    (None, Some(c))
                        if !swapped && !monitor.as_ref().is_some_and(|t| t.ends_playback()) =>
                    {
                        self.confirm_climb(*c)
                    }
                    (None, Some(c)) => {
                        // The climb was measured against a model no longer served, or on a
                        // rig that has since moved.
                        tracing::info!(
                            "progressive calibration: {} is not checked: {}",
                            c.plan.method,
                            if swapped {
                                "another model was swapped in"
                            } else {
                                "the rig drifted"
                            }
                        );
                        if monitor.as_ref().is_some_and(|t| t.ends_playback()) {
                            self.on_drift();
                        } else if self.mode == Mode::Wait {
                            self.mode = Mode::Play;
                        }
                    }
                    (Some(ev), candidate) => {
                        if let Some(c) = candidate {
                            tracing::info!(
                                "progressive calibration: {} is not checked: a request ended \
                                 the playback first",
                                c.plan.method
                            );
                        }
                        self.handle(ev);
                        // A request that was refused changed nothing: play on.
                        if self.mode == Mode::Wait {
                            self.mode = Mode::Play;
                        }
                    }
                    (None, None) if monitor.as_ref().is_some_and(|t| t.ends_playback()) => {
                        self.on_drift();
                    }
                    (None, None) if self.training_ended() => {}
                    (None, None) => {
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

    /// The source `play` plays, opened (by a `play` request while the playback before went
    /// on, or here); `None`, reported and idle, when it cannot be.
    fn open_source(&mut self) -> Option<Box<dyn source::VideoSource>> {
        let opened = match self.opened.take() {
            Some((list, o)) if list == self.source => Ok(o),
            _ => self.source.open(&self.config.audio.out()),
        };
        match opened {
            Ok(s) => Some(s),
            Err(e) => {
                self.io.fail(
                    &format!("cannot play {}", clipped(&self.source.describe())),
                    &e,
                );
                self.io.state(State::Idle, "idle: the source failed");
                None
            }
        }
    }

    /// Monitoring for the playback about to start (`[monitoring]`), when it is on and the rig
    /// can be watched (`watchable`: the virtual rig, or a camera whose latency was measured on
    /// this rig); otherwise `None`, said in the log. `set`: what it watches of a set.
    fn monitor_tap(&self, watchable: bool, set: Option<SetWatch>) -> Option<Arc<Tap>> {
        let m = &self.config.monitoring;
        if m.enabled && !watchable {
            tracing::warn!(
                "monitoring is off for this playback: the model was not calibrated on this rig \
                 ({}), so the projector-to-camera latency is unknown; `compend recalibrate` \
                 measures it",
                rig_name(&self.config.rig)
            );
        }
        (m.enabled && watchable).then(|| {
            // A calibration already under way (training beside this playback) is not started
            // again: drift is reported only.
            let recalibrate =
                m.on_drift != DriftPolicy::Report && self.background.training().is_none();
            Tap::new(
                self.baseline_for_source(),
                m.drift_threshold_db,
                recalibrate,
                set,
            )
        })
    }

    /// The current model's first monitoring score, if it was measured on the source about to
    /// play: scores depend on the content, so another source starts a new baseline.
    fn baseline_for_source(&self) -> Option<f64> {
        self.baseline
            .as_ref()
            .filter(|(source, _)| *source == self.source)
            .map(|(_, b)| *b)
    }

    /// Drift ended the playback (`on_drift = "recalibrate"` or `"refit"`; with "report" it
    /// plays on).
    fn on_drift(&mut self) {
        let m = &self.config.monitoring;
        if m.on_drift == DriftPolicy::Refit {
            tracing::warn!(
                "drift: refitting the linear rung from {} sampling images",
                m.refit_ntrain
            );
        } else {
            tracing::warn!("drift: recalibrating");
        }
        self.mode = Mode::Calibrate(match m.on_drift {
            DriftPolicy::Refit => calibration::Kind::Refit,
            _ => calibration::Kind::Fresh,
        });
    }
}

/// A playback of `source` begins: its counts start from zero, the state says `line`. Returns
/// the totals of the playbacks before it.
fn begin_playback(io: &mut Io, source: &Playlist, line: &str) -> Frames {
    let src = source.describe();
    let before = io.shared.status().frames;
    io.shared.update(|s| {
        s.source = Some(src);
        s.media = None;
        s.frames.refreshes = 0;
        s.frames.shown = 0;
        s.frames.held = 0;
        s.frames.dropped_source = 0;
        s.frames.dropped_pipeline = 0;
    });
    io.state(State::Playing, line);
    tracing::info!("{line}");
    before
}

/// Plays on the virtual rig: its projector shows the pass's output, its camera (set to one
/// exposure per shown frame, no delay) watches on a thread of its own and feeds monitoring.
/// `(range, source, fps)`: content mapped into `range`, from `source`, shown at `fps`;
/// `timing`: the monitoring and log periods. A climb under way goes on during the playback and
/// stays in `climb` if it has not ended.
fn play_virtual(
    v: &mut VirtualDevices,
    model: &Model,
    (range, source, fps): (DisplayRange, Box<dyn source::VideoSource>, f64),
    (io, climb): (&mut Io, &mut Option<climb::Climb>),
    (monitor, timing): (Option<Arc<Tap>>, (Duration, Duration)),
    mut around: Around<'_>,
) -> Result<Ended> {
    v.rig.set_latency(Latency {
        fps,
        delay_frames: 0,
        drop_rate: 0.0,
    })?;
    let mut player = Player::start(
        &v.ctx,
        model,
        v.scene.projector.size(),
        range,
        source,
        FeedMode::Latest,
    )?;
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
    let mut sink = WatchedSink::new(&v.ctx, fps, v.rig.clone(), v.rig.clone(), views);
    let sizes = (v.scene.camera.size(), v.scene.projector.size());
    let output = start_output(around.output.take(), sizes.1, fps, io);
    let mut teed = Teed::new(&mut sink, output);
    let mut screen = ServiceScreen::new(&mut teed, io, monitor, timing, sizes);
    around.dress(&mut screen);
    screen.rig = Some(v.rig.clone());
    screen.climb = climb.take();
    screen.media = player.feed.control().cloned();
    let stats = player.run(&mut screen, None);
    screen.settle();
    *climb = screen.climb.take();
    if let Some(b) = &mut v.bump {
        b.played(&screen.drift);
    }
    Ok(Ended {
        stats,
        pending: screen.pending.take(),
        swapped: screen.swapped.take(),
        candidate: screen.candidate.take(),
    })
}

/// Exposures to wait after a change of content before the camera shows it: the latency
/// measured when `model` was calibrated, if that was on the rig named `rig`.
fn settle_frames(model: &Model, rig: &str) -> Option<u64> {
    let c = model.meta.calibration.as_ref()?;
    (c.rig == rig).then_some(c.latency.settle_frames)
}

/// Plays on the projector window, watched by a camera on its own clock (a V4L2 camera, the
/// window rig's): the camera goes to a thread of its own that feeds monitoring with the views
/// it saw alone ([`monitor::watch_camera`]; `settle`: exposures of latency), while the window
/// stays on this thread. The camera is set to the exposure the model was calibrated at.
fn play_hardware(
    h: &mut Hardware,
    model: &Model,
    (range, source): (DisplayRange, Box<dyn source::VideoSource>),
    (io, climb): (&mut Io, &mut Option<climb::Climb>),
    (monitor, settle, timing): (Option<Arc<Tap>>, Option<u64>, (Duration, Duration)),
    mut around: Around<'_>,
) -> Result<Ended> {
    let Hardware {
        win,
        camera,
        bump: bumps,
        ..
    } = h;
    if settle.is_some()
        && let Err(e) = match_exposure(&mut **camera, model)
    {
        tracing::warn!("monitoring: {e}");
    }
    let sizes = (FrameSource::size(&**camera), DisplaySink::size(win));
    let mut player = Player::start(
        win.context(),
        model,
        sizes.1,
        range,
        source,
        FeedMode::Latest,
    )?;
    let (tx, rx) = mpsc::channel();
    let stop = AtomicBool::new(false);
    let shared = io.shared.clone();
    std::thread::scope(|scope| {
        let watcher = start_watcher(
            scope,
            &mut **camera,
            (&monitor, settle),
            rx,
            (&stop, &shared),
        );
        let hz = win.refresh_hz();
        let output = start_output(around.output.take(), sizes.1, hz, io);
        let mut teed = Teed::new(&mut *win, output);
        let mut screen = ServiceScreen::new(&mut teed, io, monitor.clone(), timing, sizes);
        around.dress(&mut screen);
        screen.climb = climb.take();
        if watcher.is_some() {
            screen.changes = Some(tx);
        }
        screen.media = player.feed.control().cloned();
        let stats = player.run(&mut screen, None);
        screen.settle();
        *climb = screen.climb.take();
        if let Some(b) = bumps {
            b.played(&screen.drift);
        }
        let ended = Ended {
            stats,
            pending: screen.pending.take(),
            swapped: screen.swapped.take(),
            candidate: screen.candidate.take(),
        };
        drop(screen);
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(w) = watcher
            && w.join().is_err()
        {
            tracing::error!("monitoring: its camera thread panicked");
        }
        Ok(ended)
    })
}

/// What a playback has around it: the frame totals of the playbacks before it, what ends it
/// once set (a calibration's training beside it), and the simulated projector's bump due
/// during it.
struct Around<'a> {
    before: &'a Frames,
    end_when: Option<Arc<AtomicBool>>,
    bump: Option<(VirtualRig, Instant)>,
    /// `[output] to`: the compensated frames to a file or a pipeline as well.
    output: Option<OutputSpec>,
    /// `[[projector]] to`: a set's projectors' frames each to its own output (one per
    /// projector, or none).
    projector_outputs: Vec<OutputSpec>,
    /// Where a source asked for while playing plays its sound.
    audio: source::AudioOut,
    /// The folders requests may name files in.
    allowed: Allowed,
    /// This service's rig ([`rig_name`]) and its seed: a model swapped in from another is
    /// named.
    rig: String,
    seed: u64,
}

impl Around<'_> {
    /// Sets what the playback has around it on its `screen` (the output goes separately, to
    /// [`start_output`]).
    fn dress<S: ?Sized, P>(self, screen: &mut ServiceScreen<'_, S, P>) {
        screen.before = self.before.clone();
        screen.end_when = self.end_when;
        screen.drift = self.bump;
        screen.audio = self.audio;
        screen.allowed = self.allowed;
        screen.rig_name = self.rig;
        screen.rig_seed = self.seed;
    }
}

/// Starts the thread of a camera on its own clock that feeds monitoring with the views it saw
/// alone ([`monitor::watch_camera`]; `settle`: exposures of latency), when monitoring is on
/// and the latency is known; `None` otherwise, or when the thread cannot start (said in the
/// log). `stop` ends it.
fn start_watcher<'scope, 'env, C: FrameSource + Send + ?Sized>(
    scope: &'scope std::thread::Scope<'scope, 'env>,
    camera: &'env mut C,
    (monitor, settle): (&'env Option<Arc<Tap>>, Option<u64>),
    changes: mpsc::Receiver<(u64, Instant)>,
    (stop, shared): (&'env AtomicBool, &'env Shared),
) -> Option<std::thread::ScopedJoinHandle<'scope, ()>> {
    let (Some(tap), Some(settle)) = (monitor, settle) else {
        return None;
    };
    let spawned = std::thread::Builder::new()
        .name("compend-monitor".into())
        .spawn_scoped(scope, move || {
            monitor::watch_camera(camera, changes, settle, (tap, shared), stop)
        });
    match spawned {
        Ok(w) => Some(w),
        Err(e) => {
            tracing::warn!("monitoring is off: cannot start its camera thread: {e}");
            None
        }
    }
}

/// Starts `[output] to` for a playback on a display of `size` at `fps`: a file goes to the
/// next free `NAME-NNNN.EXT`. An output that cannot start is logged and left out: the show
/// goes on without it.
fn start_output(
    spec: Option<OutputSpec>,
    size: ImageSize,
    fps: f64,
    io: &Io,
) -> Option<MediaOutput> {
    let spec = spec?.numbered();
    match MediaOutput::start(&spec, size, fps, true) {
        Ok(o) => {
            tracing::info!("output: compensated frames also to {spec}");
            Some(o)
        }
        Err(e) => {
            io.fail(
                "[output] to: the output could not start; playing without it",
                &e,
            );
            None
        }
    }
}

/// How a playback ended: its counts, the event that ended it (none: the source ended,
/// monitoring found drift or a climb ended), a model swapped in while it played, and a climbed
/// model waiting for the rig's check.
struct Ended {
    /// The counts, or how the playback failed (a model swapped in before still counts).
    stats: Result<PlayStats>,
    pending: Option<Event>,
    swapped: Option<(PathBuf, Model)>,
    /// A climbed model for the engine to check on the rig ([`climb::settle`]).
    candidate: Option<Box<climb::Candidate>>,
}
