//! Media decoded by GStreamer as a video source: video files with their sound, network streams,
//! other programs' screens and any GStreamer pipeline ([`MediaSpec`]).
//!
//! - Files and URIs play through `playbin`: demuxing, decoding (any installed decoder, hardware
//!   ones included), the sound to an audio sink, seeking. Screens and `gst:` pipelines are parsed
//!   pipelines that end in compend's sink.
//! - Frames leave GStreamer through an `appsink` as 8-bit RGBA (content pixels, sRGB-encoded as
//!   stored). In live pacing the sink is synchronised to the pipeline's clock, so a frame leaves
//!   at its presentation time (the sound's clock when there is sound) and the display's refresh
//!   takes the newest: a 24 fps film on a 60 Hz display gets the usual 3:2 cadence, with no drift
//!   because both follow one clock. Offline, frames leave as fast as they decode and none is
//!   lost.
//! - The sound is delayed by the picture's measured latency (set through [`Control`] by the
//!   player) plus the configured trim, on the audio sink's `ts-offset`.
//! - Errors are GStreamer's in words ([`crate::media::fault`]). Before the first frame an error
//!   fails the source; after it, a network stream, a screen or any live pipeline that drops
//!   (an error, or the end of a live stream) is reconnected with backoff (1 s doubling to 30 s,
//!   the last frame held meanwhile), and a damaged or truncated file ends where it stops
//!   decoding, the problem reported.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use gstreamer_video as gst_video;
use gstreamer_video::prelude::*;

use super::spec::{MediaSpec, ScreenSpec};
use super::{Next, VideoSource};
use crate::error::{Error, Result};
use crate::media::{self, Control, Watch};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// Where the sound goes.
#[derive(Clone, Debug, PartialEq)]
pub struct AudioOut {
    /// A GStreamer audio sink description (`alsasink device=hw:1`, `pulsesink device=...`)
    /// or `auto` ([`media::audio`]); None: no sound.
    pub sink: Option<String>,
    /// A trim added to the measured picture latency, ms (negative: the sound earlier).
    pub delay_ms: f64,
}

impl Default for AudioOut {
    fn default() -> Self {
        Self {
            sink: Some(media::audio::AUTO.into()),
            delay_ms: 0.0,
        }
    }
}

/// How long a source may take to show it works (preroll its first frame), by kind.
fn start_timeout(spec: &MediaSpec) -> Duration {
    match spec {
        MediaSpec::File(_) => Duration::from_secs(10),
        _ => Duration::from_secs(20),
    }
}

/// The first wait before reconnecting a dropped stream; it doubles up to [`BACKOFF_MAX`].
const BACKOFF_START: Duration = Duration::from_secs(1);
const BACKOFF_MAX: Duration = Duration::from_secs(30);
/// How long one `next` waits for a frame before it lets the feed look for a stop.
const PULL_SLICE: Duration = Duration::from_millis(100);

/// A running pipeline.
struct Stream {
    pipeline: gst::Pipeline,
    sink: gst_app::AppSink,
    watch: Watch,
}

impl Drop for Stream {
    fn drop(&mut self) {
        media::stop(&self.pipeline);
    }
}

/// Media decoded by GStreamer.
pub struct MediaSource {
    spec: MediaSpec,
    describe: String,
    audio: AudioOut,
    live: bool,
    stream: Option<Stream>,
    control: Control,
    /// Frames delivered.
    frames: u64,
    /// When a dropped stream is tried again, and the wait after that.
    retry: Option<(Instant, Duration)>,
    /// The pipeline is live (it did not preroll: a camera, a screen, a network stream).
    live_source: bool,
}

impl MediaSource {
    /// A source for `spec`, checked as far as can be without starting it (a file must be a
    /// readable regular file, the elements it needs installed). GStreamer starts in
    /// [`VideoSource::prepare`], on the feed's thread.
    pub fn new(spec: &MediaSpec, audio: AudioOut) -> Result<Self> {
        Self::with_control(spec, audio, Control::default())
    }

    /// [`MediaSource::new`] reporting through `control` (a playlist's, shared by its items).
    pub fn with_control(spec: &MediaSpec, audio: AudioOut, control: Control) -> Result<Self> {
        media::init()?;
        check_static(spec)?;
        control.set_trim(audio.delay_ms);
        Ok(Self {
            describe: describe(spec),
            spec: spec.clone(),
            audio,
            live: true,
            stream: None,
            control,
            frames: 0,
            retry: None,
            live_source: false,
        })
    }

    /// Builds and starts the pipeline, waiting for its first frame to be ready.
    fn start(&mut self) -> Result<()> {
        let (pipeline, sink, audio_sinks) = build(&self.spec, &self.audio, self.live)?;
        let watch = Watch::new(&pipeline, &self.describe);
        let stream = Stream {
            pipeline,
            sink,
            watch,
        };
        // A file is never live (a pipeline of one may answer the latency query as live when
        // its sinks are synchronised); other sources say so themselves.
        let live = media::set_state(
            &stream.pipeline,
            gst::State::Playing,
            start_timeout(&self.spec),
            &self.describe,
        )?;
        // A film over HTTP or a file URI ends like a file.
        let film = match &self.spec {
            MediaSpec::File(_) => true,
            MediaSpec::Uri(u) => ["http://", "https://", "file://"]
                .iter()
                .any(|p| u.to_ascii_lowercase().starts_with(p)),
            _ => false,
        };
        self.live_source = live && !film;
        self.control
            .attach(Some(stream.pipeline.clone()), audio_sinks.clone());
        let duration = stream
            .pipeline
            .query_duration::<gst::ClockTime>()
            .map(|t| t.nseconds() as f64 / 1e9);
        // playbin knows how many sound streams the media has; a film without one plays
        // silently.
        let streams = if stream.pipeline.find_property("n-audio").is_some() {
            stream.pipeline.property::<i32>("n-audio")
        } else {
            0
        };
        let audio = !audio_sinks.is_empty() && streams > 0;
        self.control.update(|s| {
            s.audio = audio;
            s.duration_s = duration;
        });
        self.stream = Some(stream);
        Ok(())
    }

    /// Whether a failure after the first frame is worth a reconnection: a network stream, a
    /// screen, any live pipeline (a film ends instead).
    fn reconnects(&self) -> bool {
        self.live_source || matches!(self.spec, MediaSpec::Uri(_) | MediaSpec::Screen(_))
    }

    /// A fault while playing: before the first frame it fails the source; after it a stream is
    /// reconnected later, and a file ends where it stopped decoding.
    fn fault(&mut self, f: media::Fault) -> Result<Next> {
        if self.frames == 0 {
            return Err(f.into_error());
        }
        let words = f.message.clone();
        self.control
            .update(|s| s.last_problem = Some(words.clone()));
        if self.reconnects() {
            tracing::warn!("{words}; holding the last frame and reconnecting");
            self.drop_stream();
            self.retry = Some((Instant::now() + BACKOFF_START, BACKOFF_START));
            Ok(Next::Idle)
        } else {
            tracing::warn!(
                "{words}; {} frame(s) played up to there, the rest is skipped",
                self.frames
            );
            Ok(Next::End)
        }
    }

    fn drop_stream(&mut self) {
        self.control.attach(None, Vec::new());
        self.stream = None;
    }

    /// A dropped stream: try again when its time has come.
    fn reconnect(&mut self, due: Instant, wait: Duration) -> Result<Next> {
        if Instant::now() < due {
            std::thread::sleep(PULL_SLICE.min(due - Instant::now()));
            return Ok(Next::Idle);
        }
        match self.start() {
            Ok(()) => {
                self.retry = None;
                self.control.update(|s| s.reconnects += 1);
                tracing::info!("{}: reconnected", self.describe);
            }
            Err(e) => {
                self.drop_stream();
                let next = (wait * 2).min(BACKOFF_MAX);
                tracing::warn!("{e}; trying again in {:.0} s", next.as_secs_f64());
                self.control
                    .update(|s| s.last_problem = Some(format!("{e} (reconnecting)")));
                self.retry = Some((Instant::now() + next, next));
            }
        }
        Ok(Next::Idle)
    }
}

impl VideoSource for MediaSource {
    fn describe(&self) -> String {
        self.describe.clone()
    }

    fn set_live(&mut self, live: bool) {
        self.live = live;
    }

    fn prepare(&mut self) -> Result<()> {
        self.start()
    }

    fn next(&mut self) -> Result<Next> {
        if let Some((due, wait)) = self.retry {
            return self.reconnect(due, wait);
        }
        if self.stream.is_none() {
            self.start()?;
        }
        let stream = self.stream.as_mut().expect("started above");
        if let Some(f) = stream.watch.poll() {
            return self.fault(f);
        }
        let warnings = stream.watch.warnings;
        let Some(sample) = stream.sink.try_pull_sample(media::clock_time(PULL_SLICE)) else {
            if !stream.sink.is_eos() {
                return Ok(Next::Idle);
            }
            // A live stream that ends (a server that went away, a camera that stopped)
            // dropped: it is reconnected. A film, or a file over the network, ends.
            if self.frames > 0 && self.live_source {
                return self.fault(media::Fault {
                    message: format!("{}: the stream ended", self.describe),
                    input: false,
                    transient: true,
                    source: None,
                });
            }
            return Ok(Next::End);
        };
        let (frame, fps) = to_frame(&sample, &self.describe)?;
        // The frame's place in the media, s (its timestamp in the stream's segment).
        let position = sample.buffer().and_then(|b| b.pts()).and_then(|pts| {
            let seg = sample.segment()?.downcast_ref::<gst::ClockTime>()?;
            seg.to_stream_time(pts).map(|t| t.nseconds() as f64 / 1e9)
        });
        self.frames += 1;
        let n = self.frames;
        self.control.update(|s| {
            s.frames = n;
            s.warnings = warnings;
            s.size = Some((frame.width, frame.height));
            s.fps = fps;
            if position.is_some() {
                s.position_s = position;
            }
        });
        Ok(Next::Frame { frame, wait: None })
    }

    fn ends_playback(&self) -> bool {
        // A film ends; a screen or a live stream plays until it is stopped (it ends only if
        // its source ends it).
        true
    }

    fn control(&self) -> Option<Control> {
        Some(self.control.clone())
    }
}

/// The words for `spec` in messages.
fn describe(spec: &MediaSpec) -> String {
    match spec {
        MediaSpec::File(p) => format!("video file {}", p.display()),
        MediaSpec::Uri(u) => format!("stream {}", redact(u)),
        MediaSpec::Screen(ScreenSpec::X11 { display, xid, .. }) => format!(
            "screen {}{}",
            display.as_deref().unwrap_or("(DISPLAY)"),
            xid.map(|x| format!(" window 0x{x:x}")).unwrap_or_default()
        ),
        MediaSpec::Screen(ScreenSpec::PipeWire { node, .. }) => {
            format!("PipeWire screen-cast node {node}")
        }
        MediaSpec::Pipeline(p) => {
            let short: String = p.chars().take(120).collect();
            let more = if short.len() < p.len() { "..." } else { "" };
            format!("GStreamer pipeline {short:?}{more}")
        }
    }
}

/// A URI without the password it may carry (`rtsp://user:secret@host` → `rtsp://user:***@host`).
fn redact(uri: &str) -> String {
    if let Some((scheme, rest)) = uri.split_once("://")
        && let Some((auth, host)) = rest.split_once('@')
        && let Some((user, _)) = auth.split_once(':')
    {
        return format!("{scheme}://{user}:***@{host}");
    }
    uri.to_string()
}

/// What can be checked without starting GStreamer's pipeline: a file is a readable regular file
/// that is not empty; the elements a screen needs are installed.
fn check_static(spec: &MediaSpec) -> Result<()> {
    match spec {
        MediaSpec::File(path) => {
            let (_, len) = crate::files::open_regular(path, "a video file")?;
            if len == 0 {
                return Err(Error::Input(format!(
                    "{}: empty (0 bytes), not a video file",
                    path.display()
                )));
            }
            Ok(())
        }
        MediaSpec::Screen(ScreenSpec::X11 { display, .. }) => {
            if display.is_none() && std::env::var_os("DISPLAY").is_none() {
                return Err(Error::Input(
                    "screen: no X display to capture: DISPLAY is not set; name one with \
                     screen:x11?display=:0"
                        .into(),
                ));
            }
            media::make("ximagesrc").map(|_| ())
        }
        MediaSpec::Screen(ScreenSpec::PipeWire { .. }) => media::make("pipewiresrc").map(|_| ()),
        MediaSpec::Uri(_) | MediaSpec::Pipeline(_) => Ok(()),
    }
}

/// The URI of a file path (absolute, percent-encoded).
fn file_uri(path: &Path) -> Result<String> {
    let abs: PathBuf = std::path::absolute(path).map_err(|e| Error::io(path, "resolve", e))?;
    gst::glib::filename_to_uri(&abs, None)
        .map(|u| u.to_string())
        .map_err(|e| {
            Error::Input(format!(
                "{}: not a path GStreamer can open ({e})",
                path.display()
            ))
        })
}

/// The caps compend's sink takes: 8-bit RGBA at any size.
fn rgba_caps() -> gst::Caps {
    gst_video::VideoCapsBuilder::new()
        .format(gst_video::VideoFormat::Rgba)
        .build()
}

/// compend's sink: synchronised to the clock in live pacing, as fast as decoding offline.
fn app_sink(live: bool) -> gst_app::AppSink {
    gst_app::AppSink::builder()
        .name("compend-sink")
        .caps(&rgba_caps())
        .sync(live)
        .max_buffers(2)
        .drop(false)
        .build()
}

/// The pipeline for `spec`, its sink, and the sinks of its sound (empty without sound).
fn build(
    spec: &MediaSpec,
    audio: &AudioOut,
    live: bool,
) -> Result<(gst::Pipeline, gst_app::AppSink, Vec<gst::Element>)> {
    let uri = match spec {
        MediaSpec::File(p) => Some(file_uri(p)?),
        MediaSpec::Uri(u) => Some(u.clone()),
        _ => None,
    };
    if let Some(uri) = uri {
        return build_playbin(&uri, audio, live);
    }
    let head = match spec {
        MediaSpec::Screen(ScreenSpec::X11 { display, xid, fps }) => format!(
            "ximagesrc use-damage=false show-pointer=false{}{} ! \
             video/x-raw,framerate={fps}/1 ! queue max-size-buffers=2 leaky=downstream",
            display
                .as_ref()
                .map(|d| format!(" display-name={}", quote(d)))
                .unwrap_or_default(),
            xid.map(|x| format!(" xid={x}")).unwrap_or_default()
        ),
        MediaSpec::Screen(ScreenSpec::PipeWire { node, fps }) => format!(
            "pipewiresrc path={} do-timestamp=true ! videorate ! video/x-raw,framerate={fps}/1",
            quote(node)
        ),
        MediaSpec::Pipeline(p) => p.clone(),
        MediaSpec::File(_) | MediaSpec::Uri(_) => unreachable!("played through playbin"),
    };
    let desc = format!("{head} ! videoconvert ! videoscale");
    let bin = gst::parse::bin_from_description(&desc, true)
        .map_err(|e| media::fault::parse_error(&head, e))?;
    let pipeline = gst::Pipeline::with_name("compend-media");
    let sink = app_sink(live);
    pipeline
        .add_many([bin.upcast_ref::<gst::Element>(), sink.upcast_ref()])
        .map_err(|e| Error::Failed(format!("GStreamer: building the pipeline: {e}")))?;
    bin.link(&sink).map_err(|_| {
        Error::Input(format!(
            "GStreamer pipeline {head:?}: its last element has no video output compend can \
             take (it must end in raw or decodable video)"
        ))
    })?;
    Ok((pipeline, sink, Vec::new()))
}

/// A property value quoted for a pipeline description.
fn quote(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

/// `playbin` for `uri`: its video to compend's sink, its sound to `audio`'s sink (live pacing
/// only: offline there is no clock to play sound against).
fn build_playbin(
    uri: &str,
    audio: &AudioOut,
    live: bool,
) -> Result<(gst::Pipeline, gst_app::AppSink, Vec<gst::Element>)> {
    let playbin = media::make("playbin")?;
    let sink = app_sink(live);
    let video = gst::Bin::with_name("compend-video");
    let convert = media::make("videoconvert")?;
    video
        .add_many([&convert, sink.upcast_ref()])
        .and_then(|_| {
            convert
                .link(&sink)
                .map_err(|e| gst::glib::bool_error!("{e}"))
        })
        .map_err(|e| Error::Failed(format!("GStreamer: building the video branch: {e}")))?;
    let pad = convert
        .static_pad("sink")
        .expect("videoconvert has a sink pad");
    let ghost = gst::GhostPad::with_target(&pad)
        .map_err(|e| Error::Failed(format!("GStreamer: building the video branch: {e}")))?;
    video
        .add_pad(&ghost)
        .map_err(|e| Error::Failed(format!("GStreamer: building the video branch: {e}")))?;
    playbin.set_property("uri", uri);
    playbin.set_property("video-sink", &video);
    let mut audio_sinks = Vec::new();
    // `auto` is resolved on each start: a sound card plugged in later is found by the next item.
    let sound = match (&audio.sink, live) {
        (Some(device), true) => media::audio::resolve(device),
        _ => None,
    };
    match sound {
        Some(desc) => {
            let abin = gst::parse::bin_from_description(
                &format!("audioconvert ! audioresample ! {desc}"),
                true,
            )
            .map_err(|e| media::fault::parse_error(&desc, e))?;
            // Its sinks' ts-offset delays the sound; an auto sink makes its sink when it starts,
            // so the control looks inside the bin each time it sets the delay.
            audio_sinks.push(abin.clone().upcast());
            playbin.set_property("audio-sink", &abin);
            playbin.set_property_from_str("flags", "video+audio+soft-volume");
        }
        None => {
            // playbin makes an `autoaudiosink` even for video alone unless it is given a sink,
            // and that one can block in a sound library: a sink that opens nothing.
            let quiet = media::make("fakesink")?;
            quiet.set_property("sync", false);
            quiet.set_property("async", false);
            playbin.set_property("audio-sink", &quiet);
            playbin.set_property_from_str("flags", "video");
        }
    }
    let pipeline = playbin
        .downcast::<gst::Pipeline>()
        .map_err(|_| Error::Failed("GStreamer: playbin is not a pipeline".into()))?;
    Ok((pipeline, sink, audio_sinks))
}

/// An RGBA sample as a content frame, with the frame rate its caps declare.
fn to_frame(sample: &gst::Sample, what: &str) -> Result<(ContentFrame, Option<f64>)> {
    let bad = |why: String| Error::Media {
        message: format!("{what}: a decoded frame compend cannot read ({why})"),
        input: false,
        source: None,
    };
    let caps = sample.caps().ok_or_else(|| bad("no caps".into()))?;
    let info = gst_video::VideoInfo::from_caps(caps).map_err(|e| bad(e.to_string()))?;
    let (w, h) = (info.width() as usize, info.height() as usize);
    if w * h > ImageSize::MAX_PIXELS {
        return Err(Error::Media {
            message: format!(
                "{what}: frames of {w}x{h} are more than the 8192x8192 pixels a frame may have"
            ),
            input: true,
            source: None,
        });
    }
    let buffer = sample.buffer().ok_or_else(|| bad("no buffer".into()))?;
    let frame = gst_video::VideoFrameRef::from_buffer_ref_readable(buffer, &info)
        .map_err(|e| bad(e.to_string()))?;
    let stride = frame.plane_stride()[0] as usize;
    let data = frame.plane_data(0).map_err(|e| bad(e.to_string()))?;
    let row = w * 4;
    let mut rgba = Vec::with_capacity(row * h);
    for y in 0..h {
        let start = y * stride;
        rgba.extend_from_slice(
            data.get(start..start + row)
                .ok_or_else(|| bad(format!("row {y} outside the buffer")))?,
        );
    }
    let fps = info.fps();
    let fps = (fps.numer() > 0 && fps.denom() > 0).then(|| fps.numer() as f64 / fps.denom() as f64);
    Ok((ContentFrame::from_rgba(w, h, rgba)?, fps))
}

/// What [`probe`] found of media before playing it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Probe {
    /// The frame rate it declares, frames per second (None: a live source, or variable).
    pub fps: Option<f64>,
    /// Its frame size (width, height), content pixels (None: a live source).
    pub size: Option<(usize, usize)>,
    /// Its length, s (None: a live source or a stream).
    pub duration_s: Option<f64>,
}

/// Whether `spec` plays, and what it is: the pipeline is built and brought to its first frame
/// (prerolled) with the sound off, within `timeout`, then stopped. A missing file, a file that
/// is not media, a codec no plugin decodes, an unknown element: an input error in words. A live
/// source (a screen) does not preroll; it is only built and started.
pub fn probe(spec: &MediaSpec, timeout: Duration) -> Result<Probe> {
    media::init()?;
    check_static(spec)?;
    let what = describe(spec);
    let (pipeline, sink, _) = build(
        spec,
        &AudioOut {
            sink: None,
            delay_ms: 0.0,
        },
        false,
    )?;
    let result = media::set_state(&pipeline, gst::State::Paused, timeout, &what).map(|_| {
        let mut probe = Probe {
            duration_s: pipeline
                .query_duration::<gst::ClockTime>()
                .map(|t| t.nseconds() as f64 / 1e9),
            ..Probe::default()
        };
        if let Some(sample) = sink.try_pull_preroll(gst::ClockTime::ZERO)
            && let Some(caps) = sample.caps()
            && let Ok(info) = gst_video::VideoInfo::from_caps(caps)
        {
            let f = info.fps();
            probe.fps =
                (f.numer() > 0 && f.denom() > 0).then(|| f.numer() as f64 / f.denom() as f64);
            probe.size = Some((info.width() as usize, info.height() as usize));
        }
        probe
    });
    media::stop(&pipeline);
    result
}

/// Whether `spec` plays ([`probe`], its findings left out).
pub fn check(spec: &MediaSpec, timeout: Duration) -> Result<()> {
    probe(spec, timeout).map(|_| ())
}
