//! The virtual rig as devices: a projector ([`DisplaySink`]) and a camera ([`FrameSource`])
//! with realistic timing, so the capture protocol's synchronisation is really exercised.
//!
//! Timing model (virtual clock, one tick per camera frame period 1/fps):
//! - the camera exposes frame k at time k/fps and delivers it `delay_frames` periods later;
//!   each exposure is dropped with probability `drop_rate` (decided by hashing the seed and k,
//!   so the same seed drops the same frames), and a dropped frame's sequence number is skipped;
//! - [`FrameSource::grab`] returns the next exposure that was not dropped;
//! - [`DisplaySink::show`] takes effect for exposures after the moment of the call, which is the
//!   delivery time of the last grabbed frame: with a delay of d frames, the next d exposures
//!   were already taken and still show the previous image.
//!
//! A scene with several projectors ([`crate::rig::scene::Scene::more_projectors`]) gives a rig
//! with one output per projector ([`VirtualRig::output`]), all seen by the one camera: each
//! output's shows follow the rule above on its own, and an exposure sees the sum of what every
//! output shows at that moment ([`super::SetSimulator`]'s light model: the room's light once,
//! noise and clipping on the sum). The rig itself is output 0.
//!
//! On a wall clock ([`VirtualRig::on_wall_clock`], what `calibrate --rig virtual` uses by
//! default) exposure k is delivered no earlier than (k + delay) / fps seconds after the rig
//! started, as a real camera's would be; a reader that falls behind finds only the last
//! [`CAMERA_BUFFERS`] exposures waiting (older ones were overwritten, their sequence numbers
//! skipped), and a show takes effect from the first exposure that starts after it. Exposure k's
//! picture is simulated as soon as it is asked for, but not before the exposure starts, and
//! delivered at its due time, so the simulation's time (tens of milliseconds on a busy 2-core
//! machine) does not add to the camera's delay unless it exceeds what is left of it. Without the wall clock (tests, the fit's benches) frames come as fast
//! as they are simulated.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::physics::{Phase, SetSimulator, Simulator, mix64};
use super::scene::{Latency, Scene};
use crate::device::{DisplaySink, Frame, FrameSource};
use crate::error::{Error, Result};
use crate::raster::{CamImage, ImageSize, PrjImage};

/// Range of the virtual camera's manual exposure, factors of the scene's exposure.
const MIN_EXPOSURE: f64 = 1.0 / 16.0;
const MAX_EXPOSURE: f64 = 4.0;

/// Exposures a camera on the wall clock keeps for a reader that falls behind (a V4L2 camera's
/// buffers; compend's V4L2 camera asks for 4).
pub const CAMERA_BUFFERS: u64 = 4;

/// A simulated projector-camera pair. Clones share one rig: give one clone to the code that
/// projects and another to the code that captures.
#[derive(Clone, Debug)]
pub struct VirtualRig {
    inner: Arc<Mutex<State>>,
}

/// One projector of a rig (of a set, [`VirtualRig::output`]) as a display. Clones share the rig.
#[derive(Clone, Debug)]
pub struct VirtualOutput {
    rig: VirtualRig,
    index: usize,
}

#[derive(Debug)]
struct Shown {
    /// First exposure index that sees this image.
    from: u64,
    image: Arc<PrjImage>,
    /// Noise-free sensor signal of this output's light alone (no room light), computed on first
    /// capture, with the phase it was made for.
    signal: Option<(Phase, Arc<Vec<f32>>)>,
}

#[derive(Debug)]
struct State {
    scene: Scene,
    seed: u64,
    /// Output 0's projector, at its calibration pose and after drift.
    calibrated: Arc<Simulator>,
    drifted: Option<Arc<Simulator>>,
    /// The projectors of outputs 1.. (a set's; they do not drift).
    others: Vec<Arc<Simulator>>,
    phase: Phase,
    latency: Latency,
    /// What each output shows and will show, output 0 first.
    shows: Vec<VecDeque<Shown>>,
    /// Next exposure index that may be delivered.
    next: u64,
    /// Manual exposure: a factor of the scene's camera exposure (1 = as the scene says).
    exposure: f64,
    /// When exposure 0 started, on a wall clock ([`VirtualRig::on_wall_clock`]).
    epoch: Option<Instant>,
    /// On the wall clock, the threads that simulate the camera's exposures: its own, as a real
    /// camera's are its own hardware, so a fit or a writer busy on rayon's global threads does
    /// not hold back the frames (the reader would fall behind, and the latency measured and
    /// every capture's wait would grow with this machine's load instead of the rig's delay).
    camera_threads: Option<Arc<rayon::ThreadPool>>,
}

impl VirtualRig {
    /// A rig for `scene` with seed `seed` (texture, noise and frame drops), projectors at their
    /// calibration pose, showing black: one output per projector of the scene.
    pub fn new(scene: &Scene, seed: u64) -> Result<Self> {
        if scene.more_projectors.is_empty() {
            let sim = Simulator::new(scene, seed, Phase::Calibration)?;
            return Ok(Self::from_simulator(sim));
        }
        let set = SetSimulator::new(scene, seed, Phase::Calibration)?;
        Ok(Self::from_set(set))
    }

    /// A rig around a prepared simulator (its phase is the rig's starting phase).
    pub fn from_simulator(sim: Simulator) -> Self {
        let scene = sim.scene().clone();
        Self::from_parts(scene, sim, Vec::new())
    }

    /// A rig around a prepared set of projectors: one output per projector, the scene's first
    /// (output 0, the rig's own display) the only one that drifts.
    pub fn from_set(set: SetSimulator) -> Self {
        let (scene, mut sims) = set.into_parts();
        let first = sims.remove(0);
        Self::from_parts(scene, first, sims)
    }

    fn from_parts(scene: Scene, sim: Simulator, others: Vec<Simulator>) -> Self {
        let phase = sim.phase();
        let seed = sim.seed();
        let sim = Arc::new(sim);
        let others: Vec<Arc<Simulator>> = others.into_iter().map(Arc::new).collect();
        let shows = std::iter::once(&sim)
            .chain(&others)
            .map(|s| {
                let ImageSize { width, height } = s.projector_size();
                VecDeque::from([Shown {
                    from: 0,
                    image: Arc::new(PrjImage::new(width, height)),
                    signal: None,
                }])
            })
            .collect();
        let (calibrated, drifted) = match phase {
            Phase::Calibration => (sim, None),
            Phase::AfterDrift => (sim.clone(), Some(sim)),
        };
        VirtualRig {
            inner: Arc::new(Mutex::new(State {
                latency: scene.latency.clone(),
                scene,
                seed,
                calibrated,
                drifted,
                others,
                phase,
                shows,
                next: 0,
                exposure: 1.0,
                epoch: None,
                camera_threads: None,
            })),
        }
    }

    /// The same rig with its camera on the wall clock: frames no faster than the scene's frame
    /// rate, counted from now (see the module documentation).
    pub fn on_wall_clock(self) -> Self {
        let threads = camera_threads();
        let mut st = self.state();
        st.epoch = Some(Instant::now());
        st.camera_threads = threads;
        drop(st);
        self
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock leaves the state consistent (every update is a
        // single assignment or push), so a poisoned lock is still usable.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// On the wall clock, sleeps (the state unlocked) until `exposures` frame periods after
    /// exposure 0 started; at once otherwise. Returns the state locked again.
    fn wait_for<'s>(&'s self, st: MutexGuard<'s, State>, exposures: f64) -> MutexGuard<'s, State> {
        let Some(epoch) = st.epoch else { return st };
        if st.exposures_now().is_some_and(|now| now >= exposures) {
            return st;
        }
        let at = epoch + Duration::from_secs_f64(exposures / st.latency.fps);
        drop(st);
        std::thread::sleep(at.saturating_duration_since(Instant::now()));
        self.state()
    }

    /// The simulator of the current phase (for scoring and oracles): output 0's projector.
    pub fn simulator(&self) -> Arc<Simulator> {
        let st = self.state();
        st.current()
    }

    /// How many projectors the rig has (1 unless its scene is a set).
    pub fn outputs(&self) -> usize {
        self.state().shows.len()
    }

    /// Projector `k` (0: the scene's first) as a display; an input error naming the scene past
    /// its last projector.
    pub fn output(&self, k: usize) -> Result<VirtualOutput> {
        let st = self.state();
        if k >= st.shows.len() {
            return Err(Error::Input(format!(
                "scene {:?} has {} projector(s), not a projector {}",
                st.scene.name,
                st.shows.len(),
                k + 1
            )));
        }
        drop(st);
        Ok(VirtualOutput {
            rig: self.clone(),
            index: k,
        })
    }

    /// Moves the projector to its drifted pose ([`Phase::AfterDrift`], as after a bump) or back.
    /// Later exposures see the new geometry. Scenes without drift are unchanged by it.
    pub fn set_phase(&self, phase: Phase) -> Result<()> {
        let mut st = self.state();
        if phase == Phase::AfterDrift && st.drifted.is_none() {
            let first = st.scene.alone(0).unwrap_or_else(|| st.scene.clone());
            let sim = Simulator::new(&first, st.seed, Phase::AfterDrift)?;
            st.drifted = Some(Arc::new(sim));
        }
        st.phase = phase;
        Ok(())
    }

    /// Changes the camera timing from the next grab on.
    pub fn set_latency(&self, latency: Latency) -> Result<()> {
        let ok =
            latency.fps.is_finite() && latency.fps > 0.0 && (0.0..0.9).contains(&latency.drop_rate);
        if !ok {
            return Err(Error::Input(format!(
                "virtual camera latency needs fps > 0 and drop_rate in [0, 0.9), got {latency:?}"
            )));
        }
        self.state().latency = latency;
        Ok(())
    }

    pub fn latency(&self) -> Latency {
        self.state().latency.clone()
    }
}

/// The wall-clock camera's own threads (as many as the machine has cores, at most 4); `None`,
/// with a warning, when they cannot be started: the camera then shares rayon's global threads.
fn camera_threads() -> Option<Arc<rayon::ThreadPool>> {
    let n = std::thread::available_parallelism().map_or(2, |n| n.get().min(4));
    match rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .thread_name(|i| format!("virtual camera {i}"))
        .build()
    {
        Ok(pool) => Some(Arc::new(pool)),
        Err(e) => {
            tracing::warn!(
                "the virtual camera's threads did not start ({e}); it shares the machine's"
            );
            None
        }
    }
}

impl State {
    fn current(&self) -> Arc<Simulator> {
        match (self.phase, &self.drifted) {
            (Phase::AfterDrift, Some(d)) => d.clone(),
            _ => self.calibrated.clone(),
        }
    }

    /// Output `k`'s projector in the current phase.
    fn projector(&self, k: usize) -> Arc<Simulator> {
        match k {
            0 => self.current(),
            k => self.others[k - 1].clone(),
        }
    }

    /// Output `k` shows `frame` from the first exposure it can reach (see the module
    /// documentation).
    fn show(&mut self, k: usize, frame: &PrjImage) -> Result<()> {
        let expected = self.projector(k).projector_size();
        if frame.size() != expected {
            let which = if self.shows.len() > 1 {
                format!("virtual projector {}", k + 1)
            } else {
                "virtual projector".into()
            };
            return Err(Error::Shape(format!(
                "{which} is {expected}, got a {}x{} frame",
                frame.width(),
                frame.height()
            )));
        }
        let mut from = self.next + self.latency.delay_frames as u64;
        if let Some(now) = self.exposures_now() {
            // The first exposure that starts after now.
            from = from.max(now.ceil() as u64);
        }
        let shows = &mut self.shows[k];
        while shows.len() > 1 && shows.back().is_some_and(|s| s.from >= from) {
            shows.pop_back();
        }
        if shows.back().is_some_and(|s| s.from >= from) {
            // Only the initial entry is left and it starts no earlier: replace it.
            shows.clear();
        }
        shows.push_back(Shown {
            from,
            image: Arc::new(frame.clone()),
            signal: None,
        });
        Ok(())
    }

    /// The noise-free sensor signal of exposure `k`: every output's light as shown then, plus
    /// the room's once. Forgets what no exposure from `k` on can see.
    fn signal_at(&mut self, k: u64) -> Result<Vec<f32>> {
        let phase = self.phase;
        let mut sum: Option<Vec<f32>> = None;
        for o in 0..self.shows.len() {
            let sim = self.projector(o);
            let shows = &mut self.shows[o];
            while shows.len() > 1 && shows[1].from <= k {
                shows.pop_front();
            }
            let shown = shows.front_mut().ok_or_else(|| {
                Error::Failed(format!("virtual projector {} shows nothing", o + 1))
            })?;
            let signal = match &shown.signal {
                Some((p, s)) if *p == phase || o > 0 => s.clone(),
                _ => {
                    sim.check_prj(&shown.image)?;
                    let s = Arc::new(sim.sensor(&sim.emission(&shown.image)));
                    shown.signal = Some((phase, s.clone()));
                    s
                }
            };
            match &mut sum {
                None => sum = Some(signal.as_ref().clone()),
                Some(acc) => acc.iter_mut().zip(signal.iter()).for_each(|(a, b)| *a += b),
            }
        }
        let mut s = sum.unwrap_or_default();
        // The room's light (ambient, glare) once, whatever the projectors show.
        self.current().add_constant(&mut s);
        Ok(s)
    }

    /// On the wall clock: exposures (fractional) since exposure 0 started.
    fn exposures_now(&self) -> Option<f64> {
        self.epoch
            .map(|e| e.elapsed().as_secs_f64() * self.latency.fps)
    }

    fn dropped(&self, k: u64) -> bool {
        let r = self.latency.drop_rate;
        if r <= 0.0 {
            return false;
        }
        let h = mix64(self.seed ^ mix64(k ^ 0xd409_0000_0000_0001));
        ((h >> 11) as f64 / (1u64 << 53) as f64) < r
    }
}

impl DisplaySink for VirtualRig {
    fn size(&self) -> ImageSize {
        self.state().calibrated.projector_size()
    }

    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        self.state().show(0, frame)
    }
}

impl DisplaySink for VirtualOutput {
    fn size(&self) -> ImageSize {
        self.rig.state().projector(self.index).projector_size()
    }

    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        self.rig.state().show(self.index, frame)
    }
}

impl FrameSource for VirtualRig {
    fn size(&self) -> ImageSize {
        self.state().calibrated.camera_size()
    }

    /// A factor of the scene's exposure, from 1/16 to 4.
    fn exposure(&self) -> Option<crate::device::ExposureRange> {
        Some(crate::device::ExposureRange {
            value: self.state().exposure,
            min: MIN_EXPOSURE,
            max: MAX_EXPOSURE,
        })
    }

    fn set_exposure(&mut self, value: f64) -> Result<f64> {
        if !value.is_finite() {
            return Err(Error::Input(format!(
                "virtual camera exposure {value}: expected a factor of the scene's exposure"
            )));
        }
        let accepted = value.clamp(MIN_EXPOSURE, MAX_EXPOSURE);
        self.state().exposure = accepted;
        Ok(accepted)
    }

    fn grab(&mut self) -> Result<Frame> {
        let mut st = self.state();
        let mut k = st.next;
        let delay = st.latency.delay_frames as u64;
        if let Some(now) = st.exposures_now() {
            // Delivered by now: exposures up to now − delay; the buffers hold the last few.
            let delivered = (now.floor() as u64).saturating_sub(delay);
            k = k.max(delivered.saturating_sub(CAMERA_BUFFERS - 1));
        }
        while st.dropped(k) {
            k += 1;
        }
        st.next = k + 1;
        // On the wall clock the picture of exposure k is made once the exposure has started
        // (no later show reaches it: [`State::show`]) and delivered at its due time, as a real
        // camera's readout is: the time this machine takes to simulate it is hidden in the
        // delay instead of adding to it, unless it takes longer than the delay.
        st = self.wait_for(st, k as f64);
        let expose = |st: &mut State| -> Result<CamImage> {
            let signal = st.signal_at(k)?;
            Ok(st
                .current()
                .finish_exposed(&signal, st.exposure as f32, Some(k)))
        };
        let image = match st.camera_threads.clone() {
            Some(threads) => {
                let st: &mut State = &mut st;
                threads.install(|| expose(st))?
            }
            None => expose(&mut st)?,
        };
        let st = self.wait_for(st, (k + delay) as f64);
        let timestamp = Duration::from_secs_f64(k as f64 / st.latency.fps);
        Ok(Frame {
            image,
            seq: k,
            timestamp,
        })
    }
}
