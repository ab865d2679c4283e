//! GStreamer's errors in words: what went wrong with which media, whether the request was at
//! fault (exit 2: a missing file, a file that is not media, a codec no installed plugin decodes)
//! or the operation (exit 1: a stream or device that failed), and the Debian package that
//! decodes a missing codec. GStreamer's own text is kept as the error's source and in the
//! debug log, never shown alone.

use std::time::Duration;

use gstreamer as gst;
use gstreamer::prelude::*;

use crate::error::{Error, Result};

/// What went wrong in a pipeline, in words.
#[derive(Debug)]
pub struct Fault {
    /// The sentence for a person: the media, what happened, what to do.
    pub message: String,
    /// The request's fault (exit 2) rather than the operation's (exit 1).
    pub input: bool,
    /// A network or device failure that may clear up (a reconnect may help).
    pub transient: bool,
    /// GStreamer's error, kept as the source.
    pub source: Option<gst::glib::Error>,
}

impl Fault {
    pub fn into_error(self) -> Error {
        Error::Media {
            message: self.message,
            input: self.input,
            source: self.source.map(|e| Box::new(e) as _),
        }
    }
}

/// A codec's caps name, in words, and the Debian package whose plugin decodes it.
const CODECS: &[(&str, &str, &str)] = &[
    ("video/x-h264", "H.264 video", "gstreamer1.0-libav"),
    ("video/x-h265", "H.265 (HEVC) video", "gstreamer1.0-libav"),
    ("video/x-vp8", "VP8 video", "gstreamer1.0-plugins-good"),
    ("video/x-vp9", "VP9 video", "gstreamer1.0-plugins-good"),
    ("video/x-av1", "AV1 video", "gstreamer1.0-plugins-bad"),
    ("video/x-prores", "ProRes video", "gstreamer1.0-libav"),
    ("video/x-hap", "HAP video", "gstreamer1.0-libav"),
    ("video/mpeg", "MPEG video", "gstreamer1.0-libav"),
    (
        "video/x-theora",
        "Theora video",
        "gstreamer1.0-plugins-base",
    ),
    (
        "image/jpeg",
        "Motion JPEG video",
        "gstreamer1.0-plugins-good",
    ),
    (
        "audio/mpeg",
        "MPEG audio (AAC or MP3)",
        "gstreamer1.0-libav",
    ),
    ("audio/x-opus", "Opus audio", "gstreamer1.0-plugins-base"),
    (
        "audio/x-vorbis",
        "Vorbis audio",
        "gstreamer1.0-plugins-base",
    ),
    ("audio/x-ac3", "AC-3 audio", "gstreamer1.0-libav"),
    ("audio/x-flac", "FLAC audio", "gstreamer1.0-plugins-good"),
    (
        "video/quicktime",
        "the MP4/MOV container",
        "gstreamer1.0-plugins-good",
    ),
    (
        "video/x-matroska",
        "the Matroska/WebM container",
        "gstreamer1.0-plugins-good",
    ),
];

/// The Debian package that brings the GStreamer element `factory`, for the elements compend
/// names itself.
pub fn package_of_element(factory: &str) -> Option<&'static str> {
    Some(match factory {
        "playbin" | "uridecodebin" | "decodebin" | "videoconvert" | "videoscale"
        | "audioconvert" | "audioresample" | "appsink" | "appsrc" | "videorate" => {
            "gstreamer1.0-plugins-base"
        }
        "ximagesrc" | "autoaudiosink" | "pulsesink" | "mp4mux" | "matroskamux" | "webmmux"
        | "vp8enc" | "vp9enc" | "qtdemux" | "matroskademux" | "jpegenc" => {
            "gstreamer1.0-plugins-good"
        }
        "pipewiresrc" => "gstreamer1.0-pipewire",
        "openh264enc" | "shmsink" | "ndisink" | "srtsrc" => "gstreamer1.0-plugins-bad",
        "x264enc" => "gstreamer1.0-plugins-ugly",
        "v4l2sink" => "gstreamer1.0-plugins-good",
        f if f.starts_with("av") => "gstreamer1.0-libav",
        _ => return None,
    })
}

/// A codec's caps (`video/x-h265, ...`) in words with the package that decodes it.
fn codec_words(caps: &str) -> String {
    let name = caps.split([',', ' ']).next().unwrap_or(caps);
    match CODECS.iter().find(|(c, _, _)| *c == name) {
        Some((_, words, pkg)) => format!(
            "no installed GStreamer plugin decodes {words} ({name}); the Debian package {pkg} \
             does"
        ),
        None => format!("no installed GStreamer plugin decodes {name}"),
    }
}

/// Reads a pipeline's bus: errors become [`Fault`]s, a missing plugin is remembered so that the
/// error that follows it names the codec, warnings are counted and logged once each.
pub struct Watch {
    bus: gst::Bus,
    what: String,
    /// The codecs a decoder was missing for (from `missing-plugin` messages).
    missing: Vec<String>,
    /// Warnings posted (decoding errors a decoder skipped past, dropped data).
    pub warnings: u64,
    /// End of stream was posted.
    pub eos: bool,
}

impl Watch {
    /// The bus of `pipeline`; `what` names the media in messages.
    pub fn new(pipeline: &gst::Pipeline, what: &str) -> Self {
        Self {
            bus: pipeline.bus().expect("a pipeline has a bus"),
            what: what.to_string(),
            missing: Vec::new(),
            warnings: 0,
            eos: false,
        }
    }

    /// Reads every message posted so far; returns the first error, if any.
    pub fn poll(&mut self) -> Option<Fault> {
        while let Some(msg) = self.bus.pop() {
            if let Some(f) = self.read(&msg) {
                return Some(f);
            }
        }
        None
    }

    /// Waits up to `timeout` for an error (or end of stream); returns the error.
    pub fn first_error(mut self, timeout: Duration) -> Option<Fault> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let msg = self.bus.timed_pop(super::clock_time(left))?;
            if let Some(f) = self.read(&msg) {
                return Some(f);
            }
            if self.eos || left.is_zero() {
                return None;
            }
        }
    }

    /// Waits up to `timeout` for the end of the stream; an error ends the wait with it.
    pub fn wait_eos(&mut self, timeout: Duration) -> Result<bool> {
        let deadline = std::time::Instant::now() + timeout;
        while !self.eos {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Ok(false);
            }
            if let Some(msg) = self.bus.timed_pop(super::clock_time(left))
                && let Some(f) = self.read(&msg)
            {
                return Err(f.into_error());
            }
        }
        Ok(true)
    }

    fn read(&mut self, msg: &gst::Message) -> Option<Fault> {
        use gst::MessageView;
        match msg.view() {
            MessageView::Eos(_) => self.eos = true,
            MessageView::Element(e) => {
                if let Some(s) = e.structure()
                    && s.name() == "missing-plugin"
                {
                    let detail = s
                        .get::<gst::Caps>("detail")
                        .map(|c| c.to_string())
                        .or_else(|_| s.get::<String>("detail"))
                        .unwrap_or_else(|_| "an unknown format".into());
                    tracing::debug!("{}: GStreamer is missing a plugin for {detail}", self.what);
                    self.missing.push(detail);
                }
            }
            MessageView::Warning(w) => {
                self.warnings += 1;
                if self.warnings <= 3 {
                    tracing::warn!(
                        "{}: {} ({})",
                        self.what,
                        w.error().message(),
                        w.src().map(|s| s.name().to_string()).unwrap_or_default()
                    );
                }
            }
            MessageView::Error(e) => {
                let element = e.src().map(|s| s.name().to_string()).unwrap_or_default();
                tracing::debug!(
                    "{}: GStreamer error from {element}: {} ({})",
                    self.what,
                    e.error(),
                    e.debug().map(|d| d.to_string()).unwrap_or_default()
                );
                return Some(self.explain(e.error(), &element));
            }
            _ => {}
        }
        None
    }

    /// An error in words.
    fn explain(&self, err: gst::glib::Error, element: &str) -> Fault {
        let what = &self.what;
        let gmsg = err.message().to_string();
        let fault = |message: String, input: bool, transient: bool| Fault {
            message,
            input,
            transient,
            source: Some(err.clone()),
        };
        if let Some(codec) = self.missing.first() {
            return fault(format!("{what}: {}", codec_words(codec)), true, false);
        }
        if let Some(k) = err.kind::<gst::StreamError>() {
            use gst::StreamError as S;
            return match k {
                S::TypeNotFound | S::WrongType => fault(
                    format!(
                        "{what}: not a media file GStreamer recognises (a video file: MP4, \
                         MKV, MOV or WebM)"
                    ),
                    true,
                    false,
                ),
                S::CodecNotFound => fault(
                    format!("{what}: no installed GStreamer plugin decodes its streams ({gmsg})"),
                    true,
                    false,
                ),
                S::Demux | S::Decode | S::Format | S::Failed => fault(
                    format!(
                        "{what}: damaged or truncated media: {element} could not read it \
                         ({gmsg})"
                    ),
                    true,
                    false,
                ),
                _ => fault(format!("{what}: {element}: {gmsg}"), false, false),
            };
        }
        if let Some(k) = err.kind::<gst::ResourceError>() {
            use gst::ResourceError as R;
            return match k {
                R::NotFound => fault(format!("{what}: not found ({gmsg})"), true, false),
                R::OpenRead | R::OpenReadWrite | R::OpenWrite | R::NotAuthorized => fault(
                    format!("{what}: cannot be opened by {element} ({gmsg})"),
                    true,
                    true,
                ),
                R::NoSpaceLeft => fault(format!("{what}: the disk is full ({gmsg})"), false, false),
                R::Read | R::Write | R::Seek | R::Busy | R::Failed | R::Settings => {
                    fault(format!("{what}: {element} failed ({gmsg})"), false, true)
                }
                _ => fault(format!("{what}: {element}: {gmsg}"), false, true),
            };
        }
        if let Some(k) = err.kind::<gst::CoreError>()
            && k == gst::CoreError::MissingPlugin
        {
            return fault(
                format!("{what}: a GStreamer plugin is missing ({gmsg})"),
                true,
                false,
            );
        }
        fault(format!("{what}: {element}: {gmsg}"), false, false)
    }
}

/// A pipeline description that `gst::parse` refused, in words (an unknown element named, with
/// the package that brings it where compend knows it).
pub fn parse_error(desc: &str, err: gst::glib::Error) -> Error {
    let words = match err.kind::<gst::ParseError>() {
        Some(gst::ParseError::NoSuchElement) => {
            // GStreamer's message names the element: no element "x264enc"
            let name = err
                .message()
                .split('"')
                .nth(1)
                .unwrap_or_default()
                .to_string();
            let pkg = package_of_element(&name)
                .map(|p| format!("; the Debian package {p} brings it"))
                .unwrap_or_default();
            format!("no GStreamer element {name:?} is installed{pkg}")
        }
        Some(gst::ParseError::NoSuchProperty) | Some(gst::ParseError::CouldNotSetProperty) => {
            format!("a property is wrong: {}", err.message())
        }
        _ => format!("not a pipeline GStreamer can build: {}", err.message()),
    };
    Error::Media {
        message: format!("GStreamer pipeline {desc:?}: {words}"),
        input: true,
        source: Some(Box::new(err)),
    }
}
