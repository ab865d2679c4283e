//! The one playback loop (docs/architecture.md, "Playback"): a source's frames through the
//! compensation pass to a display, paced at the display's refresh, with the frame accounting:
//!
//! - a *refresh* is one display period (vsync on the projector window, `1/fps` of real time on
//!   the virtual rig and with no display); at each refresh the loop takes the newest frame from
//!   the source's [`Feed`] without waiting, runs the pass on it and presents the result;
//! - `held`: refreshes with no new frame (the source is slower than the display): the last frame
//!   stays on screen;
//! - `dropped_source`: frames the source delivered that were replaced by a newer one before a
//!   refresh took them (the source is faster than the display);
//! - `dropped_pipeline`: refreshes the pipeline missed because its work for the previous refresh
//!   was not done in time (the display repeated a frame although a new one was being processed).
//!
//! With `--pace source` ([`FeedMode::Queue`]) every source frame is shown once and nothing is
//! dropped: a display with a refresh of its own (the window) still presents at its vsync; one
//! without (the virtual rig) has no clock at all, and a refresh is a frame.
//!
//! Displays are [`Screen`]s: the projector window (`crate::window::ProjectorWindow`), a
//! [`DisplaySink`] watched by a [`FrameSource`] on a thread of their own ([`WatchedSink`]: the
//! virtual rig's projector and camera, whose simulation cost does not count against the
//! pipeline), and no display at all ([`Headless`], for benchmarks). [`Player::start`] builds the
//! pipeline for a model and a display; [`Player::run`] plays it.

use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::device::{DisplaySink, FrameSource};
use crate::error::{Error, Result};
use crate::fov::DisplayRange;
use crate::gpu::{CompensationPass, FramePass, GpuContext};
use crate::model::Model;
use crate::playback::ContentFrame;
use crate::raster::{CamImage, ImageSize, PrjImage};
use crate::source::{Feed, FeedMode, Poll, VideoSource};

/// Counts and timings of one playback (`play.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PlayStats {
    /// What was played.
    pub source: String,
    /// Display refresh rate the playback was paced at, Hz (0 = paced by the source).
    pub refresh_hz: f64,
    /// Display refreshes played.
    pub refreshes: u64,
    /// Distinct source frames compensated and presented.
    pub shown: u64,
    /// Refreshes that repeated the previous frame because no new one had arrived.
    pub held: u64,
    /// Frames the source delivered.
    pub received: u64,
    /// Frames replaced before a refresh took them (source faster than the display).
    pub dropped_source: u64,
    /// Refreshes missed because the pipeline was late.
    pub dropped_pipeline: u64,
    /// Mean wall time per shown frame, ms: upload + pass + what the display does with a new
    /// frame (presenting on the window, reading back on the virtual rig, waiting for the GPU with
    /// no display).
    pub pipeline_ms_mean: f64,
    /// Worst of the same, ms.
    pub pipeline_ms_max: f64,
    /// Camera views captured (virtual rig).
    pub camera_views: u64,
    /// Camera views skipped because the simulated camera fell behind (live pacing only).
    pub camera_views_skipped: u64,
    /// Wall time of the playback loop, s.
    pub seconds: f64,
    /// Mean picture latency of the shown frames, ms: from the source's delivery of a frame
    /// (for media, its presentation time on the pipeline's clock) to its presentation, plus
    /// the display's own delay ([`Screen::display_delay`]). A media source's sound is delayed
    /// by as much.
    pub latency_ms_mean: f64,
    /// Frames written to a media output (`--to`), when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output_frames: Option<u64>,
    /// A media source's counts (position, length, frame rate, sound, warnings, reconnects).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub media: Option<crate::media::MediaStatus>,
}

impl PlayStats {
    /// The counts on one line, for a person (the log, the command's summary).
    pub fn summary(&self) -> String {
        format!(
            "{} refreshes, {} frames shown, {} held, {} dropped by the source (faster than the \
             display), {} dropped by the pipeline; pipeline {:.2} ms mean, {:.2} ms worst",
            self.refreshes,
            self.shown,
            self.held,
            self.dropped_source,
            self.dropped_pipeline,
            self.pipeline_ms_mean,
            self.pipeline_ms_max
        )
    }
}

/// How a display refreshes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Refresh {
    /// Its own vertical sync at this rate, Hz: presenting waits for a free refresh. A display
    /// someone watches (the projector window): a still image stays on it until it is closed.
    Vsync(f64),
    /// No refresh of its own: in live pacing the loop keeps time at this rate, Hz; in offline
    /// pacing there is no clock. A simulated or absent display: playback ends with the source.
    Timer(f64),
}

impl Refresh {
    fn hz(self) -> f64 {
        match self {
            Refresh::Vsync(hz) | Refresh::Timer(hz) => hz,
        }
    }
}

/// What a refresh presents.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Show {
    /// A new frame: its source sequence number (from 1) and its index among the frames shown
    /// (from 1).
    New { seq: u64, index: u64 },
    /// The last frame again: nothing new arrived for this refresh.
    Again,
}

/// A display the playback loop drives, presenting the pictures of a pass `P` (one projector's
/// [`CompensationPass`] by default; a set's [`crate::gpu::joint::SetPass`] on a set's outputs).
pub trait Screen<P = CompensationPass> {
    /// The GPU device the pass runs on (the window's: one that can present to it).
    fn context(&self) -> &GpuContext;

    /// How the display refreshes.
    fn refresh(&self) -> Refresh;

    /// Called once before the first refresh. `live`: real-time pacing, where a display may skip
    /// what it cannot keep up with; otherwise offline, where every frame counts.
    fn begin(&mut self, live: bool) -> Result<()> {
        let _ = live;
        Ok(())
    }

    /// Called before each refresh: lets the display catch up (the window handles its events,
    /// [`WatchedSink`] hands its thread a frame it had no room for) and says whether playback
    /// goes on (false once the window was closed).
    fn keep_going(&mut self) -> bool {
        true
    }

    /// Called before each refresh: a pass to play from the next new frame on (a model swapped in
    /// while playing). Refreshes until that frame present the current pass's output.
    fn take_pass(&mut self) -> Option<P> {
        None
    }

    /// Called after each refresh with the counts so far (a service shows them live).
    fn refreshed(&mut self, stats: &PlayStats) {
        let _ = stats;
    }

    /// Puts the pass's output on the display; for [`Show::New`] the pass was just submitted
    /// with a new frame, and the time from its upload to the end of this call is the frame's
    /// pipeline time.
    fn present(&mut self, pass: &P, show: Show) -> Result<()>;

    /// How long after `present` returns the picture is seen (a window: about one refresh from
    /// the swap to the scan-out); zero by default.
    fn display_delay(&self) -> Duration {
        Duration::ZERO
    }

    /// Called once after the last refresh, also when playback failed: the display's own counts
    /// go into `stats` (camera views).
    fn finish(&mut self, stats: &mut PlayStats) -> Result<()> {
        let _ = stats;
        Ok(())
    }
}

/// Deadline accounting for a display paced at `period`: call [`Clock::finish`] after each
/// refresh's work; it sleeps to the next refresh or reports how many were missed.
#[derive(Debug)]
struct Clock {
    period: Duration,
    next: Instant,
}

impl Clock {
    fn new(period: Duration) -> Self {
        Self {
            period,
            next: Instant::now() + period,
        }
    }

    /// Ends a refresh whose work is done now: waits for the refresh instant when early, and
    /// returns the number of refresh instants missed when late.
    fn finish(&mut self) -> u64 {
        let now = Instant::now();
        if now <= self.next {
            std::thread::sleep(self.next - now);
            self.next += self.period;
            return 0;
        }
        let late = now - self.next;
        let missed = (late.as_nanos() / self.period.as_nanos().max(1)) as u64 + 1;
        self.next += self.period * (missed as u32 + 1);
        missed
    }
}

/// Ends each refresh at the display's pace and counts the refreshes the pipeline missed.
struct Pacer {
    refresh: Refresh,
    live: bool,
    clock: Clock,
    /// End of the previous refresh (vsync displays).
    last: Option<Instant>,
}

impl Pacer {
    fn new(refresh: Refresh, live: bool) -> Self {
        Self {
            refresh,
            live,
            clock: Clock::new(Duration::from_secs_f64(1.0 / refresh.hz())),
            last: None,
        }
    }

    /// Offline pacing on a display without a refresh of its own: only frames are refreshes.
    fn frames_only(&self) -> bool {
        matches!(self.refresh, Refresh::Timer(_)) && !self.live
    }

    /// Ends a refresh (`presented`: whether it presented anything); returns the refreshes the
    /// pipeline missed before it, counted in live pacing only.
    fn end_refresh(&mut self, presented: bool) -> u64 {
        match self.refresh {
            Refresh::Timer(_) if self.live => self.clock.finish(),
            Refresh::Timer(_) => 0,
            Refresh::Vsync(_) => {
                let period = self.clock.period;
                if !presented {
                    // Nothing to present yet: let one refresh go by.
                    std::thread::sleep(period);
                }
                let now = Instant::now();
                match self.last.replace(now) {
                    // A refresh that took longer than 1.5 periods: the display repeated a frame.
                    Some(prev) if self.live => {
                        let periods = (now - prev).as_secs_f64() / period.as_secs_f64();
                        if periods > 1.5 {
                            (periods.round() as u64).saturating_sub(1)
                        } else {
                            0
                        }
                    }
                    _ => 0,
                }
            }
        }
    }
}

/// What the feed had for one refresh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Step {
    /// A new frame (source sequence number, when the source delivered it) was compensated and
    /// submitted.
    New(u64, Instant),
    /// Nothing new: the last frame stays.
    Held,
    /// The source ended and every frame was shown.
    Ended,
}

/// A pass fed by a source: one playback (one projector's [`CompensationPass`] by default, or a
/// set's joint pass).
pub struct Player<P = CompensationPass> {
    pub pass: P,
    pub feed: Feed,
    /// A pass handed over by the screen, in use from the next new frame on (or at once on the
    /// last frame, when the display holds it).
    next_pass: Option<P>,
    /// The last frame run through the pass (moved here, not copied).
    last: Option<ContentFrame>,
    stats: PlayStats,
    /// Sum of the pipeline times of the frames shown, s.
    pipeline_total: f64,
    /// Sum of the picture latencies of the frames shown, s.
    latency_total: f64,
    /// The latency given to a media source's sound last, and when.
    latency_applied: Option<(Duration, Instant)>,
}

impl Player {
    /// The pipeline for `model` on a display of `display` projector pixels, content values
    /// mapped into `range`: the pass built on `ctx` ([`CompensationPass::for_display`]), fed by
    /// `source` on its own thread in `mode`.
    pub fn start(
        ctx: &GpuContext,
        model: &Model,
        display: ImageSize,
        range: DisplayRange,
        source: Box<dyn VideoSource>,
        mode: FeedMode,
    ) -> Result<Self> {
        let pass = CompensationPass::for_display(ctx, model, display, range)?;
        Ok(Self::new(pass, Feed::spawn(source, mode)?))
    }
}

impl<P: FramePass> Player<P> {
    /// A player of `pass` fed by `feed`.
    pub fn new(pass: P, feed: Feed) -> Self {
        let stats = PlayStats {
            source: feed.describe().to_string(),
            ..PlayStats::default()
        };
        Self {
            pass,
            feed,
            next_pass: None,
            last: None,
            stats,
            pipeline_total: 0.0,
            latency_total: 0.0,
            latency_applied: None,
        }
    }

    /// The counts so far.
    pub fn stats(&self) -> &PlayStats {
        &self.stats
    }

    /// Plays on `screen` until the source ends (a still image on a display without vsync: after
    /// its frame), `refreshes` refreshes were played, or the screen is closed; returns the
    /// counts.
    pub fn run<S: Screen<P> + ?Sized>(
        &mut self,
        screen: &mut S,
        refreshes: Option<u64>,
    ) -> Result<PlayStats> {
        let refresh = screen.refresh();
        let hz = refresh.hz();
        if !(hz.is_finite() && hz > 0.0) {
            return Err(Error::Input(format!(
                "display refresh rate must be positive, got {hz} Hz"
            )));
        }
        let start = Instant::now();
        let live = self.feed.mode() == FeedMode::Latest;
        self.stats.refresh_hz = match refresh {
            Refresh::Timer(_) if !live => 0.0,
            _ => hz,
        };
        screen.begin(live)?;
        let played = self.play(screen, refreshes, Pacer::new(refresh, live));
        let finished = screen.finish(&mut self.stats);
        played?;
        finished?;
        self.count_feed();
        self.stats.media = self.feed.control().map(|c| c.status());
        self.stats.seconds = start.elapsed().as_secs_f64();
        Ok(self.stats.clone())
    }

    /// The refreshes.
    fn play<S: Screen<P> + ?Sized>(
        &mut self,
        screen: &mut S,
        refreshes: Option<u64>,
        mut pacer: Pacer,
    ) -> Result<()> {
        // Offline: wait for the source, in slices so that a stalled source can still end.
        let wait = if pacer.live {
            Duration::ZERO
        } else {
            Duration::from_millis(100)
        };
        let holds_stills = matches!(pacer.refresh, Refresh::Vsync(_)) && !self.feed.ends_playback();
        while screen.keep_going() && refreshes.is_none_or(|n| self.stats.refreshes < n) {
            if let Some(pass) = screen.take_pass() {
                self.next_pass = Some(pass);
            }
            let t = Instant::now();
            let presented = match self.next(screen.context(), wait)? {
                Step::New(seq, at) => {
                    self.stats.refreshes += 1;
                    self.stats.shown += 1;
                    let index = self.stats.shown;
                    screen.present(&self.pass, Show::New { seq, index })?;
                    self.record_pipeline(t.elapsed().as_secs_f64());
                    if pacer.live {
                        self.record_latency(at.elapsed() + screen.display_delay());
                    }
                    true
                }
                Step::Held if pacer.frames_only() => continue,
                Step::Held => self.hold(screen)?,
                // A still image on a watched display: keep it on screen.
                Step::Ended if holds_stills => self.hold(screen)?,
                Step::Ended => break,
            };
            self.stats.dropped_pipeline += pacer.end_refresh(presented);
            self.count_feed();
            screen.refreshed(&self.stats);
        }
        Ok(())
    }

    /// Takes the newest frame (waiting up to `wait` for one; zero = never wait), uploads it and
    /// submits the pass.
    fn next(&mut self, ctx: &GpuContext, wait: Duration) -> Result<Step> {
        let poll = if wait.is_zero() {
            self.feed.poll()?
        } else {
            self.feed.wait(wait)?
        };
        self.count_feed();
        match poll {
            Poll::Frame { seq, frame, at } => {
                if let Some(pass) = self.next_pass.take() {
                    self.pass = pass;
                }
                self.pass.run_frame(ctx, &frame)?;
                self.last = Some(frame);
                Ok(Step::New(seq, at))
            }
            Poll::Nothing => Ok(Step::Held),
            Poll::Ended => Ok(Step::Ended),
        }
    }

    /// A refresh with no new frame: the last one stays, presented again where the display needs
    /// that. Returns whether anything was presented.
    fn hold<S: Screen<P> + ?Sized>(&mut self, screen: &mut S) -> Result<bool> {
        self.stats.refreshes += 1;
        self.stats.held += 1;
        if self.stats.shown == 0 {
            return Ok(false);
        }
        // A pass handed over while the display holds a still: the still through it.
        if let Some(frame) = &self.last
            && let Some(pass) = self.next_pass.take()
        {
            self.pass = pass;
            self.pass.run_frame(screen.context(), frame)?;
        }
        screen.present(&self.pass, Show::Again)?;
        Ok(true)
    }

    fn count_feed(&mut self) {
        let fs = self.feed.stats();
        self.stats.received = fs.received;
        self.stats.dropped_source = fs.dropped;
    }

    /// Records the picture latency of a shown frame (live pacing) and hands the running mean to
    /// a media source, whose sound is delayed by it: after the first 10 frames, then when it
    /// moved by more than 2 ms, at most once a second (each change may click).
    fn record_latency(&mut self, latency: Duration) {
        self.latency_total += latency.as_secs_f64();
        let n = self.stats.shown.max(1) as f64;
        self.stats.latency_ms_mean = self.latency_total * 1e3 / n;
        let Some(control) = self.feed.control() else {
            return;
        };
        if self.stats.shown < 10 {
            return;
        }
        let mean = Duration::from_secs_f64(self.latency_total / n);
        let due = match self.latency_applied {
            None => true,
            Some((applied, when)) => {
                when.elapsed() >= Duration::from_secs(1)
                    && (mean.as_secs_f64() - applied.as_secs_f64()).abs() > 0.002
            }
        };
        if due {
            control.set_picture_latency(mean);
            self.latency_applied = Some((mean, Instant::now()));
        }
    }

    /// Records the pipeline time of a shown frame, s.
    fn record_pipeline(&mut self, seconds: f64) {
        self.pipeline_total += seconds;
        let ms = seconds * 1e3;
        self.stats.pipeline_ms_max = self.stats.pipeline_ms_max.max(ms);
        self.stats.pipeline_ms_mean = self.pipeline_total * 1e3 / self.stats.shown.max(1) as f64;
    }
}

/// No display: each new frame's upload and pass are waited for on the GPU and nothing is
/// presented, at `hz` in live pacing. This is the window's work per frame without the
/// presentation, so its `dropped_pipeline` says whether the upload and the pass keep up with
/// the display on this adapter, whatever a virtual rig's read-back to the CPU costs.
pub struct Headless<'a> {
    ctx: &'a GpuContext,
    hz: f64,
}

impl<'a> Headless<'a> {
    pub fn new(ctx: &'a GpuContext, hz: f64) -> Self {
        Self { ctx, hz }
    }
}

impl<P> Screen<P> for Headless<'_> {
    fn context(&self) -> &GpuContext {
        self.ctx
    }

    fn refresh(&self) -> Refresh {
        Refresh::Timer(self.hz)
    }

    fn present(&mut self, _pass: &P, show: Show) -> Result<()> {
        match show {
            Show::New { .. } => self.ctx.wait(),
            Show::Again => Ok(()),
        }
    }
}

/// A camera view of a shown frame: (source sequence number, index among the frames shown from
/// 1, the view in camera pixels).
pub type ViewSink = Box<dyn FnMut(u64, u64, &CamImage) -> Result<()> + Send>;

/// A shown frame on its way to the display thread: (sequence number, index, projector frame).
type Item = (u64, u64, PrjImage);

/// The display thread of a [`WatchedSink`]: its channel and the thread, which returns the
/// number of views captured.
struct Watcher {
    tx: mpsc::SyncSender<Item>,
    thread: JoinHandle<Result<u64>>,
}

/// A [`DisplaySink`] watched by a [`FrameSource`]: each new frame is read back from the GPU
/// (part of its pipeline time) and handed to a thread of their own, which shows it on the sink,
/// grabs the camera's next frame and passes it to a [`ViewSink`]; that thread's time does not
/// count against the pipeline. The virtual rig's projector and camera (two clones of one
/// [`crate::rig::VirtualRig`], set to deliver one exposure per shown frame), paced by a timer at
/// `hz`. In live pacing a frame the thread has no room for is skipped and counted
/// (`camera_views_skipped`); offline, the loop waits for the thread.
pub struct WatchedSink<'a, D, C> {
    ctx: &'a GpuContext,
    hz: f64,
    /// The devices and the view sink until [`Screen::begin`] moves them to their thread.
    devices: Option<(D, C, ViewSink)>,
    watcher: Option<Watcher>,
    live: bool,
    /// A frame the thread had no room for yet (offline pacing).
    pending: Option<Item>,
    skipped: u64,
    /// The thread stopped taking frames (it failed; [`Screen::finish`] reports why).
    closed: bool,
}

impl<'a, D, C> WatchedSink<'a, D, C>
where
    D: DisplaySink + Send + 'static,
    C: FrameSource + Send + 'static,
{
    /// Frames of `ctx`'s passes shown on `display`, seen by `camera`, the views going to `views`.
    pub fn new(ctx: &'a GpuContext, hz: f64, display: D, camera: C, views: ViewSink) -> Self {
        Self {
            ctx,
            hz,
            devices: Some((display, camera, views)),
            watcher: None,
            live: true,
            pending: None,
            skipped: 0,
            closed: false,
        }
    }
}

/// The display thread's work: show each frame, grab a view, hand it on. Returns the views taken.
fn watch(
    rx: mpsc::Receiver<Item>,
    mut display: impl DisplaySink,
    mut camera: impl FrameSource,
    mut views: ViewSink,
) -> Result<u64> {
    let mut n = 0;
    for (seq, index, frame) in rx {
        display.show(&frame)?;
        let view = camera.grab()?;
        views(seq, index, &view.image)?;
        n += 1;
    }
    Ok(n)
}

impl<D, C, P> Screen<P> for WatchedSink<'_, D, C>
where
    D: DisplaySink + Send + 'static,
    C: FrameSource + Send + 'static,
    P: FramePass,
{
    fn context(&self) -> &GpuContext {
        self.ctx
    }

    fn refresh(&self) -> Refresh {
        Refresh::Timer(self.hz)
    }

    fn begin(&mut self, live: bool) -> Result<()> {
        let (display, camera, views) = self
            .devices
            .take()
            .ok_or_else(|| Error::Failed("a watched display plays only once".into()))?;
        self.live = live;
        let (tx, rx) = mpsc::sync_channel::<Item>(if live { 8 } else { 1 });
        let thread = std::thread::Builder::new()
            .name("compend-virtual-camera".into())
            .spawn(move || watch(rx, display, camera, views))
            .map_err(|e| Error::Failed(format!("cannot start the virtual camera: {e}")))?;
        self.watcher = Some(Watcher { tx, thread });
        Ok(())
    }

    fn keep_going(&mut self) -> bool {
        if let (Some(item), Some(w)) = (self.pending.take(), &self.watcher)
            && w.tx.send(item).is_err()
        {
            self.closed = true;
        }
        !self.closed
    }

    fn present(&mut self, pass: &P, show: Show) -> Result<()> {
        let Show::New { seq, index } = show else {
            return Ok(()); // the sink keeps showing the last frame
        };
        let frame = pass.read_frame(self.ctx)?;
        let w = self
            .watcher
            .as_ref()
            .ok_or_else(|| Error::Failed("a watched display presented before it began".into()))?;
        match w.tx.try_send((seq, index, frame)) {
            Ok(()) => {}
            Err(mpsc::TrySendError::Full(_)) if self.live => self.skipped += 1,
            Err(mpsc::TrySendError::Full(item)) => self.pending = Some(item),
            Err(mpsc::TrySendError::Disconnected(_)) => self.closed = true,
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut PlayStats) -> Result<()> {
        let Some(Watcher { tx, thread }) = self.watcher.take() else {
            return Ok(());
        };
        if let Some(item) = self.pending.take() {
            let _ = tx.send(item); // a failed thread reports its error below
        }
        drop(tx);
        let views = thread
            .join()
            .map_err(|_| Error::Failed("the virtual camera thread panicked".into()))??;
        stats.camera_views = views;
        stats.camera_views_skipped = self.skipped;
        Ok(())
    }
}
