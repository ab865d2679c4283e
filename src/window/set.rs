//! The windows of a set of projectors: one borderless fullscreen window per projector, each on
//! its own monitor, all on one event loop and one GPU device. Each refresh takes every
//! surface's next texture first, draws every projector's image (its network lattice, stretched
//! over its monitor by the bilinear blit) in one submission, then presents them one after
//! another, so that every output shows the same source frame in the same refresh.
//! [`SetPresents`] counts what each output presented and any refresh where one output
//! presented and another did not (an output a frame behind): the measurement of that promise.
//!
//! For calibration each output is also a [`DisplaySink`] of its own ([`WindowOutput`], a
//! handle on the shared windows): showing a projector image on one output presents every
//! output, the others keeping what they showed. With [`ProjectorWindows::record_presented`]
//! every output's presented frames are read back, for a virtual camera looking at the set.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use winit::event_loop::EventLoop;
use winit::platform::pump_events::{EventLoopExtPumpEvents, PumpStatus};
use winit::window::Window;

use super::blit::{Blit, Fit};
use super::record::{Pacer, Pending, PresentLog, Recorder, ShowTiming};
use super::{App, SHOW_TRIES, next_target, open_windows, refresh_of, surface_config};
use crate::device::DisplaySink;
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::gpu::joint::SetPass;
use crate::player::{Refresh, Screen, Show};
use crate::raster::{ImageSize, PrjImage};

/// Refresh rates (Hz) that differ by more than this cannot keep outputs in step.
const REFRESH_TOLERANCE_HZ: f64 = 0.5;

/// One projector's window.
struct Output {
    window: Arc<Window>,
    /// The monitor's name (or index) as the operator knows it.
    monitor: String,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    blit: Blit,
    /// Usages the surface allows (a read-back needs `COPY_SRC`).
    surface_usages: wgpu::TextureUsages,
    /// What [`ProjectorWindows::show`] last put on this output (black at first), its size.
    shown: wgpu::Texture,
    /// Reads back every presented frame, once asked to.
    recorder: Option<Recorder>,
}

/// What the outputs of a set presented so far.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct SetPresents {
    /// Frames presented, per output (in the set's order).
    pub presented: Vec<u64>,
    /// Refreshes in which every output presented.
    pub together: u64,
    /// Refreshes in which some output presented and another skipped: that output was a frame
    /// behind the others until its next present.
    pub out_of_step: u64,
    /// The longest time from the first output's present to the last one's in one refresh, ms
    /// (wall clock of the presenting thread; a display's scan-out adds its own).
    pub skew_ms_max: f64,
}

/// One fullscreen window per projector of a set on one GPU device (see the module
/// documentation).
pub struct ProjectorWindows {
    event_loop: EventLoop<()>,
    app: App,
    outputs: Vec<Output>,
    ctx: GpuContext,
    refresh_hz: f64,
    pacer: Pacer,
    presents: SetPresents,
    timing: ShowTiming,
}

impl ProjectorWindows {
    /// Opens one window on each of `monitors` (names or indices, one per projector, in the
    /// set's order) and a GPU device that presents to all of them. A monitor that is not there
    /// or named twice is an input error naming it; monitors whose refresh rates differ too.
    pub fn open(monitors: &[&str]) -> Result<Self> {
        if monitors.is_empty() {
            return Err(Error::Input(
                "--monitor: a set of projectors needs one monitor per projector".into(),
            ));
        }
        let wanted: Vec<Option<&str>> = monitors.iter().map(|m| Some(*m)).collect();
        let (event_loop, app, opened) = open_windows(&wanted)?;
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let mut surfaces = Vec::with_capacity(opened.len());
        for ((window, _), name) in opened.iter().zip(monitors) {
            surfaces.push(instance.create_surface(window.clone()).map_err(|e| {
                Error::gpu(format!("cannot draw into the window on monitor {name}"), e)
            })?);
        }
        let ctx = GpuContext::with_instance(instance, surfaces.first())?;
        let rates: Vec<f64> = opened.iter().map(|(_, m)| refresh_of(m)).collect();
        let (lo, hi) = rates
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        if hi - lo > REFRESH_TOLERANCE_HZ {
            let list: Vec<String> = monitors
                .iter()
                .zip(&rates)
                .map(|(m, r)| format!("{m} at {r:.2} Hz"))
                .collect();
            return Err(Error::Input(format!(
                "--monitor: the monitors refresh at different rates ({}): a set's outputs show \
                 each frame in the same refresh only at one rate; set them alike (xrandr \
                 --rate)",
                list.join(", ")
            )));
        }
        let mut outputs = Vec::with_capacity(opened.len());
        for ((surface, (window, _)), name) in surfaces.into_iter().zip(opened).zip(monitors) {
            if !ctx.adapter.is_surface_supported(&surface) {
                return Err(Error::Failed(format!(
                    "the GPU adapter {} cannot present to the window on monitor {name}: a set's \
                     monitors must hang off one GPU",
                    ctx.describe()
                )));
            }
            let caps = surface.get_capabilities(&ctx.adapter);
            let config = surface_config(&caps, window.inner_size())?;
            surface.configure(&ctx.device, &config);
            let blit = Blit::new(&ctx, config.format, Fit::Stretch)?;
            let shown = black_texture(&ctx, config.width, config.height);
            outputs.push(Output {
                window,
                monitor: name.to_string(),
                surface,
                config,
                blit,
                surface_usages: caps.usages,
                shown,
                recorder: None,
            });
        }
        let refresh_hz = rates[0];
        let n = outputs.len();
        Ok(Self {
            event_loop,
            app,
            outputs,
            ctx,
            refresh_hz,
            pacer: Pacer::new(refresh_hz),
            presents: SetPresents {
                presented: vec![0; n],
                ..SetPresents::default()
            },
            timing: ShowTiming::default(),
        })
    }

    /// Reads back every frame each output presents from now on; returns one log per output,
    /// each keeping what its screen showed over the last `keep`.
    pub fn record_presented(&mut self, keep: Duration) -> Vec<PresentLog> {
        let mut logs = Vec::with_capacity(self.outputs.len());
        for o in &mut self.outputs {
            if let Some(r) = &o.recorder {
                logs.push(r.log.clone());
                continue;
            }
            let log = PresentLog::new(keep);
            let r = Recorder::new(log.clone(), o.config.format, o.surface_usages);
            if r.surface_usage() != o.config.usage {
                o.config.usage = r.surface_usage();
                o.surface.configure(&self.ctx.device, &o.config);
            }
            o.recorder = Some(r);
            logs.push(log);
        }
        logs
    }

    /// A virtual camera looking at the set's windows: it sees what every window really
    /// presented (read back from now on) through `scene`'s surface and camera, the set's
    /// projectors in window order, with its latency (the scene's projectors must be the
    /// windows' size); texture and noise seed `seed`.
    pub fn watched_by(
        &mut self,
        scene: &crate::rig::scene::Scene,
        seed: u64,
    ) -> Result<crate::rig::window_camera::WindowCamera> {
        let looks = self
            .record_presented(super::camera_lookback(scene))
            .into_iter()
            .map(|log| {
                move |t| {
                    log.at(t).map(|p| crate::rig::window_camera::Shown {
                        index: p.index,
                        at: p.at,
                        image: p.image,
                    })
                }
            })
            .collect();
        crate::rig::window_camera::WindowCamera::start_set(scene, seed, looks)
    }

    /// Timing of the shows so far ([`WindowOutput`]'s [`DisplaySink::show`]).
    pub fn show_timing(&self) -> ShowTiming {
        self.timing.clone()
    }

    /// Puts `frame` (projector pixels, the output's size) on output `k` and presents every
    /// output, the others showing what they showed, at most once per refresh period; a
    /// refresh an output skipped is tried again, up to a few times.
    pub fn show(&mut self, k: usize, frame: &PrjImage) -> Result<()> {
        let Some(o) = self.outputs.get(k) else {
            return Err(Error::Shape(format!(
                "a set of {} windows has no output {k}",
                self.outputs.len()
            )));
        };
        let (w, h) = (o.config.width as usize, o.config.height as usize);
        if frame.size() != ImageSize::new(w, h) {
            return Err(Error::Shape(format!(
                "the window on monitor {} is {w}x{h}, got a {}x{} frame",
                o.monitor,
                frame.width(),
                frame.height()
            )));
        }
        if o.shown.width() as usize != w || o.shown.height() as usize != h {
            let t = black_texture(&self.ctx, w as u32, h as u32);
            self.outputs[k].shown = t;
        }
        super::write_frame(&self.ctx, &self.outputs[k].shown, frame);
        if !self.pump() {
            return Err(Error::Failed(
                "a projector window was closed (Escape or the window system)".into(),
            ));
        }
        self.timing.shows += 1;
        let frames: Vec<wgpu::Texture> = self.outputs.iter().map(|o| o.shown.clone()).collect();
        let frames: Vec<&wgpu::Texture> = frames.iter().collect();
        for _ in 0..SHOW_TRIES {
            if self.present(&frames)? {
                return Ok(());
            }
            self.timing.skipped += 1;
            self.pump();
        }
        Err(Error::Failed(format!(
            "the projector windows presented nothing on every output in {SHOW_TRIES} refreshes \
             (is one hidden or minimised?)"
        )))
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The windows' sizes in pixels, in the set's order.
    pub fn sizes(&self) -> Vec<ImageSize> {
        self.outputs
            .iter()
            .map(|o| ImageSize::new(o.config.width as usize, o.config.height as usize))
            .collect()
    }

    /// The monitors, as named on the command line, in the set's order.
    pub fn monitors(&self) -> Vec<String> {
        self.outputs.iter().map(|o| o.monitor.clone()).collect()
    }

    /// The monitors' common refresh rate, Hz.
    pub fn refresh_hz(&self) -> f64 {
        self.refresh_hz
    }

    /// What the outputs presented so far.
    pub fn presents(&self) -> &SetPresents {
        &self.presents
    }

    /// Handles pending window events; false once a window was closed or Escape pressed.
    pub fn pump(&mut self) -> bool {
        if let PumpStatus::Exit(_) = self
            .event_loop
            .pump_app_events(Some(std::time::Duration::ZERO), &mut self.app)
        {
            self.app.closed = true;
        }
        !self.app.closed
    }

    /// Presents `frames[k]` (projector `k`'s image: any size, stretched over its monitor) on
    /// output `k`, all in this refresh, at most once per refresh period. Returns whether every
    /// output presented.
    pub fn present(&mut self, frames: &[&wgpu::Texture]) -> Result<bool> {
        if frames.len() != self.outputs.len() {
            return Err(Error::Shape(format!(
                "{} frames for a set of {} windows",
                frames.len(),
                self.outputs.len()
            )));
        }
        self.pacer.wait();
        let mut targets = Vec::with_capacity(self.outputs.len());
        for o in &mut self.outputs {
            targets.push(next_target(
                &o.surface,
                &mut o.config,
                &o.window,
                &self.ctx.device,
            )?);
        }
        let mut enc = self.ctx.encoder("present a set");
        let mut pending: Vec<Option<Pending>> = Vec::with_capacity(self.outputs.len());
        for ((o, target), frame) in self.outputs.iter_mut().zip(&targets).zip(frames) {
            let mut copy = None;
            if let Some(t) = target {
                let view = t
                    .texture
                    .create_view(&wgpu::TextureViewDescriptor::default());
                o.blit.draw(&self.ctx, &mut enc, frame, &view);
                copy = o
                    .recorder
                    .as_mut()
                    .and_then(|r| r.copy(&self.ctx, &mut enc, &t.texture, frame));
            }
            pending.push(copy);
        }
        self.ctx.queue.submit([enc.finish()]);
        let mut first: Option<Instant> = None;
        let mut last = Instant::now();
        let mut presented = 0;
        let mut at = vec![last; self.outputs.len()];
        for (k, (o, target)) in self.outputs.iter().zip(targets).enumerate() {
            if let Some(t) = target {
                o.window.pre_present_notify();
                self.ctx.queue.present(t);
                last = Instant::now();
                at[k] = last;
                first.get_or_insert(last);
                self.presents.presented[k] += 1;
                presented += 1;
            }
        }
        for ((o, p), when) in self.outputs.iter_mut().zip(pending).zip(at) {
            if let (Some(r), Some(p)) = (o.recorder.as_mut(), p) {
                r.finish(&self.ctx, p, when, &mut self.timing)?;
            }
        }
        if let Some(d) = self.pacer.presented(last) {
            self.timing.interval(d);
        }
        let all = presented == self.outputs.len();
        if all {
            self.presents.together += 1;
        } else if presented > 0 {
            self.presents.out_of_step += 1;
        }
        if let Some(f) = first {
            let skew = last.duration_since(f).as_secs_f64() * 1e3;
            self.presents.skew_ms_max = self.presents.skew_ms_max.max(skew);
        }
        Ok(all)
    }
}

/// A black projector frame texture of `w`×`h` ([`super::frame_texture`]).
fn black_texture(ctx: &GpuContext, w: u32, h: u32) -> wgpu::Texture {
    let t = super::frame_texture(ctx, w, h);
    let size = t.size();
    let black = PrjImage::new(size.width as usize, size.height as usize);
    super::write_frame(ctx, &t, &black);
    t
}

/// The set's windows in the playback loop: events pumped before each refresh, each projector's
/// image of the joint pass presented on its window in the same refresh, at the monitors' vsync.
impl Screen<SetPass> for ProjectorWindows {
    fn context(&self) -> &GpuContext {
        ProjectorWindows::context(self)
    }

    fn refresh(&self) -> Refresh {
        Refresh::Vsync(self.refresh_hz)
    }

    fn keep_going(&mut self) -> bool {
        self.pump()
    }

    /// Scanned out at the next vertical sync: one refresh later.
    fn display_delay(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.refresh_hz)
    }

    fn present(&mut self, pass: &SetPass, _show: Show) -> Result<()> {
        ProjectorWindows::present(self, &pass.outputs()).map(|_| ())
    }
}

/// One output of a set's windows as a display of its own (for calibrating a set projector by
/// projector): showing on it presents every output, the others unchanged.
pub struct WindowOutput {
    windows: Rc<RefCell<ProjectorWindows>>,
    k: usize,
}

impl ProjectorWindows {
    /// Each output as a display of its own, sharing these windows.
    pub fn outputs(windows: &Rc<RefCell<ProjectorWindows>>) -> Vec<WindowOutput> {
        (0..windows.borrow().outputs.len())
            .map(|k| WindowOutput {
                windows: windows.clone(),
                k,
            })
            .collect()
    }
}

impl DisplaySink for WindowOutput {
    fn size(&self) -> ImageSize {
        self.windows.borrow().sizes()[self.k]
    }

    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        self.windows.borrow_mut().show(self.k, frame)
    }
}
