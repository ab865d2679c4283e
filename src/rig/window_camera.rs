//! A virtual camera looking at a real display: the projector window presents the patterns, and
//! this camera sees what the window actually presented, through the rig's surface and camera
//! physics, with the scene's latency. For a set of projectors ([`WindowCamera::start_set`]) it
//! looks at every projector's window, each seen through its own projector of the scene.
//!
//! Timing (real clock, from [`WindowCamera::start`]):
//! - the camera runs on its own thread and exposes frame k at k/fps seconds (the scene's
//!   `latency.fps`); an exposure is dropped with probability `drop_rate` (hashing the seed and
//!   k, as [`super::VirtualRig`] does), and a dropped frame's sequence number is skipped;
//! - exposure k sees the last frame the display presented at least `delay_frames / fps` before
//!   it (the projector-to-camera latency), asked of the display through a look-up function (for
//!   the projector window, its log of presented frames read back from the GPU); before the
//!   first present it sees black;
//! - the image is what a private [`super::VirtualRig`] (no delay, no drops) shows for that
//!   frame: the simulator's surface, camera response, noise and quantisation; its manual
//!   exposure is the camera's ([`FrameSource::set_exposure`] applies from the next exposure);
//! - frames wait in a queue of [`BUFFERS`] like a driver's buffers: while nobody takes them, the
//!   queue fills up and newer frames are lost (their sequence numbers skipped), so a reader that
//!   comes back after a pause first gets frames exposed during the pause (stale frames);
//! - when rendering falls behind the clock, the exposures it missed are skipped too.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::live::VirtualRig;
use super::physics::mix64;
use super::scene::{Latency, Scene};
use crate::device::{DisplaySink, ExposureRange, Frame, FrameSource};
use crate::error::{Error, Result};
use crate::raster::{ImageSize, PrjImage};

/// Frames the camera holds for its reader, like a driver's capture buffers.
pub const BUFFERS: usize = 4;

/// The shortest wait of [`FrameSource::grab`] for a frame before it reports the camera dead.
const MIN_GRAB_TIMEOUT: Duration = Duration::from_secs(5);

/// A frame the display presented, as the look-up function returns it.
#[derive(Clone, Debug)]
pub struct Shown {
    /// Number of the present (increasing; a new number is a new image on the surface).
    pub index: u64,
    /// When it was presented.
    pub at: Instant,
    /// Its pixels, projector space, the scene's projector size.
    pub image: Arc<PrjImage>,
}

/// How the camera's frames went.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct CameraTiming {
    /// Exposures taken, delivered to the queue, dropped as the scene's drop rate says, lost
    /// because the queue was full, and missed because rendering fell behind the clock.
    pub exposures: u64,
    pub delivered: u64,
    pub dropped: u64,
    pub overflowed: u64,
    pub behind: u64,
    /// Presented frames the camera saw (each new image on the surface).
    pub changes: u64,
    /// Shortest and longest time from a present to the first exposure that saw it, ms (the
    /// scene's delay plus up to one frame period).
    pub lag_ms_min: f64,
    pub lag_ms_max: f64,
    /// Mean time to render one exposure, ms.
    pub render_ms_mean: f64,
}

/// The virtual camera; frames are rendered on its own thread, stopped on drop.
pub struct WindowCamera {
    size: ImageSize,
    /// The private rig the camera thread renders with (shared: its exposure is the camera's).
    rig: VirtualRig,
    frames: Receiver<Result<Frame>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    timing: Arc<Mutex<CameraTiming>>,
    timeout: Duration,
}

/// The camera thread's state.
struct Exposer<L> {
    rig: VirtualRig,
    /// Per projector of the scene: its display's look-up, and its output of the private rig.
    looks: Vec<L>,
    outputs: Vec<super::live::VirtualOutput>,
    latency: Latency,
    seed: u64,
    /// Per projector: the present its output of the private rig shows.
    seen: Vec<Option<u64>>,
    timing: Arc<Mutex<CameraTiming>>,
    stop: Arc<AtomicBool>,
}

fn lock(t: &Mutex<CameraTiming>) -> MutexGuard<'_, CameraTiming> {
    // Counters only: a poisoned lock still holds usable numbers.
    t.lock().unwrap_or_else(|e| e.into_inner())
}

impl WindowCamera {
    /// Prepares the simulator for `scene` (texture and noise seed `seed`) and starts the camera.
    /// `look(t)` returns the last frame the display presented at or before `t`, None when it
    /// presented nothing yet; its images must be the scene's projector size.
    pub fn start<L>(scene: &Scene, seed: u64, look: L) -> Result<Self>
    where
        L: FnMut(Instant) -> Option<Shown> + Send + 'static,
    {
        Self::start_set(scene, seed, vec![look])
    }

    /// [`WindowCamera::start`] for a scene of several projectors: `looks[k]` is projector
    /// `k`'s display, one per projector of the scene.
    pub fn start_set<L>(scene: &Scene, seed: u64, looks: Vec<L>) -> Result<Self>
    where
        L: FnMut(Instant) -> Option<Shown> + Send + 'static,
    {
        let projectors = scene.projectors().len();
        if looks.len() != projectors {
            return Err(Error::Input(format!(
                "scene {:?} has {projectors} projector(s); the camera was given {} display(s) \
                 to look at",
                scene.name,
                looks.len()
            )));
        }
        let latency = scene.latency.clone();
        if !(latency.fps.is_finite() && latency.fps > 0.0) {
            return Err(Error::Input(format!(
                "scene {:?}: the camera needs a frame rate above 0, got {} fps",
                scene.name, latency.fps
            )));
        }
        let mut private = scene.clone();
        private.latency = Latency {
            fps: latency.fps,
            delay_frames: 0,
            drop_rate: 0.0,
        };
        let rig = VirtualRig::new(&private, seed)?;
        let size = FrameSource::size(&rig);
        let period = 1.0 / latency.fps;
        let timeout = MIN_GRAB_TIMEOUT.max(Duration::from_secs_f64(
            period * (10.0 + latency.delay_frames as f64),
        ));
        let (tx, frames) = sync_channel(BUFFERS);
        let stop = Arc::new(AtomicBool::new(false));
        let timing = Arc::new(Mutex::new(CameraTiming::default()));
        let outputs = (0..projectors)
            .map(|k| rig.output(k))
            .collect::<Result<Vec<_>>>()?;
        let exposer = Exposer {
            rig: rig.clone(),
            seen: vec![None; looks.len()],
            looks,
            outputs,
            latency,
            seed,
            timing: timing.clone(),
            stop: stop.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("window camera".into())
            .spawn(move || exposer.run(tx))
            .map_err(|e| Error::Failed(format!("cannot start the virtual camera: {e}")))?;
        Ok(Self {
            size,
            rig,
            frames,
            stop,
            thread: Some(thread),
            timing,
            timeout,
        })
    }

    /// The simulator the camera renders with (a clone sharing its state): moving its
    /// projector ([`VirtualRig::set_phase`]) moves what this camera sees.
    pub fn rig(&self) -> VirtualRig {
        self.rig.clone()
    }

    /// How the frames went so far.
    pub fn timing(&self) -> CameraTiming {
        lock(&self.timing).clone()
    }
}

impl<L: FnMut(Instant) -> Option<Shown>> Exposer<L> {
    /// Exposes frames on the clock until stopped or the reader is gone; an error is handed to
    /// the reader and ends the camera.
    fn run(mut self, tx: SyncSender<Result<Frame>>) {
        let fps = self.latency.fps;
        let origin = Instant::now();
        let mut k: u64 = 0;
        while !self.stop.load(Ordering::Relaxed) {
            let offset = Duration::from_secs_f64(k as f64 / fps);
            let t = origin + offset;
            let now = Instant::now();
            if now < t {
                std::thread::sleep(t - now);
            } else if (now - t).as_secs_f64() * fps >= 1.0 {
                // Rendering fell behind: skip to the latest exposure slot that has begun.
                let missed = ((now - t).as_secs_f64() * fps).floor() as u64;
                lock(&self.timing).behind += missed;
                k += missed;
                continue;
            }
            lock(&self.timing).exposures += 1;
            if self.dropped(k) {
                lock(&self.timing).dropped += 1;
                k += 1;
                continue;
            }
            let frame = self.expose(t).map(|image| Frame {
                image,
                seq: k,
                timestamp: offset,
            });
            let failed = frame.is_err();
            match tx.try_send(frame) {
                Ok(()) if !failed => lock(&self.timing).delivered += 1,
                Err(TrySendError::Full(_)) if !failed => lock(&self.timing).overflowed += 1,
                Err(TrySendError::Full(e)) => return self.hand_over(&tx, e),
                Ok(()) | Err(TrySendError::Disconnected(_)) => return,
            }
            k += 1;
        }
    }

    /// Hands an error to the reader once the queue has room (or the camera is stopped).
    fn hand_over(&self, tx: &SyncSender<Result<Frame>>, mut msg: Result<Frame>) {
        let period = Duration::from_secs_f64(1.0 / self.latency.fps);
        while !self.stop.load(Ordering::Relaxed) {
            match tx.try_send(msg) {
                Err(TrySendError::Full(m)) => {
                    msg = m;
                    std::thread::sleep(period);
                }
                _ => return,
            }
        }
    }

    /// Whether exposure `k` is dropped.
    fn dropped(&self, k: u64) -> bool {
        let r = self.latency.drop_rate;
        let h = mix64(self.seed ^ mix64(k ^ 0xd409_0000_0000_0001));
        r > 0.0 && ((h >> 11) as f64 / (1u64 << 53) as f64) < r
    }

    /// The image of the exposure at `t`: the frame presented at least the delay before it,
    /// through the simulator.
    fn expose(&mut self, t: Instant) -> Result<crate::raster::CamImage> {
        let start = Instant::now();
        let delay = Duration::from_secs_f64(self.latency.delay_frames as f64 / self.latency.fps);
        for k in 0..self.looks.len() {
            let shown = t.checked_sub(delay).and_then(|when| (self.looks[k])(when));
            if let Some(s) = shown
                && self.seen[k] != Some(s.index)
            {
                self.outputs[k].show(&s.image).map_err(|e| {
                    Error::Failed(format!(
                        "the virtual camera cannot look at the presented frame: {e}"
                    ))
                })?;
                self.seen[k] = Some(s.index);
                let lag = t.saturating_duration_since(s.at).as_secs_f64() * 1e3;
                let mut tm = lock(&self.timing);
                tm.lag_ms_min = if tm.changes == 0 {
                    lag
                } else {
                    tm.lag_ms_min.min(lag)
                };
                tm.lag_ms_max = tm.lag_ms_max.max(lag);
                tm.changes += 1;
            }
        }
        let image = self.rig.grab()?.image;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let mut tm = lock(&self.timing);
        let n = (tm.delivered + tm.overflowed) as f64;
        tm.render_ms_mean = (tm.render_ms_mean * n + ms) / (n + 1.0);
        Ok(image)
    }
}

impl FrameSource for WindowCamera {
    fn size(&self) -> ImageSize {
        self.size
    }

    /// The private rig's: a factor of the scene's exposure.
    fn exposure(&self) -> Option<ExposureRange> {
        self.rig.exposure()
    }

    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        self.rig.set_exposure(value)
    }

    fn grab(&mut self) -> Result<Frame> {
        match self.frames.recv_timeout(self.timeout) {
            Ok(frame) => frame,
            Err(RecvTimeoutError::Timeout) => Err(Error::Failed(format!(
                "the virtual camera delivered no frame within {:.1} s",
                self.timeout.as_secs_f64()
            ))),
            Err(RecvTimeoutError::Disconnected) => Err(Error::Failed(
                "the virtual camera stopped (its thread ended)".into(),
            )),
        }
    }
}

impl Drop for WindowCamera {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            // The thread never blocks for longer than a frame period, so this returns soon.
            let _ = t.join();
        }
    }
}
