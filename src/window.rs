//! The projector window: borderless fullscreen on the projector's monitor, cursor hidden, vsync
//! (FIFO presentation), showing projector frames pixel for pixel.
//!
//! Frames reach the screen without a CPU round trip: the compensation pass writes its projector
//! frame into a GPU texture and [`ProjectorWindow::present`] draws that texture onto the
//! window's surface (one fullscreen triangle, `shaders/blit.wgsl`, textureLoad per pixel, a
//! non-sRGB surface format, so the bytes on screen are the frame's bytes). The window is also a
//! [`DisplaySink`] (for the capture protocol): `show` uploads a CPU image and presents it.
//!
//! The window is a [`Screen`] of the playback loop ([`crate::player`]): the loop pumps
//! its events ([`ProjectorWindow::pump`]) before each refresh and presents the pass's output at
//! the monitor's vsync. Under Xvfb (no window manager) a fullscreen request keeps the default
//! size, so the window is also placed at the monitor's origin and sized to the monitor
//! explicitly.
//!
//! `show` honours the refresh rate itself: it presents at most once per refresh period, since a
//! display without vsync (Xvfb) presents at once. With [`ProjectorWindow::record_presented`] the
//! window reads back every frame it presents, with the moment it was presented, into a
//! [`PresentLog`]: what a camera looking at the projection could see.

mod blit;
mod record;
mod set;

use std::sync::Arc;
use std::time::{Duration, Instant};

use winit::application::ApplicationHandler;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::monitor::MonitorHandle;
use winit::platform::pump_events::{EventLoopExtPumpEvents, PumpStatus};
use winit::window::{Fullscreen, Window, WindowId};

use crate::device::DisplaySink;
use crate::error::{Error, Result};
use crate::gpu::{CompensationPass, FRAME_FORMAT, GpuContext};
use crate::player::{Refresh, Screen, Show};
use crate::raster::{ImageSize, PrjImage};
use blit::{Blit, Fit};
use record::{Pacer, Pending, Recorder};
pub use record::{PresentLog, Presented, ShowTiming};
pub use set::{ProjectorWindows, SetPresents, WindowOutput};

/// How long the window system may take to open the window.
const OPEN_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the window may take to reach the monitor's size.
const RESIZE_TIMEOUT: Duration = Duration::from_secs(2);
/// Refreshes `show` tries before it gives up on a surface that skips them (occluded, resized).
const SHOW_TRIES: usize = 10;

/// The window system's side: the monitors asked for, one window per monitor once open.
#[derive(Default)]
struct App {
    /// One entry per window: the monitor's name or index (None = primary).
    monitors: Vec<Option<String>>,
    windows: Vec<Arc<Window>>,
    chosen: Vec<MonitorHandle>,
    error: Option<Error>,
    closed: bool,
}

fn describe_monitor(i: usize, m: &MonitorHandle) -> String {
    let (s, p) = (m.size(), m.position());
    format!(
        "{i}: {} {}x{}+{}+{}",
        m.name().unwrap_or_else(|| "(unnamed)".into()),
        s.width,
        s.height,
        p.x,
        p.y
    )
}

/// The monitor `wanted` names (name or index; None = primary). `who` says whose monitor it is
/// in the error ("" for the one projector).
fn pick_monitor(el: &ActiveEventLoop, wanted: Option<&str>, who: &str) -> Result<MonitorHandle> {
    let all: Vec<MonitorHandle> = el.available_monitors().collect();
    let found = match wanted {
        None => el.primary_monitor().or_else(|| all.first().cloned()),
        Some(w) => match w.parse::<usize>() {
            Ok(i) => all.get(i).cloned(),
            Err(_) => all
                .iter()
                .find(|m| m.name().is_some_and(|n| n.eq_ignore_ascii_case(w)))
                .cloned(),
        },
    };
    found.ok_or_else(|| {
        let list: Vec<String> = all
            .iter()
            .enumerate()
            .map(|(i, m)| describe_monitor(i, m))
            .collect();
        Error::Input(format!(
            "--monitor {}: no such monitor{who} (monitors: {})",
            wanted.unwrap_or("(primary)"),
            if list.is_empty() {
                "none".into()
            } else {
                list.join("; ")
            }
        ))
    })
}

impl App {
    /// Every window's monitor, checked: each there, none named twice.
    fn pick_monitors(&self, el: &ActiveEventLoop) -> Result<Vec<MonitorHandle>> {
        let many = self.monitors.len() > 1;
        let mut picked: Vec<MonitorHandle> = Vec::with_capacity(self.monitors.len());
        for (k, wanted) in self.monitors.iter().enumerate() {
            let who = if many {
                format!(" for projector {k}")
            } else {
                String::new()
            };
            let m = pick_monitor(el, wanted.as_deref(), &who)?;
            if let Some(j) = picked.iter().position(|p| *p == m) {
                return Err(Error::Input(format!(
                    "--monitor: projectors {j} and {k} both name monitor {}: each projector of a \
                     set needs its own monitor",
                    m.name().unwrap_or_else(|| format!("{:?}", wanted))
                )));
            }
            picked.push(m);
        }
        Ok(picked)
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if !self.windows.is_empty() || self.error.is_some() {
            return;
        }
        let monitors = match self.pick_monitors(el) {
            Ok(m) => m,
            Err(e) => {
                self.error = Some(e);
                return;
            }
        };
        for monitor in monitors {
            let attrs = Window::default_attributes()
                .with_title("compend")
                .with_decorations(false)
                .with_position(monitor.position())
                .with_inner_size(monitor.size())
                .with_fullscreen(Some(Fullscreen::Borderless(Some(monitor.clone()))));
            match el.create_window(attrs) {
                Ok(w) => {
                    w.set_cursor_visible(false);
                    self.windows.push(Arc::new(w));
                    self.chosen.push(monitor);
                }
                Err(e) => {
                    self.error = Some(Error::Failed(format!(
                        "cannot open the projector window on monitor {}: {}",
                        monitor.name().unwrap_or_else(|| "(unnamed)".into()),
                        winit_words(&e)
                    )));
                    return;
                }
            }
        }
    }

    fn window_event(&mut self, _el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => self.closed = true,
            WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key: Key::Named(NamedKey::Escape),
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => self.closed = true,
            _ => {}
        }
    }
}

/// The surface configuration for presenting exact bytes at vsync: a non-sRGB 8-bit format (the
/// frame holds projector input values already), FIFO presentation, `size` in pixels.
fn surface_config(
    caps: &wgpu::SurfaceCapabilities,
    size: winit::dpi::PhysicalSize<u32>,
) -> Result<wgpu::SurfaceConfiguration> {
    let format = [
        wgpu::TextureFormat::Bgra8Unorm,
        wgpu::TextureFormat::Rgba8Unorm,
    ]
    .into_iter()
    .find(|f| caps.formats.contains(f))
    .or_else(|| caps.formats.iter().copied().find(|f| !f.is_srgb()))
    .or_else(|| caps.formats.first().copied())
    .ok_or_else(|| Error::Failed("the projector window's surface has no formats".into()))?;
    Ok(wgpu::SurfaceConfiguration {
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        format,
        width: size.width.max(1),
        height: size.height.max(1),
        present_mode: wgpu::PresentMode::Fifo,
        desired_maximum_frame_latency: 2,
        alpha_mode: caps
            .alpha_modes
            .first()
            .copied()
            .unwrap_or(wgpu::CompositeAlphaMode::Auto),
        view_formats: vec![],
        color_space: wgpu::SurfaceColorSpace::Auto,
    })
}

/// An event loop with one window open on each of `monitors` (name or index; None = primary),
/// each sized to its monitor (waiting briefly for that), with the chosen monitors.
type Opened = (EventLoop<()>, App, Vec<(Arc<Window>, MonitorHandle)>);

fn open_windows(monitors: &[Option<&str>]) -> Result<Opened> {
    let mut builder = EventLoop::builder();
    #[cfg(all(unix, not(target_os = "macos"), not(target_os = "android")))]
    {
        use winit::platform::x11::EventLoopBuilderExtX11;
        builder.with_any_thread(true);
    }
    let mut event_loop = builder.build().map_err(|e| {
        Error::Failed(format!(
            "no display for the projector window: {}",
            winit_words(&e)
        ))
    })?;
    let mut app = App {
        monitors: monitors.iter().map(|m| m.map(str::to_string)).collect(),
        ..App::default()
    };
    let start = Instant::now();
    loop {
        if let Some(e) = app.error.take() {
            return Err(e);
        }
        if !app.windows.is_empty() && app.windows.len() == monitors.len() {
            break;
        }
        if let PumpStatus::Exit(code) =
            event_loop.pump_app_events(Some(Duration::from_millis(10)), &mut app)
        {
            return Err(Error::Failed(format!(
                "the window system closed the event loop ({code})"
            )));
        }
        if start.elapsed() > OPEN_TIMEOUT {
            return Err(Error::Failed(format!(
                "the projector window did not open within {} s",
                OPEN_TIMEOUT.as_secs()
            )));
        }
    }
    let start = Instant::now();
    while app
        .windows
        .iter()
        .zip(&app.chosen)
        .any(|(w, m)| w.inner_size() != m.size())
        && start.elapsed() < RESIZE_TIMEOUT
    {
        let _ = event_loop.pump_app_events(Some(Duration::from_millis(10)), &mut app);
    }
    let opened = app
        .windows
        .iter()
        .cloned()
        .zip(app.chosen.iter().cloned())
        .collect();
    Ok((event_loop, app, opened))
}

/// A monitor's refresh rate, Hz (60 when it does not say).
fn refresh_of(m: &MonitorHandle) -> f64 {
    m.refresh_rate_millihertz()
        .filter(|&m| m > 0)
        .map_or(60.0, |m| m as f64 / 1000.0)
}

/// The surface texture to draw the next frame into; None when this refresh is skipped (window
/// occluded, surface timed out, surface reconfigured after a resize).
fn next_target(
    surface: &wgpu::Surface<'static>,
    config: &mut wgpu::SurfaceConfiguration,
    window: &Window,
    device: &wgpu::Device,
) -> Result<Option<wgpu::SurfaceTexture>> {
    match surface.get_current_texture() {
        wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
            Ok(Some(t))
        }
        wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => Ok(None),
        wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
            let size = window.inner_size();
            config.width = size.width.max(1);
            config.height = size.height.max(1);
            surface.configure(device, config);
            Ok(None)
        }
        wgpu::CurrentSurfaceTexture::Validation => Err(Error::Failed(
            "presenting to the projector window failed validation".into(),
        )),
    }
}

/// The projector window with its GPU context.
pub struct ProjectorWindow {
    event_loop: EventLoop<()>,
    app: App,
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    ctx: GpuContext,
    blit: Blit,
    /// Texture for [`DisplaySink::show`].
    upload: Option<wgpu::Texture>,
    refresh_hz: f64,
    /// Usages the surface allows (a read-back needs `COPY_SRC`).
    surface_usages: wgpu::TextureUsages,
    /// Reads back every presented frame, once asked to.
    recorder: Option<Recorder>,
    /// Keeps `show` to the refresh rate.
    pacer: Pacer,
    timing: ShowTiming,
}

impl ProjectorWindow {
    /// Opens the window on `monitor` (name or index; None = primary) and a GPU device that can
    /// present to it.
    pub fn open(monitor: Option<&str>) -> Result<Self> {
        let (event_loop, app, mut opened) = open_windows(&[monitor])?;
        let (window, chosen) = opened.remove(0);
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| Error::gpu("cannot draw into the projector window", e))?;
        let ctx = GpuContext::with_instance(instance, Some(&surface))?;
        let caps = surface.get_capabilities(&ctx.adapter);
        let config = surface_config(&caps, window.inner_size())?;
        surface.configure(&ctx.device, &config);
        let blit = Blit::new(&ctx, config.format, Fit::Exact)?;
        let refresh_hz = refresh_of(&chosen);
        Ok(Self {
            event_loop,
            app,
            window,
            surface,
            config,
            ctx,
            blit,
            upload: None,
            refresh_hz,
            surface_usages: caps.usages,
            recorder: None,
            pacer: Pacer::new(refresh_hz),
            timing: ShowTiming::default(),
        })
    }

    /// Reads back every frame presented from now on into the returned log, which keeps what
    /// the screen showed over the last `keep` (shared with the log's clones). The read-back
    /// waits for the GPU after each present.
    pub fn record_presented(&mut self, keep: Duration) -> PresentLog {
        if let Some(r) = &self.recorder {
            return r.log.clone();
        }
        let log = PresentLog::new(keep);
        let r = Recorder::new(log.clone(), self.config.format, self.surface_usages);
        if r.surface_usage() != self.config.usage {
            self.config.usage = r.surface_usage();
            self.surface.configure(&self.ctx.device, &self.config);
        }
        self.recorder = Some(r);
        log
    }

    /// A virtual camera looking at this window: it sees what the window really presented
    /// (read back from now on) through `scene`'s surface and camera, with its latency (the
    /// scene's projector must be the window's size); texture and noise seed `seed`.
    pub fn watched_by(
        &mut self,
        scene: &crate::rig::scene::Scene,
        seed: u64,
    ) -> Result<crate::rig::window_camera::WindowCamera> {
        let log = self.record_presented(camera_lookback(scene));
        let look = move |t| {
            log.at(t).map(|p| crate::rig::window_camera::Shown {
                index: p.index,
                at: p.at,
                image: p.image,
            })
        };
        crate::rig::window_camera::WindowCamera::start(scene, seed, look)
    }

    /// Timing of [`DisplaySink::show`] so far.
    pub fn show_timing(&self) -> ShowTiming {
        self.timing.clone()
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The monitor's refresh rate, Hz (60 when it does not say).
    pub fn refresh_hz(&self) -> f64 {
        self.refresh_hz
    }

    /// Handles pending window events; false once the window was closed or Escape pressed.
    pub fn pump(&mut self) -> bool {
        if let PumpStatus::Exit(_) = self
            .event_loop
            .pump_app_events(Some(Duration::ZERO), &mut self.app)
        {
            self.app.closed = true;
        }
        !self.app.closed
    }

    /// The surface texture to draw the next frame into; None when this refresh is skipped.
    fn next_target(&mut self) -> Result<Option<wgpu::SurfaceTexture>> {
        next_target(
            &self.surface,
            &mut self.config,
            &self.window,
            &self.ctx.device,
        )
    }

    /// Presents `frame` (a projector frame texture, e.g. [`CompensationPass::output`]) at the
    /// next vsync; blocks while the presentation queue is full. Returns false when the frame was
    /// skipped (window occluded, surface timed out).
    pub fn present_texture(&mut self, frame: &wgpu::Texture) -> Result<bool> {
        let Some(target) = self.next_target()? else {
            return Ok(false);
        };
        let view = target
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let mut enc = self.ctx.encoder("present");
        self.blit.draw(&self.ctx, &mut enc, frame, &view);
        let pending: Option<Pending> = self
            .recorder
            .as_mut()
            .and_then(|r| r.copy(&self.ctx, &mut enc, &target.texture, frame));
        self.ctx.queue.submit([enc.finish()]);
        self.window.pre_present_notify();
        self.ctx.queue.present(target);
        let at = Instant::now();
        if let (Some(r), Some(p)) = (self.recorder.as_mut(), pending) {
            r.finish(&self.ctx, p, at, &mut self.timing)?;
        }
        Ok(true)
    }

    /// The texture [`DisplaySink::show`] uploads into, made on first use.
    fn upload_texture(&mut self) -> wgpu::Texture {
        let ImageSize {
            width: w,
            height: h,
        } = DisplaySink::size(self);
        self.upload
            .get_or_insert_with(|| frame_texture(&self.ctx, w as u32, h as u32))
            .clone()
    }
}

/// Writes `frame` (projector pixels, the texture's size) into `tex` as 8-bit RGBA.
fn write_frame(ctx: &GpuContext, tex: &wgpu::Texture, frame: &PrjImage) {
    let rgba = crate::pngio::to_rgba8(frame);
    ctx.queue.write_texture(
        tex.as_image_copy(),
        &rgba,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(tex.width() * 4),
            rows_per_image: Some(tex.height()),
        },
        tex.size(),
    );
}

/// How far back a virtual camera watching the windows looks: the scene's delay, and a quarter
/// second more for a camera rendering late (one that falls further behind skips the exposures
/// it missed).
fn camera_lookback(scene: &crate::rig::scene::Scene) -> Duration {
    let l = &scene.latency;
    Duration::from_secs_f64(0.25 + (l.delay_frames as f64 + 4.0) / l.fps)
}

/// A projector frame texture of `w`×`h` ([`FRAME_FORMAT`]) that `show` writes, the blit draws
/// and a recorder can read back.
fn frame_texture(ctx: &GpuContext, w: u32, h: u32) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("shown frame"),
        size: wgpu::Extent3d {
            width: w.max(1),
            height: h.max(1),
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: FRAME_FORMAT,
        usage: wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_DST
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

impl DisplaySink for ProjectorWindow {
    fn size(&self) -> ImageSize {
        ImageSize::new(self.config.width as usize, self.config.height as usize)
    }

    fn show(&mut self, frame: &PrjImage) -> Result<()> {
        let ImageSize {
            width: w,
            height: h,
        } = DisplaySink::size(self);
        if frame.size() != ImageSize::new(w, h) {
            return Err(Error::Shape(format!(
                "projector window is {w}x{h}, got a {}x{} frame",
                frame.width(),
                frame.height()
            )));
        }
        let tex = self.upload_texture();
        write_frame(&self.ctx, &tex, frame);
        if !self.pump() {
            return Err(Error::Failed(
                "the projector window was closed (Escape or the window system)".into(),
            ));
        }
        self.timing.shows += 1;
        for _ in 0..SHOW_TRIES {
            self.timing.waited_s += self.pacer.wait().as_secs_f64();
            let presented = self.present_texture(&tex)?;
            let since = self.pacer.presented(Instant::now());
            if presented {
                if let Some(d) = since {
                    self.timing.interval(d);
                }
                return Ok(());
            }
            // The surface skipped this refresh: try at the next one.
            self.timing.skipped += 1;
            self.pump();
        }
        Err(Error::Failed(format!(
            "the projector window presented nothing in {SHOW_TRIES} refreshes (is it hidden or \
             minimised?)"
        )))
    }
}

/// The window in the playback loop: events pumped before each refresh, the pass's output
/// presented at the monitor's vsync, a still image kept on screen until the window is closed.
impl Screen for ProjectorWindow {
    fn context(&self) -> &GpuContext {
        &self.ctx
    }

    fn refresh(&self) -> Refresh {
        Refresh::Vsync(self.refresh_hz)
    }

    fn keep_going(&mut self) -> bool {
        self.pump()
    }

    /// The frame presented is scanned out at the next vertical sync: one refresh later.
    fn display_delay(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(1.0 / self.refresh_hz)
    }

    fn present(&mut self, pass: &CompensationPass, show: Show) -> Result<()> {
        self.present_texture(pass.output())?;
        if let Show::New { index: 1, .. } = show {
            eprintln!("play: first frame presented");
        }
        Ok(())
    }
}

/// A winit error in words for the operator: winit's OS errors say where in winit's own source
/// they were raised (`os error at /…/winit-0.30.13/src/….rs:765: …`), which helps no one
/// setting up a projector; that place is left out.
fn winit_words(e: &dyn std::fmt::Display) -> String {
    let text = e.to_string();
    if let Some(rest) = text.strip_prefix("os error at ")
        && let Some(i) = rest.find(".rs:")
        && let Some(j) = rest[i + 4..].find(": ")
    {
        return rest[i + 4 + j + 2..].to_string();
    }
    text
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_winit_error_leaves_out_where_in_winit_it_was_raised() {
        let e = "os error at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/\
                 winit-0.30.13/src/platform_impl/linux/mod.rs:765: neither WAYLAND_DISPLAY nor \
                 WAYLAND_SOCKET nor DISPLAY is set.";
        assert_eq!(
            super::winit_words(&e),
            "neither WAYLAND_DISPLAY nor WAYLAND_SOCKET nor DISPLAY is set."
        );
        assert_eq!(super::winit_words(&"a plain error"), "a plain error");
    }
}
