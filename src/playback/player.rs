//! Playback: a source's frames through the compensation pass to a display, with the frame
//! accounting of DESIGN.md section 1 (playback) and issue 6:
//!
//! - a *refresh* is one display period (vsync on the projector window, `1/fps` of real time on
//!   the virtual rig); at each refresh the player takes the newest frame from the source's
//!   [`Feed`] without waiting, runs the pass on it and presents the result;
//! - `held`: refreshes with no new frame (the source is slower than the display): the last frame
//!   stays on screen;
//! - `dropped_source`: frames the source delivered that were replaced by a newer one before a
//!   refresh took them (the source is faster than the display);
//! - `dropped_pipeline`: refreshes the pipeline missed because its work for the previous refresh
//!   was not done in time (the display repeated a frame although a new one was being processed).
//!
//! On the virtual rig ([`play_virtual`]) the simulated camera runs on its own thread, as a real
//! camera would, so its simulation cost does not count against the pipeline.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::device::{DisplaySink, FrameSource};
use crate::error::{Error, Result};
use crate::gpu::{CompensationPass, GpuContext};
use crate::raster::CamImage;
use crate::rig::VirtualRig;
use crate::source::{Feed, FeedMode, Poll};

/// Counts and timings of one playback.
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
    /// Mean wall time per shown frame of upload + pass (+ read-back on the virtual rig), ms.
    pub pipeline_ms_mean: f64,
    /// Worst of the same, ms.
    pub pipeline_ms_max: f64,
    /// Camera views captured (virtual rig).
    pub camera_views: u64,
    /// Camera views skipped because the simulated camera fell behind (live pacing only).
    pub camera_views_skipped: u64,
    /// Wall time of the playback, s.
    pub seconds: f64,
}

/// Deadline accounting for a display paced at `period`: call [`Clock::finish`] after each
/// refresh's work; it sleeps to the next refresh or reports how many were missed.
#[derive(Debug)]
pub struct Clock {
    period: Duration,
    next: Instant,
}

impl Clock {
    pub fn new(period: Duration) -> Self {
        Self {
            period,
            next: Instant::now() + period,
        }
    }

    /// Ends a refresh whose work is done now: waits for the refresh instant when early (if
    /// `sleep`), and returns the number of refresh instants missed when late.
    pub fn finish(&mut self, sleep: bool) -> u64 {
        let now = Instant::now();
        if now <= self.next {
            if sleep {
                std::thread::sleep(self.next - now);
            }
            self.next += self.period;
            return 0;
        }
        let late = now - self.next;
        let missed = (late.as_nanos() / self.period.as_nanos().max(1)) as u64 + 1;
        self.next += self.period * (missed as u32 + 1);
        missed
    }
}

/// What one refresh did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// A new frame (source sequence number) was compensated and submitted.
    New(u64),
    /// Nothing new: the last frame stays.
    Held,
    /// The source ended and every frame was shown.
    Ended,
}

/// The pass fed by a source.
pub struct Player {
    pub pass: CompensationPass,
    pub feed: Feed,
    pub stats: PlayStats,
    pipeline_total: f64,
}

impl Player {
    pub fn new(pass: CompensationPass, feed: Feed) -> Self {
        let stats = PlayStats {
            source: feed.describe().to_string(),
            ..PlayStats::default()
        };
        Self {
            pass,
            feed,
            stats,
            pipeline_total: 0.0,
        }
    }

    /// One refresh: takes the newest frame (waiting up to `wait` for one; zero = never wait),
    /// uploads it and submits the pass. Counts the refresh.
    pub fn step(&mut self, ctx: &GpuContext, wait: Duration) -> Result<Step> {
        let poll = if wait.is_zero() {
            self.feed.poll()?
        } else {
            self.feed.wait(wait)?
        };
        let fs = self.feed.stats();
        self.stats.received = fs.received;
        self.stats.dropped_source = fs.dropped;
        match poll {
            Poll::Frame { seq, frame } => {
                self.pass.run(ctx, &frame)?;
                self.stats.refreshes += 1;
                self.stats.shown += 1;
                Ok(Step::New(seq))
            }
            Poll::Nothing => {
                self.stats.refreshes += 1;
                self.stats.held += 1;
                Ok(Step::Held)
            }
            Poll::Ended => Ok(Step::Ended),
        }
    }

    /// Records the pipeline time of a shown frame.
    pub fn record_pipeline(&mut self, seconds: f64) {
        self.pipeline_total += seconds;
        let ms = seconds * 1e3;
        self.stats.pipeline_ms_max = self.stats.pipeline_ms_max.max(ms);
        self.stats.pipeline_ms_mean = self.pipeline_total * 1e3 / self.stats.shown.max(1) as f64;
    }
}

/// How the virtual rig plays.
#[derive(Clone, Copy, Debug)]
pub struct VirtualOptions {
    /// Display refresh rate, Hz.
    pub fps: f64,
    /// Stop after this many refreshes.
    pub refreshes: Option<u64>,
    /// [`FeedMode::Latest`]: real-time pacing at `fps`, frames dropped and counted as they
    /// would be live. [`FeedMode::Queue`]: every source frame shown once, as fast as the
    /// pipeline goes (offline rendering; nothing dropped by construction).
    pub mode: FeedMode,
}

/// Plays at `fps` with no display and no read-back: each refresh uploads the newest frame, runs
/// the pass and waits until the GPU has finished it, then sleeps to the next refresh. This is the
/// window's per-frame work without the presentation, so its `dropped_pipeline` says whether the
/// upload and the pass keep up with the display on this adapter, whatever a virtual rig's
/// read-back to the CPU costs. Ends when the source ends or after `refreshes`.
pub fn play_headless(
    ctx: &GpuContext,
    player: &mut Player,
    fps: f64,
    refreshes: Option<u64>,
) -> Result<PlayStats> {
    let start = Instant::now();
    player.stats.refresh_hz = fps;
    let mut clock = Clock::new(Duration::from_secs_f64(1.0 / fps));
    while refreshes.is_none_or(|n| player.stats.refreshes < n) {
        let t = Instant::now();
        match player.step(ctx, Duration::ZERO)? {
            Step::New(_) => {
                ctx.wait()?;
                player.record_pipeline(t.elapsed().as_secs_f64());
            }
            Step::Held => {}
            Step::Ended => break,
        }
        player.stats.dropped_pipeline += clock.finish(true);
    }
    let fs = player.feed.stats();
    player.stats.received = fs.received;
    player.stats.dropped_source = fs.dropped;
    player.stats.seconds = start.elapsed().as_secs_f64();
    Ok(player.stats.clone())
}

/// A camera view of a shown frame: (source sequence number, shown index from 1, image).
pub type ViewSink = Box<dyn FnMut(u64, u64, &CamImage) -> Result<()> + Send>;

/// Plays on the virtual rig: each new compensated frame is read back (the rig is simulated on
/// the CPU), shown on the rig's projector, and captured by its camera on a separate thread,
/// which hands the camera view to `views`. Ends when the source ends (a still image: after its
/// frame) or after `opts.refreshes`.
pub fn play_virtual(
    ctx: &GpuContext,
    player: &mut Player,
    rig: &VirtualRig,
    opts: VirtualOptions,
    mut views: ViewSink,
) -> Result<PlayStats> {
    let start = Instant::now();
    let live = opts.mode == FeedMode::Latest;
    let (tx, rx) =
        mpsc::sync_channel::<(u64, u64, crate::raster::PrjImage)>(if live { 8 } else { 1 });
    let mut cam_rig = rig.clone();
    let camera = std::thread::Builder::new()
        .name("compend-virtual-camera".into())
        .spawn(move || -> Result<u64> {
            let mut n = 0;
            for (seq, shown, frame) in rx {
                cam_rig.show(&frame)?;
                let view = cam_rig.grab()?;
                views(seq, shown, &view.image)?;
                n += 1;
            }
            Ok(n)
        })
        .map_err(|e| Error::Failed(format!("cannot start the virtual camera: {e}")))?;
    player.stats.refresh_hz = if live { opts.fps } else { 0.0 };
    let mut clock = Clock::new(Duration::from_secs_f64(1.0 / opts.fps));
    let mut skipped = 0;
    let result = (|| -> Result<()> {
        while opts.refreshes.is_none_or(|n| player.stats.refreshes < n) {
            let t = Instant::now();
            // Offline: wait for the source (in slices, so a stalled source can still end).
            let wait = if live {
                Duration::ZERO
            } else {
                Duration::from_millis(100)
            };
            let step = player.step(ctx, wait)?;
            match step {
                Step::New(seq) => {
                    let frame = player.pass.read_output(ctx)?;
                    player.record_pipeline(t.elapsed().as_secs_f64());
                    let item = (seq, player.stats.shown, frame);
                    if live {
                        if let Err(mpsc::TrySendError::Full(_)) = tx.try_send(item) {
                            skipped += 1;
                        }
                    } else if tx.send(item).is_err() {
                        break; // the camera thread failed; its error is reported below
                    }
                }
                Step::Held if !live => {
                    // Offline pacing: a refresh only counts with a frame.
                    player.stats.refreshes -= 1;
                    player.stats.held -= 1;
                    continue;
                }
                Step::Held => {}
                Step::Ended => break,
            }
            if live {
                player.stats.dropped_pipeline += clock.finish(true);
            }
        }
        Ok(())
    })();
    drop(tx);
    let cam = camera
        .join()
        .map_err(|_| Error::Failed("the virtual camera thread panicked".into()))?;
    result?;
    player.stats.camera_views = cam?;
    player.stats.camera_views_skipped = skipped;
    let fs = player.feed.stats();
    player.stats.received = fs.received;
    player.stats.dropped_source = fs.dropped;
    player.stats.seconds = start.elapsed().as_secs_f64();
    Ok(player.stats.clone())
}
