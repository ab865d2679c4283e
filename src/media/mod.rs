//! GStreamer, the media stack compend plays and writes media through (shell): starting it once
//! per process, turning its errors into messages a person can act on ([`fault`]), watching a
//! pipeline's bus ([`Watch`]), choosing a sound output ([`audio`]), and a handle on a playing
//! source ([`Control`]). The video sources built on it live in [`crate::source::media`], the
//! outputs that send compensated frames to other software in [`crate::output`].
//!
//! Frames cross into and out of GStreamer as 8-bit RGBA, sRGB-encoded as stored (content pixels
//! on the way in, projector pixels on the way out); timestamps are GStreamer clock times in
//! nanoseconds.

pub mod audio;
pub mod fault;

use std::sync::OnceLock;
use std::time::Duration;

use gstreamer as gst;
use gstreamer::prelude::*;

pub use fault::{Fault, Watch};

use crate::error::{Error, Result};

/// Starts GStreamer once for the process (the plugin registry is scanned on the first start and
/// cached under `~/.cache/gstreamer-1.0`); later calls return the first outcome.
pub fn init() -> Result<()> {
    static STARTED: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    STARTED
        .get_or_init(|| gst::init().map_err(|e| e.to_string()))
        .clone()
        .map_err(|e| {
            Error::Failed(format!(
                "GStreamer did not start ({e}); install the packages in scripts/deps.sh \
                 (libgstreamer1.0-0, gstreamer1.0-plugins-base)"
            ))
        })
}

/// Whether an element of this name is installed (a plugin feature in the registry).
pub fn has_element(name: &str) -> bool {
    init().is_ok() && gst::ElementFactory::find(name).is_some()
}

/// Makes an element, naming the Debian package that brings it when it is missing.
pub fn make(factory: &str) -> Result<gst::Element> {
    init()?;
    gst::ElementFactory::make(factory).build().map_err(|_| {
        Error::Input(format!(
            "the GStreamer element {factory:?} is not installed{}",
            fault::package_of_element(factory)
                .map(|p| format!(": the Debian package {p} brings it"))
                .unwrap_or_default()
        ))
    })
}

/// A GStreamer clock time as a [`Duration`].
pub fn duration(t: gst::ClockTime) -> Duration {
    Duration::from_nanos(t.nseconds())
}

/// A [`Duration`] as a GStreamer clock time.
pub fn clock_time(d: Duration) -> gst::ClockTime {
    gst::ClockTime::from_nseconds(d.as_nanos().min(u64::MAX as u128) as u64)
}

/// How often [`set_state`] reads the bus while a pipeline prerolls.
const PREROLL_POLL: Duration = Duration::from_millis(50);

/// Sets `pipeline` to `state`, and for a target of PAUSED or PLAYING waits up to `timeout` for
/// it to get there (a file prerolls its first frame), reading its bus for the reason when it
/// does not. `what` names the media in messages. Returns whether the pipeline is live (its
/// source produces in real time and does not preroll: a camera, a screen, a network stream).
pub fn set_state(
    pipeline: &gst::Pipeline,
    state: gst::State,
    timeout: Duration,
    what: &str,
) -> Result<bool> {
    let changed = pipeline.set_state(state);
    let waited = match changed {
        // An element that fails while the pipeline prerolls (a demuxer that finds no stream
        // in a truncated file) posts its error and leaves the change pending: the bus is read
        // between short waits so that the error, not the timeout, is what is reported.
        Ok(gst::StateChangeSuccess::Async) => {
            let deadline = std::time::Instant::now() + timeout;
            let mut watch = Watch::new(pipeline, what);
            loop {
                let left = deadline.saturating_duration_since(std::time::Instant::now());
                let (r, _, _) = pipeline.state(clock_time(left.min(PREROLL_POLL)));
                if !matches!(r, Ok(gst::StateChangeSuccess::Async)) || left.is_zero() {
                    break r;
                }
                if let Some(f) = watch.poll() {
                    return Err(f.into_error());
                }
            }
        }
        other => other,
    };
    match waited {
        Ok(gst::StateChangeSuccess::Async) => Err(Error::Failed(format!(
            "{what}: not ready after {:.1} s (a stream that does not answer, or a source \
             that waits for data)",
            timeout.as_secs_f64()
        ))),
        Ok(gst::StateChangeSuccess::NoPreroll) => Ok(true),
        // There now: a live pipeline says so when its latency is asked.
        Ok(_) => {
            let mut q = gst::query::Latency::new();
            Ok(pipeline.query(&mut q) && q.result().0)
        }
        Err(_) => {
            // The bus says why; failing that, the state change alone. A resource that does not
            // open as it starts (a display or a host that is not there) is what the request
            // named: an input error.
            let watch = Watch::new(pipeline, what);
            Err(watch
                .first_error(Duration::from_millis(200))
                .map(|mut f| {
                    if f.transient {
                        f.input = true;
                    }
                    f.into_error()
                })
                .unwrap_or_else(|| {
                    Error::Failed(format!("{what}: GStreamer could not start it ({state:?})"))
                }))
        }
    }
}

/// Stops `pipeline` (NULL state: files closed, devices released). Errors are logged, not
/// returned: this runs on teardown.
pub fn stop(pipeline: &gst::Pipeline) {
    if let Err(e) = pipeline.set_state(gst::State::Null) {
        tracing::warn!("GStreamer: stopping a pipeline failed: {e}");
    }
}

/// Sets `ts-offset` (ns; positive delays rendering) on `e` and, in a bin, on every element
/// inside that has it (the sinks).
fn set_ts_offset(e: &gst::Element, offset: i64) {
    let has = |e: &gst::Element| {
        e.find_property("ts-offset")
            .is_some_and(|p| p.value_type() == i64::static_type())
    };
    if has(e) {
        e.set_property("ts-offset", offset);
    }
    if let Some(bin) = e.downcast_ref::<gst::Bin>() {
        for child in bin.iterate_recurse().into_iter().flatten() {
            if has(&child) {
                child.set_property("ts-offset", offset);
            }
        }
    }
}

/// What a media source reports while it plays (`status`, `play.json`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MediaStatus {
    /// Frames taken from the decoder.
    pub frames: u64,
    /// The stream's position, s (None before the first frame or where it has none).
    pub position_s: Option<f64>,
    /// The media's length, s (None for live streams and screens).
    pub duration_s: Option<f64>,
    /// The frame rate the media declares, frames per second (None: variable or unknown).
    pub fps: Option<f64>,
    /// The frame size (width, height), content pixels.
    pub size: Option<(usize, usize)>,
    /// Whether its sound is played.
    pub audio: bool,
    /// The delay given to the sound so that it meets the picture (measured picture latency plus
    /// the configured trim), ms.
    pub audio_delay_ms: f64,
    /// Warnings GStreamer posted (data a decoder skipped past).
    pub warnings: u64,
    /// Times a network stream was reconnected.
    pub reconnects: u64,
    /// Paused by a request.
    pub paused: bool,
    /// What went wrong last, in words (a stream that dropped, a damaged part of a file).
    pub last_problem: Option<String>,
    /// The playlist item playing, when the source is a playlist.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub item: Option<ItemStatus>,
}

/// Where a playlist is.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ItemStatus {
    /// The item playing, from 1.
    pub index: usize,
    /// Items in the playlist.
    pub count: usize,
    /// Its source, as configured.
    pub source: String,
    /// Its pass (from 1) when it is played several times in a row.
    pub pass: u32,
}

/// A handle on a playing media source, shared by its feed thread and whoever controls it (the
/// player, the service): pause, resume, seek, the sound's delay and the counts. Every call is
/// safe from any thread (GStreamer's state changes and seeks are).
#[derive(Clone, Default)]
pub struct Control {
    inner: std::sync::Arc<std::sync::Mutex<ControlInner>>,
}

#[derive(Default)]
struct ControlInner {
    pipeline: Option<gst::Pipeline>,
    /// The sinks of the sound branch, whose `ts-offset` delays the sound.
    audio_sinks: Vec<gst::Element>,
    /// The configured trim of the sound's delay, ns (may be negative).
    trim_ns: i64,
    /// The picture's measured latency, ns.
    picture_ns: i64,
    /// Items a playlist was asked to move by (next: +1, previous: −1), not yet done.
    skip: i64,
    status: MediaStatus,
}

impl Control {
    fn lock(&self) -> std::sync::MutexGuard<'_, ControlInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The pipeline now playing (None between a dropped stream and its reconnection).
    pub fn attach(&self, pipeline: Option<gst::Pipeline>, audio_sinks: Vec<gst::Element>) {
        let mut c = self.lock();
        c.pipeline = pipeline;
        c.audio_sinks = audio_sinks;
        Self::apply_delay(&mut c);
    }

    /// The pipeline playing now, if any (for benchmarks that read its elements).
    pub fn pipeline(&self) -> Option<gst::Pipeline> {
        self.lock().pipeline.clone()
    }

    /// Updates the counts.
    pub fn update(&self, f: impl FnOnce(&mut MediaStatus)) {
        f(&mut self.lock().status);
    }

    /// The counts; the position is the last frame's delivered (a paused or ended film keeps
    /// it), the length as the media declared it.
    pub fn status(&self) -> MediaStatus {
        self.lock().status.clone()
    }

    /// The configured trim of the sound's delay (`[audio] delay_ms`), ms.
    pub fn set_trim(&self, ms: f64) {
        let mut c = self.lock();
        c.trim_ns = (ms * 1e6) as i64;
        Self::apply_delay(&mut c);
    }

    /// The picture's measured latency from the decoder's release of a frame to its presentation
    /// (the sound is delayed by as much, plus the trim).
    pub fn set_picture_latency(&self, latency: Duration) {
        let mut c = self.lock();
        c.picture_ns = latency.as_nanos().min(i64::MAX as u128) as i64;
        Self::apply_delay(&mut c);
    }

    fn apply_delay(c: &mut ControlInner) {
        let offset = c.trim_ns + c.picture_ns;
        for e in &c.audio_sinks {
            set_ts_offset(e, offset);
        }
        c.status.audio_delay_ms = offset as f64 / 1e6;
    }

    /// Asks a playlist to move by `delta` items (the feed's thread does it at its next frame);
    /// an error for a source that is not a playlist.
    pub fn skip(&self, delta: i64) -> Result<()> {
        let mut c = self.lock();
        if c.status.item.is_none() {
            return Err(Error::Input(
                "next/previous: the source playing is not a playlist ([playback] source with \
                 several items)"
                    .into(),
            ));
        }
        c.skip += delta;
        Ok(())
    }

    /// The move a playlist was asked for since the last call (0: none).
    pub fn take_skip(&self) -> i64 {
        std::mem::take(&mut self.lock().skip)
    }

    /// Pauses the media where it is (a live stream keeps running at its source).
    pub fn pause(&self) -> Result<()> {
        self.set(gst::State::Paused)?;
        self.update(|s| s.paused = true);
        Ok(())
    }

    /// Resumes paused media.
    pub fn resume(&self) -> Result<()> {
        self.set(gst::State::Playing)?;
        self.update(|s| s.paused = false);
        Ok(())
    }

    fn set(&self, state: gst::State) -> Result<()> {
        let p = self.lock().pipeline.clone();
        let p = p.ok_or_else(|| Error::Failed("the media is not playing now".into()))?;
        p.set_state(state).map(|_| ()).map_err(|e| Error::Media {
            message: format!("the media could not change to {state:?}"),
            input: false,
            source: Some(Box::new(e)),
        })
    }

    /// Seeks to `to` from the start (to the key frame before it: fast, and the picture
    /// continues from there); media that cannot seek (a live stream) says so.
    pub fn seek(&self, to: Duration) -> Result<()> {
        let p = self.lock().pipeline.clone();
        let p = p.ok_or_else(|| Error::Failed("the media is not playing now".into()))?;
        if let Some(d) = p.query_duration::<gst::ClockTime>()
            && clock_time(to) > d
        {
            return Err(Error::Input(format!(
                "seek to {:.3} s: the media is {:.3} s long",
                to.as_secs_f64(),
                d.nseconds() as f64 / 1e9
            )));
        }
        p.seek_simple(
            gst::SeekFlags::FLUSH | gst::SeekFlags::KEY_UNIT,
            clock_time(to),
        )
        .map_err(|_| {
            Error::Input(format!(
                "seek to {:.3} s: this media cannot seek (a live stream or a screen)",
                to.as_secs_f64()
            ))
        })
    }
}
