//! What the projector window really presented: each presented frame read back from the GPU
//! (the surface texture the blit drew into, when the surface allows copies; otherwise the frame
//! texture it drew from), stamped with the moment `present` returned, and kept for a while in a
//! [`PresentLog`] that another thread (a camera looking at the window) reads. Also the timing of
//! [`crate::device::DisplaySink::show`] on the window ([`ShowTiming`]).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::raster::PrjImage;

/// A frame the window presented.
#[derive(Clone, Debug)]
pub struct Presented {
    /// Number of the present, from 1, counting every present of the window while recording.
    pub index: u64,
    /// When `present` returned: the frame was handed to the window system. Under Xvfb it is on
    /// the screen then; a display with vsync shows it at one of the next refreshes (FIFO, at
    /// most two frames queued).
    pub at: Instant,
    /// The presented pixels as read back, projector pixels, 8-bit levels.
    pub image: Arc<PrjImage>,
}

/// The frames the window presented lately, shared with readers on other threads. Clones share
/// one log.
#[derive(Clone, Debug)]
pub struct PresentLog {
    frames: Arc<Mutex<Frames>>,
    /// How far back a reader may look: older frames are forgotten, except the newest of them.
    keep: Duration,
}

#[derive(Debug, Default)]
struct Frames {
    list: VecDeque<Presented>,
    /// Whether older frames were forgotten.
    forgot: bool,
}

impl PresentLog {
    pub(super) fn new(keep: Duration) -> Self {
        Self {
            frames: Arc::new(Mutex::new(Frames::default())),
            keep,
        }
    }

    fn frames(&self) -> MutexGuard<'_, Frames> {
        // Every update is one push or pop, so a poisoned lock still holds a consistent log.
        self.frames.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The last frame presented at or before `t`: what the screen showed at `t`. None before
    /// the first present (the screen is black); the oldest frame kept when `t` lies further back
    /// than the log keeps.
    pub fn at(&self, t: Instant) -> Option<Presented> {
        let frames = self.frames();
        let found = frames.list.iter().rev().find(|p| p.at <= t);
        match found {
            Some(p) => Some(p.clone()),
            None if frames.forgot => frames.list.front().cloned(),
            None => None,
        }
    }

    /// The newest frame presented.
    pub fn latest(&self) -> Option<Presented> {
        self.frames().list.back().cloned()
    }

    fn push(&self, p: Presented) {
        let mut frames = self.frames();
        let horizon = p.at.checked_sub(self.keep);
        frames.list.push_back(p);
        // Forget a frame once the frame after it was presented before the horizon: no reader
        // looking back at most `keep` can see it any more.
        while let Some(h) = horizon
            && frames.list.len() > 1
            && frames.list[1].at <= h
        {
            frames.list.pop_front();
            frames.forgot = true;
        }
    }
}

/// Timing of `show` on the window.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ShowTiming {
    /// Calls of `show`, and refreshes it had to retry because the surface skipped them.
    pub shows: u64,
    pub skipped: u64,
    /// Time `show` waited for the next refresh slot (the refresh rate honoured by the window
    /// itself, since a display without vsync presents at once), s.
    pub waited_s: f64,
    /// Shortest and longest time between two refreshes `show` used (presented or skipped), ms.
    pub interval_ms_min: f64,
    pub interval_ms_max: f64,
    /// Mean and worst time of the read-back after a present, ms (recording only).
    pub readback_ms_mean: f64,
    pub readback_ms_max: f64,
    /// Frames recorded in the [`PresentLog`].
    pub recorded: u64,
}

impl ShowTiming {
    pub(super) fn interval(&mut self, d: Duration) {
        let ms = d.as_secs_f64() * 1e3;
        if self.interval_ms_min == 0.0 || ms < self.interval_ms_min {
            self.interval_ms_min = ms;
        }
        self.interval_ms_max = self.interval_ms_max.max(ms);
    }

    fn readback(&mut self, d: Duration) {
        let ms = d.as_secs_f64() * 1e3;
        let n = self.recorded as f64;
        self.readback_ms_mean = (self.readback_ms_mean * n + ms) / (n + 1.0);
        self.readback_ms_max = self.readback_ms_max.max(ms);
        self.recorded += 1;
    }
}

/// Keeps `show` to one present per refresh period, as a display with vsync would.
#[derive(Debug)]
pub(super) struct Pacer {
    period: Duration,
    last: Option<Instant>,
}

impl Pacer {
    /// A pacer for a display refreshing at `hz`, Hz.
    pub(super) fn new(hz: f64) -> Self {
        Self {
            period: Duration::from_secs_f64(1.0 / hz),
            last: None,
        }
    }

    /// Sleeps until one period after the last present; returns how long it slept.
    pub(super) fn wait(&mut self) -> Duration {
        let Some(last) = self.last else {
            return Duration::ZERO;
        };
        let wait = (last + self.period).saturating_duration_since(Instant::now());
        if !wait.is_zero() {
            std::thread::sleep(wait);
        }
        wait
    }

    /// Notes a present (or a refresh the surface skipped) at `at`; returns the time since the
    /// previous one.
    pub(super) fn presented(&mut self, at: Instant) -> Option<Duration> {
        self.last
            .replace(at)
            .map(|prev| at.saturating_duration_since(prev))
    }
}

/// Where the read-back comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Source {
    /// The surface texture, in its 8-bit format: blue first (`Bgra8Unorm`) or red first.
    Surface { bgra: bool },
    /// The frame texture the blit drew from ([`crate::gpu::FRAME_FORMAT`], red first).
    Frame,
}

/// Reads back every presented frame into a [`PresentLog`].
pub(super) struct Recorder {
    pub(super) log: PresentLog,
    source: Source,
    staging: Option<(wgpu::Buffer, u64)>,
    count: u64,
    warned: bool,
}

/// A copy recorded before a present, to finish after it.
pub(super) struct Pending {
    buffer: wgpu::Buffer,
    width: u32,
    height: u32,
    padded: u32,
}

impl Recorder {
    /// A recorder for a surface of `format` that allows `usages`; the surface must then be
    /// configured with [`Recorder::surface_usage`].
    pub(super) fn new(
        log: PresentLog,
        format: wgpu::TextureFormat,
        usages: wgpu::TextureUsages,
    ) -> Self {
        let copyable = usages.contains(wgpu::TextureUsages::COPY_SRC);
        let source = match format {
            wgpu::TextureFormat::Bgra8Unorm if copyable => Source::Surface { bgra: true },
            wgpu::TextureFormat::Rgba8Unorm if copyable => Source::Surface { bgra: false },
            _ => Source::Frame,
        };
        Self {
            log,
            source,
            staging: None,
            count: 0,
            warned: false,
        }
    }

    /// The usage the surface needs for this recorder.
    pub(super) fn surface_usage(&self) -> wgpu::TextureUsages {
        match self.source {
            Source::Surface { .. } => {
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC
            }
            Source::Frame => wgpu::TextureUsages::RENDER_ATTACHMENT,
        }
    }

    /// Records copying what is presented (`surface`, drawn from `frame`) into a staging
    /// buffer; None when neither texture can be copied (warned once).
    pub(super) fn copy(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        surface: &wgpu::Texture,
        frame: &wgpu::Texture,
    ) -> Option<Pending> {
        let texture = match self.source {
            Source::Surface { .. } => surface,
            Source::Frame if frame.usage().contains(wgpu::TextureUsages::COPY_SRC) => frame,
            Source::Frame => {
                if !std::mem::replace(&mut self.warned, true) {
                    tracing::warn!("the presented frame cannot be read back: it is not recorded");
                }
                return None;
            }
        };
        let (width, height) = (texture.width(), texture.height());
        let padded = (width * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let size = u64::from(padded) * u64::from(height);
        let buffer = match &self.staging {
            Some((b, s)) if *s == size => b.clone(),
            _ => {
                let b = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("presented frame"),
                    size,
                    usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                    mapped_at_creation: false,
                });
                self.staging = Some((b.clone(), size));
                b
            }
        };
        enc.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(height),
                },
            },
            texture.size(),
        );
        Some(Pending {
            buffer,
            width,
            height,
            padded,
        })
    }

    /// Reads the copy back once the GPU is done and logs it as presented at `at`.
    pub(super) fn finish(
        &mut self,
        ctx: &GpuContext,
        pending: Pending,
        at: Instant,
        timing: &mut ShowTiming,
    ) -> Result<()> {
        let start = Instant::now();
        let Pending {
            buffer,
            width,
            height,
            padded,
        } = pending;
        let bgra = self.source == Source::Surface { bgra: true };
        let (w, h) = (width as usize, height as usize);
        let data = ctx.map_read(&buffer, |view| {
            let mut out = Vec::with_capacity(w * h * 3);
            for row in view.chunks_exact(padded as usize).take(h) {
                for px in row[..w * 4].chunks_exact(4) {
                    let rgb = if bgra {
                        [px[2], px[1], px[0]]
                    } else {
                        [px[0], px[1], px[2]]
                    };
                    out.extend(rgb.map(|b| f32::from(b) / 255.0));
                }
            }
            Ok(out)
        })?;
        let image = PrjImage::from_vec(w, h, data)
            .map_err(|e| Error::Failed(format!("reading back the presented frame: {e}")))?;
        self.count += 1;
        self.log.push(Presented {
            index: self.count,
            at,
            image: Arc::new(image),
        });
        timing.readback(start.elapsed());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(index: u64, at: Instant) -> Presented {
        Presented {
            index,
            at,
            image: Arc::new(PrjImage::new(2, 2)),
        }
    }

    #[test]
    fn the_pacer_presents_at_most_once_per_refresh_period() {
        let mut pacer = Pacer::new(100.0);
        let start = Instant::now();
        for _ in 0..5 {
            pacer.wait();
            pacer.presented(Instant::now());
        }
        // Four waits of a 10 ms period after the first present.
        let took = start.elapsed();
        assert!(took >= Duration::from_millis(40), "{took:?}");
        assert!(pacer.presented(Instant::now()).is_some());
    }

    #[test]
    fn the_log_answers_what_the_screen_showed_and_forgets_old_frames() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let log = PresentLog::new(ms(100));
        assert!(log.at(t0 + ms(5)).is_none());
        log.push(frame(1, t0 + ms(10)));
        log.push(frame(2, t0 + ms(50)));
        assert!(log.at(t0 + ms(5)).is_none());
        assert_eq!(log.at(t0 + ms(10)).map(|p| p.index), Some(1));
        assert_eq!(log.at(t0 + ms(49)).map(|p| p.index), Some(1));
        assert_eq!(log.at(t0 + ms(60)).map(|p| p.index), Some(2));
        // Frame 3 at 200 ms: frame 2 is still what the screen showed at the horizon (100 ms).
        log.push(frame(3, t0 + ms(200)));
        // Further back than the log keeps: the oldest frame kept.
        assert_eq!(log.at(t0 + ms(20)).map(|p| p.index), Some(2));
        assert_eq!(log.at(t0 + ms(120)).map(|p| p.index), Some(2));
        log.push(frame(4, t0 + ms(400)));
        assert_eq!(log.frames().list.len(), 2);
        assert_eq!(log.latest().map(|p| p.index), Some(4));
    }
}
