//! The windows of a set of projectors: one borderless fullscreen window per projector, each on
//! its own monitor, all on one event loop and one GPU device. Each refresh takes every
//! surface's next texture first, draws every projector's image (its network lattice, stretched
//! over its monitor by the bilinear blit) in one submission, then presents them one after
//! another, so that every output shows the same source frame in the same refresh.
//! [`SetPresents`] counts what each output presented and any refresh where one output
//! presented and another did not (an output a frame behind): the measurement of that promise.

use std::sync::Arc;
use std::time::Instant;

use winit::event_loop::EventLoop;
use winit::platform::pump_events::{EventLoopExtPumpEvents, PumpStatus};
use winit::window::Window;

use super::blit::{Blit, Fit};
use super::record::Pacer;
use super::{App, next_target, open_windows, refresh_of, surface_config};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::raster::ImageSize;

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
            outputs.push(Output {
                window,
                monitor: name.to_string(),
                surface,
                config,
                blit,
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
        })
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
        for ((o, target), frame) in self.outputs.iter_mut().zip(&targets).zip(frames) {
            if let Some(t) = target {
                let view = t
                    .texture
                    .create_view(&wgpu::TextureViewDescriptor::default());
                o.blit.draw(&self.ctx, &mut enc, frame, &view);
            }
        }
        self.ctx.queue.submit([enc.finish()]);
        let mut first: Option<Instant> = None;
        let mut last = Instant::now();
        let mut presented = 0;
        for (k, (o, target)) in self.outputs.iter().zip(targets).enumerate() {
            if let Some(t) = target {
                o.window.pre_present_notify();
                self.ctx.queue.present(t);
                last = Instant::now();
                first.get_or_insert(last);
                self.presents.presented[k] += 1;
                presented += 1;
            }
        }
        self.pacer.presented(last);
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
