//! Compensated frames to other software (shell, above the playback loop: an output is one of its
//! [`Screen`]s) (`play --to`, `compensate` of a film): the projector
//! canvas (projector pixels, 8-bit RGBA as presented) pushed into a GStreamer pipeline through
//! an `appsrc`, as well as or instead of the window.
//!
//! - `gst:PIPELINE`: any pipeline that takes raw video, e.g. `videoconvert ! x264enc ! mp4mux !
//!   filesink location=out.mp4`, `v4l2sink device=/dev/video10` (v4l2loopback),
//!   `shmsink socket-path=/tmp/compend`, `ndisink` where the plugin is installed.
//! - `file:PATH`: an encoded file chosen by its ending (`.mp4`, `.mov`, `.mkv`: H.264; `.webm`:
//!   VP8; an odd side padded with one black row or column, as 4:2:0 needs), written to a
//!   temporary sibling and renamed when the stream is complete, so a run
//!   that is killed or fails leaves no half-written file under the name; an existing file is
//!   never replaced.
//!
//! Timestamps: offline (`--pace source`) frame `n` (from 0) is at `n / fps`, so a film renders
//! faster than real time with its own timing; live, a frame is stamped with the time since the
//! first was presented.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use gstreamer_video as gst_video;

use crate::error::{Error, Result};
use crate::gpu::joint::SetPass;
use crate::gpu::{FramePass, GpuContext};
use crate::media::{self, Watch, fault};
use crate::player::{PlayStats, Refresh, Screen, Show};
use crate::raster::{ImageSize, PrjImage};

/// The spellings of `--to`, as `compend play --help` shows them.
pub const HELP: &str = "\
Outputs (--to, [output] to):
  file:PATH                an encoded video file by its ending: .mp4, .mov, .mkv (H.264),
                           .webm (VP8); written complete or not at all, never over a file
  gst:PIPELINE             any GStreamer pipeline that takes raw RGBA video at the projector's
                           size, e.g. gst:videoconvert ! v4l2sink device=/dev/video10";

/// Where compensated frames go.
#[derive(Clone, Debug, PartialEq)]
pub enum OutputSpec {
    /// An encoded file, written to a temporary sibling and renamed when complete.
    File(PathBuf),
    /// A pipeline description that takes raw video.
    Pipeline(String),
}

impl std::fmt::Display for OutputSpec {
    /// The spelling `--to` takes.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::File(p) => write!(f, "file:{}", p.display()),
            Self::Pipeline(p) => write!(f, "gst:{p}"),
        }
    }
}

impl OutputSpec {
    /// For a service that plays many times into one configured file: the first free
    /// `NAME-0001.EXT`, `NAME-0002.EXT`, ... beside it (a pipeline is used as it is).
    pub fn numbered(&self) -> Self {
        let Self::File(path) = self else {
            return self.clone();
        };
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let ext = path
            .extension()
            .map(|e| format!(".{}", e.to_string_lossy()))
            .unwrap_or_default();
        let mut n = 1u32;
        loop {
            let candidate = path.with_file_name(format!("{stem}-{n:04}{ext}"));
            if std::fs::symlink_metadata(&candidate).is_err() || n == u32::MAX {
                return Self::File(candidate);
            }
            n += 1;
        }
    }

    /// Parses a `--to` value.
    pub fn parse(to: &str) -> Result<Self> {
        let bad =
            |why: &str| Error::Input(format!("--to {to:?}: {why} (see `compend play --help`)"));
        match to.split_once(':') {
            Some(("gst", p)) if !p.trim().is_empty() => Ok(Self::Pipeline(p.trim().to_string())),
            Some(("gst", _)) => Err(bad("gst: needs a pipeline description")),
            Some(("file", p)) if !p.is_empty() => {
                let path = PathBuf::from(p);
                encoder_for(&path)?;
                Ok(Self::File(path))
            }
            Some(("file", _)) => Err(bad("file: needs a path")),
            _ => Err(bad("expected file:PATH or gst:PIPELINE")),
        }
    }
}

/// The encoding pipeline for a file by its ending (without the sink).
fn encoder_for(path: &Path) -> Result<String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let h264 = || -> Result<&'static str> {
        // The best H.264 encoder installed: x264 (plugins-ugly), else OpenH264 (plugins-bad).
        if media::has_element("x264enc") {
            Ok("x264enc speed-preset=veryfast bitrate=20000 key-int-max=60")
        } else if media::has_element("openh264enc") {
            Ok("openh264enc bitrate=20000000 complexity=low")
        } else {
            Err(Error::Input(format!(
                "{}: no H.264 encoder is installed: the Debian package gstreamer1.0-plugins-ugly \
                 (x264enc) or gstreamer1.0-plugins-bad (openh264enc) brings one",
                path.display()
            )))
        }
    };
    let mux = match ext.as_str() {
        "mp4" | "m4v" => "mp4mux",
        "mov" => "qtmux",
        "mkv" => "matroskamux",
        "webm" => {
            return Ok(
                "videoconvert ! video/x-raw,format=I420 ! vp8enc deadline=1 \
                       target-bitrate=20000000 ! webmmux"
                    .into(),
            );
        }
        _ => {
            return Err(Error::Input(format!(
                "{}: not a video file ending compend writes (.mp4, .mov, .mkv, .webm)",
                path.display()
            )));
        }
    };
    Ok(format!(
        "videoconvert ! video/x-raw,format=I420 ! {} ! h264parse ! {mux}",
        h264()?
    ))
}

/// A running output: frames in through `appsrc`.
pub struct MediaOutput {
    pipeline: gst::Pipeline,
    src: gst_app::AppSrc,
    watch: Watch,
    what: String,
    size: ImageSize,
    fps: f64,
    /// For a file: (the temporary sibling written, the final path).
    file: Option<(PathBuf, PathBuf)>,
    frames: u64,
    finished: bool,
}

impl MediaOutput {
    /// Starts the output for frames of `size` (projector pixels) at `fps`. `live`: frames
    /// arrive in real time (the appsrc is live and does not block the render loop: a frame the
    /// pipeline has no room for is dropped and counted by GStreamer); offline, a frame waits
    /// for room. A file already at the path, an unknown element or a pipeline that cannot
    /// start is an input error, before any frame.
    pub fn start(spec: &OutputSpec, size: ImageSize, fps: f64, live: bool) -> Result<Self> {
        media::init()?;
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Error::Input(format!(
                "output frame rate must be positive, got {fps}"
            )));
        }
        let (tail, file, what) = match spec {
            OutputSpec::Pipeline(p) => (p.clone(), None, format!("output pipeline {p:?}")),
            OutputSpec::File(path) => {
                if std::fs::symlink_metadata(path).is_ok() {
                    return Err(Error::Input(format!(
                        "{}: already there; compend does not write over a file (choose another \
                         path or remove it)",
                        path.display()
                    )));
                }
                let tmp = crate::files::temp_sibling(path)?;
                let parent = crate::files::parent_of(path);
                if !parent.is_dir() {
                    return Err(Error::Missing {
                        path: parent.to_path_buf(),
                        expected: "the folder the output file goes into".into(),
                    });
                }
                let loc = tmp
                    .to_str()
                    .ok_or_else(|| Error::Input(format!("{}: not a UTF-8 path", path.display())))?;
                // 4:2:0 encoders take even sizes: an odd projector side gets one black row or
                // column (the projector's pixels stay as they are, none scaled).
                let pad = if size.width % 2 == 1 || size.height % 2 == 1 {
                    format!(
                        "videobox right=-{} bottom=-{} fill=black ! ",
                        size.width % 2,
                        size.height % 2
                    )
                } else {
                    String::new()
                };
                (
                    format!(
                        "{pad}{} ! filesink location=\"{}\"",
                        encoder_for(path)?,
                        loc.replace('\\', "\\\\").replace('"', "\\\"")
                    ),
                    Some((tmp, path.clone())),
                    format!("output file {}", path.display()),
                )
            }
        };
        let desc = format!("appsrc name=compend-src ! queue max-size-buffers=4 ! {tail}");
        let pipeline = gst::parse::launch(&desc)
            .map_err(|e| fault::parse_error(&tail, e))?
            .downcast::<gst::Pipeline>()
            .map_err(|_| Error::Failed("GStreamer: the output is not a pipeline".into()))?;
        let src = pipeline
            .by_name("compend-src")
            .and_then(|e| e.downcast::<gst_app::AppSrc>().ok())
            .ok_or_else(|| Error::Failed("GStreamer: the output has no appsrc".into()))?;
        let rate = gst::Fraction::approximate_f64(fps)
            .ok_or_else(|| Error::Input(format!("output frame rate {fps} is not a fraction")))?;
        let caps = gst_video::VideoCapsBuilder::new()
            .format(gst_video::VideoFormat::Rgba)
            .width(size.width as i32)
            .height(size.height as i32)
            .framerate(rate)
            .build();
        src.set_caps(Some(&caps));
        src.set_format(gst::Format::Time);
        src.set_is_live(live);
        src.set_block(!live);
        src.set_max_bytes((size.width * size.height * 4 * 3) as u64);
        if live {
            src.set_leaky_type(gst_app::AppLeakyType::Downstream);
        }
        let mut watch = Watch::new(&pipeline, &what);
        if pipeline.set_state(gst::State::Playing).is_err() {
            let f = watch.poll();
            media::stop(&pipeline);
            if let Some((tmp, _)) = &file {
                let _ = std::fs::remove_file(tmp);
            }
            return Err(f
                .map(|f| f.into_error())
                .unwrap_or_else(|| Error::Input(format!("{what}: GStreamer could not start it"))));
        }
        Ok(Self {
            pipeline,
            src,
            watch,
            what,
            size,
            fps,
            file,
            frames: 0,
            finished: false,
        })
    }

    /// Pushes one frame (RGBA, `size` of the output) at `pts` from the output's start.
    pub fn push(&mut self, rgba: Vec<u8>, pts: Duration) -> Result<()> {
        let expected = self.size.width * self.size.height * 4;
        if rgba.len() != expected {
            return Err(Error::Shape(format!(
                "{}: a frame of {} bytes, expected {expected} ({} RGBA)",
                self.what,
                rgba.len(),
                self.size
            )));
        }
        if let Some(f) = self.watch.poll() {
            return Err(f.into_error());
        }
        let mut buffer = gst::Buffer::from_mut_slice(rgba);
        {
            let b = buffer.get_mut().expect("a new buffer is writable");
            b.set_pts(media::clock_time(pts));
            b.set_duration(media::clock_time(Duration::from_secs_f64(1.0 / self.fps)));
        }
        match self.src.push_buffer(buffer) {
            Ok(_) => {
                self.frames += 1;
                Ok(())
            }
            Err(flow) => Err(self
                .watch
                .poll()
                .map(|f| f.into_error())
                .unwrap_or_else(|| {
                    Error::Failed(format!(
                        "{}: it stopped taking frames ({flow:?})",
                        self.what
                    ))
                })),
        }
    }

    /// Ends the stream and waits for the pipeline to write it out (a file is complete and
    /// renamed into place); returns the frames written.
    pub fn finish(mut self) -> Result<u64> {
        self.finished = true;
        self.close(Duration::from_secs(120))?;
        Ok(self.frames)
    }

    fn close(&mut self, timeout: Duration) -> Result<()> {
        let ended = match self.src.end_of_stream() {
            Ok(_) => self.watch.wait_eos(timeout),
            Err(_) => Ok(false),
        };
        media::stop(&self.pipeline);
        let ended = match ended {
            Ok(true) => Ok(()),
            Ok(false) => Err(Error::Failed(format!(
                "{}: the stream did not end within {:.0} s",
                self.what,
                timeout.as_secs_f64()
            ))),
            Err(e) => Err(e),
        };
        if let Some((tmp, path)) = self.file.take() {
            match &ended {
                Ok(()) if self.frames > 0 => {
                    crate::files::rename_no_replace(&tmp, &path)?;
                }
                _ => {
                    let _ = std::fs::remove_file(&tmp);
                }
            }
        }
        ended
    }
}

impl Drop for MediaOutput {
    /// An output dropped without [`MediaOutput::finish`] (playback failed): the stream is ended
    /// briefly so a file is still complete up to there; errors only logged.
    fn drop(&mut self) {
        if !self.finished
            && let Err(e) = self.close(Duration::from_secs(10))
        {
            tracing::warn!("{e}");
        }
    }
}

/// One media output per projector of a set (`play --to` once per projector, `[[projector]] to`),
/// fed each projector's canvas (projector pixels).
pub struct SetOutputs {
    outputs: Vec<MediaOutput>,
    live: bool,
    fps: f64,
    started: Option<Instant>,
    pushed: u64,
}

impl SetOutputs {
    /// Starts `specs` (none: no outputs) for `n` projectors of `size` at `fps`.
    pub fn start(
        specs: &[OutputSpec],
        n: usize,
        size: ImageSize,
        fps: f64,
        live: bool,
    ) -> Result<Option<Self>> {
        if specs.is_empty() {
            return Ok(None);
        }
        if specs.len() != n {
            return Err(Error::Input(format!(
                "{} output(s) for a set of {n} projectors: one output per projector, in the \
                 set's order",
                specs.len()
            )));
        }
        // Two projectors' frames cannot go into one file (a pipeline may be meant twice).
        for (i, a) in specs.iter().enumerate() {
            if let OutputSpec::File(_) = a
                && let Some(j) = specs[i + 1..].iter().position(|b| b == a)
            {
                return Err(Error::Input(format!(
                    "{a} is given for projectors {} and {}: each projector needs an output of its \
                     own",
                    i + 1,
                    i + j + 2
                )));
            }
        }
        let outputs = specs
            .iter()
            .map(|s| MediaOutput::start(s, size, fps, live))
            .collect::<Result<Vec<_>>>()?;
        Ok(Some(Self {
            outputs,
            live,
            fps,
            started: None,
            pushed: 0,
        }))
    }

    /// Pushes one frame per projector (projector pixels, the outputs' size).
    pub fn push(&mut self, frames: &[PrjImage]) -> Result<()> {
        let now = Instant::now();
        let pts = if self.live {
            now.saturating_duration_since(*self.started.get_or_insert(now))
        } else {
            Duration::from_secs_f64(self.pushed as f64 / self.fps)
        };
        for (o, f) in self.outputs.iter_mut().zip(frames) {
            o.push(crate::pngio::to_rgba8(f), pts)?;
        }
        self.pushed += 1;
        Ok(())
    }

    /// Ends every output's stream (files complete and renamed into place); the frames each
    /// wrote.
    pub fn finish(self) -> Result<Vec<u64>> {
        self.outputs.into_iter().map(MediaOutput::finish).collect()
    }
}

/// A set's screen whose every new frame also goes to one output per projector
/// ([`SetOutputs`]: each projector's canvas, read back from the GPU as presented).
pub struct SetTeed<'a, S: ?Sized> {
    inner: &'a mut S,
    out: Option<SetOutputs>,
}

impl<'a, S: ?Sized> SetTeed<'a, S> {
    pub fn new(inner: &'a mut S, out: Option<SetOutputs>) -> Self {
        Self { inner, out }
    }

    /// Ends the outputs' streams (files complete and renamed into place); the frames each
    /// wrote, none without outputs.
    pub fn finish_outputs(&mut self) -> Result<Option<Vec<u64>>> {
        self.out.take().map(SetOutputs::finish).transpose()
    }
}

impl<S: Screen<SetPass> + ?Sized> Screen<SetPass> for SetTeed<'_, S> {
    fn context(&self) -> &GpuContext {
        self.inner.context()
    }
    fn refresh(&self) -> Refresh {
        self.inner.refresh()
    }
    fn begin(&mut self, live: bool) -> Result<()> {
        self.inner.begin(live)
    }
    fn keep_going(&mut self) -> bool {
        self.inner.keep_going()
    }
    fn take_pass(&mut self) -> Option<SetPass> {
        self.inner.take_pass()
    }
    fn refreshed(&mut self, stats: &PlayStats) {
        self.inner.refreshed(stats)
    }
    fn display_delay(&self) -> Duration {
        self.inner.display_delay()
    }
    fn present(&mut self, pass: &SetPass, show: Show) -> Result<()> {
        self.inner.present(pass, show)?;
        let (Show::New { .. }, Some(out)) = (show, self.out.as_mut()) else {
            return Ok(());
        };
        out.push(&pass.canvases(self.inner.context())?)
    }
    fn finish(&mut self, stats: &mut PlayStats) -> Result<()> {
        let inner = self.inner.finish(stats);
        // The outputs' files are completed even when the display failed.
        let outputs = self.finish_outputs();
        inner?;
        outputs.map(drop)
    }
}

/// A screen whose every new frame also goes to a [`MediaOutput`] (read back from the GPU as
/// presented), when there is one. With [`crate::player::Headless`] as the inner
/// screen, the output replaces the window.
pub struct Teed<'a, S: ?Sized> {
    inner: &'a mut S,
    out: Option<MediaOutput>,
    live: bool,
    fps: f64,
    start: Option<Instant>,
}

impl<'a, S: ?Sized> Teed<'a, S> {
    pub fn new(inner: &'a mut S, out: impl Into<Option<MediaOutput>>) -> Self {
        let out = out.into();
        let fps = out.as_ref().map_or(60.0, |o| o.fps);
        Self {
            inner,
            out,
            live: true,
            fps,
            start: None,
        }
    }
}

impl<P: FramePass, S: Screen<P> + ?Sized> Screen<P> for Teed<'_, S> {
    fn context(&self) -> &GpuContext {
        self.inner.context()
    }
    fn refresh(&self) -> Refresh {
        self.inner.refresh()
    }
    fn begin(&mut self, live: bool) -> Result<()> {
        self.live = live;
        self.inner.begin(live)
    }
    fn keep_going(&mut self) -> bool {
        self.inner.keep_going()
    }
    fn take_pass(&mut self) -> Option<P> {
        self.inner.take_pass()
    }
    fn refreshed(&mut self, stats: &PlayStats) {
        self.inner.refreshed(stats)
    }
    fn display_delay(&self) -> Duration {
        self.inner.display_delay()
    }
    fn present(&mut self, pass: &P, show: Show) -> Result<()> {
        self.inner.present(pass, show)?;
        let Show::New { index, .. } = show else {
            return Ok(());
        };
        let Some(out) = self.out.as_mut() else {
            return Ok(());
        };
        let rgba = pass.read_frame_rgba(self.inner.context())?;
        let pts = if self.live {
            self.start.get_or_insert_with(Instant::now).elapsed()
        } else {
            Duration::from_secs_f64((index - 1) as f64 / self.fps)
        };
        out.push(rgba, pts)
    }
    fn finish(&mut self, stats: &mut PlayStats) -> Result<()> {
        let inner = self.inner.finish(stats);
        // The output's frames are counted and the file completed even when the display
        // failed.
        if let Some(out) = self.out.take() {
            stats.output_frames = Some(out.finish()?);
        }
        inner
    }
}
