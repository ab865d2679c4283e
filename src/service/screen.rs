//! The service's screen: the playback loop's display wrapped with the engine's checks between
//! two refreshes: events, the watchdog, live counts, monitoring requests, the virtual rig's
//! drift, and models swapped in while playing.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, TryRecvError};
use std::time::{Duration, Instant};

use super::climb::{Candidate, Climb};
use super::devices::{load_model, match_exposure};
use super::monitor::Tap;
use super::opening::{Allowed, Opening};
use super::protocol::{Frames, ModelStatus, Monitoring, Reply, Request, State};
use super::{Envelope, Event, Io};
use crate::error::{Error, Result};
use crate::gpu::joint::SetPass;
use crate::gpu::{CompensationPass, FramePass, GpuContext};
use crate::model::Model;
use crate::player::{PlayStats, Refresh, Screen, Show};
use crate::raster::{CamImage, ImageSize, Rect};
use crate::rig::{Phase, VirtualRig};
use crate::source::AudioOut;

/// A job for the loading thread.
type Job = Box<dyn FnOnce() + Send>;

/// The thread that loads every model swapped in while playing, owned by the engine (its
/// [`Io`]) and started on first use (and again if it has gone); it ends when the engine drops
/// it. One thread for all swaps, not one per swap: with a thread per swap the service's memory
/// grew with the swaps, most likely as glibc's allocator gave the threads arenas of their own
/// and kept what was freed in them (docs/service.md, "Memory").
#[derive(Default)]
pub(super) struct Loader {
    jobs: Option<mpsc::Sender<Job>>,
}

impl Loader {
    /// Runs `job` on the loading thread. A job that panics ends without an answer (its sender
    /// dropped); the thread goes on.
    fn run(&mut self, job: Job) -> std::io::Result<()> {
        let job = match self.jobs.as_ref() {
            Some(jobs) => match jobs.send(job) {
                Ok(()) => return Ok(()),
                // The thread has gone: start another.
                Err(mpsc::SendError(job)) => job,
            },
            None => job,
        };
        let (jobs, next) = mpsc::channel::<Job>();
        std::thread::Builder::new()
            .name("compend-load".into())
            .spawn(move || {
                for job in next {
                    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job));
                }
            })?;
        jobs.send(job)
            .map_err(|_| std::io::Error::other("the loading thread ended before its first job"))?;
        self.jobs = Some(jobs);
        Ok(())
    }
}

/// A model being loaded, and its pass built, on the loading thread while playback goes on.
struct Loading {
    path: PathBuf,
    envelope: Envelope,
    started: Instant,
    result: mpsc::Receiver<Result<(Model, CompensationPass)>>,
}

impl Loading {
    /// Starts loading the model directory `path` for a rig with this camera and display: the
    /// model, checked against the camera, and its pass on (a clone of) `ctx`.
    fn start(
        loader: &mut Loader,
        path: PathBuf,
        envelope: Envelope,
        ctx: GpuContext,
        camera: ImageSize,
        display: ImageSize,
    ) -> Self {
        let (tx, result) = mpsc::channel();
        let from = path.clone();
        let spawned = loader.run(Box::new(move || {
            let built = load_model(&from, camera).and_then(|model| {
                let range = model.display_range();
                let pass = CompensationPass::for_display(&ctx, &model, display, range)?;
                Ok((model, pass))
            });
            let _ = tx.send(built);
        }));
        if let Err(e) = spawned {
            // The receiver then sees a closed channel, answered as a failed load.
            tracing::error!(
                "cannot start a thread to load {}: {e}",
                super::clipped(&path.display().to_string())
            );
        }
        Self {
            path,
            envelope,
            started: Instant::now(),
            result,
        }
    }
}

/// What the service's screen needs of the pass it plays beyond what the loop needs: the
/// desired view of the frame last run, for monitoring, and whether a `model` request may swap
/// another model in while it plays.
pub(super) trait ServedPass: FramePass + Sized {
    /// Whether a `model` request swaps one projector's model in while this pass plays.
    const SWAPS: bool;

    /// The desired camera view of the frame last run (camera pixels, encoded values) and the
    /// displayable area it fills.
    fn desired_view(&self, ctx: &GpuContext) -> Result<(CamImage, Rect)>;

    /// The pass of a model swapped in while playing (only asked for where [`Self::SWAPS`]).
    fn swapped(pass: CompensationPass) -> Option<Self>;
}

impl ServedPass for CompensationPass {
    const SWAPS: bool = true;

    fn desired_view(&self, ctx: &GpuContext) -> Result<(CamImage, Rect)> {
        Ok((self.read_desired(ctx)?, self.placement().area))
    }

    fn swapped(pass: CompensationPass) -> Option<Self> {
        Some(pass)
    }
}

/// A set of projectors' joint pass: its desired view is made on the CPU, and another set's
/// model is loaded by the engine between two playbacks.
impl ServedPass for SetPass {
    const SWAPS: bool = false;

    fn desired_view(&self, _ctx: &GpuContext) -> Result<(CamImage, Rect)> {
        self.desired()
            .map(|(d, area)| (d.clone(), area))
            .ok_or_else(|| Error::Failed("the set's pass has run no frame yet".into()))
    }

    fn swapped(_pass: CompensationPass) -> Option<Self> {
        None
    }
}

/// A display in the service: the playback loop's screen with the engine's checks between
/// refreshes (events, the watchdog, live counts, monitoring requests, the virtual rig's drift),
/// playing a pass `P` (one projector's, or a set's).
pub(super) struct ServiceScreen<'a, S: ?Sized, P = CompensationPass> {
    inner: &'a mut S,
    io: &'a mut Io,
    /// An event that ended the playback, for the engine.
    pub(super) pending: Option<Event>,
    monitor: Option<Arc<Tap>>,
    period: Duration,
    next_check: Instant,
    last_check: Option<Instant>,
    stats_every: Duration,
    last_stats: Instant,
    last_counts: Instant,
    /// The virtual rig and when its projector moves (`[rig] drift_after_s`).
    pub(super) drift: Option<(VirtualRig, Instant)>,
    /// The frame totals before this playback.
    pub(super) before: Frames,
    /// The virtual rig, whose camera exposure follows the model (a model swapped in).
    pub(super) rig: Option<VirtualRig>,
    /// The rig's camera and display sizes, for a model swapped in.
    camera: ImageSize,
    display: ImageSize,
    loading: Option<Loading>,
    /// Progressive calibration under way (it outlives a playback: the engine keeps it).
    pub(super) climb: Option<Climb>,
    /// A climbed model that beat the installed one on the held-out pairs: it ends the playback,
    /// for the engine to check both on the rig.
    pub(super) candidate: Option<Box<Candidate>>,
    /// Ends the playback once set (a calibration's training beside it has ended).
    pub(super) end_when: Option<Arc<AtomicBool>>,
    /// A model swapped in during this playback, and where it came from: the engine serves it
    /// from now on.
    pub(super) swapped: Option<(PathBuf, Model)>,
    /// For a camera watching on its own clock ([`super::monitor::watch_camera`]): each change
    /// of what the projector shows, as (first frame of the new content, when it was
    /// presented).
    pub(super) changes: Option<mpsc::Sender<(u64, Instant)>>,
    /// The frame a check waits for and its desired view: later frames with the same desired
    /// view are the same content, not a change.
    checked: Option<(u64, CamImage)>,
    /// The media source playing (a film, a stream, a playlist): pause, resume, seek, next and
    /// previous act on it without ending the playback.
    pub(super) media: Option<crate::media::Control>,
    /// A `play` request whose source is being opened on a thread of its own (a film is
    /// prerolled, a stream connected: seconds the picture must not wait for).
    checking: Option<(Envelope, Opening)>,
    /// Where a source asked for plays its sound.
    pub(super) audio: AudioOut,
    /// The folders requests may name files in.
    pub(super) allowed: Allowed,
    /// This service's rig (`rig_name`): a model swapped in from another is named.
    pub(super) rig_name: String,
    /// This service's `[rig] seed`: a simulated surface's texture.
    pub(super) rig_seed: u64,
    /// The pass it plays, a type only.
    pass: std::marker::PhantomData<fn(&P)>,
}

impl<'a, S: Screen<P> + ?Sized, P: ServedPass> ServiceScreen<'a, S, P> {
    pub(super) fn new(
        inner: &'a mut S,
        io: &'a mut Io,
        monitor: Option<Arc<Tap>>,
        (period, stats_every): (Duration, Duration),
        (camera, display): (ImageSize, ImageSize),
    ) -> Self {
        let now = Instant::now();
        Self {
            inner,
            io,
            pending: None,
            monitor,
            period,
            // The first check soon after the start: the baseline of a new model.
            next_check: now + Duration::from_millis(500).min(period),
            last_check: None,
            stats_every,
            last_stats: now,
            last_counts: now,
            drift: None,
            before: Frames::default(),
            rig: None,
            camera,
            display,
            loading: None,
            climb: None,
            candidate: None,
            end_when: None,
            swapped: None,
            changes: None,
            checked: None,
            media: None,
            checking: None,
            audio: AudioOut::default(),
            allowed: Allowed::default(),
            rig_name: String::new(),
            rig_seed: 0,
            pass: std::marker::PhantomData,
        }
    }

    /// Starts opening the source of a `play` request on a thread of its own; the answer comes
    /// from [`ServiceScreen::checked_source`].
    fn check_source(&mut self, envelope: Envelope, text: String) {
        if self.checking.is_some() {
            envelope.answer(Reply::error(
                "busy: still opening the source asked for before; ask again in a moment",
            ));
            return;
        }
        match Opening::start(text, self.audio.clone(), self.allowed.clone()) {
            Ok(o) => self.checking = Some((envelope, o)),
            Err(e) => envelope.answer(Reply::error(e.to_string())),
        }
    }

    /// A source being opened that is ready: one that plays ends this playback (the engine
    /// plays it); one that does not (or does not within its time) is refused and this
    /// playback goes on. Returns whether the playback goes on.
    fn checked_source(&mut self) -> bool {
        let Some(result) = self.checking.as_ref().and_then(|(_, o)| o.poll()) else {
            return true;
        };
        let (mut envelope, _) = self.checking.take().expect("looked at above");
        match result {
            Ok(opened) if self.pending.is_none() => {
                envelope.opened = Some(opened);
                self.pending = Some(Event::Request(envelope));
                false
            }
            Ok(_) => {
                envelope.answer(Reply::error(
                    "another request ended the playback first; ask again",
                ));
                true
            }
            Err(e) => {
                envelope.answer(Reply::error(e.to_string()));
                true
            }
        }
    }

    /// A pause, resume, seek, next or previous for the media playing, answered here so that
    /// the playback goes on; `None` when the request is not one of those (or, for pause and
    /// play, the source cannot do it: the engine then stops or restarts the playback).
    fn media_request(&mut self, request: &Request) -> Option<Reply> {
        let c = self.media.clone()?;
        let at = |c: &crate::media::Control| {
            c.status()
                .position_s
                .map_or(String::new(), |p| format!(" at {p:.1} s"))
        };
        match request {
            Request::Pause => {
                c.pause().ok()?;
                let line = format!("paused{}; compend play resumes", at(&c));
                self.io.state(State::Paused, &line);
                tracing::info!("{line}");
                Some(Reply::ok(line))
            }
            Request::Play { source: None } if c.status().paused => {
                c.resume().ok()?;
                let line = format!("playing on{}", at(&c));
                self.io.state(State::Playing, &line);
                tracing::info!("{line}");
                Some(Reply::ok(line))
            }
            Request::Seek { position_s } => {
                Some(match c.seek(Duration::from_secs_f64(*position_s)) {
                    Ok(()) => {
                        tracing::info!("seek to {position_s:.3} s");
                        Reply::ok(format!("at {position_s:.3} s"))
                    }
                    Err(e) => Reply::error(e.to_string()),
                })
            }
            Request::Next | Request::Previous => {
                let delta = if *request == Request::Next { 1 } else { -1 };
                Some(match c.skip(delta) {
                    Ok(()) => {
                        let what = if delta > 0 { "next" } else { "previous" };
                        tracing::info!("playlist: {what} item");
                        Reply::ok(format!("the {what} item"))
                    }
                    Err(e) => Reply::error(e.to_string()),
                })
            }
            _ => None,
        }
    }

    /// An event while playing: a `model` request starts loading it beside the playback (and
    /// playback goes on); anything else ends the playback and goes to the engine.
    fn event(&mut self, ev: Event) -> bool {
        let Event::Request(envelope) = ev else {
            self.pending = Some(ev);
            return false;
        };
        // A play request is checked on a thread of its own (a film prerolls, a stream
        // connects) while the picture goes on; a source that cannot be played (unparsed, a
        // damaged image, an empty folder, a missing file, not media) changes nothing.
        if let Request::Play { source: Some(text) } = &envelope.request {
            if let Err(e) = super::protocol::check_requested_source(text) {
                envelope.answer(Reply::error(e));
                return true;
            }
            let text = text.clone();
            self.check_source(envelope, text);
            return true;
        }
        if let Some(reply) = self.media_request(&envelope.request) {
            envelope.answer(reply);
            return true;
        }
        let Request::Model { path } = &envelope.request else {
            self.pending = Some(Event::Request(envelope));
            return false;
        };
        if !P::SWAPS {
            // A set's model is loaded by the engine, between two playbacks.
            self.pending = Some(Event::Request(envelope));
            return false;
        }
        if let Err(e) = self.allowed.model(path) {
            envelope.answer(Reply::error(e.to_string()));
            return true;
        }
        if let Some(l) = &self.loading {
            let busy = format!(
                "busy: still loading {}; ask again when it is swapped in",
                l.path.display()
            );
            envelope.answer(Reply::error(busy));
            return true;
        }
        tracing::info!(
            "loading {} to swap in while playing",
            super::clipped(&path.display().to_string())
        );
        let ctx = self.inner.context().clone();
        self.loading = Some(Loading::start(
            &mut self.io.loader,
            path.clone(),
            envelope,
            ctx,
            self.camera,
            self.display,
        ));
        true
    }

    /// The model being loaded, once it is ready: recorded, announced and answered; its pass for
    /// the player. A failed load is answered and playback goes on with the current model.
    fn loaded(&mut self, wait: bool) -> Option<CompensationPass> {
        let l = self.loading.as_ref()?;
        let got = if wait {
            l.result.recv().map_err(|_| TryRecvError::Disconnected)
        } else {
            l.result.try_recv()
        };
        let built = match got {
            Err(TryRecvError::Empty) => return None,
            Ok(built) => built,
            Err(TryRecvError::Disconnected) => Err(Error::Failed(
                "loading the model ended without an answer (it panicked, or its thread could not \
                 start; see the log)"
                    .into(),
            )),
        };
        let l = self.loading.take()?;
        let (model, pass) = match built.and_then(|(model, pass)| {
            if let Some(rig) = &mut self.rig {
                match_exposure(rig, &model)?;
            }
            Ok((model, pass))
        }) {
            Ok(done) => done,
            Err(e) => {
                tracing::warn!(
                    "{} was not swapped in: {}",
                    super::clipped(&l.path.display().to_string()),
                    super::clipped(&e.to_string())
                );
                l.envelope.answer(Reply::error(e.to_string()));
                return None;
            }
        };
        let seconds = l.started.elapsed().as_secs_f64();
        tracing::info!(
            "swapped in {} ({}) while playing, loaded in {seconds:.2} s",
            super::clipped(&l.path.display().to_string()),
            model.meta.method
        );
        self.io.shared.views.set_fov(&model.fov);
        self.io.shared.update(|s| {
            let why =
                "swapped in while playing by a model request (the event log says who sent it)";
            s.model = Some(ModelStatus::of(&l.path, &model, why.into()));
            s.monitoring = Monitoring::fresh(&s.monitoring);
        });
        if let Some(tap) = &self.monitor {
            tap.reset();
            self.next_check = Instant::now() + Duration::from_millis(500).min(self.period);
        }
        let warning = super::devices::other_rig(&model, &self.rig_name, self.rig_seed).map_or(
            String::new(),
            |w| {
                tracing::warn!("{}: {w}", super::clipped(&l.path.display().to_string()));
                format!("; {w}")
            },
        );
        l.envelope.answer(Reply::ok(format!(
            "swapped in {} while playing (loaded in {seconds:.2} s){warning}",
            l.path.display()
        )));
        self.swapped = Some((l.path, model));
        // A climb from the model it replaced would install over the operator's choice.
        self.climb = None;
        if let Some(c) = self.candidate.take() {
            tracing::info!(
                "progressive calibration: {} is not checked: another model was swapped in",
                c.plan.method
            );
        }
        Some(pass)
    }

    /// The climb's outcome, once there is one: a trained candidate ends the playback, for the
    /// engine to check it on the rig ([`super::climb::settle`]); a failed climb is logged.
    fn climbed(&mut self) {
        let Some(outcome) = self.climb.as_ref().and_then(Climb::poll) else {
            return;
        };
        let Some(climb) = self.climb.take() else {
            return;
        };
        let (method, seconds) = (climb.plan.method, climb.seconds());
        match outcome {
            Err(Error::Cancelled(_)) => {}
            Err(e) => {
                let msg = format!("climbing to {method} failed: {e}");
                tracing::warn!("progressive calibration: {msg}");
                self.io.climbed(method, false, msg.clone());
                self.io
                    .shared
                    .update(|s| s.last_error = Some(format!("progressive calibration: {msg}")));
            }
            Ok(c) => {
                if let Some(r) = c
                    .model
                    .meta
                    .calibration
                    .as_ref()
                    .and_then(|c| c.climb.as_ref())
                {
                    tracing::info!(
                        "progressive calibration: {method} scored {:.2} dB on {} against {:.2} \
                         dB for {} ({:+.2} dB); {seconds:.0} s; checking both on the rig",
                        r.psnr,
                        r.judged_on(),
                        r.replaced_psnr,
                        r.replaced,
                        r.psnr - r.replaced_psnr
                    );
                }
                self.candidate = Some(c);
            }
        }
    }

    /// Ends the playback's business: a model still loading is waited for, so its request is
    /// answered and, loaded, it is served from the next playback on.
    pub(super) fn settle(&mut self) {
        let _ = self.loaded(true);
        // A source still opening is not waited for: the playback ends for another reason.
        if let Some((envelope, opening)) = self.checking.take() {
            envelope.answer(Reply::error(format!(
                "{}: the playback ended for another request before it opened; ask again",
                super::clipped(&opening.text)
            )));
        }
    }
}

impl<S: Screen<P> + ?Sized, P: ServedPass> Screen<P> for ServiceScreen<'_, S, P> {
    fn context(&self) -> &GpuContext {
        self.inner.context()
    }

    fn refresh(&self) -> Refresh {
        self.inner.refresh()
    }

    fn begin(&mut self, live: bool) -> Result<()> {
        self.inner.begin(live)
    }

    fn display_delay(&self) -> Duration {
        self.inner.display_delay()
    }

    fn keep_going(&mut self) -> bool {
        self.io.notify.ping();
        if self.pending.is_some() || self.candidate.is_some() {
            return false;
        }
        if !self.checked_source() {
            return false;
        }
        match self.io.rx.try_recv() {
            Ok(ev) => {
                if !self.event(ev) {
                    return false;
                }
            }
            Err(TryRecvError::Empty) => {}
            Err(TryRecvError::Disconnected) => {
                self.pending = Some(Event::Terminate("the control channel closed"));
                return false;
            }
        }
        if let Some((rig, at)) = &self.drift
            && Instant::now() >= *at
        {
            match rig.set_phase(Phase::AfterDrift) {
                Ok(()) => tracing::warn!(
                    "virtual rig: the projector was moved to the scene's drifted pose"
                ),
                Err(e) => tracing::error!("virtual rig: could not move the projector: {e}"),
            }
            self.drift = None;
        }
        if self.monitor.as_ref().is_some_and(|t| t.ends_playback())
            || self
                .end_when
                .as_ref()
                .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            return false;
        }
        self.inner.keep_going()
    }

    fn take_pass(&mut self) -> Option<P> {
        self.climbed();
        self.loaded(false).and_then(P::swapped)
    }

    fn refreshed(&mut self, stats: &PlayStats) {
        let now = Instant::now();
        if now.duration_since(self.last_counts) >= Duration::from_millis(100) {
            self.last_counts = now;
            let age = self.last_check.map(|t| t.elapsed().as_secs_f64());
            let media = self.media.as_ref().map(|c| c.status());
            self.io.shared.update(|s| {
                set_frames(&mut s.frames, stats, &self.before);
                if age.is_some() {
                    s.monitoring.age_s = age;
                }
                if media.is_some() {
                    s.media = media;
                }
            });
        }
        if now.duration_since(self.last_stats) >= self.stats_every {
            self.last_stats = now;
            tracing::info!("playback: {}", stats.summary());
        }
    }

    fn present(&mut self, pass: &P, show: Show) -> Result<()> {
        self.inner.present(pass, show)?;
        if let Show::New { seq, .. } = show {
            if !self.io.notify.is_ready() {
                self.io.notify.ready("playing");
            }
            let now = Instant::now();
            let mut requested = false;
            if let Some(tap) = &self.monitor
                && now >= self.next_check
            {
                let (desired, area) = pass.desired_view(self.inner.context())?;
                if self.changes.is_some() {
                    self.checked = Some((seq, desired.clone()));
                }
                tap.request(seq, desired, area, &self.io.shared);
                self.next_check = now + self.period;
                self.last_check = Some(now);
                requested = true;
            }
            if let Some(changes) = &self.changes {
                // While a check waits for its view, a frame whose desired view is the check's
                // is the same content (a still, a repeated pattern); otherwise every new frame
                // is taken as a change.
                let waiting = match &self.checked {
                    Some((s, _)) => self.monitor.as_ref().and_then(|t| t.wanted()) == Some(*s),
                    None => false,
                };
                let same = !requested
                    && waiting
                    && self.checked.as_ref().is_some_and(|(_, d)| {
                        pass.desired_view(self.inner.context())
                            .is_ok_and(|(v, _)| v.data() == d.data())
                    });
                if !same {
                    if !requested {
                        self.checked = None;
                    }
                    // The watching thread is gone (the camera failed): nothing to tell.
                    let _ = changes.send((seq, now));
                }
            }
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut PlayStats) -> Result<()> {
        self.inner.finish(stats)
    }
}

/// The counts of the playback under way; `before` holds the totals of the playbacks before it.
pub(super) fn set_frames(f: &mut Frames, s: &PlayStats, before: &Frames) {
    f.shown_total = before.shown_total + s.shown;
    f.dropped_total = before.dropped_total + s.dropped_source + s.dropped_pipeline;
    f.refreshes = s.refreshes;
    f.shown = s.shown;
    f.held = s.held;
    f.dropped_source = s.dropped_source;
    f.dropped_pipeline = s.dropped_pipeline;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A job that panics is answered by its dropped sender, and the loading thread goes on: the
    /// next jobs run, on that same thread.
    #[test]
    fn the_loading_thread_outlives_a_job_that_panics() {
        let mut loader = Loader::default();
        let thread_of = |loader: &mut Loader| {
            let (tx, rx) = mpsc::channel();
            loader
                .run(Box::new(move || {
                    let _ = tx.send(std::thread::current().id());
                }))
                .unwrap();
            rx.recv_timeout(Duration::from_secs(10)).unwrap()
        };
        let before = thread_of(&mut loader);
        let (tx, rx) = mpsc::channel::<()>();
        loader
            .run(Box::new(move || {
                let _keep = tx;
                panic!("a load that panics (expected in this test)");
            }))
            .unwrap();
        assert_eq!(
            rx.recv_timeout(Duration::from_secs(10)),
            Err(mpsc::RecvTimeoutError::Disconnected)
        );
        assert_eq!(thread_of(&mut loader), before);
        assert_eq!(thread_of(&mut loader), before);
    }
}
